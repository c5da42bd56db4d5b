"""The tool's trace in 3D (issue 12, build item 6): where the tool went during the shown run, drawn as
a line that grows while the run goes on and stays after it, until the next run starts.

Redrawn at most every `REDRAW_S` (a line is sent whole, so not at every live frame), and kept under
`MAX_POINTS` by dropping every other point when full (the trace of a long run keeps its shape).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

TRACE_COLOR = (30, 160, 90)
MAX_POINTS = 4000
REDRAW_S = 0.2


class ToolTrace:
    """The trace of one page's shown run."""

    def __init__(self, scene: Any, name: str = "/env/tool_trace") -> None:
        self.scene = scene
        self.name = name
        self.points = np.zeros((0, 3))
        self.visible = True
        self._line: Any = None
        self._drawn = 0  # points in the line sent
        self._last = 0.0

    def clear(self) -> None:
        """A new run: its trace starts empty."""
        self.points = np.zeros((0, 3))
        self._remove_line()

    def add(self, positions: np.ndarray, now: float | None = None) -> None:
        """Tool positions of new live rows (k, 3); the line follows at most every REDRAW_S."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        positions = positions[np.all(np.isfinite(positions), axis=1)]
        if not positions.shape[0]:
            return
        self.points = np.concatenate([self.points, positions])
        if self.points.shape[0] > MAX_POINTS:
            self.points = np.concatenate([self.points[:-1:2], self.points[-1:]])
        now = time.monotonic() if now is None else now
        if now - self._last >= REDRAW_S:
            self.draw(now)

    def draw(self, now: float | None = None) -> None:
        """Send the line as it is now (also at a run's end, so its last part is not left out)."""
        self._last = time.monotonic() if now is None else now
        if self.points.shape[0] == self._drawn:
            return
        self._remove_line()
        if self.points.shape[0] >= 2 and self.visible:
            segments = np.stack([self.points[:-1], self.points[1:]], axis=1).astype(np.float32)
            self._line = self.scene.add_line_segments(
                self.name, segments, colors=TRACE_COLOR, thickness=2.5, thickness_units="screen"
            )
            self._drawn = self.points.shape[0]

    def show(self, visible: bool) -> None:
        self.visible = visible
        self._remove_line()
        self.draw()

    def _remove_line(self) -> None:
        self._drawn = 0
        if self._line is not None:
            try:
                self._line.remove()
            except Exception:
                pass
            self._line = None

    def remove(self) -> None:
        self._remove_line()
