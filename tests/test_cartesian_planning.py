"""Cartesian moves as a teach pendant builds them (issue 32, item 3): a line too fast for a joint is
time-scaled to the joint limits and says by how much (CommandPlan.slowed), planning costs what the
line's geometry needs whatever its speed, a pose out of reach is refused as out of reach, and what truly
cannot be done (a singularity on the line) is still refused.

No network, no processes: the planner and its numba kernels run in this process. Timing targets live in
`simecs bench commands` (cartesian_plan_ms_max), not here; these tests bound the work instead (rows,
inverse-kinematics solves).
"""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.limits import limit
from simecs.mesh.rules.kinematics import rpy_of
from simecs.models import CommandError, get_model
from simecs.models.ik import ArmKinematics, orientation_error
from simecs.models.line_walk import LINE_OK
from simecs.models.path_checks import PATH_CHECK_STEP
from simecs.models.plan import Plan
from simecs.models.planner import LIN_KNOT_STEP, LIN_KNOT_TURN, LIN_MAX_KNOTS, SINGULAR_SIGMA, Planner
from simecs.models.reference_rows import LIN_TOLERANCE

SPIDER_Q0 = [0.5, 0.2, -0.3, -0.5, -0.3, -0.2, 0.7]
#: The Spider's default pose (a new session's) and a Teach there, then 150 mm along +y at 100 %: the
#: line users saw refused ("joint4 would need 0.441 rad/s ... lower speed_pct").
TEACH_LINE = np.array([0.0, 0.15, 0.0])


def planner(model_id: str, q0: list[float] | None = None, **kw: object) -> Planner:
    pkg = get_model(model_id)
    values = pkg.check_values({})
    return Planner(pkg, values, list(pkg.home()) if q0 is None else q0, 60.0, **kw)  # type: ignore[arg-type]


def taught(p: Planner, d: np.ndarray, sp: float = 100.0, move: str = "lin") -> m.CartesianPath:
    """Teach at the planner's start pose (node 0), then a node `d` m away at `sp` %."""
    p0, R0 = p.kin.tool_pose(p.q0)
    rpy = [float(x) for x in rpy_of(R0)]
    return m.CartesianPath(
        [
            m.CartesianNode([float(x) for x in p0], rpy),
            m.CartesianNode([float(x) for x in p0 + d], rpy, move, sp),
        ]
    )


def rows(plan: Plan, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    assert plan.tab is not None
    return plan.tab[:, 0], plan.tab[:, 1 : 1 + n], plan.tab[:, 1 + n : 1 + 2 * n]


def off_line(kin: ArmKinematics, q: np.ndarray, p0: np.ndarray, p1: np.ndarray, R: np.ndarray) -> float:
    """The larger of the distance (m) from the tool at q to the segment p0-p1 and its turn (rad) off R."""
    p, Rq = kin.tool_pose(q)
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    rel = p - p0
    return max(float(np.linalg.norm(rel - (rel @ u) * u)), float(np.linalg.norm(orientation_error(Rq, R))))


def test_a_line_too_fast_for_a_joint_is_time_scaled_to_the_joint_limits() -> None:
    p = planner("spider")
    command = taught(p, TEACH_LINE)
    plan = p.plan(command)
    summary = plan.summary(60.0)
    assert [s.slowed for s in summary.steps][0] == 1.0  # the taught node: no move
    assert summary.slowed == summary.steps[1].slowed > 1.05
    # Slowed says how much longer than the Cartesian trapezoid asked: 0.15 m at cart.max_speed 0.25 m/s
    # and cart.max_acc 0.5 m/s^2 take 0.5 s + 0.6 s.
    asked = 0.15 / p.values["cart.max_speed"] + p.values["cart.max_speed"] / p.values["cart.max_acc"]
    assert math.isclose(plan.duration, summary.slowed * asked, rel_tol=1e-9)
    t, q, qd = rows(plan, p.n)
    speed = np.max(np.abs(qd), axis=0) / p.vmax
    assert np.all(speed <= 1.0 + 1e-9), speed
    assert np.all(np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None] <= p.vmax * (1.0 + 1e-9))
    assert np.max(speed) > 0.95  # slowed no more than the binding joint needs
    acc = np.abs(np.diff(qd, axis=0)) / np.diff(t)[:, None]
    assert np.all(acc <= p.amax * 1.02), np.max(acc / p.amax, axis=0)
    # Still the same straight line, at every row and between rows (references.ref_eval is linear).
    p0, R0 = p.kin.tool_pose(p.q0)
    p1 = p0 + TEACH_LINE
    worst = max(off_line(p.kin, qk, p0, p1, R0) for qk in q)
    worst_mid = max(off_line(p.kin, 0.5 * (q[k] + q[k + 1]), p0, p1, R0) for k in range(len(q) - 1))
    assert worst <= LIN_TOLERANCE and worst_mid <= LIN_TOLERANCE, (worst, worst_mid)
    assert np.linalg.norm(p.kin.tool_pose(plan.final_q)[0] - p1) < 1e-9
    assert np.all(np.abs(qd[-1]) == 0.0)
    # Planned twice (proxy, then simulator): the same rows.
    again = p.plan(command)
    assert again.tab is not None and np.array_equal(again.tab, plan.tab)


def test_a_slow_line_costs_what_its_geometry_needs_not_its_duration() -> None:
    p = planner("spider")
    fast = p.plan(taught(p, TEACH_LINE))
    slow = p.plan(taught(p, TEACH_LINE, 2.0))
    # 0.15 m at 2 % of 0.25 m/s: 30 s, and 0.01 s of acceleration (a hair longer: joint4's traj.max_acc)
    assert 30.01 - 1e-9 <= slow.duration < 30.1 and slow.summary(60.0).slowed < 1.01
    crawl = p.plan(taught(p, TEACH_LINE, 1e-6))  # about as slow as speed_pct may be: years
    assert crawl.duration > 6e7
    assert fast.tab is not None and slow.tab is not None and crawl.tab is not None
    # Rows where the move curves and accelerates, not one per millisecond (the 2 % line used to take
    # 30,000 rows, each an IK solve); the smallest speed needs no more rows than 2 %.
    assert slow.tab.shape[0] < 300 and crawl.tab.shape[0] <= slow.tab.shape[0] + 10
    assert fast.tab.shape[0] < 300
    p0, R0 = p.kin.tool_pose(p.q0)
    walk = p.kin.walk_line(
        p.q0,
        p0 + TEACH_LINE,
        R0,
        tol_pos=LIN_TOLERANCE / 2,
        tol_rot=LIN_TOLERANCE / 2,
        step=LIN_KNOT_STEP,
        turn=LIN_KNOT_TURN,
        sigma_min=SINGULAR_SIGMA,
        max_knots=LIN_MAX_KNOTS,
    )
    assert walk.status == LINE_OK and walk.solves <= 20, walk.solves
    # The protocol's most nodes, back and forth at 2 %, fits the reference bound.
    p1 = [float(x) for x in p0 + TEACH_LINE]
    rpy = [float(x) for x in rpy_of(R0)]
    nodes = [m.CartesianNode(p1 if k % 2 else [float(x) for x in p0], rpy, "lin", 2.0) for k in range(1000)]
    long = p.plan(m.CartesianPath(nodes))
    assert long.tab is not None and long.tab.shape[0] < limit("reference_samples")


@pytest.mark.parametrize("move", ["lin", "ptp"])
def test_a_pose_out_of_reach_is_refused_as_out_of_reach(move: str) -> None:
    p = planner("spider")
    p0, _R0 = p.kin.tool_pose(p.q0)
    far = p.kin.base + 5.0 * (p0 - p.kin.base) / np.linalg.norm(p0 - p.kin.base)
    with pytest.raises(CommandError) as err:
        p.plan(taught(p, far - p0, move=move))
    assert err.value.field == "nodes[1]"
    assert err.value.reason.startswith(
        "the pose is out of reach: 5.00 m from the arm's base, the arm reaches 2.24 m"
    ), err.value.reason
    if move == "lin":
        assert "the line leaves the workspace by" in err.value.reason
    action = "move_linear" if move == "lin" else "move_to_pose"
    with pytest.raises(CommandError) as err:
        p.plan(m.Task("t", [m.Action(action, {"position": [float(x) for x in far]})]))
    assert err.value.field == "actions[0]" and "out of reach: 5.00 m" in err.value.reason


def test_a_line_beyond_the_workspace_says_the_pose_cannot_be_reached() -> None:
    """Within the reach bound but past what the arm reaches (the Spider's shoulder sits 0.3 m up): the
    solver, not the line, says so, with the closest pose."""
    p = planner("spider", SPIDER_Q0)
    p0, _R0 = p.kin.tool_pose(p.q0)
    edge = p.kin.base + 0.99 * p.kin.reach * (p0 - p.kin.base) / np.linalg.norm(p0 - p.kin.base)
    with pytest.raises(CommandError) as err:
        p.plan(taught(p, edge - p0))
    assert err.value.field == "nodes[1]"
    assert "the pose cannot be reached (out of reach" in err.value.reason, err.value.reason


PUMA_WRIST = [-1.916, 0.962, -0.058, 1.644, 0.131, -0.176]  # joint5 near 0: the wrist nearly singular
PUMA_THROUGH_WRIST = np.array([-0.13, 0.0, 0.15])  # a line that takes joint5 through 0, orientation kept


def test_a_real_singularity_on_the_line_is_still_refused() -> None:
    p = planner("puma560", PUMA_WRIST)
    with pytest.raises(CommandError) as err:
        p.plan(taught(p, PUMA_THROUGH_WRIST))
    assert err.value.field == "nodes[1]" and "crosses a singularity" in err.value.reason, err.value.reason
    assert "split it with a ptp move" in err.value.reason
    with pytest.raises(CommandError) as err:  # however slow: the joint speed it needs is unbounded
        p.plan(taught(p, PUMA_THROUGH_WRIST, 1.0))
    assert "crosses a singularity" in err.value.reason
    assert p.plan(taught(p, PUMA_THROUGH_WRIST, move="ptp")).duration > 0.0  # the pose itself is reachable
    at_zero = planner("puma560", [0.0] * 6)  # the wrist straight: singular where the line starts
    with pytest.raises(CommandError) as err:
        at_zero.plan(taught(at_zero, np.array([0.0, 0.0, -0.05])))
    assert "the line starts at a singular posture" in err.value.reason


def test_the_obstacle_check_looks_between_rows_far_apart() -> None:
    """A joint move's rows sit where it accelerates and brakes; the check samples between them (every
    PATH_CHECK_STEP of the arm's motion), so a box in the middle of its cruise is found."""
    p = planner("spider", SPIDER_Q0)
    target = list(np.array(SPIDER_Q0) + np.array([1.2, 0, 0, 0, 0, 0, 0]))
    mid = np.array(SPIDER_Q0) + np.array([0.6, 0, 0, 0, 0, 0, 0])
    tip, _R = p.kin.tool_pose(mid)
    box = m.Obstacle("box1", "box", [float(x) for x in tip], size=[0.05, 0.05, 0.05])
    p = planner("spider", SPIDER_Q0, obstacles=[box])
    plan = p.plan(m.Task("t", [m.Action("move_joints", {"q": target, "speed_pct": 50.0})]))
    assert plan.tab is not None
    t, q, _qd = rows(plan, p.n)
    assert np.max(np.abs(np.diff(q, axis=0)).sum(axis=1)) * p.kin.reach > 10 * PATH_CHECK_STEP  # far apart
    touch = p.checks.collision(plan)
    assert touch is not None and touch[0] == "command.actions[0]" and "box1" in touch[1], touch


def test_a_client_that_knows_no_slowed_reads_the_plan_and_one_that_does_reads_one() -> None:
    old = {"kind": "cartesian_path", "duration": 1.0, "steps": [], "final_q": [0.0]}
    plan = msgspec.json.decode(msgspec.json.encode(old), type=m.CommandPlan)
    assert plan.slowed == 1.0
    step = m.PlanStep("nodes[0]", "lin", 0.0, 1.0, slowed=1.5)
    assert msgspec.json.decode(msgspec.json.encode(step), type=m.PlanStep).slowed == 1.5
    with pytest.raises(msgspec.ValidationError):
        msgspec.json.decode(b'{"step":"a","what":"lin","start":0,"end":1,"slowed":0.5}', type=m.PlanStep)


def test_a_plan_carries_its_motion_for_a_preview() -> None:
    """Issue 32: a client plays the planned move on its arm before Run (MoveIt's Plan/Execute) from the
    server's own set points: `CommandPlan.motion`, at most 200 even samples from the initial pose to
    the command's end; none where the positions are not known before the run (motor currents)."""
    p = planner("spider")
    target = [0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2]
    plan = p.plan(m.JointPath([m.PathNode(target)]))
    motion = plan.summary(10.0).motion
    assert motion is not None and len(motion.t) == m.MOTION_POINTS == len(motion.q)
    assert motion.t[0] == 0.0 and motion.t[-1] == pytest.approx(plan.duration)
    assert np.allclose(motion.q[0], p.q0) and np.allclose(motion.q[-1], target, atol=1e-9)
    assert np.all(np.diff(motion.t) > 0)
    line = plan_of(p, taught(p, np.array([0.0, 0.15, 0.0])))
    assert line.motion is not None and np.allclose(line.motion.q[-1], line.final_q, atol=1e-9)
    currents = m.DirectInput("open_loop", {"joint1": m.StepSignal(amplitude=0.5)})
    assert p.plan(currents).summary(2.0).motion is None


def plan_of(p: Planner, command: m.RobotCommand) -> m.CommandPlan:
    return p.plan(command).summary(60.0)
