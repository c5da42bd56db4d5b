"""The direct-input pendant (paper §2.1-2.2, the lowest command level): a signal editor per joint, a
table of points or a generator with its numbers, and a preview plot of what the run will follow as
the server expanded it. The signals themselves are `direct.DirectInputEditor`, owned by the session
controller.

Typed numbers are drafts until **Apply signal** (viser's fields report every keystroke, as in the
parameter panel): applying one joint's signal makes the whole direct input the session's command,
and the server answers with its plan (the preview) or a refusal naming the field, shown here.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

import numpy as np
from simecs.mesh.protocol import messages as m

from .direct import GENERATORS, MODES, NO_SIGNAL, SIGNAL_TYPES, TABLE, DirectInputEditor, signal_fields
from .markup import escape_text
from .params import APPLY_GRACE_S
from .path import LOCKED, PathError, refused_text
from .plots import COLORS, scales

SIGNAL_FIELD = re.compile(r"^command\.signals\.([A-Za-z0-9_.-]+?)(?:\.(.+))?$")
PREVIEW_TITLE = "Preview: the signals as the server expanded them"


def refusal_text(field: str, reason: str) -> str:
    """The server's refusal of a direct input, naming the joint and the number it blames."""
    found = SIGNAL_FIELD.match(field or "")
    if found is None:
        return refused_text("the signals", reason)
    joint, sub = found.group(1), found.group(2)
    where = f"{joint}'s {sub}" if sub else joint
    return refused_text(where, reason)


def plan_text(plan: m.CommandPlan | None, stop_time: float) -> str:
    if plan is None or plan.signals is None:
        return "_Not planned yet: **Apply signal** sends the signals to the server._"
    return (
        f"The signals run for the whole run: **{stop_time:g} s** (stop time, in Settings); "
        f"values in {plan.signals.unit}."
    )


class DirectInputPanel:
    """Draws a `DirectInputEditor`; calls `on_changed()` after every applied edit."""

    def __init__(
        self,
        gui: Any,
        editor: DirectInputEditor,
        on_changed: Callable[[], None],
        on_error: Callable[[str], None],
        after: Callable[[float, Callable[[], None]], None] = lambda _s, job: job(),
    ) -> None:
        """`after(s, job)`: `job` later on the tab's loop (at once by default: tests without one)."""
        self.gui = gui
        self.editor = editor
        self.after = after
        self.on_changed = on_changed
        self.on_error = on_error
        self.locked = False
        self.table = gui.add_markdown("")
        self.planned = gui.add_markdown(plan_text(None, 0.0))
        self.mode = gui.add_dropdown(
            "Mode", tuple(MODES), initial_value=editor.mode_label, hint="what every joint's signal drives"
        )
        self.mode.on_update(self._mode_picked)
        first = editor.joints[0]
        self.joint = gui.add_dropdown("Joint", tuple(editor.joints), initial_value=first)
        self.joint.on_update(self._joint_picked)
        self.kind = gui.add_dropdown(
            "Signal",
            (NO_SIGNAL, *SIGNAL_TYPES),
            hint="a table of points or a generator; none: the joint holds its initial position",
        )
        self.kind.on_update(self._kind_picked)
        self.numbers: dict[str, dict[str, Any]] = {}
        for kind in GENERATORS:
            self.numbers[kind] = {
                f.name: gui.add_number(
                    f.label.format(u=editor.unit), f.first, step=1e-4, hint=f.hint, visible=False
                )
                for f in signal_fields(kind)
            }
        self.points = gui.add_text(
            "Points (t, value)",
            "",
            multiline=True,
            visible=False,
            hint="one point per line: time in s, then the value; times must not decrease, "
            "two equal times make a jump",
        )
        self.refusal = gui.add_markdown("")  # under the numbers just typed, above Apply
        self.apply = gui.add_button(
            "Apply signal", color="green", hint="send this joint's signal with the others to the server"
        )
        self.apply.on_click(self._applied)
        self.remove = gui.add_button("Remove signal", color="gray", hint="the joint holds its position")
        self.remove.on_click(self._removed)
        self.preview = gui.add_uplot(
            (np.zeros(2), np.zeros(2)),
            ({"label": "t [s]"}, {"label": "—"}),
            scales=scales((-1.0, 1.0)),
            legend={"show": True},
            title=PREVIEW_TITLE,
            height=200,
        )
        self.show_joint(first)

    # -- user events -------------------------------------------------------------------------------
    def _mode_picked(self, event: Any) -> None:
        if event.client is None:
            return
        if self.locked:
            self.on_error(LOCKED)
            self.mode.value = self.editor.mode_label
            return
        self.editor.set_mode(event.target.value)
        self._label_units()
        self.refresh()
        if not self.editor.empty:
            self.on_changed()

    def _joint_picked(self, event: Any) -> None:
        if event.client is not None:
            self.show_joint(event.target.value)

    def _kind_picked(self, event: Any) -> None:
        if event.client is not None:
            self._show_fields(event.target.value)

    def _applied(self, _event: Any) -> None:
        if self.locked:
            self.on_error(LOCKED)
            return
        # the last keystrokes may still be on their way
        self.after(APPLY_GRACE_S, lambda: self._apply(self.joint.value, self.kind.value))

    def _apply(self, joint: str, kind: str) -> None:
        try:
            if kind == NO_SIGNAL:
                if joint in self.editor.signals:
                    self.editor.remove(joint)
            else:
                numbers = {k: float(h.value) for k, h in self.numbers.get(kind, {}).items()}
                self.editor.set_signal(joint, kind, numbers, self.points.value)
        except (PathError, TypeError, ValueError) as exc:
            self.on_error(str(exc))
            return
        self.refresh()
        self.on_changed()

    def _removed(self, _event: Any) -> None:
        if self.locked:
            self.on_error(LOCKED)
            return
        try:
            self.editor.remove(self.joint.value)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self.show_joint(self.joint.value)
        if not self.editor.empty:
            self.on_changed()
        else:
            self.show_plan(None, 0.0, False)

    # -- drawing -----------------------------------------------------------------------------------
    def show_joint(self, joint: str) -> None:
        """The fields of `joint`'s signal (its own numbers, the first values for the others)."""
        if self.joint.value != joint:
            self.joint.value = joint
        kind, numbers, table = self.editor.shown(joint)
        for k, fields in self.numbers.items():
            for name, handle in fields.items():
                if handle.value != numbers[k][name]:
                    handle.value = numbers[k][name]
        self.points.value = table
        self._show_fields(kind)
        self.refresh()

    def _show_fields(self, kind: str) -> None:
        if self.kind.value != kind:
            self.kind.value = kind
        for k, fields in self.numbers.items():
            for handle in fields.values():
                handle.visible = k == kind
        self.points.visible = kind == TABLE

    def _label_units(self) -> None:
        unit = self.editor.unit
        for kind, fields in self.numbers.items():
            for f in signal_fields(kind):
                fields[f.name].label = f.label.format(u=unit)

    def refresh(self) -> None:
        """The table and the mode as the editor holds them."""
        ed = self.editor
        self.table.content = ed.table_markdown(self.joint.value)
        if self.mode.value != ed.mode_label:
            self.mode.value = ed.mode_label
            self._label_units()

    def show_plan(self, plan: m.CommandPlan | None, stop_time: float, current: bool = True) -> None:
        """The server's expansion of the signals as the preview (`current`: the direct input is the
        session's command)."""
        self.refusal.content = ""
        if not current and not self.editor.empty:
            self.planned.content = "_Not the session's command: apply a signal to make it so._"
            self._draw(None)
            return
        planned = plan_text(plan if current else None, stop_time)
        signals = plan.signals if current and plan is not None else None
        jumps = self.editor.jumps(signals)
        self.planned.content = planned + "".join(f"\n\n**⚠ {escape_text(j)}**" for j in jumps)
        self._draw(signals)

    def show_refusal(self, field: str, reason: str) -> None:
        """The server refused the signals: its reason beside them, no preview."""
        self.refusal.content = refusal_text(field, reason)
        self.planned.content = "_Not planned: the session keeps the last command the server took._"
        self._draw(None)

    def _draw(self, signals: m.SignalPreview | None) -> None:
        if signals is None or len(signals.t) < 2:  # empty axes: uPlot fits no range over NaN alone
            self.preview.series = ({"label": "t [s]"}, {"label": "—"})
            self.preview.scales = scales((-1.0, 1.0))
            self.preview.data = (np.array([0.0, 1.0]), np.full(2, np.nan))
            return
        self.preview.scales = scales(None)
        names = list(signals.values)
        self.preview.series = (
            {"label": "t [s]"},
            *[
                {"label": f"{j} [{signals.unit}]", "stroke": COLORS[k % len(COLORS)], "width": 1.5}
                for k, j in enumerate(names)
            ],
        )
        self.preview.data = (
            np.asarray(signals.t, dtype=float),
            *[np.asarray(signals.values[j], dtype=float) for j in names],
        )

    def set_disabled(self, disabled: bool) -> None:
        """While a run goes on the command cannot change (the server refuses it anyway)."""
        self.locked = disabled
        for handle in (self.mode, self.apply, self.remove):
            handle.disabled = disabled
