"""The requests a client sends about its sessions: each command on `<session>/cmd` (and each request on
`simecs/u/<user>/sessions`) is one class, which states everything about it once: its `op` and fields,
the type of its reply's `data`, the session phases it is accepted in and what its refusal says in
the others. The union the proxy decodes, the reply table the client reads (REPLIES), the phase check
the proxy enforces and the viewer enables its buttons by (refusal) and PROTOCOL.md's tables all derive
from these classes.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from msgspec import Meta

from .environment import ObstacleList, check_obstacles
from .phases import EDITABLE, GOING, OPEN, UNDER_WAY
from .plans import CommandPlan
from .primitives import VERSION, FieldProblem, Name, Record
from .robot_commands import Program, ProgramKind, RobotCommand, Seconds
from .run_settings import RunSettings
from .session_state import ProgramEntry, RunStarted, SessionEntry, SessionSnapshot


class Command(Record, kw_only=True, tag_field="op"):
    """A request on `<session>/cmd` (or `simecs/u/<user>/sessions`): told apart by `op`."""

    v: Literal[1] = VERSION
    #: The type of the `data` of its Ok reply (PROTOCOL.md §5).
    reply: ClassVar[Any] = str

    @property
    def op(self) -> str:
        return str(type(self).__struct_config__.tag)


#: Every session command, in the order its class is defined (the document's order too).
SESSION_COMMANDS: list[type[SessionCommandBase]] = []
#: Every request on simecs/u/<user>/sessions.
SESSION_REQUESTS: list[type[SessionRequestBase]] = []


class SessionCommandBase(Command):
    """A command on `<session>/cmd`; defining a subclass registers it."""

    #: The session phases it is accepted in.
    accepted_in: ClassVar[tuple[str, ...]] = OPEN
    #: Why it is refused in another phase ({phase} is filled in; "" = "<op> is not possible while ...").
    refused: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        SESSION_COMMANDS.append(cls)


class SessionRequestBase(Command):
    """A request on `simecs/u/<user>/sessions`; defining a subclass registers it."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        SESSION_REQUESTS.append(cls)


def _edit(what: str) -> str:
    return f"cannot change {what} while the run is {{phase}}"


_BUSY = "a run is already {phase} in this session"


# -- commands on <session>/cmd -------------------------------------------------------------------------
class SetParams(SessionCommandBase, tag="set_params"):
    reply = dict[str, float]
    accepted_in = EDITABLE
    refused = _edit("parameters")

    values: Annotated[dict[Name, float], Meta(max_length=100_000)]


class ResetParams(SessionCommandBase, tag="reset_params"):
    reply = dict[str, float]
    accepted_in = EDITABLE
    refused = _edit("parameters")

    names: Annotated[list[Name], Meta(max_length=100_000, description="empty: every parameter")] = []


class SetInitial(SessionCommandBase, tag="set_initial"):
    reply = list[float]
    accepted_in = EDITABLE
    refused = _edit("the initial pose")

    joints: Annotated[
        list[float], Meta(max_length=64, description="rad, one per joint; the arm starts at rest")
    ]


class SetCommand(SessionCommandBase, tag="set_command"):
    reply = CommandPlan
    accepted_in = EDITABLE
    refused = _edit("the command")

    command: RobotCommand


class SetSettings(SessionCommandBase, tag="set_settings"):
    reply = RunSettings
    accepted_in = EDITABLE
    refused = _edit("the simulation settings")

    settings: RunSettings


class SetObstacles(SessionCommandBase, tag="set_obstacles"):
    """Replace the session's obstacles: the whole list, as with settings (the model's own are in
    ModelDescription.obstacles: send those to go back to them)."""

    reply = ObstacleList
    accepted_in = EDITABLE
    refused = _edit("the obstacles")

    obstacles: ObstacleList

    def __post_init__(self) -> None:
        check_obstacles(self.obstacles)


class Run(SessionCommandBase, tag="run"):
    """Assign the command: start a run with the session's values, pose, command and settings."""

    reply = RunStarted
    accepted_in = EDITABLE
    refused = _BUSY

    until_stopped: Annotated[
        bool,
        Meta(
            description="a run until stopped (to jog an idle arm and teach poses): paced in real time "
            "whatever the settings say, it follows the command if the session has one (then holds its "
            "last set point), else holds the initial pose, and lasts until `stop`, at most open_run_s "
            "(PROTOCOL.md §4.1); settings.stop_time is not used"
        ),
    ] = False


class Replay(SessionCommandBase, tag="replay"):
    """Start a run that replays a recording of this session's model instead of simulating."""

    reply = RunStarted
    accepted_in = EDITABLE
    refused = _BUSY

    recording: Name
    speed: Annotated[float, Meta(ge=0.0, le=1000.0, description="x real time; 0 = as fast as possible")] = 1.0
    paused: bool = False

    def __post_init__(self) -> None:
        if 0.0 < self.speed < 0.01:
            raise FieldProblem("speed", f"{self.speed:g} is outside [0.01, 1000] (0 = as fast as possible)")


class Continue(SessionCommandBase, tag="continue"):
    """Run again a run that failed part way (its simulator process crashed or was killed) and go on
    from where its kept results end: the same inputs as that run (not the session's now), simulated as
    fast as possible up to there and then at its pacing. A new run, whose results are the whole run."""

    reply = RunStarted
    accepted_in = EDITABLE
    refused = _BUSY

    run_id: Annotated[Name, Meta(description="the failed run, one of the session's kept runs")]


class Pause(SessionCommandBase, tag="pause"):
    accepted_in = ("running",)
    refused = "nothing to pause: the session is {phase}"


class Resume(SessionCommandBase, tag="resume"):
    accepted_in = ("paused",)
    refused = "nothing to resume: the session is {phase}"


class Abort(SessionCommandBase, tag="abort"):
    accepted_in = UNDER_WAY
    refused = "nothing to abort: the session is {phase}"


class Stop(SessionCommandBase, tag="stop"):
    """End the run now as `finished`, its results up to now kept (`abort` ends it as `aborted`)."""

    accepted_in = GOING
    refused = "nothing to stop: the session is {phase}"


class Seek(SessionCommandBase, tag="seek"):
    """Jump a replay run to simulated time `time` (replay runs only)."""

    accepted_in = GOING
    refused = "nothing to seek in: the session is {phase}"

    time: Seconds


class SaveParamSet(SessionCommandBase, tag="save_param_set"):
    name: Name


class LoadParamSet(SessionCommandBase, tag="load_param_set"):
    reply = dict[str, float]
    accepted_in = EDITABLE
    refused = _edit("parameters")

    name: Name


class DeleteParamSet(SessionCommandBase, tag="delete_param_set"):
    name: Name


class ListParamSets(SessionCommandBase, tag="list_param_sets"):
    reply = list[str]


class SaveProgram(SessionCommandBase, tag="save_program"):
    """Keep an action, task or mission in the user's library of this model, under `name` (replacing
    one of the same kind and name)."""

    name: Name
    program: Program


class LoadProgram(SessionCommandBase, tag="load_program"):
    """A saved program, checked against the model's current bounds (not made the session's command)."""

    reply = Program

    kind: ProgramKind
    name: Name


class DeleteProgram(SessionCommandBase, tag="delete_program"):
    kind: ProgramKind
    name: Name


class ListPrograms(SessionCommandBase, tag="list_programs"):
    reply = list[ProgramEntry]

    kind: Annotated[Literal["", "action", "task", "mission"], Meta(description="'' = every kind")] = ""


class GetSession(SessionCommandBase, tag="get_session"):
    reply = SessionSnapshot


class CloseSession(SessionCommandBase, tag="close_session"):
    pass


# -- requests on simecs/u/<user>/sessions --------------------------------------------------------------
class CreateSession(SessionRequestBase, tag="create"):
    """A new session of the key's user on a model, with its default values."""

    reply = SessionSnapshot

    model_id: Name


class ListSessions(SessionRequestBase, tag="list"):
    """The key's user's open sessions."""

    reply = list[SessionEntry]


#: What the proxy decodes a `<session>/cmd` payload as, and a sessions request as.
SessionCommand: Any = Union[tuple(SESSION_COMMANDS)]  # noqa: UP007 (built from the registry)
SessionRequest: Any = Union[tuple(SESSION_REQUESTS)]  # noqa: UP007
#: Reply `data` of every command and request (the schema and the client use it).
REPLIES: dict[type, Any] = {cls: cls.reply for cls in (*SESSION_COMMANDS, *SESSION_REQUESTS)}
_BY_OP: dict[str, type[SessionCommandBase]] = {str(c.__struct_config__.tag): c for c in SESSION_COMMANDS}


def refusal(op: str, phase: str) -> str:
    """Why session command `op` is refused in `phase` ('' when it is accepted)."""
    command = _BY_OP[op]
    if phase in command.accepted_in:
        return ""
    return command.refused.format(phase=phase) or f"{op} is not possible while {phase}"
