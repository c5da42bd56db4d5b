"""Every JSON message type of the protocol, with its version.

Each message is a dataclass; `codec.loads(Type, payload)` decodes strictly and `codec.dumps(obj)`
encodes. Messages that travel alone carry `type` and `v`; unions are told apart by `op` (commands)
or `kind` (robot commands). A newer minor field is added with a default, so `v` only changes when
old clients could misread a message. docs/PROTOCOL.md lists them all with examples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

from .codec import DecodeError
from .model import ModelSummary

VERSION = 1


# -- replies ------------------------------------------------------------------------------------
@dataclass
class Error:
    """Sent with `reply_err` (or on `state`): what was wrong, and in which field."""

    code: str  # bad_request | not_found | forbidden | conflict | busy | internal | unsupported
    message: str
    field: str = ""
    type: Literal["error"] = "error"
    v: int = VERSION


@dataclass
class Ok:
    """Successful reply; `data` depends on the request (see PROTOCOL.md)."""

    data: Any = None
    type: Literal["ok"] = "ok"
    v: int = VERSION


# -- robot commands, one dataclass per level of the paper (§2.1) ---------------------------------
def _check_pct(value: float, name: str) -> None:
    if not 0.0 < value <= 100.0:
        raise DecodeError(name, f"{value} is not a percentage in (0, 100]")


@dataclass
class PathNode:
    """A via point of a joint path (PDL2 MOVE-like): destination, speed and acceleration reductions."""

    q: list[float]  # rad, one per joint
    speed_pct: float = 100.0
    acc_pct: float = 100.0

    def validate(self) -> None:
        if not self.q:
            raise DecodeError("q", "empty joint vector")
        _check_pct(self.speed_pct, "speed_pct")
        _check_pct(self.acc_pct, "acc_pct")


@dataclass
class JointPath:
    nodes: list[PathNode]
    kind: Literal["joint_path"] = "joint_path"

    def validate(self) -> None:
        if not self.nodes:
            raise DecodeError("nodes", "a path needs at least one node")
        if len(self.nodes) > 1000:
            raise DecodeError("nodes", "at most 1000 nodes")


@dataclass
class CartesianNode:
    """A straight-line tool move to a pose: position in m, orientation roll-pitch-yaw in rad."""

    position: list[float]
    rpy: list[float]
    speed_pct: float = 100.0
    acc_pct: float = 100.0

    def validate(self) -> None:
        if len(self.position) != 3 or len(self.rpy) != 3:
            raise DecodeError("position", "position and rpy need 3 numbers each")
        _check_pct(self.speed_pct, "speed_pct")
        _check_pct(self.acc_pct, "acc_pct")


@dataclass
class CartesianPath:
    nodes: list[CartesianNode]
    kind: Literal["cartesian_path"] = "cartesian_path"


@dataclass
class DirectInput:
    """Open loop: motor currents; closed loop: set points. `signals[name]` is a list of [t, value]."""

    mode: Literal["open_loop", "closed_loop"]
    signals: dict[str, list[list[float]]]
    kind: Literal["direct_input"] = "direct_input"


@dataclass
class Action:
    """A named, reusable step (e.g. 'reach', 'grasp') with numeric arguments."""

    name: str
    args: dict[str, float] = field(default_factory=dict)
    kind: Literal["action"] = "action"


@dataclass
class Task:
    name: str
    actions: list[Action]
    kind: Literal["task"] = "task"


@dataclass
class Mission:
    name: str
    tasks: list[Task]
    kind: Literal["mission"] = "mission"


RobotCommand = JointPath | CartesianPath | DirectInput | Action | Task | Mission
COMMAND_LEVELS = ("direct_input", "joint_path", "cartesian_path", "action", "task", "mission")


# -- simulation settings ------------------------------------------------------------------------
@dataclass
class RunSettings:
    """Paper §2.2 step 6. `step` 0 = the model's default; pacing 'scaled' runs at `factor` x real time."""

    stop_time: float = 5.0  # s
    output_interval: float = 0.002  # s
    step: float = 0.0  # s
    pacing: Literal["realtime", "scaled", "fast"] = "realtime"
    factor: float = 1.0
    live_rate_hz: float = 50.0
    live_vars: list[str] = field(default_factory=list)  # empty: every variable

    def validate(self) -> None:
        if not 0.0 < self.stop_time <= 3600.0:
            raise DecodeError("stop_time", f"{self.stop_time} s is outside (0, 3600] s")
        if not 1e-4 <= self.output_interval <= self.stop_time:
            raise DecodeError("output_interval", f"{self.output_interval} s is outside [1e-4 s, stop_time]")
        if self.stop_time / self.output_interval > 2_000_000:
            raise DecodeError("output_interval", "more than 2,000,000 output samples per run")
        if self.step != 0.0 and not 1e-5 <= self.step <= 0.01:
            raise DecodeError("step", f"{self.step} s is outside [1e-5, 0.01] s (0 = model default)")
        if not 0.01 <= self.factor <= 1000.0:
            raise DecodeError("factor", f"{self.factor} is outside [0.01, 1000]")
        if not 0.1 <= self.live_rate_hz <= 1000.0:
            raise DecodeError("live_rate_hz", f"{self.live_rate_hz} Hz is outside [0.1, 1000] Hz")
        if len(self.live_vars) > 10_000:
            raise DecodeError("live_vars", "too many variables")

    @property
    def speed(self) -> float:
        """Wanted real-time factor; math.inf for as fast as possible."""
        return {"realtime": 1.0, "scaled": self.factor, "fast": math.inf}[self.pacing]


# -- commands on simecs/<session>/cmd (a get with one of these as payload) ------------------------
@dataclass
class SetParams:
    values: dict[str, float]
    op: Literal["set_params"] = "set_params"
    v: int = VERSION


@dataclass
class ResetParams:
    names: list[str] = field(default_factory=list)  # empty: all
    op: Literal["reset_params"] = "reset_params"
    v: int = VERSION


@dataclass
class SetInitial:
    joints: list[float]  # rad; the robot starts at rest there
    op: Literal["set_initial"] = "set_initial"
    v: int = VERSION


@dataclass
class SetCommand:
    command: RobotCommand
    op: Literal["set_command"] = "set_command"
    v: int = VERSION


@dataclass
class SetSettings:
    settings: RunSettings
    op: Literal["set_settings"] = "set_settings"
    v: int = VERSION


@dataclass
class Run:
    """Assign the command: start a run with the session's current values, pose, command and settings."""

    op: Literal["run"] = "run"
    v: int = VERSION


@dataclass
class Pause:
    op: Literal["pause"] = "pause"
    v: int = VERSION


@dataclass
class Resume:
    op: Literal["resume"] = "resume"
    v: int = VERSION


@dataclass
class Abort:
    op: Literal["abort"] = "abort"
    v: int = VERSION


@dataclass
class SaveParamSet:
    name: str
    op: Literal["save_param_set"] = "save_param_set"
    v: int = VERSION


@dataclass
class LoadParamSet:
    name: str
    op: Literal["load_param_set"] = "load_param_set"
    v: int = VERSION


@dataclass
class DeleteParamSet:
    name: str
    op: Literal["delete_param_set"] = "delete_param_set"
    v: int = VERSION


@dataclass
class ListParamSets:
    op: Literal["list_param_sets"] = "list_param_sets"
    v: int = VERSION


@dataclass
class GetSession:
    op: Literal["get_session"] = "get_session"
    v: int = VERSION


@dataclass
class CloseSession:
    op: Literal["close_session"] = "close_session"
    v: int = VERSION


Command = (
    SetParams
    | ResetParams
    | SetInitial
    | SetCommand
    | SetSettings
    | Run
    | Pause
    | Resume
    | Abort
    | SaveParamSet
    | LoadParamSet
    | DeleteParamSet
    | ListParamSets
    | GetSession
    | CloseSession
)


# -- requests on simecs/sessions ----------------------------------------------------------------
@dataclass
class CreateSession:
    user: str
    model_id: str
    op: Literal["create"] = "create"
    v: int = VERSION


@dataclass
class ListSessions:
    user: str
    op: Literal["list"] = "list"
    v: int = VERSION


SessionRequest = CreateSession | ListSessions

# -- published state ----------------------------------------------------------------------------
Phase = Literal[
    "created", "configured", "queued", "running", "paused", "finished", "aborted", "failed", "closed"
]


@dataclass
class SessionState:
    """Lifecycle of a session on simecs/<session>/state (paper §3.2 Time Presentation)."""

    session: str
    phase: Phase
    seq: int = 0  # grows with every publication of this session's state
    run_id: str = ""
    queue_position: int = 0  # 1 = next to start; 0 when not queued
    progress: float = 0.0  # 0..1 of stop_time
    sim_time: float = 0.0  # s
    rtf: float = 0.0  # simulated seconds per wall second, over the run so far
    reason: str = ""  # why failed / aborted / refused
    warnings: list[str] = field(default_factory=list)  # notices about the current run (e.g. data dropped)
    type: Literal["state"] = "state"
    v: int = VERSION


@dataclass
class ParamValues:
    """Every parameter value of a session, published on simecs/<session>/params after each change."""

    session: str
    model_id: str
    values: dict[str, float]
    changed: list[str] = field(default_factory=list)
    type: Literal["params"] = "params"
    v: int = VERSION


@dataclass
class RunInfo:
    run_id: str
    phase: Phase
    stop_time: float
    sim_time: float
    samples: int = 0
    reason: str = ""


@dataclass
class SessionSnapshot:
    """Reply data of create / get_session: everything a client needs to restore its view."""

    session: str
    user: str
    model_id: str
    values: dict[str, float]
    initial: list[float]
    command: RobotCommand | None
    settings: RunSettings
    state: SessionState
    runs: list[RunInfo] = field(default_factory=list)
    type: Literal["session"] = "session"
    v: int = VERSION


@dataclass
class ModelList:
    models: list[ModelSummary]
    type: Literal["models"] = "models"
    v: int = VERSION


# -- proxy <-> simulator ------------------------------------------------------------------------
@dataclass
class RunRequest:
    """Everything a simulator needs for one run; sent by the proxy to simecs/simulators/<id>/run."""

    session: str
    run_id: str
    run_index: int
    model_id: str
    values: dict[str, float]
    initial: list[float]
    command: RobotCommand
    settings: RunSettings
    type: Literal["run_request"] = "run_request"
    v: int = VERSION


@dataclass
class RunControl:
    op: Literal["pause", "resume", "abort", "seek"]
    run_id: str
    time: float = 0.0  # seek target in s (replays only)
    type: Literal["run_control"] = "run_control"
    v: int = VERSION


@dataclass
class RunStatus:
    """A worker's report on simecs/<session>/run; the proxy turns it into SessionState."""

    session: str
    run_id: str
    phase: Literal["starting", "running", "paused", "finished", "aborted", "failed"]
    sim_time: float = 0.0
    stop_time: float = 0.0
    rtf: float = 0.0
    samples: int = 0
    reason: str = ""
    type: Literal["run_status"] = "run_status"
    v: int = VERSION


@dataclass
class RunLayout:
    """Announced once per run on simecs/<session>/vars/layout, before the first frame."""

    session: str
    run_id: str
    run_index: int  # the run_index carried in every frame header of this run
    model_id: str
    columns: list[str]  # "time" first; every column a float64
    units: list[str]
    live_columns: list[str]  # the subset (with "time" first) forwarded on vars/live
    live_rate_hz: float
    stop_time: float
    output_interval: float
    # Who produces the frames: a simulation, or a replay of a recording (the recorder does not
    # record replays; a viewer can say what it shows).
    source: Literal["simulator", "replay"] = "simulator"
    type: Literal["layout"] = "layout"
    v: int = VERSION


@dataclass
class Notice:
    """Something the user must know about a run that is not a failure of it, e.g. the recorder had to
    drop samples. Put on simecs/<session>/notices; the proxy lists it in SessionState.warnings."""

    session: str
    run_id: str
    source: str  # role of the node that noticed, e.g. "recorder"
    message: str
    type: Literal["notice"] = "notice"
    v: int = VERSION


@dataclass
class JogInput:
    """Reserved for live jogging (telemanipulation): joint velocity offsets in rad/s."""

    run_id: str
    qd: list[float]
    type: Literal["jog"] = "jog"
    v: int = VERSION


# -- nodes --------------------------------------------------------------------------------------
@dataclass
class NodeStatus:
    role: str
    node_id: str
    pid: int
    host: str
    state: Literal["starting", "ready", "stopping"]
    detail: dict[str, Any] = field(default_factory=dict)
    type: Literal["node_status"] = "node_status"
    v: int = VERSION


@dataclass
class RecordingInfo:
    name: str
    session: str
    run_id: str
    model_id: str
    bytes: int
    recovered: bool = False


@dataclass
class ReplayRequest:
    """Replay a recording as a session: `speed` x real time (0 = as fast as possible)."""

    speed: float = 1.0
    session: str = ""  # empty: a new session id
    paused: bool = False
    type: Literal["replay_request"] = "replay_request"
    v: int = VERSION

    def validate(self) -> None:
        if not 0.0 <= self.speed <= 1000.0:
            raise DecodeError("speed", f"{self.speed} is outside [0, 1000]")


@dataclass
class RecordingList:
    recordings: list[RecordingInfo]
    type: Literal["recordings"] = "recordings"
    v: int = VERSION
