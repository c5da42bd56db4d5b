"""Trend presentation (paper §3.2, footnote 3: several plots at once): uPlot charts of the live
window, or of a run's full-resolution transient on request, with zoom, the runs picked for comparison
overlaid (compare.py), the shared time cursor, and one variable against another (xy_plot.py). The
data they draw are `series.py`'s, bounded there; the dock that holds the charts is `plot_dock.py`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import units as unit_choice
from .series import LiveBuffer, Transient, overlay, value_at, with_cursor, y_range
from .xy_plot import XYLine, svg

log = logging.getLogger("simecs.viewer")
COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
#: A compared run's lines on a chart of several variables: a lighter shade of each variable's colour,
#: dashed in the run's own pattern (on a chart of one variable each run takes a colour of its own).
PREV_COLORS = ["#9ecae1", "#fc9272", "#a1d99b", "#fdae6b", "#bcbddc", "#c49c94", "#f7b6d2", "#9edae5"]
DASHES = [[6, 4], [2, 3], [10, 3, 2, 3], [1, 5], [14, 4]]
CURSOR = {"label": "cursor", "stroke": "#444444", "width": 1.0}
TIME_AXIS = "time"  # the X axis choice of a chart over time (any other: a variable, xy_plot.py)


def scales(
    y: tuple[float, float] | None, x: tuple[float, float] | None = None, reset: int = 0
) -> dict[str, Any]:
    """A chart's scales: time on x, shown over `x` (None: fitted by uPlot); y fitted by uPlot, or the
    range given when a series has gaps. viser keeps a user's drag-zoom of an x range across data
    pushes and draws the chart anew when the scales change: `reset` is bumped to clear a zoom."""
    out: dict[str, Any] = {"x": {"time": False}}
    if x is not None:
        out["x"] = {"time": False, "range": [x[0], x[1]], "reset": reset}
    if y is not None:
        out["y"] = {"auto": False, "range": [y[0], y[1]]}
    return out


#: Of the live window, how far ahead of the newest sample the time axis reaches once the trace has
#: filled it: the axis then moves on by this much at a time, a sweep rather than a scroll, so the
#: chart is drawn anew a few times per window instead of at every redraw.
SWEEP_AHEAD = 0.25


def live_axis(
    t_last: float, window: float, stop_time: float, shown: tuple[float, float] | None
) -> tuple[float, float]:
    """The time axis of the live window: the run's own span from 0 when it is shorter than the window,
    else the window; kept as `shown` while the newest sample `t_last` is inside it."""
    span = min(window, stop_time) if stop_time > 0 else window
    if shown is not None and abs((shown[1] - shown[0]) - span) < 1e-9 and shown[0] <= t_last <= shown[1]:
        return shown
    if t_last <= span:
        return 0.0, span
    hi = t_last + SWEEP_AHEAD * span
    return hi - span, hi


class Plot:
    """One chart: some variables, live or at full resolution, over the runs picked for comparison."""

    def __init__(
        self,
        gui: Any,
        number: int,
        variables: list[str],
        units: dict[str, str],
        actions: PlotActions,
        live_label: str = "",
    ) -> None:
        self.gui = gui
        self.number = number
        self.variables = list(variables)
        self.units = units
        self.actions = actions
        self.full: Transient | None = None  # set when the full resolution is loaded
        self.others: list[Transient] = []  # the compared runs, as loaded for this chart's variables
        self.cursor: float | None = None  # the shared time cursor, s (None: not shown)
        self.angles = "rad"  # what angles are shown in (the plots dock's choice, units.py)
        self.dirty = True
        self.live_label = live_label  # the run the live window shows ("run r3", "replay r4")
        self.stop_time = 0.0  # of the run shown live: its span, when shorter than the window
        self.x_var = TIME_AXIS  # what the variables are drawn against
        self.x_shown: tuple[float, float] | None = None  # the time axis the chart was last given
        self.resets = 0  # bumped by reset_zoom: the chart is drawn anew in the browser
        self.folder = gui.add_folder(self.title())
        with self.folder:
            self.chart = gui.add_uplot(
                (np.zeros(2), np.zeros(2)),
                ({"label": "t [s]"}, {"label": "…"}),
                scales=scales(None),
                cursor={"drag": {"x": True, "y": False}},
                legend={"show": True},
                height=220,
            )
            self.xy = gui.add_html("", visible=False)
            self.window = gui.add_number("Live window [s]", 10.0, min=0.5, max=3600.0, step=0.5)
            self.window.on_update(lambda _e: self.mark())
            self.span = gui.add_vector2("Zoom t0, t1 [s]", (0.0, 0.0), step=0.001, hint="0, 0: the whole run")
            zoom = gui.add_button_group("Transient", ("Full resolution", "Zoom", "Live"))
            zoom.on_click(self._transient)
            reset = gui.add_button(
                "Reset zoom", color="gray", hint="undo a drag-zoom: the whole window, axes fitted to the data"
            )
            reset.on_click(lambda _e: self.reset_zoom())
            self.add_var = gui.add_dropdown(
                "Add variable", ("—",), hint="variables with the same unit fit best"
            )
            self.add_var.on_update(self._add_variable)
            self.x_axis = gui.add_dropdown(
                "X axis", (TIME_AXIS,), hint="time, or a variable to draw the others against (tool x vs y)"
            )
            self.x_axis.on_update(self._x_axis_changed)
            close = gui.add_button("Close plot", color="gray")
            close.on_click(lambda _e: self.actions.close(self))

    def reset_zoom(self) -> None:
        """Back to the whole window with fitted axes. A drag-zoom lives in the browser's chart (kept
        across data pushes): new scales make the browser draw the same chart anew, unzoomed."""
        self.resets += 1
        self.x_shown = None
        self.mark()

    def title(self) -> str:
        where = f" · {self.live_label} live" if self.live_label else " · live"
        if self.full is not None:
            window = f" {self.full.t0:g}–{self.full.t1:g} s" if self.full.t0 is not None else ""
            where = f" · {self.full.run_id} full res{window}"
        against = f" vs {self.x_var}" if self.x_var != TIME_AXIS else ""
        return f"Plot {self.number}: " + ", ".join(self.variables) + against + where

    def mark(self) -> None:
        self.dirty = True

    def _transient(self, event: Any) -> None:
        choice = event.target.value
        if choice == "Live":
            self.full = None
            self.folder.label = self.title()
            self.reset_zoom()  # live follows the newest samples: no drag-zoom left over
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
        self.add(event.target.value)
        self.add_var.value = "—"

    def add(self, name: str) -> None:
        """Another variable on this chart (one the run streams or can stream)."""
        if name in self.actions.variable_names() and name not in self.variables:
            self.variables.append(name)
            self.folder.label = self.title()
            if self.full is not None:
                self.actions.load_full(self, None, None)
            self.actions.added(self, name)
            self.mark()

    def set_choices(self, names: Sequence[str]) -> None:
        options = ("—", *[n for n in names if n not in self.variables])
        if tuple(self.add_var.options) != options:
            self.add_var.options = options
        axes = (TIME_AXIS, *[n for n in names if n not in self.variables])
        if self.x_var not in axes:
            axes = (*axes, self.x_var)
        if tuple(self.x_axis.options) != axes:
            self.x_axis.options = axes

    def names(self) -> list[str]:
        """What the chart needs of a run: its variables, and the one on the X axis if not time."""
        return self.variables + ([self.x_var] if self.x_var != TIME_AXIS else [])

    def _x_axis_changed(self, event: Any) -> None:
        if event.client is not None:
            self.set_x(str(event.target.value))

    def set_x(self, name: str) -> None:
        """Draw the variables against `name` (TIME_AXIS: over time)."""
        if name == self.x_var:
            return
        self.x_var = name
        if self.x_axis.value != name:
            if name not in self.x_axis.options:
                self.x_axis.options = (*self.x_axis.options, name)
            self.x_axis.value = name
        self.chart.visible = self.x_var == TIME_AXIS
        self.xy.visible = self.x_var != TIME_AXIS
        if self.x_var != TIME_AXIS:
            self.actions.added(self, self.x_var)  # streamed from now on
            if self.full is not None:
                self.actions.load_full(self, self.full.t0, self.full.t1)
        self.folder.label = self.title()
        self.mark()

    def unit_of(self, name: str) -> tuple[str, float]:
        """The unit `name` is drawn in and the factor from the server's value (units.py)."""
        return unit_choice.shown(self.units.get(name, ""), self.angles)

    def style(self, run: int, k: int) -> tuple[str, list[int]]:
        """Colour and dash pattern of variable `k` of run `run` (0: the shown run, 1..: the compared
        ones in order): on a chart of one variable each run takes a colour of its own."""
        if run == 0:
            return COLORS[k % len(COLORS)], []
        colour = COLORS[run % len(COLORS)] if len(self.variables) == 1 else PREV_COLORS[k % len(PREV_COLORS)]
        return colour, DASHES[(run - 1) % len(DASHES)]

    def series(self) -> tuple[dict[str, Any], ...]:
        out: list[dict[str, Any]] = [{"label": "t [s]"}]
        for k, name in enumerate(self.variables):
            label = unit_choice.labelled(name, self.unit_of(name)[0])
            out.append({"label": label, "stroke": self.style(0, k)[0], "width": 1.5})
        for j, other in enumerate(self.others, start=1):
            for k, name in enumerate(self.variables):
                colour, dash = self.style(j, k)
                out.append(
                    {"label": f"{name} ({other.run_id})", "stroke": colour, "width": 1.0, "dash": dash}
                )
        if self.cursor is not None:
            out.append(CURSOR)
        return tuple(out)

    def runs_data(
        self, live: LiveBuffer, names: list[str], missing: float = 0.0
    ) -> list[tuple[str, np.ndarray, list[np.ndarray]]]:
        """(run, t, the columns `names` in the units shown) of the shown run (its full resolution,
        else the live window) and then of each compared run; `missing` fills a column a run lacks."""
        if self.full is not None:
            shown = [(self.full.run_id, self.full.t, [self.full.ys.get(v) for v in names])]
        else:
            t, ys = live.window(names, float(self.window.value))
            shown = [(self.live_label or "live", t, list(ys))]
        runs = shown + [(o.run_id, o.t, [o.ys.get(v) for v in names]) for o in self.others]
        factors = [self.unit_of(v)[1] for v in names]
        return [
            (
                run_id,
                t,
                [np.full(len(t), missing) if y is None else y * f for y, f in zip(ys, factors, strict=True)],
            )
            for run_id, t, ys in runs
        ]

    def redraw(self, live: LiveBuffer) -> None:
        """Send the chart its data: live window, or the loaded transient; compared runs overlaid."""
        self.dirty = False
        if self.x_var != TIME_AXIS:
            self._redraw_xy(live)
            return
        (_, t, ys), *others = self.runs_data(live, self.variables)
        t, ys, compared = overlay(t, ys, [(t_o, ys_o) for _, t_o, ys_o in others])
        ys = ys + [y for run in compared for y in run]
        x_axis = self._x_axis(t)
        if len(t) < 2:  # uPlot needs two x values to draw axes: the axis' ends, nothing invented in it
            t = np.array(x_axis)
            ys = [np.array([y[-1] if len(y) else np.nan, np.nan]) for y in ys]
        if self.cursor is not None:
            t, ys, line = with_cursor(np.asarray(t, dtype=float), ys, self.cursor)
            ys = [*ys, line]
        series = self.series()
        units = sorted({self.unit_of(v)[0] for v in self.variables} - {"", "-"})
        axes = ({"label": "time [s]"}, {"label": ", ".join(units)})
        fixed = scales(y_range(ys), x_axis, self.resets)
        with self.actions.batch():
            if self.chart.series != series:
                self.chart.series = series
                self.chart.axes = axes
            if self.chart.scales != fixed:
                self.chart.scales = fixed
            self.chart.data = (np.asarray(t, dtype=float), *[np.asarray(y, dtype=float) for y in ys])

    def _x_axis(self, t: np.ndarray) -> tuple[float, float]:
        """The time axis shown: the live window (live_axis), or what a loaded transient and the runs
        beside it span (the window asked for, when one was)."""
        if self.full is None:
            t_last = float(t[-1]) if len(t) else 0.0
            self.x_shown = live_axis(t_last, float(self.window.value), self.stop_time, self.x_shown)
            return self.x_shown
        lo = self.full.t0 if self.full.t0 is not None else (float(t[0]) if len(t) else 0.0)
        hi = self.full.t1 if self.full.t1 is not None else (float(t[-1]) if len(t) else 1.0)
        if hi <= lo:
            hi = lo + 1.0
        self.x_shown = (float(lo), float(hi))
        return self.x_shown

    def _redraw_xy(self, live: LiveBuffer) -> None:
        """The variables against the X-axis variable, for the shown run and the compared ones."""
        lines, marks = [], []
        for j, (run_id, t, ys) in enumerate(self.runs_data(live, self.names(), missing=np.nan)):
            x = ys[-1]
            for k, name in enumerate(self.variables):
                colour, dash = self.style(j, k)
                lines.append(XYLine(f"{name} ({run_id})", colour, x, ys[k], " ".join(map(str, dash))))
                if self.cursor is not None:
                    at_x, at_y = value_at(t, x, self.cursor), value_at(t, ys[k], self.cursor)
                    if at_x is not None and at_y is not None:
                        marks.append((at_x, at_y))
        y_units = sorted({self.unit_of(v)[0] for v in self.variables} - {"", "-"})
        x_label = unit_choice.labelled(self.x_var, self.unit_of(self.x_var)[0])
        content = svg(lines, x_label, ", ".join(y_units), marks)
        with self.actions.batch():
            if self.xy.content != content:
                self.xy.content = content

    def remove(self) -> None:
        self.folder.remove()


@dataclass
class PlotActions:
    """What a plot asks its tab to do (the session controller does the requests off-thread)."""

    load_full: Callable[[Plot, float | None, float | None], None]
    close: Callable[[Plot], None]
    error: Callable[[str], None]
    added: Callable[[Plot, str], None]
    variable_names: Callable[[], Sequence[str]]
    batch: Callable[[], AbstractContextManager[None]]
