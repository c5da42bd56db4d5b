"""A robot command of any level (paper §2.1) turned into what the drives follow, checked before a run.

A joint path stays a table of trapezoid segments (drive.traj_eval, exact). Every other level becomes a
sampled reference table (drive.ref_eval, linear between rows): a Cartesian `lin` move is planned in
geometry first and in time second. Its joint solutions are found along the line at a spacing its
accuracy needs (ArmKinematics.walk_line: a cubic Hermite curve through them stays within
LIN_TOLERANCE of the line), whatever its speed; then a path-velocity profile moves along that curve
as fast as the Cartesian maxima times the node's percentages allow, slowed where a joint's
traj.max_speed or traj.max_acc would be exceeded (`slowed` says by how much); the rows are that
curve at the times the profile gives, as many as keep the linear interpolation between them within
LIN_TOLERANCE of the line and within PROFILE_LAG of the profile. So the cost of a line grows with its
geometry, not with its duration. Joint moves (a `ptp` node, move_joints, home) are their trapezoids
sampled where they curve; direct inputs are expanded by signals.py. Actions, tasks and missions expand
into those lower levels; the payload changes of set_payload and the grasps and releases become events
of the run.

Everything that can be known before the run is checked here, so a command the arm cannot carry out
is refused as a whole before anything runs, naming the field inside the command (CommandError).
The proxy plans to check a command; the simulator plans again to run it (same code, same result).
"""

from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit
from simecs.mesh import messages as m
from simecs.mesh import scene_state
from simecs.mesh.codec import DecodeError
from simecs.mesh.environment import Obstacle, grasp_problem
from simecs.mesh.kinematics import rot_rpy, rpy_of
from simecs.mesh.limits import limit
from simecs.mesh.model import check_joints
from simecs.mesh.robot_commands import ACTION_ARGS, NAME_ARG

from . import contact, contact_geometry, grasp, signals
from . import drive as dr
from .chain_dynamics import chain_frames, gravity_torques
from .description import ArmDescription
from .errors import CommandError
from .ik import (
    LINE_JUMP,
    LINE_KNOTS,
    LINE_SINGULAR,
    ArmKinematics,
    IKResult,
    LineWalk,
    orientation_error,
    turned,
)
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .mechanics import chain_arrays, drive_array, gravity_of, holding_capacity
from .self_collision import SelfCollision
from .trapezoid import trapezoid_samples

#: s: the closest two rows of a sampled reference may be (where a move curves fast; slow or straight
#: stretches take fewer rows, spaced by accuracy).
REFERENCE_PERIOD = 1e-3
#: Smallest singular value of the 6 x n tool Jacobian a `lin` move may pass through.
SINGULAR_SIGMA = 1e-3
#: Largest distance (m) and angle (rad) between the planned pose of a `lin` move and its line, at any
#: row of the reference and between two rows (the linear interpolation of drive.ref_eval).
LIN_TOLERANCE = 1e-6
#: How far (m, or rad) along its path a sampled reference's linear interpolation may lag or lead its
#: speed profile where that accelerates: a timing error, not a path error (it sets how many rows an
#: acceleration takes; the drives follow the set points to a fraction of a millimetre at best).
PROFILE_LAG = 1e-5
#: Largest distance (m) and turn (rad) between two joint solutions of a `lin` move (closer where the
#: accuracy needs it).
LIN_KNOT_STEP = 0.05
LIN_KNOT_TURN = 0.1
#: Most joint solutions one `lin` move may take (a line that needs more passes too close to a
#: singularity to be followed).
LIN_MAX_KNOTS = 4096
#: Points of the planned tool path returned to clients.
TOOL_PATH_POINTS = 1000
#: s between the set points a path is checked at against the obstacles (before a run): at 1 m/s a
#: sphere moves 2 mm between two, a fifth of the thinnest one.
PATH_CHECK_PERIOD = 2e-3
#: s between the poses whose gravity load the hold check weighs, and rad the joints may turn together
#: between two of them (gravity changes slowly along a path)
HOLD_CHECK_PERIOD = 0.02
HOLD_CHECK_STEP = 0.02
#: m: how far a point of the arm may move between two of those checks of a reference table (whose
#: rows may be far apart in time on a slow move): the same 2 mm.
PATH_CHECK_STEP = 2e-3


@dataclass
class PlanStep:
    path: str  # where the step sits in the command: nodes[2], tasks[1].actions[0], action, signals
    what: str  # joint, lin, ptp, a primitive, open_loop / closed_loop
    start: float
    end: float
    task: str = ""
    action: str = ""
    q_end: list[float] = field(default_factory=list)  # the joint set points when it ends ([]: not known)
    slowed: float = 1.0  # its duration over the one its Cartesian percentages asked (joint limits)


@dataclass
class World:
    """What the arm can touch from time `t` on: the obstacles where they are (a released object where
    the tool left it) and the object the tool holds."""

    t: float
    obstacles: list[Obstacle]
    held: grasp.Held | None = None


@dataclass
class Plan:
    """What a run follows: joint-path nodes, or a reference table with joint modes and events."""

    kind: str
    duration: float
    steps: list[PlanStep]
    final_q: np.ndarray
    joint_nodes: list[tuple[np.ndarray, float, float]] | None = None
    segments: np.ndarray | None = None  # joint paths: the trapezoid rows of drive.plan_segment
    forces: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))  # opspace.FP_* rows
    tab: np.ndarray | None = None
    jmode: np.ndarray | None = None
    events: list[tuple[float, dict[str, float]]] = field(default_factory=list)
    grasps: list[tuple[float, str]] = field(default_factory=list)  # (t, object taken; '': a release)
    worlds: list[World] = field(default_factory=list)  # from each grasp and release on (planned poses)
    tool_path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    start_pose: list[float] = field(default_factory=list)  # the tool: x, y, z, roll, pitch, yaw
    end_pose: list[float] = field(default_factory=list)
    signalled: list[tuple[str, int]] = field(default_factory=list)  # direct input: (joint, index)
    signal_unit: m.SignalUnit = "A"
    q0: np.ndarray | None = None  # the initial pose it was planned from (Planner.plan)

    def apply(self, sim: Any) -> None:
        """Hand the plan to a `Simulation` for its next run."""
        if self.joint_nodes is not None:
            sim.set_joint_path(self.joint_nodes)
        else:
            assert self.tab is not None and self.jmode is not None
            sim.set_reference(self.tab, self.jmode, self.events, self.grasps)
        sim.set_forces(self.forces)

    def pushing(self, times: np.ndarray) -> np.ndarray:
        """Whether the tool is meant to push (a force set point above 0) at each of `times`."""
        out = np.zeros(times.shape[0], dtype=bool)
        for row in self.forces:
            out[times >= row[0] - 1e-12] = row[4] > 0.0
        return out

    def joint_samples(
        self, q0: np.ndarray, dt: float, turn: float = math.inf
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(times, joint positions) of the set points every dt s from 0 to the plan's end (a joint
        path), or the reference table's rows with points between them where the joints turn by more
        than `turn` rad together (a slow move's rows may be seconds apart); None when a joint follows
        a speed or a current (its position is not known before the run)."""
        if self.segments is not None:
            times = np.append(np.arange(0.0, self.duration, dt), self.duration)
            qs = np.empty((times.shape[0], q0.shape[0]))
            qd = np.empty(q0.shape[0])
            for k, t in enumerate(times):
                dr.traj_eval(self.segments, q0, float(t), qs[k], qd)
            return times, qs
        if self.tab is None or self.jmode is None:
            return None
        if np.any((self.jmode == dr.JM_SPEED) | (self.jmode == dr.JM_CURRENT)):
            return None
        n = q0.shape[0]
        t, qs = self.tab[:, 0], self.tab[:, 1 : 1 + n]
        if t.shape[0] < 2 or not math.isfinite(turn):
            return t.copy(), qs.copy()
        row, frac = _cut(np.ceil(np.abs(np.diff(qs, axis=0)).sum(axis=1) / turn))
        times = np.append(t[row] + frac * (t[row + 1] - t[row]), t[-1])
        return times, np.vstack([qs[row] + frac[:, None] * (qs[row + 1] - qs[row]), qs[-1:]])

    def step_at(self, t: float) -> PlanStep | None:
        """The step running at simulated time t (the last one once all are done). A run's worker asks
        at every frame (40 a second), for commands of up to 1000 steps: a bisection over the starts,
        which come in time order (a step begins where the one before it ends)."""
        k = bisect.bisect_right(self._starts, t + 1e-12)
        return self.steps[k - 1] if k else None

    def field_at(self, t: float) -> str:
        """The command field a refusal at simulated time t names: the step's (`command.nodes[2]`), or
        `command` before the first step."""
        step = self.step_at(t)
        return f"command.{step.path}" if step is not None else "command"

    @functools.cached_property
    def _starts(self) -> list[float]:
        return [step.start for step in self.steps]

    def summary(self, stop_time: float) -> m.CommandPlan:
        return m.CommandPlan(
            start_pose=self.start_pose,
            end_pose=self.end_pose,
            kind=self.kind,
            duration=self.duration,
            steps=[
                m.PlanStep(s.path, s.what, s.start, s.end, s.task, s.action, s.q_end, s.slowed)
                for s in self.steps
            ],
            final_q=[float(x) for x in self.final_q],
            tool_path=[[float(x) for x in p] for p in self.tool_path],
            stop_time_cuts=self.duration > stop_time + 1e-9,
            signals=self._preview(),
            slowed=max([1.0, *(s.slowed for s in self.steps)]),
            motion=self._motion(),
        )

    def _motion(self) -> m.PlannedMotion | None:
        """The joint set points at MOTION_POINTS even times over the command (only a reply needs it)."""
        if self.q0 is None or self.duration <= 0.0:
            return None
        sampled = self.joint_samples(self.q0, self.duration / (m.MOTION_POINTS - 1))
        if sampled is None:
            return None
        times, qs = sampled
        t = np.linspace(0.0, self.duration, m.MOTION_POINTS)
        q = np.column_stack([np.interp(t, times, qs[:, j]) for j in range(qs.shape[1])])
        return m.PlannedMotion(_floats(t), [_floats(row) for row in q])

    def _preview(self) -> m.SignalPreview | None:
        """A direct input's signals as expanded, sampled for a client (only a reply needs it: a run
        does not pay for it)."""
        if not self.signalled or self.tab is None or self.jmode is None:
            return None
        joints = [j for _name, j in self.signalled]
        t, values = signals.preview(self.tab, self.jmode, joints, m.PREVIEW_POINTS)
        return m.SignalPreview(
            self.signal_unit,
            _floats(t),
            {name: _floats(values[:, k]) for k, (name, _j) in enumerate(self.signalled)},
        )


def _floats(q: np.ndarray) -> list[float]:
    return [float(x) for x in q]


def _trapezoid_times(T: float, ta: float, motion: float) -> np.ndarray:
    """Sample times of a trapezoid: its corners where it is straight and, where it curves, as many as
    keep the linear interpolation between them within PROFILE_LAG of it for a point `motion` m
    away at the end (a slow acceleration takes few), at most one every REFERENCE_PERIOD."""
    k_acc = math.ceil(ta / REFERENCE_PERIOD)
    if 0.0 < ta < T:  # s'' = 1 / ((T - ta) ta); the chord of s'' t^2 / 2 over dt is off by s'' dt^2 / 8
        k_acc = min(k_acc, math.ceil(ta * math.sqrt(motion / ((T - ta) * ta) / (8.0 * PROFILE_LAG))))
    acc = np.linspace(0.0, ta, max(1, k_acc) + 1)
    return np.unique(np.concatenate([acc, T - acc]))


# ---- a line in time: a path-velocity profile along its joint curve -----------------------------------
def _line_rows(
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
    the other half of the line: the rows drive.ref_eval interpolates linearly. `along` (line
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


def _cut(pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interval k cut into pieces[k] equal parts (at least 1): for each part, its interval and where
    it starts in it (0 <= fraction < 1)."""
    count = np.maximum(1, pieces).astype(np.int64)
    k = np.repeat(np.arange(count.shape[0]), count)
    return k, (np.arange(k.shape[0]) - np.repeat(np.cumsum(count) - count, count)) / count[k]


def _where(path: str, sub: str) -> str:
    return f"{path}.{sub}" if path else sub


class _Reference:
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
        row = dr.plan_segment(self.q, dest, vmax, amax, 0.0)
        T, ta = float(row[1]), float(row[2])
        if T <= 0.0:
            return
        times = _trapezoid_times(T, ta, self.reach * float(np.sum(np.abs(dest - self.q))))
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


class Planner:
    """Plans commands for one model at one set of values, from one initial pose."""

    def __init__(
        self,
        model: ArmDescription,
        values: Mapping[str, float],
        initial: Sequence[float] | np.ndarray,
        stop_time: float,
        max_rows: int | None = None,
        obstacles: Sequence[Obstacle] = (),
    ) -> None:
        """`obstacles`: the session's, which grasps take (and the path check looks at)."""
        self.model = model
        self.obstacles = list(obstacles)
        self.n = model.n
        self.values = dict(values)
        self.q0 = np.asarray(initial, dtype=float)
        self.stop_time = float(stop_time)
        self.max_rows = max_rows if max_rows is not None else limit("reference_samples")
        self.kin = ArmKinematics(model.spec, self.values)
        self.names = [f"joint{j + 1}" for j in range(self.n)]
        self.lower = np.array([lk.joint_min for lk in model.spec.links])
        self.upper = np.array([lk.joint_max for lk in model.spec.links])
        self.vmax = np.array([self.values[f"{j}.traj.max_speed"] for j in self.names])
        self.amax = np.array([self.values[f"{j}.traj.max_acc"] for j in self.names])
        self._arrays = chain_arrays(model.spec, self.values)
        self._spheres = contact_geometry.sphere_table(model.spec, self.values)

    # ---- entry ----
    def plan(self, command: m.RobotCommand) -> Plan:
        """The plan of `command`, or CommandError naming what is wrong with it."""
        plan = self._plan(command)
        plan.start_pose, plan.end_pose = self.pose(self.q0), self.pose(plan.final_q)
        plan.q0 = self.q0.copy()
        return plan

    def collision(self, plan: Plan) -> tuple[str, str] | None:
        """(field, why) when the planned path makes the arm (or what it carries) touch an obstacle: the
        field is `initial` or the step's path under `command`. A path that follows speeds or currents
        is not known before the run: None. While a node sets a force the tool may touch (it is meant
        to push); the last link (the gripper's) passes through the objects the command grasps."""
        sampled = plan.joint_samples(self.q0, PATH_CHECK_PERIOD, PATH_CHECK_STEP / self.kin.reach)
        if sampled is None or not self.obstacles:
            return None
        times, qs = sampled
        pushing = plan.pushing(times)  # where the tool pushes, only the rest of the arm must not touch
        worlds = plan.worlds or [World(0.0, self.obstacles)]
        taken = {name for _t, name in plan.grasps if name}
        found = np.zeros(4)
        for w, world in enumerate(worlds):
            end = worlds[w + 1].t if w + 1 < len(worlds) else math.inf
            rows = np.flatnonzero((times >= world.t - 1e-12) & (times < end - 1e-12))
            if rows.size == 0:
                continue
            spheres, obs = grasp.world_tables(self._spheres, world.obstacles, taken, world.held, self.n - 1)
            hit = contact.first_touch(
                spheres,
                obs,
                self._arrays.pre_R,
                self._arrays.pre_p,
                np.ascontiguousarray(qs[rows]),
                pushing[rows],
                found,
            )
            if hit >= 0:
                return self._touch(plan, int(rows[hit]), float(times[rows[hit]]), world.obstacles, found)
        return None

    @functools.cached_property
    def self_check(self) -> SelfCollision:
        """The arm's check against itself at these values (self_collision.py), made when first asked."""
        spec = self.model.spec
        return SelfCollision.of(spec, self._spheres, self._arrays.pre_R, self._arrays.pre_p, spec.home)

    def self_touch(self, plan: Plan) -> tuple[str, str] | None:
        """(field, why) when the planned path makes two links of the arm touch (`initial`, or the step's
        path under `command`); a path that follows speeds or currents is not known: None."""
        sampled = plan.joint_samples(self.q0, PATH_CHECK_PERIOD, PATH_CHECK_STEP / self.kin.reach)
        if sampled is None:
            return None
        times, qs = sampled
        hit = self.self_check.first_touch(qs)
        if hit is None:
            return None
        k, a, b, depth = hit
        what = f"{a} would touch {b} ({depth * 1000:.1f} mm deep)"
        if k == 0:
            return "initial", f"at the initial pose {what}: choose a pose where the arm is clear of itself"
        t = float(times[k])
        return (
            plan.field_at(t),
            f"{what} at t = {t:.3f} s of the planned path: change the path, or set settings.collisions to "
            "simulate",
        )

    def holding_problem(self, plan: Plan | None) -> tuple[str, str] | None:
        """(field, why) when a drive cannot hold the arm against gravity at the initial pose or at a
        pose of the planned path (`plan` None: a run without a command, which holds the initial pose):
        the joint's gravity torque there (payload included) exceeds what its drive gives at rest
        (mechanics.holding_capacity). The motion's own torques are not counted: the drives' current
        limit shapes them in the run."""
        gravity = gravity_of(self.values)
        if not np.any(gravity):
            return None
        P = drive_array(self.n, self.values)
        capacity = holding_capacity(P)
        sampled = None if plan is None else plan.joint_samples(self.q0, HOLD_CHECK_PERIOD, HOLD_CHECK_STEP)
        times, qs = sampled if sampled is not None else (np.zeros(1), self.q0[None, :])
        g = np.empty(self.n)
        for k in range(qs.shape[0]):
            gravity_torques(*self._arrays, gravity, np.ascontiguousarray(qs[k]), g)
            over = np.flatnonzero(np.abs(g) > capacity)
            if over.size:
                j = int(over[np.argmax(np.abs(g[over]) / capacity[over])])
                need = (
                    f"joint{j + 1} cannot hold the arm against gravity: it needs {abs(g[j]):.3g} N m, its "
                    f"drive gives at most {capacity[j]:.3g} N m at rest (motor.i_max {P[j, dr.P_IMAX]:g} A, "
                    f"motor.kt {P[j, dr.P_KT]:g} N m/A, gear.ratio {P[j, dr.P_N]:g})"
                )
                if k == 0:
                    return "initial", f"at the initial pose {need}: choose another pose or a lighter payload"
                return (
                    plan.field_at(float(times[k])) if plan is not None else "command",
                    f"at t = {float(times[k]):.3f} s of the planned path {need}: change the path or lighten "
                    "the payload",
                )
        return None

    def _touch(
        self, plan: Plan, k: int, t: float, obstacles: Sequence[Obstacle], found: np.ndarray
    ) -> tuple[str, str]:
        hit = obstacles[int(found[1])].name
        world = next(w for w in reversed(plan.worlds or [World(0.0, [])]) if w.t <= t + 1e-12)
        if found[3] == contact_geometry.CARRIED and world.held is not None:
            what = f"the carried {world.obstacles[world.held.index].name} would touch obstacle {hit}"
        else:
            what = f"link{int(found[0]) + 1} would touch obstacle {hit}"
        depth = f"{found[2] * 1000:.1f} mm deep"
        if k == 0:
            return "initial", f"at the initial pose {what} ({depth}): move the arm or the obstacle clear"
        return (
            plan.field_at(t),
            f"{what} at t = {t:.3f} s of the planned path ({depth}): change the path, move the obstacle "
            "(set_obstacles), or set settings.collisions to simulate",
        )

    def pose(self, q: np.ndarray) -> list[float]:
        """The tool pose at q as x, y, z (m), roll, pitch, yaw (rad)."""
        p, R = self.kin.tool_pose(q)
        return [float(x) for x in (*p, *rpy_of(R))]

    def _plan(self, command: m.RobotCommand) -> Plan:
        if self.q0.shape != (self.n,):
            raise CommandError("", f"the initial pose has {self.q0.shape[0]} joints, the arm {self.n}")
        if isinstance(command, m.JointPath):
            return self._joint_path(command)
        if isinstance(command, m.DirectInput):
            return self._direct_input(command)
        ref = _Reference(self.q0, self.max_rows, self.obstacles, self.kin.reach)
        steps: list[PlanStep] = []
        forces = []
        if isinstance(command, m.CartesianPath):
            for i, node in enumerate(command.nodes):
                t0 = ref.t
                axis = np.asarray(node.force_axis, float)
                forces.append([t0, *(axis / np.linalg.norm(axis)), node.force])
                path = f"nodes[{i}]"
                target = rot_rpy(node.rpy)
                position = np.asarray(node.position, float)
                slowed = 1.0
                if node.move == "lin":
                    slowed = self._lin(ref, path, position, target, node.speed_pct, node.acc_pct)
                else:
                    self._ptp(ref, path, position, target, node.speed_pct, node.acc_pct)
                steps.append(PlanStep(path, node.move, t0, ref.t, q_end=_floats(ref.q), slowed=slowed))
        else:
            steps.extend(self._action(ref, act, path, task) for path, task, act in _actions_of(command))
        tab = ref.table()
        return Plan(
            kind=command.kind,
            duration=ref.t,
            steps=steps,
            final_q=ref.q,
            tab=tab,
            jmode=np.full(self.n, dr.JM_POSITION, dtype=np.int64),
            events=ref.events,
            grasps=ref.grasps,
            worlds=ref.worlds,
            tool_path=self._tool_path(tab[:, 1 : 1 + self.n]),
            forces=np.array(forces) if any(f[4] > 0 for f in forces) else np.zeros((0, 5)),
        )

    def check_arguments(self, program: m.Action | m.Task | m.Mission) -> None:
        """The checks that need no start pose: every action's arguments against its primitive, joint
        targets within their ranges (CommandError naming the field)."""
        for path, _task, act in _actions_of(program):
            args = self._args(act, _where(path, "args"))
            if act.primitive == "move_joints":
                self._joints(args["q"], _where(path, "args.q"))

    # ---- levels ----
    def _joint_path(self, cmd: m.JointPath) -> Plan:
        q = self.q0
        t = 0.0
        steps = []
        nodes = []
        rows = []
        samples = [q]
        for i, node in enumerate(cmd.nodes):
            dest = self._joints(node.q, f"nodes[{i}].q")
            row = dr.plan_segment(
                q, dest, self.vmax * node.speed_pct / 100, self.amax * node.acc_pct / 100, t
            )
            steps.append(PlanStep(f"nodes[{i}]", "joint", t, t + float(row[1]), q_end=_floats(dest)))
            rows.append(row)
            nodes.append((dest, node.speed_pct, node.acc_pct))
            samples.extend(q + s * (dest - q) for s in np.linspace(0.0, 1.0, 21)[1:])
            t += float(row[1])
            q = dest
        return Plan(
            "joint_path",
            t,
            steps,
            q,
            joint_nodes=nodes,
            segments=np.array(rows) if rows else np.zeros((0, 3 + 2 * self.n)),
            tool_path=self._tool_path(np.array(samples)),
        )

    def _direct_input(self, cmd: m.DirectInput) -> Plan:
        bounds = signals.JointBounds(
            lower=self.lower,
            upper=self.upper,
            max_speed=self.vmax,
            i_max=np.array([self.values[f"{j}.motor.i_max"] for j in self.names]),
        )
        tab, jmode = signals.expand_direct_input(
            cmd, self.names, bounds, self.q0, self.stop_time, self.max_rows
        )
        what = cmd.mode if cmd.mode == "open_loop" else f"closed_loop {cmd.reference}"
        # Where the joints are meant to be is known before the run unless a current drives one.
        known = cmd.mode == "closed_loop"
        qs = tab[:, 1 : 1 + self.n]
        final_q = qs[-1].copy() if known else self.q0
        return Plan(
            kind="direct_input",
            duration=self.stop_time,
            steps=[PlanStep("signals", what, 0.0, self.stop_time, q_end=_floats(final_q) if known else [])],
            final_q=final_q,
            tab=tab,
            jmode=jmode,
            tool_path=self._tool_path(qs) if known else np.zeros((0, 3)),
            signalled=[(name, self.names.index(name)) for name in cmd.signals],
            signal_unit=cmd.unit,
        )

    # ---- moves ----
    def _joints(self, q: Sequence[float], where: str) -> np.ndarray:
        try:
            check_joints(self.model.describe(), q, where)  # the protocol's one rule for joint vectors
        except DecodeError as exc:
            raise CommandError(exc.field, exc.problem) from None
        return np.asarray(q, dtype=float)

    def _ptp(self, ref: _Reference, path: str, p1: np.ndarray, R1: np.ndarray, sp: float, ac: float) -> None:
        self._within_reach(path, p1)
        res = self.kin.solve_near(p1, R1, ref.q)
        if not res.ok:
            raise self._unreachable(path, res)
        ref.joint_move(path, res.q, self.vmax * sp / 100, self.amax * ac / 100)

    def _within_reach(self, path: str, p1: np.ndarray, p0: np.ndarray | None = None) -> None:
        """Refuse a target farther from the arm's base than it reaches (no solver needed), and say
        where a line from p0 leaves that sphere."""
        d, reach = self.kin.from_base(p1), self.kin.reach
        if d <= reach:
            return
        why = (
            f"the pose is out of reach: {_metres(d, reach)} from the arm's base, the arm reaches "
            f"{_metres(reach, d)}"
        )
        if p0 is not None:
            a, b = p0 - self.kin.base, p1 - p0
            ab, bb = float(a @ b), float(b @ b)
            s = (-ab + math.sqrt(max(ab * ab - bb * (float(a @ a) - reach * reach), 0.0))) / bb
            why += f"; the line leaves the workspace by {100 * min(max(s, 0.0), 1.0):.0f} % of its length"
        raise CommandError(path, why)

    def _unreachable(self, path: str, res: IKResult) -> CommandError:
        p, R = self.kin.tool_pose(res.q)
        return CommandError(
            path,
            f"the pose cannot be reached ({res.reason}); the closest pose the arm reaches is "
            f"position {_fmt(p)} m, rpy {_fmt(rpy_of(R))} rad",
        )

    def _lin(self, ref: _Reference, path: str, p1: np.ndarray, R1: np.ndarray, sp: float, ac: float) -> float:
        """A straight line in position, slerp in orientation: planned in geometry (the joint solutions
        along it, ArmKinematics.walk_line, each nearest the one before, so among the Spider's postures
        for a pose the one closest to where the arm just was), then in time (_line_rows). Returns how
        much the joint limits slowed it: its duration over the Cartesian trapezoid's (1 = not)."""
        p0, R0 = self.kin.tool_pose(ref.q)
        dp = p1 - p0
        rot = orientation_error(R0, R1)  # R1 = exp(rot) R0, world frame
        length, angle = float(np.linalg.norm(dp)), float(np.linalg.norm(rot))
        if length < 1e-12 and angle < 1e-12:
            return 1.0
        self._within_reach(path, p1, p0)
        walk = self.kin.walk_line(
            ref.q,
            p1,
            R1,
            tol_pos=LIN_TOLERANCE / 2,  # the other half: the chords between rows (_line_rows)
            tol_rot=LIN_TOLERANCE / 2,
            step=LIN_KNOT_STEP,
            turn=LIN_KNOT_TURN,
            sigma_min=SINGULAR_SIGMA,
            max_knots=LIN_MAX_KNOTS,
        )
        if not walk.ok:
            target = self.kin.solve_near(p1, R1, walk.q_at)
            if not target.ok:  # the target itself: out of reach is said as out of reach
                raise self._unreachable(path, target)
            raise self._walk_refusal(path, walk, p0, dp, R0, rot)
        v = self.values
        rates, accs = [], []
        if length > 0:
            rates.append(v["cart.max_speed"] * sp / 100 / length)
            accs.append(v["cart.max_acc"] * ac / 100 / length)
        if angle > 0:
            rates.append(v["cart.max_rot_speed"] * sp / 100 / angle)
            accs.append(v["cart.max_rot_acc"] * ac / 100 / angle)
        along = PROFILE_LAG / max(length, angle)  # in line parameter
        times, qs, qds, asked = _line_rows(
            walk, self.lower, self.upper, self.vmax, self.amax, min(rates), min(accs), along
        )
        ref.add(path, times, qs, qds)
        slowed = float(times[-1]) / asked
        return slowed if slowed > 1.0 + 1e-9 else 1.0

    def _walk_refusal(
        self,
        path: str,
        walk: LineWalk,
        p0: np.ndarray,
        dp: np.ndarray,
        R0: np.ndarray,
        rot: np.ndarray,
    ) -> CommandError:
        """Why a reachable target's line cannot be followed, where (percent of its length) and in which
        posture: a joint limit or the workspace's edge on the way, a singularity (or a jump to
        another posture, which needs an unbounded joint speed)."""
        s = walk.at
        pct = 100.0 * s
        p = p0 + s * dp
        if walk.status == LINE_SINGULAR and s == 0.0:
            return CommandError(path, f"the line starts at a singular posture ({_posture(walk.q_at)})")
        if walk.status == LINE_SINGULAR:
            return CommandError(
                path,
                f"the line crosses a singularity at {pct:.0f} % of its length, at position {_fmt(p)} m "
                f"({_posture(walk.q_at)}): split it with a ptp move",
            )
        if walk.status == LINE_JUMP:
            limited = self._at_limit(walk.q[-1])
            if limited:
                return CommandError(
                    path,
                    f"the line leaves the workspace at {pct:.0f} % of its length, at position {_fmt(p)} m "
                    f"({', '.join(limited)} at its limit): the arm would have to jump to another posture "
                    "to follow it; split it with a ptp move",
                )
            return CommandError(
                path,
                f"the line crosses a singularity at {pct:.0f} % of its length, at position {_fmt(p)} m "
                f"({_posture(walk.q_at)}): the joints would need an unbounded speed there; split it "
                "with a ptp move",
            )
        if walk.status == LINE_KNOTS:
            return CommandError(
                path,
                f"the line passes too close to a singularity after {pct:.0f} % of its length (more than "
                f"{LIN_MAX_KNOTS:,} joint solutions to follow it within {LIN_TOLERANCE:g} m): split it "
                "with a ptp move",
            )
        res = self.kin.solve(p, turned(s * rot, R0), walk.q_at, tol_pos=1e-10, tol_rot=1e-10, max_iter=50)
        if res.ok:
            return CommandError(
                path,
                f"the line cannot be followed at {pct:.0f} % of its length, at position {_fmt(p)} m: the arm "
                f"would have to jump to another posture ({_posture(res.q)}); split it with a ptp move",
            )
        limited = self._at_limit(res.q)
        why = f"{', '.join(limited)} at its limit" if limited else "out of the arm's reach"
        return CommandError(
            path,
            f"the line leaves the workspace at {pct:.0f} % of its length, at position {_fmt(p)} m "
            f"({why}); the pose closest to it is {res.position_error * 1000:.3g} mm and "
            f"{res.rotation_error:.3g} rad away",
        )

    def _at_limit(self, q: np.ndarray) -> list[str]:
        return [
            self.names[j] for j in range(self.n) if min(q[j] - self.lower[j], self.upper[j] - q[j]) < 1e-6
        ]

    # ---- actions ----
    def _action(self, ref: _Reference, act: m.Action, path: str, task: str) -> PlanStep:
        args = self._args(act, _where(path, "args"))
        t0 = ref.t
        sp = float(args.get("speed_pct", 100.0))
        ac = float(args.get("acc_pct", 100.0))
        slowed = 1.0
        if act.primitive == "move_joints":
            dest = self._joints(list(args["q"]), _where(path, "args.q"))
            ref.joint_move(path, dest, self.vmax * sp / 100, self.amax * ac / 100)
        elif act.primitive in ("move_linear", "move_to_pose"):
            position = np.asarray(args["position"], dtype=float)
            R = rot_rpy(args["rpy"]) if "rpy" in args else self.kin.tool_pose(ref.q)[1]
            if act.primitive == "move_linear":
                slowed = self._lin(ref, path, position, R, sp, ac)
            else:
                self._ptp(ref, path, position, R, sp, ac)
        elif act.primitive == "wait":
            ref.hold(path, float(args["duration"]))
        elif act.primitive == "home":
            home = self._joints(self.model.home(), _where(path, "primitive"))
            ref.joint_move(path, home, self.vmax * sp / 100, self.amax * ac / 100)
        elif act.primitive == "set_payload":
            changes = {"payload.mass": float(args["mass"])}
            if "size" in args:
                changes["payload.size"] = float(args["size"])
            ref.events.append((ref.t, changes))
        elif act.primitive == "grasp":
            self._grasp(ref, str(args["object"]), _where(path, "args.object"))
        elif act.primitive == "release":
            self._release(ref, _where(path, "primitive"))
        return PlanStep(
            path or "action",
            act.primitive,
            t0,
            ref.t,
            task,
            act.name or act.primitive,
            _floats(ref.q),
            slowed,
        )

    def _last_frame(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The last joint's frame (R, p) at q: what a grasped object hangs on."""
        R_all, p_all = np.empty((self.n, 3, 3)), np.empty((self.n, 3))
        chain_frames(self._arrays.pre_R, self._arrays.pre_p, q, R_all, p_all)
        return R_all[-1], p_all[-1]

    def _grasp(self, ref: _Reference, name: str, where: str) -> None:
        world = ref.world
        index = next((k for k, ob in enumerate(world.obstacles) if ob.name == name), -1)
        if index < 0:
            known = ", ".join(ob.name for ob in world.obstacles) or "none"
            raise CommandError(where, f"no obstacle named {name} in the session (obstacles: {known})")
        if world.held is not None:
            holding = world.obstacles[world.held.index].name
            raise CommandError(where, f"the tool holds {holding} already: release it first")
        ob = world.obstacles[index]
        why = grasp_problem(ob) or grasp.reach_problem(ob, self.kin.tool_pose(ref.q)[0])
        if why:
            raise CommandError(where, why)
        R, p = self._last_frame(ref.q)
        ref.grasps.append((ref.t, name))
        ref.worlds.append(World(ref.t, world.obstacles, grasp.take(index, ob, R, p)))

    def _release(self, ref: _Reference, where: str) -> None:
        world = ref.world
        if world.held is None:
            raise CommandError(where, "the tool holds nothing to release (grasp comes first)")
        R, p = self._last_frame(ref.q)
        obstacles = list(world.obstacles)
        k = world.held.index
        obstacles[k] = scene_state.at_pose(obstacles[k], *grasp.world_pose(world.held, R, p))
        ref.grasps.append((ref.t, ""))
        ref.worlds.append(World(ref.t, obstacles))

    def _args(self, act: m.Action, where: str) -> dict[str, Any]:
        """The action's arguments checked against its primitive's table, defaults filled in."""
        spec = ACTION_ARGS[act.primitive]
        for name in act.args:
            if name not in spec:
                raise CommandError(f"{where}.{name}", f"{act.primitive} takes {', '.join(spec)}, not {name}")
        out: dict[str, Any] = {}
        for name, arg in spec.items():
            raw = act.args.get(name)
            field_ = f"{where}.{name}"
            if raw is None:
                if arg.default is not None:
                    out[name] = arg.default
                elif not arg.optional:
                    raise CommandError(field_, f"{act.primitive} needs {name} ({arg.description})")
                continue
            size = self.n if arg.size == -1 else arg.size
            if size == NAME_ARG:
                if not isinstance(raw, str):
                    raise CommandError(field_, f"must be a name ({arg.description})")
                out[name] = raw
            elif isinstance(raw, str):
                raise CommandError(field_, f"must be a number in {arg.unit}, not a name")
            elif size == 0:
                if isinstance(raw, list):
                    raise CommandError(field_, f"must be a number in {arg.unit}, not a list")
                low_ok = raw > arg.min if arg.above_min else raw >= arg.min
                if not (math.isfinite(raw) and low_ok and raw <= arg.max):
                    low = "(" if arg.above_min else "["
                    raise CommandError(
                        field_, f"{raw:g} {arg.unit} is outside {low}{arg.min:g}, {arg.max:g}]"
                    )
                out[name] = float(raw)
            else:
                if not isinstance(raw, list) or len(raw) != size:
                    raise CommandError(field_, f"must be a list of {size} numbers in {arg.unit}")
                if not all(math.isfinite(x) for x in raw):
                    raise CommandError(field_, "must hold finite numbers")
                out[name] = [float(x) for x in raw]
        return out

    # ---- helpers ----
    def _tool_path(self, qs: np.ndarray) -> np.ndarray:
        if qs.shape[0] == 0:
            return np.zeros((0, 3))
        idx = np.unique(
            np.linspace(0, qs.shape[0] - 1, min(TOOL_PATH_POINTS, qs.shape[0])).round().astype(int)
        )
        return self.kin.tool_positions(qs[idx])


def _actions_of(program: m.Action | m.Task | m.Mission) -> list[tuple[str, str, m.Action]]:
    """Every action of a high-level command in order: (its path in the command, its task, it)."""
    if isinstance(program, m.Action):
        return [("", "", program)]
    if isinstance(program, m.Task):
        return [(f"actions[{i}]", program.name, a) for i, a in enumerate(program.actions)]
    return [
        (f"tasks[{i}].actions[{k}]", t.name, a)
        for i, t in enumerate(program.tasks)
        for k, a in enumerate(t.actions)
    ]


def _metres(x: float, other: float) -> str:
    """x in m with as many decimals (2 to 6) as it takes to differ from `other` once rounded."""
    dec = 2
    while dec < 6 and round(x, dec) == round(other, dec):
        dec += 1
    return f"{x:.{dec}f} m"


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


def _posture(q: np.ndarray) -> str:
    return "q = " + _fmt(q) + " rad"


def warmup() -> None:
    """Compile (or load from numba's cache) the kinematics kernels: a line and a reach on the Spider,
    and a pose just beyond its reach (the closest-pose search a refusal runs)."""
    from . import get_model

    pkg = get_model("spider")
    q0 = [0.5, 0.2, -0.3, -0.5, -0.3, -0.2, 0.7]
    planner = Planner(pkg, pkg.check_values({}), q0, 1.0)
    p, R = planner.kin.tool_pose(np.array(q0))
    rpy = [float(x) for x in rpy_of(R)]
    nodes = [
        m.CartesianNode([float(p[0]), float(p[1]), float(p[2]) - 0.01], rpy, move) for move in ("lin", "ptp")
    ]
    planner.plan(m.CartesianPath(nodes))
    try:
        planner.plan(m.CartesianPath([m.CartesianNode([0.0, 2.2, 0.3], rpy, "ptp")]))
    except CommandError:
        pass
