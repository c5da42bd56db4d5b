"""`ModelPackage`: one model of the library, what `get_model(id)` returns.

Its description (description.py) plus what the simulator needs from it: the chain and drive arrays
(mechanics.py) and `build`, a ready `Simulation` (simulation.py).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import mechanics
from .description import ArmDescription
from .simulation import Simulation


class ModelPackage(ArmDescription):
    """One model of the library: its description as data, validation, and `build`."""

    def chain_arrays(self, values: Mapping[str, float]) -> mechanics.ChainArrays:
        """pre_R, pre_p (joint i frame from joint i-1 frame), masses, COMs, inertias in joint frames."""
        return mechanics.chain_arrays(self.spec, values)

    def drive_array(self, values: Mapping[str, float]) -> np.ndarray:
        """The drive parameters as the kernels' array P[joint, k] (`drive.DRIVE_PARAMS` order)."""
        return mechanics.drive_array(self.n, values)

    def build(self, values: Mapping[str, float] | None = None) -> Simulation:
        """A simulation with these parameter values (the rest at their defaults), checked first:
        ParameterError names the first bad value."""
        return Simulation(self, self.check_values(values or {}))
