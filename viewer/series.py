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
from simecs.mesh.protocol.columns import TIME
from simecs.mesh.protocol.messages import RunContext

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
    t: np.ndarray, ys: Sequence[np.ndarray], others: Sequence[tuple[np.ndarray, Sequence[np.ndarray]]]
) -> tuple[np.ndarray, list[np.ndarray], list[list[np.ndarray]]]:
    """The shown run and the compared runs on one time axis (uPlot needs one x array for all series).

    The axis is the union of every run's times; each run is interpolated onto it and has no value
    (NaN: uPlot draws nothing there) outside its own samples, so a run that ended early is drawn to
    where its data ends, never held flat beyond it.
    """
    if not others:
        return t, list(ys), []
    x = t
    for t_other, _ in others:
        x = np.union1d(x, t_other)
    if len(x) > 2 * MAX_POINTS:
        x = np.linspace(x[0], x[-1], 2 * MAX_POINTS)

    def onto(t_run: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.interp(x, t_run, y, left=np.nan, right=np.nan) if len(t_run) else np.full(len(x), np.nan)

    cur = [onto(t, y) for y in ys]
    return x, cur, [[onto(t_other, y) for y in ys_other] for t_other, ys_other in others]


def with_cursor(
    x: np.ndarray, ys: Sequence[np.ndarray], at: float
) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """`x` and `ys` with the time cursor drawn as one more series: a vertical line at `at`.

    uPlot joins a series' neighbouring points and draws nothing at all when two x values are equal,
    so the cursor is two points a millionth of the axis apart (before the next sample) spanning the
    data's range, with no value anywhere else; the other series get their values there, so their
    lines run on unbroken.
    """
    if len(x) < 2 or not x[0] <= at <= x[-1]:
        return x, list(ys), np.full(len(x), np.nan)
    k = int(np.searchsorted(x, at, side="right"))  # x[k - 1] <= at < x[k]
    step = 1e-6 * float(x[-1] - x[0])
    top = at + (min(step, (float(x[k]) - at) / 2) if k < len(x) else step)
    new = [top] if x[k - 1] == at else [at, top]
    x2 = np.insert(x, [k] * len(new), new)
    first = k - 1 if x[k - 1] == at else k

    def at_cursor(y: np.ndarray) -> np.ndarray:
        ok = np.isfinite(y)
        if not ok.any():
            return np.full(len(new), np.nan)
        xs = x[ok]
        return np.where(
            (xs[0] <= np.array(new)) & (np.array(new) <= xs[-1]), np.interp(new, xs, y[ok]), np.nan
        )

    ys2 = [np.insert(y, [k] * len(new), at_cursor(y)) for y in ys]
    lo, hi = finite_span(ys)
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    line = np.full(len(x2), np.nan)
    line[first], line[first + 1] = lo, hi
    return x2, ys2, line


def finite_span(ys: Sequence[np.ndarray]) -> tuple[float, float]:
    """The smallest and largest finite value of all `ys` ((0, 0) when there is none)."""
    finite = [y[np.isfinite(y)] for y in ys]
    values = np.concatenate([f for f in finite if len(f)]) if any(len(f) for f in finite) else np.zeros(1)
    return float(values.min()), float(values.max())


def y_range(ys: Sequence[np.ndarray]) -> tuple[float, float] | None:
    """The y range a chart must be given when some value is NaN (None: uPlot may fit it itself).

    uPlot fits its y axis with Math.min/Math.max over the data, and one NaN makes the whole range
    NaN: the chart draws nothing at all. A gap (a run that ended, the cursor's empty points) can only
    be NaN in the arrays viser sends, so such a chart gets its range from here, rounded out to half
    a decade so a live run growing inside it does not change it at every redraw.
    """
    if all(np.isfinite(y).all() for y in ys):
        return None
    lo, hi = finite_span(ys)
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    step = 10.0 ** math.floor(math.log10(span)) / 2
    lo, hi = math.floor(lo / step) * step, math.ceil(hi / step) * step
    return (lo - step, hi + step) if hi <= lo else (lo, hi)


def value_at(t: np.ndarray, y: np.ndarray, at: float) -> float | None:
    """A run's value at time `at`, linear between samples; None outside the run's samples."""
    if len(t) == 0 or not t[0] <= at <= t[-1]:
        return None
    return float(np.interp(at, t, y))


@dataclass
class Transient:
    """Full-resolution data of some variables of one run."""

    run_id: str
    t: np.ndarray
    ys: dict[str, np.ndarray] = field(default_factory=dict)
    t0: float | None = None  # the time window asked for (None: from the start / to the end)
    t1: float | None = None
    every: int = 1  # 1: every sample; more: decimated to stay under MAX_POINTS
    context: RunContext | None = None  # what produced the run (the server's results reply says)


def transient(
    run_id: str,
    columns: Sequence[str],
    rows: np.ndarray,
    t0: float | None,
    t1: float | None,
    every: int = 1,
    context: RunContext | None = None,
) -> Transient:
    """A results reply (time first, then the asked columns) as a Transient."""
    ys = {c: rows[:, k].copy() for k, c in enumerate(columns) if k}
    return Transient(run_id, rows[:, 0].copy(), ys, t0, t1, every, context)
