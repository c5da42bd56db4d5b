"""The run a tab shows, as its frames arrive: what the columns are (from the run's layout), where the
link poses and joint positions sit in them, and the bounded live window the plots draw.

Column names come from `simecs.mesh.protocol.columns` only; frames of another run (an older run index) or of
another width are dropped here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from simecs.mesh.protocol import columns, frames
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription
from simecs.mesh.rules.scene_state import WorldColumns

from .series import LiveBuffer


@dataclass
class Sample:
    """What one live frame gives the tab: its rows, the links' poses and the joint positions of the
    newest row (None when the run does not stream them), where the grasped obstacles are after it
    (index in the run's list -> pose) and its contact forces as arrows (k, 2, 3)."""

    rows: np.ndarray
    poses: np.ndarray | None
    q: list[float] | None
    first_gap: bool = False  # the first live frames of this run that never came were before this one
    moved: dict[int, np.ndarray] = field(default_factory=dict)
    arrows: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    tool: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # the tool's position, every row


#: What a tab says (title, text, kind) when its first live frame of a run is missing.
LIVE_BEHIND = (
    "Live view behind",
    "This tab could not keep up with the run: some live samples were skipped (the run and its full "
    "results are not affected; reload them when it ends).",
    "warning",
)


class RunStream:
    """Layout and live window of the run being shown."""

    def __init__(self, model: ModelDescription) -> None:
        self.model = model
        self.layout: m.RunLayout | None = None
        self.live = LiveBuffer()
        self.units: dict[str, str] = {v.name: v.unit for v in model.variables}
        self.units.setdefault(columns.TIME, "s")
        self._poses: np.ndarray | None = None
        self._tool: np.ndarray | None = None  # the live columns of the tool's x, y, z
        self._q: list[int] | None = None
        # The scene draws the link frames: the poses of pose_frames() up to the tool.
        self._frames = model.pose_frames()[: len(model.links)]
        self._joints = model.joint_position_columns()
        self._world = WorldColumns([])
        self.moved: dict[int, np.ndarray] = {}  # where the run's grasps left its obstacles so far
        #: Live frames of the shown run that never reached this tab (gaps in their numbers): the hub
        #: drops them for a link that cannot keep up (PROTOCOL.md §1), so a slow tab slows only itself.
        self.missed = 0
        self._next_seq: int | None = None

    def take_layout(self, layout: m.RunLayout) -> None:
        """A run announced its columns: start its live window, find its poses and joint positions."""
        self.layout = layout
        self.missed, self._next_seq = 0, None
        self.live.reset(layout.live_columns)
        self._poses = columns.pose_indices(layout.live_columns, self._frames)
        tool = columns.pose_indices(layout.live_columns, [columns.TOOL_FRAME])
        self._tool = tool[0, :3] if tool is not None else None
        self._world = WorldColumns(layout.live_columns)
        self.moved = {}
        where = {c: i for i, c in enumerate(layout.live_columns)}
        complete = len(self._joints) == len(self.model.links) and all(c in where for c in self._joints)
        self._q = [where[c] for c in self._joints] if complete else None
        for name, unit in zip(layout.columns, layout.units, strict=False):
            self.units.setdefault(name, unit)

    def take_frame(self, frame: frames.Frame) -> Sample | None:
        """Add a live frame of the shown run to the window; None if it belongs to no run shown."""
        layout = self.layout
        if layout is None or not frame.of(layout.run_index, layout.context.attempt):
            return None  # another run's, or an earlier attempt's
        rows = frame.rows
        if rows.ndim != 2 or rows.shape[0] == 0 or rows.shape[1] != len(layout.live_columns):
            return None
        first_gap = False
        if self._next_seq is not None and frame.seq > self._next_seq:
            first_gap = self.missed == 0
            self.missed += frame.seq - self._next_seq
        self._next_seq = max(frame.seq + 1, self._next_seq or 0)
        self.live.append(rows)
        last = rows[-1]
        poses = last[self._poses] if self._poses is not None else None
        q = [float(last[i]) for i in self._q] if self._q is not None else None
        self._world.moved(rows, self.moved)
        tool = rows[:, self._tool] if self._tool is not None else np.zeros((0, 3))
        return Sample(rows, poses, q, first_gap, dict(self.moved), self._world.arrows(last), tool)
