"""The set points a run's joints follow at time t: a joint path's trapezoid segments, or a reference
table (with each joint's mode: what its column holds), a hold, and the live inputs changed between
solver calls (a jog, an external controller's current). The drives (drive.py), the operational-space
controller and the planner's checks evaluate them alike.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .trapezoid import trapezoid


# ---- trajectory: trapezoidal speed profiles, one segment per via point -------------------------------
# segment table row: [t0, T, ta, q0[0..n-1], dq[0..n-1]]
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def traj_eval(seg, hold, t, qr, qdr):
    n = qr.shape[0]
    nseg = seg.shape[0]
    if nseg == 0 or t <= seg[0, 0]:
        for j in range(n):
            qr[j] = hold[j] if nseg == 0 else seg[0, 3 + j]
            qdr[j] = 0.0
        return
    k = nseg - 1
    for i in range(nseg):
        if t < seg[i, 0] + seg[i, 1]:
            k = i
            break
    s, sd = trapezoid(seg[k, 1], seg[k, 2], t - seg[k, 0])
    for j in range(n):
        qr[j] = seg[k, 3 + j] + seg[k, 3 + n + j] * s
        qdr[j] = seg[k, 3 + n + j] * sd


# joint modes: what the reference table holds for a joint (models/signals.py writes them)
JM_POSITION, JM_SPEED, JM_CURRENT, JM_HOLD = 0, 1, 2, 3

# live inputs per joint, changed between solver calls (SetPoints.jog, SetPoints.set_actuators):
# the jog (offset at t0, rate, t0) and an external controller's current set point, which replaces
# the built-in cascade of the joint while LV_EXTERNAL is 1 (the drive's current loops stay); and,
# renewed every step (step.gravity_feedforward), the cascade's gravity feed-forward current.
NLIVE = 6
LV_OFFSET, LV_RATE, LV_T0, LV_EXTERNAL, LV_IREF, LV_GRAVITY = range(NLIVE)


class SetPointArrays(NamedTuple):
    """The set points of a run as every kernel reads them (set_points.SetPoints owns the arrays)."""

    seg: np.ndarray  # (segments, 3 + 2n): a joint path's trapezoid segments (rows as in traj_eval)
    hold: np.ndarray  # (n,): the held positions (before a path, and of joints in JM_HOLD)
    tab: np.ndarray  # (rows, 1 + 2n): a sampled reference [t, r, rd]; empty: the segments hold
    jmode: np.ndarray  # (n,) int64: what the table holds per joint (JM_*)
    live: np.ndarray  # (n, NLIVE): the live inputs (LV_*)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def ref_eval(sp, t, qr, qdr):
    """The set points at t: the trapezoid segments when the table is empty, else the table; plus the
    jog offset of each joint not in current mode (live[j, LV_OFFSET..LV_T0]: offset at t0, rate, t0).

    Table rows are [t, r[0..n-1], rd[0..n-1]], linear between the rightmost row at or before t and the
    next (so two rows at one time make a jump); held before the first row and after the last. A joint
    in JM_HOLD keeps its initial set point `hold`."""
    ref_nominal(sp, t, qr, qdr)
    jmode, live = sp.jmode, sp.live
    for j in range(qr.shape[0]):
        if jmode[j] != JM_CURRENT:
            qr[j] += live[j, LV_OFFSET] + live[j, LV_RATE] * (t - live[j, LV_T0])
            qdr[j] += live[j, LV_RATE]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def ref_nominal(sp, t, qr, qdr):
    """The command's set points at t, without the jog (what a jog's range check starts from)."""
    tab, hold, jmode = sp.tab, sp.hold, sp.jmode
    K = tab.shape[0]
    if K == 0:
        traj_eval(sp.seg, hold, t, qr, qdr)
        return
    n = qr.shape[0]
    if t < tab[0, 0]:
        k = 0
        w = 0.0
    else:
        lo = 0
        hi = K - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if tab[mid, 0] <= t:
                lo = mid
            else:
                hi = mid - 1
        k = lo
        w = 0.0 if k >= K - 1 else (t - tab[k, 0]) / (tab[k + 1, 0] - tab[k, 0])
    k1 = k + 1 if k < K - 1 else k
    for j in range(n):
        if jmode[j] == JM_HOLD:
            qr[j] = hold[j]
            qdr[j] = 0.0
        else:
            qr[j] = tab[k, 1 + j] + w * (tab[k1, 1 + j] - tab[k, 1 + j])
            qdr[j] = tab[k, 1 + n + j] + w * (tab[k1, 1 + n + j] - tab[k, 1 + n + j])


def plan_segment(q0, q1, vmax, amax, t0):
    """Synchronised trapezoid for all joints: one acceleration time, one duration, every limit kept."""
    q0 = np.asarray(q0, float)
    dq = np.asarray(q1, float) - q0
    a = np.abs(dq)
    if not np.any(a > 0.0):
        return np.concatenate([[t0, 0.0, 0.0], q0, dq])
    moving = a > 0.0
    ta = 0.0
    for j in np.nonzero(moving)[0]:
        ta = max(ta, min(vmax[j] / amax[j], math.sqrt(a[j] / amax[j])))
    cruise = max(ta, float(np.max(a[moving] / vmax[moving])), float(np.max(a[moving] / (amax[moving] * ta))))
    return np.concatenate([[t0, cruise + ta, ta], q0, dq])
