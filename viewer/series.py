"""Time series the plots show, kept bounded: the live window of a run, full-resolution transients,
and two runs on one time axis (paper §3.2 trend presentation).

The live buffer keeps the last `LIVE_CAPACITY` samples; a full-resolution load asks the server for
at most `MAX_POINTS` rows (decimating with `every` when a run is longer), so neither memory nor the
data resent to the browser on every redraw (uPlot gets whole arrays) grows with the run.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from simecs.mesh.columns import TIME

LIVE_CAPACITY = 3000  # samples per live column kept for plots (60 s at 50 Hz)
MAX_POINTS = 20_000  # rows per full-resolution load


class LiveBuffer:
    """The last `capacity` rows of a run's live columns (a ring; oldest rows fall out)."""

    def __init__(self, capacity: int = LIVE_CAPACITY) -> None:
        self.capacity = capacity
        self.columns: list[str] = []
        self.index: dict[str, int] = {}
        self._data = np.empty((0, 0))
        self._n = 0  # rows ever appended
        self.lock = threading.Lock()

    def reset(self, columns: Sequence[str]) -> None:
        with self.lock:
            self.columns = list(columns)
            self.index = {c: i for i, c in enumerate(self.columns)}
            self._data = np.empty((self.capacity, len(self.columns)))
            self._n = 0

    def append(self, rows: np.ndarray) -> None:
        with self.lock:
            if rows.ndim != 2 or rows.shape[1] != len(self.columns) or not rows.shape[0]:
                return
            rows = rows[-self.capacity :]
            k = rows.shape[0]
            start = self._n % self.capacity
            first = min(k, self.capacity - start)
            self._data[start : start + first] = rows[:first]
            if first < k:
                self._data[: k - first] = rows[first:]
            self._n += k

    def __len__(self) -> int:
        return min(self._n, self.capacity)

    def has(self, name: str) -> bool:
        return name in self.index

    def window(
        self, names: Sequence[str], seconds: float | None = None
    ) -> tuple[np.ndarray, list[np.ndarray]]:
        """Time and the columns `names` (zeros for a column not streamed), oldest first, last `seconds`."""
        with self.lock:
            n = len(self)
            if n == 0 or TIME not in self.index:
                return np.empty(0), [np.empty(0) for _ in names]
            start = self._n % self.capacity if self._n > self.capacity else 0
            order = (np.arange(n) + start) % self.capacity
            rows = self._data[order]
        t = rows[:, self.index[TIME]]
        if seconds is not None and seconds > 0:
            keep = t >= t[-1] - seconds
            rows, t = rows[keep], t[keep]
        ys = [rows[:, self.index[c]] if c in self.index else np.zeros(len(t)) for c in names]
        return t.copy(), [y.copy() for y in ys]


def every_for(
    samples: int, t0: float | None, t1: float | None, stop_time: float, max_points: int = MAX_POINTS
) -> int:
    """The decimation step that keeps a full-resolution request under `max_points` rows."""
    if samples <= 0:
        return 1
    span = stop_time if stop_time > 0 else 1.0
    lo = 0.0 if t0 is None else max(0.0, t0)
    hi = span if t1 is None else min(span, t1)
    fraction = max(0.0, min(1.0, (hi - lo) / span)) if hi > lo else 1.0
    return max(1, math.ceil(samples * fraction / max_points))


def overlay(
    t: np.ndarray, ys: Sequence[np.ndarray], t_prev: np.ndarray, ys_prev: Sequence[np.ndarray]
) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Current and previous run on one time axis (uPlot needs one x array for all series).

    The axis is the union of both runs' times; each run is interpolated onto it and has no value
    (NaN: uPlot draws nothing there) outside its own samples, so a run that ended early is drawn to
    where its data ends, never held flat beyond it.
    """
    if len(t_prev) == 0:
        return t, list(ys), [np.full(len(t), np.nan) for _ in ys_prev]
    if len(t) == 0:
        return t_prev, [np.full(len(t_prev), np.nan) for _ in ys], list(ys_prev)
    x = np.union1d(t, t_prev)
    if len(x) > 2 * MAX_POINTS:
        x = np.linspace(x[0], x[-1], 2 * MAX_POINTS)
    cur = [np.interp(x, t, y, left=np.nan, right=np.nan) for y in ys]
    prev = [np.interp(x, t_prev, y, left=np.nan, right=np.nan) for y in ys_prev]
    return x, cur, prev


@dataclass
class Transient:
    """Full-resolution data of some variables of one run."""

    run_id: str
    t: np.ndarray
    ys: dict[str, np.ndarray] = field(default_factory=dict)
    t0: float | None = None  # the time window asked for (None: from the start / to the end)
    t1: float | None = None
    every: int = 1  # 1: every sample; more: decimated to stay under MAX_POINTS


def transient(
    run_id: str, columns: Sequence[str], rows: np.ndarray, t0: float | None, t1: float | None, every: int = 1
) -> Transient:
    """A results reply (time first, then the asked columns) as a Transient."""
    ys = {c: rows[:, k].copy() for k, c in enumerate(columns) if k}
    return Transient(run_id, rows[:, 0].copy(), ys, t0, t1, every)
