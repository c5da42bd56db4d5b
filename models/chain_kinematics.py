"""The tool's pose, Jacobian and orientation error of a serial chain, compiled: shared by inverse
kinematics (ik.py), the operational-space controller (opspace.py) and the result rows' task-space
reference (drive.py), so the three agree on what "the tool" is; and the small Cholesky solves the
first two use (allocation-free loops: they run every control period).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .chain_dynamics import chain_frames
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def tool_frames(pre_R, pre_p, R_last, tool_local, q, R_all, p_all, p, R):
    """Joint frames (R_all, p_all) and the tool pose (p, R), as `chain_dynamics.pose_rows` row n
    computes them."""
    chain_frames(pre_R, pre_p, q, R_all, p_all)
    tool_pose_at(R_all, p_all, R_last, tool_local, p, R)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def tool_pose_at(R_all, p_all, R_last, tool_local, p, R):
    """The tool pose (p, R) from the joint frames of `chain_frames` (computed once per step)."""
    k = R_all.shape[0] - 1
    for a in range(3):
        p[a] = p_all[k, a] + (
            R_all[k, a, 0] * tool_local[0] + R_all[k, a, 1] * tool_local[1] + R_all[k, a, 2] * tool_local[2]
        )
        for b in range(3):
            R[a, b] = (
                R_all[k, a, 0] * R_last[0, b] + R_all[k, a, 1] * R_last[1, b] + R_all[k, a, 2] * R_last[2, b]
            )


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def tool_jacobian(R_all, p_all, p, J):
    """Geometric Jacobian (6, n) of the tool point p: rows 0-2 z_i x (p - o_i), rows 3-5 z_i (world)."""
    n = R_all.shape[0]
    for i in range(n):
        z0, z1, z2 = R_all[i, 0, 2], R_all[i, 1, 2], R_all[i, 2, 2]
        r0 = p[0] - p_all[i, 0]
        r1 = p[1] - p_all[i, 1]
        r2 = p[2] - p_all[i, 2]
        J[0, i] = z1 * r2 - z2 * r1
        J[1, i] = z2 * r0 - z0 * r2
        J[2, i] = z0 * r1 - z1 * r0
        J[3, i] = z0
        J[4, i] = z1
        J[5, i] = z2


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def tool_jdot_qd(R_all, p_all, p, qd, out):
    """out = Jdot qd (6): the tool's acceleration (linear, angular; world) when qdd = 0, in closed form
    from the frames: column i of J is (z_i x (p - o_i), z_i), with z_i' = w_i x z_i, o_i' the speed of
    joint i's origin and p' = J_v qd the tool's."""
    n = qd.shape[0]
    v0 = v1 = v2 = 0.0  # the tool point's speed
    for i in range(n):
        z0, z1, z2 = R_all[i, 0, 2], R_all[i, 1, 2], R_all[i, 2, 2]
        r0 = p[0] - p_all[i, 0]
        r1 = p[1] - p_all[i, 1]
        r2 = p[2] - p_all[i, 2]
        v0 += (z1 * r2 - z2 * r1) * qd[i]
        v1 += (z2 * r0 - z0 * r2) * qd[i]
        v2 += (z0 * r1 - z1 * r0) * qd[i]
    for a in range(6):
        out[a] = 0.0
    w0 = w1 = w2 = 0.0  # the angular speed of the link before joint i
    o0 = o1 = o2 = 0.0  # the speed of joint i's origin
    for i in range(n):
        if i > 0:  # joint i's origin rides on link i - 1
            d0 = p_all[i, 0] - p_all[i - 1, 0]
            d1 = p_all[i, 1] - p_all[i - 1, 1]
            d2 = p_all[i, 2] - p_all[i - 1, 2]
            o0 += w1 * d2 - w2 * d1
            o1 += w2 * d0 - w0 * d2
            o2 += w0 * d1 - w1 * d0
        z0, z1, z2 = R_all[i, 0, 2], R_all[i, 1, 2], R_all[i, 2, 2]
        zd0 = w1 * z2 - w2 * z1  # z_i' = w x z_i
        zd1 = w2 * z0 - w0 * z2
        zd2 = w0 * z1 - w1 * z0
        r0 = p[0] - p_all[i, 0]
        r1 = p[1] - p_all[i, 1]
        r2 = p[2] - p_all[i, 2]
        u0 = v0 - o0
        u1 = v1 - o1
        u2 = v2 - o2
        qi = qd[i]
        out[0] += qi * ((zd1 * r2 - zd2 * r1) + (z1 * u2 - z2 * u1))
        out[1] += qi * ((zd2 * r0 - zd0 * r2) + (z2 * u0 - z0 * u2))
        out[2] += qi * ((zd0 * r1 - zd1 * r0) + (z0 * u1 - z1 * u0))
        out[3] += qi * zd0
        out[4] += qi * zd1
        out[5] += qi * zd2
        w0 += z0 * qi
        w1 += z1 * qi
        w2 += z2 * qi


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def rotation_vector(R_now, R_t, e):
    """e = log(R_t R_now^T): the rotation vector (world frame) that turns R_now into R_t; returns |e|.

    Near pi the axis comes from the symmetric part of the relative rotation (the antisymmetric part
    vanishes there), its sign from the antisymmetric part."""
    M = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            M[a, b] = R_t[a, 0] * R_now[b, 0] + R_t[a, 1] * R_now[b, 1] + R_t[a, 2] * R_now[b, 2]
    c = 0.5 * (M[0, 0] + M[1, 1] + M[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    v0 = 0.5 * (M[2, 1] - M[1, 2])
    v1 = 0.5 * (M[0, 2] - M[2, 0])
    v2 = 0.5 * (M[1, 0] - M[0, 1])
    s = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    theta = math.atan2(s, c)
    if c > -0.9:
        f = 1.0 + theta * theta / 6.0 if s < 1e-6 else theta / s
        e[0] = f * v0
        e[1] = f * v1
        e[2] = f * v2
        return theta
    # near pi: (M + M^T)/2 = c I + (1 - c) a a^T
    k = 0
    for i in range(1, 3):
        if M[i, i] > M[k, k]:
            k = i
    ak = math.sqrt(max((M[k, k] - c) / (1.0 - c), 0.0))
    ax = np.empty(3)
    for i in range(3):
        if i == k:
            ax[i] = ak
        else:
            ax[i] = 0.5 * (M[i, k] + M[k, i]) / ((1.0 - c) * ak)
    nrm = math.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2])
    sg = 1.0 if ax[0] * v0 + ax[1] * v1 + ax[2] * v2 >= 0.0 else -1.0
    for i in range(3):
        e[i] = sg * theta * ax[i] / nrm
    return theta


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def gram_of_free(J, free, G):
    """G = J_f J_f^T (6 x 6), J_f the columns of J that `free` marks: the normal matrix of a step that
    leaves the other joints where they are (at their limits)."""
    n = J.shape[1]
    for a in range(6):
        for b in range(a + 1):
            s = 0.0
            for j in range(n):
                if free[j]:
                    s += J[a, j] * J[b, j]
            G[a, b] = s
            G[b, a] = s


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def cholesky(A, lam, L):
    """Cholesky factor L of A + lam I; A (m, m) symmetric positive semi-definite (definite with lam = 0)."""
    m = A.shape[0]
    for i in range(m):
        for j in range(i + 1):
            s = A[i, j]
            if i == j:
                s += lam
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(max(s, 1e-300))
            else:
                L[i, j] = s / L[j, j]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def cholesky_solve(L, b, x):
    """x = (L L^T)^-1 b."""
    m = L.shape[0]
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(m - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, m):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def spd_inverse(A):
    """A^-1 of a symmetric positive definite A through its Cholesky factor: no LAPACK call (the drives
    invert the mass matrix every step)."""
    m = A.shape[0]
    factors = np.empty((2, m, m))
    L, Ainv = factors[0], factors[1]
    cholesky(A, 0.0, L)
    for c in range(m):  # column c: solve L y = e_c, then L^T x = y
        for i in range(m):
            s = 1.0 if i == c else 0.0
            for k in range(c, i):
                s -= L[i, k] * Ainv[k, c]
            Ainv[i, c] = s / L[i, i] if i >= c else 0.0
        for i in range(m - 1, -1, -1):
            s = Ainv[i, c]
            for k in range(i + 1, m):
                s -= L[k, i] * Ainv[k, c]
            Ainv[i, c] = s / L[i, i]
    return Ainv


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def rotvec_exp(r, R0, R):
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
