"""Grasping (issue 17, item 5): an obstacle with a mass is taken by a `grasp` action, carried with the
tool (its mass and inertia the last link's load, its shape touching the rest of the world) and left
where `release` puts it.

Through the service (real processes, a real mesh): a pick-and-place task moves a box by the commanded
displacement, rigidly with the tool while held, and its recording draws the box on the tool, then where
it was put. The grasp's rules are refused before the run, naming the action's field. On the
simulation: a held cube centred on the tool point weighs on the chain exactly as the payload parameters
of the same cube do (an independent path: the payload model), and a grasp the arm does not reach
takes nothing and says so.
"""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import numpy as np
import pytest
from simecs import models
from simecs.mesh.client import RemoteError, SessionClient
from simecs.mesh.protocol import columns, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.kinematics import rpy_of
from simecs.nodes.recording import mcapfmt, mcapread, mcapscene

from tests.conftest import Service
from tests.test_commands import SPIDER_Q0, kinematics, run_to_end
from tests.test_recorder_support import wait_file_closed

EDGE = 0.05  # m, the box's edge
LIFT = np.array([0.0, 0.0, 0.1])
SHIFT = np.array([0.1, 0.0, 0.0])


def _pick_and_place(s: SessionClient) -> tuple[m.Obstacle, m.Task, np.ndarray]:
    """A 2 kg box whose underside is 5 mm over the tool point at SPIDER_Q0 (the tool points up), and
    the task that lifts it, carries it by SHIFT and puts it down there."""
    s.set_initial(SPIDER_Q0)
    p0, R0 = kinematics("spider").tool_pose(np.array(SPIDER_Q0))
    rpy = [float(a) for a in rpy_of(R0)]
    centre = [float(p0[0]), float(p0[1]), float(p0[2]) + 0.005 + EDGE / 2]  # the tool points up
    box = m.Obstacle("box1", "box", centre, size=[EDGE] * 3, mass=2.0, color=[200, 120, 40])

    def line(p: np.ndarray, name: str) -> m.Action:
        args = {"position": [float(x) for x in p], "rpy": rpy, "speed_pct": 60.0}
        return m.Action("move_linear", args, name)

    task = m.Task(
        "pick_and_place",
        [
            m.Action("grasp", {"object": "box1"}),
            line(p0 + LIFT, "lift"),
            line(p0 + LIFT + SHIFT, "carry"),
            line(p0 + SHIFT, "lower"),
            m.Action("release"),
            line(p0 + SHIFT + LIFT / 2, "leave"),
        ],
    )
    return box, task, p0


def test_a_pick_and_place_task_moves_the_box_and_its_recording_shows_it(service: Service) -> None:
    service.mesh.start("recorder", "--dir", str(service.mesh.folder / "rec"))
    s = service.client.create_session("ann", "spider")
    box, task, p0 = _pick_and_place(s)
    plate = s.snapshot().obstacles[0]
    s.set_obstacles([plate, box])
    plan = s.set_command(task)
    assert [st.action for st in plan.steps] == ["grasp", "lift", "carry", "lower", "release", "leave"]
    cols, rows = run_to_end(s, plan, 0.3)  # the path check (collisions refused) lets it through
    c = {name: k for k, name in enumerate(cols)}
    held = rows[:, c[columns.GRASP_HELD]]
    assert np.all(rows[:, c[columns.GRASP_OBJECT]][1:] == 2)  # box1, second in the list
    assert held[1] == 1.0 and held[-1] == 0.0 and np.all(np.diff(held[1:]) <= 0)
    obj = rows[:, [c[columns.pose_column(columns.GRASPED_FRAME, f)] for f in columns.POSE_FIELDS]]
    tool = rows[:, [c[columns.pose_column(columns.TOOL_FRAME, f)] for f in columns.POSE_FIELDS]]
    # Held, the box moves rigidly with the tool: it stays where it was over the tool point.
    carrying = held == 1.0
    carrying[0] = False
    gap = np.linalg.norm(obj[carrying, :3] - tool[carrying, :3], axis=1)
    assert np.ptp(gap) < 1e-9 and abs(gap[0] - (0.005 + EDGE / 2)) < 2e-3
    # Put down by the commanded displacement (to the arm's tracking), orientation kept; released, it
    # stays there while the tool leaves.
    start = np.asarray(box.position)
    assert np.linalg.norm(obj[-1, :3] - (start + SHIFT)) < 1.5e-3, obj[-1, :3] - (start + SHIFT)
    assert abs(abs(obj[-1, 3]) - 1.0) < 1e-3  # the box's frame is still (nearly) the world's
    after = ~carrying & (np.arange(len(rows)) > 1)
    assert np.ptp(obj[after, :3], axis=0).max() == 0.0
    assert np.linalg.norm(tool[-1, :3] - (p0 + SHIFT + LIFT / 2)) < 2e-3
    # Nothing touched anything: the carried box went around the plate, the gripper held it.
    assert rows[:, c["contact.depth"]].max() == 0.0
    assert not [w for w in s.snapshot().state.warnings if "hit" in w or "grasp" in w]
    # The session's list is the user's: the next run starts with the box where it was listed.
    assert s.snapshot().obstacles[1].position == box.position
    # The recording: /tf has the grasped frame; /scene draws the box on it while held, then in the
    # world where it was put.
    run_id = s.snapshot().state.run_id
    path = service.mesh.folder / "rec" / s.user / f"{keys.recording_name(s.id, run_id)}.mcap"
    wait_file_closed(path, timeout=40.0)
    scenes = _messages(path, mcapfmt.TOPIC_SCENE)
    held_on = [u for u in scenes if any(e["id"] == mcapscene.HELD_ENTITY for e in u["entities"])]
    assert held_on and held_on[0]["entities"][1]["frame_id"] == columns.GRASPED_FRAME
    placed = scenes[-1]
    assert placed["deletions"][0]["id"] == mcapscene.HELD_ENTITY
    cubes = [e for e in placed["entities"] if e["id"] == mcapscene.OBSTACLES_ENTITY][0]["cubes"]
    put = [q["pose"]["position"] for q in cubes if abs(q["size"]["x"] - EDGE) < 1e-9]
    assert len(put) == 1 and np.allclose([put[0][a] for a in "xyz"], obj[-1, :3], atol=1e-9)
    tf = _messages(path, mcapfmt.TOPIC_TF)
    assert columns.GRASPED_FRAME in {t["child_frame_id"] for t in tf[-1]["transforms"]}


def _messages(path: Path, topic: str) -> list[dict]:
    scan = mcapread.scan(path)
    ids = {cid for cid, ch in scan.channels.items() if ch.topic == topic}
    # in log time order, as Foxglove plays them: rows that fill a gap are written after the run
    found = sorted((msg for msg in scan.messages if msg.channel_id in ids), key=lambda msg: msg.log_time)
    return [json.loads(msg.data) for msg in found]


@pytest.mark.shares_service
def test_the_grasps_rules_are_refused_before_the_run(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    box, task, p0 = _pick_and_place(s)
    plate = s.snapshot().obstacles[0]
    far = m.Obstacle("far", "sphere", [float(p0[0]), float(p0[1]) + 0.3, float(p0[2])], radius=0.03, mass=1.0)
    floor = m.Obstacle("floor", "plane", [0.0, 0.0, -2.0])
    s.set_obstacles([plate, msgspec.structs.replace(box, mass=0.0), far, floor])

    def refused(actions: list[m.Action]) -> m.Error:
        with pytest.raises(RemoteError) as err:
            s.set_command(m.Task("t", actions))
        return err.value.error

    e = refused([m.Action("grasp", {"object": "box9"})])
    assert e.field == "command.actions[0].args.object" and "no obstacle named box9" in e.message
    assert "plate, box1, far, floor" in e.message
    e = refused([m.Action("grasp", {"object": "floor"})])
    assert "a plane cannot be grasped" in e.message
    e = refused([m.Action("grasp", {"object": "plate"})])
    assert "obstacle plate has mass 0" in e.message
    e = refused([m.Action("grasp", {"object": "box1"})])
    assert "mass 0" in e.message and e.field == "command.actions[0].args.object"
    e = refused([m.Action("grasp", {"object": "far"})])
    assert "the tool point is 270.0 mm from obstacle far" in e.message and "within 10 mm" in e.message
    e = refused([m.Action("release")])
    assert e.field == "command.actions[0].primitive" and "holds nothing" in e.message
    e = refused([m.Action("grasp", {"object": 3.0})])
    assert e.field == "command.actions[0].args.object" and "must be a name" in e.message
    s.set_obstacles([plate, box, far])
    e = refused([m.Action("grasp", {"object": "box1"}), m.Action("grasp", {"object": "box1"})])
    assert e.field == "command.actions[1].args.object" and "holds box1 already" in e.message
    assert s.set_command(task).kind == "task"


@pytest.mark.shares_service
def test_a_carried_box_that_would_hit_an_obstacle_is_refused_naming_it(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    box, task, p0 = _pick_and_place(s)
    plate = s.snapshot().obstacles[0]
    # a wall across the carry, above the tool's line: only the box (on the tool) reaches it
    centre = p0 + LIFT + SHIFT / 2 + np.array([0.0, 0.0, 0.05])
    wall = m.Obstacle("wall", "box", [float(x) for x in centre], size=[0.01, 0.3, 0.06])
    s.set_obstacles([plate, box, wall])
    s.set_command(task)
    with pytest.raises(RemoteError) as err:
        s.run()
    assert err.value.error.field == "command.actions[2]"
    assert "the carried box1 would touch obstacle wall" in err.value.error.message


def test_a_held_cube_loads_the_chain_as_the_same_payload_does() -> None:
    """A cube centred on the tool point, taken at t = 0: the chain's mass matrix is that of the payload
    parameters describing the same cube (mechanics' payload model, written independently)."""
    pkg = models.get_model("spider")
    values = {**pkg.describe().default_values(), "payload.mass": 0.0}
    q0 = np.array(SPIDER_Q0)
    p, _R = kinematics("spider").tool_pose(q0)
    cube = m.Obstacle("cube", "box", [float(x) for x in p], size=[0.08] * 3, mass=3.0)
    held = pkg.build(values)
    loaded = pkg.build({**values, "payload.mass": 3.0, "payload.size": 0.08})
    bare = pkg.build(values)
    try:
        held.set_obstacles([cube])
        held.set_initial(q0)
        tab = np.array([[0.0, *q0, *np.zeros(pkg.n)], [0.5, *q0, *np.zeros(pkg.n)]])
        held.set_reference(tab, np.zeros(pkg.n, dtype=np.int64), grasps=[(0.0, "cube")])
        held.start(0.5, 0.01)
        held.advance(0.1)
        assert held.take_notices() == []
        M_held, M_payload = held.mass_matrix(q0), loaded.mass_matrix(q0)
        assert np.allclose(M_held, M_payload, rtol=1e-12, atol=1e-12)
        assert not np.allclose(M_held, bare.mass_matrix(q0))
        # the next run starts without it: the world comes back as listed
        held.start(0.5, 0.01)
        assert np.allclose(held.mass_matrix(q0), bare.mass_matrix(q0))
        held.set_joint_path([(q0, 50.0, 50.0)])
        held.start(0.5, 0.01)
        rows = held.advance(0.1)
        assert np.all(rows[:, held.columns.index(columns.GRASP_OBJECT)] == 0.0)
        assert held.world[0].position == cube.position
    finally:
        for sim in (held, loaded, bare):
            sim.close()


def test_a_grasp_the_arm_did_not_reach_takes_nothing_and_says_so() -> None:
    pkg = models.get_model("spider")
    values = pkg.describe().default_values()
    q0 = np.array(SPIDER_Q0)
    p, _R = kinematics("spider").tool_pose(q0)
    ball = m.Obstacle("ball", "sphere", [float(p[0]), float(p[1]), float(p[2]) + 0.2], radius=0.02, mass=0.5)
    sim = pkg.build(values)
    try:
        sim.set_obstacles([ball])
        sim.set_initial(q0)
        tab = np.array([[0.0, *q0, *np.zeros(pkg.n)], [0.3, *q0, *np.zeros(pkg.n)]])
        sim.set_reference(tab, np.zeros(pkg.n, dtype=np.int64), grasps=[(0.1, "ball"), (0.2, "")])
        sim.start(0.3, 0.01)
        rows = sim.advance(0.3)
        notices = sim.take_notices()
        assert len(notices) == 1 and "the grasp at t = 0.100 s took nothing" in notices[0]
        assert "the tool point is 180.0 mm from obstacle ball" in notices[0]
        assert np.all(rows[:, sim.columns.index(columns.GRASP_HELD)] == 0.0)
    finally:
        sim.close()
