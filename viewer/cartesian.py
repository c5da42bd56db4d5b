"""A Cartesian path as data (paper §2.1 movement commands in Cartesian space): nodes, each a tool pose
(position in m, roll-pitch-yaw in the world frame) reached by a straight line (LIN) or a joint move
(PTP), with speed and acceleration percentages; edited as a teach pendant edits it and kept valid.

Whether the arm can reach a pose is the server's to say (it plans the path with the session's model,
values and initial pose); the editor keeps what it was told (`refused`) so the pendant shows the
reason beside the node. No GUI here: `cartesian_pendant.py` draws it, the session controller owns it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription
from simecs.mesh.rules.kinematics import link_frames, matrix_from_quat, quat_from_matrix, rot_rpy, rpy_of

from .path import DEG, NodeList, PathError, refused_text
from .tree import fmt

MOVES = ("lin", "ptp")  # messages.CartesianNode.move
#: Where a refusal's field names a node: command.nodes[3].position -> node 3.
NODE_FIELD = re.compile(r"^command\.nodes\[(\d+)\]")


@dataclass
class Pose:
    """A tool pose: position (m) and roll, pitch, yaw (rad) about the fixed world axes."""

    position: list[float]
    rpy: list[float]

    def __post_init__(self) -> None:
        for name, v in (("position", self.position), ("orientation", self.rpy)):
            if len(v) != 3 or not all(math.isfinite(float(x)) for x in v):
                raise PathError(f"the {name} needs three finite numbers, got {list(v)}")
        self.position = [float(x) for x in self.position]
        self.rpy = [float(x) for x in self.rpy]


def tool_pose(model: ModelDescription, values: Mapping[str, float], q: Sequence[float]) -> Pose:
    """The tool pose of the arm at joint positions `q` (what **Teach** records)."""
    p, R = link_frames(model, values, q)[-1]
    return Pose([float(x) for x in p], [float(x) for x in rpy_of(R)])


@dataclass
class CartNode:
    pose: Pose
    move: str = "lin"
    speed_pct: float = 100.0
    acc_pct: float = 100.0
    force: float = 0.0  # kept as loaded (opspace_hybrid); the pendant shows it, edits keep it
    force_axis: list[float] = field(default_factory=lambda: [0.0, 0.0, -1.0])


class CartesianPathEditor(NodeList[CartNode]):
    """A Cartesian path being edited: nodes and the selected one; `refused` is the server's last
    refusal (node index or -1 for the whole command, and its reason), cleared by the next plan."""

    def __init__(self) -> None:
        super().__init__()
        self.refused: tuple[int, str] | None = None

    def insert(self, pose: Pose, move: str = "lin", speed_pct: float = 100.0, acc_pct: float = 100.0) -> int:
        """Insert a node after the selected one (at the end if none) and select it."""
        return self._insert(CartNode(pose, self._move(move), *self._pct(speed_pct, acc_pct)))

    def teach(self, pose: Pose) -> int:
        """Record the tool's current pose as a new node, with the selected node's move and speeds."""
        if self.selected < 0:
            return self.insert(pose)
        node = self.nodes[self.selected]
        return self.insert(pose, node.move, node.speed_pct, node.acc_pct)

    def duplicate(self, fallback: Pose) -> int:
        """A copy of the selected node after it (or a node at `fallback` on an empty path)."""
        if self.selected < 0:
            return self.insert(fallback)
        src = self.nodes[self.selected]
        return self.insert(
            Pose(list(src.pose.position), list(src.pose.rpy)), src.move, src.speed_pct, src.acc_pct
        )

    def set_pose(self, pose: Pose, i: int | None = None) -> None:
        self.nodes[self._check_index(self.selected if i is None else i)].pose = pose

    def set_force(self, force: float, axis: Sequence[float], i: int | None = None) -> None:
        """The force the tool pushes with from this node on, and along which world direction (under
        the hybrid control system; 0 N: motion only). The protocol's bounds, checked here."""
        node = self.nodes[self._check_index(self.selected if i is None else i)]
        obj = {"position": [0.0] * 3, "rpy": [0.0] * 3, "force": float(force), "force_axis": list(axis)}
        try:
            codec.from_obj(m.CartesianNode, obj)
        except (codec.DecodeError, TypeError, ValueError) as exc:
            raise PathError(str(exc)) from None
        node.force, node.force_axis = float(force), [float(a) for a in axis]

    def set_move(self, move: str, i: int | None = None) -> None:
        self.nodes[self._check_index(self.selected if i is None else i)].move = self._move(move)

    @staticmethod
    def _move(move: str) -> str:
        move = str(move).lower()
        if move not in MOVES:
            raise PathError(f"a move is LIN or PTP, not {move!r}")
        return move

    # -- the server's answer -------------------------------------------------------------------------
    def refuse(self, field_name: str, reason: str) -> int:
        """Keep the server's refusal of the path; the node it names (-1: the whole path)."""
        found = NODE_FIELD.match(field_name or "")
        node = int(found.group(1)) if found and int(found.group(1)) < len(self.nodes) else -1
        self.refused = (node, reason)
        return node

    def accepted(self) -> None:
        self.refused = None

    # -- protocol --------------------------------------------------------------------------------
    def to_command(self) -> m.CartesianPath:
        if not self.nodes:
            raise PathError("the Cartesian path is empty: teach or add at least one node")
        return m.CartesianPath(
            [
                m.CartesianNode(
                    list(n.pose.position),
                    list(n.pose.rpy),
                    n.move,  # type: ignore[arg-type]  # checked by _move
                    n.speed_pct,
                    n.acc_pct,
                    n.force,
                    list(n.force_axis),
                )
                for n in self.nodes
            ]
        )

    def load(self, path: m.CartesianPath) -> None:
        """Take a path from the server (a restored session)."""
        self.nodes = [
            CartNode(
                Pose(list(n.position), list(n.rpy)),
                n.move,
                n.speed_pct,
                n.acc_pct,
                n.force,
                list(n.force_axis),
            )
            for n in path.nodes
        ]
        self.selected = 0 if self.nodes else -1
        self.refused = None

    def table_markdown(self) -> str:
        """The path as a table (mm, degrees); the selected node is marked, a refused one crossed."""
        if not self.nodes:
            return "_The path is empty: **Teach** records the tool's current pose as a node._"
        forces = any(n.force > 0 for n in self.nodes)
        head = "| # | move | x | y | z | roll | pitch | yaw | v % | a % |" + (" F N |" if forces else "")
        rows = [head, "|---" * (10 + forces) + "|"]
        bad = self.refused[0] if self.refused is not None else -2
        for k, node in enumerate(self.nodes):
            mark = f"▶{k + 1}" if k == self.selected else str(k + 1)
            mark = f"**{mark}**" if k == self.selected else mark
            if k == bad:
                mark += " ✗"
            xyz = " | ".join(f"{x * 1000:.0f}" for x in node.pose.position)
            rpy = " | ".join(f"{a * DEG:.1f}" for a in node.pose.rpy)
            pct = f"{fmt(node.speed_pct)} | {fmt(node.acc_pct)}"
            row = f"| {mark} | {node.move.upper()} | {xyz} | {rpy} | {pct} |"
            rows.append(row + (f" {fmt(node.force)} |" if forces else ""))
        return "\n".join(rows) + "\n\npositions in mm, angles in degrees (world frame)"


def refusal_text(editor: CartesianPathEditor) -> str:
    """The server's reason for refusing the path, naming the node ('' when it took the path)."""
    if editor.refused is None:
        return ""
    node, reason = editor.refused
    where = f"node {node + 1}" if node >= 0 else "the path"
    return refused_text(where, reason)


def node_target(plan: m.CommandPlan | None, node: int) -> list[float] | None:
    """The joint set points at the end of node `node` as the server planned them (None: not known)."""
    if plan is None or plan.kind != "cartesian_path" or not 0 <= node < len(plan.steps):
        return None
    q = plan.steps[node].q_end
    return list(q) if q else None


def rotation_wxyz(rpy: Sequence[float]) -> tuple[float, float, float, float]:
    """The quaternion (w, x, y, z) of roll, pitch, yaw (for the gizmo)."""
    q = quat_from_matrix(rot_rpy(rpy))
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def rpy_of_wxyz(wxyz: Sequence[float]) -> list[float]:
    """Roll, pitch, yaw of a quaternion (w, x, y, z) (from the gizmo)."""
    q = np.asarray(wxyz, dtype=float)
    n = float(np.linalg.norm(q))
    if not (math.isfinite(n) and n > 1e-9):
        raise PathError(f"the orientation {list(wxyz)} is not a rotation")
    return [float(a) for a in rpy_of(matrix_from_quat(q / n))]
