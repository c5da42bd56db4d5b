"""One mechanics step's compiled work, in one call from Exudyn's PreStep: the chain's quantities at the
step start (joint frames, mass matrix and its inverse, bias forces) computed once and shared by the
operational-space controller, the contact pairs and the drives' in-step predictor.

One call, not one per part: every call into a kernel costs about a microsecond of argument checks,
and the controller and the drives each used to compute the same frames, mass matrix and bias again.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import drive as dr
from . import references
from .chain_dynamics import chain_state, gravity_torques
from .chain_kinematics import spd_inverse
from .drive_integrator import drive_step
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .opspace import control_update


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def chain_step(
    P,
    seg,
    hold,
    tab,
    jmode,
    live,
    pre_R,
    pre_p,
    masses,
    coms,
    inertias,
    gravity,
    X,
    Xbak,
    repeat,
    q,
    qd,
    t,
    h,
    nsub,
    tau_out,
    work,
    tables,
    control_due,
    R_last,
    tool_local,
    gains,
    period,
    forces,
    f_tool,
    integ,
    memo,
    i_ref,
):
    """The step from t to t + h at the chain state q, qd: when `control_due`, the operational-space
    controller's period first (opspace.control_update: gains, period, forces, f_tool, integ, memo,
    i_ref are its own), then the drives over the step (drive_integrator.drive_step, whose status this returns:
    STEP_*)."""
    R_all, p_all, M, bias = chain_state(pre_R, pre_p, masses, coms, inertias, gravity, q, qd)
    Minv = spd_inverse(M)
    gravity_feedforward(P, seg, hold, tab, jmode, live, pre_R, pre_p, masses, coms, inertias, gravity, t)
    spheres, bounds, obs, _pairs, caps, _cw, _scratch = tables
    if control_due:
        control_update(
            P,
            seg,
            hold,
            tab,
            jmode,
            live,
            X,
            pre_R,
            pre_p,
            masses,
            coms,
            inertias,
            gravity,
            R_all,
            p_all,
            M,
            bias,
            R_last,
            tool_local,
            gains,
            q,
            qd,
            t,
            (round(t / h) + round(period / h)) * h,  # the next period's t, as the caller will pass it
            period,
            forces,
            (spheres, bounds, obs, caps),
            f_tool,
            integ,
            memo,
            i_ref,
        )
    return drive_step(
        P,
        seg,
        hold,
        tab,
        jmode,
        live,
        R_all,
        p_all,
        Minv,
        bias,
        X,
        Xbak,
        repeat,
        q,
        qd,
        t,
        h,
        nsub,
        tau_out,
        work,
        tables,
    )


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def gravity_feedforward(P, seg, hold, tab, jmode, live, pre_R, pre_p, masses, coms, inertias, gravity, t):
    """The cascade's gravity feed-forward for the step from t, into live[:, LV_GRAVITY]: the current
    whose motor torque holds the model's gravity torque at the set points (not at the measured pose: a
    model-based feed-forward, as a real controller computes it), weighted per joint by ctrl.ff_gravity.
    Nothing to compute (0 written) in zero gravity or when no joint is under the cascade."""
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
    references.ref_eval(seg, hold, tab, jmode, live, t, qr, qdr)
    gravity_torques(pre_R, pre_p, masses, coms, inertias, gravity, qr, g)
    for j in range(n):
        holding = g[j] / P[j, dr.P_N] * dr.resting_gear_factor(P[j, dr.P_ETA])
        live[j, references.LV_GRAVITY] = P[j, dr.P_FFG] * holding / P[j, dr.P_KT]
