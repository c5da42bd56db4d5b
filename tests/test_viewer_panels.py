"""The viewer's panels without a page: component trees, the arm's shapes and their kinematics, the
joint path editor and pendant, the parameter and variable panels (driven on a real viser server with
no page attached: user events are given to the callbacks a click would reach)."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from simecs.mesh.protocol import codec, columns
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import Parameter, Shape
from simecs.mesh.rules import shapes
from simecs.mesh.rules.kinematics import link_poses
from simecs.viewer import (
    joints,
    params,
    path,
    pendant,
    scene,
    tree,
)

from tests.viewer_fakes import Event, arm


# -- trees ------------------------------------------------------------------------------------------
def test_component_tree_groups_by_component() -> None:
    model = arm()
    roots = tree.build_tree(model.parameters)
    assert [r.path for r in roots] == ["link1", "link2", "link3", "joint1", "drives"]
    joint1 = tree.find(roots, "joint1")
    assert joint1 is not None and not joint1.items and [c.label for c in joint1.children] == ["motor", "gear"]
    assert joint1.count() == 3
    motor = tree.find(roots, "joint1.motor")
    assert motor is not None and [tree.short_name(p) for p in motor.items] == ["R", "kt"]
    assert sum(r.count() for r in roots) == len(model.parameters)


def test_labels_and_hints_carry_unit_bounds_description() -> None:
    p = arm().parameter("joint1.motor.R")
    assert tree.param_label(p) == "R [ohm]"
    hint = tree.param_hint(p, 1.2)
    assert "winding resistance" in hint and "0.01 … 50 ohm" in hint and "Default 1.2 ohm" in hint
    assert tree.param_label(arm().parameter("drives.enabled")) == "enabled"
    assert "whole numbers" in tree.param_hint(arm().parameter("drives.enabled"))
    assert "Changes the 3D shape" in tree.param_hint(arm().parameter("link2.length"))
    assert tree.var_label(arm().variables[1]) == "qd [rad/s]"
    assert [p.name for p in tree.search(arm().parameters, "torque")] == ["joint1.motor.kt"]
    assert tree.search(arm().parameters, "  ") == []
    assert tree.fmt(0.1 + 0.2) == "0.3" and tree.fmt(160.0) == "160" and tree.fmt(1.5e-3) == "0.0015"


def test_number_step_keeps_four_significant_digits() -> None:
    model = arm()
    assert params.number_step(model.parameter("drives.enabled"), 1.0) == 1.0
    assert params.number_step(model.parameter("joint1.motor.kt"), 0.12) == pytest.approx(1e-4)
    assert params.number_step(model.parameter("joint1.gear.ratio"), 160.0) == pytest.approx(0.1)
    assert params.number_step(model.parameter("joint1.motor.kt"), 1.5e-3) == pytest.approx(1e-6)
    assert params.number_step(model.parameter("link2.mass"), 0.0) == pytest.approx(0.01)


def test_real_spider_description_builds_trees_and_shapes() -> None:
    """The Spider as the server sends it: every parameter and variable in the trees, shapes drawable."""
    models = pytest.importorskip("simecs.models")
    desc = models.get_model("spider").describe()
    roots = tree.build_tree(desc.parameters)
    assert sum(r.count() for r in roots) == len(desc.parameters)
    assert sum(r.count() for r in tree.build_tree(desc.variables)) == len(desc.variables)
    drawn = list(shapes.solids(desc, desc.default_values()))
    assert len(drawn) == len(desc.shapes) + len(desc.environment)
    assert all(np.all(np.isfinite(s.geometry.position)) for s in drawn)
    names, _units = desc.run_columns()
    assert columns.pose_indices(names, desc.pose_frames()) is not None
    assert len(desc.joint_position_columns()) == len(desc.links)


# -- scene: geometry from mesh.rules.shapes, drawn by ArmScene ---------------------------------------------
def test_shape_geometry_follows_the_shape_convention() -> None:
    cyl = shapes.shape_geometry(Shape("cylinder", 0, [0.0, 0.0, -0.05], "z", length=0.1, radius=0.06))
    assert (
        cyl.kind == "cylinder" and np.allclose(cyl.position, [0, 0, 0]) and cyl.wxyz == (1.0, 0.0, 0.0, 0.0)
    )
    pipe = shapes.shape_geometry(Shape("pipe", 0, [0.1, 0, 0], "x", 0.8, 0.05, 0.04))
    assert (
        pipe.kind == "pipe"
        and np.allclose(pipe.position, [0.5, 0, 0])
        and pipe.inner_ratio == pytest.approx(0.8)
    )
    # the rotation takes local z onto the shape axis
    w, x, y, z = pipe.wxyz
    rz = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    assert np.allclose(rz, [1, 0, 0])
    w, x, y, z = shapes.AXIS_WXYZ["y"]
    assert np.allclose([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], [0, 1, 0])
    box = shapes.shape_geometry(Shape("box", -1, [-1.0, 0.0, -0.02], "x", length=2.0, width=3.0, height=0.02))
    assert box.dimensions == (2.0, 3.0, 0.02) and np.allclose(box.position, [0, 0, -0.02])
    beam = shapes.shape_geometry(Shape("beam", 0, [0, 0, 0], "z", length=1.0, width=0.2, height=0.1))
    assert beam.dimensions == (0.2, 0.1, 1.0)
    solid = shapes.shape_geometry(Shape("pipe", 0, [0, 0, 0], "x", 1.0, 0.05, 0.0))
    assert solid.kind == "cylinder"
    assert shapes.shape_geometry(Shape("sphere", 0, [1, 2, 3], radius=0.1)).position.tolist() == [1, 2, 3]
    assert not shapes.shape_geometry(Shape("cylinder", 0, [0, 0, 0], length=0.0, radius=0.1)).visible


def test_resizable_shape_takes_the_link_length() -> None:
    model = arm()
    defaults = model.default_values()
    values = {**defaults, "link2.length": 1.25}
    assert shapes.effective_shape(model.shapes[2], model, values, defaults).length == 1.25
    assert shapes.effective_shape(model.shapes[0], model, values, defaults).length == 0.1  # not resizable
    link2 = [s for s in shapes.solids(model, values) if s.frame == "link2"]
    assert len(link2) == 1 and link2[0].geometry.length == 1.25


def test_shapes_follow_bound_parameters_when_the_description_carries_them() -> None:
    """`scales_with` and `anchor` reshape and move solids proportionally."""
    model = arm()
    model.parameters.append(Parameter("link3.radius", 0.05, "m", "tube", 0.01, 0.5, "link3", appearance=True))
    defaults = model.default_values()
    tube = Shape("pipe", 2, [0.0, 0.0, 0.0], "x", 0.3, 0.05, 0.04, resizable=True)
    tube.scales_with = {"radius": "link3.radius", "inner_radius": "link3.radius"}
    flange = Shape("cylinder", 2, [0.3, 0.0, 0.0], "x", length=0.02, radius=0.06)
    flange.anchor = "end"
    values = {**defaults, "link3.radius": 0.1, "link3.length": 0.5}
    t = shapes.effective_shape(tube, model, values, defaults)
    assert (t.length, t.radius, t.inner_radius) == pytest.approx((0.5, 0.1, 0.08))
    f = shapes.effective_shape(flange, model, values, defaults)
    assert f.origin[0] == pytest.approx(0.5) and flange.origin[0] == 0.3  # the description is untouched
    plain = shapes.effective_shape(model.shapes[0], model, values, defaults)
    assert plain == model.shapes[0]
    assert "link3.radius" in shapes.appearance_parameters(model)


def test_pipe_mesh_is_closed_and_outward() -> None:
    v, f = shapes.pipe_mesh(0.8, segments=16)
    assert v.shape == (8 * 16, 3) and f.shape == (8 * 16, 3) and f.max() < len(v)
    assert np.allclose(np.abs(v[:, 2]), 0.5)
    # outer-wall triangles face away from the axis
    tri = v[f[:32]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1)
    assert np.all((normal[:, :2] * centre[:, :2]).sum(axis=1) > 0)


def test_pose_indices_map_the_pose_columns() -> None:
    model = arm()
    names, _units = model.run_columns()
    idx = columns.pose_indices(names, model.pose_frames())
    # three links, the tool and the grasped object
    assert idx is not None and idx.shape == (5, 7) and names[idx[1, 0]] == "pose.link2.x"
    assert columns.pose_indices([columns.TIME, "joint1.q"], model.pose_frames()) is None


def test_arm_scene_builds_poses_and_reshapes(server: Any) -> None:
    model = arm()
    values = model.default_values()
    s = scene.ArmScene(server.scene, model, values, root="/t_arm")
    s.build()
    try:
        assert len(s.frames) == 3 and len(s.solids) == 5
        q = [0.3, -0.5, 0.7]
        s.show_q(q)
        expected = link_poses(model, values, q)
        for frame, row in zip(s.frames, expected, strict=False):
            assert np.allclose(frame.position, row[:3]) and np.allclose(frame.wxyz, row[3:])
        # a longer upper arm: its pipe stretches and the next link frame moves along
        before = np.array(s.frames[2].position)
        assert s.set_values({**values, "link2.length": 1.0})
        pipe = s.solids[2][0]
        assert pipe.scale[2] == pytest.approx(1.0) and np.allclose(pipe.position, [0.5, 0, 0])
        beam = s.solids[3][0]
        assert s.set_values({**values, "link2.length": 1.0, "link3.length": 0.8})
        assert beam.dimensions[0] == pytest.approx(0.8)
        assert not np.allclose(s.frames[2].position, before)
        assert not s.set_values({**values, "link2.length": 1.0, "link3.length": 0.8, "link2.mass": 9.0})
    finally:
        s.remove()


# -- joint path -----------------------------------------------------------------------------------
def test_joint_path_editor_add_teach_remove_reorder() -> None:
    ed = path.JointPathEditor(arm().links)
    with pytest.raises(path.PathError, match="empty"):
        ed.to_command()
    ed.teach([0.1, 0.2, 0.3])
    ed.duplicate([0.0, 0.0, 0.0])
    ed.set_q([1.0, 5.0, -5.0])  # clamped into the joint ranges
    assert ed.nodes[1].q == [1.0, 2.0, -2.0] and ed.selected == 1
    ed.set_pct(50, 25)
    ed.select(0)
    ed.teach([0.5, 0.5, 0.5])  # inserted after the selected node
    assert [n.q[0] for n in ed.nodes] == [0.1, 0.5, 1.0] and ed.selected == 1
    ed.move(+1)
    assert [n.q[0] for n in ed.nodes] == [0.1, 1.0, 0.5] and ed.selected == 2
    with pytest.raises(path.PathError, match="already last"):
        ed.move(+1)
    with pytest.raises(path.PathError, match="speed"):
        ed.set_pct(0, 50)
    with pytest.raises(path.PathError, match="3 joint positions"):
        ed.teach([0.0])
    ed.remove()
    assert len(ed.nodes) == 2 and ed.selected == 1
    cmd = ed.to_command()
    assert isinstance(cmd, m.JointPath) and cmd.nodes[1].speed_pct == 50 and cmd.nodes[1].acc_pct == 25
    assert codec.loads(m.SetCommand, codec.dumps(m.SetCommand(cmd))).command == cmd  # valid on the wire
    table = ed.table_markdown()
    assert "**▶2**" in table and "57.3" in table and "| 50 | 25 |" in table
    again = path.JointPathEditor(arm().links)
    again.load(cmd)
    assert [n.q for n in again.nodes] == [n.q for n in ed.nodes] and again.selected == 0


def test_pendant_panel_buttons_and_sliders(server: Any) -> None:
    ed = path.JointPathEditor(arm().links)
    changes, previews, errors = [], [], []
    current = [0.2, -0.3, 0.4]
    panel = pendant.PendantPanel(
        server.gui,
        ed,
        current_q=lambda: list(current),
        on_changed=lambda: changes.append(len(ed.nodes)),
        on_preview=previews.append,
        on_error=errors.append,
    )

    def click(label: str) -> None:
        panel._clicked(Event(SimpleNamespace(value=label)))

    click("Teach")
    click("Teach")
    assert len(ed.nodes) == 2 and changes == [1, 2]
    assert panel.node.options == ("1", "2") and panel.node.value == "2"
    panel.sliders.sliders[0].value = 30.0
    panel.sliders._moved(Event(panel.sliders.sliders[0]))
    assert ed.nodes[1].q[0] == pytest.approx(math.radians(30)) and previews[-1][0] == pytest.approx(
        math.radians(30)
    )
    panel.speed.value = 150.0
    panel._pct(Event(panel.speed))
    assert errors and "speed 150" in errors[-1] and ed.nodes[1].speed_pct == 100.0
    panel.set_disabled(True)
    click("Remove")
    assert len(ed.nodes) == 2 and "cannot change" in errors[-1]
    panel.set_disabled(False)
    click("Up")
    assert ed.selected == 0 and ed.nodes[0].q[0] == pytest.approx(math.radians(30))
    assert "**▶1**" in panel.table.content


def test_a_slider_value_newer_than_its_callback_is_not_undone(server: Any) -> None:
    """viser stores a slider's value on its own thread when the browser sends it, and calls back on
    the tab's loop: typing "30" sends 3, then 30, and the 30 may be stored while the callback of 3
    runs. That callback must not write its node (3 deg) back over the slider: the callback of 30
    comes next and reads the slider (the fresh-clone failure: the path's node kept 3 deg)."""
    ed = path.JointPathEditor(arm().links)
    arrivals: list[float] = []

    def preview(_q: list[float]) -> None:  # called inside the callback: the browser's next value lands
        if arrivals:
            panel.sliders.sliders[0].value = arrivals.pop()

    panel = pendant.PendantPanel(
        server.gui, ed, lambda: [0.0, 0.0, 0.0], lambda: None, preview, lambda _e: None
    )
    panel._clicked(Event(SimpleNamespace(value="Teach")))
    slider = panel.sliders.sliders[0]
    slider.value = 3.0  # the browser's "3"; its "30" lands during the callback of "3"
    arrivals.append(30.0)
    panel.sliders._moved(Event(slider))
    assert slider.value == 30.0, "the callback of 3 wrote its node back over the newer 30"
    panel.sliders._moved(Event(slider))
    assert ed.nodes[0].q[0] == pytest.approx(math.radians(30))


def test_joint_sliders_are_in_degrees_within_limits(server: Any) -> None:
    got = []
    s = joints.JointSliders(server.gui, arm().links, [0.5, 0.0, -3.0], got.append)
    assert s.sliders[0].value == pytest.approx(28.648) and s.sliders[2].value == pytest.approx(-114.5)
    assert s.sliders[1].min == pytest.approx(-114.5) and s.sliders[1].max == pytest.approx(114.5)
    s.sliders[1].value = 10.0  # code assigning: no callback to the tab
    s._moved(Event(s.sliders[1], client=None))
    assert got == []
    s._moved(Event(s.sliders[1]))
    assert got[-1][1] == pytest.approx(math.radians(10.0))
    assert "`jointN.q_motor`" in joints.init_equations_markdown(arm().init_equations)


# -- parameters / variables panels ------------------------------------------------------------------
def test_param_panel_shows_a_component_and_sends_only_applied_edits(server: Any) -> None:
    """Issue 12, 0: a value typed key by key is a draft (checked as typed, never sent half-typed,
    never overwritten by the server's values); Apply sends the drafts at once; a refusal stays beside
    the fields with the server's reason; Discard goes back to the stored values."""
    model = arm()
    sent, resets, ops = [], [], []
    panel = params.ParamPanel(
        server.gui,
        model,
        model.default_values(),
        lambda changes: sent.append(dict(changes)),
        resets.append,
        lambda op, name: ops.append((op, name)),
    )
    assert list(panel.fields) == ["link1.length"]  # the first component with items
    assert panel.tree.folder.label == "Components · link1"  # folded under what it shows
    panel.tree.buttons["joint1.motor"]._impl.update_cb[0](Event(panel.tree.buttons["joint1.motor"]))
    assert list(panel.fields) == ["joint1.motor.R", "joint1.motor.kt"]
    assert panel.tree.folder.label == "Components · joint1.motor" and panel.tree.picked == "joint1.motor"
    field = panel.fields["joint1.motor.R"]
    assert field.label == "R [ohm]" and "winding resistance" in field.hint
    R = model.parameter("joint1.motor.R")
    assert panel.apply.disabled and panel.discard.disabled
    for typed in (0.0, 2.0, 2.5):  # "0" on the way is out of bounds: shown, not sent
        field.value = typed
        panel._edited(Event(field), R)
        if typed == 0.0:
            assert "outside" in panel.notice.content and panel.apply.disabled
    assert sent == [] and field.label == "R [ohm]" + params.DRAFT_MARK and not panel.apply.disabled
    # the server's values (another field changed meanwhile) leave the draft as typed
    panel.show_values({**model.default_values(), "joint1.motor.kt": 0.2})
    assert field.value == 2.5 and panel.fields["joint1.motor.kt"].label.endswith("•")
    panel._apply()
    assert sent == [{"joint1.motor.R": 2.5}]
    panel.refused("joint1.motor.R", "values.joint1.motor.R: too hot")
    assert "too hot" in panel.notice.content and field.value == 2.5
    panel.show_values({**model.default_values(), "joint1.motor.kt": 0.2, "joint1.motor.R": 2.5})
    assert (
        panel.drafts == {} and field.label == "R [ohm]" + params.CHANGED_MARK and panel.notice.content == ""
    )
    field.value = 3.0
    panel._edited(Event(field), R)
    panel._discard()
    assert field.value == 2.5 and panel.drafts == {} and panel.apply.disabled
    panel.search.value = "torque"
    panel._on_search(Event(panel.search))
    assert list(panel.fields) == ["joint1.motor.kt"]
    panel.set_names(["a", "b"])
    assert panel.sets.options == ("a", "b")
    # "Reset all" asks first: keeping the values sends nothing, agreeing resets every parameter
    click = lambda button: button._impl.update_cb[0](Event(button))  # noqa: E731
    click(panel.reset_all)
    assert panel.confirm is not None and resets == []
    click(panel.confirm[1])
    assert resets == []
    click(panel.reset_all)
    click(panel.confirm[0])
    assert resets == [[]]


def test_variable_panel_streams_and_plots(server: Any) -> None:
    model = arm()
    streamed, plotted = [], []
    panel = params.VariablePanel(server.gui, model, {"joint1.q"}, streamed.append, plotted.append)
    assert set(panel.checks) == {"joint1.q", "joint1.qd"}
    check = panel.checks["joint1.qd"]
    check.value = True
    panel._ticked(Event(check), model.variables[1])
    assert streamed[-1] == {"joint1.q", "joint1.qd"}
    panel.show_streamed({"joint1.qd"})
    assert panel.checks["joint1.q"].value is False and "Streaming **1**" in panel.summary.content
    # the component shown first, picked in the tree: its rows stay (a click on them is not lost)
    rows = list(panel.rows)
    panel.tree.pick(panel.tree.first)
    assert panel.rows == rows and not any(r._impl.removed for r in rows)
    rows[1]._impl.update_cb[0](Event(rows[1]))
    assert plotted == ["joint1.q"]
