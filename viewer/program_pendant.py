"""The task pendant (paper §2.1-2.2, the high level; §3 the Action Level Simulator's library): tasks
of actions composed from primitives and from the user's saved programs, reordered, saved, sent as a
task (or a mission when there are several), and the step that runs marked while it runs. The
composition itself is `program.ProgramEditor`, owned by the session controller.

Typed arguments are drafts until **Add** or **Update** (viser's text fields report every keystroke),
in the pendants' units (degrees, mm) under the user's names for them. Every composition edit makes it
the session's command; the server answers with its plan (each action's start and end, the arm drawn
where a picked action ends) or a refusal naming the action.

It runs on the tab's loop; the library's requests go to a worker (`submit`), which hands what it got
back to the loop (`ui`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.robot_commands import ACTION_ARGS, ACTION_DOC

from .cartesian import Pose
from .params import APPLY_GRACE_S
from .path import LOCKED, PathError, plan_text, refused_text
from .program import PRIMITIVES, ProgramEditor, arg_hint, arg_label, arg_name, arg_text

ACTION_FIELD = re.compile(r"^command\.(?:tasks\[(\d+)\]\.)?actions\[(\d+)\](?:\.(.+))?$")
TASK_BUTTONS = ("New", "Rename", "Remove", "Up", "Down")
ACTION_BUTTONS = ("Teach", "Add", "Update", "Remove", "Up", "Down")
SAVE_KINDS = ("action", "task", "mission")
NO_SAVED = "(none saved)"
#: Where the run is in its command: these phases have a step that runs.
RUNNING = ("running", "paused")


def refusal_text(editor: ProgramEditor, field: str, reason: str) -> str:
    """The server's refusal, naming the task and the action it blames."""
    found = ACTION_FIELD.match(field or "")
    if found is None:
        return refused_text(f"the {editor.kind}", reason)
    task = int(found.group(1) or 0)
    name = editor.tasks[task].name if task < len(editor.tasks) else f"task {task + 1}"
    arg = f" ({arg_name(found.group(3).removeprefix('args.'))})" if found.group(3) else ""
    return refused_text(f"{name}, action {int(found.group(2)) + 1}{arg}", reason)


def saved_label(entry: m.ProgramEntry) -> str:
    return f"{entry.kind} · {entry.name}"


class ProgramPanel:
    """Draws a `ProgramEditor`; `on_changed()` after every edit of the composition, `on_preview(q)`
    to show where a picked action leaves the arm; `request(cmd)` asks the server (the library)."""

    def __init__(
        self,
        gui: Any,
        editor: ProgramEditor,
        current_q: Callable[[], list[float]],
        tool_pose: Callable[[list[float]], Pose],
        on_changed: Callable[[], None],
        on_preview: Callable[[list[float]], None],
        request: Callable[[Any], Any],
        submit: Callable[[str, Callable[[], None]], None],
        on_error: Callable[[str], None],
        ui: Callable[[Callable[[], Any]], Any] = lambda job: job(),
        after: Callable[[float, Callable[[], None]], None] = lambda _s, job: job(),
    ) -> None:
        """`submit(what, job)` runs a request on a worker, `ui(job)` runs `job` back on the tab's
        loop and `after(s, job)` later on it (the defaults run at once: for tests without a loop)."""
        self.editor = editor
        self.ui = ui
        self.after = after
        self.current_q = current_q
        self.tool_pose = tool_pose
        self.on_changed = on_changed
        self.on_preview = on_preview
        self.request = request
        self.submit = submit
        self.on_error = on_error
        self.locked = False
        self.times: dict[str, tuple[float, float]] = {}
        self.ends: dict[str, list[float]] = {}  # where each step leaves the arm (the plan's q_end)
        self.running = ""
        self.saved: dict[str, m.ProgramEntry] = {}
        self.table = gui.add_markdown("")
        self.planned = gui.add_markdown(plan_text(None, 0.0, "task"))
        self.task = gui.add_dropdown("Task", ("1",), hint="the task the actions below are added to")
        self.task.on_update(self._task_picked)
        self.task_name = gui.add_text(
            "Task name",
            "task2",
            hint="New and Rename take it: 1-64 letters, digits, '_', '-', '.' (no spaces)",
        )
        self.task_buttons = gui.add_button_group("Tasks", TASK_BUTTONS)
        self.task_buttons.on_click(self._task_clicked)
        # above the action's fields: a refusal that appears pushes the buttons down, not itself out
        self.refusal = gui.add_markdown("")
        self.action = gui.add_dropdown("Action", ("-",), hint="the action Update, Remove, Up and Down act on")
        self.action.on_update(self._action_picked)
        self.primitive = gui.add_dropdown("Primitive", PRIMITIVES, hint=ACTION_DOC[PRIMITIVES[0]])
        self.primitive.on_update(self._primitive_picked)
        n = len(editor.joints)
        self.args: dict[str, dict[str, Any]] = {
            p: {
                name: gui.add_text(arg_label(name, spec), "", hint=arg_hint(name, spec, n), visible=False)
                for name, spec in specs.items()
            }
            for p, specs in ACTION_ARGS.items()
        }
        self.label = gui.add_text(
            "Label", "", hint="the action's name in the table (may stay empty; no spaces)"
        )
        self.action_buttons = gui.add_button_group(
            "Actions", ACTION_BUTTONS, hint="Teach: the arm's pose into the arguments (moves)"
        )
        self.action_buttons.on_click(self._action_clicked)
        with gui.add_folder("Library", expand_by_default=False):
            self.library = gui.add_dropdown("Saved", (NO_SAVED,), hint="your saved programs for this model")
            self.save_as = gui.add_text("Save as", "", hint="1-64 letters, digits, '_', '-', '.' (no spaces)")
            self.save = gui.add_button_group(
                "Save", SAVE_KINDS, hint="the picked action, the task, or all tasks"
            )
            self.save.on_click(self._save_clicked)
            self.use = gui.add_button_group(
                "Saved program", ("Insert", "Delete"), hint="Insert: after the picked one"
            )
            self.use.on_click(self._use_clicked)
        self._show_primitive(PRIMITIVES[0])
        self.refresh()
        self.submit("Library", self.refresh_library)

    # -- tasks and actions -------------------------------------------------------------------------
    def _task_picked(self, event: Any) -> None:
        if event.client is None:
            return
        try:
            self.editor.select(int(event.target.value.split(".")[0]) - 1)
        except (ValueError, PathError):
            return
        self.editor.action = len(self.editor.current.actions) - 1
        self.refresh()

    def _task_clicked(self, event: Any) -> None:
        button = event.target.value
        if self.locked:
            self.on_error(LOCKED)
            return
        # the name's last keystrokes may still be on their way
        self.after(APPLY_GRACE_S, lambda: self._task_button(button))

    def _task_button(self, button: str) -> None:
        ed = self.editor
        try:
            if button == "New":
                ed.add_task(self.task_name.value)
            elif button == "Rename":
                ed.rename_task(self.task_name.value)
            elif button == "Remove":
                ed.remove_task()
            else:
                ed.move_task(-1 if button == "Up" else 1)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self.refresh()
        self.changed()

    def _action_picked(self, event: Any) -> None:
        if event.client is None:
            return
        try:
            self.editor.select(self.editor.task, int(event.target.value) - 1)
        except (ValueError, PathError):
            return
        self.refresh()
        self._show_action()

    def _primitive_picked(self, event: Any) -> None:
        if event.client is not None:
            self._show_primitive(event.target.value)

    def _action_clicked(self, event: Any) -> None:
        button = event.target.value
        if self.locked and button != "Teach":
            self.on_error(LOCKED)
            return
        if button in ("Add", "Update"):
            primitive = self.primitive.value  # picked before the click; typed text may lag it
            # the last keystrokes may still be on their way
            self.after(APPLY_GRACE_S, lambda: self._add(button, primitive))
            return
        ed = self.editor
        try:
            if button == "Teach":
                self._teach()
                return
            if button == "Remove":
                ed.remove()
            else:
                ed.move(-1 if button == "Up" else 1)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self.refresh()
        self.changed()

    def _add(self, button: str, primitive: str) -> None:
        """Add (after the picked action) or Update it with the typed arguments."""
        ed = self.editor
        texts = {k: str(h.value) for k, h in self.args[primitive].items()}
        try:
            action = ed.build(primitive, texts, self.label.value.strip())
            (ed.insert if button == "Add" else ed.update)(action)
        except PathError as exc:
            self.on_error(str(exc))
            return
        if button == "Add":
            self.label.value = ""  # a label names one action
        self.refresh()
        self.changed()

    def _teach(self) -> None:
        """The arm's pose (where the pendants left it) into the picked primitive's arguments."""
        primitive, q = self.primitive.value, self.current_q()
        fields, specs = self.args[primitive], ACTION_ARGS[primitive]
        if "q" in fields:
            fields["q"].value = arg_text("q", specs["q"], q)
        elif "position" in fields:
            pose = self.tool_pose(q)
            fields["position"].value = arg_text("position", specs["position"], pose.position)
            fields["rpy"].value = arg_text("rpy", specs["rpy"], pose.rpy)
        else:
            raise PathError(f"{primitive} takes no pose: Teach fills the moves' arguments")

    def changed(self) -> None:
        """The composition changed: it is the session's command once the server has planned it (a
        composition that cannot be sent yet, a new task without actions, says why instead)."""
        if self.editor.empty:
            self.show_plan(None, 0.0)
            return
        try:
            self.editor.to_command()
        except PathError as exc:
            self.refusal.content = ""
            self.planned.content = f"_Not sent yet: {exc}._"
            return
        self.on_changed()

    # -- library -----------------------------------------------------------------------------------
    def refresh_library(self) -> None:
        """The user's saved programs for this model, from the server (on a worker)."""
        entries: list[m.ProgramEntry] = list(self.request(m.ListPrograms()))
        self.ui(lambda: self._show_library(entries))

    def _show_library(self, entries: list[m.ProgramEntry], picked: str = "") -> None:
        self.saved = {saved_label(e): e for e in entries}
        options = tuple(self.saved) or (NO_SAVED,)
        if tuple(self.library.options) != options:
            self.library.options = options
        if picked in options:
            self.library.value = picked

    def _save_clicked(self, event: Any) -> None:
        kind = event.target.value
        self.after(APPLY_GRACE_S, lambda: self._save(kind))  # the name's last keystrokes may lag

    def _save(self, kind: str) -> None:
        name = self.save_as.value.strip()
        try:
            program = self.editor.program(kind)
            if isinstance(program, m.Mission):
                self.editor.set_mission_name(name)
                program = m.Mission(name, program.tasks)
        except PathError as exc:
            self.on_error(str(exc))
            return

        def job() -> None:
            self.request(m.SaveProgram(name, program))
            entries: list[m.ProgramEntry] = list(self.request(m.ListPrograms()))
            picked = saved_label(m.ProgramEntry(kind, name))  # type: ignore[arg-type]
            self.ui(lambda: self._saved(entries, picked))

        self.submit(f"{kind.capitalize()} not saved", job)

    def _use_clicked(self, event: Any) -> None:
        entry = self.saved.get(self.library.value)
        if entry is None:
            self.on_error("no saved program picked: save one first")
            return
        if event.target.value == "Delete":

            def delete() -> None:
                self.request(m.DeleteProgram(entry.kind, entry.name))
                self.refresh_library()

            self.submit(f"{entry.kind.capitalize()} not deleted", delete)
            return
        if self.locked:
            self.on_error(LOCKED)
            return

        def insert() -> None:
            program = self.request(m.LoadProgram(entry.kind, entry.name))
            self.ui(lambda: self._take(program))

        self.submit(f"{entry.kind.capitalize()} not inserted", insert)

    def _saved(self, entries: list[m.ProgramEntry], picked: str) -> None:
        self._show_library(entries, picked)
        self.refresh()

    def _take(self, program: m.Program) -> None:
        try:
            self.editor.take(program)
        except PathError as exc:
            self.on_error(str(exc))
            return
        self.refresh()
        self.changed()

    # -- drawing -----------------------------------------------------------------------------------
    def _show_primitive(self, primitive: str) -> None:
        if self.primitive.value != primitive:
            self.primitive.value = primitive
        self.primitive.hint = ACTION_DOC[primitive]
        for p, fields in self.args.items():
            for handle in fields.values():
                handle.visible = p == primitive

    def _show_action(self) -> None:
        """The picked action's primitive, arguments and label in the fields; the arm where it ends."""
        action = self.editor.selected_action()
        if action is None:
            return
        self._show_primitive(action.primitive)
        specs = ACTION_ARGS[action.primitive]
        for name, handle in self.args[action.primitive].items():
            handle.value = arg_text(name, specs[name], action.args.get(name))
        self.label.value = action.name
        q = self.ends.get(self.editor.step_path(self.editor.task, self.editor.action))
        if q:
            self.on_preview(q)

    def refresh(self) -> None:
        """Every widget as the editor holds it."""
        ed = self.editor
        self.table.content = ed.table_markdown(self.times, self.running)
        tasks = tuple(f"{k + 1}. {t.name}" for k, t in enumerate(ed.tasks))
        if tuple(self.task.options) != tasks:
            self.task.options = tasks
        if self.task.value != tasks[ed.task]:
            self.task.value = tasks[ed.task]
        actions = tuple(str(k + 1) for k in range(len(ed.current.actions))) or ("-",)
        if tuple(self.action.options) != actions:
            self.action.options = actions
        want = str(ed.action + 1) if ed.action >= 0 else "-"
        if self.action.value != want:
            self.action.value = want

    def show_plan(self, plan: m.CommandPlan | None, stop_time: float, current: bool = True) -> None:
        """Each action's planned start and end (`current`: the composition is the session's command)."""
        self.refusal.content = ""
        if not current:
            plan = None  # another pendant's
        if not current and not self.editor.empty:
            self.planned.content = "_Not the session's command: edit the tasks to make it so._"
        else:
            self.planned.content = plan_text(plan, stop_time, self.editor.kind)
        steps = plan.steps if plan is not None else []
        self.times = {s.step: (s.start, s.end) for s in steps}
        self.ends = {s.step: s.q_end for s in steps}
        self.refresh()

    def show_refusal(self, field: str, reason: str) -> None:
        self.refusal.content = refusal_text(self.editor, field, reason)
        self.planned.content = "_Not planned: the session keeps the last command the server took._"
        self.times, self.ends = {}, {}
        self.refresh()

    def show_state(self, state: m.SessionState | None, current: bool) -> None:
        """Mark the step that runs (`current`: the composition is the run's command)."""
        running = state.step if state is not None and current and state.phase in RUNNING else ""
        if running != self.running:
            self.running = running
            self.refresh()

    def set_disabled(self, disabled: bool) -> None:
        """While a run goes on the composition cannot change (the server refuses it anyway); viser's
        button groups cannot be disabled, so their clicks say why instead."""
        self.locked = disabled
