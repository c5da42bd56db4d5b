"""Session phases and what moves a session between them: one table that the proxy enforces, the
viewer uses to enable its buttons, and the tests and PROTOCOL.md read.

    created --edit--> configured --run/replay--> queued --started--> running <--> paused
    queued/running/paused --finished|aborted|failed--> that phase --run/replay--> queued ...
    running/paused --stop--> finished (results kept), --abort--> aborted
    running/paused --restarted (its host lost)--> queued
    any phase --closed--> closed
"""

from __future__ import annotations

from typing import Literal, get_args

Phase = Literal[
    "created", "configured", "queued", "running", "paused", "finished", "aborted", "failed", "closed"
]
#: What a worker reports about its run on <session>/run.
WorkerPhase = Literal["starting", "running", "paused", "finished", "aborted", "failed"]

PHASES: tuple[str, ...] = get_args(Phase)
WORKER_PHASES: tuple[str, ...] = get_args(WorkerPhase)
#: A run waits for a slot or holds one.
UNDER_WAY = ("queued", "running", "paused")
#: A worker runs it.
GOING = ("running", "paused")
ENDED = ("finished", "aborted", "failed")
#: Values, pose, command and settings may change; a new run may start.
EDITABLE = ("created", "configured", "finished", "aborted", "failed")
OPEN = tuple(p for p in PHASES if p != "closed")

#: event -> {phase before: phase after}. An event not listed for a phase does not happen in it.
TRANSITIONS: dict[str, dict[str, str]] = {
    "edited": {p: ("configured" if p == "created" else p) for p in EDITABLE},
    "queued": {p: "queued" for p in EDITABLE},
    "started": {"queued": "running"},
    "restarted": {p: "queued" for p in GOING},  # its simulator host was lost: from the start elsewhere
    "paused": {"running": "paused"},
    "resumed": {"paused": "running"},
    "finished": {p: "finished" for p in UNDER_WAY},
    "aborted": {p: "aborted" for p in UNDER_WAY},
    "failed": {p: "failed" for p in UNDER_WAY},
    "closed": {p: "closed" for p in OPEN},
}

#: Command (its `op`) -> the phases it is accepted in, and what a refusal says otherwise.
_EDIT = "cannot change {what} while the run is {phase}"
ALLOWED: dict[str, tuple[tuple[str, ...], str]] = {
    "set_params": (EDITABLE, _EDIT.replace("{what}", "parameters")),
    "reset_params": (EDITABLE, _EDIT.replace("{what}", "parameters")),
    "load_param_set": (EDITABLE, _EDIT.replace("{what}", "parameters")),
    "set_initial": (EDITABLE, _EDIT.replace("{what}", "the initial pose")),
    "set_command": (EDITABLE, _EDIT.replace("{what}", "the command")),
    "set_settings": (EDITABLE, _EDIT.replace("{what}", "the simulation settings")),
    "set_obstacles": (EDITABLE, _EDIT.replace("{what}", "the obstacles")),
    "run": (EDITABLE, "a run is already {phase} in this session"),
    "replay": (EDITABLE, "a run is already {phase} in this session"),
    "continue": (EDITABLE, "a run is already {phase} in this session"),
    "pause": (("running",), "nothing to pause: the session is {phase}"),
    "resume": (("paused",), "nothing to resume: the session is {phase}"),
    "stop": (GOING, "nothing to stop: the session is {phase}"),
    "abort": (UNDER_WAY, "nothing to abort: the session is {phase}"),
    "seek": (GOING, "nothing to seek in: the session is {phase}"),
    "save_param_set": (OPEN, ""),
    "delete_param_set": (OPEN, ""),
    "list_param_sets": (OPEN, ""),
    "save_program": (OPEN, ""),
    "load_program": (OPEN, ""),
    "delete_program": (OPEN, ""),
    "list_programs": (OPEN, ""),
    "get_session": (OPEN, ""),
    "close_session": (OPEN, ""),
}


def after(phase: str, event: str) -> str:
    """The phase `event` leads to from `phase`; ValueError if it cannot happen there."""
    to = TRANSITIONS[event].get(phase)
    if to is None:
        raise ValueError(f"{event} cannot happen to a session that is {phase}")
    return to


def refusal(op: str, phase: str) -> str:
    """Why command `op` is refused in `phase` ('' when it is accepted)."""
    phases, why = ALLOWED[op]
    return "" if phase in phases else why.format(phase=phase) or f"{op} is not possible while {phase}"


def of_worker(phase: str) -> str:
    """The session phase a worker's report means ('starting' counts as running)."""
    return "running" if phase == "starting" else phase
