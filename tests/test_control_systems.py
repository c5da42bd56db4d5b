"""The control systems of paper §5 (issue 17): operational-space motion control beside the
joint-independent cascade, on the same drive train.

Through the service (real processes, a real mesh): a straight-line move under operational-space control
reaches its target and holds it, the tool columns agree with an independent forward kinematics, and
every refusal names its field. On the simulation itself: the controller is digital (its current set
points change only once per control period) and holds the Spider's redundant freedom on the planner's
posture.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from simecs import models
from simecs.mesh.client import RemoteError, SessionClient
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.primitives import FieldProblem
from simecs.mesh.rules.kinematics import matrix_from_quat, rot_rpy, rpy_of
from simecs.models.contact_geometry import TOOL_RADIUS
from simecs.models.planner import Planner

from tests.conftest import Service
from tests.test_commands import SPIDER_Q0, kinematics, run_to_end, tool_columns

HOLD_S = 1.0  # the run goes on this long after the move: the controller must hold the target


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)))


def _line(s: SessionClient) -> tuple[np.ndarray, np.ndarray, m.CommandPlan]:
    """A 0.2 m straight line with a 0.15 rad turn of the tool, set as the session's command."""
    kin = kinematics("spider")
    p0, R0 = kin.tool_pose(np.array(SPIDER_Q0))
    p1 = p0 + np.array([0.12, -0.1, -0.12])
    R1 = rot_rpy([0.0, 0.0, 0.15]) @ R0
    plan = s.set_command(m.CartesianPath([m.CartesianNode(list(p1), list(rpy_of(R1)), "lin", 50.0, 50.0)]))
    return p1, R1, plan


@pytest.mark.shares_service
def test_opspace_motion_reaches_a_cartesian_target_and_holds_it(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    assert "opspace_motion" in service.client.describe("spider").control_systems
    s.set_initial(SPIDER_Q0)
    p1, R1, plan = _line(s)
    cols, rows = run_to_end(s, plan, HOLD_S, control_system="opspace_motion")
    assert s.snapshot().settings.control_system == "opspace_motion"
    t = rows[:, 0]
    tool = rows[:, tool_columns(cols)]
    hold = t >= plan.duration
    # Holding: over the second after the move the tool stays within 0.5 mm and 2 mrad of the target
    # (bench control: about 0.1 mm at rest on this move, as under the joint cascade).
    dist = np.linalg.norm(tool[hold, :3] - p1, axis=1)
    assert dist.max() < 0.5e-3, f"held {dist.max() * 1e3:.3f} mm from the target"
    turn = max(_angle(matrix_from_quat(row[3:]), R1) for row in tool[hold][::10])
    assert turn < 2e-3, f"held {turn * 1e3:.3f} mrad from the target orientation"
    # Moving: the tool follows the line, within 1 mm of its set point at every sample.
    e_pos = rows[:, cols.index("tool.e_pos")]
    assert e_pos.max() < 1e-3, f"{e_pos.max() * 1e3:.3f} mm behind the set point"
    # The tool columns are what an independent forward kinematics of the set points says.
    kin = kinematics("spider")
    q_ref = rows[:, [cols.index(f"joint{j}.q_ref") for j in range(1, 8)]]
    for k in range(0, len(rows), 97):
        p_ref, R_ref = kin.tool_pose(q_ref[k])
        ref_cols = [cols.index(f"tool.{a}_ref") for a in "xyz"]
        assert np.allclose(rows[k, ref_cols], p_ref, atol=1e-9)
        assert abs(e_pos[k] - np.linalg.norm(p_ref - tool[k, :3])) < 1e-9
        e_rot = rows[k, cols.index("tool.e_rot")]
        assert abs(e_rot - _angle(matrix_from_quat(tool[k, 3:]), R_ref)) < 1e-6
    # The same command under the joint cascade: another controller drives the same drives.
    cols_j, rows_j = run_to_end(s, plan, HOLD_S, control_system="joint_independent")
    i_op = rows[:, cols.index("joint2.i_ref")]
    i_ji = rows_j[:, cols_j.index("joint2.i_ref")]
    assert np.max(np.abs(i_op - i_ji)) > 0.05
    assert np.linalg.norm(rows_j[-1, tool_columns(cols_j)][:3] - p1) < 0.5e-3


@pytest.mark.shares_service
def test_control_system_refusals_name_their_field(service: Service) -> None:
    client = service.client
    s = client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    # Not a control system: the decoder names the field.
    raw = {"op": "set_settings", "settings": {"control_system": "fuzzy"}}
    with pytest.raises(RemoteError) as err:
        client.request(keys.cmd(s.user, s.id), json.dumps(raw).encode())
    assert err.value.field == "settings.control_system"
    # A built-in control system with an external controller: both cannot drive the joints.
    raw = {"op": "set_settings", "settings": {"control_system": "opspace_motion", "controller": "external"}}
    with pytest.raises(RemoteError) as err:
        client.request(keys.cmd(s.user, s.id), json.dumps(raw).encode())
    assert err.value.field == "settings.control_system" and "builtin" in err.value.error.message
    with pytest.raises(FieldProblem):
        m.RunSettings(control_system="opspace_motion", controller="external")
    # A period that is not a whole number of solver steps.
    with pytest.raises(RemoteError) as err:
        s.set_settings(control_system="opspace_motion", step=0.001, control_period=0.0015)
    assert err.value.field == "settings.control_period"
    # Open-loop currents cannot be tracked in task space: refused at run, and at set_settings once set.
    s.set_settings(control_system="opspace_motion")
    s.set_command(m.DirectInput("open_loop", {"joint2": m.StepSignal(amplitude=0.5)}))
    with pytest.raises(RemoteError) as err:
        s.run()
    assert err.value.field == "settings.control_system" and "joint_independent" in err.value.error.message
    s.set_settings(control_system="joint_independent")
    with pytest.raises(RemoteError) as err:
        s.set_settings(control_system="opspace_motion")
    assert err.value.field == "settings.control_system"
    assert s.snapshot().settings.control_system == "joint_independent"
    assert s.snapshot().runs == []


def _simulate(model_id: str, q0: list[float], command: m.RobotCommand, stop: float, **kw: float) -> tuple:
    pkg = models.get_model(model_id)
    values = pkg.check_values({})
    plan = Planner(pkg, values, q0, stop).plan(command)
    sim = pkg.build(values)
    sim.set_initial(q0)
    plan.apply(sim)
    sim.set_control("opspace_motion", kw.get("period", 0.001))
    sim.start(stop, kw.get("output", 0.002))
    rows = [sim.advance(0.0)]
    while not sim.finished:
        rows.append(sim.advance(sim.time + 0.1))
    cols = list(sim.columns)
    sim.close()
    return cols, np.vstack(rows), plan


def test_the_controller_is_digital_its_set_points_held_for_a_period() -> None:
    q_end = list(np.array(SPIDER_Q0) + 0.1)
    cols, rows, _ = _simulate(
        "spider", SPIDER_Q0, m.JointPath([m.PathNode(q_end)]), 1.0, period=0.004, output=0.001
    )
    i_ref = rows[:, [cols.index(f"joint{j}.i_ref") for j in range(1, 8)]]
    changed = np.flatnonzero(np.any(np.diff(i_ref, axis=0) != 0.0, axis=1)) + 1  # rows where it changed
    assert len(changed) > 100  # it does control
    # Only once per period: a row at t shows the state at t, the left limit of an update made at t,
    # so a new set point shows first in the sample after the period's start.
    assert np.all(np.round((rows[changed, 0] - 0.001) / 0.004, 6) % 1 == 0)


def test_the_spider_redundancy_follows_the_planned_posture() -> None:
    """Seven joints, six task coordinates: the null-space task keeps the joints on the planner's
    posture, so the arm does not drift along its self-motion while the tool is held."""
    kin = kinematics("spider")
    p0, R0 = kin.tool_pose(np.array(SPIDER_Q0))
    cmd = m.CartesianPath([m.CartesianNode(list(p0 + np.array([0.0, 0.0, -0.2])), list(rpy_of(R0)))])
    cols, rows, plan = _simulate("spider", SPIDER_Q0, cmd, 4.0)
    q = rows[:, [cols.index(f"joint{j}.q") for j in range(1, 8)]]
    q_ref = rows[:, [cols.index(f"joint{j}.q_ref") for j in range(1, 8)]]
    assert np.max(np.abs(q - q_ref)) < 5e-3, np.max(np.abs(q - q_ref), axis=0)
    assert rows[-1, cols.index("tool.e_pos")] < 0.5e-3


HYBRID_FORCE_N = 20.0


@pytest.mark.shares_service
def test_opspace_hybrid_slides_on_a_plane_holding_the_commanded_force(service: Service) -> None:
    """The tool touches a plane above it and slides 0.1 m along it, pushing with 20 N (paper §5's
    hybrid control: force along the plane's normal, motion along the plane). Tolerances: at rest the
    force integral leaves under 1 N (5 %) of error; while sliding the joints' stick-slip friction
    disturbs the force loop (30 rad/s on this 1e5 N/m plane) by a few N: RMS under 4 N (20 %), the
    mean within 1 N. The tool keeps to its line across the axis within 1 mm."""
    s = service.client.create_session("ann", "spider")
    q0 = [0.0] * 7
    s.set_initial(q0)
    kin = kinematics("spider")
    p0, R0 = kin.tool_pose(np.array(q0))  # the tool points up
    lid = m.Obstacle("lid", "plane", [float(p0[0]), float(p0[1]), float(p0[2] + TOOL_RADIUS)], [np.pi, 0, 0])
    s.set_obstacles([lid])
    end = p0 + np.array([0.1, 0.0, 0.0])
    node = m.CartesianNode(list(end), list(rpy_of(R0)), "lin", 20.0, 20.0, HYBRID_FORCE_N, [0.0, 0.0, 1.0])
    plan = s.set_command(m.CartesianPath([node]))
    # A force set point needs the hybrid controller: refused under the others, naming the setting.
    with pytest.raises(RemoteError) as err:
        s.run()
    assert err.value.error.field == "settings.control_system" and "opspace_hybrid" in err.value.error.message
    # The tool touches the plane on purpose while it pushes: the path check lets it.
    cols, rows = run_to_end(s, plan, 1.0, control_system="opspace_hybrid")
    t = rows[:, 0]
    fn = rows[:, cols.index("contact.tool_fn")]
    sliding = (t >= 0.5) & (t <= plan.duration)
    rest = t >= t[-1] - 0.5
    assert np.sqrt(np.mean((fn[rest] - HYBRID_FORCE_N) ** 2)) < 1.0, fn[rest]
    assert np.sqrt(np.mean((fn[sliding] - HYBRID_FORCE_N) ** 2)) < 4.0
    assert abs(np.mean(fn[sliding]) - HYBRID_FORCE_N) < 1.0
    assert fn[sliding].min() > 0.0, "the tool never lifts off the plane"
    tip = rows[:, tool_columns(cols)][:, :3]
    assert np.abs(tip[:, 1] - p0[1]).max() < 1e-3
    assert abs(tip[-1, 0] - end[0]) < 1e-3, "it slid to the end of its line"
    # The force pushes the tool up into the plane, which pushes back down on it.
    assert rows[-1, cols.index("contact.tool_fz")] < -0.9 * HYBRID_FORCE_N


def _hybrid_slide(stiffness: float, twist_damping: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The hybrid case above in process, on a plane of `stiffness` N/m: (t, contact.tool_fn, the
    plan's duration), with each joint's ctrl.twist_damping set."""
    pkg = models.get_model("spider")
    values = pkg.check_values({f"joint{j}.ctrl.twist_damping": twist_damping for j in range(1, 8)})
    q0 = np.zeros(7)
    planner = Planner(pkg, values, q0, 5.0)
    p0, R0 = planner.kin.tool_pose(q0)
    lid = m.Obstacle("lid", "plane", [*p0[:2], p0[2] + TOOL_RADIUS], [np.pi, 0, 0], stiffness=stiffness)
    end = p0 + np.array([0.1, 0.0, 0.0])
    node = m.CartesianNode(list(end), list(rpy_of(R0)), "lin", 20.0, 20.0, HYBRID_FORCE_N, [0.0, 0.0, 1.0])
    plan = planner.plan(m.CartesianPath([node]))
    sim = pkg.build(values)
    try:
        sim.set_obstacles([lid])
        sim.set_initial(q0)
        plan.apply(sim)
        sim.set_control("opspace_hybrid", 0.001)
        sim.start(plan.duration + 1.0, 0.002)
        rows = [sim.advance(0.0)]
        while not sim.finished:
            rows.append(sim.advance(sim.time + 0.1))
        cols = list(sim.columns)
    finally:
        sim.close()
    data = np.vstack(rows)
    return data[:, 0], data[:, cols.index("contact.tool_fn")], plan.duration


def test_the_twist_damping_keeps_the_force_loop_from_ringing_on_soft_and_stiff_surfaces() -> None:
    """The field-oriented drives leave the motors' mode on their elastic gears undamped (31 Hz on the
    large drives with the link held); the operational-space laws damp it from the gear's twist rate.
    Without it the tool bounces off a 1e6 N/m plane; with it the slide holds its 20 N there and on a
    soft 1e4 N/m one."""
    for stiffness in (1e4, 1e6):
        t, fn, duration = _hybrid_slide(stiffness, 0.3)
        sliding = (t >= 0.5) & (t <= duration)
        rms = float(np.sqrt(np.mean((fn[sliding] - HYBRID_FORCE_N) ** 2)))
        assert rms < 1.5 and fn[sliding].min() > 15.0, (stiffness, rms, fn[sliding].min())
    t, fn, duration = _hybrid_slide(1e6, 0.0)
    sliding = (t >= 0.5) & (t <= duration)
    assert fn[sliding].min() == 0.0, "without the twist damping the tool lifts off the stiff plane"
