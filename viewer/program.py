"""Actions, tasks and missions as data (paper §2.1 high level, §3 the Action Level Simulator): the
user composes tasks of actions (a primitive with its arguments), one task or several in order (a
mission), as the task pendant edits them: insert after the selected one, update, remove, reorder,
and take saved programs from the user's library.

The primitives and their arguments are the protocol's table (`ACTION_ARGS`); an argument is typed
as text (numbers separated by commas, a name, or nothing for a default or an optional one) and the
server checks it against the model, naming `tasks[1].actions[2].args.speed_pct` when it refuses.

No GUI here: `program_pendant.py` draws it, the session controller owns it, tests use it directly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.robot_commands import ACTION_ARGS, MAX_ITEMS, NAME_ARG, ArgSpec

from .path import PathError
from .tree import fmt, numbers_text, parse_numbers

PRIMITIVES = tuple(ACTION_ARGS)
MAX_ACTIONS = MAX_ITEMS  # the protocol's limit per task, and of tasks per mission
#: The levels this editor sends: one task alone, several as a mission (an action alone is a task of one).
LEVELS = ("task", "mission")


def pendant_level(kind: str) -> str:
    """The level a pendant edits a command of `kind` as: an action is taken as a task of one."""
    return "task" if kind == "action" else kind


#: What the pendant calls each argument of the protocol's table (`ACTION_ARGS`): the user's words,
#: not the protocol's field names.
ARG_NAMES = {
    "q": "Joint positions",
    "speed_pct": "Speed",
    "acc_pct": "Acceleration",
    "position": "Position",
    "rpy": "Roll, pitch, yaw",
    "duration": "Duration",
    "mass": "Mass",
    "size": "Cube edge",
    "object": "Object",
}
#: Decimals an argument is written with in its typed unit (Teach, a loaded action): 0.001 deg, 0.01 mm.
TYPED_DECIMALS = {"deg": 3, "mm": 2}


def arg_name(name: str) -> str:
    return ARG_NAMES.get(name, name)


def typed_unit(name: str, spec: ArgSpec) -> tuple[str, float]:
    """The unit an argument is typed and shown in, as on the other pendants (angles in degrees, the
    tool's position in mm), and the factor from the protocol's value to it."""
    if spec.unit == "rad":
        return "deg", 180.0 / math.pi
    if spec.unit == "m" and name == "position":
        return "mm", 1000.0
    return spec.unit, 1.0


def arg_label(name: str, spec: ArgSpec) -> str:
    unit = typed_unit(name, spec)[0]
    return f"{arg_name(name)} [{unit}]" if unit else arg_name(name)


def arg_hint(name: str, spec: ArgSpec, joints: int) -> str:
    """What a user types for an argument."""
    if spec.size == NAME_ARG:
        shape = "a name"
    elif spec.size == 0:
        shape = "a number"
    else:
        shape = f"{joints if spec.size == -1 else spec.size} numbers, separated by commas"
    unit, factor = typed_unit(name, spec)
    if spec.default is not None:
        rule = f"empty: {fmt(spec.default * factor)}"
    elif spec.optional:
        rule = "may stay empty"
    else:
        rule = "required"
    what = f"{spec.description} ({unit})" if unit else spec.description
    return f"{what}: {shape} ({rule})"


def arg_text(name: str, spec: ArgSpec, value: float | list[float] | str | None) -> str:
    """An argument's protocol value as the user types it (in `typed_unit`, sensibly rounded)."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    unit, factor = typed_unit(name, spec)
    decimals = TYPED_DECIMALS.get(unit)

    def shown(x: float) -> float:
        y = x * factor
        return round(y, decimals) + 0.0 if decimals is not None else y  # + 0.0: no "-0"

    if isinstance(value, list):
        return numbers_text([shown(float(x)) for x in value])
    return fmt(shown(float(value)))


def parse_arg(name: str, spec: ArgSpec, text: str, joints: int) -> float | list[float] | str | None:
    """One argument from its typed text, in the protocol's unit (None: left out). PathError names it
    and what it needs."""
    text = text.strip()
    label = arg_name(name)
    if not text:
        if spec.default is None and not spec.optional:
            raise PathError(f"{label} is required: {spec.description}")
        return None
    if spec.size == NAME_ARG:
        return text
    try:
        values = parse_numbers(text)
    except ValueError:
        raise PathError(f"{label}: {text!r} is not {'a number' if spec.size == 0 else 'numbers'}") from None
    if not all(math.isfinite(x) for x in values):
        raise PathError(f"{label}: the numbers must be finite")
    factor = typed_unit(name, spec)[1]
    values = [x / factor for x in values]
    size = joints if spec.size == -1 else spec.size
    if spec.size == 0:
        if len(values) != 1:
            raise PathError(f"{label}: one number, got {len(values)}")
        return values[0]
    if len(values) != size:
        raise PathError(f"{label}: {size} numbers, got {len(values)}")
    return values


@dataclass
class TaskDraft:
    name: str
    actions: list[m.Action] = field(default_factory=list)


class ProgramEditor:
    """Tasks of actions and the selection (a task, and an action in it; -1: none)."""

    def __init__(self, joints: Sequence[str]) -> None:
        self.joints = list(joints)
        self.tasks = [TaskDraft("task1")]
        self.task = 0
        self.action = -1
        self.mission = "mission1"  # the name the composition runs and saves under when it has tasks

    # -- reading ---------------------------------------------------------------------------------
    @property
    def empty(self) -> bool:
        return not any(t.actions for t in self.tasks)

    @property
    def kind(self) -> str:
        """What the composition is sent as: a task alone, or a mission of tasks."""
        return "task" if len(self.tasks) == 1 else "mission"

    @property
    def current(self) -> TaskDraft:
        return self.tasks[self.task]

    def step_path(self, task: int, action: int) -> str:
        """Where an action sits in the command sent: the server's PlanStep.step and SessionState.step."""
        return f"actions[{action}]" if self.kind == "task" else f"tasks[{task}].actions[{action}]"

    def selected_action(self) -> m.Action | None:
        return self.current.actions[self.action] if self.action >= 0 else None

    # -- tasks -----------------------------------------------------------------------------------
    def _name(self, name: str, what: str) -> str:
        try:
            return keys.check_name(name.strip(), what)
        except ValueError as exc:
            raise PathError(str(exc)) from None

    def add_task(self, name: str) -> None:
        """A new empty task after the selected one, selected."""
        name = self._name(name, "task name")
        if len(self.tasks) >= MAX_ACTIONS:
            raise PathError(f"a mission holds at most {MAX_ACTIONS} tasks")
        self.task += 1
        self.tasks.insert(self.task, TaskDraft(name))
        self.action = -1

    def rename_task(self, name: str) -> None:
        self.current.name = self._name(name, "task name")

    def set_mission_name(self, name: str) -> None:
        self.mission = self._name(name, "mission name")

    def remove_task(self) -> None:
        if len(self.tasks) == 1:
            self.tasks[0] = TaskDraft(self.tasks[0].name)
        else:
            del self.tasks[self.task]
            self.task = min(self.task, len(self.tasks) - 1)
        self.action = len(self.current.actions) - 1

    def move_task(self, delta: int) -> None:
        j = self.task + delta
        if not 0 <= j < len(self.tasks):
            raise PathError(f"task {self.current.name} is already {'first' if delta < 0 else 'last'}")
        self.tasks[self.task], self.tasks[j] = self.tasks[j], self.tasks[self.task]
        self.task = j

    def select(self, task: int, action: int = -1) -> None:
        if not 0 <= task < len(self.tasks):
            raise PathError(f"there is no task {task + 1}")
        if not -1 <= action < len(self.tasks[task].actions):
            raise PathError(f"task {self.tasks[task].name} has no action {action + 1}")
        self.task, self.action = task, action

    # -- actions ---------------------------------------------------------------------------------
    def build(self, primitive: str, texts: dict[str, str], label: str = "") -> m.Action:
        """An action from its typed arguments; PathError names the argument it cannot take."""
        if primitive not in ACTION_ARGS:
            raise PathError(f"no primitive {primitive!r}: one of {', '.join(PRIMITIVES)}")
        args = {}
        for name, spec in ACTION_ARGS[primitive].items():
            value = parse_arg(name, spec, texts.get(name, ""), len(self.joints))
            if value is not None:
                args[name] = value
        try:
            return codec.from_obj(
                m.Action, {"kind": "action", "primitive": primitive, "args": args, "name": label}
            )
        except codec.DecodeError as exc:
            raise PathError(f"{primitive}: {exc}") from None

    def insert(self, action: m.Action) -> None:
        """After the selected action of the selected task (first when none is selected), selected."""
        actions = self.current.actions
        if len(actions) >= MAX_ACTIONS:
            raise PathError(f"a task holds at most {MAX_ACTIONS} actions")
        self.action += 1
        actions.insert(self.action, action)

    def update(self, action: m.Action) -> None:
        if self.action < 0:
            raise PathError("no action selected: Add one first")
        self.current.actions[self.action] = action

    def remove(self) -> None:
        if self.action < 0:
            raise PathError("no action selected")
        del self.current.actions[self.action]
        self.action = min(self.action, len(self.current.actions) - 1)

    def move(self, delta: int) -> None:
        actions, i = self.current.actions, self.action
        if i < 0:
            raise PathError("no action selected")
        j = i + delta
        if not 0 <= j < len(actions):
            raise PathError(f"action {i + 1} is already {'first' if delta < 0 else 'last'}")
        actions[i], actions[j] = actions[j], actions[i]
        self.action = j

    # -- programs ----------------------------------------------------------------------------------
    def to_command(self) -> m.Task | m.Mission:
        for t in self.tasks:
            if not t.actions:
                what = f"task {t.name}" if len(self.tasks) > 1 else "the task"
                raise PathError(f"{what} has no action: add one (or remove the task)")
        tasks = [m.Task(t.name, list(t.actions)) for t in self.tasks]
        return tasks[0] if len(tasks) == 1 else m.Mission(self.mission, tasks)

    def program(self, kind: str) -> m.Program:
        """What Save keeps: the selected action, the selected task, or every task as a mission."""
        if kind == "action":
            action = self.selected_action()
            if action is None:
                raise PathError("no action selected to save")
            return action
        if kind == "task":
            if not self.current.actions:
                raise PathError(f"task {self.current.name} has no action to save")
            return m.Task(self.current.name, list(self.current.actions))
        cmd = self.to_command()
        return cmd if isinstance(cmd, m.Mission) else m.Mission(self.mission, [cmd])

    def take(self, program: m.Program) -> None:
        """A saved program into the composition: an action after the selected one, a task after the
        selected task, a mission's tasks after it (an empty first task gives way)."""
        if isinstance(program, m.Action):
            self.insert(program)
            return
        tasks = [program] if isinstance(program, m.Task) else program.tasks
        if isinstance(program, m.Mission):
            self.mission = program.name
        if len(self.tasks) == 1 and not self.tasks[0].actions:
            self.tasks, self.task = [], -1
        for t in tasks:
            self.task += 1
            self.tasks.insert(self.task, TaskDraft(t.name, list(t.actions)))
        self.action = len(self.current.actions) - 1

    def load(self, cmd: m.Action | m.Task | m.Mission) -> None:
        """The session's stored command (a restored session) as the composition."""
        self.tasks, self.task, self.action = [TaskDraft("task1")], 0, -1
        if isinstance(cmd, m.Action):
            self.tasks[0].actions.append(cmd)
            self.action = 0
        else:
            self.take(cmd)
            self.task, self.action = 0, len(self.tasks[0].actions) - 1

    # -- shown -------------------------------------------------------------------------------------
    def describe(self, action: m.Action) -> str:
        """An action as the table shows it, its arguments in the units they are typed in."""
        specs = ACTION_ARGS.get(action.primitive, {})
        parts = []
        for k, v in action.args.items():
            spec = specs.get(k)
            if spec is None:
                parts.append(f"{k} {v}")
                continue
            unit = typed_unit(k, spec)[0]
            parts.append(f"{arg_name(k).lower()} {arg_text(k, spec, v)}" + (f" {unit}" if unit else ""))
        return f"{action.primitive}" + (f" ({'; '.join(parts)})" if parts else "")

    def table_markdown(self, times: dict[str, tuple[float, float]], running: str = "") -> str:
        """Every task and its actions: the selected action ▶, the running one ⏵ (`running`: its
        step path), each with its planned start and end (`times` by step path)."""
        if self.empty and len(self.tasks) == 1:
            return (
                "_No action yet: pick a primitive, fill its arguments (Teach takes the arm's pose), "
                "then **Add**._"
            )
        rows = ["| # | action | planned [s] |", "|---|---|---|"]
        for ti, task in enumerate(self.tasks):
            head = f"**{task.name}**" if ti != self.task else f"**▶ {task.name}**"
            rows.append(f"| | {head} ({len(task.actions)} actions) | |")
            for ai, action in enumerate(task.actions):
                path = self.step_path(ti, ai)
                mark = "⏵ " if path == running else ""
                number = f"**▶{ai + 1}**" if (ti, ai) == (self.task, self.action) else str(ai + 1)
                label = f"{action.name}: " if action.name else ""
                span = times.get(path)
                when = f"{span[0]:.2f}–{span[1]:.2f}" if span else "—"
                rows.append(f"| {mark}{number} | {label}{self.describe(action)} | {when} |")
        sent = "a task" if self.kind == "task" else f"mission **{self.mission}**"
        return "\n".join(rows) + f"\n\nSent as {sent}; ⏵ the step running."
