"""Session phases and what moves a session between them: one table that the proxy enforces and the
tests and PROTOCOL.md read. The phases each command is accepted in are stated with the command
(session_commands.py), from the sets named here.

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


def after(phase: str, event: str) -> str:
    """The phase `event` leads to from `phase`; ValueError if it cannot happen there."""
    to = TRANSITIONS[event].get(phase)
    if to is None:
        raise ValueError(f"{event} cannot happen to a session that is {phase}")
    return to


def of_worker(phase: str) -> str:
    """The session phase a worker's report means ('starting' counts as running)."""
    return "running" if phase == "starting" else phase
