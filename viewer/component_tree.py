"""The "Components" folder of the parameter and variable panels (paper §5.2 figure 9): the model's
component tree as folders and buttons, folded under the component it shows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from . import tree as tr


class ComponentTree:
    """The "Components" folder: folders and buttons for a component tree; `on_pick(component)` when
    one is clicked. A pick folds the tree up under the chosen component's name, so the table of its
    items, right below, comes into view (an open tree is taller than the panel)."""

    def __init__(self, gui: Any, roots: Sequence[tr.Component], on_pick: Callable[[tr.Component], None]):
        self.gui = gui
        self.roots = list(roots)
        self.on_pick = on_pick
        self.buttons: dict[str, Any] = {}
        first = next((c for root in self.roots for c in root.walk() if c.items), None)
        self.first = first  # shown at the start, the tree folded under its name
        self.picked = first.path if first is not None else ""  # the path of the component shown
        # A frame without a header holds the folder: a rebuilt folder (a pick, from a click callback
        # outside any `with` block) goes back in the same place.
        self.frame = gui.add_folder(None)
        self.folder: Any = None
        self._build(expanded=first is None)

    def _build(self, expanded: bool) -> None:
        if self.folder is not None:
            self.folder.remove()
        self.buttons.clear()
        label = f"Components · {self.picked}" if self.picked else "Components"
        with self.frame:
            self.folder = self.gui.add_folder(label, expand_by_default=expanded)
        with self.folder:
            for root in self.roots:
                self._add(root)

    def pick(self, comp: tr.Component) -> None:
        self.picked = comp.path
        self.on_pick(comp)
        self._build(expanded=False)

    def find(self, path: str) -> tr.Component | None:
        return next((c for root in self.roots for c in root.walk() if c.path == path and c.items), None)

    def _add(self, comp: tr.Component) -> None:
        if not comp.children:
            self._button(comp, f"{comp.label} ({comp.count()})")
            return
        with self.gui.add_folder(f"{comp.label} ({comp.count()})", expand_by_default=False):
            if comp.items:
                self._button(comp, f"{comp.label} ({len(comp.items)} own)")
            for child in comp.children:
                self._add(child)

    def _button(self, comp: tr.Component, label: str) -> None:
        button = self.gui.add_button(label, hint=comp.path)
        button.on_click(lambda _e, c=comp: self.pick(c))
        self.buttons[comp.path] = button
