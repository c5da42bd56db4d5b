"""Where each region of a tab goes (issue: a layout that never hides the arm).

Every region is docked around the 3D view, none floats over it: the model's trees on the left edge,
the session's toolbar and the command pendant stacked on the right edge, the documentation under the
trees, the plots in a column of their own on a wide screen and under the trees on a narrow one. The
user may drag, resize and minimise any of them (viser's dock); these are the places they start in.
Modals (the models list, the run settings) are the only things drawn over the view, and only while
the user answers them.

The widths follow the browser's viewport, read when the tab connects (`browser.recall`), so the 3D
view keeps at least `MIN_VIEW_PX` at 1024×768 and half the screen at 1920×1080.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

WIDE_PX = 1400  # from this viewport width on, the plots get a column of their own
MIN_VIEW_PX = 360  # the 3D view is never narrower than this at the smallest supported width (1024)


@dataclass(frozen=True)
class Layout:
    """The starting places of a tab's regions for a viewport of `width` × `height` CSS pixels."""

    width: int = 1600
    height: int = 900

    @property
    def wide(self) -> bool:
        return self.width >= WIDE_PX

    @property
    def left_px(self) -> int:
        """The trees (parameters, variables, results) and, below them, documentation."""
        return 380 if self.wide else max(260, min(300, (self.width - MIN_VIEW_PX) // 2))

    @property
    def right_px(self) -> int:
        """The toolbar and the command pendant."""
        return 440 if self.wide else max(300, min(360, self.width - MIN_VIEW_PX - self.left_px))

    @property
    def plots_px(self) -> int:
        """The plot column on a wide screen (a narrow one stacks the plots under the trees)."""
        return max(380, min(560, self.width - self.left_px - self.right_px - 560))

    # -- placing the regions --------------------------------------------------------------------
    def place_main(self, gui: Any) -> None:
        gui.main_panel.dock_left()
        gui.main_panel.set_width(self.left_px)

    def place_toolbar(self, panel: Any) -> None:
        panel.dock_right()
        panel.set_width(self.right_px)

    @property
    def run_bar_px(self) -> int:
        """The run bar, floating at the foot of the 3D view: as wide as its buttons and status need,
        never wider than the view."""
        view = self.width - self.left_px - self.right_px - (self.plots_px if self.wide else 0)
        return max(300, min(460, view - 24))

    def place_run_bar(self, panel: Any) -> None:
        """Bottom left of the 3D view, clear of the docks (floating: its height follows its content,
        so nothing in it is ever scrolled away)."""
        panel.float(x=12, y=-12, width=self.run_bar_px)

    def place_command(self, panel: Any, toolbar: Any) -> None:
        """The command pendant, under the toolbar: beside the arm it moves."""
        panel.dock_below(toolbar)

    def place_init(self, panel: Any, toolbar: Any) -> None:
        """The initial-pose sliders between the toolbar and the command pendant: beside the arm."""
        panel.dock_below(toolbar)

    def place_docs(self, panel: Any, gui: Any) -> None:
        panel.dock_below(gui.main_panel)

    def place_plots(self, panel: Any, gui: Any) -> None:
        if self.wide:
            panel.dock_right()  # the innermost right column, beside the pendant
            panel.set_width(self.plots_px)
        else:
            panel.dock_below(gui.main_panel)
