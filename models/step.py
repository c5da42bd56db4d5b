"""One mechanics step's compiled work, in one call from Exudyn's PreStep: the chain's quantities at the
step start (joint frames, mass matrix and its inverse, bias forces) computed once and shared by the
operational-space controller, the contact pairs and the drives' in-step predictor.

One call, not one per part: every call into a kernel costs about a microsecond of argument checks,
and the controller and the drives each used to compute the same frames, mass matrix and bias again.
"""

from __future__ import annotations

from numba import njit

from .chain_dynamics import chain_state
from .chain_kinematics import spd_inverse
from .drive import drive_step
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
    i_ref are its own), then the drives over the step (drive.drive_step, whose status this returns:
    STEP_*)."""
    R_all, p_all, M, bias = chain_state(pre_R, pre_p, masses, coms, inertias, gravity, q, qd)
    Minv = spd_inverse(M)
    spheres, bounds, obs, _pairs, caps, _cw, _scratch = tables
    if control_due:
        control_update(
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
