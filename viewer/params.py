"""The parameter tree and the variable tree (paper §3.2 Robot Model Interface, §5.2 figure 9, left).

Both trees share the left panel on two tabs. A click on a component shows its items as a table
below the tree (the paper's "table at the bottom left corner"), so a model with hundreds of
parameters costs only the widgets of one component at a time. Parameter descriptions, units and
bounds appear as hints; an applied edit goes to the server, which accepts it or refuses it with a
reason.

A typed value is a draft until the user applies it (**Apply edits**): viser's number fields report
every keystroke, and sending those would store half-typed values ("0" on the way to "0.00008") and
overwrite the field under the user's fingers with the server's answer. Drafts are checked here as the
user types (the protocol's own bounds check), kept when the server's values arrive, and sent all at
once; a refusal is shown beside the fields with the server's reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.protocol.model import ModelDescription, Parameter, Variable, check_values

from . import tree as tr
from .component_tree import ComponentTree
from .markup import escape_text

CHANGED_MARK = " •"  # appended to the label of a value that differs from its default
DRAFT_MARK = " ✎"  # appended to the label of a typed value not applied yet
#: Apply waits this long for the last keystrokes still on their way from the browser (viser sends a
#: field's value as it changes, and a click may overtake the last of them).
APPLY_GRACE_S = 0.3


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


def is_switch(p: Parameter) -> bool:
    """A 0/1 parameter (drives.enabled, motor.ideal): shown as a check box, not a number."""
    return p.integer and p.min == 0.0 and p.max == 1.0


class ParamPanel:
    """Edit parameter values in place, reset them, keep named sets.

    The panel never changes a value by itself: `on_apply(changes)` asks the tab, which asks the
    server; `show_values` then brings every visible field without a draft to the server's values.
    """

    def __init__(
        self,
        gui: Any,
        model: ModelDescription,
        values: dict[str, float],
        on_apply: Callable[[dict[str, float]], None],
        on_reset: Callable[[list[str]], None],
        on_set_op: Callable[[str, str], None],
        on_undo: Callable[[], None] = lambda: None,
        after: Callable[[float, Callable[[], None]], None] = lambda _s, job: job(),
    ) -> None:
        self.gui = gui
        self.after = after  # runs a job later on the tab's loop (the page's `loop.after`)
        self.model = model
        self.values = dict(values)
        self.defaults = model.default_values()
        self.on_apply = on_apply
        self.drafts: dict[str, float] = {}  # typed, not applied yet
        self.refusal = ""  # the server's reason for the last refused apply
        self.confirm: tuple[Any, Any] | None = None  # the last "Reset every parameter?": its yes, no
        self.on_reset = on_reset
        self.on_set_op = on_set_op  # (op, name): save / load / delete / refresh a parameter set
        self.fields: dict[str, Any] = {}
        self.shown: list[Parameter] = []
        self.whole_names = False  # the fields shown are labelled with their component (a search)
        self.roots = tr.build_tree(model.parameters)
        self.title: str = ""

        gui.add_markdown(
            "Open **Components** and pick one; its parameters appear below it. Hover a field for its "
            f"description, range and default; `{CHANGED_MARK.strip()}` marks a changed value."
        )
        self.tree = ComponentTree(gui, self.roots, self.show_component)
        self.search = gui.add_text("Find parameter", "", hint="words of a parameter name or description")
        self.search.on_update(self._on_search)
        self.table = gui.add_folder("Values")
        with self.table:
            self.caption = gui.add_markdown("_No component chosen._")
        self.notice = gui.add_markdown("")
        self.apply = gui.add_button(
            "Apply edits", color="green", disabled=True, hint="send the typed values (✎) to the server"
        )
        self.apply.on_click(lambda _e: self._apply())
        self.discard = gui.add_button("Discard edits", disabled=True, hint="back to the stored values")
        self.discard.on_click(lambda _e: self._discard())
        self.undo = gui.add_button("Undo last change", disabled=True, hint="no change of values yet")
        self.undo.on_click(lambda _e: on_undo())
        self.reset_shown = gui.add_button("Reset shown to defaults", hint="only the parameters listed above")
        self.reset_shown.on_click(lambda _e: self.on_reset([p.name for p in self.shown]))
        self.reset_all = gui.add_button("Reset all to defaults", color="orange", hint="every parameter")
        self.reset_all.on_click(lambda _e: self.confirm_reset_all())
        with gui.add_folder("Parameter sets", expand_by_default=False):
            self.set_name = gui.add_text("Set name", "", hint="letters, digits, '_', '-', '.'")
            save = gui.add_button("Save set", hint="save every current value under this name")
            save.on_click(lambda _e: self.on_set_op("save", self.set_name.value.strip()))
            self.sets = gui.add_dropdown("Saved sets", ("(none)",))
            load = gui.add_button("Load set")
            load.on_click(lambda _e: self.on_set_op("load", self.sets.value))
            delete = gui.add_button("Delete set", color="red")
            delete.on_click(lambda _e: self.on_set_op("delete", self.sets.value))
        if self.tree.first is not None:
            self.show_component(self.tree.first)

    # -- the table -------------------------------------------------------------------------------
    def show_component(self, comp: tr.Component) -> None:
        self._show(comp.items, f"**{comp.path}**: {len(comp.items)} parameters")

    def show_path(self, path: str) -> None:
        """Show the component at `path` (a reloaded tab's); an unknown path changes nothing."""
        comp = self.tree.find(path)
        if comp is not None:
            self.tree.pick(comp)

    def _on_search(self, event: Any) -> None:
        if event.client is None:
            return
        found = tr.search(self.model.parameters, self.search.value)
        text = self.search.value.strip()
        caption = f"**{len(found)}** parameters match “{escape_text(text)}”" if text else "_No search._"
        self._show(found, caption, whole_names=True)

    def _show(self, params: Sequence[Parameter], caption: str, whole_names: bool = False) -> None:
        """The table: `params`' fields under `caption`; `whole_names`: labelled with their component
        (search results come from many components: seven `kp_pos` must be told apart). The same
        fields asked again are kept, not rebuilt: one the user is about to click stays the one clicked."""
        self.caption.content = caption
        if [q.name for q in params] == [q.name for q in self.shown] and whole_names == self.whole_names:
            return
        for handle in self.fields.values():
            handle.remove()
        self.fields.clear()
        self.shown = list(params)
        self.whole_names = whole_names
        with self.table:
            for p in self.shown:
                value = self.drafts.get(p.name, self.values.get(p.name, p.value))
                hint = tr.param_hint(p, self.defaults.get(p.name))
                if is_switch(p):
                    handle = self.gui.add_checkbox(self._label(p, value), bool(value), hint=hint)
                else:
                    handle = self.gui.add_number(
                        self._label(p, value), initial_value=value, step=number_step(p, value), hint=hint
                    )
                handle.on_update(lambda e, p=p: self._edited(e, p))
                self.fields[p.name] = handle

    def _label(self, p: Parameter, value: float) -> str:
        label = tr.param_label(p, self.whole_names)
        if p.name in self.drafts:
            return label + DRAFT_MARK
        changed = value != self.defaults.get(p.name, p.value)
        return label + (CHANGED_MARK if changed else "")

    def _edited(self, event: Any, p: Parameter) -> None:
        if event.client is None:  # our own assignment, not the user's
            return
        value = float(event.target.value)
        if value == self.values.get(p.name, p.value):
            self.drafts.pop(p.name, None)
        else:
            self.drafts[p.name] = value
        self.refusal = ""
        self._show_edits()

    def problems(self) -> list[str]:
        """What is wrong with the drafts, checked as the server will check it (bounds, whole numbers)."""
        out = []
        for name, value in self.drafts.items():
            try:
                check_values(self.model, {name: value}, self.values)
            except DecodeError as exc:
                out.append(f"**{name}**: {exc.problem}")
        return out

    def _show_edits(self) -> None:
        """Labels, the notice beside the fields and the buttons, after the drafts changed."""
        for name, handle in self.fields.items():
            p = self.model.parameter(name)
            label = self._label(p, self.drafts.get(name, self.values.get(name, p.value)))
            if handle.label != label:
                handle.label = label
        problems = self.problems()
        if problems:
            text = "⚠ Not applicable yet: " + "; ".join(problems)
        elif self.refusal:
            text = f"✗ The server refused: {escape_text(self.refusal)}"
        elif self.drafts:
            text = f"{len(self.drafts)} typed value(s) ✎ not sent yet: **Apply edits** sends them."
        else:
            text = ""
        if self.notice.content != text:
            self.notice.content = text
        self.apply.disabled = not self.drafts or bool(problems)
        self.discard.disabled = not self.drafts

    def _apply(self) -> None:
        self.after(APPLY_GRACE_S, self._apply_typed)  # the last keystrokes may still be on their way

    def _apply_typed(self) -> None:
        # viser sets a field's value as its message arrives, before the update callbacks run in its
        # thread pool: the fields themselves say what was typed last
        for name, handle in self.fields.items():
            value = float(handle.value)
            if value != self.values.get(name, self.model.parameter(name).value):
                self.drafts[name] = value
            else:
                self.drafts.pop(name, None)
        if not self.drafts or self.problems():
            self._show_edits()
            return
        self.on_apply(dict(self.drafts))

    def show_undo(self, what: str) -> None:
        """What Undo would put back ('' : nothing to undo, the button is off)."""
        self.undo.disabled = not what
        self.undo.hint = f"puts {what}" if what else "no change of values yet"

    def confirm_reset_all(self) -> None:
        """Every parameter back to its default, once the user says so: it cannot be undone here
        (a saved parameter set can bring the values back)."""
        changed = sum(1 for k, v in self.values.items() if v != self.defaults.get(k, v))
        modal = self.gui.add_modal("Reset every parameter?")
        with modal:
            self.gui.add_markdown(
                f"**{changed}** parameters differ from their defaults; all go back to the defaults. "
                "Save a parameter set first to keep the current values."
            )
            yes = self.gui.add_button("Reset all", color="orange")
            no = self.gui.add_button("Keep the values", color="gray")

        def answer(reset: bool) -> None:
            modal.close()
            if reset:
                self.on_reset([])

        yes.on_click(lambda _e: answer(True))
        no.on_click(lambda _e: answer(False))
        self.confirm = (yes, no)

    def _discard(self) -> None:
        self.drafts.clear()
        self.refusal = ""
        self.show_values(self.values)

    def refused(self, field: str, reason: str) -> None:
        """The server refused the applied drafts: they stay, with its reason beside them."""
        self.refusal = reason
        self._show_edits()

    # -- values from the server --------------------------------------------------------------------
    def show_values(self, values: dict[str, float]) -> None:
        """Bring the visible fields to `values` (the server's truth, after a change or a refusal); a
        draft the server now holds is done, the others stay as typed."""
        self.values = dict(values)
        for name in [n for n, v in self.drafts.items() if self.values.get(n) == v]:
            del self.drafts[name]
        if not self.drafts:
            self.refusal = ""
        for name, handle in self.fields.items():
            if name in self.drafts:
                continue
            p = self.model.parameter(name)
            value = self.values.get(name, p.value)
            if float(handle.value) != value:
                handle.value = bool(value) if is_switch(p) else value
        self._show_edits()

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
        on_plot: Callable[[str], object],
    ) -> None:
        self.gui = gui
        self.model = model
        self.streamed = set(streamed)
        self.on_stream = on_stream
        self.on_plot = on_plot
        self.rows: list[Any] = []
        self.checks: dict[str, Any] = {}
        self.shown: tuple[list[str], bool] = ([], False)  # the rows' variables, and whole_names
        self.roots = tr.build_tree(model.variables)
        gui.add_markdown(
            "Tick the variables to stream while a run goes on; **Plot** opens a live plot "
            "(several plots can be open at once)."
        )
        self.summary = gui.add_markdown("")
        self.tree = ComponentTree(gui, self.roots, self.show_component)
        self.search = gui.add_text("Find variable", "", hint="words of a variable name or description")
        self.search.on_update(self._on_search)
        self.table = gui.add_folder("Variables")
        with self.table:
            self.caption = gui.add_markdown("_No component chosen._")
        none = gui.add_button("Stream only the plotted ones", hint="untick every variable not in a plot")
        none.on_click(lambda _e: self.on_stream(set()))
        if self.tree.first is not None:
            self.show_component(self.tree.first)
        self._summary()

    def show_component(self, comp: tr.Component) -> None:
        self._show(comp.items, f"**{comp.path}**: {len(comp.items)} variables")

    def _on_search(self, event: Any) -> None:
        if event.client is None:
            return
        found = tr.search(self.model.variables, self.search.value)
        text = self.search.value.strip()
        caption = f"**{len(found)}** variables match “{escape_text(text)}”" if text else "_No search._"
        self._show(found, caption, whole_names=True)

    def _show(self, variables: Sequence[Variable], caption: str, whole_names: bool = False) -> None:
        """The rows of `variables`; the same rows asked again (the component shown first, picked in
        the tree) are kept, not rebuilt: a Plot button the user is about to click stays the one clicked."""
        self.caption.content = caption
        shown = ([v.name for v in variables], whole_names)
        if shown == self.shown:
            return
        self.shown = shown
        for handle in self.rows:
            handle.remove()
        self.rows.clear()
        self.checks.clear()
        with self.table:
            for v in variables:
                label = tr.var_label(v, whole_names)
                check = self.gui.add_checkbox(label, v.name in self.streamed, hint=tr.var_hint(v))
                check.on_update(lambda e, v=v: self._ticked(e, v))
                name = v.name if whole_names else tr.short_name(v)
                plot = self.gui.add_button(f"Plot {name}", icon=None, hint=f"open a plot of {v.name}")
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
