"""Every bound the service puts on what one peer may cost it, in one table.

A bound is a promise to every other user: one user's sessions, runs, files or hostile messages cost
the server at most this much. The nodes enforce them (their refusals name the bound: `busy` for a
quota or capacity, `bad_request` for a value too large), and PROTOCOL.md §4.1 is generated from this
table, so the document and the nodes state the same numbers. The operator may change the ones marked
with a flag.
"""

from __future__ import annotations

from dataclasses import dataclass

from .primitives import MAX_NUMBERS, MAX_TEXT

#: Runs whose full-resolution results are kept per session (the oldest go first): the proxy lists
#: these, the simulator keeps these.
RUNS_KEPT = 10

KiB = 1024
MiB = 1024 * KiB
GiB = 1024 * MiB


@dataclass(frozen=True)
class Limit:
    name: str
    value: int
    unit: str  # "bytes", "count", "s"
    enforcer: str  # the node that refuses
    refusal: str  # the error code of the refusal, or what happens instead
    meaning: str
    flag: str = ""  # the node's command-line option that changes it


_TABLE = (
    Limit("message_bytes", 4 * MiB, "bytes", "every node", "bad_request", "one JSON message (request, put)"),
    Limit("text_chars", MAX_TEXT, "count", "every node", "bad_request", "characters of one text field"),
    Limit("numbers", MAX_NUMBERS, "count", "every node", "bad_request", "entries of one list of numbers"),
    Limit(
        "samples_per_run",
        2_000_000,
        "count",
        "proxy",
        "bad_request",
        "output samples of one run (stop_time / output_interval)",
    ),
    Limit(
        "results_bytes_per_run",
        256 * MiB,
        "bytes",
        "proxy",
        "bad_request",
        "full-resolution results of one run: (samples + 1) x columns x 8 bytes",
    ),
    Limit(
        "reference_samples",
        200_000,
        "count",
        "proxy",
        "bad_request",
        "rows of one run's expanded reference (Cartesian and joint moves: where they curve or accelerate, "
        "at most one per ms; signal samples)",
    ),
    Limit(
        "programs_per_user",
        500,
        "count",
        "proxy",
        "busy",
        "saved actions, tasks and missions of one user, all models together",
    ),
    Limit("sessions", 256, "count", "proxy", "busy", "open sessions on the server", "--max-sessions"),
    Limit(
        "sessions_per_user",
        16,
        "count",
        "proxy",
        "busy",
        "open sessions of one user",
        "--max-sessions-per-user",
    ),
    Limit(
        "session_idle_s",
        7 * 24 * 3600,
        "s",
        "proxy",
        "the session is closed",
        "a session without a command or a run for this long is closed (its results go with it)",
        "--session-idle-s",
    ),
    Limit(
        "runs_per_user",
        4,
        "count",
        "proxy",
        "busy",
        "runs and replays of one user going at once (queued, running or paused)",
        "--max-runs-per-user",
    ),
    Limit("run_queue", 16, "count", "proxy", "busy", "runs waiting for a simulator", "--max-queue"),
    Limit(
        "open_run_s",
        600,
        "s",
        "proxy",
        "the run ends as finished, its reason naming the bound",
        "simulated (= wall) s a run until stopped lasts at most; less when its results would exceed "
        "results_bytes_per_run at its output_interval",
        "--open-run-s",
    ),
    Limit(
        "results_bytes_per_user",
        2 * GiB,
        "bytes",
        "proxy",
        "busy",
        f"results kept for one user's sessions (the last {RUNS_KEPT} runs of each)",
        "--max-results-mb-per-user",
    ),
    Limit(
        "param_sets_per_user",
        200,
        "count",
        "proxy",
        "busy",
        "parameter sets of one user, every model together",
    ),
    Limit(
        "upload_bytes",
        256 * MiB,
        "bytes",
        "recorder",
        "bad_request",
        "one uploaded (or downloaded) recording",
    ),
    Limit(
        "upload_chunk_bytes",
        64 * MiB,
        "bytes",
        "recorder",
        "bad_request",
        "one chunk of an uploaded recording, decompressed",
    ),
    Limit(
        "upload_decompressed_bytes",
        1 * GiB,
        "bytes",
        "recorder",
        "bad_request",
        "every chunk of an uploaded recording, decompressed",
    ),
    Limit(
        "upload_records",
        3_000_000,
        "count",
        "recorder",
        "bad_request",
        "MCAP records of one uploaded recording, every kind counted (a run of samples_per_run samples "
        "holds about as many, one /vars message each): reading each costs time and memory",
    ),
    Limit(
        "recordings_bytes_per_user",
        2 * GiB,
        "bytes",
        "recorder",
        "busy (uploads); a run is then not recorded, and its session is told",
        "recordings kept for one user",
        "--max-mb-per-user",
    ),
    Limit(
        "recorder_queue_bytes",
        256 * MiB,
        "bytes",
        "recorder",
        "frames are dropped, counted and filled from the run's results at its end",
        "frames waiting to be written, every run together",
        "--queue-mb",
    ),
)

LIMITS: dict[str, Limit] = {lim.name: lim for lim in _TABLE}


def limit(name: str) -> int:
    return LIMITS[name].value


def human(value: int, unit: str) -> str:
    """`256 MiB`, `16`, `7 d`: how refusals and the document say a bound."""
    if unit == "bytes":
        for size, suffix in ((GiB, "GiB"), (MiB, "MiB"), (KiB, "KiB")):
            if value >= size and value % size == 0:
                return f"{value // size} {suffix}"
        return f"{value} bytes"
    if unit == "s":
        for size, suffix in ((86400, "d"), (3600, "h"), (60, "min")):
            if value >= size and value % size == 0:
                return f"{value // size} {suffix}"
        return f"{value} s"
    return f"{value:,}"
