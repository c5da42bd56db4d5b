"""The parameter tree and the variable tree (paper §3.2 Robot Model Interface, §5.2 figure 9, left).

Both trees share the left panel on two tabs. A click on a component shows its items as a table
below the tree (the paper's "table at the bottom left corner"), so a model with hundreds of
parameters costs only the widgets of one component at a time. Parameter descriptions, units and
bounds appear as hints; an edit goes to the server, which accepts it or refuses it with a reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from simecs.mesh.model import ModelDescription, Parameter, Variable

from . import tree as tr

CHANGED_MARK = " •"  # appended to the label of a value that differs from its default


def number_step(p: Parameter, value: float) -> float:
    """Increment (and so the typed precision) of a parameter's number field: ~4 significant digits
    of the value, and enough decimals to type the bounds exactly."""
    if p.integer:
        return 1.0
    digits = int(math.floor(-math.log10(abs(value)))) + 4 if value else 2
    for x in (value, p.min, p.max):
        while digits < 7 and x != round(x, digits):
            digits += 1
    return 10.0 ** (-min(max(digits, 0), 7))


class ComponentTree:
    """Folders and buttons for a component tree; `on_pick(component)` when one is clicked."""

    def __init__(self, gui: Any, roots: Sequence[tr.Component], on_pick: Callable[[tr.Component], None]):
        self.gui = gui
        self.on_pick = on_pick
        self.buttons: dict[str, Any] = {}
        for root in roots:
            self._add(root)

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
        button.on_click(lambda _e, c=comp: self.on_pick(c))
        self.buttons[comp.path] = button


class ParamPanel:
    """Edit parameter values in place, reset them, keep named sets.

    The panel never changes a value by itself: `on_set(name, value)` asks the tab, which asks the
    server; `show_values` then brings every visible field to the server's values.
    """

    def __init__(
        self,
        gui: Any,
        model: ModelDescription,
        values: dict[str, float],
        on_set: Callable[[str, float], None],
        on_reset: Callable[[list[str]], None],
        on_set_op: Callable[[str, str], None],
    ) -> None:
        self.gui = gui
        self.model = model
        self.values = dict(values)
        self.defaults = model.default_values()
        self.on_set = on_set
        self.on_reset = on_reset
        self.on_set_op = on_set_op  # (op, name): save / load / delete / refresh a parameter set
        self.fields: dict[str, Any] = {}
        self.shown: list[Parameter] = []
        self.roots = tr.build_tree(model.parameters)
        self.title: str = ""

        gui.add_markdown(
            "Pick a component; its parameters appear below. Hover a field for its description, "
            f"range and default; `{CHANGED_MARK.strip()}` marks a changed value."
        )
        with gui.add_folder("Components"):
            self.tree = ComponentTree(gui, self.roots, self.show_component)
        self.search = gui.add_text("Find parameter", "", hint="words of a parameter name or description")
        self.search.on_update(self._on_search)
        self.table = gui.add_folder("Values")
        with self.table:
            self.caption = gui.add_markdown("_No component chosen._")
        self.reset_shown = gui.add_button("Reset shown to defaults", hint="only the parameters listed above")
        self.reset_shown.on_click(lambda _e: self.on_reset([p.name for p in self.shown]))
        self.reset_all = gui.add_button("Reset all to defaults", color="orange", hint="every parameter")
        self.reset_all.on_click(lambda _e: self.on_reset([]))
        with gui.add_folder("Parameter sets", expand_by_default=False):
            self.set_name = gui.add_text("Set name", "", hint="letters, digits, '_', '-', '.'")
            save = gui.add_button("Save set", hint="save every current value under this name")
            save.on_click(lambda _e: self.on_set_op("save", self.set_name.value.strip()))
            self.sets = gui.add_dropdown("Saved sets", ("(none)",))
            load = gui.add_button("Load set")
            load.on_click(lambda _e: self.on_set_op("load", self.sets.value))
            delete = gui.add_button("Delete set", color="red")
            delete.on_click(lambda _e: self.on_set_op("delete", self.sets.value))
        first = next((c for root in self.roots for c in root.walk() if c.items), None)
        if first is not None:
            self.show_component(first)

    # -- the table -------------------------------------------------------------------------------
    def show_component(self, comp: tr.Component) -> None:
        self._show(comp.items, f"**{comp.path}**: {len(comp.items)} parameters")

    def _on_search(self, event: Any) -> None:
        if event.client is None:
            return
        found = tr.search(self.model.parameters, self.search.value)
        text = self.search.value.strip()
        self._show(found, f"**{len(found)}** parameters match “{text}”" if text else "_No search._")

    def _show(self, params: Sequence[Parameter], caption: str) -> None:
        for handle in self.fields.values():
            handle.remove()
        self.fields.clear()
        self.shown = list(params)
        self.caption.content = caption
        with self.table:
            for p in self.shown:
                value = self.values.get(p.name, p.value)
                handle = self.gui.add_number(
                    self._label(p, value),
                    initial_value=value,
                    step=number_step(p, value),
                    hint=tr.param_hint(p, self.defaults.get(p.name)),
                )
                handle.on_update(lambda e, p=p: self._edited(e, p))
                self.fields[p.name] = handle

    def _label(self, p: Parameter, value: float) -> str:
        changed = value != self.defaults.get(p.name, p.value)
        return tr.param_label(p) + (CHANGED_MARK if changed else "")

    def _edited(self, event: Any, p: Parameter) -> None:
        if event.client is None:  # our own assignment, not the user's
            return
        self.on_set(p.name, float(event.target.value))

    # -- values from the server --------------------------------------------------------------------
    def show_values(self, values: dict[str, float]) -> None:
        """Bring the visible fields to `values` (the server's truth, after a change or a refusal)."""
        self.values = dict(values)
        for name, handle in self.fields.items():
            p = self.model.parameter(name)
            value = self.values.get(name, p.value)
            if handle.value != value:
                handle.value = value
            label = self._label(p, value)
            if handle.label != label:
                handle.label = label

    def set_names(self, names: Sequence[str]) -> None:
        options = tuple(names) or ("(none)",)
        self.sets.options = options
        if self.sets.value not in options:
            self.sets.value = options[0]


class VariablePanel:
    """Choose the variables streamed live (paper §2.2 step 3) and open plots of them."""

    def __init__(
        self,
        gui: Any,
        model: ModelDescription,
        streamed: set[str],
        on_stream: Callable[[set[str]], None],
        on_plot: Callable[[str], None],
    ) -> None:
        self.gui = gui
        self.model = model
        self.streamed = set(streamed)
        self.on_stream = on_stream
        self.on_plot = on_plot
        self.rows: list[Any] = []
        self.checks: dict[str, Any] = {}
        self.roots = tr.build_tree(model.variables)
        gui.add_markdown(
            "Tick the variables to stream while a run goes on; **Plot** opens a live plot "
            "(several plots can be open at once)."
        )
        self.summary = gui.add_markdown("")
        with gui.add_folder("Components"):
            self.tree = ComponentTree(gui, self.roots, self.show_component)
        self.search = gui.add_text("Find variable", "", hint="words of a variable name or description")
        self.search.on_update(self._on_search)
        self.table = gui.add_folder("Variables")
        with self.table:
            self.caption = gui.add_markdown("_No component chosen._")
        none = gui.add_button("Stream only the plotted ones", hint="untick every variable not in a plot")
        none.on_click(lambda _e: self.on_stream(set()))
        first = next((c for root in self.roots for c in root.walk() if c.items), None)
        if first is not None:
            self.show_component(first)
        self._summary()

    def show_component(self, comp: tr.Component) -> None:
        self._show(comp.items, f"**{comp.path}**: {len(comp.items)} variables")

    def _on_search(self, event: Any) -> None:
        if event.client is None:
            return
        found = tr.search(self.model.variables, self.search.value)
        text = self.search.value.strip()
        self._show(found, f"**{len(found)}** variables match “{text}”" if text else "_No search._")

    def _show(self, variables: Sequence[Variable], caption: str) -> None:
        for handle in self.rows:
            handle.remove()
        self.rows.clear()
        self.checks.clear()
        self.caption.content = caption
        with self.table:
            for v in variables:
                check = self.gui.add_checkbox(tr.var_label(v), v.name in self.streamed, hint=tr.var_hint(v))
                check.on_update(lambda e, v=v: self._ticked(e, v))
                plot = self.gui.add_button(
                    f"Plot {tr.short_name(v)}", icon=None, hint=f"open a plot of {v.name}"
                )
                plot.on_click(lambda _e, v=v: self.on_plot(v.name))
                self.checks[v.name] = check
                self.rows += [check, plot]

    def _ticked(self, event: Any, v: Variable) -> None:
        if event.client is None:
            return
        wanted = set(self.streamed)
        if event.target.value:
            wanted.add(v.name)
        else:
            wanted.discard(v.name)
        self.on_stream(wanted)

    def show_streamed(self, streamed: set[str]) -> None:
        self.streamed = set(streamed)
        for name, check in self.checks.items():
            want = name in self.streamed
            if check.value != want:
                check.value = want
        self._summary()

    def _summary(self) -> None:
        n = len(self.streamed)
        names = ", ".join(sorted(self.streamed)[:6]) + (" …" if n > 6 else "")
        self.summary.content = f"Streaming **{n}** of {len(self.model.variables)} variables" + (
            f": {names}" if n else ""
        )
