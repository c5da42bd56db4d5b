"""A robot command of any level (paper §2.1) turned into what the drives follow, checked before a run.

A joint path stays a table of trapezoid segments (drive.traj_eval, exact). Every other level becomes a
sampled reference table (drive.ref_eval): Cartesian `lin` moves are sampled every REFERENCE_PERIOD
through inverse kinematics and handed to the joint-independent cascade as joint set points; joint
moves (a `ptp` node, move_joints, home) are their trapezoids sampled where they curve; direct inputs
are expanded by signals.py. Actions, tasks and missions expand into those lower levels; the payload
changes of set_payload and the grasps and releases become events of the run.

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
from .chain_dynamics import chain_frames
from .description import ArmDescription
from .errors import CommandError
from .ik import ArmKinematics, orientation_error
from .mechanics import chain_arrays

#: s between the samples of a Cartesian reference (and of the curved parts of sampled joint moves).
REFERENCE_PERIOD = 1e-3
#: Smallest singular value of the 6 x n tool Jacobian a `lin` move may pass through.
SINGULAR_SIGMA = 1e-3
#: Largest distance (m) and angle (rad) between a `lin` sample's pose and the arm's pose after IK.
LIN_TOLERANCE = 1e-6
#: Points of the planned tool path returned to clients.
TOOL_PATH_POINTS = 1000
#: s between the set points a path is checked at against the obstacles (before a run): at 1 m/s a
#: sphere moves 2 mm between two, a fifth of the thinnest one.
PATH_CHECK_PERIOD = 2e-3


@dataclass
class PlanStep:
    path: str  # where the step sits in the command: nodes[2], tasks[1].actions[0], action, signals
    what: str  # joint, lin, ptp, a primitive, open_loop / closed_loop
    start: float
    end: float
    task: str = ""
    action: str = ""
    q_end: list[float] = field(default_factory=list)  # the joint set points when it ends ([]: not known)


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

    def joint_samples(self, q0: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(times, joint positions) of the set points every dt s from 0 to the plan's end; None when a
        joint follows a speed or a current (its position is not known before the run)."""
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
        return self.tab[:, 0].copy(), self.tab[:, 1 : 1 + n].copy()

    def step_at(self, t: float) -> PlanStep | None:
        """The step running at simulated time t (the last one once all are done). A run's worker asks
        at every frame (40 a second), for commands of up to 1000 steps: a bisection over the starts,
        which come in time order (a step begins where the one before it ends)."""
        k = bisect.bisect_right(self._starts, t + 1e-12)
        return self.steps[k - 1] if k else None

    @functools.cached_property
    def _starts(self) -> list[float]:
        return [step.start for step in self.steps]

    def summary(self, stop_time: float) -> m.CommandPlan:
        return m.CommandPlan(
            start_pose=self.start_pose,
            end_pose=self.end_pose,
            kind=self.kind,
            duration=self.duration,
            steps=[m.PlanStep(s.path, s.what, s.start, s.end, s.task, s.action, s.q_end) for s in self.steps],
            final_q=[float(x) for x in self.final_q],
            tool_path=[[float(x) for x in p] for p in self.tool_path],
            stop_time_cuts=self.duration > stop_time + 1e-9,
            signals=self._preview(),
        )

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


def _trapezoid(T: float, ta: float, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Path parameter s in [0, 1] and its rate at times tau of a trapezoid of duration T and
    acceleration time ta (the profile of drive.traj_eval)."""
    tau = np.clip(tau, 0.0, T)
    v = 1.0 / (T - ta)
    s = np.where(
        tau < ta,
        0.5 * v / ta * tau**2,
        np.where(tau < T - ta, v * (tau - 0.5 * ta), 1.0 - 0.5 * v / ta * (T - tau) ** 2),
    )
    sd = np.where(tau < ta, v * tau / ta, np.where(tau < T - ta, v, v * (T - tau) / ta))
    return s, sd


def _trapezoid_times(T: float, ta: float) -> np.ndarray:
    """Sample times of a trapezoid: every period where it curves, its corners where it is straight."""
    k_acc = max(1, math.ceil(ta / REFERENCE_PERIOD))
    acc = np.linspace(0.0, ta, k_acc + 1)
    return np.unique(np.concatenate([acc, T - acc]))


def _where(path: str, sub: str) -> str:
    return f"{path}.{sub}" if path else sub


class _Reference:
    """A reference table being built move by move: rows [t, q, qd], the set point moving on, and the
    world the arm moves in (objects grasped and released on the way)."""

    def __init__(self, q0: np.ndarray, max_rows: int, obstacles: Sequence[Obstacle]) -> None:
        self.n = q0.shape[0]
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
        times = _trapezoid_times(T, ta)
        s, sd = _trapezoid(T, ta, times)
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
        return plan

    def collision(self, plan: Plan) -> tuple[str, str] | None:
        """(field, why) when the planned path makes the arm (or what it carries) touch an obstacle: the
        field is `initial` or the step's path under `command`. A path that follows speeds or currents
        is not known before the run: None. While a node sets a force the tool may touch (it is meant
        to push); the last link (the gripper's) passes through the objects the command grasps."""
        sampled = plan.joint_samples(self.q0, PATH_CHECK_PERIOD)
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
        step = plan.step_at(t)
        return (
            f"command.{step.path}" if step is not None else "command",
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
        ref = _Reference(self.q0, self.max_rows, self.obstacles)
        steps: list[PlanStep] = []
        forces = []
        if isinstance(command, m.CartesianPath):
            for i, node in enumerate(command.nodes):
                t0 = ref.t
                axis = np.asarray(node.force_axis, float)
                forces.append([t0, *(axis / np.linalg.norm(axis)), node.force])
                path = f"nodes[{i}]"
                target = rot_rpy(node.rpy)
                if node.move == "lin":
                    position = np.asarray(node.position, float)
                    self._lin(ref, path, position, target, node.speed_pct, node.acc_pct, f"{path}.speed_pct")
                else:
                    self._ptp(
                        ref, path, np.asarray(node.position, float), target, node.speed_pct, node.acc_pct
                    )
                steps.append(PlanStep(path, node.move, t0, ref.t, q_end=_floats(ref.q)))
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
        res = self.kin.solve_near(p1, R1, ref.q)
        if not res.ok:
            p, R = self.kin.tool_pose(res.q)
            raise CommandError(
                path,
                f"the pose cannot be reached ({res.reason}); the closest pose the arm reaches is "
                f"position {_fmt(p)} m, rpy {_fmt(rpy_of(R))} rad",
            )
        ref.joint_move(path, res.q, self.vmax * sp / 100, self.amax * ac / 100)

    def _lin(
        self,
        ref: _Reference,
        path: str,
        p1: np.ndarray,
        R1: np.ndarray,
        sp: float,
        ac: float,
        speed_field: str,
    ) -> None:
        """A straight line in position, slerp in orientation, one trapezoid in the path parameter
        that keeps the cart.* maxima; every sample solved by IK from the previous one (so among the
        Spider's postures for a pose, the one closest to where the arm just was)."""
        p0, R0 = self.kin.tool_pose(ref.q)
        dp = p1 - p0
        rot = orientation_error(R0, R1)  # R1 = exp(rot) R0, world frame
        length, angle = float(np.linalg.norm(dp)), float(np.linalg.norm(rot))
        if length < 1e-12 and angle < 1e-12:
            return
        v = self.values
        rates, accs = [], []
        if length > 0:
            rates.append(v["cart.max_speed"] * sp / 100 / length)
            accs.append(v["cart.max_acc"] * ac / 100 / length)
        if angle > 0:
            rates.append(v["cart.max_rot_speed"] * sp / 100 / angle)
            accs.append(v["cart.max_rot_acc"] * ac / 100 / angle)
        vs, as_ = min(rates), min(accs)
        ta = min(vs / as_, math.sqrt(1.0 / as_))
        T = max(ta, 1.0 / vs, 1.0 / (as_ * ta)) + ta
        k = max(2, math.ceil(T / REFERENCE_PERIOD))
        times = np.linspace(0.0, T, k + 1)
        s, _ = _trapezoid(T, ta, times)
        qs = np.empty((k + 1, self.n))
        qs[0] = ref.q
        sigma = np.empty(k + 1)
        sigma[0] = self.kin.sigma_min(ref.q)
        if sigma[0] < SINGULAR_SIGMA:
            raise CommandError(path, f"the line starts at a singular posture ({_posture(ref.q)})")
        for i in range(1, k + 1):
            p = p0 + s[i] * dp
            R = _rotvec_matrix(s[i] * rot) @ R0
            res = self.kin.solve(p, R, qs[i - 1], tol_pos=1e-10, tol_rot=1e-10, max_iter=50)
            pct = 100.0 * s[i]
            if res.position_error > LIN_TOLERANCE or res.rotation_error > LIN_TOLERANCE:
                limited = [
                    self.names[j]
                    for j in range(self.n)
                    if min(res.q[j] - self.lower[j], self.upper[j] - res.q[j]) < 1e-6
                ]
                why = f"{', '.join(limited)} at its limit" if limited else "out of the arm's reach"
                raise CommandError(
                    path,
                    f"the line leaves the workspace at {pct:.0f} % of its length, at position {_fmt(p)} m "
                    f"({why}); the pose closest to it is {res.position_error * 1000:.3g} mm away",
                )
            qs[i] = res.q
            sigma[i] = self.kin.sigma_min(res.q)
            if sigma[i] < SINGULAR_SIGMA:
                raise CommandError(
                    path,
                    f"the line crosses a singularity at {pct:.0f} % of its length, at position {_fmt(p)} m "
                    f"({_posture(res.q)}): split it with a ptp move",
                )
        qds = np.asarray(np.gradient(qs, times, axis=0))
        qds[0] = 0.0
        qds[-1] = 0.0
        peak = np.abs(qds) / self.vmax
        if np.max(peak) > 1.0 + 1e-6:
            i, j = (int(x) for x in np.unravel_index(int(np.argmax(peak)), peak.shape))
            raise CommandError(
                speed_field,
                f"{self.names[j]} would need {abs(qds[i, j]):.3g} rad/s at {100 * s[i]:.0f} % of the line, "
                f"above its traj.max_speed of {self.vmax[j]:.3g} rad/s: lower speed_pct",
            )
        ref.add(path, times, qs, qds)

    # ---- actions ----
    def _action(self, ref: _Reference, act: m.Action, path: str, task: str) -> PlanStep:
        args = self._args(act, _where(path, "args"))
        t0 = ref.t
        sp = float(args.get("speed_pct", 100.0))
        ac = float(args.get("acc_pct", 100.0))
        if act.primitive == "move_joints":
            dest = self._joints(list(args["q"]), _where(path, "args.q"))
            ref.joint_move(path, dest, self.vmax * sp / 100, self.amax * ac / 100)
        elif act.primitive in ("move_linear", "move_to_pose"):
            position = np.asarray(args["position"], dtype=float)
            R = rot_rpy(args["rpy"]) if "rpy" in args else self.kin.tool_pose(ref.q)[1]
            if act.primitive == "move_linear":
                self._lin(ref, path, position, R, sp, ac, _where(path, "args.speed_pct"))
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
            path or "action", act.primitive, t0, ref.t, task, act.name or act.primitive, _floats(ref.q)
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
        return np.array([self.kin.tool_pose(qs[i])[0] for i in idx])


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


def _rotvec_matrix(r: np.ndarray) -> np.ndarray:
    """exp([r]x): the rotation by |r| about r (Rodrigues)."""
    angle = float(np.linalg.norm(r))
    if angle < 1e-15:
        return np.eye(3)
    k = r / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


def _posture(q: np.ndarray) -> str:
    return "q = " + _fmt(q) + " rad"


def warmup() -> None:
    """Compile (or load from numba's cache) the kinematics kernels: a line and a reach on the Spider."""
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
