"""The compiled inverse-kinematics solver (ik.py's `ArmKinematics` calls it, one call per attempt).

`solve_kernel`, compiled with numba like drive.py:

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
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .chain_kinematics import (
    cholesky,
    cholesky_solve,
    gram_of_free,
    rotation_vector,
    tool_frames,
    tool_jacobian,
)
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST

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
def solve_kernel(
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
            gram_of_free(Je, free, A)
            for a in range(6):
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
def cost_grad(pre_R, pre_p, R_last, tool_local, p_t, R_t, w_pos, w_rot, q, grad):
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
def tool_positions_of(pre_R, pre_p, R_last, tool_local, qs, out):
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
