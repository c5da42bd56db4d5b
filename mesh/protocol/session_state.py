"""What a session publishes and answers about itself: its phase and progress, its values, obstacles and
command, its runs, and the snapshot a client restores its view from."""

from __future__ import annotations

from typing import Annotated

from msgspec import Meta

from .environment import ObstacleList
from .phases import Phase
from .plans import CommandPlan
from .primitives import Message, Name, Numbers, Record, SessionId, Text
from .robot_commands import ProgramKind, RobotCommand
from .run_settings import RunSettings


class HilStats(Record):
    """An external controller's timeliness over the run so far (PROTOCOL.md §6.3)."""

    periods: Annotated[int, Meta(ge=0, description="control periods exchanged")] = 0
    misses: Annotated[int, Meta(ge=0, description="actuator frames later than one period (paced runs)")] = 0
    worst_late_ms: Annotated[float, Meta(ge=0.0, description="ms past the deadline, the worst miss")] = 0.0


class SessionState(Message, tag="state"):
    """Lifecycle of a session on <session>/state (paper §3.2 Time Presentation)."""

    session: SessionId
    phase: Phase
    seq: Annotated[int, Meta(ge=0, description="grows with every publication")] = 0
    run_id: Annotated[str, Meta(max_length=64, description="the current or last run; '' before any")] = ""
    queue_position: Annotated[int, Meta(ge=0, description="1 = next to start; 0 when not waiting")] = 0
    progress: Annotated[float, Meta(ge=0.0, le=1.0, description="of stop_time")] = 0.0
    sim_time: Annotated[float, Meta(ge=0.0, description="s")] = 0.0
    rtf: Annotated[float, Meta(ge=0.0, description="simulated s per wall s over the run so far")] = 0.0
    reason: Annotated[Text, Meta(description="why failed / aborted")] = ""
    warnings: Annotated[list[Text], Meta(max_length=100, description="notices about the current run")] = []
    step: Annotated[Text, Meta(description="the running step (PlanStep.step); '' if none")] = ""
    task: Annotated[str, Meta(max_length=64, description="the running task's name (task, mission)")] = ""
    action: Annotated[str, Meta(max_length=64, description="the running action's label or primitive")] = ""
    hil: Annotated[HilStats | None, Meta(description="controller external: its timeliness so far")] = None
    host: Annotated[
        str, Meta(max_length=64, description="the simulator host running the run; '' if none")
    ] = ""
    wait_s: Annotated[
        float,
        Meta(ge=0.0, description="queued: estimated s until the run starts (0 = not queued or unknown)"),
    ] = 0.0
    attempt: Annotated[
        int, Meta(ge=1, description="2+: restarted from the start after its host was lost")
    ] = 1


class ParamValues(Message, tag="params"):
    """Every parameter value of a session, published on <session>/params after each change."""

    session: SessionId
    model_id: Name
    values: dict[Name, float]
    changed: list[Name] = []


class ObstacleValues(Message, tag="obstacles"):
    """The obstacles of a session, published on <session>/obstacles after each set_obstacles."""

    session: SessionId
    obstacles: ObstacleList


class CommandValue(Message, tag="command"):
    """The command of a session and its plan, published on <session>/command after each set_command
    (what every client of the session shows in its pendants)."""

    session: SessionId
    command: Annotated[RobotCommand | None, Meta(description="null: no command set yet")] = None
    plan: Annotated[
        CommandPlan | None, Meta(description="the reply set_command gave; null after a proxy restart")
    ] = None


class RunInfo(Record):
    """One run of a session, as its list of runs shows it."""

    run_id: Name
    phase: Phase
    stop_time: Annotated[float, Meta(ge=0.0, description="s")]
    sim_time: Annotated[float, Meta(ge=0.0, description="s reached")]
    samples: Annotated[int, Meta(ge=0)] = 0
    reason: Text = ""
    recording: Annotated[str, Meta(max_length=64, description="replay runs: the recording replayed")] = ""
    host: Annotated[str, Meta(max_length=64, description="the simulator host that ran it")] = ""
    attempt: Annotated[
        int, Meta(ge=1, description="2+: restarted from the start after its host was lost")
    ] = 1
    until_stopped: Annotated[
        bool, Meta(description="a run until stopped (Run.until_stopped): stop_time is its bound")
    ] = False
    jogged_s: Annotated[
        float,
        Meta(
            ge=0.0,
            description="simulated s during which a jog moved the arm (JogInput, §5.4): 0 = never "
            "jogged; a replay: the recorded run's",
        ),
    ] = 0.0


class SessionSnapshot(Message, tag="session"):
    """Reply data of create / get_session: everything a client needs to restore its view."""

    session: SessionId
    user: Name
    model_id: Name
    values: dict[Name, float]
    initial: Numbers
    command: RobotCommand | None
    settings: RunSettings
    state: SessionState
    runs: Annotated[list[RunInfo], Meta(description="the runs whose results are kept, oldest first")] = []
    obstacles: Annotated[
        ObstacleList, Meta(description="what the arm can touch (a new session: the model's obstacles)")
    ] = []


RunList = list[RunInfo]


class SessionEntry(Record):
    """One of a user's sessions (reply of `list`)."""

    session: SessionId
    model_id: Name
    phase: Phase


class RunStarted(Record):
    """Reply data of `run`, `replay` and `continue`."""

    run_id: Name
    phase: Phase
    queue_position: Annotated[int, Meta(ge=0)]


class ProgramEntry(Record):
    """One saved program (reply of `list_programs`)."""

    kind: ProgramKind
    name: Name
