"""Trend presentation (paper §3.2, footnote 3: several plots at once): live uPlot charts fed by the
decimated stream, then the full-resolution transient on request, zoom, and the previous run overlaid.

Every window is bounded: the live buffer keeps the last `LIVE_CAPACITY` samples and a plot shows at
most `window_s` seconds of them; a full-resolution load asks the server for at most
`MAX_POINTS` rows (decimating with `every` when a run is longer), so neither memory nor the data
resent to the browser on every redraw (uPlot gets whole arrays) can grow with the run.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

LIVE_CAPACITY = 3000  # samples per live column kept for plots (60 s at 50 Hz)
MAX_POINTS = 20_000  # rows per full-resolution load
COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]


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
            if n == 0 or "time" not in self.index:
                return np.empty(0), [np.empty(0) for _ in names]
            start = self._n % self.capacity if self._n > self.capacity else 0
            order = (np.arange(n) + start) % self.capacity
            rows = self._data[order]
        t = rows[:, self.index["time"]]
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


def overlay(t: np.ndarray, ys: Sequence[np.ndarray], t_prev: np.ndarray, ys_prev: Sequence[np.ndarray]):
    """Current and previous run on one time axis (uPlot needs one x array for all series).

    The axis is the union of both runs' times; each run is interpolated onto it and holds its last
    value beyond its own end (runs of different lengths compare from t = 0).
    """
    if len(t_prev) == 0:
        return t, list(ys), [np.zeros(len(t)) for _ in ys_prev]
    if len(t) == 0:
        return t_prev, [np.zeros(len(t_prev)) for _ in ys], list(ys_prev)
    x = np.union1d(t, t_prev)
    if len(x) > 2 * MAX_POINTS:
        x = np.linspace(x[0], x[-1], 2 * MAX_POINTS)
    cur = [np.interp(x, t, y) for y in ys]
    prev = [np.interp(x, t_prev, y) for y in ys_prev]
    return x, cur, prev


@dataclass
class Transient:
    """Full-resolution data of some variables of one run."""

    run_id: str
    t: np.ndarray
    ys: dict[str, np.ndarray] = field(default_factory=dict)
    t0: float | None = None  # the time window asked for (None: from the start / to the end)
    t1: float | None = None


class Plot:
    """One chart: some variables, live or at full resolution, optionally over the previous run."""

    def __init__(
        self,
        gui: Any,
        number: int,
        variables: list[str],
        units: dict[str, str],
        actions: PlotActions,
    ) -> None:
        self.gui = gui
        self.number = number
        self.variables = list(variables)
        self.units = units
        self.actions = actions
        self.full: Transient | None = None  # set when the full resolution is loaded
        self.prev: Transient | None = None  # set when "overlay previous run" is on and loaded
        self.dirty = True
        self.folder = gui.add_folder(self.title())
        with self.folder:
            self.chart = gui.add_uplot(
                (np.zeros(2), np.zeros(2)),
                ({"label": "t [s]"}, {"label": "…"}),
                scales={"x": {"time": False}},
                cursor={"drag": {"x": True, "y": False}},
                legend={"show": True},
                height=220,
            )
            self.window = gui.add_number("Live window [s]", 10.0, min=0.5, max=3600.0, step=0.5)
            self.window.on_update(lambda _e: self.mark())
            self.span = gui.add_vector2("Zoom t0, t1 [s]", (0.0, 0.0), step=0.001, hint="0, 0: the whole run")
            zoom = gui.add_button_group("Transient", ("Full resolution", "Zoom", "Live"))
            zoom.on_click(self._transient)
            self.compare = gui.add_checkbox("Overlay previous run", False)
            self.compare.on_update(
                lambda e: e.client is not None and self.actions.overlay(self, self.compare.value)
            )
            self.add_var = gui.add_dropdown(
                "Add variable", ("—",), hint="variables with the same unit fit best"
            )
            self.add_var.on_update(self._add_variable)
            close = gui.add_button("Close plot", color="gray")
            close.on_click(lambda _e: self.actions.close(self))

    def title(self) -> str:
        where = " · live"
        if self.full is not None:
            window = f" {self.full.t0:g}–{self.full.t1:g} s" if self.full.t0 is not None else ""
            where = f" · {self.full.run_id} full res{window}"
        return f"Plot {self.number}: " + ", ".join(self.variables) + where

    def mark(self) -> None:
        self.dirty = True

    def _transient(self, event: Any) -> None:
        choice = event.target.value
        if choice == "Live":
            self.full = None
            self.folder.label = self.title()
            self.mark()
            return
        t0, t1 = (float(v) for v in self.span.value)
        window = (t0, t1) if t1 > t0 else (None, None)
        if choice == "Zoom" and window == (None, None):
            self.actions.error(
                "Zoom: set t0 < t1 first (e.g. 0.5, 1.5), or drag across the plot to zoom there"
            )
            return
        self.actions.load_full(self, *window)

    def _add_variable(self, event: Any) -> None:
        if event.client is None:
            return
        name = event.target.value
        if name in self.actions.variable_names() and name not in self.variables:
            self.variables.append(name)
            self.folder.label = self.title()
            if self.full is not None:
                self.actions.load_full(self, None, None)
            self.actions.added(self, name)
            self.mark()
        self.add_var.value = "—"

    def set_choices(self, names: Sequence[str]) -> None:
        options = ("—", *[n for n in names if n not in self.variables])
        if tuple(self.add_var.options) != options:
            self.add_var.options = options

    def series(self, with_prev: bool) -> tuple[dict[str, Any], ...]:
        out: list[dict[str, Any]] = [{"label": "t [s]"}]
        for k, name in enumerate(self.variables):
            unit = self.units.get(name, "")
            label = f"{name} [{unit}]" if unit and unit != "-" else name
            out.append({"label": label, "stroke": COLORS[k % len(COLORS)], "width": 1.5})
        if with_prev and self.prev is not None:
            for k, name in enumerate(self.variables):
                out.append(
                    {
                        "label": f"{name} ({self.prev.run_id})",
                        "stroke": COLORS[k % len(COLORS)],
                        "width": 1.0,
                        "dash": [6, 4],
                    }
                )
        return tuple(out)

    def redraw(self, live: LiveBuffer) -> None:
        """Send the chart its data: live window, or the loaded transient; previous run overlaid."""
        self.dirty = False
        if self.full is not None:
            t = self.full.t
            ys = [self.full.ys.get(v, np.zeros(len(t))) for v in self.variables]
        else:
            t, ys = live.window(self.variables, float(self.window.value))
        with_prev = bool(self.compare.value) and self.prev is not None
        if with_prev:
            assert self.prev is not None
            prev_ys = [self.prev.ys.get(v, np.zeros(len(self.prev.t))) for v in self.variables]
            t, ys, prev = overlay(t, ys, self.prev.t, prev_ys)
            ys = ys + prev
        if len(t) < 2:  # uPlot needs two points to draw axes
            t = np.array([0.0, 1e-3]) if len(t) == 0 else np.array([t[0], t[0] + 1e-3])
            ys = [np.zeros(2) if len(y) == 0 else np.full(2, y[-1]) for y in ys]
        series = self.series(with_prev)
        units = sorted({self.units.get(v, "") for v in self.variables} - {"", "-"})
        axes = ({"label": "time [s]"}, {"label": ", ".join(units)})
        with self.actions.batch():
            if self.chart.series != series:
                self.chart.series = series
                self.chart.axes = axes
            self.chart.data = (np.asarray(t, dtype=float), *[np.asarray(y, dtype=float) for y in ys])

    def remove(self) -> None:
        self.folder.remove()


@dataclass
class PlotActions:
    """What a plot asks its tab to do (all may block on the server: the tab runs them off-thread)."""

    load_full: Callable[[Plot, float | None, float | None], None]
    overlay: Callable[[Plot, bool], None]
    close: Callable[[Plot], None]
    error: Callable[[str], None]
    added: Callable[[Plot, str], None]
    variable_names: Callable[[], Sequence[str]]
    batch: Callable[[], AbstractContextManager[None]]
