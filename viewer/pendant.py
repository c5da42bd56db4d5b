"""The joint command panel in teach-pendant style (paper §2.2 step 5, §5.2): the path's table, the
selected node's sliders (the same sliders as the initialisation panel) and its percentages, and the
buttons. The path itself is `path.JointPathEditor`, owned by the session controller.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from simecs.mesh.protocol import messages as m

from .cartesian import NODE_FIELD
from .joints import JointSliders
from .path import (
    LOCKED,
    PATH_BUTTONS,
    JointPathEditor,
    PathError,
    pick,
    plan_text,
    press,
    refused_text,
    take_pct,
)


class PendantPanel:
    """Draws a `JointPathEditor`; calls `on_changed()` after every edit and `on_preview(q)` to show a
    node's destination (the goal ghost); `current_q()` gives the pose that **Teach** records."""

    def __init__(
        self,
        gui: Any,
        editor: JointPathEditor,
        current_q: Callable[[], list[float]],
        on_changed: Callable[[], None],
        on_preview: Callable[[list[float]], None],
        on_error: Callable[[str], None],
    ) -> None:
        self.gui = gui
        self.editor = editor
        self.current_q = current_q
        self.on_changed = on_changed
        self.on_preview = on_preview
        self.on_error = on_error
        self.locked = False
        self.table = gui.add_markdown(editor.table_markdown())
        self.refusal = gui.add_markdown("")
        self.duration = gui.add_markdown(plan_text(None, 0.0))
        self.buttons = gui.add_button_group(
            "Path",
            PATH_BUTTONS,
            hint="Teach: record the arm's current pose as a node",
        )
        self.buttons.on_click(self._clicked)
        self.node = gui.add_dropdown("Node", ("-",), hint="the node edited by the sliders below")
        self.node.on_update(self._picked)
        self.speed = gui.add_number(
            "Speed [%]", 100.0, min=None, max=None, step=1.0, hint="of each joint's maximum speed, (0, 100]"
        )
        self.acc = gui.add_number(
            "Acceleration [%]", 100.0, step=1.0, hint="of each joint's maximum acceleration, (0, 100]"
        )
        self.speed.on_update(self._pct)
        self.acc.on_update(self._pct)
        gui.add_markdown("Destination of the node (the 3D arm shows it while you move a slider):")
        q0 = editor.nodes[editor.selected].q if editor.nodes else current_q()
        self.sliders = JointSliders(gui, editor.links, q0, self._moved, label="{joint} target [deg]")
        self.refresh()

    def _clicked(self, event: Any) -> None:
        action = event.target.value
        ed = self.editor
        if self.locked:
            self.on_error(LOCKED)
            return
        try:
            press(ed, action, self.current_q)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self.refresh()
        self.on_changed()

    def _picked(self, event: Any) -> None:
        if event.client is None or not self.editor.nodes or not pick(self.editor, event.target.value):
            return
        self.refresh()
        self.on_preview(self.editor.nodes[self.editor.selected].q)

    def _pct(self, event: Any) -> None:
        if event.client is None:
            return
        if not self.editor.nodes:
            self.on_error("the path is empty: teach a node first")
            return
        if not take_pct(self.editor, self.speed, self.acc, self.on_error):
            return
        self.refresh()
        self.on_changed()

    def _moved(self, q: list[float]) -> None:
        if not self.editor.nodes:
            # the first node: the arm's pose with the joint the user moved (not the sliders' pose,
            # which is whatever they showed before the arm moved)
            k = self.sliders.moved
            here = self.current_q()
            q = [q[j] if j == k else here[j] for j in range(len(here))] if 0 <= k < len(here) else q
            self.editor.teach(q)
            self.sliders.set_q(q)
        else:
            self.editor.set_q(q)
        self.on_preview(q)
        # not the sliders: viser stores a slider's newer value (the next key of "30" after "3") before
        # this callback of the older one runs, and writing the node back would undo it
        self.refresh(sliders=False)
        self.on_changed()

    def refresh(self, sliders: bool = True) -> None:
        """Bring every widget to the editor's state (the sliders too, unless they are what changed)."""
        ed = self.editor
        self.table.content = ed.table_markdown()
        options = tuple(str(k + 1) for k in range(len(ed.nodes))) or ("-",)
        if tuple(self.node.options) != options:
            self.node.options = options
        want = str(ed.selected + 1) if ed.nodes else "-"
        if self.node.value != want:
            self.node.value = want
        if ed.nodes:
            node = ed.nodes[ed.selected]
            if sliders:
                self.sliders.set_q(node.q)
            if self.speed.value != node.speed_pct:
                self.speed.value = node.speed_pct
            if self.acc.value != node.acc_pct:
                self.acc.value = node.acc_pct

    def show_plan(self, plan: m.CommandPlan | None, stop_time: float, current: bool = True) -> None:
        """The path's duration as the server planned it, and whether the stop time cuts it
        (`current`: the path is the session's command)."""
        self.refusal.content = ""
        if current or not self.editor.nodes:
            self.duration.content = plan_text(plan, stop_time)
        else:
            self.duration.content = "_Not the session's command: edit the path to make it so._"

    def show_refusal(self, field: str, reason: str) -> None:
        """The server refused the path: its reason beside the table, naming the node."""
        found = NODE_FIELD.match(field or "")
        where = f"node {int(found.group(1)) + 1}" if found else "the path"
        self.refusal.content = refused_text(where, reason)
        self.duration.content = "_Not planned: the session keeps the last path the server took._"

    def set_disabled(self, disabled: bool) -> None:
        """While a run goes on the command cannot change (the server refuses it anyway)."""
        self.locked = disabled
        self.sliders.set_disabled(disabled)
        self.speed.disabled = disabled
        self.acc.disabled = disabled
