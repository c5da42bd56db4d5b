"""One mechanics step's compiled work, in one call from Exudyn's PreStep: the chain's quantities at the
step start (joint frames, mass matrix and its inverse, bias forces) computed once and shared by the
operational-space controller, the contact pairs and the drives' in-step predictor.

One call, not one per part: every call into a kernel costs about a microsecond of argument checks,
and the controller and the drives each used to compute the same frames, mass matrix and bias again.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any

import numpy as np
from numba import njit

from . import drive as dr
from . import jit, references
from .chain_dynamics import chain_state, gravity_torques
from .chain_kinematics import spd_inverse
from .contact import ContactTables
from .drive_integrator import DriveArrays, drive_step
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .mechanics import ChainArrays
from .opspace import ControllerArrays, control_update


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def chain_step(drives, sp, chain, gravity, ctl, tables, q, qd, t, h, nsub, repeat, control_due):
    """The step from t to t + h at the chain state q, qd: when `control_due`, the operational-space
    controller's period first (opspace.control_update, with `ctl`: opspace.ControllerArrays), then the
    drives (drive_integrator.DriveArrays) over the step (drive_integrator.drive_step, whose status this
    returns: STEP_*; `repeat`: the solver takes the same step again). `sp`: the set points
    (references.SetPointArrays); `chain`: mechanics.ChainArrays; `tables`: contact.ContactTables."""
    state = chain_state(chain, gravity, q, qd)
    R_all, p_all, M, bias = state
    Minv = spd_inverse(M)
    P = drives.P
    gravity_feedforward(P, sp, chain, gravity, t)
    if control_due:
        t_next = (round(t / h) + round(ctl.period / h)) * h  # the next period's t, as the caller will pass it
        control_update(P, drives.X, sp, chain, gravity, state, ctl, tables, q, qd, t, t_next)
    return drive_step(drives, sp, R_all, p_all, Minv, bias, tables, repeat, q, qd, t, h, nsub)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def gravity_feedforward(P, sp, chain, gravity, t):
    """The cascade's gravity feed-forward for the step from t, into live[:, LV_GRAVITY]: the current
    whose motor torque holds the model's gravity torque at the set points (not at the measured pose: a
    model-based feed-forward, as a real controller computes it), weighted per joint by ctrl.ff_gravity.
    Nothing to compute (0 written) in zero gravity or when no joint is under the cascade."""
    live = sp.live
    n = live.shape[0]
    cascade = False
    for j in range(n):
        cascade = cascade or live[j, references.LV_EXTERNAL] <= 0.5
    if not cascade or (gravity[0] == 0.0 and gravity[1] == 0.0 and gravity[2] == 0.0):
        for j in range(n):
            live[j, references.LV_GRAVITY] = 0.0
        return
    refs = np.empty((3, n))
    qr, qdr, g = refs[0], refs[1], refs[2]
    references.ref_eval(sp, t, qr, qdr)
    gravity_torques(chain, gravity, qr, g)
    for j in range(n):
        holding = g[j] / P[j, dr.P_N] * dr.resting_gear_factor(P[j, dr.P_ETA])
        live[j, references.LV_GRAVITY] = P[j, dr.P_FFG] * holding / P[j, dr.P_KT]


#: What the step kernel reads besides the step's own values, taken once per solver call (nothing
#: replaces these arrays while the solver runs).
StepArrays = tuple[
    DriveArrays, references.SetPointArrays, ChainArrays, np.ndarray, ControllerArrays, ContactTables
]

#: The step kernel's machine code (jit.compiled_for) as mypy sees it: StepArrays, then q, qd, t, h,
#: substeps, repeat, control_due.
StepKernel = Callable[
    [
        DriveArrays,
        references.SetPointArrays,
        ChainArrays,
        np.ndarray,
        ControllerArrays,
        ContactTables,
        np.ndarray,
        np.ndarray,
        float,
        float,
        int,
        bool,
        bool,
    ],
    int,
]


class CompiledStep:
    """`chain_step`'s machine code for the types of a solver call's arguments, called past numba's
    type dispatch (jit.compiled_for); looked up again only when a type changed (a command that
    replaced an array by one of another kind)."""

    def __init__(self) -> None:
        self._key: Hashable = None
        self._entry: StepKernel | None = None

    def for_args(self, args: tuple[Any, ...]) -> StepKernel:
        key = jit.type_key(args)
        if self._entry is None or key != self._key:
            self._key, self._entry = key, jit.compiled_for(chain_step, args)
        return self._entry
