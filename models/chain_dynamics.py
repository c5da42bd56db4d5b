"""The rigid chain's dynamics and kinematics, compiled: joint frames, the mass matrix, the bias forces
(recursive Newton-Euler: velocity terms and gravity) and the link poses of a serial chain of revolute
z joints in the Link convention, from the arrays `mechanics.chain_arrays` builds.

The drives' in-step load predictor (drive.py) and the result rows use them every step; the tests hold
them against Exudyn and an independent rigid-body library.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit import CACHE as _CACHE
from .jit import FAST as _FAST


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def chain_frames(pre_R, pre_p, q, R_out, p_out):
    """Joint frames after rotation: R_out[i], p_out[i] (world); scalar loops, no allocation (every
    kernel of a step calls it): frame i is frame i - 1 carried by pre_R[i], pre_p[i], turned by q[i]."""
    n = q.shape[0]
    for i in range(n):
        if i == 0:
            for a in range(3):
                p_out[0, a] = pre_p[0, a]
                for b in range(3):
                    R_out[0, a, b] = pre_R[0, a, b]
        else:
            for a in range(3):
                p_out[i, a] = p_out[i - 1, a] + (
                    R_out[i - 1, a, 0] * pre_p[i, 0]
                    + R_out[i - 1, a, 1] * pre_p[i, 1]
                    + R_out[i - 1, a, 2] * pre_p[i, 2]
                )
                for b in range(3):
                    R_out[i, a, b] = (
                        R_out[i - 1, a, 0] * pre_R[i, 0, b]
                        + R_out[i - 1, a, 1] * pre_R[i, 1, b]
                        + R_out[i - 1, a, 2] * pre_R[i, 2, b]
                    )
        c, s = math.cos(q[i]), math.sin(q[i])
        for a in range(3):
            r0 = R_out[i, a, 0]
            r1 = R_out[i, a, 1]
            R_out[i, a, 0] = r0 * c + r1 * s
            R_out[i, a, 1] = -r0 * s + r1 * c


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def chain_state(chain, gravity, q, qd):
    """What a step's kernels start from at the chain state (q, qd): (R_all, p_all, M, bias), the joint
    frames, the mass matrix and the bias forces. `chain`: the link data (mechanics.ChainArrays)."""
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    M = np.empty((n, n))
    bias = np.empty(n)
    chain_frames(chain.pre_R, chain.pre_p, q, R_all, p_all)
    mass_matrix_at(R_all, p_all, chain.masses, chain.coms, chain.inertias, M)
    bias_forces_at(R_all, p_all, chain.masses, chain.coms, chain.inertias, gravity, qd, bias)
    return R_all, p_all, M, bias


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def mass_matrix(chain, q, M):
    """M(q) = sum_k m_k Jv_k^T Jv_k + Jw_k^T I_k Jw_k, for a serial chain of revolute z joints."""
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    chain_frames(chain.pre_R, chain.pre_p, q, R_all, p_all)
    mass_matrix_at(R_all, p_all, chain.masses, chain.coms, chain.inertias, M)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def mass_matrix_at(R_all, p_all, masses, coms, inertias, M):
    """`mass_matrix` from the joint frames of `chain_frames` (computed once per step by the drives)."""
    n = masses.shape[0]
    for a in range(n):
        for b in range(n):
            M[a, b] = 0.0
    Jv = np.empty((n, 3))
    ck = np.empty(3)
    T = np.empty((3, 3))
    Iw = np.empty((3, 3))
    Iz = np.empty(3)
    for k in range(n):
        for a in range(3):
            ck[a] = p_all[k, a]
            for b in range(3):
                ck[a] += R_all[k, a, b] * coms[k, b]
        # Iw = R I R^T
        for a in range(3):
            for b in range(3):
                T[a, b] = (
                    R_all[k, a, 0] * inertias[k, 0, b]
                    + R_all[k, a, 1] * inertias[k, 1, b]
                    + (R_all[k, a, 2] * inertias[k, 2, b])
                )
        for a in range(3):
            for b in range(3):
                Iw[a, b] = T[a, 0] * R_all[k, b, 0] + T[a, 1] * R_all[k, b, 1] + T[a, 2] * R_all[k, b, 2]
        for i in range(k + 1):
            r0 = ck[0] - p_all[i, 0]
            r1 = ck[1] - p_all[i, 1]
            r2 = ck[2] - p_all[i, 2]
            z0, z1, z2 = R_all[i, 0, 2], R_all[i, 1, 2], R_all[i, 2, 2]
            Jv[i, 0] = z1 * r2 - z2 * r1
            Jv[i, 1] = z2 * r0 - z0 * r2
            Jv[i, 2] = z0 * r1 - z1 * r0
        mk = masses[k]
        for i in range(k + 1):
            for a in range(3):
                Iz[a] = Iw[a, 0] * R_all[i, 0, 2] + Iw[a, 1] * R_all[i, 1, 2] + Iw[a, 2] * R_all[i, 2, 2]
            for j in range(i, k + 1):
                v = mk * (Jv[i, 0] * Jv[j, 0] + Jv[i, 1] * Jv[j, 1] + Jv[i, 2] * Jv[j, 2])
                v += R_all[j, 0, 2] * Iz[0] + R_all[j, 1, 2] * Iz[1] + R_all[j, 2, 2] * Iz[2]
                M[i, j] += v
    for i in range(n):
        for j in range(i):
            M[i, j] = M[j, i]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def bias_forces(chain, gravity, q, qd, out):
    """out = C(q, qd) qd + g(q): the joint torques that hold the chain at zero acceleration (recursive
    Newton-Euler in world axes, the base accelerated by -gravity). With the mass matrix they give the
    chain's forward dynamics: M qdd = tau - out."""
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    chain_frames(chain.pre_R, chain.pre_p, q, R_all, p_all)
    bias_forces_at(R_all, p_all, chain.masses, chain.coms, chain.inertias, gravity, qd, out)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def gravity_torques(chain, gravity, q, out):
    """out = g(q): the joint torques that hold the chain still at q against gravity (the bias forces
    at rest); what a controller feeds forward and what the drives must give to hold a pose."""
    bias_forces(chain, gravity, q, np.zeros(q.shape[0]), out)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def bias_forces_at(R_all, p_all, masses, coms, inertias, gravity, qd, out):
    """`bias_forces` from the joint frames of `chain_frames`."""
    n = qd.shape[0]
    w = np.zeros(3)
    wd = np.zeros(3)
    a_o = np.empty(3)
    for a in range(3):
        a_o[a] = -gravity[a]
    F = np.empty((n, 3))
    N = np.empty((n, 3))
    r = np.empty((n, 3))
    zq = np.empty(3)
    t1 = np.empty(3)
    t2 = np.empty(3)
    Iw = np.empty(3)
    for i in range(n):
        if i > 0:  # the joint's origin rides on the previous link
            for a in range(3):
                zq[a] = p_all[i, a] - p_all[i - 1, a]
            _cross(wd, zq, t1)
            _cross(w, zq, t2)
            _cross(w, t2, zq)
            for a in range(3):
                a_o[a] += t1[a] + zq[a]
        for a in range(3):
            zq[a] = R_all[i, a, 2] * qd[i]
        _cross(w, zq, t1)
        for a in range(3):
            wd[a] += t1[a]
            w[a] += zq[a]
        for a in range(3):
            r[i, a] = R_all[i, a, 0] * coms[i, 0] + R_all[i, a, 1] * coms[i, 1] + R_all[i, a, 2] * coms[i, 2]
        _cross(wd, r[i], t1)
        _cross(w, r[i], t2)
        _cross(w, t2, zq)
        for a in range(3):
            F[i, a] = masses[i] * (a_o[a] + t1[a] + zq[a])
        # N = Iw wd + w x (Iw w), Iw = R I R^T applied as R (I (R^T v))
        for v_is_w in range(2):
            v = w if v_is_w else wd
            for a in range(3):
                t1[a] = R_all[i, 0, a] * v[0] + R_all[i, 1, a] * v[1] + R_all[i, 2, a] * v[2]
            for a in range(3):
                t2[a] = inertias[i, a, 0] * t1[0] + inertias[i, a, 1] * t1[1] + inertias[i, a, 2] * t1[2]
            for a in range(3):
                Iw[a] = R_all[i, a, 0] * t2[0] + R_all[i, a, 1] * t2[1] + R_all[i, a, 2] * t2[2]
            if v_is_w:
                _cross(w, Iw, t1)
                for a in range(3):
                    N[i, a] += t1[a]
            else:
                for a in range(3):
                    N[i, a] = Iw[a]
    f = np.zeros(3)
    m_next = np.zeros(3)  # moment about the next joint's origin
    for i in range(n - 1, -1, -1):
        _cross(r[i], F[i], t1)
        if i < n - 1:
            for a in range(3):
                zq[a] = p_all[i + 1, a] - p_all[i, a]
            _cross(zq, f, t2)
        else:
            t2[:] = 0.0
        for a in range(3):
            m_next[a] += N[i, a] + t1[a] + t2[a]
            f[a] += F[i, a]
        out[i] = R_all[i, 0, 2] * m_next[0] + R_all[i, 1, 2] * m_next[1] + R_all[i, 2, 2] * m_next[2]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def quats_from_matrices(Rs, out):
    """Unit quaternions (w, x, y, z), w >= 0, of rotation matrices Rs[k] into out[k]."""
    for k in range(Rs.shape[0]):
        m = Rs[k]
        t = m[0, 0] + m[1, 1] + m[2, 2]
        if t > 0:
            s = math.sqrt(t + 1.0) * 2
            w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
            w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
        elif m[1, 1] > m[2, 2]:
            s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
            w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
        else:
            s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
            w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
        nrm = math.sqrt(w * w + x * x + y * y + z * z)
        if w < 0:
            nrm = -nrm
        out[k, 0] = w / nrm
        out[k, 1] = x / nrm
        out[k, 2] = y / nrm
        out[k, 3] = z / nrm


# ---- drive right-hand side -------------------------------------------------------------------------


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def pose_rows(pre_R, pre_p, Rrpy, tool_local, q, out):
    """World poses (x, y, z, qw, qx, qy, qz) of every link frame, then of the tool: out[n + 1, 7].

    The chain of `chain_frames` (the one handed to Exudyn as joint transforms): link frame i = joint
    frame i after its rotation q_i, times the link's initial rotation Rrpy[i]; the tool sits at
    `tool_local` (joint frame n-1 coordinates) and takes the last link's orientation.
    """
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    chain_frames(pre_R, pre_p, q, R_all, p_all)
    pose_rows_at(R_all, p_all, Rrpy, tool_local, out)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def pose_rows_at(R_all, p_all, Rrpy, tool_local, out):
    """`pose_rows` from the joint frames of `chain_frames` (the result rows have them already)."""
    n = R_all.shape[0]
    Rs = np.empty((n + 1, 3, 3))
    for i in range(n):
        for a in range(3):
            out[i, a] = p_all[i, a]
            for b in range(3):
                Rs[i, a, b] = (
                    R_all[i, a, 0] * Rrpy[i, 0, b]
                    + R_all[i, a, 1] * Rrpy[i, 1, b]
                    + R_all[i, a, 2] * Rrpy[i, 2, b]
                )
    for a in range(3):
        out[n, a] = p_all[n - 1, a] + (
            R_all[n - 1, a, 0] * tool_local[0]
            + R_all[n - 1, a, 1] * tool_local[1]
            + R_all[n - 1, a, 2] * tool_local[2]
        )
        for b in range(3):
            Rs[n, a, b] = Rs[n - 1, a, b]
    quats = np.empty((n + 1, 4))
    quats_from_matrices(Rs, quats)
    for i in range(n + 1):
        for c in range(4):
            out[i, 3 + c] = quats[i, c]
