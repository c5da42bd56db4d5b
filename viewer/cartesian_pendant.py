"""The Cartesian command panel in teach-pendant style (paper §2.1, §2.2 step 5): the path's nodes as
a table, the selected node's move (LIN/PTP), pose and percentages, and a gizmo on the tool target in
3D. Dragging the gizmo or setting a typed pose sends the path at once; the server plans it and the
arm is drawn where the node puts it (the plan's `q_end`), or the node is marked ✗ with the server's
reason beside the table. The path itself is `cartesian.CartesianPathEditor`, owned by the session
controller.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from simecs.mesh.protocol import messages as m

from .cartesian import (
    CartesianPathEditor,
    Pose,
    node_target,
    refusal_text,
    rotation_wxyz,
    rpy_of_wxyz,
)
from .path import DEG, LOCKED, PATH_BUTTONS, PathError, pick, plan_text, press, take_pct

GIZMO = "/cartesian/target"
NODE_COLOR = (40, 110, 220)
REFUSED_COLOR = (220, 40, 40)
MOVE_LABELS = {"LIN (straight line)": "lin", "PTP (joint move)": "ptp"}


class CartesianPendant:
    """Draws a `CartesianPathEditor` in the command panel and its nodes and target gizmo in 3D.

    `tool_pose()` gives the tool pose **Teach** records; `on_changed()` is called after an edit made
    in the panel and `on_dragged()` after a pose change to send at once; `on_preview(q)` shows the arm
    at a node's planned joint positions."""

    def __init__(
        self,
        gui: Any,
        scene: Any,
        editor: CartesianPathEditor,
        tool_pose: Callable[[], Pose],
        on_changed: Callable[[], None],
        on_dragged: Callable[[], None],
        on_preview: Callable[[list[float]], None],
        on_error: Callable[[str], None],
        reach: float,
    ) -> None:
        self.scene = scene
        self.editor = editor
        self.tool_pose = tool_pose
        self.on_changed = on_changed
        self.on_dragged = on_dragged
        self.on_preview = on_preview
        self.on_error = on_error
        self.locked = False
        self.is_command = False  # the path is the session's command: its gizmo and dots are drawn
        self.plan: m.CommandPlan | None = None
        self._preview_wanted = False  # the next plan answers an edit here: show its node's arm
        self._markers: list[Any] = []
        self.table = gui.add_markdown(editor.table_markdown())
        self.duration = gui.add_markdown(plan_text(None, 0.0))
        self.buttons = gui.add_button_group(
            "Path",
            PATH_BUTTONS,
            hint="Teach: record the tool's current pose as a node",
        )
        self.buttons.on_click(self._clicked)
        self.node = gui.add_dropdown("Node", ("-",), hint="the node edited below and by the gizmo in 3D")
        self.node.on_update(self._picked)
        gui.add_markdown("Drag the gizmo in 3D, or type a pose and press **Set pose**:")
        self.refusal = gui.add_markdown("")  # right above the pose the server names, in sight
        # Steps as fine as the values shown (0.1 mm, 0.01 deg): viser's boxes take no more decimals than
        # their step has, and a coarser one turned a typed "4250.5" into 42505.
        self.position = gui.add_vector3("Position [mm]", (0.0, 0.0, 0.0), step=0.1, hint="world frame")
        self.rpy = gui.add_vector3(
            "Roll, pitch, yaw [deg]", (0.0, 0.0, 0.0), step=0.01, hint="about the fixed world x, y, z axes"
        )
        self.set_pose = gui.add_button("Set pose", hint="send the typed pose as the selected node's")
        self.set_pose.on_click(self._typed)
        self.move = gui.add_dropdown(
            "Move", tuple(MOVE_LABELS), hint="LIN: the tool on a straight line; PTP: a joint move to the pose"
        )
        self.move.on_update(self._moved)
        self.speed = gui.add_number(
            "Speed [%]", 100.0, step=1.0, hint="LIN: of the Cartesian maxima; PTP: joints'"
        )
        self.acc = gui.add_number("Acceleration [%]", 100.0, step=1.0, hint="(0, 100]")
        self.speed.on_update(self._pct)
        self.acc.on_update(self._pct)
        self.force = gui.add_number(
            "Force [N]",
            0.0,
            min=0.0,
            max=1000.0,
            step=1.0,
            hint="control system opspace_hybrid (Settings): the tool pushes with this force from this "
            "node on; 0 = motion only",
        )
        self.force_axis = gui.add_vector3(
            "Force along", (0.0, 0.0, -1.0), step=0.1, hint="the world direction the tool pushes along"
        )
        self.force.on_update(self._forced)
        self.force_axis.on_update(self._forced)
        self.gizmo = scene.add_transform_controls(
            GIZMO, scale=max(0.08, 0.25 * reach), line_width=3.0, depth_test=False, visible=False
        )
        self.gizmo.on_update(self._dragged)
        self.refresh()

    # -- the user's edits --------------------------------------------------------------------------
    def _guard(self) -> bool:
        if self.locked:
            self.on_error(LOCKED)
        return not self.locked

    def _clicked(self, event: Any) -> None:
        action = event.target.value
        ed = self.editor
        if not self._guard():
            return
        try:
            press(ed, action, self.tool_pose)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self._edited(at_once=False)

    def _picked(self, event: Any) -> None:
        if event.client is None or not self.editor.nodes or not pick(self.editor, event.target.value):
            return
        self.refresh()
        q = node_target(self.plan, self.editor.selected)
        if q is not None and self.editor.refused is None:
            self.on_preview(q)

    def _moved(self, event: Any) -> None:
        if event.client is None or not self.editor.nodes or not self._guard():
            return
        self.editor.set_move(MOVE_LABELS[str(self.move.value)])
        self._edited(at_once=False)

    def _pct(self, event: Any) -> None:
        if event.client is None or not self.editor.nodes:
            return
        if take_pct(self.editor, self.speed, self.acc, self.on_error):
            self._edited(at_once=False)

    def _forced(self, event: Any) -> None:
        if event.client is None or not self.editor.nodes or not self._guard():
            return
        try:
            self.editor.set_force(float(self.force.value), [float(a) for a in self.force_axis.value])
        except (PathError, TypeError, ValueError) as exc:
            self.on_error(str(exc))
            node = self.editor.nodes[self.editor.selected]
            self.force.value, self.force_axis.value = node.force, tuple(node.force_axis)
            return
        self._edited(at_once=False)

    def _typed(self, _event: Any) -> None:
        if not self.editor.nodes:
            self.on_error("the path is empty: teach a node first")
            return
        if not self._guard():
            return
        try:
            pose = Pose(
                [float(x) / 1000.0 for x in self.position.value], [float(a) / DEG for a in self.rpy.value]
            )
        except (PathError, TypeError, ValueError) as exc:
            self.on_error(str(exc))
            return
        self.editor.set_pose(pose)
        self._edited(at_once=True)

    def _dragged(self, event: Any) -> None:
        if event.client is None or event.phase == "start" or not self.editor.nodes or self.locked:
            return
        handle = self.gizmo  # its pose now, whatever order the drag's callbacks run in
        try:
            pose = Pose([float(x) for x in handle.position], rpy_of_wxyz(handle.wxyz))
        except PathError as exc:
            self.on_error(str(exc))
            return
        if same_pose(pose, self.editor.nodes[self.editor.selected].pose):
            return  # a drag's end comes at the pose of its last update
        self.editor.set_pose(pose)
        self._edited(at_once=True, gizmo=False)

    def _edited(self, at_once: bool, gizmo: bool = True) -> None:
        self._preview_wanted = True
        self.is_command = True  # an edit here makes the path the session's command
        self.refresh(gizmo=gizmo)
        (self.on_dragged if at_once else self.on_changed)()

    # -- the server's answer -----------------------------------------------------------------------
    def show_plan(self, plan: m.CommandPlan | None, stop_time: float, current: bool, answer: bool) -> None:
        """The server's plan of the session's command (`current`: it is this path; `answer`: the
        server just answered an edit). While the user edits here, every answer draws the arm where
        the selected node puts it (a drag's answers come one after the other)."""
        self.plan = plan if current else None
        self.is_command = current or (self.is_command and plan is None)  # an answer still to come
        if current:
            self.editor.accepted()
            self.duration.content = plan_text(plan, stop_time)
        else:
            self._preview_wanted = False
            if self.editor.nodes:
                self.duration.content = "_Not the session's command: edit the path to make it so._"
            else:  # emptied: the last plan's duration and warnings are no longer the path's
                self.duration.content = plan_text(None, stop_time)
        self.refresh(gizmo=False)
        if current and answer and self._preview_wanted and self.editor.nodes:
            q = node_target(plan, self.editor.selected)
            if q is not None:
                self.on_preview(q)

    def show_refusal(self, field: str, reason: str) -> None:
        """The server refused the path: the node it names is marked, its reason shown here (the arm
        stays where the last plan put it)."""
        self.plan = None
        self.editor.refuse(field, reason)
        self.duration.content = "_Not planned: the session keeps the last path the server took._"
        self.refresh(gizmo=False)

    # -- drawing -----------------------------------------------------------------------------------
    def refresh(self, gizmo: bool = True) -> None:
        """Bring every widget and the 3D markers to the editor's state (`gizmo`: move it too)."""
        ed = self.editor
        self.table.content = ed.table_markdown()
        self.refusal.content = refusal_text(ed)
        options = tuple(str(k + 1) for k in range(len(ed.nodes))) or ("-",)
        if tuple(self.node.options) != options:
            self.node.options = options
        want = str(ed.selected + 1) if ed.nodes else "-"
        if self.node.value != want:
            self.node.value = want
        if ed.nodes:
            node = ed.nodes[ed.selected]
            label = next(k for k, v in MOVE_LABELS.items() if v == node.move)
            if self.move.value != label:
                self.move.value = label
            if self.speed.value != node.speed_pct:
                self.speed.value = node.speed_pct
            if self.acc.value != node.acc_pct:
                self.acc.value = node.acc_pct
            if self.force.value != node.force:
                self.force.value = node.force
            if tuple(self.force_axis.value) != tuple(node.force_axis):
                self.force_axis.value = tuple(node.force_axis)
            mm = tuple(round(x * 1000.0, 1) for x in node.pose.position)
            deg = tuple(round(a * DEG, 2) for a in node.pose.rpy)
            if tuple(self.position.value) != mm:
                self.position.value = mm
            if tuple(self.rpy.value) != deg:
                self.rpy.value = deg
            if gizmo:
                self.gizmo.position = tuple(node.pose.position)
                self.gizmo.wxyz = rotation_wxyz(node.pose.rpy)
        visible = bool(ed.nodes) and not self.locked and self.is_command
        if self.gizmo.visible != visible:
            self.gizmo.visible = visible
        self._draw_markers()

    def _draw_markers(self) -> None:
        """A dot at every node (red where the server refused it); the gizmo sits on the selected one.
        Drawn while the path is the session's command (another pendant's command draws its own)."""
        ed = self.editor
        if not self.is_command:
            while self._markers:
                self._markers.pop().remove()
            return
        bad = ed.refused[0] if ed.refused is not None else -1
        for k, node in enumerate(ed.nodes):
            color = REFUSED_COLOR if k == bad else NODE_COLOR
            if k >= len(self._markers):
                self._markers.append(
                    self.scene.add_icosphere(f"/cartesian/nodes/{k}", radius=0.012, color=color)
                )
            marker = self._markers[k]
            if tuple(marker.position) != tuple(node.pose.position):
                marker.position = tuple(node.pose.position)
            if tuple(marker.color) != color:
                marker.color = color
        while len(self._markers) > len(ed.nodes):
            self._markers.pop().remove()

    def set_disabled(self, disabled: bool) -> None:
        """While a run goes on the command cannot change (the server refuses it anyway)."""
        self.locked = disabled
        if disabled:
            self._preview_wanted = False  # the run shows the arm now
        fields = (self.speed, self.acc, self.move, self.position, self.rpy, self.set_pose, self.force)
        for handle in (*fields, self.force_axis):
            handle.disabled = disabled
        self.gizmo.visible = bool(self.editor.nodes) and not disabled and self.is_command

    def remove(self) -> None:
        """The 3D part (the panel's widgets go with the command panel)."""
        self.gizmo.remove()
        for marker in self._markers:
            marker.remove()
        self._markers.clear()


def same_pose(a: Pose, b: Pose, tol: float = 1e-9) -> bool:
    """Whether two poses are the same to rounding (the gizmo's quaternion round trip)."""
    return all(abs(x - y) <= tol for x, y in zip(a.position, b.position, strict=True)) and all(
        abs(math.remainder(x - y, math.tau)) <= 1e-7 for x, y in zip(a.rpy, b.rpy, strict=True)
    )
