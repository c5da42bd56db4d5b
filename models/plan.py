"""A planned command: what a run follows and what a client is told of it.

`Planner` (planner.py) makes a `Plan` of a robot command: its steps and their times, a joint path's
trapezoid segments or a sampled reference table with the joints' modes, the force set points, the
grasps and releases and the world the arm moves in after each. A run's worker hands it to its
simulation (`apply`); the path checks (path_checks.py) sample it (`joint_samples`); a client gets its
`summary`.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.environment import Obstacle

from . import grasp, references, signals


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
    segments: np.ndarray | None = None  # joint paths: the trapezoid rows of references.plan_segment
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
        sim.set_points.set_forces(self.forces)

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
                references.traj_eval(self.segments, q0, float(t), qs[k], qd)
            return times, qs
        if self.tab is None or self.jmode is None:
            return None
        if np.any((self.jmode == references.JM_SPEED) | (self.jmode == references.JM_CURRENT)):
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
        return m.PlannedMotion(floats(t), [floats(row) for row in q])

    def _preview(self) -> m.SignalPreview | None:
        """A direct input's signals as expanded, sampled for a client (only a reply needs it: a run
        does not pay for it)."""
        if not self.signalled or self.tab is None or self.jmode is None:
            return None
        joints = [j for _name, j in self.signalled]
        t, values = signals.preview(self.tab, self.jmode, joints, m.PREVIEW_POINTS)
        return m.SignalPreview(
            self.signal_unit,
            floats(t),
            {name: floats(values[:, k]) for k, (name, _j) in enumerate(self.signalled)},
        )


def floats(q: np.ndarray) -> list[float]:
    """An array as a message's list of floats."""
    return [float(x) for x in q]


def _cut(pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interval k cut into pieces[k] equal parts (at least 1): for each part, its interval and where
    it starts in it (0 <= fraction < 1)."""
    count = np.maximum(1, pieces).astype(np.int64)
    k = np.repeat(np.arange(count.shape[0]), count)
    return k, (np.arange(k.shape[0]) - np.repeat(np.cumsum(count) - count, count)) / count[k]
