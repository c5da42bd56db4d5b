"""Where each region of a tab goes (issue: a layout that never hides the arm, nor the run's controls).

The model's trees (and the toolbar above them) dock on the left edge; the command pendant on the
right edge (the initial pose one of its tabs), with the documentation docked above it while open; the
run bar floats at the foot of the 3D view, sized to its content, so its buttons are never scrolled
away. The plots get a column of their own between the arm and the pendant on a wide screen (from
1800 px), share the pendant's column from 1400 px, and are a tab beside the trees on a narrower
screen: no stack of small docks that each scroll. The user may drag, resize
and minimise any of them (viser's dock); these are the places they start in. Modals (the models list,
the run settings) are the only things drawn over the view, and only while the user answers them.

The widths follow the browser's viewport, read when the tab connects (`browser.recall`), so the 3D
view keeps at least `MIN_VIEW_PX` at 1024×768, and a plot real room on a wide screen.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

WIDE_PX = 1800  # from this viewport width on, the plots get a column of their own
ROOMY_PX = 1400  # from this width on, the pendant's column is wide enough to share with the plots
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
    def plots_where(self) -> str:
        """Where the plots go: `column` (their own, on a wide screen), `above_pendant` (sharing the
        pendant's column, from ROOMY_PX), `tab` (beside the trees, on a narrow screen)."""
        if self.wide:
            return "column"
        return "above_pendant" if self.width >= ROOMY_PX else "tab"

    @property
    def left_px(self) -> int:
        """The trees (parameters, variables, results), the toolbar above them, and on a narrow screen
        the plots' tab."""
        if self.width >= ROOMY_PX:
            return 360
        return max(260, min(300, (self.width - MIN_VIEW_PX) // 2))

    @property
    def right_px(self) -> int:
        """The command pendant (and above it, while open, the documentation; from ROOMY_PX to a wide
        screen, the plots)."""
        if self.wide:
            return 420
        if self.width >= ROOMY_PX:
            return 480  # room for a plot above the pendant
        return max(300, min(360, self.width - MIN_VIEW_PX - self.left_px))

    @property
    def plots_px(self) -> int:
        """The plot column on a wide screen: more than half of what the trees and the pendant leave."""
        free = self.width - self.left_px - self.right_px
        return max(420, min(760, int(0.55 * free)))

    @property
    def run_bar_px(self) -> int:
        """The run bar, floating at the foot of the 3D view: as wide as its buttons and status need,
        never wider than the view."""
        view = self.width - self.left_px - self.right_px - (self.plots_px if self.wide else 0)
        return max(300, min(540, view - 24))

    # -- placing the regions --------------------------------------------------------------------
    def place_main(self, gui: Any) -> None:
        gui.main_panel.dock_left()
        gui.main_panel.set_width(self.left_px)

    def place_run_bar(self, panel: Any) -> None:
        """Bottom left of the 3D view, clear of the docks (floating: its height follows its content,
        so nothing in it is ever scrolled away)."""
        panel.float(x=12, y=-12, width=self.run_bar_px)

    def place_command(self, panel: Any) -> None:
        """The command pendant on the right edge, beside the arm it moves."""
        panel.dock_right()
        panel.set_width(self.right_px)

    def place_beside_pendant(self, panel: Any, pendant: Any) -> None:
        """The initial-pose sliders or the documentation, above the pendant while open: the trees
        keep their column."""
        panel.dock_above(pendant)

    def place_plots(self, panel: Any) -> None:
        """The plots' own column on a wide screen, between the arm and the pendant."""
        panel.dock_right()  # the innermost right column: placed after the pendant's
        panel.set_width(self.plots_px)
