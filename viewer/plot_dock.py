"""The plots dock (paper §3.2, several plots at once): the open charts of a tab, docked where the
layout says, and what they share: the angle unit, the time cursor, the run shown live.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from . import units as unit_choice
from .plots import Plot, PlotActions
from .series import LiveBuffer

log = logging.getLogger("simecs.viewer")


#: Where the plots go: a tab to fill (a context) and the handle whose removal takes them away.
PlotsPlace = Callable[[], tuple[Any, Any]]


class PlotDock:
    """The open plots of a tab, where the layout puts them (`place()`: a column of their own on a wide
    screen, a tab beside the trees on a narrow one): they appear with the first plot and go with the
    last; plots are known by their number (what the session controller's events name)."""

    def __init__(self, gui: Any, units: dict[str, str], actions: PlotActions, place: PlotsPlace) -> None:
        self.gui = gui
        self.place = place
        self.units = units
        self.actions = actions
        self.plots: dict[int, Plot] = {}
        self.live_label = ""  # the run shown live, named in each plot's title
        self.stop_time = 0.0  # its span (0: not known)
        #: Angles in rad or deg: one choice for every plot (units.py); degrees at first, as the
        #: pendants' sliders and fields (issue 32, 9: one unit a user sees everywhere).
        self.angles = "deg"
        self.on_angles: Callable[[str], None] = lambda _a: None
        self.angle_choice: Any = None  # the dropdown, while the dock is shown
        self.counter = 0
        self.panel: Any = None
        self.tab: Any = None

    def open(self, name: str, choices: Sequence[str]) -> Plot:
        if self.panel is None:
            self.panel, self.tab = self.place()
            with self.tab:
                self.angle_choice = self.gui.add_dropdown(
                    "Angles in",
                    unit_choice.ANGLES,
                    initial_value=self.angles,
                    hint="every plot and the cursor",
                )
                self.angle_choice.on_update(lambda e: self.set_angles(str(e.target.value)))
        self.counter += 1
        with self.tab:
            plot = Plot(self.gui, self.counter, [name], self.units, self.actions, self.live_label)
            plot.angles = self.angles
            plot.stop_time = self.stop_time
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

    def new_run(self, label: str = "", stop_time: float = 0.0) -> None:
        """A new run is shown (`label`: "run r3", "replay r4"; `stop_time`: its span, 0 unknown):
        every plot back to its live window."""
        self.live_label = label
        self.stop_time = stop_time
        for plot in self.plots.values():
            plot.live_label = label
            plot.stop_time = stop_time
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

    def unit_of(self, name: str) -> tuple[str, float]:
        """The unit `name` is shown in on every plot, and the factor from the server's value."""
        return unit_choice.shown(self.units.get(name, ""), self.angles)

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
