"""Every command level of paper §2.1 end to end through the service: real processes, a real mesh.

A Cartesian line, a point-to-point move to a pose, an open-loop current step, a closed-loop set point,
and a saved mission; each run on the full drive train and judged on the results a client reads back.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from simecs import models
from simecs.mesh.client import RemoteError, SessionClient
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.kinematics import matrix_from_quat, rot_rpy, rpy_of
from simecs.models.ik import ArmKinematics
from simecs.nodes.recording import mcapread

from tests.conftest import Mesh, Service, restart_every_node, start_service, wait_until
from tests.test_recorder_support import wait_file_closed
from tests.test_service import Recorder

# Postures well away from singularities (smallest singular value of the tool Jacobian ~0.3-0.5).
SPIDER_Q0 = [0.5, 0.2, -0.3, -0.5, -0.3, -0.2, 0.7]
PUMA_Q0 = [0.2, -0.7, 0.5, 0.5, 1.0, 1.2]


def kinematics(model_id: str) -> ArmKinematics:
    pkg = models.get_model(model_id)
    return ArmKinematics(pkg.spec, pkg.check_values({}))


def tool_columns(columns: list[str]) -> list[int]:
    return [columns.index(f"pose.tool.{f}") for f in ("x", "y", "z", "qw", "qx", "qy", "qz")]


def run_to_end(
    s: SessionClient, plan: m.CommandPlan, after: float = 1.0, **settings: Any
) -> tuple[list[str], np.ndarray]:
    """Run the planned command to its end and `after` s more, as fast as possible; its results."""
    s.set_settings(
        stop_time=round(plan.duration + after, 3), output_interval=0.002, pacing="fast", **settings
    )
    run_id = s.run()
    state = s.wait_for(["finished", "failed"], 120, run_id)
    assert state.phase == "finished", state.reason
    return s.results(run_id)


@pytest.mark.shares_service
def test_a_lin_move_ends_on_its_target_and_stays_near_its_line(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    kin = kinematics("spider")
    p0, R0 = kin.tool_pose(np.array(SPIDER_Q0))
    p1 = p0 + np.array([0.12, -0.08, -0.06])
    rpy1 = rpy_of(rot_rpy([0.0, 0.0, 0.15]) @ R0)
    plan = s.set_command(m.CartesianPath([m.CartesianNode(list(p1), list(rpy1), "lin", 50.0, 50.0)]))
    assert plan.kind == "cartesian_path" and plan.duration > 0.5 and not plan.stop_time_cuts
    assert [st.step for st in plan.steps] == ["nodes[0]"]
    assert np.linalg.norm(np.array(plan.tool_path[-1]) - p1) < 1e-6
    p_end, _R = kin.tool_pose(np.array(plan.steps[0].q_end))  # where a pendant draws the arm
    assert np.linalg.norm(p_end - p1) < 1e-6 and plan.steps[0].q_end == plan.final_q
    cols, rows = run_to_end(s, plan)
    tool = rows[:, tool_columns(cols)]
    end = tool[-1]
    assert np.linalg.norm(end[:3] - p1) < 2e-3, f"LIN ends {np.linalg.norm(end[:3] - p1) * 1000:.2f} mm off"
    R_end = matrix_from_quat(end[3:])
    angle = np.arccos(np.clip((np.trace(R_end.T @ rot_rpy(rpy1)) - 1) / 2, -1, 1))
    assert angle < 5e-3, f"orientation {angle * 1000:.2f} mrad off"
    # Every sample of the tool stays close to the straight line from p0 to p1.
    d = (p1 - p0) / np.linalg.norm(p1 - p0)
    rel = tool[:, :3] - p0
    off_line = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
    assert off_line.max() < 5e-3, f"{off_line.max() * 1000:.2f} mm from the line"
    along = rel @ d
    assert along.min() > -2e-3 and along.max() < np.linalg.norm(p1 - p0) + 2e-3


@pytest.mark.shares_service
def test_a_ptp_move_to_a_pose_reaches_it_on_the_puma(service: Service) -> None:
    s = service.client.create_session("ann", "puma560")
    s.set_initial(PUMA_Q0)
    kin = kinematics("puma560")
    target_q = np.array(PUMA_Q0) + np.array([0.5, 0.3, -0.3, 0.4, -0.3, 0.5])
    p1, R1 = kin.tool_pose(target_q)
    plan = s.set_command(m.CartesianPath([m.CartesianNode(list(p1), list(rpy_of(R1)), "ptp")]))
    p_end, R_end = kin.tool_pose(np.array(plan.steps[0].q_end))
    assert np.linalg.norm(p_end - p1) < 1e-6 and np.allclose(R_end, R1, atol=1e-6)
    cols, rows = run_to_end(s, plan, after=1.5)
    end = rows[-1, tool_columns(cols)]
    assert np.linalg.norm(end[:3] - p1) < 2e-3
    # The arm went through joint space, not along a line: the planned path bends.
    path = np.array(plan.tool_path)
    chord = (p1 - path[0]) / np.linalg.norm(p1 - path[0])
    rel = path - path[0]
    assert np.max(np.linalg.norm(rel - np.outer(rel @ chord, chord), axis=1)) > 5e-3


IMPORTED = ["panda", "ur5", "jaco2"]


@pytest.mark.parametrize("model_id", IMPORTED)
@pytest.mark.shares_service
def test_an_imported_model_runs_a_joint_and_a_cartesian_move(service: Service, model_id: str) -> None:
    """Each model imported from URDF takes the same commands as the Spider, through the service."""
    pkg = models.get_model(model_id)
    home, target = list(pkg.home()), list(pkg.spec.standard_target)
    s = service.client.create_session("ann", model_id)
    s.set_initial(home)
    plan = s.set_command(m.JointPath([m.PathNode(target)]))
    cols, rows = run_to_end(s, plan, after=0.5)
    q_end = [rows[-1, cols.index(f"joint{j}.q")] for j in range(1, len(home) + 1)]
    assert np.max(np.abs(np.array(q_end) - target)) < 2e-3
    s.set_initial(target)
    kin = kinematics(model_id)
    p0, R0 = kin.tool_pose(np.array(target))
    p1 = p0 + np.array([0.05, -0.04, 0.03])
    rpy1 = rpy_of(rot_rpy([0.0, 0.1, 0.0]) @ R0)
    plan = s.set_command(m.CartesianPath([m.CartesianNode(list(p1), list(rpy1), "lin", 50.0, 50.0)]))
    cols, rows = run_to_end(s, plan)
    end = rows[-1, tool_columns(cols)]
    assert np.linalg.norm(end[:3] - p1) < 2e-3, (
        f"{model_id}: LIN ends {np.linalg.norm(end[:3] - p1) * 1e3:.2f} mm off"
    )
    angle = np.arccos(np.clip((np.trace(matrix_from_quat(end[3:]).T @ rot_rpy(rpy1)) - 1) / 2, -1, 1))
    assert angle < 5e-3


@pytest.mark.shares_service
def test_an_open_loop_current_step_moves_the_joint_as_its_inertia_predicts(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    values = s.snapshot().values
    j = 2  # joint3, the others held by their cascades
    amps = 0.5
    cmd = m.DirectInput("open_loop", {"joint3": m.StepSignal(amplitude=amps, start=0.1)})
    plan = s.set_command(cmd)
    assert plan.steps[0].what == "open_loop"
    # the preview: the server's own expansion of the step, in A; no pose is known before the run
    assert plan.signals is not None and plan.signals.unit == "A" and list(plan.signals.values) == ["joint3"]
    shown = dict(zip(plan.signals.t, plan.signals.values["joint3"], strict=True))
    assert shown[0.0] == 0.0 and plan.signals.values["joint3"][-1] == amps
    assert plan.steps[0].q_end == [] and plan.tool_path == []
    s.set_settings(stop_time=0.6, output_interval=0.002, pacing="fast")
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    cols, rows = s.results(run_id, ["joint3.q", "joint3.i_ref", "joint3.tau_motor"])
    t, q, iref = rows[:, 0], rows[:, 1], rows[:, 2]
    assert np.allclose(iref[t >= 0.1 + 1e-9], amps) and np.allclose(iref[t < 0.1 - 1e-9], iref[0])
    # The prediction: the joint's inertia from the mass matrix plus the reflected rotor and gear.
    sim = models.get_model("spider").build(values)
    M = sim.mass_matrix(SPIDER_Q0)
    n = values["joint3.gear.ratio"]
    inertia = M[j, j] + n**2 * (values["joint3.motor.J_rotor"] + values["joint3.gear.J_gear"])
    torque = values["joint3.motor.kt"] * amps * n * values["joint3.gear.efficiency"]
    predicted = torque / inertia  # rad/s^2
    window = (t > 0.25) & (t < 0.5)
    acc = np.polyfit(t[window], q[window], 2)[0] * 2
    assert acc > 0, f"a positive current turned joint3 backwards ({acc:.3g} rad/s^2)"
    assert 0.3 < acc / predicted < 3.0, f"joint3 accelerates at {acc:.3g} rad/s^2, predicted {predicted:.3g}"
    sim.close()


@pytest.mark.shares_service
def test_a_closed_loop_position_step_settles_and_a_speed_set_point_is_held(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    target = SPIDER_Q0[4] + 0.05
    plan = s.set_command(
        m.DirectInput(
            "closed_loop",
            {"joint5": m.StepSignal(amplitude=0.05, offset=SPIDER_Q0[4], start=0.1)},
            "position",
        )
    )
    # a position signal: where the arm ends and the tool's path are known before the run
    assert plan.signals is not None and plan.signals.unit == "rad"
    assert plan.signals.values["joint5"][-1] == pytest.approx(target)
    assert plan.final_q == pytest.approx([*SPIDER_Q0[:4], target, *SPIDER_Q0[5:]])
    assert plan.steps[0].q_end == plan.final_q and len(plan.tool_path) >= 2
    s.set_settings(stop_time=2.0, output_interval=0.002, pacing="fast")
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    _, rows = s.results(run_id, ["joint5.q", "joint5.q_ref", "joint1.q"])
    assert rows[-1, 2] == pytest.approx(target)
    assert abs(rows[-1, 1] - target) < 1e-3, f"settled {abs(rows[-1, 1] - target) * 1000:.2f} mrad off"
    assert abs(rows[-1, 3] - SPIDER_Q0[0]) < 1e-3  # a joint without a signal holds its place
    s.set_command(m.DirectInput("closed_loop", {"joint1": m.StepSignal(amplitude=0.1)}, "speed"))
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    _, rows = s.results(run_id, ["joint1.qd", "joint1.q"])
    late = rows[:, 0] > 1.0
    assert np.allclose(rows[late, 1], 0.1, atol=0.01)
    assert rows[-1, 2] - SPIDER_Q0[0] == pytest.approx(0.1 * 2.0, abs=0.03)


FIRST_Q = [0.3, 0.3, -0.2, -0.6, -0.2, -0.3, 0.6]


def mission_for_spider() -> m.Mission:
    """Two tasks: a joint move, a line 5 cm down from where it leaves the tool; grasp, wait, home."""
    p, _ = kinematics("spider").tool_pose(np.array(FIRST_Q))
    down = list(p + np.array([0.0, 0.0, -0.05]))
    approach = m.Task(
        "approach",
        [
            m.Action("move_joints", {"q": FIRST_Q, "speed_pct": 80.0}),
            m.Action("move_linear", {"position": down, "speed_pct": 60.0}, "down"),
        ],
    )
    carry = m.Task(
        "carry",
        [
            m.Action("set_payload", {"mass": 2.0}, "grasp"),
            m.Action("wait", {"duration": 0.1}),  # shorter than the 0.2 s between progress reports
            m.Action("home", {"speed_pct": 50.0}),
        ],
    )
    return m.Mission("shift", [approach, carry])


def test_a_saved_mission_survives_a_restart_of_every_node_and_runs_step_by_step(mesh: Mesh) -> None:
    svc = start_service(mesh)
    s = svc.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    mission = mission_for_spider()
    assert s.save_program("shift", mission) == "shift"
    assert s.save_program("approach", mission.tasks[0]) == "approach"
    assert [(e.kind, e.name) for e in s.list_programs()] == [("task", "approach"), ("mission", "shift")]
    restart_every_node(mesh)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    c = mesh.client()
    s = c.session(s.user, s.id)
    loaded = s.load_program("mission", "shift")
    assert loaded == mission
    assert c.create_session("bob", "spider").list_programs() == []
    plan = s.set_command(loaded)
    paths = [st.step for st in plan.steps]
    assert paths == [
        f"tasks[{i}].actions[{k}]" for i, t in enumerate(mission.tasks) for k in range(len(t.actions))
    ]
    assert [st.action for st in plan.steps] == ["move_joints", "down", "grasp", "wait", "home"]
    s.set_settings(stop_time=round(plan.duration + 0.5, 3), output_interval=0.002, pacing="realtime")
    rec = Recorder(s)
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 120, run_id).phase == "finished"
    rec.close()
    seen = [(st.task, st.action) for st in rec.states if st.run_id == run_id and st.step]
    order = [a for i, (_, a) in enumerate(seen) if i == 0 or seen[i - 1][1] != a]
    # every step that lasts a chunk (25 ms) shows in the state as it begins, the short wait too
    assert order == [st.action for st in plan.steps if st.end - st.start >= 0.025], seen
    _, rows = s.results(run_id, [f"joint{j}.q" for j in range(1, 8)])
    assert np.allclose(rows[-1, 1:], 0.0, atol=2e-3)  # home is every joint at 0 for the Spider
    assert s.snapshot().command == mission
    # The recording keeps the command that produced the run (a replay's layout carries it again).
    path = mesh.folder / "rec" / s.user / f"{keys.recording_name(s.id, run_id)}.mcap"
    wait_file_closed(path, timeout=40.0)
    assert mcapread.load(path).context().command == mission


@pytest.mark.shares_service
def test_every_refusal_names_its_field_and_changes_nothing(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    first = s.set_command(m.JointPath([m.PathNode(SPIDER_Q0, 50.0, 50.0)]))
    assert first.kind == "joint_path"
    kin = kinematics("spider")
    p0, R0 = kin.tool_pose(np.array(SPIDER_Q0))
    rpy0 = list(rpy_of(R0))
    far = list(p0 + np.array([3.0, 0.0, 0.0]))
    cases: list[tuple[m.RobotCommand, str, str]] = [
        (m.CartesianPath([m.CartesianNode(far, rpy0, "ptp")]), "command.nodes[0]", "out of reach"),
        (
            m.CartesianPath([m.CartesianNode(list(p0), rpy0, "lin"), m.CartesianNode(far, rpy0, "lin")]),
            "command.nodes[1]",
            "out of reach",
        ),
        (
            m.DirectInput("open_loop", {"joint2": m.StepSignal(amplitude=99.0)}),
            "command.signals.joint2.amplitude",
            "i_max",
        ),
        (
            m.DirectInput("open_loop", {"joint9": m.StepSignal(amplitude=1.0)}),
            "command.signals.joint9",
            "joint",
        ),
        (
            m.DirectInput("closed_loop", {"joint2": m.TableSignal([[0.0, 0.7], [1.0, 9.0]])}),
            "command.signals.joint2.points[1]",
            "outside",
        ),
        (m.Action("wait", {}), "command.args.duration", "needs duration"),
        (m.Action("move_joints", {"q": [0.0] * 6}), "command.args.q", "7"),
        (m.Action("move_linear", {"position": list(p0), "speed": 5.0}), "command.args.speed", "takes"),
        (
            m.Mission(
                "m",
                [
                    m.Task("t", [m.Action("wait", {"duration": 0.1})]),
                    m.Task("u", [m.Action("move_joints", {"q": [9.0] * 7})]),
                ],
            ),
            "command.tasks[1].actions[0].args.q[0]",
            "outside its range",
        ),
        (m.Task("t", [m.Action("set_payload", {"mass": -1.0})]), "command.actions[0].args.mass", "outside"),
    ]
    for command, field, words in cases:
        with pytest.raises(RemoteError) as err:
            s.set_command(command)
        e = err.value
        assert (e.code, e.field) == ("bad_request", field), (command.kind, e.field, e.error.message)
        assert words in e.error.message, (field, e.error.message)
    assert s.snapshot().command == m.JointPath([m.PathNode(SPIDER_Q0, 50.0, 50.0)])
    # A line too fast for the joints is not refused: it is time-scaled to them, and says by how much.
    down = m.Action("move_linear", {"position": list(p0 + np.array([0.0, 0.0, -0.03]))})
    s.set_params({f"joint{j}.traj.max_speed": 0.01 for j in range(1, 8)})
    plan = s.set_command(down)
    assert plan.slowed > 2.0 and plan.steps[0].slowed == plan.slowed
    # A command that fitted when it was set but no longer does once a value changed is refused at run.
    s.set_params({f"link{j}.length": 0.1 for j in range(1, 8)})  # the arm now reaches 0.8 m
    with pytest.raises(RemoteError) as err:
        s.run()
    assert err.value.field == "command" and "out of reach" in err.value.error.message
    assert s.snapshot().runs == []
    with pytest.raises(RemoteError) as err:
        s.load_program("task", "nothing")
    assert err.value.code == "not_found"
    assert s.snapshot().state.phase == "configured"


def test_a_level_the_model_does_not_list_is_unsupported() -> None:
    """Both shipped models take every level; a model that lists fewer is refused before planning."""
    import msgspec
    from simecs.mesh.process.runtime import RequestError
    from simecs.nodes.library import ModelLibrary

    library = ModelLibrary()
    desc = library.describe("puma560")
    assert desc.command_levels == list(m.COMMAND_LEVELS)
    library.descriptions["puma560"] = msgspec.structs.replace(desc, command_levels=["joint_path"])
    mission = m.Mission("m", [m.Task("t", [m.Action("wait", {"duration": 0.1})])])
    with pytest.raises(RequestError) as err:
        library.plan("puma560", desc.default_values(), PUMA_Q0, mission, 1.0)
    assert (err.value.code, err.value.field) == ("unsupported", "command.kind")
    assert "accepts joint_path commands, not mission" in err.value.message


@pytest.mark.shares_service
def test_the_command_is_published_for_every_client_of_the_session(service: Service) -> None:
    """<session>/command carries the command with its plan after each set_command (cached: a late
    subscriber gets the latest); a refused command publishes nothing."""
    s = service.client.create_session("ann", "spider")
    seen: list[m.CommandValue] = []
    with s.watch(on_command=seen.append):
        wait_until(lambda: seen, what="a new session's publication")
        assert seen[-1] == m.CommandValue(s.id, None, None)
        path = m.JointPath([m.PathNode([0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 50.0)])
        plan = s.set_command(path)
        wait_until(lambda: seen[-1].command == path, what="the command published")
        assert seen[-1].plan == plan and plan.duration > 0.0
        published = len(seen)
        with pytest.raises(RemoteError, match="joint1"):
            s.set_command(m.JointPath([m.PathNode([9.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])]))
        assert s.snapshot().command == path
    assert len(seen) == published
    late: list[m.CommandValue] = []
    with s.watch(on_command=late.append):
        wait_until(lambda: late, what="the latest, for a late subscriber")
        assert late[-1].command == path and late[-1].plan == plan
