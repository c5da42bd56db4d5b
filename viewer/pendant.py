"""The joint command panel in teach-pendant style (paper §2.2 step 5, §5.2): a path of nodes, each a
destination per joint with speed and acceleration percentages (PDL2 MOVE-like).

`JointPathEditor` is the table as data (add, teach, remove, reorder, edit), tested without a browser;
`PendantPanel` draws it: the table, the selected node's sliders (the same sliders as the
initialisation panel) and its percentages, and the buttons.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from simecs.mesh import messages as m
from simecs.mesh.model import Link

from .joints import DEG, JointSliders, clamp_to_limits
from .tree import fmt

MAX_NODES = 1000  # the protocol's limit (messages.JointPath)


class PathError(ValueError):
    """An edit the path cannot take; the message says why."""


@dataclass
class Node:
    q: list[float]  # rad
    speed_pct: float = 100.0
    acc_pct: float = 100.0


class JointPathEditor:
    """A joint path being edited: nodes and the selected one. Every method keeps it valid."""

    def __init__(self, links: Sequence[Link]) -> None:
        self.links = list(links)
        self.nodes: list[Node] = []
        self.selected = -1

    @property
    def n_joints(self) -> int:
        return len(self.links)

    def _check_index(self, i: int) -> int:
        if not 0 <= i < len(self.nodes):
            raise PathError(f"there is no node {i + 1} (the path has {len(self.nodes)})")
        return i

    def insert(self, q: Sequence[float], speed_pct: float = 100.0, acc_pct: float = 100.0) -> int:
        """Insert a node after the selected one (at the end if none) and select it."""
        if len(self.nodes) >= MAX_NODES:
            raise PathError(f"a path holds at most {MAX_NODES} nodes")
        if len(q) != self.n_joints:
            raise PathError(f"a node needs {self.n_joints} joint positions, got {len(q)}")
        node = Node(clamp_to_limits(q, self.links), *self._pct(speed_pct, acc_pct))
        at = self.selected + 1 if self.selected >= 0 else len(self.nodes)
        self.nodes.insert(at, node)
        self.selected = at
        return at

    def teach(self, current_q: Sequence[float]) -> int:
        """Record the arm's current pose as a new node (after the selected one)."""
        speed, acc = (
            (self.nodes[self.selected].speed_pct, self.nodes[self.selected].acc_pct)
            if self.nodes
            else (
                100.0,
                100.0,
            )
        )
        return self.insert(current_q, speed, acc)

    def duplicate(self, fallback_q: Sequence[float]) -> int:
        """A copy of the selected node after it (or a node at `fallback_q` on an empty path)."""
        if self.selected < 0:
            return self.insert(fallback_q)
        src = self.nodes[self.selected]
        return self.insert(src.q, src.speed_pct, src.acc_pct)

    def remove(self, i: int | None = None) -> None:
        i = self._check_index(self.selected if i is None else i)
        del self.nodes[i]
        self.selected = min(i, len(self.nodes) - 1)

    def move(self, delta: int, i: int | None = None) -> None:
        """Move a node `delta` places up (negative) or down; it stays selected."""
        i = self._check_index(self.selected if i is None else i)
        j = i + delta
        if not 0 <= j < len(self.nodes):
            raise PathError(f"node {i + 1} is already {'first' if delta < 0 else 'last'}")
        self.nodes[i], self.nodes[j] = self.nodes[j], self.nodes[i]
        self.selected = j

    def select(self, i: int) -> None:
        self.selected = self._check_index(i)

    def set_q(self, q: Sequence[float], i: int | None = None) -> None:
        i = self._check_index(self.selected if i is None else i)
        if len(q) != self.n_joints:
            raise PathError(f"a node needs {self.n_joints} joint positions, got {len(q)}")
        self.nodes[i].q = clamp_to_limits(q, self.links)

    @staticmethod
    def _pct(speed: float, acc: float) -> tuple[float, float]:
        for name, v in (("speed", speed), ("acceleration", acc)):
            if not 0.0 < float(v) <= 100.0:
                raise PathError(f"{name} {fmt(float(v))} % is not in (0, 100] %")
        return float(speed), float(acc)

    def set_pct(self, speed: float, acc: float, i: int | None = None) -> None:
        i = self._check_index(self.selected if i is None else i)
        self.nodes[i].speed_pct, self.nodes[i].acc_pct = self._pct(speed, acc)

    def clear(self) -> None:
        self.nodes.clear()
        self.selected = -1

    # -- protocol --------------------------------------------------------------------------------
    def to_command(self) -> m.JointPath:
        if not self.nodes:
            raise PathError("the path is empty: teach or add at least one node")
        return m.JointPath([m.PathNode(list(n.q), n.speed_pct, n.acc_pct) for n in self.nodes])

    def load(self, path: m.JointPath) -> None:
        """Take a path from the server (a restored session): nodes with other joint counts are skipped."""
        self.nodes = [
            Node(clamp_to_limits(n.q, self.links), n.speed_pct, n.acc_pct)
            for n in path.nodes
            if len(n.q) == self.n_joints
        ]
        self.selected = 0 if self.nodes else -1

    def table_markdown(self) -> str:
        """The path as a table in degrees; the selected node is marked."""
        if not self.nodes:
            return "_The path is empty: **Teach** records the arm's current pose as a node._"
        head = "| # | " + " | ".join(f"{link.joint}" for link in self.links) + " | v % | a % |"
        sep = "|---" * (self.n_joints + 3) + "|"
        rows = [head, sep]
        for k, node in enumerate(self.nodes):
            mark = f"**▶{k + 1}**" if k == self.selected else str(k + 1)
            qs = " | ".join(f"{x * DEG:.1f}" for x in node.q)
            rows.append(f"| {mark} | {qs} | {fmt(node.speed_pct)} | {fmt(node.acc_pct)} |")
        return "\n".join(rows) + "\n\nangles in degrees"


class PendantPanel:
    """Draws a `JointPathEditor`; calls `on_changed()` after every edit and `on_preview(q)` to show a
    node's destination on the 3D arm; `current_q()` gives the pose that **Teach** records."""

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
        self.buttons = gui.add_button_group(
            "Path",
            ("Teach", "Add", "Remove", "Up", "Down"),
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
            self.on_error("the command cannot change while the run goes on: abort it or wait for its end")
            return
        try:
            if action == "Teach":
                ed.teach(self.current_q())
            elif action == "Add":
                ed.duplicate(self.current_q())
            elif action == "Remove":
                ed.remove()
            elif action == "Up":
                ed.move(-1)
            elif action == "Down":
                ed.move(+1)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self.refresh()
        self.on_changed()

    def _picked(self, event: Any) -> None:
        if event.client is None or not self.editor.nodes:
            return
        try:
            self.editor.select(int(event.target.value) - 1)
        except (ValueError, PathError):
            return
        self.refresh()
        self.on_preview(self.editor.nodes[self.editor.selected].q)

    def _pct(self, event: Any) -> None:
        if event.client is None:
            return
        if not self.editor.nodes:
            self.on_error("the path is empty: teach a node first")
            return
        try:
            self.editor.set_pct(float(self.speed.value), float(self.acc.value))
        except PathError as exc:
            self.on_error(str(exc))
            node = self.editor.nodes[self.editor.selected]
            self.speed.value, self.acc.value = node.speed_pct, node.acc_pct
            return
        self.refresh()
        self.on_changed()

    def _moved(self, q: list[float]) -> None:
        if not self.editor.nodes:
            self.editor.teach(q)
        else:
            self.editor.set_q(q)
        self.on_preview(q)
        self.refresh()
        self.on_changed()

    def refresh(self) -> None:
        """Bring every widget to the editor's state."""
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
            self.sliders.set_q(node.q)
            if self.speed.value != node.speed_pct:
                self.speed.value = node.speed_pct
            if self.acc.value != node.acc_pct:
                self.acc.value = node.acc_pct

    def set_disabled(self, disabled: bool) -> None:
        """While a run goes on the command cannot change (the server refuses it anyway)."""
        self.locked = disabled
        self.sliders.set_disabled(disabled)
        self.speed.disabled = disabled
        self.acc.disabled = disabled
