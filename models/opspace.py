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

Hybrid force/motion control (`opspace_hybrid`) is the same law with a selection: along the axis n a
Cartesian node's `force` f pushes along, the position rows' motion law is replaced by a force law on
the contact force the tool feels (f_meas, what a force sensor at the tool reads: contact.py), and f
is fed forward:

    a_n = kf_force (f - f_meas) + ki_force int(f - f_meas) - kd_force (n . v)
    a   <- (I - n n^T) a + n a_n  (position rows),   F <- F + n f

The force integral runs only while the tool touches; the position integral leaves the axis out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
from numba import njit

from . import drive as dr
from . import references
from .chain_dynamics import chain_frames, chain_state, gravity_torques
from .chain_kinematics import (
    cholesky,
    cholesky_solve,
    rotation_vector,
    tool_jacobian,
    tool_jdot_qd,
    tool_pose_at,
)
from .contact import tool_force_at
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
    # Hybrid control along the force axis: on a surface of stiffness k the force error settles at
    # sqrt(kf_force k) rad/s (39 rad/s on the default 1e5 N/m), damped by kd_force; ki_force at 37 % of
    # its stability bound kd_force kf_force.
    "kf_force": (
        0.015,
        "m/(s^2*N)",
        "hybrid control: tool acceleration along the force axis per N of force error",
        0.0,
        10.0,
    ),
    "ki_force": (0.33, "m/(s^3*N)", "hybrid control: integral gain on the force error", 0.0, 100.0),
    "kd_force": (60.0, "1/s", "hybrid control: damping of the tool's speed along the force axis", 0.0, 1e3),
}
GAINS = tuple(GAIN_INFO)
G_KP, G_KD, G_KI, G_KPR, G_KDR, G_KIR, G_KPN, G_KDN, G_FRIC, G_DAMP, G_KF, G_KIF, G_KDF = range(len(GAINS))
#: The force input of one control period (`opspace_currents`): the axis the tool pushes along (unit,
#: world), the force wanted (N, 0: none) and the force measured along the axis (N).
F_AXIS, F_WANT, F_MEAS = 0, 3, 4
NFORCE = 5
#: Rows of a force profile (`Plan.forces`): from time t (s), push along (x, y, z) with f N.
FP_T, FP_AXIS, FP_F = 0, 1, 4
FRICTION_BAND = 0.5  # rad/s of motor speed over which the Coulomb feed-forward changes sign (tanh)


class ControllerArrays(NamedTuple):
    """What the controller reads and keeps from one period to the next (`OpspaceController.arrays`)."""

    R_last: np.ndarray  # (3, 3): the last joint frame's fixed rotation (the tool hangs on it)
    tool_local: np.ndarray  # (3,): the tool point in the last joint's frame
    gains: np.ndarray  # the gains, in the order of GAINS
    period: float  # s
    forces: np.ndarray  # the force profile (FP_* rows; none: motion control only)
    f_tool: np.ndarray  # (3,) out: the contact force on the tool (N, world), when there is a profile
    integ: np.ndarray  # (7,): the integral state (tool position and orientation errors, force error)
    memo: np.ndarray  # MEMO_*: the next period's reference pose, computed this period
    i_ref: np.ndarray  # (n,) out: the current set points (A)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _tool_velocity(pre_R, pre_p, R_last, tool_local, q, qd, R_all, p_all, p, R, J, v):
    """Tool pose (p, R) at q and its twist v = J(q) qd (linear, angular; world)."""
    chain_frames(pre_R, pre_p, q, R_all, p_all)
    _tool_twist_at(R_all, p_all, R_last, tool_local, qd, p, R, J, v)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _tool_twist_at(R_all, p_all, R_last, tool_local, qd, p, R, J, v):
    """Tool pose (p, R), Jacobian J and twist v = J qd from the joint frames."""
    tool_pose_at(R_all, p_all, R_last, tool_local, p, R)
    tool_jacobian(R_all, p_all, p, J)
    for a in range(6):
        s = 0.0
        for i in range(qd.shape[0]):
            s += J[a, i] * qd[i]
        v[a] = s


#: The controller's memo (`OpspaceController.memo`): whether it holds anything, then the joint set
#: points of the next period and their tool pose and twist, which that period needs again.
MEMO_SET, MEMO_Q = 0, 1


def memo_size(n: int) -> int:
    return MEMO_Q + 2 * n + 3 + 9 + 6


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _remember(memo, qr, qdr, p, R, v):
    n = qr.shape[0]
    memo[MEMO_SET] = 1.0
    k = MEMO_Q
    for j in range(n):
        memo[k + j] = qr[j]
        memo[k + n + j] = qdr[j]
    k += 2 * n
    for a in range(3):
        memo[k + a] = p[a]
        for b in range(3):
            memo[k + 3 + 3 * a + b] = R[a, b]
    for a in range(6):
        memo[k + 12 + a] = v[a]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _recall(memo, qr, qdr, p, R, v):
    """The remembered tool pose and twist when they are those of exactly these set points."""
    n = qr.shape[0]
    if memo[MEMO_SET] == 0.0:
        return False
    k = MEMO_Q
    for j in range(n):
        if memo[k + j] != qr[j] or memo[k + n + j] != qdr[j]:
            return False
    k += 2 * n
    for a in range(3):
        p[a] = memo[k + a]
        for b in range(3):
            R[a, b] = memo[k + 3 + 3 * a + b]
    for a in range(6):
        v[a] = memo[k + 12 + a]
    return True


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def opspace_currents(P, chain, R_all, p_all, M_chain, b, ctl, q, qd, refs, force):
    """The current set point of every joint (ctl.i_ref, A) for this control period; ctl.integ (7: the
    tool's position and orientation errors, the force error) is the controller's integral state,
    advanced here; ctl.memo (MEMO_*) carries the next period's reference pose over to it. Returns True
    when a set point saturated. `force` (F_*): the hybrid controller's force input; with
    force[F_WANT] = 0 the law is pure motion control. q, qd: what the load resolvers read; R_all,
    p_all, M_chain, b: the joint frames, the chain's mass matrix and its bias forces there; `chain`:
    mechanics.ChainArrays; `ctl`: ControllerArrays; refs: the set points (qr, qdr) now and at the
    next period's start (rows).

    With y the posture acceleration, the law of the module docstring is
    tau = J^T Lambda (a - Jdot qd - J y) + M y + b: one Cholesky factor of M, one of J M^-1 J^T."""
    n = q.shape[0]
    pre_R, pre_p = chain.pre_R, chain.pre_p
    R_last, tool_local, gains, period = ctl.R_last, ctl.tool_local, ctl.gains, ctl.period
    integ, memo, i_ref = ctl.integ, ctl.memo, ctl.i_ref
    qr, qdr, qr_next, qdr_next = refs[0], refs[1], refs[2], refs[3]
    # the period's small arrays, one allocation per shape (each costs about 80 ns, at every period)
    threes = np.empty((4, 3))
    p, pw, p_r, erot = threes[0], threes[1], threes[2], threes[3]
    mats = np.empty((3, 3, 3))
    R, Rw, R_r = mats[0], mats[1], mats[2]
    sixes = np.empty((7, 6))
    v, v_r2, v_r, jdqd, e, rhs, F = sixes[0], sixes[1], sixes[2], sixes[3], sixes[4], sixes[5], sixes[6]
    jacobians = np.empty((2, 6, n))
    J, Jw = jacobians[0], jacobians[1]
    ns = np.zeros((3, n))
    y, col, x = ns[0], ns[1], ns[2]
    squares = np.zeros((2, n, n))
    M, L = squares[0], squares[1]
    _tool_twist_at(R_all, p_all, R_last, tool_local, qd, p, R, J, v)
    # the reference: the tool pose and twist of the joint set points, now and one period on
    Rw_all = np.empty((n, 3, 3))
    pw_all = np.empty((n, 3))
    _tool_velocity(pre_R, pre_p, R_last, tool_local, qr_next, qdr_next, Rw_all, pw_all, pw, Rw, Jw, v_r2)
    if not _recall(memo, qr, qdr, p_r, R_r, v_r):  # the last period computed these, as a rule
        _tool_velocity(pre_R, pre_p, R_last, tool_local, qr, qdr, Rw_all, pw_all, p_r, R_r, Jw, v_r)
    _remember(memo, qr_next, qdr_next, pw, Rw, v_r2)
    tool_jdot_qd(R_all, p_all, p, qd, jdqd)
    # the posture task (null space of the tool task; none for n <= 6)
    if n > 6:
        for j in range(n):
            y[j] = gains[G_KPN] * (qr[j] - q[j]) + gains[G_KDN] * (qdr[j] - qd[j])
    # the task acceleration wanted, less Jdot qd and the posture's share J y
    for a in range(3):
        e[a] = p_r[a] - p[a]
    rotation_vector(R, R_r, erot)
    for a in range(3):
        e[3 + a] = erot[a]
    for a in range(6):
        rot = a >= 3
        kp = gains[G_KPR] if rot else gains[G_KP]
        kd = gains[G_KDR] if rot else gains[G_KD]
        ki = gains[G_KIR] if rot else gains[G_KI]
        xdd_r = (v_r2[a] - v_r[a]) / period
        rhs[a] = xdd_r + kp * e[a] + kd * (v_r[a] - v[a]) + ki * integ[a]
    # hybrid: along the force axis the force law replaces the motion law (selection S = n n^T)
    f_want = force[F_WANT]
    f_err = f_want - force[F_MEAS]
    nx, ny, nz = force[F_AXIS], force[F_AXIS + 1], force[F_AXIS + 2]
    if f_want > 0.0:
        along = nx * rhs[0] + ny * rhs[1] + nz * rhs[2]
        v_n = nx * v[0] + ny * v[1] + nz * v[2]
        a_n = gains[G_KF] * f_err + gains[G_KIF] * integ[6] - gains[G_KDF] * v_n
        rhs[0] += nx * (a_n - along)
        rhs[1] += ny * (a_n - along)
        rhs[2] += nz * (a_n - along)
        e_n = nx * e[0] + ny * e[1] + nz * e[2]  # no position error along the axis: no integral of it
        e[0] -= nx * e_n
        e[1] -= ny * e_n
        e[2] -= nz * e_n
    for a in range(6):
        rhs[a] -= jdqd[a]
        for j in range(n):
            rhs[a] -= J[a, j] * y[j]
    # the controller's model: the chain's mass matrix and the reflected rotor and gear inertia
    M[:, :] = M_chain
    for j in range(n):
        nj = P[j, dr.P_N]
        M[j, j] += nj * nj * (P[j, dr.P_JR] + P[j, dr.P_JG])
    cholesky(M, 0.0, L)
    X = np.empty((n, 6))  # M^-1 J^T
    for a in range(6):
        for j in range(n):
            col[j] = J[a, j]
        cholesky_solve(L, col, x)
        for j in range(n):
            X[j, a] = x[j]
    sixbysix = np.zeros((2, 6, 6))
    A, L6 = sixbysix[0], sixbysix[1]  # J M^-1 J^T and its factor
    for a in range(6):
        for c in range(a, 6):
            s = 0.0
            for j in range(n):
                s += J[a, j] * X[j, c]
            A[a, c] = s
            A[c, a] = s
    cholesky(A, gains[G_DAMP], L6)
    cholesky_solve(L6, rhs, F)
    if f_want > 0.0:  # the force wanted, fed forward
        F[0] += nx * f_want
        F[1] += ny * f_want
        F[2] += nz * f_want
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
        if f_want > 0.0 and force[F_MEAS] > 0.0:  # the force integral runs in contact only
            integ[6] += f_err * period
    return saturated


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def control_update(P, X, sp, chain, gravity, state, ctl, tables, q, qd, t, t_next):
    """One control period from t: the set points `sp` (references.SetPointArrays) now and at the next
    period's start t_next (on the step grid: its t then, to the bit), the current set points into
    ctl.i_ref and live[:, LV_IREF] (held until the next period). True when one saturated.
    `state` = (R_all, p_all, M, bias): the chain's (mechanics.ChainArrays) joint frames, mass matrix
    and bias forces at the true q, qd (chain_state); the controller sees them through its load
    resolvers. `ctl`: ControllerArrays. With a force profile (ctl.forces, rows FP_*; none: motion
    control), ctl.f_tool gets the contact force on the tool now (N, world: what a force sensor at the
    tool reads) from `tables` (contact.ContactTables)."""
    n = q.shape[0]
    R_all, p_all, M, bias = state
    forces, f_tool = ctl.forces, ctl.f_tool
    if forces.shape[0]:
        tool_force_at(tables.spheres, tables.bounds, tables.obs, tables.caps, R_all, p_all, qd, f_tool)
    force = np.zeros(NFORCE)
    for k in range(forces.shape[0]):  # the profile's row in force at t (a few rows: one per node)
        if forces[k, FP_T] <= t + 1e-12:
            for a in range(3):
                force[F_AXIS + a] = forces[k, FP_AXIS + a]
            force[F_WANT] = forces[k, FP_F]
    # the force the tool pushes with along the axis: the contact force on it, turned round
    force[F_MEAS] = -(
        force[F_AXIS] * f_tool[0] + force[F_AXIS + 1] * f_tool[1] + force[F_AXIS + 2] * f_tool[2]
    )
    refs = np.empty((4, n))
    qr, qdr, qr2, qdr2 = refs[0], refs[1], refs[2], refs[3]
    references.ref_eval(sp, t, qr, qdr)
    references.ref_eval(sp, t_next, qr2, qdr2)
    # what the load resolvers read; with an error the chain's quantities are those of that reading
    q_m = q
    qd_m = qd
    Rm_all = R_all
    pm_all = p_all
    M_m = M
    b_m = bias
    for j in range(n):
        if P[j, dr.P_EL] != 0.0:
            q_m = np.empty(n)
            qd_m = np.empty(n)
            for i in range(n):
                q_m[i], qd_m[i] = dr.load_resolver(P, i, q[i], qd[i])
            Rm_all, pm_all, M_m, b_m = chain_state(chain, gravity, q_m, qd_m)
            break
    # the law compensates gravity through b, each joint's share by its ctrl.ff_gravity
    for j in range(n):
        if P[j, dr.P_FFG] != 1.0 and (gravity[0] != 0.0 or gravity[1] != 0.0 or gravity[2] != 0.0):
            g = np.empty(n)
            gravity_torques(chain, gravity, q_m, g)
            b_m = b_m.copy()
            for i in range(n):
                b_m[i] -= (1.0 - P[i, dr.P_FFG]) * g[i]
            break
    saturated = opspace_currents(P, chain, Rm_all, pm_all, M_m, b_m, ctl, q_m, qd_m, refs, force)
    twist_damping(P, X, qd_m, ctl.i_ref)
    for j in range(n):
        sp.live[j, references.LV_IREF] = ctl.i_ref[j]
    return saturated


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def twist_damping(P, X, qd_m, i_ref):
    """Each joint's current set point less d (w_m' - n qd'), the gear's twist rate its two resolvers
    read, with d = 2 zeta sqrt(k / n^2 (J_rotor + J_gear)) at zeta = ctrl.twist_damping: the law acts
    on the link side and does not see the motor ringing on its elastic gear (about 31 Hz on the
    Spider's large drives with the link held, as in contact), and the field-oriented current loop
    cancels the damping the back-EMF would give it; the hybrid force loop rang at that mode without."""
    for j in range(qd_m.shape[0]):
        zeta = P[j, dr.P_TWD]
        if zeta == 0.0:
            continue
        nj = P[j, dr.P_N]
        om_meas = dr.motor_resolver(P, j, X[j, dr.S_TH], X[j, dr.S_OM])[1]
        d = 2.0 * zeta * math.sqrt(P[j, dr.P_K] / (nj * nj) * (P[j, dr.P_JR] + P[j, dr.P_JG]))
        i_ref[j] -= d * (om_meas - nj * qd_m[j]) / P[j, dr.P_KT]


class OpspaceController:
    """The controller of one run: its gains, its integral state and the period it is updated at."""

    def __init__(
        self, values: Mapping[str, float], n: int, steps: int, step: float, forces: np.ndarray
    ) -> None:
        self.gains = np.array([float(values[f"control.{g}"]) for g in GAINS])
        self.forces = forces  # the force profile (FP_* rows; none: motion control only)
        self.steps = steps  # solver steps per control period
        self.period = steps * step
        self.integ = np.zeros(7)
        self.memo = np.zeros(memo_size(n))
        self.i_ref = np.zeros(n)

    def arrays(self, R_last: np.ndarray, tool_local: np.ndarray, f_tool: np.ndarray) -> ControllerArrays:
        """What the step kernel hands `control_update`, with the tool's geometry (R_last, tool_local) and
        the array the tool's measured contact force goes to."""
        return ControllerArrays(
            R_last,
            tool_local,
            self.gains,
            self.period,
            self.forces,
            f_tool,
            self.integ,
            self.memo,
            self.i_ref,
        )

    def forget(self) -> None:
        """Drop the remembered reference pose: the chain it was computed on changed."""
        self.memo[MEMO_SET] = 0.0

    @classmethod
    def idle(cls, n: int) -> OpspaceController:
        """The arrays the step kernel is handed under joint-independent control (it never runs)."""
        return cls({f"control.{g}": 0.0 for g in GAINS}, n, 1, 0.0, np.zeros((0, 5)))
