"""The tab: controller events applied to real panels (a viser server with no page): every solid drawn
alike, the path duration, jogging, notifications, imported meshes, switches, obstacles and grasps, a
command set by another client, the digital readout (comparing runs: test_viewer_comparing.py)."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace
from typing import Any

import msgspec
import numpy as np
import pytest
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import columns
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import shapes
from simecs.mesh.rules.kinematics import link_poses
from simecs.nodes.local_mesh import wait_until
from simecs.viewer import (
    browser,
    events,
    params,
    path,
    scene,
)

from tests.viewer_fakes import (
    Event,
    H,
    arm,
    attached,
    grasp_layout,
    layout,
    live_frame,
    loaded_tab,
    settle,
    started_tab,
    state,
)


# -- the tab: controller events on real panels --------------------------------------------------------
def test_the_tab_applies_controller_events_to_its_panels(server: Any) -> None:
    model = arm()
    tab, client, mesh = started_tab(server, model)
    ctl = tab.controller
    assert tab.library is not None and client.stored["simecs.user"] == "tester"
    ctl.opening.load_model("arm3")
    ctl.drain()
    page = tab.page
    assert page is not None and tab.library is None
    sc = mesh.sessions[ctl.session.id]
    try:
        # the toolbar follows the state; the pendant locks while a run goes on
        sc.watched["on_state"](state(sc, "running", progress=0.5, sim_time=0.5, rtf=1.0))
        assert tab.run_bar.status.content.startswith("**running** run r1")
        assert "Pause or Abort" in tab.run_bar.status.content and page.commands.pendant.locked
        assert "keys: Space pauses, Esc aborts" in tab.run_bar.status.content  # the keys said in the page
        # a replay run: the status names the recording, the arm takes the recorded link length
        sc.watched["on_state"](state(sc, "queued", "r2", seq=11))
        lay = layout(sc, model, "r2", "rec_r1", **{"link2.length": 1.0})
        sc.watched["on_layout"](lay)
        sc.watched["on_state"](state(sc, "running", "r2", seq=12))
        assert "replay r2 of `rec_r1`" in tab.run_bar.status.content
        assert page.scene.solids[2][0].scale[2] == pytest.approx(1.0)
        sc.watched["on_live"](live_frame(lay, model, [0.4, 0.1, -0.2]))
        expected = link_poses(model, lay.context.values, [0.4, 0.1, -0.2])
        assert np.allclose(page.scene.frames[2].position, expected[2, :3])
        sc.watched["on_state"](state(sc, "finished", "r2", seq=13, sim_time=1.0))
        assert not page.commands.pendant.locked
        # the user's own pose: the session's shapes come back
        ctl.preview([0.0, 0.0, 0.0])
        assert page.scene.solids[2][0].scale[2] == pytest.approx(0.5)
        # a plot of a streamed variable shows the live window; Full resolution loads the run
        sc.run_list = [m.RunInfo("r2", "finished", 1.0, 1.0, 11, recording="rec_r1")]
        ctl.refresh_runs()
        page.open_plot("joint1.q")
        ctl.drain()
        plot = page.plots.get(1)
        assert plot is not None and plot.full is None
        plot._transient(Event(SimpleNamespace(value="Full resolution")))
        ctl.drain()
        assert plot.full is not None and plot.full.run_id == "r2" and "r2 full res" in plot.folder.label
        page._results_action("CSV", "r2")
        ctl.drain()
        assert client.downloads[-1].endswith("_r2.csv")
        assert any(title == "Replay r2 of rec_r1 finished" for title, _ in client.notes)
        tab.tick()
    finally:
        tab.close()
        page.remove()


@pytest.mark.parametrize(
    "changes",
    [{"link2.length": 0.9, "link4.length": 0.2}, {"link3.radius": 0.09}, {"payload.size": 0.5}],
    ids=["lengths", "radii", "payload"],
)
def test_the_browser_and_the_recordings_scene_draw_every_solid_alike(
    server: Any, changes: dict[str, float]
) -> None:
    """The 3D arm and Foxglove's /scene come from one rule: after a change of link lengths, radii or
    the payload's size, every solid sits and measures the same in both."""
    from simecs.models import get_model
    from simecs.nodes.recording import mcapscene

    desc = get_model("spider").describe()
    values = {**desc.default_values(), **changes}
    arm_scene = scene.ArmScene(server.scene, desc, desc.default_values(), root="/t_alike")
    arm_scene.build()
    try:
        assert arm_scene.set_values(values)
        entities = {e["id"]: e for e in mcapscene.scene_update(desc, values, 1)["entities"]}
        taken: dict[tuple[str, str], int] = {}
        for solid in shapes.solids(desc, values):
            if solid.frame == shapes.WORLD or not solid.geometry.visible:
                continue
            kind = {"cylinder": "cylinders", "pipe": "cylinders", "box": "cubes", "sphere": "spheres"}
            listed = kind[solid.geometry.kind]
            k = taken.get((solid.frame, listed), 0)
            taken[(solid.frame, listed)] = k + 1
            prim = entities[solid.frame][listed][k]
            handle, drawn = arm_scene.solids[solid.index]
            pos, rot, size = prim["pose"]["position"], prim["pose"]["orientation"], prim["size"]
            assert np.allclose(handle.position, [pos["x"], pos["y"], pos["z"]])
            if drawn in ("cylinder", "pipe"):
                assert np.allclose(handle.wxyz, [rot["w"], rot["x"], rot["y"], rot["z"]])
            if drawn == "pipe":
                assert np.allclose(handle.scale, [size["x"] / 2, size["y"] / 2, size["z"]])
            elif drawn == "cylinder":
                assert (2 * handle.radius, handle.height) == pytest.approx((size["x"], size["z"]))
            elif drawn == "box":
                assert np.allclose(handle.dimensions, [size["x"], size["y"], size["z"]])
            else:
                assert 2 * handle.radius == pytest.approx(size["x"])
    finally:
        arm_scene.remove()


def test_the_path_duration_is_shown_and_a_run_cut_short_by_its_stop_time_says_so() -> None:
    ctl, sc, got = attached()
    assert ctl.path is not None
    sc.plan_duration = 2.5
    ctl.path.teach([0.1] * len(ctl.path.links))
    ctl.edits.command_changed()
    ctl.edits.flush()
    ctl.drain()
    plan = got.of(events.PlanChanged)[-1].plan
    assert plan is not None and plan.duration == 2.5 and ctl.edits.plan is plan
    assert "ends the run before the path is done (2.50 s)" in path.plan_text(plan, 1.0)
    assert path.plan_text(plan, 5.0) == "Path duration **2.50 s** (stop time 5 s)."
    # a line too fast for a joint is time-scaled by the server, not refused: the pendant says so
    steps = [m.PlanStep("nodes[0]", "lin", 0.0, 1.0), m.PlanStep("nodes[1]", "lin", 1.0, 2.5, slowed=1.23)]
    slowed = m.CommandPlan("cartesian_path", 2.5, steps, [0.0], slowed=1.23)
    assert "Slowed **×1.23** (node 2) to keep every joint within its speed" in path.plan_text(slowed, 5.0)
    sc.watched["on_state"](state(sc, "finished", sim_time=1.0, rtf=2.0))
    ctl.drain()
    told = [n for n in got.of(events.Notice) if n.title == "Run r1 finished"]
    assert len(told) == 1 and told[0].kind == "warning"
    assert "stopped before its command was done (the command takes 2.50 s)" in told[0].body
    sc.plan_duration = 0.5
    ctl.edits.command_changed()
    ctl.edits.flush()
    sc.watched["on_state"](state(sc, "finished", run_id="r2", sim_time=1.0, rtf=2.0))
    ctl.drain()
    told = [n for n in got.of(events.Notice) if n.title == "Run r2 finished"]
    assert told[0].kind == "ok" and "before its command" not in told[0].body


def test_a_held_jog_is_resent_until_let_go_and_an_idle_arm_is_jogged_in_a_run_until_stopped() -> None:
    """Issue 32: jogging as on a pendant. A hold moves the axis, the release stops it at once (and
    hold messages that stop coming do too); an idle arm gets a run until stopped, ended as finished."""
    ctl, sc, got = attached()
    ctl.path.teach([0.0, 0.0, 0.0])
    ctl.edits.command_changed()
    # idle: the first hold asks for a run until stopped (edits first), once
    assert ctl.jog.hold("joint", "joint1", 1.0) == ""
    assert ctl.jog.hold("joint", "joint1", 1.0) == ""
    ctl.drain()
    runs = sc.of(m.Run)
    assert len(runs) == 1 and runs[0].until_stopped and sc.of(m.SetCommand)
    assert not sc.jogs  # nothing is sent before the run runs
    sc.watched["on_state"](state(sc, "paused", sim_time=0.1))
    assert "Resume" in ctl.jog.hold("joint", "joint1", 1.0)
    sc.watched["on_state"](state(sc, "running", seq=11, sim_time=0.1))
    ctl.settings = m.RunSettings(pacing="fast")  # a timed run paced fast cannot be jogged...
    lay = layout(sc, ctl.model, "r1")
    sc.watched["on_layout"](lay)
    assert "wall time" in ctl.jog.hold("joint", "joint1", 1.0)
    lay.context.until_stopped = True  # ...a run until stopped always can (it runs in real time)
    ctl.jog.speed_pct = 40.0
    assert ctl.jog.hold("joint", "joint2", -1.0) == ""
    wait_until(lambda: len(sc.jogs) >= 2, timeout=2.0, what="the held jog re-sent")
    first = sc.jogs[0]
    assert first.run_id == "r1" and first.space == "joint" and first.speed_pct == 40.0
    assert first.qd[1] < 0 and all(v == 0 for k, v in enumerate(first.qd) if k != 1)
    ctl.jog.release()  # let go: a zero velocity at once
    sent = len(sc.jogs)
    assert not any(sc.jogs[-1].qd) and ctl.jog.label == ""
    time.sleep(0.3)
    assert len(sc.jogs) == sent  # nothing after the release
    # hold messages that stop coming (a release the page did not report) end the jog by themselves
    assert ctl.jog.hold("cartesian", "z", -1.0) == ""
    wait_until(lambda: len(sc.jogs) > sent, timeout=2.0, what="a Cartesian jog")
    assert sc.jogs[sent].twist[2] < 0 and sc.jogs[sent].space == "cartesian"
    wait_until(lambda: ctl.jog.active is None, timeout=2.0, what="the jog let go without hold messages")
    assert not any(sc.jogs[-1].qd)
    # Stop jogging ends the run until stopped as finished (stop, not abort)
    assert ctl.jog.finish() == ""
    ctl.drain()
    assert isinstance(sc.sent[-1], m.Stop)
    sc.watched["on_state"](state(sc, "finished", seq=12, sim_time=1.0))
    assert "no run until stopped" in ctl.jog.finish()
    ctl.close()


def test_notifications_show_plain_text_not_markdown_marks() -> None:
    assert browser.plain("Run **r1** assigned; see `joint2.q` and **both** marks.") == (
        "Run r1 assigned; see joint2.q and both marks."
    )
    assert browser.plain("2 * 3 ** 2") == "2 * 3 ** 2"


def test_an_imported_models_meshes_are_drawn_where_its_description_puts_them(server: Any) -> None:
    """Each mesh shape becomes a GLB node with the bytes the proxy would serve, at its pose on its
    link frame, and the same mesh goes into the recording's /scene, embedded; a mesh the server did not
    give leaves an empty node (the indices stay whole)."""
    import base64
    import json

    import jsonschema
    from simecs.models import get_model
    from simecs.nodes.recording import mcapfmt, mcapscene

    pkg = get_model("ur5")
    desc = pkg.describe()
    store = pkg.mesh_store()
    meshes = {name: store.glb(name) for name in store.names()}
    assert all(data[:4] == b"glTF" for data in meshes.values())
    values = desc.default_values()
    arm_scene = scene.ArmScene(server.scene, desc, values, root="/t_meshes", meshes=meshes)
    arm_scene.build()
    try:
        drawn = {i: h for i, (h, kind) in arm_scene.solids.items() if kind == "mesh"}
        mesh_shapes = {i: s for i, s in enumerate(desc.shapes) if s.kind == "mesh"}
        assert set(drawn) == set(mesh_shapes) and len(drawn) == len(desc.links)
        for i, shape in mesh_shapes.items():
            geom = shapes.shape_geometry(shape)
            assert np.allclose(drawn[i].position, geom.position) and np.allclose(drawn[i].wxyz, geom.wxyz)
        update = mcapscene.scene_update(desc, values, 1, meshes)
        schema = json.loads(mcapfmt.foxglove_schema("foxglove.SceneUpdate"))
        jsonschema.Draft202012Validator(schema).validate(update)
        entities = {e["id"]: e for e in update["entities"]}
        for link in desc.links:
            models = entities[link.name]["models"]
            assert len(models) == 1 and models[0]["media_type"] == "model/gltf-binary"
            assert base64.b64decode(models[0]["data"])[:4] == b"glTF"
        # without the meshes: nothing drawn, nothing embedded, nothing broken
        assert not any(e["models"] for e in mcapscene.scene_update(desc, values, 1)["entities"])
    finally:
        arm_scene.remove()
    bare = scene.ArmScene(server.scene, desc, values, root="/t_bare")
    bare.build()
    try:
        assert sum(1 for _h, kind in bare.solids.values() if kind == "mesh") == len(desc.links)
    finally:
        bare.remove()


def test_a_switch_parameter_is_a_check_box_and_applies_as_0_or_1(server: Any) -> None:
    from simecs.models import get_model

    desc = get_model("spider").describe()
    sent: list[dict[str, float]] = []
    panel = params.ParamPanel(server.gui, desc, desc.default_values(), sent.append, print, print)
    drives = next(c for root in panel.roots for c in root.walk() if c.path == "drives")
    panel.show_component(drives)
    box = panel.fields["drives.enabled"]
    assert box.value is True and not hasattr(box, "step")
    box.value = False
    panel._edited(Event(box), desc.parameter("drives.enabled"))
    panel._apply()
    assert sent == [{"drives.enabled": 0.0}]
    panel.show_values({**desc.default_values(), "drives.enabled": 0.0})
    assert box.value is False and panel.drafts == {}
    panel.show_values(desc.default_values())
    assert box.value is True


# -- obstacles: the session's list, a run's grasps and contacts, the panel ---------------------------------
def test_the_page_draws_the_sessions_obstacles_and_a_runs_grasps_and_contacts(server: Any) -> None:
    from simecs.viewer.obstacles import NEW

    model = arm()
    tab, client, page, sc = loaded_tab(server, model)
    ctl = tab.controller
    try:
        # another client's set_obstacles reaches this tab: drawn, and offered in the panel
        box = m.Obstacle("box1", "box", [0.5, 0.0, 0.1], size=[0.1, 0.1, 0.1], mass=1.0)
        sc.watched["on_obstacles"](m.ObstacleValues(sc.id, [box]))
        assert ctl.obstacles == [box] and len(page.scene._obstacles) == 1
        assert tuple(page.commands.obstacles.pick.options) == ("box1", NEW)
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.5, 0.0, 0.1))
        # a run grasps box1 and pushes link2 onto something: the box moves with the rows, the force
        # shows as an arrow; the live columns carry what the scene draws even when few are chosen
        lay = grasp_layout(sc, model)
        assert columns.GRASP_OBJECT in lay.live_columns and "contact.link2.fx" in lay.live_columns
        assert "contact.link2.force" not in lay.live_columns
        sc.watched["on_layout"](lay)
        frame = live_frame(lay, model, [0.1, 0.2, 0.3])
        row = frame.rows[0]
        where = {c: i for i, c in enumerate(lay.live_columns)}
        pose = [0.2, 0.3, 0.4, 1.0, 0.0, 0.0, 0.0]
        for f, v in zip(columns.POSE_FIELDS, pose, strict=True):
            row[where[columns.pose_column(columns.GRASPED_FRAME, f)]] = v
        row[where[columns.GRASP_OBJECT]], row[where[columns.GRASP_HELD]] = 1.0, 1.0
        for f, v in zip(("fx", "fy", "fz", "px", "py", "pz"), (0.0, 0.0, 50.0, 0.1, 0.1, 0.1), strict=True):
            row[where[columns.contact_column(2, f)]] = v
        sc.watched["on_live"](frame)
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.2, 0.3, 0.4))
        assert page.scene._contacts is not None
        assert np.allclose(page.scene._arrows, [[[0.1, 0.1, 0.1], [0.1, 0.1, 0.15]]])
        # the user poses the arm again: the run's world is over, the box is back, no arrows
        ctl.preview([0.0, 0.0, 0.0])
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.5, 0.0, 0.1))
        assert page.scene._contacts is None
        sc.watched["on_live"](frame)
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.2, 0.3, 0.4))
        # the next run starts from the list: the box is back where it is listed, no arrows
        sc.watched["on_layout"](grasp_layout(sc, model))
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.5, 0.0, 0.1))
        assert page.scene._contacts is None
        # the panel: a new sphere, applied, goes to the server with the list it joins
        panel = page.commands.obstacles
        panel.pick.value = NEW
        settle(tab)  # as a pick from the page would: the fields of a new obstacle
        panel.name.value = "ball"
        panel.kind.value = "sphere"
        panel.radius.value = 0.04
        panel.position.value = (0.3, 0.3, 0.2)
        panel.apply()
        ctl.drain()
        sent = sc.of(m.SetObstacles)[-1].obstacles
        assert [ob.name for ob in sent] == ["box1", "ball"] and sent[1].radius == 0.04
        assert len(page.scene._obstacles) == 2 and tuple(panel.pick.options) == ("box1", "ball", NEW)
        # a wrong field is named and nothing is sent; a name twice neither
        panel.radius.value = -1.0
        panel.apply()
        panel.pick.value = NEW
        settle(tab)
        panel.name.value = "box1"
        panel.radius.value = 0.04
        panel.apply()
        assert len(sc.of(m.SetObstacles)) == 1
        assert client.notes[-2][1].startswith("radius:") and "box1" in client.notes[-1][1]
        # refused by the server: the list drawn comes back to the stored one
        sc.refuse[m.SetObstacles] = RemoteError(m.Error("bad_request", "no", "obstacles[0].name"))
        panel.pick.value = "ball"
        settle(tab)
        panel.remove()
        ctl.drain()
        assert [ob.name for ob in ctl.obstacles] == ["box1", "ball"] and len(page.scene._obstacles) == 2
    finally:
        tab.close()
        page.remove()


def test_a_command_another_client_set_shows_in_its_pendant_and_an_echo_changes_nothing(server: Any) -> None:
    model = msgspec.structs.replace(arm(), command_levels=["joint_path", "direct_input"])
    tab, client, page, sc = loaded_tab(server, model)
    ctl = tab.controller
    commands = page.commands
    assert commands.pendant is not None and commands.direct is not None and ctl.path is not None
    try:
        # another client's joint path: the pendant shows its nodes and the plan that came with it
        path = m.JointPath([m.PathNode([0.1, 0.2, 0.3], 50.0, 100.0), m.PathNode([0.0, 0.0, 0.0])])
        plan = m.CommandPlan("joint_path", 2.5, [], [0.0, 0.0, 0.0])
        sc.watched["on_command"](m.CommandValue(sc.id, path, plan))
        assert ctl.path.to_command() == path and ctl.command_kind == "joint_path"
        assert "| 5.7 | 11.5 | 17.2 | 50 | 100 |" in commands.pendant.table.content
        assert "Path duration **2.50 s**" in commands.pendant.duration.content
        # then a direct input: its pendant takes it, the joint path says it is not the command
        signals = m.DirectInput("closed_loop", {"joint2": m.StepSignal(0.2)}, "speed")
        preview = m.SignalPreview("rad/s", [0.0, 1.0], {"joint2": [0.2, 0.2]})
        planned = m.CommandPlan("direct_input", 1.0, [], [0.0, 0.0, 0.0], signals=preview)
        sc.watched["on_command"](m.CommandValue(sc.id, signals, planned))
        assert ctl.command_kind == "direct_input" and ctl.direct is not None
        assert ctl.direct.to_command() == signals
        assert commands.direct.mode.value == "Speed set point (closed loop)"
        assert "step 0 → 0.2 rad/s" in commands.direct.table.content
        assert "Not the session's command" in commands.pendant.duration.content
        # this tab's own send comes back while the user edits on: the newer edit stays
        ctl.path.teach([0.2, 0.2, 0.2])
        ctl.edits.command_changed()
        ctl.edits.flush()
        ctl.drain()
        sent = sc.of(m.SetCommand)[-1].command
        ctl.path.set_q([0.3, 0.3, 0.3])
        sc.watched["on_command"](m.CommandValue(sc.id, sent, plan))
        assert ctl.path.nodes[ctl.path.selected].q == [0.3, 0.3, 0.3]
        # another session's publication, and a session without a command: nothing changes
        sc.watched["on_command"](m.CommandValue("x" * 22, path, plan))
        sc.watched["on_command"](m.CommandValue(sc.id, None, None))
        assert ctl.path.nodes[ctl.path.selected].q == [0.3, 0.3, 0.3] and ctl.command_kind == "joint_path"
        assert not client.notes
    finally:
        tab.close()
        page.remove()


def test_the_digital_readout_shows_joints_and_tool_in_the_tabs_angle_unit() -> None:
    """Issue 32: the joints (in the tab's angle unit) and the tool pose, always in the run bar."""
    from simecs.viewer.readout import readout_text

    deg = readout_text(["joint1", "joint2"], [math.pi / 2, -1e-9], [0.5, 0.0, 1.25, 0.0, H, 0.0], "deg")
    assert "**joints [deg]** 1:90.0 2:0" in deg and "x 500 y 0 z 1250 · r 0 p 90.0 y 0" in deg
