"""The drives of all joints integrated over one mechanics step, inside one Exudyn PreStep call.

Classical RK4 over `nsub` substeps (more when the LuGre bristle state stiffens with speed) while the
load angles follow a local predictor (q_l'' = M(q)^-1 (tau_gear + tau_contact - bias), with M the chain
mass matrix and the bias at the start of the step, the contact forces of contact.py at every
substep); the mean gear and contact torque over the step is handed to Exudyn as the joint torque
vector. See docs/MODELS.md, "Coupling".
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .contact import (
    MAX_SUBSTEP_FACTOR,
    contact_substeps,
    find_pairs,
    pair_torques,
    set_caps,
)
from .drive import NL, NO, NS, P_FC, P_FS, P_S0, P_VS, S_IMP, S_OM, S_QDL, S_QL, S_Z, drive_rhs
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .jit import NO_REFCOUNTS as _NO_REFCOUNTS
from .references import LV_EXTERNAL

# ---- substeps: the LuGre bristle state stiffens with speed ------------------------------------------
FRICTION_RATE_STEP = 2.0  # its relaxation rate x substep: RK4 is stable to 2.8, damped 3x per substep here
SPEED_MARGIN = 1.25  # the motor speed may grow within a step: size the substeps for this much more
FRICTION_BOUND_MARGIN = 1.05
STEP_OK, STEP_NOT_FINITE, STEP_FRICTION = 0, 1, 2
RK4_AT = (0.0, 0.5, 0.5, 1.0)  # the stages' times within a substep, in substeps
RK4_WEIGHT = (1.0, 2.0, 2.0, 1.0)


class DriveArrays(NamedTuple):
    """The drives as a step reads and writes them (simulation.Simulation owns the arrays)."""

    P: np.ndarray  # (n, NP): the parameters (drive.P_*)
    X: np.ndarray  # (n, NS + ...): the states (drive.S_*), advanced in place
    Xbak: np.ndarray  # X before the step, restored when the solver takes the same step again
    tau: np.ndarray  # (n,): out, the step's mean gear + contact torque (Exudyn's joint torques)
    work: np.ndarray  # (5, n, NL): scratch, the RK4 stages' derivatives and the stage state


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def contact_stage(contact, X, cw, cimp, weight):
    """The contacts' joint torques J^T F at the stage X into cw[2], and weight x them added to cimp
    (the step's contact impulse). `contact` = (spheres, obstacles, pairs of the step, count, q at the
    step start, a 4 x 3 scratch) of contact.py; cw: work rows (q, qd, torque)."""
    spheres, obs, pairs, npairs, q0, scratch = contact
    n = X.shape[0]
    for j in range(n):
        cw[0, j] = X[j, S_QL]
        cw[1, j] = X[j, S_QDL]
    pair_torques(pairs, npairs, spheres, obs, q0, cw[0], cw[1], cw[2], scratch)
    for j in range(n):
        cimp[j] += weight * cw[2, j]


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def friction_rate(P, j, om):
    """1/s at which joint j's LuGre bristle state relaxes at motor speed om: s0 |om| / g(om). It grows
    with speed (about 100 |om| with s0 = fc / 0.01), and RK4 is stable only while rate x substep < 2.8."""
    fc = P[j, P_FC]
    fs = P[j, P_FS]
    if P[j, P_S0] <= 0.0 or (fc <= 0.0 and fs <= 0.0):
        return 0.0
    g = fc + (fs - fc) * math.exp(-((om / P[j, P_VS]) ** 2))
    return P[j, P_S0] * abs(om) / max(g, 1e-300)


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def friction_bound(P, j):
    """LuGre keeps |z| <= max(fc, fs) / s0 exactly; a state past it (with a margin) means the
    integration broke down. math.inf for a joint without bristles."""
    if P[j, P_S0] <= 0.0 or (P[j, P_FC] <= 0.0 and P[j, P_FS] <= 0.0):
        return math.inf
    return FRICTION_BOUND_MARGIN * max(P[j, P_FC], P[j, P_FS]) / P[j, P_S0]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def substeps_for(P, X, h, nsub):
    """RK4 substeps over a step of h: at least nsub, more while a joint's friction state relaxes fast
    (rate x substep <= FRICTION_RATE_STEP, at the speed now plus a margin for the step's change)."""
    rate = 0.0
    for j in range(X.shape[0]):
        rate = max(rate, friction_rate(P, j, SPEED_MARGIN * X[j, S_OM]))
    return max(nsub, min(int(math.ceil(rate * h / FRICTION_RATE_STEP)), nsub * MAX_SUBSTEP_FACTOR))


# Compiled without numba's reference counting (jit.NO_REFCOUNTS, and the kernels it calls with it): every
# array view and every array handed to an inlined helper cost an atomic increment and decrement, and in
# this loop (20 right-hand sides of 7 joints a step) they were 37 % of a real-time run's CPU (perf).
# numba then refuses to make an array here: the scratch comes from drive_step.
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST, **_NO_REFCOUNTS)
def rk4_substeps(
    P,
    sp,
    Minv,
    bias,
    X,
    work,
    contact,
    npairs,
    cw,
    cimp,
    sig,
    rows,
    refs,
    t,
    hs,
    nsub,
):
    """drive_step's nsub RK4 substeps of hs from t, X advanced in place: STEP_OK, or STEP_FRICTION.
    `work`: the 4 stages' derivatives and the stage state; `cw`, `cimp`: contact_stage's; `sig`: the
    joint signals; `rows`: the set points and gear torques (qr, qdr, tau) of drive_rhs; `refs`: some
    joint reads the set points; `sp`: references.SetPointArrays."""
    n = X.shape[0]
    Xt = work[4]
    tc, qr, qdr, tau = cw[2], rows[0], rows[1], rows[2]
    w = hs / 6.0
    for s in range(nsub):
        ts = t + s * hs
        for stage in range(4):  # classical RK4: stage k at X + RK4_AT[k] hs k_(k-1), into work[k]
            Xs = X
            if stage > 0:
                for j in range(n):
                    for k in range(NL):
                        Xt[j, k] = X[j, k] + RK4_AT[stage] * hs * work[stage - 1, j, k]
                Xs = Xt
            if npairs > 0:
                contact_stage(contact, Xs, cw, cimp, RK4_WEIGHT[stage] * w)
            ref_due = refs and stage != 2  # stage 2 has stage 1's time
            drive_rhs(
                P,
                sp,
                Minv,
                bias,
                tc,
                ts + RK4_AT[stage] * hs,
                Xs,
                work[stage],
                sig,
                qr,
                qdr,
                tau,
                ref_due,
            )
        k1, k2, k3, k4 = work[0], work[1], work[2], work[3]
        for j in range(n):
            for k in range(NL):
                X[j, k] += hs / 6.0 * (k1[j, k] + 2.0 * k2[j, k] + 2.0 * k3[j, k] + k4[j, k])
            if abs(X[j, S_Z]) > friction_bound(P, j):  # caught before it overflows
                return STEP_FRICTION
    return STEP_OK


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def drive_step(drives, sp, R_all, p_all, Minv, bias, tables, repeat, q, qd, t, h, nsub):
    """Integrate all drives (DriveArrays) over [t, t+h] with RK4 substeps (nsub, more where friction or
    a contact is stiff) following the set points `sp` (references.SetPointArrays); drives.tau = mean
    gear + contact torque. STEP_OK, or STEP_NOT_FINITE / STEP_FRICTION when the states broke down.
    R_all, p_all, Minv, bias: the chain's joint frames, inverse mass matrix and bias forces at the step
    start (step.py computes them once for every kernel of the step); `tables`: contact.ContactTables.
    The drive state is kept for a repeated step: `repeat` (the solver takes the same step again)
    restores X from Xbak, else Xbak saves X before the step."""
    P, X, Xbak, tau_out, work = drives
    if repeat:
        X[:, :] = Xbak
    else:
        Xbak[:, :] = X
    n = q.shape[0]
    spheres, bounds, obs, pairs, caps, cw, scratch = tables
    npairs, rate = find_pairs(spheres, bounds, obs, R_all, p_all, qd, Minv, h, pairs, scratch)
    nsub = max(substeps_for(P, X, h, nsub), contact_substeps(rate, h, nsub))
    hs = h / nsub
    set_caps(pairs, npairs, hs, caps)
    contact = (spheres, obs, pairs, npairs, q, scratch)
    tc = cw[2]  # the contacts' torques at the stage (none without pairs)
    cimp = cw[3]
    for j in range(n):
        tc[j] = 0.0
        cimp[j] = 0.0
    # The load side within the step: M qdd = tau_gear - bias, the bias (velocity terms, gravity) held
    # at the step start; without it the gear torques lag the chain's other forces by up to 8 %.
    for j in range(n):
        X[j, S_QL] = q[j]
        X[j, S_QDL] = qd[j]
        X[j, S_IMP] = 0.0
    sig = np.empty(NO + 10)
    rows = np.zeros((3, n))
    # Joints all under an external controller read no set point: the reference is not evaluated.
    # (np.bool_: a literal False would have numba compile rk4_substeps once more, for that literal.)
    refs = np.bool_(False)
    for j in range(n):
        if sp.live[j, LV_EXTERNAL] <= 0.5:
            refs = True
    status = rk4_substeps(P, sp, Minv, bias, X, work, contact, npairs, cw, cimp, sig, rows, refs, t, hs, nsub)
    if status != STEP_OK:
        return status
    for j in range(n):
        tau_out[j] = (X[j, S_IMP] + cimp[j]) / h
        for k in range(NS):
            if not math.isfinite(X[j, k]):
                return STEP_NOT_FINITE
        if not math.isfinite(tau_out[j]):
            return STEP_NOT_FINITE
    return STEP_OK
