"""The compiled kernels free every array they make, whatever path a step takes.

A step runs a dozen kernels that make scratch arrays, and the drives' hot loop is compiled without
numba's reference counting (drive_integrator.rk4_substeps; numba refuses to compile an allocation there). An
array that one of them failed to free would leak at every step, silently, until a long real-time run
filled its host's memory. numba's allocation counters see it at once: over a stretch of steps every
allocation of the compiled code is freed again, for each path a step can take (the drives alone, the
drives with a contact, the operational-space controller, the drives off).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba.core.runtime import _nrt_python, rtsys
from simecs import models
from simecs.mesh.protocol import messages as m
from simecs.models.contact_geometry import TOOL_RADIUS
from simecs.models.ik import ArmKinematics


def unfreed_during(advance: object) -> int:
    """Allocations of the compiled code not freed while `advance()` ran."""
    before = rtsys.get_allocation_stats()
    advance()  # type: ignore[operator]
    after = rtsys.get_allocation_stats()
    return (after.alloc - before.alloc) - (after.free - before.free)


@pytest.fixture(scope="module", autouse=True)
def counting() -> None:
    _nrt_python.memsys_enable_stats()


def spider_pressing_a_plane() -> tuple[models.Simulation, list[float]]:
    """The Spider with a plane 5 mm into its tool tip: every step has a contact pair."""
    pkg = models.get_model("spider")
    values = pkg.describe().default_values()
    q0 = [0.0] * pkg.n
    p, _R = ArmKinematics(pkg.spec, values).tool_pose(np.zeros(pkg.n))
    lid = m.Obstacle(
        "lid", "plane", [float(p[0]), float(p[1]), float(p[2] + TOOL_RADIUS - 0.005)], [math.pi, 0.0, 0.0]
    )
    sim = pkg.build(values)
    sim.set_obstacles([lid])
    return sim, q0


@pytest.mark.parametrize("path", ["drives", "contact", "opspace", "drives_off"])
def test_the_steps_kernels_free_every_array_they_make(path: str) -> None:
    pkg = models.get_model("spider")
    if path == "contact":
        sim, q0 = spider_pressing_a_plane()
    else:
        sim, q0 = pkg.build({}), list(pkg.home())
    try:
        sim.set_initial(q0)
        target = [0.4, -0.3, 0.5, 0.2, -0.2, 0.3, 0.1] if path != "contact" else q0
        sim.set_joint_path([(target, 30.0, 30.0)])
        if path == "opspace":
            sim.set_control("opspace_motion", 0.002)
        if path == "drives_off":
            sim.set_values({"drives.enabled": 0.0})
        sim.start(1.0, 0.002)
        sim.advance(0.05)  # compiled and warm
        assert unfreed_during(lambda: sim.advance(0.3)) == 0
        rows = sim.advance(1.0)
        assert rows.shape[0] > 0 and np.all(np.isfinite(rows))
        if path == "contact":
            c = sim.columns.index("contact.link7.force")
            assert rows[-1, c] > 0.0  # the path this case is for was taken
    finally:
        sim.close()
