"""The Cartesian pendant without a browser (issue 12, build item 2): the path as data, and the panel
and its 3D gizmo driven by injected user events on a real viser server, with the server's answers
(a plan, a refusal naming a node) from the fake mesh of viewer_fakes.py."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import msgspec
import numpy as np
import pytest
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.kinematics import link_frames, quat_from_matrix, rot_rpy
from simecs.viewer import cartesian
from simecs.viewer.path import PathError

from .viewer_fakes import Event, arm, started_tab, state

POSE = cartesian.Pose([0.4, 0.1, 0.3], [0.0, 0.2, -0.1])


def drag(gizmo: Any, phase: str = "update") -> Any:
    """What viser hands a gizmo's callback while a user drags it."""
    return SimpleNamespace(target=gizmo, client="user", client_id=1, phase=phase)


def cart_arm() -> Any:
    return msgspec.structs.replace(arm(), command_levels=["joint_path", "cartesian_path"])


def test_the_path_is_edited_like_a_pendants_and_is_valid_on_the_wire() -> None:
    ed = cartesian.CartesianPathEditor()
    ed.teach(POSE)
    ed.set_move("PTP")
    ed.set_pct(50.0, 25.0)
    ed.teach(cartesian.Pose([0.5, 0.0, 0.2], [0.0, 0.0, 0.0]))  # takes the selected node's move, speeds
    assert [n.move for n in ed.nodes] == ["ptp", "ptp"] and ed.nodes[1].speed_pct == 50.0
    ed.duplicate(POSE)
    assert len(ed.nodes) == 3 and ed.selected == 2 and ed.nodes[2].pose == ed.nodes[1].pose
    assert ed.nodes[2].pose is not ed.nodes[1].pose  # a copy: moving it leaves the original
    ed.move(-2)
    assert ed.selected == 0 and ed.nodes[0].pose.position == [0.5, 0.0, 0.2]
    with pytest.raises(PathError, match="already first"):
        ed.move(-1)
    with pytest.raises(PathError, match="LIN or PTP"):
        ed.set_move("spline")
    with pytest.raises(PathError, match="speed 0"):
        ed.set_pct(0.0, 10.0)
    with pytest.raises(PathError, match="three finite numbers"):
        cartesian.Pose([0.1, math.nan, 0.0], [0.0, 0.0, 0.0])
    cmd = ed.to_command()
    assert codec.loads(m.SetCommand, codec.dumps(m.SetCommand(cmd))).command == cmd
    again = cartesian.CartesianPathEditor()
    again.load(cmd)
    assert again.to_command() == cmd and again.selected == 0

    # the server's refusal names a node: marked in the table, said beside it, cleared by a plan
    assert ed.refuse("command.nodes[1].position", "out of reach: 12 mm too far") == 1
    assert "2 ✗" in ed.table_markdown()
    assert cartesian.refusal_text(ed) == "**✗ The server refused node 2:** out of reach: 12 mm too far"
    assert ed.refuse("command", "the initial pose is outside") == -1
    assert "refused the path" in cartesian.refusal_text(ed)
    ed.accepted()
    assert cartesian.refusal_text(ed) == "" and "✗" not in ed.table_markdown()
    table = ed.table_markdown()
    assert "| PTP | 500 | 0 | 200 |" in table and "mm" in table


def test_teach_records_the_tool_pose_and_the_gizmo_quaternion_round_trips() -> None:
    model = cart_arm()
    values = model.default_values()
    q = [0.3, -0.4, 0.5]
    pose = cartesian.tool_pose(model, values, q)
    p, R = link_frames(model, values, q)[-1]
    assert np.allclose(pose.position, p) and np.allclose(rot_rpy(pose.rpy), R)
    wxyz = cartesian.rotation_wxyz(POSE.rpy)
    assert np.allclose(wxyz, quat_from_matrix(rot_rpy(POSE.rpy)))
    assert np.allclose(cartesian.rpy_of_wxyz(wxyz), POSE.rpy)
    assert np.allclose(cartesian.rpy_of_wxyz([2 * x for x in wxyz]), POSE.rpy)  # not normalised
    with pytest.raises(PathError, match="not a rotation"):
        cartesian.rpy_of_wxyz([0.0, 0.0, 0.0, 0.0])


def test_the_pendant_sends_a_dragged_pose_and_shows_the_nodes_arm_or_the_refusal(server: Any) -> None:
    tab, client, mesh = started_tab(server, cart_arm())
    ctl = tab.controller
    ctl.opening.load_model("arm3")
    ctl.drain()
    page = tab.page
    assert page is not None and ctl.session is not None
    cart = page.commands.cartesian
    assert cart is not None and ctl.cart is cart.editor
    sc = mesh.sessions[ctl.session.id]
    try:
        assert not cart.gizmo.visible  # nothing to drag on an empty path
        expected = cartesian.tool_pose(ctl.model, ctl.values, ctl.shown_q)
        cart._clicked(Event(SimpleNamespace(value="Teach")))
        ctl.edits.flush()
        ctl.drain()
        sent = sc.of(m.SetCommand)[-1].command
        assert isinstance(sent, m.CartesianPath) and sent.nodes[0].position == expected.position
        assert ctl.command_kind == "cartesian_path" and cart.gizmo.visible
        assert np.allclose(cart.gizmo.position, expected.position)
        assert "Path duration **1.00 s**" in cart.duration.content
        assert "Not the session's command" not in cart.duration.content
        assert page.scene._path_line is not None  # the planned tool path in 3D

        # the gizmo dragged: sent at once, the goal ghost drawn where the server puts the node (the arm
        # itself stays where the run starts: what Teach records)
        cart.gizmo.position = (0.45, 0.05, 0.25)
        cart._dragged(drag(cart.gizmo))
        ctl.drain()
        assert sc.of(m.SetCommand)[-1].command.nodes[0].position == pytest.approx([0.45, 0.05, 0.25])
        assert cart.position.value == pytest.approx((450.0, 50.0, 250.0))
        assert page.ghost.q == pytest.approx([0.25, 0.0, 0.0])  # the plan's q_end of node 1
        assert ctl.shown_q == pytest.approx([0.0, 0.0, 0.0]) and page.ghost.frames[0].visible
        sent = len(sc.of(m.SetCommand))
        cart._dragged(drag(cart.gizmo, "end"))  # the release, at the last update's pose: nothing new
        cart._dragged(drag(cart.gizmo, "start"))
        ctl.drain()
        assert len(sc.of(m.SetCommand)) == sent

        # a fast drag: every pose is sent or overtaken, and the last one sent is where it stopped
        before = len(sc.of(m.SetCommand))
        for k in range(30):
            cart.gizmo.position = (0.45, 0.05 + 0.002 * k, 0.25)
            cart._dragged(drag(cart.gizmo))
        ctl.drain()
        assert sc.of(m.SetCommand)[-1].command.nodes[0].position == pytest.approx([0.45, 0.108, 0.25])
        assert len(sc.of(m.SetCommand)) - before <= 30 and not ctl.edits._in_flight

        # a pose typed below the floor: refused, the node marked and the reason beside the path
        cart.position.value = (450.0, 50.0, -20.0)
        cart._typed(Event(cart.set_pose))
        ctl.drain()
        assert "refused node 1:** out of reach: 12 mm too far" in cart.refusal.content
        assert "Not planned" in cart.duration.content
        assert "▶1** ✗" in cart.table.content and cart._markers[0].color == (220, 40, 40)
        assert page.scene._path_line is None and not client.notes  # beside the path, not a notice
        assert page.ghost.q == pytest.approx([0.25, 0.0, 0.0])  # the ghost stays where it could go
        ctl.control.run_action("run")  # Run with the refused path: not the old one, the reason
        ctl.drain()
        assert not sc.of(m.Run) and "server refused the command (out of reach" in client.notes[-1][1]
        client.notes.clear()
        # typed back within reach: accepted, marks cleared
        cart.position.value = (450.0, 50.0, 300.0)
        cart._typed(Event(cart.set_pose))
        ctl.drain()
        assert cart.refusal.content == "" and page.ghost.q == pytest.approx([0.3, 0.0, 0.0])
        ctl.control.run_action("run")  # the Cartesian path runs (the joint path is empty)
        ctl.drain()
        assert len(sc.of(m.Run)) == 1 and isinstance(sc.of(m.SetCommand)[-1].command, m.CartesianPath)
        client.notes.clear()

        # the joint pendant says its path is not the session's command
        page.commands.pendant._clicked(Event(SimpleNamespace(value="Teach")))
        assert ctl.command_kind == "joint_path"
        ctl.edits.flush()
        ctl.drain()
        assert "Not the session's command" in cart.duration.content
        # a joint path refused (a node through an obstacle): the reason beside that path too
        joint = page.commands.pendant
        sc.refuse[m.SetCommand] = RemoteError(
            m.Error("bad_request", "link3 would touch obstacle box1", "command.nodes[1]")
        )
        joint._clicked(Event(SimpleNamespace(value="Teach")))
        ctl.edits.flush()
        ctl.drain()
        assert joint.refusal.content == "**✗ The server refused node 2:** link3 would touch obstacle box1"
        assert "Not planned" in joint.duration.content and not client.notes
        del sc.refuse[m.SetCommand]
        joint._clicked(Event(SimpleNamespace(value="Remove")))
        ctl.edits.flush()
        ctl.drain()
        assert joint.refusal.content == "" and "Path duration" in joint.duration.content

        # while a run goes on the gizmo is gone and the fields are locked
        sc.watched["on_state"](state(sc, "running", progress=0.5, sim_time=0.5, rtf=1.0))
        assert cart.locked and not cart.gizmo.visible and cart.set_pose.disabled
        sc.watched["on_state"](state(sc, "finished", seq=11, sim_time=1.0))
        # unlocked, but the joint path is the session's command: no gizmo nor dots of the Cartesian
        # path in 3D (issue 32, 9); an edit of the Cartesian path makes it the command again
        assert not cart.locked and not cart.gizmo.visible and not cart._markers
        cart._clicked(Event(SimpleNamespace(value="Add")))
        assert cart.gizmo.visible and len(cart._markers) == len(cart.editor.nodes)
    finally:
        tab.close()
        page.remove()


def test_a_node_sets_the_force_the_hybrid_controller_pushes_with() -> None:
    """Issue 32: the hybrid control system's force set point is reachable from the pendant (a node's
    force and direction, checked with the protocol's bounds before anything is sent)."""
    ed = cartesian.CartesianPathEditor()
    ed.insert(cartesian.Pose([0.4, 0.0, 0.3], [0.0, 0.0, 0.0]))
    ed.set_force(12.5, [0.0, 0.0, -2.0])
    node = ed.to_command().nodes[0]
    assert node.force == 12.5 and node.force_axis == [0.0, 0.0, -2.0]
    for force, axis, field in ((-1.0, [0.0, 0.0, 1.0], "force"), (5.0, [0.0, 0.0, 0.0], "force_axis")):
        with pytest.raises(PathError, match=field):
            ed.set_force(force, axis)
    assert ed.nodes[0].force == 12.5  # a refused value changes nothing
