"""The joint solutions along a straight tool line (`ArmKinematics.walk_line` calls `line_kernel`).

A line is walked in steps of the line parameter (`line_kernel`): each knot solved by ik_solver.py's kernel
from the previous knot moved along its rates dq/ds = J+ twist (the smallest joint motion, the limit of
"nearest the previous solution" as the steps shrink), its step halved until the cubic Hermite curve
through the two knots and their rates is on the line at its middle and the joint step agrees with the
rates, and doubled again when it is well within. The knots' spacing so follows the line's geometry
(curvature of the joint path, singular regions), never its speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .chain_kinematics import (
    cholesky,
    cholesky_solve,
    gram_of_free,
    rotation_vector,
    rotvec_exp,
    tool_frames,
    tool_jacobian,
)
from .ik_solver import solve_kernel
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST

# ---- straight lines: the joint solutions along a tool line (ArmKinematics.walk_line) ----------------------
# status of a walk
LINE_OK, LINE_UNREACHED, LINE_SINGULAR, LINE_JUMP, LINE_KNOTS = range(5)
LINE_ITER = 50  # solver iterations per knot (its start: the previous knot moved along its rates)
LINE_IK_TOL = 1e-10  # m, rad: what each knot is solved to
#: A knot's joint step may differ from the trapezoid rule of the rates by this share of it (a jump to
#: another branch does not shrink with the step; a kink, where a joint reaches its limit and stops while
#: the others take over, does: there the share is 1).
JUMP_REL = 0.05
RATE_DAMPING = 1e-12  # of J J^T when the rates are solved (below any posture a line may pass)
LIMIT_EPS = 1e-12  # rad: a joint this close to its limit is at it


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _line_pose(p0, dp, R0, rot, s, p, R, r):
    """The pose at parameter s of the line: p0 + s dp, exp(s rot) R0 (r: scratch)."""
    for a in range(3):
        p[a] = p0[a] + s * dp[a]
        r[a] = s * rot[a]
    rotvec_exp(r, R0, R)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _off_pose(pre_R, pre_p, R_last, tool_local, q, p_t, R_t, R_all, p_all, p, R, erot):
    """(m, rad): how far the tool at q is from the pose (p_t, R_t)."""
    tool_frames(pre_R, pre_p, R_last, tool_local, q, R_all, p_all, p, R)
    d0, d1, d2 = p[0] - p_t[0], p[1] - p_t[1], p[2] - p_t[2]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), rotation_vector(R, R_t, erot)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _min_eigenvalue(H):
    """The smallest eigenvalue of a small symmetric matrix (cyclic Jacobi rotations, H overwritten):
    no LAPACK call, whose thread pool would only contend with the process's other work."""
    m = H.shape[0]
    for _ in range(60):
        off = 0.0
        scale = 0.0
        for a in range(m):
            scale += H[a, a] * H[a, a]
            for b in range(a + 1, m):
                off += H[a, b] * H[a, b]
        if off <= 1e-32 * scale or off == 0.0:
            break
        for a in range(m - 1):
            for b in range(a + 1, m):
                h = H[a, b]
                if h == 0.0:
                    continue
                theta = (H[b, b] - H[a, a]) / (2.0 * h)
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(m):
                    x, z = H[k, a], H[k, b]
                    H[k, a] = c * x - s * z
                    H[k, b] = s * x + c * z
                for k in range(m):
                    x, z = H[a, k], H[b, k]
                    H[a, k] = c * x - s * z
                    H[b, k] = s * x + c * z
    low = H[0, 0]
    for a in range(1, m):
        low = min(low, H[a, a])
    return low


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _line_rates(R_all, p_all, p, lower, upper, q, twist, J, G, L, y, free, rate):
    """rate = dq/ds that moves the tool by `twist` (linear, angular) per unit s: J+ twist, the smallest
    joint motion (the limit of "the solution nearest the previous one" as the steps shrink); a joint at
    a limit that it would push past is held. Returns the smallest singular value of J (frames at q)."""
    n = q.shape[0]
    tool_jacobian(R_all, p_all, p, J)
    m = 6 if n >= 6 else n
    H = np.empty((m, m))
    for a in range(m):
        for b in range(a + 1):
            s = 0.0
            if n >= 6:
                for j in range(n):
                    s += J[a, j] * J[b, j]
            else:
                for i in range(6):
                    s += J[i, a] * J[i, b]
            H[a, b] = s
            H[b, a] = s
    sigma = math.sqrt(max(_min_eigenvalue(H), 0.0))
    for j in range(n):
        free[j] = True
    for _ in range(n + 1):
        gram_of_free(J, free, G)
        cholesky(G, RATE_DAMPING, L)
        cholesky_solve(L, twist, y)
        changed = False
        for j in range(n):
            s = 0.0
            if free[j]:
                for a in range(6):
                    s += J[a, j] * y[a]
            rate[j] = s
            if free[j] and (
                (q[j] <= lower[j] + LIMIT_EPS and s < 0.0) or (q[j] >= upper[j] - LIMIT_EPS and s > 0.0)
            ):
                free[j] = False
                changed = True
        if not changed:
            break
    return sigma


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def line_kernel(
    pre_R,
    pre_p,
    R_last,
    tool_local,
    lower,
    upper,
    p0,
    dp,
    R0,
    rot,
    q_start,
    w_pos,
    h_max,
    h_min,
    tol_pos,
    tol_rot,
    sigma_min,
    S,
    Q,
    D,
    C,
    q_at,
    info,
):
    """Walk the line p0 + s dp, exp(s rot) R0 for s from 0 to 1 from q_start (its pose at s = 0): knots
    S, joint positions Q, rates D = dq/ds, and C[k] the (m, rad) pose error of the joint-space chord
    of segment k at its middle; returns the number of knots.

    A step of h (at most h_max) is solved from the previous knot moved along its rates, toward the
    solution nearest the previous knot, and kept when the cubic Hermite curve through both knots and
    their rates is on the line at the middle within (tol_pos, tol_rot) and the joint step agrees with
    the rates (no jump to another branch); otherwise it is halved. A step that fails at h_min, a
    knot below sigma_min, or more knots than S holds end the walk: info = [status (LINE_*), s where
    it ended, position and rotation error there, smallest singular value there, IK solves];
    q_at: the posture there (the last knot, or the one that failed)."""
    n = q_start.shape[0]
    kmax = S.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    p = np.empty(3)
    R = np.empty((3, 3))
    pt = np.empty(3)
    Rt = np.empty((3, 3))
    r = np.empty(3)
    erot = np.empty(3)
    J = np.empty((6, n))
    G = np.empty((6, 6))
    L = np.zeros((6, 6))
    y = np.empty(6)
    free = np.empty(n, dtype=np.bool_)
    twist = np.empty(6)
    for a in range(3):
        twist[a] = dp[a]
        twist[3 + a] = rot[a]
    turn = np.zeros(n)
    q = q_start.copy()
    m0 = np.empty(n)
    q1 = np.empty(n)
    m1 = np.empty(n)
    seed = np.empty(n)
    qm = np.empty(n)
    sinfo = np.zeros(4)
    tool_frames(pre_R, pre_p, R_last, tool_local, q, R_all, p_all, p, R)
    sig = _line_rates(R_all, p_all, p, lower, upper, q, twist, J, G, L, y, free, m0)
    S[0] = 0.0
    for j in range(n):
        Q[0, j] = q[j]
        D[0, j] = m0[j]
        q_at[j] = q[j]
    for i in range(info.shape[0]):
        info[i] = 0.0
    info[4] = sig
    if sig < sigma_min:
        info[0] = LINE_SINGULAR
        return 1
    status = LINE_OK
    k = 0
    s = 0.0
    h = h_max
    solves = 0
    while s < 1.0:
        last = s + h >= 1.0 - 1e-12  # (a sum of steps may fall short of 1 by a rounding)
        if last:
            h = 1.0 - s
        s1 = 1.0 if last else s + h
        _line_pose(p0, dp, R0, rot, s1, pt, Rt, r)
        for j in range(n):
            seed[j] = min(max(q[j] + h * m0[j], lower[j]), upper[j])
        solve_kernel(
            pre_R,
            pre_p,
            R_last,
            tool_local,
            lower,
            upper,
            turn,
            pt,
            Rt,
            seed,
            q,
            w_pos,
            1.0,
            LINE_IK_TOL,
            LINE_IK_TOL,
            n > 6,
            np.int64(LINE_ITER),  # not the literal 50: numba would compile solve_kernel once more for it
            q1,
            sinfo,
        )
        solves += 1
        if not (sinfo[0] <= tol_pos and sinfo[1] <= tol_rot):
            if h > h_min:
                h *= 0.5
                continue
            status = LINE_UNREACHED
            info[1], info[2], info[3] = s1, sinfo[0], sinfo[1]
            break
        tool_frames(pre_R, pre_p, R_last, tool_local, q1, R_all, p_all, p, R)
        sig = _line_rates(R_all, p_all, p, lower, upper, q1, twist, J, G, L, y, free, m1)
        jump = 0.0
        size = 0.0
        kink = JUMP_REL  # or 1 where a joint is at a limit (its rate may change there at once)
        for j in range(n):
            if min(q[j] - lower[j], upper[j] - q[j], q1[j] - lower[j], upper[j] - q1[j]) <= LIMIT_EPS:
                kink = 1.0
            jump = max(jump, abs(q1[j] - q[j] - 0.5 * h * (m0[j] + m1[j])))
            size = max(size, abs(m0[j]), abs(m1[j]))
            qm[j] = min(max(0.5 * (q[j] + q1[j]) + 0.125 * h * (m0[j] - m1[j]), lower[j]), upper[j])
        _line_pose(p0, dp, R0, rot, s + 0.5 * h, pt, Rt, r)
        mid_pos, mid_rot = _off_pose(pre_R, pre_p, R_last, tool_local, qm, pt, Rt, R_all, p_all, p, R, erot)
        if jump > kink * h * size + 1e-9 or mid_pos > tol_pos or mid_rot > tol_rot:
            if h > h_min:
                h *= 0.5
                continue
            status = LINE_JUMP
            info[1], info[2], info[3], info[4] = s + 0.5 * h, mid_pos, mid_rot, sig
            for j in range(n):
                q_at[j] = qm[j]
            break
        if sig < sigma_min:
            if h > h_min:
                h *= 0.5
                continue
            status = LINE_SINGULAR
            info[1], info[4] = s1, sig
            for j in range(n):
                q_at[j] = q1[j]
            break
        if k + 1 >= kmax:
            status = LINE_KNOTS
            info[1] = s
            break
        for j in range(n):
            qm[j] = 0.5 * (q[j] + q1[j])
        chord_pos, chord_rot = _off_pose(
            pre_R, pre_p, R_last, tool_local, qm, pt, Rt, R_all, p_all, p, R, erot
        )
        k += 1
        S[k] = s1
        C[k - 1, 0] = chord_pos
        C[k - 1, 1] = chord_rot
        for j in range(n):
            Q[k, j] = q1[j]
            D[k, j] = m1[j]
            q[j] = q1[j]
            m0[j] = m1[j]
            q_at[j] = q1[j]
        s = s1
        if 16.0 * mid_pos <= tol_pos and 16.0 * mid_rot <= tol_rot and 4.0 * jump <= kink * h * size:
            h = min(2.0 * h, h_max)
    info[0] = status
    info[5] = solves
    return k + 1


@dataclass
class LineWalk:
    """The joint solutions along a straight tool line (`ArmKinematics.walk_line`): knots at line
    parameters `s` (0 = the start, 1 = the target), spaced by the accuracy they need, not by time."""

    s: np.ndarray  # (K,) from 0; the last is 1 when the walk reached the target
    q: np.ndarray  # (K, n) rad: the joint solutions there
    dq: np.ndarray  # (K, n) rad per unit s: dq/ds (J+ of the line's twist)
    chord: np.ndarray  # (K - 1, 2) m, rad: the pose error of the straight joint-space chord at its middle
    status: int  # LINE_OK, or why the walk ended (LINE_UNREACHED, LINE_SINGULAR, LINE_JUMP, LINE_KNOTS)
    at: float  # s where it ended
    position_error: float  # m, there (LINE_UNREACHED: of the IK; LINE_JUMP: of the curve's middle)
    rotation_error: float  # rad
    sigma: float  # smallest singular value of the Jacobian there
    q_at: np.ndarray  # (n,) the posture there
    solves: int  # inverse-kinematics solves spent, kept or not

    @property
    def ok(self) -> bool:
        return self.status == LINE_OK
