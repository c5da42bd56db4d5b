"""Trend presentation (paper §3.2, footnote 3: several plots at once): uPlot charts of the live
window, or of a run's full-resolution transient on request, with zoom, the runs picked for comparison
overlaid (compare.py) and the shared time cursor; the dock on the right that holds them. The data they
draw are `series.py`'s, bounded there.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import units as unit_choice
from .series import LiveBuffer, Transient, overlay, with_cursor, y_range

log = logging.getLogger("simecs.viewer")
COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
#: A compared run's lines on a chart of several variables: a lighter shade of each variable's colour,
#: dashed in the run's own pattern (on a chart of one variable each run takes a colour of its own).
PREV_COLORS = ["#9ecae1", "#fc9272", "#a1d99b", "#fdae6b", "#bcbddc", "#c49c94", "#f7b6d2", "#9edae5"]
DASHES = [[6, 4], [2, 3], [10, 3, 2, 3], [1, 5], [14, 4]]
CURSOR = {"label": "cursor", "stroke": "#444444", "width": 1.0}


def scales(y: tuple[float, float] | None) -> dict[str, Any]:
    """A chart's scales: time on x; y fitted by uPlot, or the range given when a series has gaps."""
    out: dict[str, Any] = {"x": {"time": False}}
    if y is not None:
        out["y"] = {"auto": False, "range": [y[0], y[1]]}
    return out


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
        self.folder = gui.add_folder(self.title())
        with self.folder:
            self.chart = self._new_chart()
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
            close = gui.add_button("Close plot", color="gray")
            close.on_click(lambda _e: self.actions.close(self))

    def _new_chart(self, order: float | None = None) -> Any:
        return self.gui.add_uplot(
            (np.zeros(2), np.zeros(2)),
            ({"label": "t [s]"}, {"label": "…"}),
            scales=scales(None),
            cursor={"drag": {"x": True, "y": False}},
            legend={"show": True},
            height=220,
            order=order,
        )

    def reset_zoom(self) -> None:
        """Back to the whole window with fitted axes. A drag-zoom lives in the browser's chart (kept
        across data pushes), so the chart is drawn anew in its place."""
        with self.actions.batch():
            order = self.chart.order
            self.chart.remove()
            with self.folder:
                self.chart = self._new_chart(order)
        self.mark()

    def title(self) -> str:
        where = f" · {self.live_label} live" if self.live_label else " · live"
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

    def unit_of(self, name: str) -> tuple[str, float]:
        """The unit `name` is drawn in and the factor from the server's value (units.py)."""
        return unit_choice.shown(self.units.get(name, ""), self.angles)

    def series(self) -> tuple[dict[str, Any], ...]:
        out: list[dict[str, Any]] = [{"label": "t [s]"}]
        for k, name in enumerate(self.variables):
            unit = self.unit_of(name)[0]
            label = f"{name} [{unit}]" if unit and unit != "-" else name
            out.append({"label": label, "stroke": COLORS[k % len(COLORS)], "width": 1.5})
        one = len(self.variables) == 1
        for j, other in enumerate(self.others):
            for k, name in enumerate(self.variables):
                colour = COLORS[(j + 1) % len(COLORS)] if one else PREV_COLORS[k % len(PREV_COLORS)]
                out.append(
                    {
                        "label": f"{name} ({other.run_id})",
                        "stroke": colour,
                        "width": 1.0,
                        "dash": DASHES[j % 5],
                    }
                )
        if self.cursor is not None:
            out.append(CURSOR)
        return tuple(out)

    def redraw(self, live: LiveBuffer) -> None:
        """Send the chart its data: live window, or the loaded transient; compared runs overlaid."""
        self.dirty = False
        if self.full is not None:
            t = self.full.t
            ys = [self.full.ys.get(v, np.zeros(len(t))) for v in self.variables]
        else:
            t, ys = live.window(self.variables, float(self.window.value))
        others = [(o.t, [o.ys.get(v, np.zeros(len(o.t))) for v in self.variables]) for o in self.others]
        factors = [self.unit_of(v)[1] for v in self.variables]
        ys = [y * f for y, f in zip(ys, factors, strict=True)]
        others = [(t_o, [y * f for y, f in zip(ys_o, factors, strict=True)]) for t_o, ys_o in others]
        t, ys, compared = overlay(t, ys, others)
        ys = ys + [y for run in compared for y in run]
        if len(t) < 2:  # uPlot needs two points to draw axes
            t = np.array([0.0, 1e-3]) if len(t) == 0 else np.array([t[0], t[0] + 1e-3])
            ys = [np.zeros(2) if len(y) == 0 else np.full(2, y[-1]) for y in ys]
        if self.cursor is not None:
            t, ys, line = with_cursor(np.asarray(t, dtype=float), ys, self.cursor)
            ys = [*ys, line]
        series = self.series()
        units = sorted({self.unit_of(v)[0] for v in self.variables} - {"", "-"})
        axes = ({"label": "time [s]"}, {"label": ", ".join(units)})
        fixed = scales(y_range(ys))
        with self.actions.batch():
            if self.chart.series != series:
                self.chart.series = series
                self.chart.axes = axes
            if self.chart.scales != fixed:
                self.chart.scales = fixed
            self.chart.data = (np.asarray(t, dtype=float), *[np.asarray(y, dtype=float) for y in ys])

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


class PlotDock:
    """The open plots of a tab, docked where the layout says: the dock appears with the first plot
    and goes with the last; plots are known by their number (what the session controller's events
    name)."""

    def __init__(
        self, gui: Any, units: dict[str, str], actions: PlotActions, place: Callable[[Any], None]
    ) -> None:
        self.gui = gui
        self.place = place  # docks the plots' panel (layout.py)
        self.units = units
        self.actions = actions
        self.plots: dict[int, Plot] = {}
        self.live_label = ""  # the run shown live, named in each plot's title
        self.angles = "rad"  # angles shown in rad or deg: one choice for every plot (units.py)
        self.on_angles: Callable[[str], None] = lambda _a: None
        self.angle_choice: Any = None  # the dropdown, while the dock is shown
        self.counter = 0
        self.panel: Any = None
        self.tab: Any = None

    def open(self, name: str, choices: Sequence[str]) -> Plot:
        if self.panel is None:
            self.panel = self.gui.add_panel()
            self.tab = self.panel.add_tab("Plots")
            with self.tab:
                self.angle_choice = self.gui.add_dropdown(
                    "Angles in",
                    unit_choice.ANGLES,
                    initial_value=self.angles,
                    hint="every plot and the cursor",
                )
                self.angle_choice.on_update(lambda e: self.set_angles(str(e.target.value)))
            self.place(self.panel)
        self.counter += 1
        with self.tab:
            plot = Plot(self.gui, self.counter, [name], self.units, self.actions, self.live_label)
            plot.angles = self.angles
        self.plots[plot.number] = plot
        self.set_choices(choices)
        return plot

    def close(self, plot: Plot) -> None:
        plot.remove()
        self.plots.pop(plot.number, None)
        if not self.plots and self.panel is not None:
            self.panel.remove()
            self.panel, self.tab, self.angle_choice = None, None, None

    def get(self, number: int) -> Plot | None:
        return self.plots.get(number)

    def plotted(self) -> set[str]:
        return {v for p in self.plots.values() for v in p.variables}

    def set_choices(self, names: Sequence[str]) -> None:
        for plot in self.plots.values():
            plot.set_choices(names)

    def new_run(self, label: str = "") -> None:
        """A new run is shown (`label`: "run r3", "replay r4"): every plot back to its live window."""
        self.live_label = label
        for plot in self.plots.values():
            plot.live_label = label
            plot.full = None
            plot.folder.label = plot.title()
            plot.reset_zoom()

    def set_angles(self, angles: str) -> None:
        """Angles in rad or deg on every plot (and the values read at the cursor)."""
        if angles not in unit_choice.ANGLES or angles == self.angles:
            return
        self.angles = angles
        if self.angle_choice is not None and self.angle_choice.value != angles:
            self.angle_choice.value = angles
        for plot in self.plots.values():
            plot.angles = angles
            plot.dirty = True
        self.on_angles(angles)

    def set_cursor(self, at: float | None) -> None:
        """The shared time cursor on every chart (None: hidden); drawn at the next redraw."""
        for plot in self.plots.values():
            if plot.cursor != at:
                plot.cursor = at
                plot.dirty = True

    def mark_all(self) -> None:
        for plot in self.plots.values():
            plot.dirty = True

    def redraw(self, live: LiveBuffer) -> None:
        """Redraw the plots that have new data (about 10 times a second)."""
        for plot in list(self.plots.values()):
            if plot.dirty:
                try:
                    plot.redraw(live)
                except Exception as exc:  # a plot removed meanwhile, a closed tab
                    log.debug("plot redraw skipped: %s", exc)

    def remove(self) -> None:
        for plot in list(self.plots.values()):
            self.close(plot)
