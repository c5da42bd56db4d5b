"""A joint path as data (paper §2.2 step 5, §5.2): nodes, each a destination per joint with speed and
acceleration percentages (PDL2 MOVE-like), edited as a teach pendant edits them (add, teach, remove,
reorder) and kept valid at every step; and the joint-range rule shared with the initial pose.

No GUI here: `pendant.py` draws it, the session controller owns it, tests use it directly.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import Link
from simecs.mesh.protocol.robot_commands import MAX_ITEMS

from .markup import escape_text
from .tree import fmt

DEG = 180.0 / math.pi


def clamp_to_limits(q: Sequence[float], links: Sequence[Link]) -> list[float]:
    """Joint positions inside every joint's range (a saved pose may predate a narrower model)."""
    return [min(max(float(x), link.joint_min), link.joint_max) for x, link in zip(q, links, strict=True)]


MAX_NODES = MAX_ITEMS  # the protocol's limit (messages.JointPath, CartesianPath)
#: Why a pendant takes no edit while a run goes on (the server refuses a command then anyway).
LOCKED = "the command cannot change while the run goes on: abort it or wait for its end"


class PaceNode(Protocol):
    """What every node of a pendant's path has: its speed and acceleration reductions."""

    speed_pct: float
    acc_pct: float


N = TypeVar("N", bound=PaceNode)


class PathError(ValueError):
    """An edit the path cannot take; the message says why."""


@dataclass
class Node:
    q: list[float]  # rad
    speed_pct: float = 100.0
    acc_pct: float = 100.0


class NodeList(Generic[N]):
    """Nodes and the selected one, edited as a teach pendant edits them (insert after the selected
    one, remove, reorder, select); every method keeps the list valid. The joint path and the
    Cartesian path (cartesian.py) are both this, with their own node type."""

    def __init__(self) -> None:
        self.nodes: list[N] = []
        self.selected = -1

    @property
    def empty(self) -> bool:
        return not self.nodes

    def _check_index(self, i: int) -> int:
        if not 0 <= i < len(self.nodes):
            raise PathError(f"there is no node {i + 1} (the path has {len(self.nodes)})")
        return i

    def _insert(self, node: N) -> int:
        """Insert `node` after the selected one (at the end if none) and select it."""
        if len(self.nodes) >= MAX_NODES:
            raise PathError(f"a path holds at most {MAX_NODES} nodes")
        at = self.selected + 1 if self.selected >= 0 else len(self.nodes)
        self.nodes.insert(at, node)
        self.selected = at
        return at

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

    def clear(self) -> None:
        self.nodes.clear()
        self.selected = -1

    def set_pct(self, speed: float, acc: float, i: int | None = None) -> None:
        node = self.nodes[self._check_index(self.selected if i is None else i)]
        node.speed_pct, node.acc_pct = self._pct(speed, acc)

    @staticmethod
    def _pct(speed: float, acc: float) -> tuple[float, float]:
        for name, v in (("speed", speed), ("acceleration", acc)):
            if not 0.0 < float(v) <= 100.0:
                raise PathError(f"{name} {fmt(float(v))} % is not in (0, 100] %")
        return float(speed), float(acc)


def pick(path: NodeList[Any], label: str) -> bool:
    """Select the node a pendant's Node dropdown names (1-based); False when it names none."""
    try:
        path.select(int(label) - 1)
    except (ValueError, PathError):
        return False
    return True


def take_pct(path: NodeList[Any], speed: Any, acc: Any, on_error: Callable[[str], None]) -> bool:
    """A pendant's Speed and Acceleration fields onto the selected node; a value the path refuses
    is said and the fields show the node's own again."""
    try:
        path.set_pct(float(speed.value), float(acc.value))
    except PathError as exc:
        on_error(str(exc))
        node = path.nodes[path.selected]
        speed.value, acc.value = node.speed_pct, node.acc_pct
        return False
    return True


#: The path buttons of every pendant: Teach records where the arm is, Add copies the selected node.
PATH_BUTTONS = ("Teach", "Add", "Remove", "Up", "Down")


class PendantPath(Protocol):
    """What the path buttons do to a path (joint or Cartesian)."""

    def teach(self, here: Any, /) -> int: ...
    def duplicate(self, here: Any, /) -> int: ...
    def remove(self, i: int | None = None) -> None: ...
    def move(self, delta: int, i: int | None = None) -> None: ...


def press(path: PendantPath, button: str, here: Callable[[], Any]) -> None:
    """One of PATH_BUTTONS on `path`; `here()` is what Teach records (and Add on an empty path).
    PathError says why the path cannot take it."""
    if button == "Teach":
        path.teach(here())
    elif button == "Add":
        path.duplicate(here())
    elif button == "Remove":
        path.remove()
    elif button in ("Up", "Down"):
        path.move(-1 if button == "Up" else +1)
    else:
        raise PathError(f"no path button {button!r}")


class JointPathEditor(NodeList[Node]):
    """A joint path being edited: nodes (a destination per joint) and the selected one."""

    def __init__(self, links: Sequence[Link]) -> None:
        super().__init__()
        self.links = list(links)

    @property
    def n_joints(self) -> int:
        return len(self.links)

    def insert(self, q: Sequence[float], speed_pct: float = 100.0, acc_pct: float = 100.0) -> int:
        """Insert a node after the selected one (at the end if none) and select it."""
        if len(q) != self.n_joints:
            raise PathError(f"a node needs {self.n_joints} joint positions, got {len(q)}")
        return self._insert(Node(clamp_to_limits(q, self.links), *self._pct(speed_pct, acc_pct)))

    def teach(self, current_q: Sequence[float]) -> int:
        """Record the arm's current pose as a new node (after the selected one)."""
        if not self.nodes:
            return self.insert(current_q)
        node = self.nodes[self.selected]
        return self.insert(current_q, node.speed_pct, node.acc_pct)

    def duplicate(self, fallback_q: Sequence[float]) -> int:
        """A copy of the selected node after it (or a node at `fallback_q` on an empty path)."""
        if self.selected < 0:
            return self.insert(fallback_q)
        src = self.nodes[self.selected]
        return self.insert(src.q, src.speed_pct, src.acc_pct)

    def set_q(self, q: Sequence[float], i: int | None = None) -> None:
        i = self._check_index(self.selected if i is None else i)
        if len(q) != self.n_joints:
            raise PathError(f"a node needs {self.n_joints} joint positions, got {len(q)}")
        self.nodes[i].q = clamp_to_limits(q, self.links)

    # -- protocol --------------------------------------------------------------------------------
    def to_command(self) -> m.JointPath:
        if not self.nodes:
            raise PathError("the joint path is empty: teach or add at least one node")
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


def refused_text(where: str, reason: str) -> str:
    """How every pendant shows the server's refusal of its command, beside it: what it blames, why
    (the server's words as written: plain text, not markdown)."""
    return f"**✗ The server refused {where}:** {escape_text(reason)}"


def plan_text(plan: m.CommandPlan | None, stop_time: float, what: str = "path") -> str:
    """The command's duration as the server planned it, and a warning when the stop time cuts it
    (`what`: the command as the pendant names it)."""
    if plan is None:
        return f"_{what.capitalize()} duration: known once the {what} is sent._"
    if plan.duration > stop_time + 1e-9:
        text = (
            f"**Warning:** the stop time ({stop_time:g} s) ends the run before the {what} is done "
            f"({plan.duration:.2f} s): raise it in Settings."
        )
    else:
        text = f"{what.capitalize()} duration **{plan.duration:.2f} s** (stop time {stop_time:g} s)."
    return text + slowed_text(plan)


#: A plan slowed by less than this is said to keep the speeds asked for.
SLOWED_NOTED = 1.005


def slowed_text(plan: m.CommandPlan) -> str:
    """What the server slowed to keep every joint within its speed and acceleration limits (a move
    too fast for a joint is time-scaled, not refused): which steps, and by how much at most."""
    if plan.slowed < SLOWED_NOTED:
        return ""
    steps = [s for s in plan.steps if s.slowed >= SLOWED_NOTED]
    where = ", ".join(step_words(s.step) for s in steps[:4]) + (" …" if len(steps) > 4 else "")
    return (
        f"  \nSlowed **×{plan.slowed:.2f}** ({where}) to keep every joint within its speed and "
        "acceleration limits."
    )


STEP_PART = re.compile(r"(nodes|tasks|actions)\[(\d+)\]")
STEP_WORD = {"nodes": "node", "tasks": "task", "actions": "action"}


def step_words(step: str) -> str:
    """A step as the server names it (`tasks[1].actions[0]`, 0-based) in the words and numbers the
    pendants' tables use (`task 2, action 1`)."""
    found = STEP_PART.findall(step)
    if not found:
        return step
    return ", ".join(f"{STEP_WORD[kind]} {int(k) + 1}" for kind, k in found)


def ended_early(plan: m.CommandPlan | None, sim_time: float) -> str:
    """What to say of a finished run that stopped before its command was done ('' if it did not)."""
    if plan is None or plan.duration <= sim_time + 1e-6:
        return ""
    return f"It stopped before its command was done (the command takes {plan.duration:.2f} s)."
