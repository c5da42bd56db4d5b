"""What travels between the proxy, a simulator host and a run's worker, and what a run announces: the
request that starts a run, its control and status, its layout and notices, and live jogging."""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta

from .environment import ObstacleList
from .phases import WorkerPhase
from .primitives import Message, Name, Numbers, Record, SessionId, Text
from .robot_commands import RobotCommand, Seconds
from .run_settings import RunSettings
from .session_state import HilStats


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


#: s between two progress reports of a running run's worker. At most 5 a second: each costs a put, a
#: routing in the hub and a state the proxy publishes in turn (the proxy's part alone about 0.09 ms of
#: CPU, measured with 27 runs); a step of the command that begins is reported at once, however short.
#: The proxy relies on it to tell a live worker from a lost one (nodes/runs.py).
RUNNING_REPORT_S = 0.2


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
