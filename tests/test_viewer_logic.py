"""viewer/ logic that needs no browser: trees, shapes and their kinematics, the joint path editor,
plot windows, documentation links, CSV, settings; and the panels driven on a real viser server with
no page attached (user events are given to the same callbacks a click would reach).
"""

from __future__ import annotations

import ast
import math
import socket
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import viser
from simecs.mesh import messages as m
from simecs.mesh.codec import DecodeError
from simecs.mesh.kinematics import link_poses, pose_column_names
from simecs.mesh.model import DocPage, InitEquation, Link, ModelDescription, Parameter, Shape, Variable
from simecs.viewer import docs, joints, library, params, pendant, plots, results, run, scene, tree
from simecs.benchmarks.viewer import viewer_latency
from simecs.viewer.browser import describe_error

VIEWER = Path(__file__).resolve().parent.parent / "viewer"
H = math.pi / 2


def arm() -> ModelDescription:
    """A 3-joint arm in the Link convention, with a resizable pipe per link and a tool box."""
    links = [
        Link("link1", "joint1", [0.0, -H, 0.0], "link1.length", [0.0, 0.0, 0.0], -math.pi, math.pi),
        Link("link2", "joint2", [-H, 0.0, 0.0], "link2.length", [0.0, 0.0, 0.0], -2.0, 2.0),
        Link("link3", "joint3", [0.0, 0.0, 0.0], "link3.length", [0.0, 0.1, 0.0], -2.0, 2.0),
    ]
    parameters = [
        Parameter("link1.length", 0.4, "m", "column", 0.0, 3.0, "link1", appearance=True),
        Parameter("link2.length", 0.5, "m", "upper arm", 0.0, 3.0, "link2", appearance=True),
        Parameter("link2.mass", 4.0, "kg", "mass", 0.0, 100.0, "link2"),
        Parameter("link3.length", 0.3, "m", "forearm", 0.0, 3.0, "link3", appearance=True),
        Parameter("joint1.motor.R", 1.2, "ohm", "winding resistance", 0.01, 50.0, "joint1.motor"),
        Parameter("joint1.motor.kt", 0.12, "N*m/A", "torque constant", 0.001, 5.0, "joint1.motor"),
        Parameter("joint1.gear.ratio", 160.0, "-", "reduction", 1.0, 1000.0, "joint1.gear"),
        Parameter("drives.enabled", 1.0, "-", "drives on", 0.0, 1.0, "drives", integer=True),
    ]
    variables = [
        Variable("joint1.q", "rad", "joint angle", "joint1"),
        Variable("joint1.qd", "rad/s", "joint speed", "joint1"),
        Variable("joint1.motor.i", "A", "current", "joint1.motor"),
        Variable("joint2.q", "rad", "joint angle", "joint2"),
        Variable("joint3.q", "rad", "joint angle", "joint3"),
    ]
    shapes = [
        Shape("cylinder", 0, [0.0, 0.0, -0.05], "z", length=0.1, radius=0.06),
        Shape("pipe", 0, [0.0, 0.0, 0.0], "x", length=0.4, radius=0.05, inner_radius=0.04, resizable=True),
        Shape("pipe", 1, [0.0, 0.0, 0.0], "x", length=0.5, radius=0.05, inner_radius=0.04, resizable=True),
        Shape("beam", 2, [0.0, 0.0, 0.0], "x", length=0.3, width=0.06, height=0.04, resizable=True),
        Shape("sphere", 2, [0.3, 0.0, 0.0], radius=0.05),
    ]
    pages = [
        DocPage(
            "arm", "Arm", "See the [joint drive](doc:arm.joint) and doc:arm.chain.", children=["arm.chain"]
        ),
        DocPage(
            "arm.joint", "Joint drive", "Motor: doc:arm.motor. Back to [the arm](doc:arm).", parent="arm"
        ),
        DocPage("arm.chain", "Chain", "Links.", parent="arm"),
    ]
    return ModelDescription(
        id="arm3",
        name="Three-link arm",
        summary="for tests",
        base_translation=[0.0, 0.0, 0.1],
        links=links,
        tool_translation=[0.05, 0.0, 0.0],
        shapes=shapes,
        parameters=parameters,
        variables=variables,
        init_equations=[InitEquation("jointN.q_motor", "n * q", "gear untwisted")],
        doc_root="arm",
        docs=pages,
        command_levels=["joint_path"],
        environment=[Shape("box", -1, [-1.0, 0.0, -0.02], "x", length=2.0, width=2.0, height=0.02)],
    )


@dataclass
class Event:
    """What viser hands a callback when a user acted (client set) or code assigned (client None)."""

    target: Any
    client: Any = "user"
    client_id: int | None = 1


@pytest.fixture(scope="module")
def server():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    srv = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    try:
        yield srv
    finally:
        srv.stop()


# -- architecture ---------------------------------------------------------------------------------
def test_viewer_imports_only_mesh_of_simecs() -> None:
    """Of our code the viewer imports only simecs.mesh: models reach it as messages."""
    for path in VIEWER.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                assert not name.startswith(("simecs.models", "simecs.nodes", "exudyn", "numba")), (path, name)
                if name.startswith("simecs."):
                    assert name.startswith(("simecs.mesh", "simecs.viewer")), (path, name)


def test_viewer_binds_loopback_by_default_and_hides_sharing() -> None:
    from simecs.viewer import app

    parser = __import__("argparse").ArgumentParser()
    app.Viewer.add_arguments(parser)
    args = parser.parse_args([])
    assert args.host == "127.0.0.1" and args.port == 8080
    assert app._no_share() is None
    source = (VIEWER / "app.py").read_text()
    assert "show_share_button=False" in source and "request_share_url = _no_share" in source


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
    values = desc.default_values()
    for shape in desc.shapes + desc.environment:
        g = scene.shape_geometry(shape, scene.shape_length(shape, desc, values))
        assert np.all(np.isfinite(g.position))
    assert scene.pose_indices(["time", *pose_column_names(desc)], desc) is not None


# -- scene ------------------------------------------------------------------------------------------
def test_shape_geometry_follows_the_shape_convention() -> None:
    cyl = scene.shape_geometry(Shape("cylinder", 0, [0.0, 0.0, -0.05], "z", length=0.1, radius=0.06), 0.1)
    assert (
        cyl.kind == "cylinder" and np.allclose(cyl.position, [0, 0, 0]) and cyl.wxyz == (1.0, 0.0, 0.0, 0.0)
    )
    pipe = scene.shape_geometry(Shape("pipe", 0, [0.1, 0, 0], "x", 0.5, 0.05, 0.04), 0.8)
    assert (
        pipe.kind == "pipe"
        and np.allclose(pipe.position, [0.5, 0, 0])
        and pipe.inner_ratio == pytest.approx(0.8)
    )
    # the rotation takes local z onto the shape axis
    w, x, y, z = pipe.wxyz
    rz = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    assert np.allclose(rz, [1, 0, 0])
    w, x, y, z = scene.AXIS_WXYZ["y"]
    assert np.allclose([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], [0, 1, 0])
    box = scene.shape_geometry(
        Shape("box", -1, [-1.0, 0.0, -0.02], "x", length=2.0, width=3.0, height=0.02), 2.0
    )
    assert box.dimensions == (2.0, 3.0, 0.02) and np.allclose(box.position, [0, 0, -0.02])
    beam = scene.shape_geometry(Shape("beam", 0, [0, 0, 0], "z", length=1.0, width=0.2, height=0.1), 1.0)
    assert beam.dimensions == (0.2, 0.1, 1.0)
    solid = scene.shape_geometry(Shape("pipe", 0, [0, 0, 0], "x", 1.0, 0.05, 0.0), 1.0)
    assert solid.kind == "cylinder"
    assert scene.shape_geometry(Shape("sphere", 0, [1, 2, 3], radius=0.1), 0).position.tolist() == [1, 2, 3]


def test_resizable_shape_takes_the_link_length() -> None:
    model = arm()
    values = {**model.default_values(), "link2.length": 1.25}
    pipe2 = model.shapes[2]
    assert scene.shape_length(pipe2, model, values) == 1.25
    assert scene.shape_length(model.shapes[0], model, values) == 0.1  # not resizable


def test_shapes_follow_bound_parameters_when_the_description_carries_them() -> None:
    """`scales_with` and `anchor` (proposed protocol fields) reshape and move solids proportionally."""
    model = arm()
    model.parameters.append(Parameter("link3.radius", 0.05, "m", "tube", 0.01, 0.5, "link3", appearance=True))
    defaults = model.default_values()
    tube = Shape("pipe", 2, [0.0, 0.0, 0.0], "x", 0.3, 0.05, 0.04, resizable=True)
    tube.scales_with = {"radius": "link3.radius", "inner_radius": "link3.radius"}  # type: ignore[attr-defined]
    flange = Shape("cylinder", 2, [0.3, 0.0, 0.0], "x", length=0.02, radius=0.06)
    flange.anchor = "end"  # type: ignore[attr-defined]
    values = {**defaults, "link3.radius": 0.1, "link3.length": 0.5}
    t = scene.effective_shape(tube, model, values, defaults)
    assert (t.length, t.radius, t.inner_radius) == pytest.approx((0.5, 0.1, 0.08))
    f = scene.effective_shape(flange, model, values, defaults)
    assert f.origin[0] == pytest.approx(0.5) and flange.origin[0] == 0.3  # the description is untouched
    plain = scene.effective_shape(model.shapes[0], model, values, defaults)
    assert plain == model.shapes[0]


def test_pipe_mesh_is_closed_and_outward() -> None:
    v, f = scene.pipe_mesh(0.8, segments=16)
    assert v.shape == (8 * 16, 3) and f.shape == (8 * 16, 3) and f.max() < len(v)
    assert np.allclose(np.abs(v[:, 2]), 0.5)
    # outer-wall triangles face away from the axis
    tri = v[f[:32]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1)
    assert np.all((normal[:, :2] * centre[:, :2]).sum(axis=1) > 0)


def test_pose_indices_map_the_pose_columns() -> None:
    model = arm()
    columns = ["time", "joint1.q", *pose_column_names(model)]
    idx = scene.pose_indices(columns, model)
    assert idx is not None and idx.shape == (3, 7) and columns[idx[1, 0]] == "pose.link2.x"
    assert scene.pose_indices(["time", "joint1.q"], model) is None


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
        pipe = s.solids[2][1]
        assert pipe.scale[2] == pytest.approx(1.0) and np.allclose(pipe.position, [0.5, 0, 0])
        beam = s.solids[3][1]
        assert s.set_values({**values, "link2.length": 1.0, "link3.length": 0.8})
        assert beam.dimensions[0] == pytest.approx(0.8)
        assert not np.allclose(s.frames[2].position, before)
        assert not s.set_values({**values, "link2.length": 1.0, "link3.length": 0.8, "link2.mass": 9.0})
    finally:
        s.remove()


# -- joint path -----------------------------------------------------------------------------------
def test_joint_path_editor_add_teach_remove_reorder() -> None:
    ed = pendant.JointPathEditor(arm().links)
    with pytest.raises(pendant.PathError, match="empty"):
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
    with pytest.raises(pendant.PathError, match="already last"):
        ed.move(+1)
    with pytest.raises(pendant.PathError, match="speed"):
        ed.set_pct(0, 50)
    with pytest.raises(pendant.PathError, match="3 joint positions"):
        ed.teach([0.0])
    ed.remove()
    assert len(ed.nodes) == 2 and ed.selected == 1
    cmd = ed.to_command()
    assert isinstance(cmd, m.JointPath) and cmd.nodes[1].speed_pct == 50 and cmd.nodes[1].acc_pct == 25
    cmd.validate()
    table = ed.table_markdown()
    assert "**▶2**" in table and "57.3" in table and "| 50 | 25 |" in table
    again = pendant.JointPathEditor(arm().links)
    again.load(cmd)
    assert [n.q for n in again.nodes] == [n.q for n in ed.nodes] and again.selected == 0


def test_pendant_panel_buttons_and_sliders(server: Any) -> None:
    ed = pendant.JointPathEditor(arm().links)
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
def test_param_panel_shows_a_component_and_sends_edits(server: Any) -> None:
    model = arm()
    sent, resets, ops = [], [], []
    panel = params.ParamPanel(
        server.gui,
        model,
        model.default_values(),
        lambda n, v: sent.append((n, v)),
        resets.append,
        lambda op, name: ops.append((op, name)),
    )
    assert list(panel.fields) == ["link1.length"]  # the first component with items
    panel.tree.buttons["joint1.motor"]._impl.update_cb[0](Event(panel.tree.buttons["joint1.motor"]))
    assert list(panel.fields) == ["joint1.motor.R", "joint1.motor.kt"]
    field = panel.fields["joint1.motor.R"]
    assert field.label == "R [ohm]" and "winding resistance" in field.hint
    field.value = 2.5
    panel._edited(Event(field), model.parameter("joint1.motor.R"))
    assert sent == [("joint1.motor.R", 2.5)]
    # the server's answer brings the fields back (e.g. after a refusal) and marks changed values
    panel.show_values({**model.default_values(), "joint1.motor.kt": 0.2})
    assert panel.fields["joint1.motor.R"].value == 1.2 and panel.fields["joint1.motor.kt"].label.endswith("•")
    panel.search.value = "torque"
    panel._on_search(Event(panel.search))
    assert list(panel.fields) == ["joint1.motor.kt"]
    panel.set_names(["a", "b"])
    assert panel.sets.options == ("a", "b")


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


# -- plots ---------------------------------------------------------------------------------------------
def test_live_buffer_is_a_bounded_window() -> None:
    buf = plots.LiveBuffer(capacity=100)
    buf.reset(["time", "a", "b"])
    for k in range(25):
        t = np.arange(k * 10, k * 10 + 10) * 0.01
        buf.append(np.column_stack([t, t * 2, -t]))
    assert len(buf) == 100
    t, (a, b) = buf.window(["a", "b"])
    assert len(t) == 100 and t[0] == pytest.approx(1.5) and t[-1] == pytest.approx(2.49)
    assert np.allclose(a, 2 * t) and np.all(np.diff(t) > 0)
    t, (a,) = buf.window(["a"], seconds=0.2)
    assert t[0] >= 2.29 - 1e-9
    _, (missing,) = buf.window(["nope"])
    assert np.all(missing == 0)
    buf.append(np.zeros((3, 2)))  # wrong width: ignored
    assert len(buf) == 100


def test_full_resolution_requests_stay_bounded() -> None:
    assert plots.every_for(2501, None, None, 5.0) == 1
    assert plots.every_for(2_000_001, None, None, 3600.0) == math.ceil(2_000_001 / plots.MAX_POINTS)
    assert plots.every_for(2_000_001, 0.0, 36.0, 3600.0) == 2  # a 1 % zoom is (nearly) full resolution


def test_overlay_puts_two_runs_on_one_time_axis() -> None:
    t = np.linspace(0, 1, 11)
    t_prev = np.linspace(0, 2, 5)
    x, cur, prev = plots.overlay(t, [t * 2], t_prev, [t_prev * 3])
    assert x[0] == 0 and x[-1] == 2 and np.all(np.diff(x) > 0)
    assert np.allclose(np.interp(0.5, x, cur[0]), 1.0) and np.allclose(np.interp(1.5, x, prev[0]), 4.5)
    assert cur[0][-1] == pytest.approx(2.0)  # holds its last value beyond its end


def test_plot_redraws_live_then_full_resolution(server: Any) -> None:
    actions = plots.PlotActions(
        load_full=lambda *a: None,
        overlay=lambda *a: None,
        close=lambda p: None,
        error=lambda msg: None,
        added=lambda p, n: None,
        variable_names=lambda: ["joint1.q", "joint2.q"],
        batch=server.atomic,
    )
    plot = plots.Plot(server.gui, 1, ["joint1.q"], {"joint1.q": "rad"}, actions)
    buf = plots.LiveBuffer()
    buf.reset(["time", "joint1.q"])
    buf.append(np.column_stack([np.linspace(0, 1, 50), np.linspace(0, 2, 50)]))
    plot.redraw(buf)
    assert len(plot.chart.data) == 2 and len(plot.chart.data[0]) == 50
    assert plot.chart.series[1]["label"] == "joint1.q [rad]"
    plot.full = plots.Transient("r2", np.linspace(0, 1, 500), {"joint1.q": np.ones(500)})
    plot.prev = plots.Transient("r1", np.linspace(0, 1, 300), {"joint1.q": np.zeros(300)})
    plot.compare.value = True
    plot.redraw(buf)
    assert len(plot.chart.data) == 3 and len(plot.chart.data[0]) >= 500
    assert plot.chart.series[2]["dash"] == [6, 4] and "r2 full res" in plot.title()
    plot.add_var.value = "joint2.q"
    plot._add_variable(Event(plot.add_var))
    assert plot.variables == ["joint1.q", "joint2.q"] and plot.add_var.value == "—"
    plot.remove()


# -- documentation ---------------------------------------------------------------------------------
def test_doc_links_become_buttons_and_history_goes_back(server: Any) -> None:
    model = arm()
    titles = {p.id: p.title for p in model.docs}
    r = docs.render(model.docs[1], titles)
    assert r.links == [("arm", "the arm")]  # doc:arm.motor does not exist: plain text, no button
    assert "**the arm** ↗" in r.markdown and "doc:" not in r.markdown.replace("arm.motor", "")
    r0 = docs.render(model.docs[0], titles)
    assert r0.links == [("arm.joint", "joint drive"), ("arm.chain", "Chain")]
    h = docs.DocHistory("arm")
    h.go("arm.joint")
    h.go("arm.chain")
    assert h.back() and h.current == "arm.joint" and h.back() and h.current == "arm" and not h.back()

    asked = []
    window = docs.DocsWindow(server.gui, model.docs, "arm", lambda page: asked.append(page))
    window.open()
    window.follow("arm.joint")
    assert window.history.current == "arm.joint"
    window.back()
    assert window.history.current == "arm"
    window.follow("arm.motor")  # not carried in the description: asked from the server
    assert asked == ["arm.motor"]
    window.close()
    assert not window.is_open


# -- results, run, library --------------------------------------------------------------------------
def test_csv_has_units_and_full_precision() -> None:
    rows = np.array([[0.0, 1 / 3], [0.002, 2.0]])
    data = results.to_csv(["time", "joint1.q"], ["s", "rad"], rows, {"run": "r1"}).decode()
    lines = data.splitlines()
    assert lines[0] == "# run: r1" and lines[1] == "time [s],joint1.q [rad]"
    assert float(lines[2].split(",")[1]) == 1 / 3
    back = np.loadtxt(data.splitlines()[2:], delimiter=",")
    assert np.array_equal(back, rows)
    assert results.csv_name("spider", "abcdefghijkl", "r3") == "simecs_spider_abcdefgh_r3.csv"


def test_status_line_and_run_buttons() -> None:
    st = m.SessionState("s" * 22, "running", run_id="r2", progress=0.5, sim_time=1.0, rtf=0.98)
    assert run.status_text(st) == "**running** run r2 · t = 1.000 s · 50 % · RTF 0.98"
    failed = m.SessionState("s" * 22, "failed", run_id="r2", reason="diverged")
    assert "diverged" in run.status_text(failed)
    queued = m.SessionState("s" * 22, "queued", run_id="r3", queue_position=2)
    assert "position 2" in run.status_text(queued)
    assert run.run_action_refusal("Run", "running") and not run.run_action_refusal("Run", "finished")
    assert run.run_action_refusal("Pause", "paused") and not run.run_action_refusal("Resume", "paused")
    assert run.run_action_refusal("Abort", "finished") and not run.run_action_refusal("Abort", "queued")


def test_settings_form_is_checked_before_sending() -> None:
    s = run.settings_from_form(2.0, 0.002, 0.0, "N x real time", 4.0, 50.0, ["joint1.q"])
    assert s.pacing == "scaled" and s.factor == 4.0 and s.live_vars == ["joint1.q"]
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(-1.0, 0.002, 0.0, "real time", 1.0, 50.0, [])
    assert err.value.field == "stop_time"
    with pytest.raises(DecodeError):
        run.settings_from_form(1.0, 0.002, 0.0, "warp", 1.0, 50.0, [])


def test_errors_read_as_sentences() -> None:
    from simecs.mesh.client import NoReply, RemoteError

    e = RemoteError(
        m.Error("bad_request", "values.link2.mass: 9999 kg is outside [0, 500] kg", "values.link2.mass")
    )
    assert describe_error(e) == "9999 kg is outside [0, 500] kg (values.link2.mass)"
    assert describe_error(RemoteError(m.Error("conflict", "a run is running"))) == "a run is running"
    text = describe_error(NoReply("no node answered simecs/library within 10.0 s"))
    assert text == "no simecs node answered: is the service running? (simecs/library)"


def test_user_names_and_model_summaries() -> None:
    assert library.valid_user(" ada ") == "ada"
    with pytest.raises(ValueError):
        library.valid_user("no spaces")
    assert library.valid_user(library.new_user_name())
    text = library.model_markdown(arm().summary_entry())
    assert "3 joints" in text and "joint path" in text


def test_bench_reads_the_viewer_latency_from_its_log() -> None:
    log = "x\n2026 INFO viewer tab 0: first live frame of r1 drawn 129 ms after the click\n"
    assert viewer_latency(log) == pytest.approx(0.129)
    assert viewer_latency("nothing") is None


def test_spider_appearance_parameters_reshape_its_shapes() -> None:
    """Every appearance parameter of the real Spider description reshapes what the viewer draws."""
    from simecs.models import get_model  # the description as the proxy sends it; the viewer gets it as data

    desc = get_model("spider").describe()
    defaults = desc.default_values()
    changed = dict(defaults)
    changed.update(
        {"payload.size": 2 * defaults["payload.size"], "link7.radius": 1.5 * defaults["link7.radius"]}
    )
    changed["link7.length"] = defaults["link7.length"] + 0.1
    before = [scene.effective_shape(s, desc, defaults, defaults) for s in desc.shapes]
    after = [scene.effective_shape(s, desc, changed, defaults) for s in desc.shapes]
    payload = next(i for i, s in enumerate(desc.shapes) if s.kind == "box" and s.link == 6)
    assert after[payload].width == pytest.approx(2 * before[payload].width)
    assert after[payload].origin[0] == pytest.approx(before[payload].origin[0] + 0.1)
    tube = next(i for i, s in enumerate(desc.shapes) if s.resizable and s.link == 6)
    assert after[tube].radius == pytest.approx(1.5 * before[tube].radius)
    assert after[tube].length == pytest.approx(before[tube].length + 0.1)
    appearance = {p.name for p in desc.parameters if p.appearance}
    tied = {v for s in desc.shapes for v in s.scales_with.values()} | {lk.length_param for lk in desc.links}
    assert appearance == tied


def test_status_line_shows_warnings() -> None:
    st = m.SessionState(session="s", phase="finished", run_id="r1", warnings=["recorder: gaps"])
    assert "⚠ recorder: gaps" in run.status_text(st)
