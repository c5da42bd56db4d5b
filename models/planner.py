"""A robot command of any level (paper §2.1) turned into what the drives follow, checked before a run.

A joint path stays a table of trapezoid segments (references.traj_eval, exact). Every other level becomes a
sampled reference table (references.ref_eval, linear between rows): a Cartesian `lin` move is planned in
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
What a plan holds is plan.py; how a motion becomes rows, reference_rows.py; the checks of the planned
path against obstacles, the arm itself and gravity, path_checks.py.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.protocol.environment import Obstacle, grasp_problem
from simecs.mesh.protocol.limits import limit
from simecs.mesh.protocol.model import check_joints
from simecs.mesh.protocol.robot_commands import ACTION_ARGS, NAME_ARG
from simecs.mesh.rules import scene_state
from simecs.mesh.rules.kinematics import rot_rpy, rpy_of

from . import contact_geometry, grasp, references, signals
from .chain_dynamics import chain_frames
from .description import ArmDescription
from .errors import CommandError
from .ik import ArmKinematics, IKResult, orientation_error, turned
from .line_walk import LINE_JUMP, LINE_KNOTS, LINE_SINGULAR, LineWalk
from .mechanics import chain_arrays
from .path_checks import PathChecks
from .plan import Plan, PlanStep, World, floats
from .reference_rows import LIN_TOLERANCE, PROFILE_LAG, ReferenceTable, line_rows

#: Smallest singular value of the 6 x n tool Jacobian a `lin` move may pass through.
SINGULAR_SIGMA = 1e-3
#: Largest distance (m) and turn (rad) between two joint solutions of a `lin` move (closer where the
#: accuracy needs it).
LIN_KNOT_STEP = 0.05
LIN_KNOT_TURN = 0.1
#: Most joint solutions one `lin` move may take (a line that needs more passes too close to a
#: singularity to be followed).
LIN_MAX_KNOTS = 4096
#: Points of the planned tool path returned to clients.
TOOL_PATH_POINTS = 1000


def _where(path: str, sub: str) -> str:
    return f"{path}.{sub}" if path else sub


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
        self.checks = PathChecks(
            model,
            self.values,
            self.q0,
            self.obstacles,
            self.kin.reach,
            self._arrays,
            contact_geometry.sphere_table(model.spec, self.values),
        )

    # ---- entry ----
    def plan(self, command: m.RobotCommand) -> Plan:
        """The plan of `command`, or CommandError naming what is wrong with it."""
        plan = self._plan(command)
        plan.start_pose, plan.end_pose = self.pose(self.q0), self.pose(plan.final_q)
        plan.q0 = self.q0.copy()
        return plan

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
        ref = ReferenceTable(self.q0, self.max_rows, self.obstacles, self.kin.reach)
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
                steps.append(PlanStep(path, node.move, t0, ref.t, q_end=floats(ref.q), slowed=slowed))
        else:
            steps.extend(self._action(ref, act, path, task) for path, task, act in _actions_of(command))
        tab = ref.table()
        return Plan(
            kind=command.kind,
            duration=ref.t,
            steps=steps,
            final_q=ref.q,
            tab=tab,
            jmode=np.full(self.n, references.JM_POSITION, dtype=np.int64),
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
            row = references.plan_segment(
                q, dest, self.vmax * node.speed_pct / 100, self.amax * node.acc_pct / 100, t
            )
            steps.append(PlanStep(f"nodes[{i}]", "joint", t, t + float(row[1]), q_end=floats(dest)))
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
            steps=[PlanStep("signals", what, 0.0, self.stop_time, q_end=floats(final_q) if known else [])],
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

    def _ptp(
        self, ref: ReferenceTable, path: str, p1: np.ndarray, R1: np.ndarray, sp: float, ac: float
    ) -> None:
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

    def _lin(
        self, ref: ReferenceTable, path: str, p1: np.ndarray, R1: np.ndarray, sp: float, ac: float
    ) -> float:
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
        times, qs, qds, asked = line_rows(
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
    def _action(self, ref: ReferenceTable, act: m.Action, path: str, task: str) -> PlanStep:
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
            floats(ref.q),
            slowed,
        )

    def _last_frame(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The last joint's frame (R, p) at q: what a grasped object hangs on."""
        R_all, p_all = np.empty((self.n, 3, 3)), np.empty((self.n, 3))
        chain_frames(self._arrays.pre_R, self._arrays.pre_p, q, R_all, p_all)
        return R_all[-1], p_all[-1]

    def _grasp(self, ref: ReferenceTable, name: str, where: str) -> None:
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

    def _release(self, ref: ReferenceTable, where: str) -> None:
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
    the checks the proxy runs on them (holding, the obstacles', the arm against itself), and a pose
    just beyond its reach (the closest-pose search a refusal runs). A kernel left out compiles on a
    session's first command instead: 10 s or more before its answer."""
    from . import get_model

    pkg = get_model("spider")
    q0 = [0.5, 0.2, -0.3, -0.5, -0.3, -0.2, 0.7]
    box = Obstacle(name="warmup", kind="box", position=[2.0, 2.0, 2.0])  # far from the arm
    planner = Planner(pkg, pkg.check_values({}), q0, 1.0, obstacles=[box])
    p, R = planner.kin.tool_pose(np.array(q0))
    rpy = [float(x) for x in rpy_of(R)]
    x, y, z = (float(v) for v in p)
    nodes = [  # a line down, and back up point to point (a move of its own: its samples' kernel)
        m.CartesianNode([x, y, z - 0.01], rpy, "lin"),
        m.CartesianNode([x, y, z], rpy, "ptp"),
    ]
    plan = planner.plan(m.CartesianPath(nodes))
    planner.checks.holding_problem(plan)
    planner.checks.collision(plan)
    planner.checks.self_touch(plan)
    try:
        planner.plan(m.CartesianPath([m.CartesianNode([0.0, 2.2, 0.3], rpy, "ptp")]))
    except CommandError:
        pass
