"""`simecs bench commands`: the command levels on the full drive train, Spider and PUMA 560.

- `lin_max_deviation_mm`: the tool's largest distance from the ideal straight line during the standard
  LIN move (0.5 m at 50 % speed and acceleration, from a posture away from singularities; the first of
  a fixed list of directions whose line the arm can follow), the run going on 1 s after the move;
- `lin_orientation_error_mrad`: the largest angle between the tool's orientation and the reference's
  (the slerp, through the joint set points) at the same instant;
- `lin_end_error_mm`: where the tool ends, 1 s after the move, against the target;
- `ik_position_error_m`: the worst position error of IK over random reachable targets, each solved from a
  seed 0.3 rad (per joint, random sign) away from the posture it was made from; `ik_ms_p50` its median;
- `expand_ms`: planning a 20-action mission (four tasks of joint, line, point-to-point, wait and home
  moves) from the initial pose, median of 5;
- `cartesian_plan_ms_max`: the longest planning (`Planner.plan`, what `set_command` runs) of the
  Cartesian paths a teach pendant builds, each the median of PLAN_REPEATS (target: at most 1000 ms,
  planned or refused): from the model's default pose (where a new session starts) Teach, then a
  PENDANT_LINE m LIN at 100 % along each of DIRECTIONS; the same at 2 % and a PTP there, along the one
  the joint limits slowed most; a LIN and a PTP to a pose 5 m from the arm's base, and to one at EDGE
  of its reach bound (past what it reaches: the solver refuses it); and from the standard posture a
  path of the protocol's most nodes (PENDANT_NODES: back and forth along the first line the arm can
  follow there, every tenth node a PTP, every third at 2 %); `cartesian_plan_ms_1000_nodes` is that
  path's time;
- `cartesian_lin_slowed`: the largest `CommandPlan.slowed` of those LINs at 100 % (how much the joint
  limits time-scaled it; 0 when all were refused);
- `rtf_cartesian`: simulated s per wall s of the LIN run, as fast as possible (one core, best of 3);
- `open_loop_torque_error`: |mean tau_motor - kt * i| / (kt * i) over 5-30 ms after an open-loop
  current step of 1 A on joint 3 (the ripple, detent and current loop stay in), while the motor is
  still slow; `open_loop_torque_ratio_300ms` is tau_motor / (kt * i) at 0.3 s, when the motor turns
  fast: field-oriented current loops (`current.rotor_frame` 1, every model's default) keep it near 1;
  the paper's stationary-frame PIs (`current.rotor_frame` 0) lag the sinusoidal phase currents there,
  and the torque per ampere falls to about 0.4 (tests/test_current_loop.py).

Each key is the worst of the two models; `per_model` has every figure per model.
"""

from __future__ import annotations

import json
import statistics
import time
from typing import Any, NamedTuple

import numpy as np

LINE_LENGTH = 0.5
RTF_REPEATS = 3
PLAN_REPEATS = 3
PENDANT_LINE = 0.15
PENDANT_NODES = 1000
EDGE = 0.995  # of the reach bound: a pose past the arm's workspace that only the solver can refuse
POSTURES = {
    "spider": [0.5, 0.2, -0.3, -0.5, -0.3, -0.2, 0.7],
    "puma560": [0.2, -0.7, 0.5, 0.5, 1.0, 1.2],
}
DIRECTIONS = [(0, 0, -1), (0, 0, 1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (1, 1, 0), (1, -1, 0)]


def _planner(model_id: str, stop_time: float) -> tuple[Any, Any]:
    """(the model, a Planner of it at its default values from its standard posture)."""
    from simecs import models
    from simecs.models.planner import Planner

    pkg = models.get_model(model_id)
    return pkg, Planner(pkg, pkg.check_values({}), POSTURES[model_id], stop_time)


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)))


class StandardLine(NamedTuple):
    """The standard LIN move of a model: its planner, plan, start point and target."""

    pkg: Any
    planner: Any
    plan: Any
    p0: np.ndarray
    target: np.ndarray


def standard_line(model_id: str) -> StandardLine:
    """LINE_LENGTH m at 50 % from the model's standard posture, along the first of DIRECTIONS the arm
    can follow (the same move for every bench that quotes "the standard LIN move")."""
    from simecs import models
    from simecs.mesh.protocol import messages as m
    from simecs.mesh.rules.kinematics import rpy_of

    pkg, planner = _planner(model_id, 60.0)
    p0, R0 = planner.kin.tool_pose(planner.q0)
    rpy0 = list(rpy_of(R0))
    for d in DIRECTIONS:
        target = p0 + LINE_LENGTH * np.asarray(d, float) / np.linalg.norm(d)
        try:
            plan = planner.plan(m.CartesianPath([m.CartesianNode(list(target), rpy0, "lin", 50.0, 50.0)]))
        except models.CommandError:
            continue
        return StandardLine(pkg, planner, plan, p0, target)
    raise RuntimeError(f"no standard line fits {model_id} from {planner.q0}")


def run_line(
    line: StandardLine, control_system: str = "joint_independent"
) -> tuple[list[str], np.ndarray, float]:
    """(columns, rows, best wall time of RTF_REPEATS) of the line and 1 s after it, as fast as possible."""
    stop = line.plan.duration + 1.0
    walls = []
    for _ in range(RTF_REPEATS):  # the machine may be shared: the best of a few
        sim = line.pkg.build(line.planner.values)
        sim.set_initial(line.planner.q0)
        line.plan.apply(sim)
        sim.set_control(control_system, 0.001)
        sim.start(stop, 0.002)
        t0 = time.perf_counter()
        rows = [sim.advance(0.0)]
        while not sim.finished:
            rows.append(sim.advance(sim.time + 0.05))
        walls.append(time.perf_counter() - t0)
        data = np.vstack(rows)
        cols = list(sim.columns)
        sim.close()
    return cols, data, min(walls)


def _lin(model_id: str) -> dict[str, float]:
    from simecs.mesh.rules.kinematics import matrix_from_quat

    line = standard_line(model_id)
    pkg, planner, plan, p0, target = line
    cols, data, wall = run_line(line)
    stop = plan.duration + 1.0
    tool = data[:, [cols.index(f"pose.tool.{f}") for f in ("x", "y", "z", "qw", "qx", "qy", "qz")]]
    qref = data[:, [cols.index(f"joint{j + 1}.q_ref") for j in range(pkg.n)]]
    d = (target - p0) / np.linalg.norm(target - p0)
    rel = tool[:, :3] - p0
    deviation = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
    orientation = [
        _angle(matrix_from_quat(tool[k, 3:]), planner.kin.tool_pose(qref[k])[1])
        for k in range(0, len(data), 5)
    ]
    return {
        "lin_max_deviation_mm": float(deviation.max() * 1000),
        "lin_orientation_error_mrad": float(max(orientation) * 1000),
        "lin_end_error_mm": float(np.linalg.norm(tool[-1, :3] - target) * 1000),
        "lin_duration_s": float(plan.duration),
        "rtf_cartesian": float(stop / wall),
    }


def _ik(model_id: str, count: int = 200) -> dict[str, float]:
    from simecs import models
    from simecs.models.ik import ArmKinematics

    pkg = models.get_model(model_id)
    kin = ArmKinematics(pkg.spec, pkg.check_values({}))
    rng = np.random.default_rng(7)
    errors: list[float] = []
    times: list[float] = []
    while len(times) < count:
        q = rng.uniform(np.maximum(kin.lower, -2.5), np.minimum(kin.upper, 2.5))
        if kin.sigma_min(q) < 1e-2:
            continue
        seed = np.clip(q + 0.3 * rng.choice([-1.0, 1.0], kin.n), kin.lower, kin.upper)
        p, R = kin.tool_pose(q)
        t0 = time.perf_counter()
        res = kin.solve(p, R, seed)
        times.append(time.perf_counter() - t0)
        if res.ok:
            errors.append(res.position_error)
    return {
        "ik_position_error_m": float(max(errors)),
        "ik_solved_fraction": len(errors) / count,
        "ik_ms_p50": float(statistics.median(times) * 1000),
    }


def _mission(model_id: str) -> dict[str, float]:
    from simecs.mesh.protocol import messages as m

    _pkg, planner = _planner(model_id, 600.0)
    q0 = planner.q0
    p0, _ = planner.kin.tool_pose(q0)
    tasks = []
    for k in range(4):
        q = list(q0 + 0.05 * (k + 1))
        pk, _ = planner.kin.tool_pose(np.array(q))
        tasks.append(
            m.Task(
                f"t{k}",
                [
                    m.Action("move_joints", {"q": q}),
                    m.Action("move_linear", {"position": list(pk + np.array([0.0, 0.0, -0.04]))}),
                    m.Action("move_to_pose", {"position": list(p0)}),
                    m.Action("wait", {"duration": 0.2}),
                    m.Action("home", {"speed_pct": 50.0}),
                ],
            )
        )
    mission = m.Mission("bench", tasks)
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        planner.plan(mission)
        times.append(time.perf_counter() - t0)
    return {"expand_ms": float(statistics.median(times) * 1000)}


def _pendant(model_id: str) -> dict[str, float]:
    from simecs import models
    from simecs.mesh.protocol import messages as m
    from simecs.mesh.rules.kinematics import rpy_of
    from simecs.models.planner import Planner

    pkg = models.get_model(model_id)
    values = pkg.check_values({})

    class Start(NamedTuple):
        """A planner from a pose, and the tool pose there (what Teach records)."""

        planner: Any
        p: np.ndarray
        rpy: list[float]

        def node(self, d: np.ndarray, sp: float = 100.0, move: str = "lin") -> m.CartesianNode:
            return m.CartesianNode([float(x) for x in self.p + d], self.rpy, move, sp)  # type: ignore[arg-type]

        def plan_ms(self, nodes: list[m.CartesianNode]) -> tuple[float, Any]:
            """The median planning time of the path (ms), and its plan (None: refused)."""
            times, plan = [], None
            for _ in range(PLAN_REPEATS):
                t0 = time.perf_counter()
                try:
                    plan = self.planner.plan(m.CartesianPath(nodes))
                except models.CommandError:
                    plan = None
                times.append(time.perf_counter() - t0)
            return statistics.median(times) * 1000, plan

    def start(q: list[float]) -> Start:
        planner = Planner(pkg, values, q, 60.0)
        p, R = planner.kin.tool_pose(planner.q0)
        return Start(planner, p, [float(x) for x in rpy_of(R)])

    home = start(list(pkg.home()))  # where a new session starts
    teach = home.node(np.zeros(3))
    figures: dict[str, tuple[float, Any]] = {}
    slowed: dict[int, float] = {}
    steps = [PENDANT_LINE * np.asarray(d, float) / np.linalg.norm(d) for d in DIRECTIONS]
    for k, step in enumerate(steps):
        figures[f"lin_100_{k}"] = home.plan_ms([teach, home.node(step)])
        plan = figures[f"lin_100_{k}"][1]
        if plan is not None:
            slowed[k] = float(plan.summary(60.0).slowed)
    d = steps[max(slowed, key=slowed.__getitem__)] if slowed else steps[0]  # the most slowed
    figures["lin_2"] = home.plan_ms([teach, home.node(d, 2.0)])
    figures["ptp"] = home.plan_ms([teach, home.node(d, move="ptp")])
    kin = home.planner.kin
    away = (home.p - kin.base) / np.linalg.norm(home.p - kin.base)
    for name, dist in (("far", 5.0), ("edge", EDGE * kin.reach)):
        target = kin.base + dist * away - home.p
        figures[f"{name}_lin"] = home.plan_ms([teach, home.node(target)])
        figures[f"{name}_ptp"] = home.plan_ms([teach, home.node(target, move="ptp")])
    standard = start(POSTURES[model_id])
    ds = next((step for step in steps if standard.plan_ms([standard.node(step)])[1] is not None), steps[0])
    figures["nodes_1000"] = standard.plan_ms(
        [
            standard.node(ds * (k % 2), 2.0 if k % 3 == 2 else 100.0, "ptp" if k % 10 == 9 else "lin")
            for k in range(PENDANT_NODES)
        ]
    )
    return {
        "cartesian_plan_ms_max": max(ms for ms, _plan in figures.values()),
        "cartesian_plan_ms_1000_nodes": figures["nodes_1000"][0],
        "cartesian_lin_slowed": max(slowed.values(), default=0.0),
    }


def _open_loop(model_id: str) -> dict[str, float]:
    from simecs.mesh.protocol import messages as m

    pkg, planner = _planner(model_id, 0.3)
    values, q0 = planner.values, planner.q0
    amps = 1.0
    plan = planner.plan(m.DirectInput("open_loop", {"joint3": m.StepSignal(amplitude=amps)}))
    sim = pkg.build(values)
    sim.set_initial(q0)
    plan.apply(sim)
    sim.start(0.3, 0.001)
    data = sim.advance(1.0)
    cols = list(sim.columns)
    sim.close()
    t = data[:, 0]
    torque = data[:, cols.index("joint3.tau_motor")]
    ideal = values["joint3.motor.kt"] * amps
    early = torque[(t >= 0.005) & (t <= 0.03)].mean()
    return {
        "open_loop_torque_error": float(abs(early - ideal) / ideal),
        "open_loop_torque_ratio_300ms": float(torque[-1] / ideal),
    }


def run_commands_bench(as_json: bool = False) -> dict[str, Any]:
    from simecs.models import warmup

    warmup()
    per_model: dict[str, dict[str, float]] = {}
    for model_id in POSTURES:
        figures: dict[str, float] = {}
        for part in (_lin, _ik, _mission, _pendant, _open_loop):
            figures.update(part(model_id))
        per_model[model_id] = figures
    worst_is_low = {"rtf_cartesian", "ik_solved_fraction", "open_loop_torque_ratio_300ms"}
    keys = list(next(iter(per_model.values())))
    result: dict[str, Any] = {
        k: (min if k in worst_is_low else max)(f[k] for f in per_model.values()) for k in keys
    }
    result["per_model"] = per_model
    print_per_model(result, as_json, 32)
    return result


def print_per_model(result: dict[str, Any], as_json: bool, width: int) -> None:
    """A bench's result as JSON, or its `per_model` figures as a table (name column `width` wide)."""
    if as_json:
        print(json.dumps(result, indent=1))
        return
    for model_id, figures in result["per_model"].items():
        print(model_id)
        for k, v in figures.items():
            print(f"  {k:{width}s} {v:12.4g}")
