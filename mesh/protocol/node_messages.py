"""What nodes say about themselves (a simulator host's capacity and load) and the recordings and results
a user can list and load."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from msgspec import Meta

from .primitives import Message, Name, Record, SessionId, Text
from .run_messages import RunContext
from .session_state import RunInfo


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
