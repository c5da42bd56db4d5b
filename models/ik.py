"""Inverse kinematics of the chain the simulator integrates (the tool pose and Jacobian kernels are in
chain_kinematics.py).

The chain is built from `mechanics.chain_arrays` and `mechanics.tool_point` and evaluated with
`chain_dynamics.chain_frames`, so the poses here are the `pose.*` rows of a run
(`chain_dynamics.pose_rows`, row n): the
tool point in the last joint frame, the tool orientation that of the last link frame,
`R_all[n-1] @ rot_rpy(spec.links[-1].rpy)`. Cartesian commands go through `ArmKinematics.walk_line`
(a straight line: the joint solutions along it, one compiled call), `ArmKinematics.solve` (local, from
a seed: resolved-rate steps) and `ArmKinematics.solve_near` (global: the goal of a point-to-point move).

The solver (`_solve_kernel`, compiled with numba like drive.py, one call per attempt):

- the 6-D error is the tool position error and the rotation vector that turns the tool orientation
  into the target's (world frame); the position rows are divided by the arm's reach so both parts are
  dimensionless;
- each step is a damped least-squares step dq = J^T (J J^T + lam I)^-1 e (a 6 x 6 Cholesky solve) with
  Levenberg-Marquardt damping: lam falls tenfold after a step that lowered the error and rises tenfold
  after one that did not (the step is then retried from the same point); it starts at 1 % of the
  squared error, so a small correction is an undamped Gauss-Newton step (a resolved-rate step from a
  seed 1 ms of motion away converges in 2 iterations);
- every iterate is clamped to the joint limits; a joint at a limit that the step pushes outwards is
  taken out of the step (its column dropped) so the other joints make up for it;
- redundancy (n > 6, the Spider) is resolved by "closest to the seed": once the error is small, the
  step adds g N (seed - q), N the projector onto the null space of J (an undamped projector, applied
  twice). At a fixed point N (seed - q) = 0, the first-order condition of the nearest point to the
  seed (Euclidean in joint space) on the self-motion manifold of the target: of all joint vectors
  that reach the target, the solver returns the (local) one nearest the seed, i.e. the smallest joint
  motion. The gain g adapts to how fast the pull shrinks from one step to the next (halved when it
  grows, raised when it barely shrinks); the solve ends when the pose is within the tolerances and
  |N (seed - q)| < NULL_TOL.

When the seed's own attempt fails, `solve` tries a few seeds around it (N_LOCAL, fixed) and
`solve_near` a fixed set of seeds over the whole joint space (N_RESTARTS, fixed RNG seed), letting
joints whose range holds a full turn pass a limit by a turn; where a seed stops at a limit, the same
seed without limits finds a branch (elbow, wrist flip) that may lie inside them once turned. Both keep
the converged solution nearest the seed.

A line is walked in steps of the line parameter (`_line_kernel`): each knot solved by the same kernel
from the previous knot moved along its rates dq/ds = J+ twist (the smallest joint motion, the limit of
"nearest the previous solution" as the steps shrink), its step halved until the cubic Hermite curve
through the two knots and their rates is on the line at its middle and the joint step agrees with the
rates, and doubled again when it is well within. The knots' spacing so follows the line's geometry
(curvature of the joint path, singular regions), never its speed.

If nothing converges, the result is the closest pose within the limits: position first, orientation
second (rotation weight W_PRIORITY), from the kernel and then L-BFGS-B (beyond reach the residual is
large and Gauss-Newton crawls), with a reason: the joint a limit stops ("joint limits: ..."), the
distance the arm cannot close ("out of reach: ...", and whether the limits bind), or the orientation
it cannot reach at the target position.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.optimize import minimize
from simecs.mesh.kinematics import rot_rpy

from .chain_kinematics import cholesky, cholesky_solve, rotation_vector, tool_frames, tool_jacobian
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .mechanics import chain_arrays, tool_point
from .spec import ArmSpec

# ---- solver constants (dimensionless: position rows are divided by the reach) ---------------------------
LAM_MIN = 1e-14  # smallest damping: a pure Gauss-Newton step near the solution
LAM_MAX = 1e10  # damping beyond which no step lowers the error: a stationary point
LAM_NULL = 1e-12  # damping of the null-space projector (only singular directions are damped)
NEAR2 = 1e-6  # squared error below which the null-space pull toward the seed is on
ACCEPT2 = 1e-4  # a step with null-space motion is kept while the squared error stays below this
STEP_MAX = 0.5  # rad: largest change of any joint in one step
NULL_STEP = 0.3  # rad: largest null-space move in one step
GAIN_MAX = 32.0  # largest null-space gain
NULL_TOL = 1e-7  # rad: the null-space pull that counts as "closest to the seed" reached
W_PRIORITY = 1e-3  # rotation weight of the "closest pose" search: position first, orientation second
N_RESTARTS = 16  # extra seeds of solve_near
N_LOCAL = 4  # extra seeds of solve when the seed itself fails: the seed moved by up to LOCAL_SPREAD
LOCAL_SPREAD = 0.3  # rad
RESTART_RNG = 20240611  # fixed: solve_near is deterministic
BIG = 1e300  # "no limit"

# status codes of the kernel
ST_MAX_ITER, ST_CONVERGED, ST_STALLED = 0, 1, 2


# ---- compiled kernels --------------------------------------------------------------------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _error(p, R, p_t, R_t, w_pos, w_rot, e, erot):
    """Weighted 6-D error e (position / reach, rotation vector) into e; returns (|dp|, angle, |e|^2)."""
    d0 = p_t[0] - p[0]
    d1 = p_t[1] - p[1]
    d2 = p_t[2] - p[2]
    ang = rotation_vector(R, R_t, erot)
    e[0] = w_pos * d0
    e[1] = w_pos * d1
    e[2] = w_pos * d2
    for a in range(3):
        e[3 + a] = w_rot * erot[a]
    F = 0.0
    for a in range(6):
        F += e[a] * e[a]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), ang, F


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _error_jacobian(J, erot, ang, w_pos, w_rot, Je):
    """Je = -d e / dq of the weighted error: position rows w_pos Jv, rotation rows w_rot Jr^-1(e) Jw.

    Jr^-1 (inverse right Jacobian of SO(3)) makes the rotation rows the exact derivative of the rotation
    vector, not only near zero error; close to pi it is left out (it is singular there)."""
    n = J.shape[1]
    if ang < 1e-4:
        g = 1.0 / 12.0 + ang * ang / 720.0
    elif ang < 2.5:
        g = 1.0 / (ang * ang) - (1.0 + math.cos(ang)) / (2.0 * ang * math.sin(ang))
    else:
        g = -1.0  # marker: identity
    K = np.zeros((3, 3))
    if g >= 0.0:
        x, y, z = erot[0], erot[1], erot[2]
        # I + 1/2 [e]x + g [e]x^2, [e]x^2 = e e^T - |e|^2 I
        sq = x * x + y * y + z * z
        K[0, 0] = 1.0 + g * (x * x - sq)
        K[1, 1] = 1.0 + g * (y * y - sq)
        K[2, 2] = 1.0 + g * (z * z - sq)
        K[0, 1] = -0.5 * z + g * x * y
        K[1, 0] = 0.5 * z + g * x * y
        K[0, 2] = 0.5 * y + g * x * z
        K[2, 0] = -0.5 * y + g * x * z
        K[1, 2] = -0.5 * x + g * y * z
        K[2, 1] = 0.5 * x + g * y * z
    else:
        K[0, 0] = 1.0
        K[1, 1] = 1.0
        K[2, 2] = 1.0
    for i in range(n):
        for a in range(3):
            Je[a, i] = w_pos * J[a, i]
            Je[3 + a, i] = w_rot * (K[a, 0] * J[3, i] + K[a, 1] * J[4, i] + K[a, 2] * J[5, i])


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _solve_kernel(
    pre_R,
    pre_p,
    R_last,
    tool_local,
    lower,
    upper,
    turn,
    p_t,
    R_t,
    q_start,
    q_pull,
    w_pos,
    w_rot,
    tol_pos,
    tol_rot,
    use_null,
    max_iter,
    q,
    info,
):
    """Damped least squares from q_start into q (see the module docstring); returns the iterations.

    turn[j] > 0: joint j passes its limit by whole turns of `turn` (2 pi) instead of stopping there
    (solve_near, where only the end pose matters); 0: clamped.
    info: [position error, rotation error, status (ST_*), null-space pull |N (q_pull - q)|].
    """
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    R_all_t = np.empty((n, 3, 3))
    p_all_t = np.empty((n, 3))
    p = np.empty(3)
    R = np.empty((3, 3))
    pt = np.empty(3)
    Rt = np.empty((3, 3))
    e = np.empty(6)
    et = np.empty(6)
    erot = np.empty(3)
    erot_t = np.empty(3)
    J = np.empty((6, n))
    Je = np.empty((6, n))
    A = np.empty((6, 6))
    L = np.zeros((6, 6))
    b2 = np.empty(6)
    y1 = np.empty(6)
    y2 = np.empty(6)
    dq = np.empty(n)
    nz = np.empty(n)
    qt = np.empty(n)
    free = np.empty(n, dtype=np.bool_)
    for j in range(n):
        q[j] = min(max(q_start[j], lower[j]), upper[j])
    tool_frames(pre_R, pre_p, R_last, tool_local, q, R_all, p_all, p, R)
    pos_err, rot_err, F = _error(p, R, p_t, R_t, w_pos, w_rot, e, erot)
    lam = max(1e-2 * F, LAM_MIN)
    alpha = 1.0  # length of the null-space move, shortened after a rejected step, regrown after
    gain = 1.0  # null-space gain, adapted from how fast the pull shrinks
    nz_last = np.inf
    need_j = True
    status = ST_MAX_ITER
    nz_norm = 0.0
    flat = 0
    it = 0
    limit = max_iter
    while True:
        if it >= limit:
            if use_null and F <= NEAR2 and limit == max_iter:
                use_null = False  # out of iterations: a few task-only steps end on the target
                limit += 20
            else:
                break
        task_ok = pos_err <= tol_pos and rot_err <= tol_rot
        if task_ok and not use_null:
            status = ST_CONVERGED
            break
        fresh = need_j
        if need_j:
            tool_jacobian(R_all, p_all, p, J)
            _error_jacobian(J, erot, rot_err, w_pos, w_rot, Je)
            need_j = False
        null_on = use_null and (F <= NEAR2 or task_ok)
        for j in range(n):
            free[j] = True
        nz_norm = 0.0
        g_new = gain
        for _ in range(n + 1):
            for a in range(6):
                for b in range(a + 1):
                    s = 0.0
                    for j in range(n):
                        if free[j]:
                            s += Je[a, j] * Je[b, j]
                    A[a, b] = s
                    A[b, a] = s
                s = 0.0
                if null_on:
                    for j in range(n):
                        if free[j]:
                            s += Je[a, j] * (q_pull[j] - q[j])
                b2[a] = s
            cholesky(A, lam, L)
            cholesky_solve(L, e, y1)
            if null_on:
                cholesky(A, LAM_NULL, L)
                cholesky_solve(L, b2, y2)
            for j in range(n):
                if free[j]:
                    s = 0.0
                    for a in range(6):
                        s += Je[a, j] * y1[a]
                    dq[j] = s
                else:
                    dq[j] = 0.0
            if null_on:
                # nz = (I - Je^T (A + mu I)^-1 Je) z, applied twice: the row-space part left by the
                # damping mu shrinks by mu / (sigma^2 + mu) per pass
                for j in range(n):
                    nz[j] = q_pull[j] - q[j] if free[j] else 0.0
                for npass in range(2):
                    if npass == 1:
                        for a in range(6):
                            s = 0.0
                            for j in range(n):
                                s += Je[a, j] * nz[j]
                            b2[a] = s
                        cholesky_solve(L, b2, y2)
                    for j in range(n):
                        if free[j]:
                            s = nz[j]
                            for a in range(6):
                                s -= Je[a, j] * y2[a]
                            nz[j] = s
                nn = 0.0
                for j in range(n):
                    nn += nz[j] * nz[j]
                nz_norm = math.sqrt(nn)
                if fresh and nz_last > NULL_TOL and alpha == 1.0:
                    # the pull shrinks by (1 - gain h) per step, h the curvature of the distance
                    # to the seed along the self-motion: grown, the gain is too high; barely
                    # shrinking, too low (a flat distance)
                    ratio = nz_norm / nz_last
                    if ratio > 1.0:
                        g_new = 0.5 * gain
                    elif ratio > 0.5:
                        g_new = min(GAIN_MAX, 1.5 * gain)
                g = alpha * g_new
                if nz_norm > NULL_STEP:
                    g *= NULL_STEP / nz_norm
                for j in range(n):
                    dq[j] += g * nz[j]
            changed = False
            for j in range(n):
                if (
                    free[j]
                    and turn[j] == 0.0
                    and ((q[j] <= lower[j] and dq[j] < 0.0) or (q[j] >= upper[j] and dq[j] > 0.0))
                ):
                    free[j] = False
                    changed = True
            if not changed:
                break
        if task_ok and nz_norm <= NULL_TOL:
            status = ST_CONVERGED
            break
        if null_on:
            gain = g_new
        mx = 0.0
        for j in range(n):
            mx = max(mx, abs(dq[j]))
        if mx < 1e-15:
            status = ST_STALLED
            break
        sc = 1.0 if mx <= STEP_MAX else STEP_MAX / mx
        for j in range(n):
            x = q[j] + sc * dq[j]
            if turn[j] > 0.0:
                if x < lower[j]:
                    x += turn[j]
                elif x > upper[j]:
                    x -= turn[j]
            qt[j] = min(max(x, lower[j]), upper[j])
        tool_frames(pre_R, pre_p, R_last, tool_local, qt, R_all_t, p_all_t, pt, Rt)
        pe_t, re_t, F_t = _error(pt, Rt, p_t, R_t, w_pos, w_rot, et, erot_t)
        it += 1
        if F_t < F or (null_on and F_t <= ACCEPT2):
            flat = flat + 1 if F - F_t <= 1e-14 * F else 0
            for j in range(n):
                q[j] = qt[j]
            R_all[:, :, :] = R_all_t
            p_all[:, :] = p_all_t
            p[:] = pt
            R[:, :] = Rt
            e[:] = et
            erot[:] = erot_t
            pos_err, rot_err, F = pe_t, re_t, F_t
            lam = max(0.1 * lam, LAM_MIN)
            alpha = min(1.0, 2.0 * alpha)
            if null_on:
                nz_last = nz_norm
            need_j = True
            if flat >= 3 and not null_on:
                status = ST_STALLED
                break
        elif null_on and alpha > 1e-3:
            alpha *= 0.25  # the null-space move was too long: shorten it first
        else:
            lam *= 10.0
            if lam > LAM_MAX:
                status = ST_STALLED
                break
    info[0] = pos_err
    info[1] = rot_err
    info[2] = status
    info[3] = nz_norm
    return it


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _cost_grad(pre_R, pre_p, R_last, tool_local, p_t, R_t, w_pos, w_rot, q, grad):
    """0.5 |e(q)|^2 of the weighted error and its gradient -Je^T e into grad (the closest-pose polish)."""
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    p = np.empty(3)
    R = np.empty((3, 3))
    e = np.empty(6)
    erot = np.empty(3)
    J = np.empty((6, n))
    Je = np.empty((6, n))
    tool_frames(pre_R, pre_p, R_last, tool_local, q, R_all, p_all, p, R)
    _, ang, F = _error(p, R, p_t, R_t, w_pos, w_rot, e, erot)
    tool_jacobian(R_all, p_all, p, J)
    _error_jacobian(J, erot, ang, w_pos, w_rot, Je)
    for j in range(n):
        s = 0.0
        for a in range(6):
            s -= Je[a, j] * e[a]
        grad[j] = s
    return 0.5 * F


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _tool_positions(pre_R, pre_p, R_last, tool_local, qs, out):
    """out[k] = the tool position at qs[k]."""
    n = qs.shape[1]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    p = np.empty(3)
    R = np.empty((3, 3))
    for k in range(qs.shape[0]):
        tool_frames(pre_R, pre_p, R_last, tool_local, qs[k], R_all, p_all, p, R)
        for a in range(3):
            out[k, a] = p[a]


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
def _rotvec_exp(r, R0, R):
    """R = exp([r]x) R0 (Rodrigues): the orientation a rotation vector r (world frame) away from R0."""
    ang = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    E = np.eye(3)
    if ang > 1e-15:
        x, y, z = r[0] / ang, r[1] / ang, r[2] / ang
        s, c1 = math.sin(ang), 1.0 - math.cos(ang)
        E[0, 0] = 1.0 - c1 * (y * y + z * z)
        E[1, 1] = 1.0 - c1 * (x * x + z * z)
        E[2, 2] = 1.0 - c1 * (x * x + y * y)
        E[0, 1] = -s * z + c1 * x * y
        E[1, 0] = s * z + c1 * x * y
        E[0, 2] = s * y + c1 * x * z
        E[2, 0] = -s * y + c1 * x * z
        E[1, 2] = -s * x + c1 * y * z
        E[2, 1] = s * x + c1 * y * z
    for a in range(3):
        for b in range(3):
            R[a, b] = E[a, 0] * R0[0, b] + E[a, 1] * R0[1, b] + E[a, 2] * R0[2, b]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _line_pose(p0, dp, R0, rot, s, p, R, r):
    """The pose at parameter s of the line: p0 + s dp, exp(s rot) R0 (r: scratch)."""
    for a in range(3):
        p[a] = p0[a] + s * dp[a]
        r[a] = s * rot[a]
    _rotvec_exp(r, R0, R)


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
        for a in range(6):
            for b in range(a + 1):
                s = 0.0
                for j in range(n):
                    if free[j]:
                        s += J[a, j] * J[b, j]
                G[a, b] = s
                G[b, a] = s
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
def _line_kernel(
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
        _solve_kernel(
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
            LINE_ITER,
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


# ---- public API ------------------------------------------------------------------------------------------
@dataclass
class IKResult:
    """One inverse-kinematics answer; `q` is within the joint limits even when `ok` is False."""

    q: np.ndarray  # the joint solution (always within the joint limits)
    ok: bool  # position error <= tol_pos and rotation error <= tol_rot
    position_error: float  # m, |p(q) - target|
    rotation_error: float  # rad, angle of R(q)^T R_target
    iterations: int  # solver iterations, summed over every attempt (restarts, diagnosis)
    reason: str  # '' when ok; else a short sentence saying why not and how far the closest pose is


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


class _Run(NamedTuple):
    q: np.ndarray
    position_error: float
    rotation_error: float
    iterations: int
    status: int
    ok: bool


def orientation_error(R_now: np.ndarray, R_target: np.ndarray) -> np.ndarray:
    """Rotation vector (3,), world frame, that turns R_now into R_target: exp([e]x) R_now = R_target.

    Its norm is the rotation error of `IKResult`; it is the rotation part of the solver's error."""
    e = np.empty(3)
    rotation_vector(np.ascontiguousarray(R_now, dtype=float), np.ascontiguousarray(R_target, dtype=float), e)
    return e


def turned(r: np.ndarray, R: np.ndarray) -> np.ndarray:
    """exp([r]x) R: the orientation R turned by the rotation vector r (world frame), the inverse of
    `orientation_error` (turned(orientation_error(R0, R1), R0) = R1)."""
    out = np.empty((3, 3))
    _rotvec_exp(np.ascontiguousarray(r, dtype=float), np.ascontiguousarray(R, dtype=float), out)
    return out


class ArmKinematics:
    """Kinematics of one model at one parameter set (link lengths matter; masses do not).

    Build it once per value set: the chain arrays are computed here, every call after that runs the
    compiled kernels only."""

    def __init__(self, spec: ArmSpec, values: Mapping[str, float]) -> None:
        self.spec = spec
        self.n = len(spec.links)
        chain = chain_arrays(spec, values)
        self.pre_R = np.ascontiguousarray(chain.pre_R)
        self.pre_p = np.ascontiguousarray(chain.pre_p)
        self.tool_local = np.ascontiguousarray(tool_point(spec, values), dtype=float)
        self.R_last = np.ascontiguousarray(rot_rpy(spec.links[-1].rpy))
        self.lower = np.array([lk.joint_min for lk in spec.links], dtype=float)
        self.upper = np.array([lk.joint_max for lk in spec.links], dtype=float)
        # the reach bound: position errors are divided by it so they weigh like radians
        self.reach = float(np.sum(np.linalg.norm(self.pre_p[1:], axis=1)) + np.linalg.norm(self.tool_local))
        self.reach = max(self.reach, 1e-3)
        self._no_lower = np.full(self.n, -BIG)
        self._no_upper = np.full(self.n, BIG)
        # joints whose range holds a full turn: solve_near lets them pass a limit by a turn
        self._turn = np.where(self.upper - self.lower >= 2 * math.pi, 2 * math.pi, 0.0)
        self._no_turn = np.zeros(self.n)
        rng = np.random.default_rng(RESTART_RNG)
        lo = np.where(np.isfinite(self.lower), self.lower, -math.pi)
        hi = np.where(np.isfinite(self.upper), self.upper, math.pi)
        self.restarts = lo + (hi - lo) * rng.random((N_RESTARTS, self.n))
        self.local_offsets = rng.uniform(-LOCAL_SPREAD, LOCAL_SPREAD, (N_LOCAL, self.n))

    # ---- forward kinematics ----
    def _q(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        qv = np.ascontiguousarray(q, dtype=float)
        if qv.shape != (self.n,):
            raise ValueError(f"expected {self.n} joint positions, got shape {qv.shape}")
        return qv

    def tool_pose(self, q: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool position (3,) and rotation matrix (3, 3) in the world frame: the `pose.*` tool row."""
        p = np.empty(3)
        R = np.empty((3, 3))
        R_all = np.empty((self.n, 3, 3))
        p_all = np.empty((self.n, 3))
        tool_frames(self.pre_R, self.pre_p, self.R_last, self.tool_local, self._q(q), R_all, p_all, p, R)
        return p, R

    def tool_positions(self, qs: np.ndarray) -> np.ndarray:
        """(k, 3): the tool position at each row of qs (k, n), in one compiled call (a planned path)."""
        qv = np.ascontiguousarray(qs, dtype=float)
        if qv.ndim != 2 or qv.shape[1] != self.n:
            raise ValueError(f"expected rows of {self.n} joint positions, got shape {qv.shape}")
        out = np.empty((qv.shape[0], 3))
        _tool_positions(self.pre_R, self.pre_p, self.R_last, self.tool_local, qv, out)
        return out

    def jacobian(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        """(6, n): rows 0-2 the tool point's linear velocity, rows 3-5 the angular velocity per unit
        joint speed, world frame (what a resolved-rate controller inverts)."""
        p = np.empty(3)
        R = np.empty((3, 3))
        R_all = np.empty((self.n, 3, 3))
        p_all = np.empty((self.n, 3))
        tool_frames(self.pre_R, self.pre_p, self.R_last, self.tool_local, self._q(q), R_all, p_all, p, R)
        J = np.empty((6, self.n))
        tool_jacobian(R_all, p_all, p, J)
        return J

    @property
    def base(self) -> np.ndarray:
        """The origin of joint 1 (world): no tool point is farther from it than `reach`."""
        return np.asarray(self.pre_p[0], dtype=float)

    def from_base(self, position: Sequence[float] | np.ndarray) -> float:
        """m from the arm's base (joint 1's origin) to a position: beyond `reach` it is out of reach."""
        return float(np.linalg.norm(np.asarray(position, dtype=float) - self.base))

    def sigma_min(self, q: Sequence[float] | np.ndarray) -> float:
        """Smallest singular value of the 6 x n Jacobian: near 0 the arm is near a singularity, where
        small Cartesian moves need large joint speeds."""
        return float(np.linalg.svd(self.jacobian(q), compute_uv=False)[-1])

    # ---- inverse kinematics ----
    def _target(
        self, position: Sequence[float] | np.ndarray, R: np.ndarray, seed: Sequence[float] | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p_t = np.ascontiguousarray(position, dtype=float)
        R_t = np.ascontiguousarray(R, dtype=float)
        q0 = self._q(seed)
        if p_t.shape != (3,) or R_t.shape != (3, 3):
            raise ValueError("expected a position (3,) and a rotation matrix (3, 3)")
        if not (np.all(np.isfinite(p_t)) and np.all(np.isfinite(R_t)) and np.all(np.isfinite(q0))):
            raise ValueError("position, rotation and seed must be finite")
        return p_t, R_t, np.clip(q0, self.lower, self.upper)

    def _run(
        self,
        p_t: np.ndarray,
        R_t: np.ndarray,
        start: np.ndarray,
        pull: np.ndarray,
        tol_pos: float,
        tol_rot: float,
        max_iter: int,
        *,
        w_rot: float = 1.0,
        limits: bool = True,
        turns: bool = False,
    ) -> _Run:
        q = np.empty(self.n)
        info = np.zeros(4)
        it = _solve_kernel(
            self.pre_R,
            self.pre_p,
            self.R_last,
            self.tool_local,
            self.lower if limits else self._no_lower,
            self.upper if limits else self._no_upper,
            self._turn if turns and limits else self._no_turn,
            p_t,
            R_t,
            np.ascontiguousarray(start, dtype=float),
            np.ascontiguousarray(pull, dtype=float),
            1.0 / self.reach,
            w_rot,
            tol_pos,
            tol_rot,
            self.n > 6,
            max_iter,
            q,
            info,
        )
        pe, re = float(info[0]), float(info[1])
        return _Run(q, pe, re, int(it), int(info[2]), pe <= tol_pos and re <= tol_rot)

    def solve(
        self,
        position: Sequence[float] | np.ndarray,
        R: np.ndarray,
        seed: Sequence[float] | np.ndarray,
        *,
        tol_pos: float = 1e-9,
        tol_rot: float = 1e-9,
        max_iter: int = 200,
    ) -> IKResult:
        """The joint vector that puts the tool at (position, R), found locally from `seed` (clamped to
        the limits): the resolved-rate step of a straight-line move and the refinement of a good guess.

        For a redundant arm the answer is the solution nearest the seed (module docstring). On failure
        `q` is the closest pose found from this seed (position first, then orientation) and `reason`
        says how far it is and whether a joint limit is in the way."""
        p_t, R_t, q0 = self._target(position, R, seed)
        best, runs, total = self._local(p_t, R_t, q0, tol_pos, tol_rot, max_iter)
        if best is not None:
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        return self._failure(p_t, R_t, q0, runs, None, tol_pos, tol_rot, max_iter, local=True, spent=total)

    def _local(
        self, p_t: np.ndarray, R_t: np.ndarray, q0: np.ndarray, tol_pos: float, tol_rot: float, max_iter: int
    ) -> tuple[_Run | None, list[_Run], int]:
        """The seed's attempt, and if it fails a few seeds around it (stuck, typically at a joint limit
        between the seed and the nearest solution): the converged run nearest the seed (or None), every
        run and the iterations."""
        r = self._run(p_t, R_t, q0, q0, tol_pos, tol_rot, max_iter)
        if r.ok:
            return r, [r], r.iterations
        runs = [r]
        for off in self.local_offsets:
            start = np.clip(q0 + off, self.lower, self.upper)
            runs.append(self._run(p_t, R_t, start, q0, tol_pos, tol_rot, max_iter))
        found = [r for r in runs if r.ok]
        total = sum(r.iterations for r in runs)
        best = min(found, key=lambda r: float(np.linalg.norm(r.q - q0))) if found else None
        return best, runs, total

    def solve_near(
        self,
        position: Sequence[float] | np.ndarray,
        R: np.ndarray,
        seed: Sequence[float] | np.ndarray,
        *,
        tol_pos: float = 1e-9,
        tol_rot: float = 1e-9,
    ) -> IKResult:
        """`solve`, and if that fails from `seed`, from a fixed set of extra seeds (deterministic): the
        goal of a point-to-point move given as a pose. Of the converged solutions the one closest to
        `seed` (Euclidean in joint space) is returned; if none converges, the closest pose the arm
        reaches, with `reason` saying how far it is and whether joint limits were binding."""
        max_iter = 200
        p_t, R_t, q0 = self._target(position, R, seed)
        best, runs, total = self._local(p_t, R_t, q0, tol_pos, tol_rot, max_iter)
        if best is not None:  # what `solve` answers
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        # then the pose wherever it is: joints with a full turn of range may pass their limits by a
        # turn, and the extra seeds cover the other branches (elbow, wrist flips)
        found: list[_Run] = []
        for s in [q0, *self.restarts]:
            r = self._run(p_t, R_t, s, q0, tol_pos, tol_rot, max_iter, turns=True)
            total += r.iterations
            runs.append(r)
            if not r.ok:
                # stuck at a limit: the branch it heads for is outside the limits, but from the
                # same seed, without limits, the solver may reach one that (turned) lies inside
                free = self._run(p_t, R_t, s, q0, tol_pos, tol_rot, max_iter, limits=False)
                total += free.iterations
                qw = self._wrap(free.q)
                if free.ok and self._inside(qw):
                    r = self._run(p_t, R_t, qw, q0, tol_pos, tol_rot, max_iter, turns=True)
                    total += r.iterations
                    runs.append(r)
            if r.ok:
                found.append(r)
        if found:
            best = min(found, key=lambda r: float(np.linalg.norm(r.q - q0)))
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        return self._failure(p_t, R_t, q0, runs, None, tol_pos, tol_rot, max_iter, local=False, spent=total)

    def walk_line(
        self,
        q_start: Sequence[float] | np.ndarray,
        position: Sequence[float] | np.ndarray,
        R: np.ndarray,
        *,
        tol_pos: float,
        tol_rot: float,
        step: float,
        turn: float,
        sigma_min: float,
        max_knots: int,
    ) -> LineWalk:
        """The joint solutions along the straight line from the tool pose at `q_start` to (position,
        R): position linear, orientation slerped (exp(s rot) R0), in one compiled call.

        Each knot is the solution nearest the previous one (as a resolved-rate walk finds it); knots
        are at most `step` m and `turn` rad apart and closer where the cubic Hermite curve through
        them and their rates would leave the line by more than (tol_pos, tol_rot) at a middle, so
        their number follows the line's geometry, not its speed. The walk ends early, saying where
        and why, at a pose the solver cannot reach from there, at a posture whose smallest singular
        value is below `sigma_min`, where the joints would have to jump (the curve cannot follow
        the line however short the step: the joint speed needed is unbounded), or after `max_knots`."""
        q0 = np.clip(self._q(q_start), self.lower, self.upper)
        p0, R0 = self.tool_pose(q0)
        p_t, R_t, _ = self._target(position, R, q0)
        dp = p_t - p0
        rot = orientation_error(R0, R_t)
        size = max(float(np.linalg.norm(dp)) / step, float(np.linalg.norm(rot)) / turn)
        fine = max(float(np.linalg.norm(dp)) / tol_pos, float(np.linalg.norm(rot)) / tol_rot)
        h_max = 1.0 / max(size, 1.0)
        h_min = min(h_max, 1.0 / max(fine, 1.0))
        S = np.empty(max_knots)
        Q = np.empty((max_knots, self.n))
        D = np.empty((max_knots, self.n))
        C = np.zeros((max_knots, 2))
        q_at = np.empty(self.n)
        info = np.zeros(6)
        k = _line_kernel(
            self.pre_R,
            self.pre_p,
            self.R_last,
            self.tool_local,
            self.lower,
            self.upper,
            np.ascontiguousarray(p0),
            np.ascontiguousarray(dp),
            np.ascontiguousarray(R0),
            np.ascontiguousarray(rot),
            q0,
            1.0 / self.reach,
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
        )
        return LineWalk(
            S[:k].copy(),
            Q[:k].copy(),
            D[:k].copy(),
            C[: max(k - 1, 0)].copy(),
            int(info[0]),
            float(info[1]),
            float(info[2]),
            float(info[3]),
            float(info[4]),
            q_at,
            int(info[5]),
        )

    # ---- failure diagnosis ----
    def _wrap(self, q: np.ndarray) -> np.ndarray:
        """Each joint moved by whole turns into its limits where a turn fits there (same pose)."""
        out = q.copy()
        for j in range(self.n):
            lo, hi = self.lower[j], self.upper[j]
            if not lo <= q[j] <= hi and np.isfinite(lo):
                w = lo + math.fmod(q[j] - lo, 2 * math.pi)
                if w < lo:
                    w += 2 * math.pi
                if w <= hi:
                    out[j] = w
        return out

    def _inside(self, q: np.ndarray) -> bool:
        return bool(np.all(q >= self.lower) and np.all(q <= self.upper))

    def _cost(self, r: _Run) -> float:
        """What the closest-pose search minimises: position first, orientation second."""
        return (r.position_error / self.reach) ** 2 + (W_PRIORITY * r.rotation_error) ** 2

    def _polish(
        self, p_t: np.ndarray, R_t: np.ndarray, q: np.ndarray, limits: bool, tol_pos: float, tol_rot: float
    ) -> _Run:
        """The closest-pose objective minimised with L-BFGS-B (bounds = the limits) from q.

        Gauss-Newton (the kernel) crawls here: beyond reach the residual is large, and its curvature,
        which Gauss-Newton leaves out, dominates (e.g. a wrist orienting a short tool offset)."""
        args = (self.pre_R, self.pre_p, self.R_last, self.tool_local, p_t, R_t, 1.0 / self.reach, W_PRIORITY)
        grad = np.empty(self.n)

        def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
            f = _cost_grad(*args, np.ascontiguousarray(x, dtype=float), grad)
            return float(f), grad.copy()

        bounds = list(zip(self.lower, self.upper, strict=True)) if limits else None
        res = minimize(
            fun,
            q,
            jac=True,
            method="L-BFGS-B",
            bounds=bounds,
            options={"maxiter": 2000, "ftol": 1e-16, "gtol": 1e-13},
        )
        x = np.clip(res.x, self.lower, self.upper) if limits else np.asarray(res.x, dtype=float)
        p, R = self.tool_pose(x)
        pe = float(np.linalg.norm(p - p_t))
        re = float(np.linalg.norm(orientation_error(R, R_t)))
        return _Run(x, pe, re, int(res.nit), ST_STALLED, pe <= tol_pos and re <= tol_rot)

    def _closest(
        self,
        p_t: np.ndarray,
        R_t: np.ndarray,
        starts: list[np.ndarray],
        q0: np.ndarray,
        tol_pos: float,
        tol_rot: float,
        max_iter: int,
        limits: bool,
    ) -> tuple[_Run, int]:
        """The closest pose (position first, then orientation) from these starts, and the iterations."""
        best: _Run | None = None
        total = 0
        for s in starts:
            c = self._run(p_t, R_t, s, q0, tol_pos, tol_rot, max_iter, w_rot=W_PRIORITY, limits=limits)
            total += c.iterations
            if best is None or self._cost(c) < self._cost(best):
                best = c
        assert best is not None
        if not best.ok:
            polished = self._polish(p_t, R_t, best.q, limits, tol_pos, tol_rot)
            total += polished.iterations
            if self._cost(polished) < self._cost(best):
                best = polished
        return best, total

    def _failure(
        self,
        p_t: np.ndarray,
        R_t: np.ndarray,
        q0: np.ndarray,
        runs: list[_Run],
        free: _Run | None,
        tol_pos: float,
        tol_rot: float,
        max_iter: int,
        *,
        local: bool,
        spent: int,
    ) -> IKResult:
        """The closest pose within the limits (position first, then orientation) and why the target
        was not reached: a joint limit in the way, out of reach, or an orientation out of reach."""
        total = spent
        starts = [q0] + [r.q for r in sorted(runs, key=self._cost)[:4]]
        closest, its = self._closest(p_t, R_t, starts, q0, tol_pos, tol_rot, max_iter, True)
        total += its
        best = min([*runs, closest], key=self._cost)
        if best.ok:  # the position-first search met both tolerances after all
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        if free is None:
            free = self._run(p_t, R_t, q0, q0, tol_pos, tol_rot, max_iter, limits=False)
            total += free.iterations
        dist = f"{best.position_error:.3g} m and {best.rotation_error:.3g} rad away"
        where = "found from this seed" if local else "the arm reaches"
        reason = ""
        if free.ok:
            qw = self._wrap(free.q)
            out = [j for j in range(self.n) if not self.lower[j] <= qw[j] <= self.upper[j]]
            if out:
                need = ", ".join(
                    f"joint{j + 1} would need {free.q[j]:.4g} rad (limits {self.lower[j]:.4g} .. "
                    f"{self.upper[j]:.4g})"
                    for j in out
                )
                reason = f"joint limits: {need}; the closest pose {where} within the limits is {dist}"
            elif local:
                turned = ", ".join(
                    f"joint{j + 1} at {qw[j]:.4g} rad" for j in range(self.n) if qw[j] != free.q[j]
                )
                reason = (
                    f"joint limits: from this seed the target needs a joint past its limit; the same pose "
                    f"is reached with {turned}, a full turn away (solve_near finds it); the closest pose "
                    f"{where} is {dist}"
                )
        if not reason:
            unlimited, its = self._closest(p_t, R_t, [best.q], q0, tol_pos, tol_rot, max_iter, False)
            total += its
            if best.position_error > tol_pos:
                reason = f"out of reach: the closest pose {where} is {best.position_error:.3g} m away"
                d_free = unlimited.position_error
                if d_free < best.position_error - 1e-6 * (1.0 + best.position_error):
                    at = [
                        f"joint{j + 1}"
                        for j in range(self.n)
                        if best.q[j] <= self.lower[j] or best.q[j] >= self.upper[j]
                    ]
                    reason += (
                        f" (joint limits bind{': ' + ', '.join(at) + ' at a limit' if at else ''}; "
                        f"without them {d_free:.3g} m)"
                    )
                else:
                    reason += " (joint limits are not the binding constraint)"
                reason += f", and {best.rotation_error:.3g} rad off in orientation"
            else:
                reason = (
                    f"orientation out of reach: at the target position the closest orientation {where} is "
                    f"{best.rotation_error:.3g} rad off"
                )
                if (
                    unlimited.position_error <= tol_pos
                    and unlimited.rotation_error < best.rotation_error - 1e-6
                ):
                    reason += f" (joint limits bind: without them {unlimited.rotation_error:.3g} rad)"
        return IKResult(best.q, False, best.position_error, best.rotation_error, total, reason)
