"""Operational-space motion control (paper §5): task-space inverse dynamics at the tool, compiled.

A digital controller: every control period it reads the load resolvers (angle and speed of every
joint), computes the current set point of every joint's current loop and holds it until the next
period (zero-order hold); the drives' current loops, motors, friction, backlash and elastic gears act
on it as they do on the joint-independent cascade's output. docs/MODELS.md, "Control systems".

The law, with the controller's model of the arm (the chain's mass matrix plus each rotor and gear
input reflected through its reducer, n^2 (J_rotor + J_gear), on the diagonal):

    a     = xdd_r + Kp e + Kd (xd_r - J qd) + Ki int(e)     the task acceleration wanted (6-D)
    F     = Lambda (a - Jdot qd),  Lambda = (J M^-1 J^T + d I)^-1
    tau   = J^T F + (I - J^T Jbar^T) M (kp_null (q_r - q) + kd_null (qd_r - qd)) + b(q, qd)
    i_ref = (tau / n + c_f (fc tanh(n qd_r / 0.5 rad/s) + sigma2 n qd_r)) / kt

e is the tool's position error and the rotation vector from its orientation to the reference's; the
reference pose is the tool pose of the command's joint set points (so a straight-line move is tracked
as the straight line the planner sampled, and a joint move as the curve its joints draw); xdd_r is
the difference of the reference velocity over one period. Jbar = M^-1 J^T Lambda is the dynamically
consistent inverse: the posture task (the planner's joint set points) acts only in the null space of
the tool task, which holds the Spider's seventh degree of freedom. b are the velocity terms and gravity.
The last term feeds the drives' nominal Coulomb and viscous friction forward along the set-point speed
(c_f = control.friction_comp): through reducers of 100-160 the friction is the largest torque the
tool task would otherwise leave to its integral. The integral runs only while no current set point is
saturated (anti-windup).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numba import njit

from . import drive as dr
from .chain_dynamics import bias_forces_at, mass_matrix_at
from .chain_kinematics import cholesky, cholesky_solve, rotation_vector, tool_frames, tool_jacobian
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST

#: The gains, parameters `control.<name>`: (default, unit, what it does, min, max), in the order of the
#: kernel's gain vector. The defaults place the tool's error dynamics at 30 rad/s, critically damped,
#: with an integral gain at 37 % of its stability bound kd * kp (the integral wears off the stiction
#: and detent torques the friction feed-forward leaves).
GAIN_INFO = {
    "kp_pos": (
        900.0,
        "1/s^2",
        "operational-space control: tool position stiffness (acceleration per m)",
        0.0,
        1e5,
    ),
    "kd_pos": (60.0, "1/s", "operational-space control: tool position damping", 0.0, 1e3),
    "ki_pos": (20000.0, "1/s^3", "operational-space control: tool position integral gain", 0.0, 1e6),
    "kp_rot": (900.0, "1/s^2", "operational-space control: tool orientation stiffness (per rad)", 0.0, 1e5),
    "kd_rot": (60.0, "1/s", "operational-space control: tool orientation damping", 0.0, 1e3),
    "ki_rot": (20000.0, "1/s^3", "operational-space control: tool orientation integral gain", 0.0, 1e6),
    "kp_null": (
        100.0,
        "1/s^2",
        "operational-space control: posture stiffness in the null space (n > 6)",
        0.0,
        1e5,
    ),
    "kd_null": (20.0, "1/s", "operational-space control: posture damping in the null space", 0.0, 1e3),
    "friction_comp": (
        1.0,
        "-",
        "operational-space control: share of the drives' nominal Coulomb and viscous friction fed forward "
        "along the set-point speed",
        0.0,
        1.5,
    ),
    "damping": (
        1e-4,
        "-",
        "operational-space control: added to J M^-1 J^T before it is inverted (near singular poses)",
        0.0,
        1.0,
    ),
}
GAINS = tuple(GAIN_INFO)
G_KP, G_KD, G_KI, G_KPR, G_KDR, G_KIR, G_KPN, G_KDN, G_FRIC, G_DAMP = range(len(GAINS))
JDOT_STEP = 1e-6  # s: Jdot qd as (J(q + h qd) - J(q)) qd / h
FRICTION_BAND = 0.5  # rad/s of motor speed over which the Coulomb feed-forward changes sign (tanh)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _tool_velocity(pre_R, pre_p, R_last, tool_local, q, qd, R_all, p_all, p, R, J, v):
    """Tool pose (p, R) at q and its twist v = J(q) qd (linear, angular; world)."""
    tool_frames(pre_R, pre_p, R_last, tool_local, q, R_all, p_all, p, R)
    tool_jacobian(R_all, p_all, p, J)
    n = q.shape[0]
    for a in range(6):
        s = 0.0
        for i in range(n):
            s += J[a, i] * qd[i]
        v[a] = s


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def opspace_currents(
    P,
    pre_R,
    pre_p,
    masses,
    coms,
    inertias,
    gravity,
    R_last,
    tool_local,
    gains,
    q_true,
    qd_true,
    qr,
    qdr,
    qr_next,
    qdr_next,
    period,
    integ,
    i_ref,
):
    """The current set point of every joint (i_ref, A) for this control period; integ (6) is the
    controller's integral state, advanced here. Returns True when a set point saturated.

    With y the posture acceleration, the law of the module docstring is
    tau = J^T Lambda (a - Jdot qd - J y) + M y + b: one Cholesky factor of M, one of J M^-1 J^T."""
    n = q_true.shape[0]
    q = np.empty(n)
    qd = np.empty(n)
    for j in range(n):
        q[j], qd[j] = dr.load_resolver(P, j, q_true[j], qd_true[j])  # what the controller reads
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    p = np.empty(3)
    R = np.empty((3, 3))
    J = np.empty((6, n))
    v = np.empty(6)
    _tool_velocity(pre_R, pre_p, R_last, tool_local, q, qd, R_all, p_all, p, R, J, v)
    # the reference: the tool pose and twist of the joint set points, now and one period on
    Rw_all = np.empty((n, 3, 3))
    pw_all = np.empty((n, 3))
    pw = np.empty(3)
    Rw = np.empty((3, 3))
    Jw = np.empty((6, n))
    v_r2 = np.empty(6)
    _tool_velocity(pre_R, pre_p, R_last, tool_local, qr_next, qdr_next, Rw_all, pw_all, pw, Rw, Jw, v_r2)
    p_r = np.empty(3)
    R_r = np.empty((3, 3))
    v_r = np.empty(6)
    _tool_velocity(pre_R, pre_p, R_last, tool_local, qr, qdr, Rw_all, pw_all, p_r, R_r, Jw, v_r)
    # Jdot qd, from the twist one small step along qd
    qh = np.empty(n)
    for j in range(n):
        qh[j] = q[j] + JDOT_STEP * qd[j]
    vh = np.empty(6)
    _tool_velocity(pre_R, pre_p, R_last, tool_local, qh, qd, Rw_all, pw_all, pw, Rw, Jw, vh)
    # the posture task (null space of the tool task; none for n <= 6)
    y = np.zeros(n)
    if n > 6:
        for j in range(n):
            y[j] = gains[G_KPN] * (qr[j] - q[j]) + gains[G_KDN] * (qdr[j] - qd[j])
    # the task acceleration wanted, less Jdot qd and the posture's share J y
    e = np.empty(6)
    for a in range(3):
        e[a] = p_r[a] - p[a]
    erot = np.empty(3)
    rotation_vector(R, R_r, erot)
    for a in range(3):
        e[3 + a] = erot[a]
    rhs = np.empty(6)
    for a in range(6):
        rot = a >= 3
        kp = gains[G_KPR] if rot else gains[G_KP]
        kd = gains[G_KDR] if rot else gains[G_KD]
        ki = gains[G_KIR] if rot else gains[G_KI]
        xdd_r = (v_r2[a] - v_r[a]) / period
        jdqd = (vh[a] - v[a]) / JDOT_STEP
        r = xdd_r + kp * e[a] + kd * (v_r[a] - v[a]) + ki * integ[a] - jdqd
        for j in range(n):
            r -= J[a, j] * y[j]
        rhs[a] = r
    # the controller's model: the chain's mass matrix and the reflected rotor and gear inertia
    M = np.empty((n, n))
    mass_matrix_at(R_all, p_all, masses, coms, inertias, M)
    for j in range(n):
        nj = P[j, dr.P_N]
        M[j, j] += nj * nj * (P[j, dr.P_JR] + P[j, dr.P_JG])
    L = np.zeros((n, n))
    cholesky(M, 0.0, L)
    X = np.empty((n, 6))  # M^-1 J^T
    col = np.empty(n)
    x = np.empty(n)
    for a in range(6):
        for j in range(n):
            col[j] = J[a, j]
        cholesky_solve(L, col, x)
        for j in range(n):
            X[j, a] = x[j]
    A = np.empty((6, 6))  # J M^-1 J^T
    for a in range(6):
        for c in range(a, 6):
            s = 0.0
            for j in range(n):
                s += J[a, j] * X[j, c]
            A[a, c] = s
            A[c, a] = s
    L6 = np.zeros((6, 6))
    cholesky(A, gains[G_DAMP], L6)
    F = np.empty(6)
    cholesky_solve(L6, rhs, F)
    b = np.empty(n)
    bias_forces_at(R_all, p_all, masses, coms, inertias, gravity, qd, b)
    saturated = False
    for j in range(n):
        tau = b[j]
        for a in range(6):
            tau += J[a, j] * F[a]
        for k in range(n):
            tau += M[j, k] * y[k]
        nj = P[j, dr.P_N]
        om_r = nj * qdr[j]  # the motor speed the set point asks for: friction fed forward along it
        tau_f = P[j, dr.P_FC] * math.tanh(om_r / FRICTION_BAND) + P[j, dr.P_S2] * om_r
        i = (tau / nj + gains[G_FRIC] * tau_f) / P[j, dr.P_KT]
        lim = P[j, dr.P_IMAX]
        if i > lim or i < -lim:
            saturated = True
        i_ref[j] = i
    if not saturated:
        for a in range(6):
            integ[a] += e[a] * period
    return saturated


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def control_update(
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
    R_last,
    tool_local,
    gains,
    q,
    qd,
    t,
    period,
    integ,
    i_ref,
):
    """One control period from t: the set points now and one period on (drive.ref_eval), the current
    set points into i_ref and live[:, LV_IREF] (held until the next period). True when one saturated."""
    n = q.shape[0]
    qr = np.empty(n)
    qdr = np.empty(n)
    qr2 = np.empty(n)
    qdr2 = np.empty(n)
    dr.ref_eval(seg, hold, tab, jmode, live, t, qr, qdr)
    dr.ref_eval(seg, hold, tab, jmode, live, t + period, qr2, qdr2)
    saturated = opspace_currents(
        P,
        pre_R,
        pre_p,
        masses,
        coms,
        inertias,
        gravity,
        R_last,
        tool_local,
        gains,
        q,
        qd,
        qr,
        qdr,
        qr2,
        qdr2,
        period,
        integ,
        i_ref,
    )
    for j in range(n):
        live[j, dr.LV_IREF] = i_ref[j]
    return saturated


class OpspaceController:
    """The controller of one run: its gains, its integral state and the period it is updated at."""

    def __init__(self, values: Mapping[str, float], n: int, steps: int, step: float) -> None:
        self.gains = np.array([float(values[f"control.{g}"]) for g in GAINS])
        self.steps = steps  # solver steps per control period
        self.period = steps * step
        self.integ = np.zeros(6)
        self.i_ref = np.zeros(n)
