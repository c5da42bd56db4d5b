"""The trapezoidal speed profile of a joint-path segment: the drives' set points follow it in the run
(references.traj_eval) and the planner samples it (the path check, the preview), so both use this one."""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit import CACHE as _CACHE
from .jit import FAST as _FAST


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def trapezoid(T, ta, tau):
    """(s, ds/dt) at time tau of a profile from s = 0 to 1 in T s, accelerating and braking for ta s
    each at constant rate (0 < ta <= T / 2); before 0 and after T it rests."""
    if tau <= 0.0:
        return 0.0, 0.0
    if tau >= T:
        return 1.0, 0.0
    v = 1.0 / (T - ta)
    if tau < ta:
        return 0.5 * v / ta * tau * tau, v * tau / ta
    if tau < T - ta:
        return v * (tau - 0.5 * ta), v
    tr = T - tau
    return 1.0 - 0.5 * v / ta * tr * tr, v * tr / ta


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _samples(T, ta, tau, s, sd):
    for k in range(tau.shape[0]):
        s[k], sd[k] = trapezoid(T, ta, tau[k])


def trapezoid_samples(T: float, ta: float, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`trapezoid` at each of the times tau."""
    tau = np.ascontiguousarray(tau, dtype=float)
    s, sd = np.empty_like(tau), np.empty_like(tau)
    _samples(float(T), float(ta), tau, s, sd)
    return s, sd
