"""Every JSON message of the protocol, defined once as msgspec Structs.

These classes are the protocol's single definition: `codec` decodes into them strictly (unknown
fields, wrong types, values out of bounds and a missing `v` are refused, naming the field), and
`schema.py` turns them into `docs/protocol.schema.json` and the message tables of PROTOCOL.md.
Bounds live in the types (`Annotated[..., Meta(...)]`), so the schema states them too.

Messages that travel alone carry a tag (`type`, or `op` for commands) and `v`; robot commands are
told apart by `kind`. A newer minor field is added with a default, so `v` only changes when old
clients could misread a message.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from msgspec import Meta

from .environment import Obstacle, ObstacleList, check_obstacles  # noqa: F401 (m.Obstacle)
from .limits import limit
from .model import ControlSystem, ModelSummary
from .phases import Phase, WorkerPhase
from .primitives import FieldProblem, Message, Name, Numbers, Record, SessionId, Text
from .robot_commands import (  # noqa: F401  (the protocol's one namespace: m.JointPath, ...)
    COMMAND_LEVELS,
    Action,
    CartesianNode,
    CartesianPath,
    ChirpSignal,
    DirectInput,
    JointPath,
    Mission,
    PathNode,
    Program,
    ProgramKind,
    RampSignal,
    RobotCommand,
    Seconds,
    Signal,
    SignalUnit,
    SineSignal,
    StepSignal,
    TableSignal,
    Task,
    control_refusal,
)

VERSION: Literal[1] = 1


class Command(Record, kw_only=True, tag_field="op"):
    """A request on `<session>/cmd` (or `simecs/u/<user>/sessions`): told apart by `op`."""

    v: Literal[1] = VERSION

    @property
    def op(self) -> str:
        return str(type(self).__struct_config__.tag)


# -- replies -------------------------------------------------------------------------------------------
ErrorCode = Literal["bad_request", "not_found", "forbidden", "conflict", "busy", "internal", "unsupported"]


class Error(Message, tag="error"):
    """A refusal, sent as a Zenoh error reply: what was wrong, and in which field ("" = the whole
    message or request)."""

    code: ErrorCode
    message: Text
    field: Text = ""


class Ok(Message, tag="ok"):
    """A successful reply; the type of `data` is given per request (REPLIES, PROTOCOL.md §5)."""

    data: Any = None


MAX_SAMPLES = limit("samples_per_run")


# -- simulation settings -------------------------------------------------------------------------------
class RunSettings(Record):
    """Paper §2.2 step 6. `set_settings` replaces the whole object: omitted fields take these defaults."""

    stop_time: Annotated[float, Meta(gt=0.0, le=3600.0, description="s, (0, 3600]")] = 5.0
    output_interval: Annotated[
        float, Meta(ge=1e-4, le=3600.0, description="s between result samples, [1e-4, stop_time]")
    ] = 0.002
    step: Annotated[
        float,
        Meta(ge=0.0, le=0.01, description="solver step in s: 0 = the model's default, else [1e-5, 0.01]"),
    ] = 0.0
    pacing: Literal["realtime", "scaled", "fast"] = "realtime"
    factor: Annotated[float, Meta(ge=0.01, le=1000.0, description="x real time, for pacing scaled")] = 1.0
    live_rate_hz: Annotated[float, Meta(ge=0.1, le=1000.0, description="live frames per wall second")] = 50.0
    live_vars: Annotated[list[Name], Meta(max_length=10_000, description="empty: every variable")] = []
    controller: Annotated[
        Literal["builtin", "external"],
        Meta(description="external: a controller on hil/actuators drives the joints (PROTOCOL.md §6.3)"),
    ] = "builtin"
    external_joints: Annotated[
        list[Name],
        Meta(max_length=64, description="controller external: the joints it drives; empty = every joint"),
    ] = []
    control_period: Annotated[
        float,
        Meta(
            ge=1e-4,
            le=0.1,
            description="s, a multiple of step: controller external, one exchange per period; "
            "control_system opspace_motion or opspace_hybrid, one controller update per period "
            "(zero-order hold)",
        ),
    ] = 0.001
    hil_timeout: Annotated[
        float,
        Meta(ge=0.05, le=60.0, description="s of wall time without an actuator frame: the run fails"),
    ] = 2.0
    control_system: Annotated[
        ControlSystem,
        Meta(
            description="controller builtin: joint_independent (each joint's cascade), opspace_motion "
            "(task-space inverse dynamics at the tool, updated every control_period) or opspace_hybrid "
            "(the same, with force control where a Cartesian node sets a force); one of the model's "
            "control_systems"
        ),
    ] = "joint_independent"
    collisions: Annotated[
        Literal["refuse", "simulate"],
        Meta(
            description="refuse: a run whose planned path makes the arm touch an obstacle or itself is "
            "refused, naming the step and the obstacle or the two links; simulate: it runs, the contact "
            "with obstacles is simulated and links touching each other are told as notices"
        ),
    ] = "refuse"

    def __post_init__(self) -> None:
        if self.output_interval > self.stop_time:
            raise FieldProblem("output_interval", f"{self.output_interval:g} s is above stop_time")
        if self.stop_time / self.output_interval > MAX_SAMPLES:
            raise FieldProblem(
                "output_interval",
                f"{self.stop_time / self.output_interval:,.0f} output samples (stop_time / output_interval), "
                f"more than samples_per_run = {MAX_SAMPLES:,}: raise output_interval or shorten stop_time",
            )
        if self.control_system != "joint_independent" and self.controller == "external":
            raise FieldProblem(
                "control_system",
                f"{self.control_system} is a built-in controller: it needs controller builtin",
            )
        if 0.0 < self.step < 1e-5:
            raise FieldProblem("step", f"{self.step:g} s is outside [1e-5, 0.01] s (0 = model default)")

    @property
    def speed(self) -> float:
        """Wanted real-time factor; math.inf for as fast as possible."""
        return {"realtime": 1.0, "scaled": self.factor, "fast": float("inf")}[self.pacing]


# -- commands on <session>/cmd -------------------------------------------------------------------------
class SetParams(Command, tag="set_params"):
    values: Annotated[dict[Name, float], Meta(max_length=100_000)]


class ResetParams(Command, tag="reset_params"):
    names: Annotated[list[Name], Meta(max_length=100_000, description="empty: every parameter")] = []


class SetInitial(Command, tag="set_initial"):
    joints: Annotated[
        list[float], Meta(max_length=64, description="rad, one per joint; the arm starts at rest")
    ]


class SetCommand(Command, tag="set_command"):
    command: RobotCommand


class SetSettings(Command, tag="set_settings"):
    settings: RunSettings


class SetObstacles(Command, tag="set_obstacles"):
    """Replace the session's obstacles: the whole list, as with settings (the model's own are in
    ModelDescription.obstacles: send those to go back to them)."""

    obstacles: ObstacleList

    def __post_init__(self) -> None:
        check_obstacles(self.obstacles)


class Run(Command, tag="run"):
    """Assign the command: start a run with the session's values, pose, command and settings."""

    until_stopped: Annotated[
        bool,
        Meta(
            description="a run until stopped (to jog an idle arm and teach poses): paced in real time "
            "whatever the settings say, it follows the command if the session has one (then holds its "
            "last set point), else holds the initial pose, and lasts until `stop`, at most open_run_s "
            "(PROTOCOL.md §4.1); settings.stop_time is not used"
        ),
    ] = False


class Replay(Command, tag="replay"):
    """Start a run that replays a recording of this session's model instead of simulating."""

    recording: Name
    speed: Annotated[float, Meta(ge=0.0, le=1000.0, description="x real time; 0 = as fast as possible")] = 1.0
    paused: bool = False

    def __post_init__(self) -> None:
        if 0.0 < self.speed < 0.01:
            raise FieldProblem("speed", f"{self.speed:g} is outside [0.01, 1000] (0 = as fast as possible)")


class Continue(Command, tag="continue"):
    """Run again a run that failed part way (its simulator process crashed or was killed) and go on
    from where its kept results end: the same inputs as that run (not the session's now), simulated as
    fast as possible up to there and then at its pacing. A new run, whose results are the whole run."""

    run_id: Annotated[Name, Meta(description="the failed run, one of the session's kept runs")]


class Pause(Command, tag="pause"):
    pass


class Resume(Command, tag="resume"):
    pass


class Abort(Command, tag="abort"):
    pass


class Stop(Command, tag="stop"):
    """End the run now as `finished`, its results up to now kept (`abort` ends it as `aborted`)."""


class Seek(Command, tag="seek"):
    """Jump a replay run to simulated time `time` (replay runs only)."""

    time: Seconds


class SaveParamSet(Command, tag="save_param_set"):
    name: Name


class LoadParamSet(Command, tag="load_param_set"):
    name: Name


class DeleteParamSet(Command, tag="delete_param_set"):
    name: Name


class ListParamSets(Command, tag="list_param_sets"):
    pass


class SaveProgram(Command, tag="save_program"):
    """Keep an action, task or mission in the user's library of this model, under `name` (replacing
    one of the same kind and name)."""

    name: Name
    program: Program


class LoadProgram(Command, tag="load_program"):
    """A saved program, checked against the model's current bounds (not made the session's command)."""

    kind: ProgramKind
    name: Name


class DeleteProgram(Command, tag="delete_program"):
    kind: ProgramKind
    name: Name


class ListPrograms(Command, tag="list_programs"):
    kind: Annotated[Literal["", "action", "task", "mission"], Meta(description="'' = every kind")] = ""


class ProgramEntry(Record):
    """One saved program (reply of `list_programs`)."""

    kind: ProgramKind
    name: Name


class PlanStep(Record):
    """One step of an expanded command: where it sits in the command and when it runs."""

    step: Annotated[Text, Meta(description="its path in the command, e.g. tasks[1].actions[2]; nodes[3]")]
    what: Annotated[Text, Meta(description="the primitive or move type: move_linear, lin, ptp, joint, ...")]
    start: Annotated[float, Meta(ge=0.0, description="s of simulated time")]
    end: Annotated[float, Meta(ge=0.0, description="s")]
    task: Annotated[str, Meta(max_length=64, description="the task's name ('' outside a task)")] = ""
    action: Annotated[str, Meta(max_length=64, description="the action's label, else its primitive")] = ""
    q_end: Annotated[
        list[float],
        Meta(
            max_length=64,
            description="rad, the joint set points when the step ends (a pendant draws the arm there); "
            "[] when not known before the run (a direct input of motor currents)",
        ),
    ] = []
    slowed: Annotated[
        float,
        Meta(
            ge=1.0,
            description="how much longer the step takes than its Cartesian speed and acceleration "
            "percentages asked, because a joint's traj.max_speed or traj.max_acc would be exceeded: "
            "the line was time-scaled to them (1.0 = not slowed; only lin moves are)",
        ),
    ] = 1.0


#: Rows of a direct input's preview in a plan (SignalPreview).
PREVIEW_POINTS = 1000


class SignalPreview(Record):
    """A direct input's signals as the server expanded them (what the run follows), for a preview plot.
    At most 1000 samples (PREVIEW_POINTS) of the full table: all its rows when they fit, else each span of
    time's first row and each joint's lowest and highest (a dense sine keeps its envelope)."""

    unit: Annotated[
        SignalUnit,
        Meta(description="open_loop: A (motor current); closed_loop: rad (position) or rad/s (speed)"),
    ]
    t: Annotated[list[float], Meta(max_length=PREVIEW_POINTS, description="s, non-decreasing")]
    values: Annotated[
        dict[Name, Annotated[list[float], Meta(max_length=PREVIEW_POINTS)]],
        Meta(max_length=64, description="per signalled joint (joint1...), one value per t"),
    ]


#: Samples of a plan's motion (PlannedMotion) at most.
MOTION_POINTS = 200


class PlannedMotion(Record):
    """The joint set points of a command over its duration, for a preview of the move before it runs
    (a client animates its arm along them): evenly spaced in time, at most 200 (MOTION_POINTS)."""

    t: Annotated[list[float], Meta(max_length=MOTION_POINTS, description="s, increasing from 0")]
    q: Annotated[
        list[Annotated[list[float], Meta(max_length=64)]],
        Meta(max_length=MOTION_POINTS, description="rad, the joint set points at each t, one per joint"),
    ]


class CommandPlan(Record):
    """Reply data of `set_command`: the command as the server expanded it for the session's model,
    values and initial pose."""

    kind: Name
    duration: Annotated[float, Meta(ge=0.0, description="s until the last step ends")]
    steps: list[PlanStep]
    final_q: Annotated[Numbers, Meta(description="rad, the joint set points once the command is done")]
    tool_path: Annotated[
        list[Annotated[list[float], Meta(min_length=3, max_length=3)]],
        Meta(max_length=1000, description="m, the planned tool positions, at most 1000 (movement levels)"),
    ] = []
    stop_time_cuts: Annotated[bool, Meta(description="the run's stop_time ends before the command")] = False
    start_pose: Annotated[
        list[float],
        Meta(max_length=6, description="the tool at the initial pose: x, y, z (m), roll, pitch, yaw (rad)"),
    ] = []
    end_pose: Annotated[list[float], Meta(max_length=6, description="the tool once the command is done")] = []
    signals: Annotated[
        SignalPreview | None, Meta(description="direct_input: its signals as expanded; null otherwise")
    ] = None
    slowed: Annotated[
        float,
        Meta(
            ge=1.0,
            description="the largest PlanStep.slowed: how much the joint limits slowed the step they "
            "slowed most (1.0 = every step as fast as its percentages asked)",
        ),
    ] = 1.0
    motion: Annotated[
        PlannedMotion | None,
        Meta(
            description="the joint set points over the command, for a preview; null when positions are "
            "not known before the run (a joint follows a speed or a motor current)"
        ),
    ] = None


class GetSession(Command, tag="get_session"):
    pass


class CloseSession(Command, tag="close_session"):
    pass


SessionCommand = (
    SetParams
    | ResetParams
    | SetInitial
    | SetCommand
    | SetSettings
    | SetObstacles
    | Run
    | Replay
    | Continue
    | Pause
    | Resume
    | Abort
    | Stop
    | Seek
    | SaveParamSet
    | LoadParamSet
    | DeleteParamSet
    | ListParamSets
    | SaveProgram
    | LoadProgram
    | DeleteProgram
    | ListPrograms
    | GetSession
    | CloseSession
)


# -- requests on simecs/u/<user>/sessions --------------------------------------------------------------
class CreateSession(Command, tag="create"):
    """A new session of the key's user on a model, with its default values."""

    model_id: Name


class ListSessions(Command, tag="list"):
    """The key's user's open sessions."""


SessionRequest = CreateSession | ListSessions


# -- published state -----------------------------------------------------------------------------------
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


class ModelList(Message, tag="models"):
    models: list[ModelSummary]


# -- proxy <-> simulator -------------------------------------------------------------------------------
class RunRequest(Message, tag="run_request"):
    """Everything a producer needs for one run; sent by the proxy to simecs/simulators/<node>/run.

    With `recording` set the run replays that recording (its stop_time and output_interval are the
    recorded ones) instead of simulating the model."""

    session: SessionId
    run_id: Name
    run_index: Annotated[int, Meta(ge=0, le=2**32 - 1)]
    user: Name
    model_id: Name
    values: dict[Name, float]
    initial: Numbers
    command: RobotCommand | None
    settings: RunSettings
    recording: Annotated[str, Meta(max_length=64, description="'' = simulate the model")] = ""
    paused: Annotated[bool, Meta(description="start paused (resume to go)")] = False
    attempt: Annotated[int, Meta(ge=1, description="2+: the run restarted after its host was lost")] = 1
    restarted: Annotated[Text, Meta(description="attempt 2+: why the run started again")] = ""
    obstacles: Annotated[ObstacleList, Meta(description="what the arm can touch in this run")] = []
    until_stopped: Annotated[
        bool, Meta(description="a run until stopped (Run.until_stopped): settings.stop_time is its bound")
    ] = False
    fast_until: Annotated[
        float,
        Meta(
            ge=0.0,
            description="s of simulated time run as fast as possible before the settings' pacing takes "
            "over: a run continued after a crash (`continue`) catches up to where it had come",
        ),
    ] = 0.0


class Accepted(Record):
    """Reply data of a RunRequest: who took the run."""

    simulator: Name
    pid: int


class RunControl(Message, tag="run_control"):
    op: Literal["pause", "resume", "stop", "abort", "seek"]
    run_id: Name
    time: Annotated[Seconds, Meta(description="seek target in s (replay runs)")] = 0.0
    attempt: Annotated[int, Meta(ge=0, description="the run's attempt it is for; 0 = whichever")] = 0


class RunStatus(Message, tag="run_status"):
    """A worker's report on <session>/run; the proxy turns it into SessionState."""

    session: SessionId
    run_id: Name
    phase: WorkerPhase
    sim_time: Annotated[float, Meta(ge=0.0)] = 0.0
    stop_time: Annotated[float, Meta(ge=0.0)] = 0.0
    rtf: Annotated[float, Meta(ge=0.0)] = 0.0
    samples: Annotated[int, Meta(ge=0)] = 0
    reason: Text = ""
    step: Annotated[Text, Meta(description="the running step (PlanStep.step)")] = ""
    task: Annotated[str, Meta(max_length=64)] = ""
    action: Annotated[str, Meta(max_length=64)] = ""
    hil: HilStats | None = None
    attempt: Annotated[
        int, Meta(ge=1, description="the attempt of the run reporting (RunRequest.attempt)")
    ] = 1
    jogged_s: Annotated[float, Meta(ge=0.0, description="simulated s jogged so far (RunInfo.jogged_s)")] = 0.0


class RunContext(Record):
    """What produced a run, carried with it (the recorder keeps it as the file's metadata)."""

    user: Name
    values: dict[Name, float]
    initial: Numbers
    command: RobotCommand | None
    settings: RunSettings
    recording: Annotated[str, Meta(max_length=64, description="replay runs: the recording replayed")] = ""
    attempt: Annotated[
        int, Meta(ge=1, description="2+: restarted from the start after its host was lost")
    ] = 1
    restarted: Annotated[Text, Meta(description="attempt 2+: why the run started again")] = ""
    obstacles: Annotated[ObstacleList, Meta(description="what the arm could touch in the run")] = []
    until_stopped: Annotated[
        bool,
        Meta(description="a run until stopped (Run.until_stopped): settings.stop_time was its bound"),
    ] = False


class RunLayout(Message, tag="layout"):
    """Announced once per run on <session>/vars/layout, before the first frame."""

    session: SessionId
    run_id: Name
    run_index: Annotated[int, Meta(ge=0, le=2**32 - 1, description="carried in every frame header")]
    model_id: Name
    columns: Annotated[list[Text], Meta(min_length=1, description='"time" first; every column a float64')]
    units: list[Text]
    live_columns: Annotated[
        list[Text], Meta(min_length=1, description='"time" first: forwarded on vars/live')
    ]
    live_rate_hz: Annotated[float, Meta(ge=0.1, le=1000.0)]
    stop_time: Annotated[float, Meta(ge=0.0)]
    output_interval: Annotated[float, Meta(ge=0.0)]
    context: RunContext
    source: Annotated[
        Literal["simulator", "replay"],
        Meta(description="replay: frames from a recording (not recorded again)"),
    ] = "simulator"


class Notice(Message, tag="notice"):
    """Something the user must know about a run that is not a failure of it, e.g. the recorder had to
    drop samples. Put on <session>/notices; the proxy lists it in SessionState.warnings."""

    session: SessionId
    run_id: Name
    source: Name
    message: Text


#: s a jog velocity holds without a new message (the deadman): then the jog stops.
JOG_DEADMAN_S = 0.25


class JogInput(Message, tag="jog"):
    """Live jogging of a running run (telemanipulation): a velocity superposed on the command, held
    until the next message or for JOG_DEADMAN_S; send it every 0.1 s or faster while the user holds a
    jog button, and a zero velocity (or nothing) to stop."""

    run_id: Annotated[Name, Meta(description="the run to jog; other runs ignore the message")]
    space: Literal["joint", "cartesian"] = "joint"
    qd: Annotated[Numbers, Meta(description="joint: rad/s, one per joint (load side)")] = []
    twist: Annotated[
        list[float],
        Meta(
            max_length=6,
            description="cartesian: vx, vy, vz (m/s), wx, wy, wz (rad/s) of the tool, world frame",
        ),
    ] = []
    speed_pct: Annotated[
        float, Meta(gt=0.0, le=100.0, description="cap: percent of each joint's traj.max_speed")
    ] = 100.0


# -- nodes and recordings ------------------------------------------------------------------------------
class RunLoad(Record):
    """One run a simulator host carries (SimulatorLoad.runs)."""

    session: SessionId
    run_id: Name
    model_id: Name
    demand: Annotated[float, Meta(ge=0.0, le=1.0, description="cores it needs at its pacing (LAN.md)")]
    cpu: Annotated[float, Meta(ge=0.0, description="cores its worker used over the last seconds")] = 0.0
    rtf: Annotated[
        float, Meta(ge=0.0, description="simulated s per wall s, its worker's last 1 s window")
    ] = 0.0
    behind: Annotated[bool, Meta(description="paced, and slower than its pace for longer than the grace")] = (
        False
    )


class SimulatorLoad(Record):
    """What a simulator host can carry and carries now: the proxy admits and places runs by it."""

    cores: Annotated[float, Meta(ge=0.0, description="CPU cores the host's runs may use")]
    capacity: Annotated[
        float, Meta(ge=0.0, description="cores offered to runs: cores x headroom - other processes' use")
    ]
    demand: Annotated[float, Meta(ge=0.0, description="sum of its runs' demand")] = 0.0
    runs: Annotated[list[RunLoad], Meta(max_length=10_000)] = []
    cost: Annotated[
        dict[Name, float],
        Meta(description="measured CPU s per simulated s of a paced run, by model: its demand's base"),
    ] = {}
    fast_cost: Annotated[
        dict[Name, float],
        Meta(description="measured CPU s per simulated s of a run as fast as possible, by model (1/its RTF)"),
    ] = {}
    models: Annotated[list[Name], Meta(max_length=10_000, description="the models it can run")] = []
    memory_free_mb: Annotated[float, Meta(ge=0.0)] = 0.0
    worker_mb: Annotated[float, Meta(ge=0.0, description="memory one more run takes")] = 0.0
    max_runs: Annotated[int, Meta(ge=0, description="a configured ceiling of runs; 0 = none")] = 0
    behind: Annotated[int, Meta(ge=0, description="runs falling behind: no new run goes here meanwhile")] = 0
    start_s: Annotated[
        float, Meta(ge=0.0, description="measured s from hand-over to a warm worker to the run's first step")
    ] = 0.0
    cold_start_s: Annotated[
        float,
        Meta(
            ge=0.0, description="measured s a new worker takes to warm up: a run finding none warm waits this"
        ),
    ] = 0.0
    warm: Annotated[
        int, Meta(ge=0, description="idle workers ready: a run starts on one in milliseconds")
    ] = 0
    starting: Annotated[int, Meta(ge=0, description="runs handed over that have not stepped yet")] = 0


class NodeStatus(Message, tag="node_status"):
    role: Name
    node_id: Name
    pid: int
    host: Text
    state: Literal["starting", "ready", "stopping"]
    detail: dict[str, Any] = {}
    load: Annotated[SimulatorLoad | None, Meta(description="simulators: capacity and load")] = None


class RecordingInfo(Record):
    name: Name
    session: Annotated[str, Meta(max_length=64)]
    run_id: Annotated[str, Meta(max_length=64)]
    model_id: Annotated[str, Meta(max_length=64)]
    bytes: Annotated[int, Meta(ge=0)]
    recovered: bool = False
    stop_time: Annotated[float, Meta(ge=0.0, description="s, as the run was set")] = 0.0
    created: Annotated[
        str,
        Meta(
            max_length=32,
            description="when it was made, UTC ISO 8601 (2026-11-27T16:18:42Z): its run's start, "
            "else the file's last change",
        ),
    ] = ""


class RecordingList(Message, tag="recordings"):
    recordings: list[RecordingInfo]
    used_bytes: Annotated[int, Meta(ge=0, description="what the user's recordings take on the server")] = 0
    quota_bytes: Annotated[
        int, Meta(ge=0, description="the most they may take (recordings_bytes_per_user)")
    ] = 0


class ResultsAttachment(Record):
    """The attachment of a results reply: what the frame's columns are, and the run they come from."""

    columns: list[Text]
    units: list[Text]
    run: RunInfo
    context: Annotated[
        RunContext | None,
        Meta(
            description="what produced the run (its parameter values, initial pose, command, settings, "
            "obstacles), for comparing runs; null only for results kept from before it was stored"
        ),
    ] = None


#: Reply `data` of every command and request (the schema and the client use it).
REPLIES: dict[type, Any] = {
    SetParams: dict[str, float],
    ResetParams: dict[str, float],
    SetInitial: list[float],
    SetCommand: CommandPlan,
    SetSettings: RunSettings,
    SetObstacles: ObstacleList,
    Run: RunStarted,
    Replay: RunStarted,
    Continue: RunStarted,
    Pause: str,
    Resume: str,
    Abort: str,
    Stop: str,
    Seek: str,
    SaveParamSet: str,
    LoadParamSet: dict[str, float],
    DeleteParamSet: str,
    ListParamSets: list[str],
    SaveProgram: str,
    LoadProgram: Program,
    DeleteProgram: str,
    ListPrograms: list[ProgramEntry],
    GetSession: SessionSnapshot,
    CloseSession: str,
    CreateSession: SessionSnapshot,
    ListSessions: list[SessionEntry],
}
