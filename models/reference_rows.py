"""A motion as the rows of a sampled reference table (references.ref_eval interpolates linearly between
them), spaced by accuracy rather than by time: a joint trapezoid sampled where it curves, and a
Cartesian `lin` move timed by a path-velocity profile along its joint curve (the fastest that keeps
the Cartesian maxima and every joint's speed and acceleration limits; planner.py walks the curve);
and `ReferenceTable`, the table a command's moves are appended to, with the world they happen in.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from simecs.mesh.protocol.environment import Obstacle

from . import references
from .errors import CommandError
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .line_walk import LineWalk
from .plan import World
from .trapezoid import trapezoid_samples

#: s: the closest two rows of a sampled reference may be (where a move curves fast; slow or straight
#: stretches take fewer rows, spaced by accuracy).
REFERENCE_PERIOD = 1e-3
#: Largest distance (m) and angle (rad) between the planned pose of a `lin` move and its line, at any
#: row of the reference and between two rows (the linear interpolation of references.ref_eval).
LIN_TOLERANCE = 1e-6
#: How far (m, or rad) along its path a sampled reference's linear interpolation may lag or lead its
#: speed profile where that accelerates: a timing error, not a path error (it sets how many rows an
#: acceleration takes; the drives follow the set points to a fraction of a millimetre at best).
PROFILE_LAG = 1e-5


def trapezoid_times(T: float, ta: float, motion: float) -> np.ndarray:
    """Sample times of a trapezoid: its corners where it is straight and, where it curves, as many as
    keep the linear interpolation between them within PROFILE_LAG of it for a point `motion` m
    away at the end (a slow acceleration takes few), at most one every REFERENCE_PERIOD."""
    k_acc = math.ceil(ta / REFERENCE_PERIOD)
    if 0.0 < ta < T:  # s'' = 1 / ((T - ta) ta); the chord of s'' t^2 / 2 over dt is off by s'' dt^2 / 8
        k_acc = min(k_acc, math.ceil(ta * math.sqrt(motion / ((T - ta) * ta) / (8.0 * PROFILE_LAG))))
    acc = np.linspace(0.0, ta, max(1, k_acc) + 1)
    return np.unique(np.concatenate([acc, T - acc]))


def line_rows(
    walk: LineWalk,
    lower: np.ndarray,
    upper: np.ndarray,
    vmax: np.ndarray,
    amax: np.ndarray,
    vs: float,
    as_: float,
    along: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(times, joint positions, joint speeds, the duration the Cartesian maxima asked for) of the rows
    of a walked line: the fastest profile of the line parameter s that starts and ends at rest, keeps
    `vs` and `as_` (the Cartesian maxima times the node's percentages, per unit s) and every joint's
    `vmax` and `amax`. Where no joint limit binds it is exactly the Cartesian trapezoid (its corners
    are points of the grid); where one does the tool slows there, and only there.

    The grid cuts each knot segment so that the joint-space chord of a piece stays within half
    LIN_TOLERANCE of the curve (its error falls with the square of its length), the curve being within
    the other half of the line: the rows references.ref_eval interpolates linearly. `along` (line
    parameter) bounds how far that interpolation may lag the profile where it accelerates."""
    ta = min(vs / as_, math.sqrt(1.0 / as_))
    asked = max(ta, 1.0 / vs, 1.0 / (as_ * ta)) + ta
    tab, over = _line_table(
        walk.s,
        walk.q,
        walk.dq,
        walk.chord,
        LIN_TOLERANCE / 2,
        0.5 * as_ * ta * ta,
        lower,
        upper,
        vmax,
        amax,
        vs,
        as_,
        along,
        REFERENCE_PERIOD,
    )
    n = walk.q.shape[1]
    t, qs, qds = tab[:, 0], tab[:, 1 : 1 + n], tab[:, 1 + n :]
    if over > 1.0:  # the profile keeps the joint speeds at the grid's points; between them a hair more
        t, qds = t * over, qds / over
    return t, qs, qds, asked


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _line_table(S, Q, D, chord, tol, s_acc, lower, upper, vmax, amax, vs, as_, along, period):
    """_line_grid, _path_profile and _profile_rows in one call (one array back to Python): the rows
    [t, q, qd] and the largest joint speed over its vmax among them."""
    grid = _line_grid(S, chord, tol, s_acc)
    u = _path_profile(S, Q, D, grid, vmax, amax, vs, as_)
    return _profile_rows(S, Q, D, grid, u, lower, upper, vmax, along, period)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _line_grid(S, chord, tol, s_acc):
    """The points of the line parameter the profile and the rows use: each knot segment cut into
    ceil(sqrt(chord / tol)) equal pieces (a chord's error falls with the square of its length), the
    trapezoid's corners s_acc and 1 - s_acc and the middle (so at least three points), sorted, none
    within 1e-12 of another."""
    K = S.shape[0]
    pieces = np.empty(K - 1, dtype=np.int64)
    total = 4
    for k in range(K - 1):
        pieces[k] = max(1, math.ceil(math.sqrt(max(chord[k, 0], chord[k, 1]) / tol)))
        total += pieces[k]
    g = np.empty(total)
    i = 0
    for k in range(K - 1):
        for r in range(pieces[k]):
            g[i] = S[k] + (S[k + 1] - S[k]) * r / pieces[k]
            i += 1
    g[i], g[i + 1], g[i + 2], g[i + 3] = 1.0, 0.5, s_acc, 1.0 - s_acc
    g = np.sort(g)
    keep = 1
    for i in range(1, total):
        if g[i] > g[keep - 1] + 1e-12:
            g[keep] = g[i]
            keep += 1
    g[0] = 0.0
    g[keep - 1] = 1.0
    return g[:keep].copy()


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _hermite(S, Q, D, k, s, q, dq, ddq):
    """The cubic Hermite curve through knots k and k + 1 (positions Q, slopes D) at s: q, dq/ds and
    d2q/ds2."""
    h = S[k + 1] - S[k]
    t = (s - S[k]) / h
    t2 = t * t
    t3 = t2 * t
    a0, a1, b0, b1 = 2.0 * t3 - 3.0 * t2 + 1.0, -2.0 * t3 + 3.0 * t2, t3 - 2.0 * t2 + t, t3 - t2
    da0, db0, db1 = 6.0 * t2 - 6.0 * t, 3.0 * t2 - 4.0 * t + 1.0, 3.0 * t2 - 2.0 * t
    dda0, ddb0, ddb1 = 12.0 * t - 6.0, 6.0 * t - 4.0, 6.0 * t - 2.0
    for j in range(q.shape[0]):
        x0, x1, m0, m1 = Q[k, j], Q[k + 1, j], D[k, j], D[k + 1, j]
        q[j] = a0 * x0 + a1 * x1 + h * (b0 * m0 + b1 * m1)
        dq[j] = da0 * (x0 - x1) / h + db0 * m0 + db1 * m1
        ddq[j] = dda0 * (x0 - x1) / (h * h) + (ddb0 * m0 + ddb1 * m1) / h


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _path_profile(S, Q, D, grid, vmax, amax, vs, as_):
    """u = (ds/dt)^2 at each grid point: the fastest profile from rest to rest with |s''| <= as_,
    ds/dt <= vs, and per joint |q'| ds/dt <= vmax and |q'| |s''| + |q''| (ds/dt)^2 <= amax (q' = dq/ds
    of the Hermite curve; its second term bounds the joint acceleration whatever the signs). s'' is
    constant between two grid points, each bound checked at both: a forward pass accelerates as
    hard as it allows, a backward pass brakes as hard as it allows."""
    N = grid.shape[0]
    n = Q.shape[1]
    K = S.shape[0]
    b = np.empty((N, n))
    c = np.empty((N, n))
    top = np.empty(N)
    q = np.empty(n)
    dq = np.empty(n)
    ddq = np.empty(n)
    k = 0
    for i in range(N):
        s = grid[i]
        while k < K - 2 and s > S[k + 1]:
            k += 1
        _hermite(S, Q, D, k, s, q, dq, ddq)
        for j in range(n):
            b[i, j] = abs(dq[j])
            c[i, j] = abs(ddq[j])
        if k < K - 2 and s == S[k + 1]:  # an inner knot: the curvature on both sides
            _hermite(S, Q, D, k + 1, s, q, dq, ddq)
            for j in range(n):
                c[i, j] = max(c[i, j], abs(ddq[j]))
        x = vs * vs
        for j in range(n):
            if b[i, j] * b[i, j] * x > vmax[j] * vmax[j]:
                x = (vmax[j] / b[i, j]) ** 2
            if c[i, j] * x > amax[j]:
                x = amax[j] / c[i, j]
        top[i] = x
    u = np.zeros(N)
    for i in range(N - 1):
        d2 = 2.0 * (grid[i + 1] - grid[i])
        g = as_
        for j in range(n):
            if b[i, j] > 0.0:
                g = min(g, (amax[j] - c[i, j] * u[i]) / b[i, j])
        x = min(top[i + 1], u[i] + d2 * max(g, 0.0))
        for j in range(n):
            if b[i + 1, j] > 0.0:
                x = min(x, (u[i] + d2 * amax[j] / b[i + 1, j]) / (1.0 + d2 * c[i + 1, j] / b[i + 1, j]))
        u[i + 1] = x
    u[N - 1] = 0.0
    for i in range(N - 2, -1, -1):
        d2 = 2.0 * (grid[i + 1] - grid[i])
        g = as_
        for j in range(n):
            if b[i + 1, j] > 0.0:
                g = min(g, (amax[j] - c[i + 1, j] * u[i + 1]) / b[i + 1, j])
        x = min(u[i], u[i + 1] + d2 * max(g, 0.0))
        for j in range(n):
            if b[i, j] > 0.0:
                x = min(x, (u[i + 1] + d2 * amax[j] / b[i, j]) / (1.0 + d2 * c[i, j] / b[i, j]))
        u[i] = x
    return u


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _profile_rows(S, Q, D, grid, u, lower, upper, vmax, along, period):
    """The rows [t, q, qd] of the profile u on the grid: each grid point, and where s'' is not 0 as
    many more as keep the linear interpolation of s(t) within `along` of it (at most one per
    `period`); q on the Hermite curve, qd = q' ds/dt. Also the largest joint speed over its vmax, of
    the rows and of the chords between them."""
    N = grid.shape[0]
    n = Q.shape[1]
    K = S.shape[0]
    dt = np.empty(N - 1)
    pieces = np.empty(N - 1, dtype=np.int64)
    total = 1
    for i in range(N - 1):
        d = grid[i + 1] - grid[i]
        dt[i] = 2.0 * d / (math.sqrt(u[i]) + math.sqrt(u[i + 1]))
        sdd = abs(u[i + 1] - u[i]) / (2.0 * d)
        p = math.ceil(dt[i] * math.sqrt(sdd / (8.0 * along)))
        pieces[i] = max(1, min(p, math.floor(dt[i] / period)))
        total += pieces[i]
    tab = np.empty((total, 1 + 2 * n))
    t = tab[:, 0]
    qs = tab[:, 1 : 1 + n]
    qds = tab[:, 1 + n :]
    q = np.empty(n)
    dq = np.empty(n)
    ddq = np.empty(n)
    row = 0
    k = 0
    now = 0.0
    for i in range(N - 1):
        v0 = math.sqrt(u[i])
        sdd = (u[i + 1] - u[i]) / (2.0 * (grid[i + 1] - grid[i]))
        for r in range(pieces[i]):
            tau = dt[i] * r / pieces[i]
            s = min(max(grid[i] + v0 * tau + 0.5 * sdd * tau * tau, grid[i]), grid[i + 1])
            while k < K - 2 and s > S[k + 1]:
                k += 1
            _hermite(S, Q, D, k, s, q, dq, ddq)
            sd = v0 + sdd * tau
            t[row] = now + tau
            for j in range(n):
                qs[row, j] = min(max(q[j], lower[j]), upper[j])
                qds[row, j] = dq[j] * sd
            row += 1
        now += dt[i]
    t[row] = now
    for j in range(n):
        qs[row, j] = Q[K - 1, j]
        qds[row, j] = 0.0
    over = 0.0
    for r in range(total):
        for j in range(n):
            over = max(over, abs(qds[r, j]) / vmax[j])
            if r > 0:
                over = max(over, abs(qs[r, j] - qs[r - 1, j]) / (t[r] - t[r - 1]) / vmax[j])
    return tab, over


class ReferenceTable:
    """A reference table being built move by move: rows [t, q, qd], the set point moving on, and the
    world the arm moves in (objects grasped and released on the way)."""

    def __init__(self, q0: np.ndarray, max_rows: int, obstacles: Sequence[Obstacle], reach: float) -> None:
        """`reach`: the farthest a point of the arm is from its base (how far a joint turn moves it)."""
        self.n = q0.shape[0]
        self.reach = reach
        self.t = 0.0
        self.q = q0.copy()
        self.max_rows = max_rows
        self.blocks: list[np.ndarray] = [np.concatenate([[0.0], q0, np.zeros(self.n)])[None, :]]
        self.rows = 1
        self.events: list[tuple[float, dict[str, float]]] = []
        self.grasps: list[tuple[float, str]] = []
        self.worlds = [World(0.0, list(obstacles))]

    @property
    def world(self) -> World:
        return self.worlds[-1]

    def add(self, path: str, times: np.ndarray, qs: np.ndarray, qds: np.ndarray) -> None:
        """Rows at times after the current end (the first sample, the current one, is left out)."""
        block = np.column_stack([self.t + times[1:], qs[1:], qds[1:]])
        self.rows += block.shape[0]
        if self.rows > self.max_rows:
            raise CommandError(
                path,
                f"the command expands to more than {self.max_rows:,} reference samples "
                f"(reference_samples): split it or make its moves shorter",
            )
        self.blocks.append(block)
        self.t += float(times[-1])
        self.q = qs[-1].copy()

    def joint_move(self, path: str, dest: np.ndarray, vmax: np.ndarray, amax: np.ndarray) -> None:
        row = references.plan_segment(self.q, dest, vmax, amax, 0.0)
        T, ta = float(row[1]), float(row[2])
        if T <= 0.0:
            return
        times = trapezoid_times(T, ta, self.reach * float(np.sum(np.abs(dest - self.q))))
        s, sd = trapezoid_samples(T, ta, times)
        dq = dest - self.q
        self.add(path, times, self.q + s[:, None] * dq, sd[:, None] * dq)
        self.q = dest.copy()

    def hold(self, path: str, duration: float) -> None:
        if duration > 0.0:
            qs = np.vstack([self.q, self.q])
            self.add(path, np.array([0.0, duration]), qs, np.zeros_like(qs))

    def table(self) -> np.ndarray:
        return np.vstack(self.blocks)
