"""Fuzzing every key (issue 14): a client without the service key sends a few thousand seeded, hostile
messages (testing/fuzz.py) while one user's runs go on and another's run is finished. Nothing may be
answered `internal`, no node may die, no other session's state, results or recording may change, and
the service must still run a new user's run afterwards.

SIMECS_FUZZ_SEED and SIMECS_FUZZ_COUNT choose another seed or length (a problem found with one seed is
found again with it)."""

from __future__ import annotations

import hashlib
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh.client import MeshClient, SessionClient
from simecs.mesh.process.config import MeshConfig
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.recording import mcapread
from simecs.testing.fuzz import FuzzReport, FuzzTargets, Victim, fuzz

from .conftest import Mesh, start_service
from .test_recorder_support import wait_file_closed
from .test_resilience import prepared

SEED = int(os.environ.get("SIMECS_FUZZ_SEED", "1"))
COUNT = int(os.environ.get("SIMECS_FUZZ_COUNT", "3000"))
DEADLINE_S = 50.0
SHOWN = 20  # offending requests printed per kind of problem
BYSTANDER_STOP_S = 0.6  # each of the bystander's runs, in real time
BYSTANDER_RUNS = 8  # at most, one after the other while the fuzz goes on
FINAL = ["finished", "failed", "aborted"]
CLOSE_WAIT_S = 20.0  # for the recorder to close the bystander's files, all together


class Bystander(threading.Thread):
    """A user who runs short real-time runs one after the other while the fuzz goes on: every run
    start is a moment the fuzz may hit (a run id is predictable)."""

    def __init__(self, s: SessionClient) -> None:
        super().__init__(name="bystander", daemon=True)
        self.s = s
        self.runs: list[str] = []
        self.ends: list[m.SessionState] = []
        self.error = ""
        self.done = threading.Event()
        self.started = threading.Event()

    def run(self) -> None:
        try:
            while not self.done.is_set() and len(self.runs) < BYSTANDER_RUNS:
                self.runs.append(self.s.run())
                self.started.set()
                self.ends.append(self.s.wait_for(FINAL, 30, self.runs[-1]))
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.started.set()


def recording_path(mesh: Mesh, s: SessionClient, run_id: str) -> Path:
    return mesh.folder / "rec" / s.user / f"{keys.recording_name(s.id, run_id)}.mcap"


def look(mesh: Mesh, s: SessionClient, run_id: str) -> dict[str, Any]:
    """Everything of a session another peer must not change: state, values, runs, results, recording."""
    path = recording_path(mesh, s, run_id)
    wait_file_closed(path, timeout=40.0)
    rec = mcapread.load(path)
    columns, rows = s.results(run_id)
    return {
        "snapshot": s.snapshot(),
        "runs": s.runs(),
        "results": (columns, rows.tobytes()),
        "recording file": hashlib.sha256(path.read_bytes()).hexdigest(),
        "recording rows": rec.rows.tobytes(),
        "recording metadata": rec.metadata,
        "recordings of the user": s.client.recordings(s.user),
        "parameter sets": s.list_param_sets(),
    }


def listed(title: str, entries: list[tuple[str, str, str]]) -> str:
    shown = "\n".join(f"  key {k}\n    request {q}\n    reply   {r}" for k, q, r in entries[:SHOWN])
    return f"{title} ({len(entries)}, first {min(len(entries), SHOWN)}):\n{shown}"


def answer_problems(report: FuzzReport) -> list[str]:
    problems = []
    if report.internal:
        problems.append(listed("requests answered `internal`", report.internal))
    if report.malformed:
        problems.append(listed("error replies that are no Error (§4)", report.malformed))
    if report.timeouts:
        problems.append(listed("requests not answered within the query timeout", report.timeouts))
    if report.multiple:
        problems.append(
            listed("requests answered more than once (§3: one answer per query)", report.multiple)
        )
    if report.out_of_time or report.sent < COUNT:
        problems.append(f"the fuzz sent only {report.sent} of {COUNT} messages within {DEADLINE_S} s")
    return problems


def test_fuzzing_every_key_changes_nothing(mesh: Mesh) -> None:
    start_service(mesh)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    client = mesh.client()
    width = len(client.describe("spider").variables) + 1

    # The victim: a finished run, looked at before and after.
    ann = prepared(client, "ann", 1.0, "fast")
    ann_run = ann.run()
    assert ann.wait_for(FINAL, 60, ann_run).phase == "finished"
    before = look(mesh, ann, ann_run)
    # A bystander whose runs go on while the fuzz does.
    bea = prepared(client, "bea", BYSTANDER_STOP_S, "realtime")
    bystander = Bystander(bea)
    nodes = tuple(client.live_nodes())
    problems: list[str] = []
    # A plain client of the same hub: no service key (MeshConfig without service_key_file).
    with MeshClient.open(MeshConfig(connect=[mesh.endpoint])) as attacker:
        assert attacker.seal is None
        own = tuple(attacker.create_session("mallory", "spider").id for _ in range(2))
        published: list[Any] = []
        with ann.watch(on_state=published.append, on_params=published.append, on_layout=published.append):
            bystander.start()
            bystander.started.wait(30)
            targets = FuzzTargets(
                attacker_user="mallory",
                attacker_sessions=own,
                victim_user="ann",
                victim_session=ann.id,
                victim_run_id=ann_run,
                victim_run_index=int(ann_run[1:]),
                width=width,
                simulators=tuple(node for role, node in nodes if role == "simulator"),
                nodes=nodes,
                bystanders=(Victim("bea", bea.id, "r1", 1),),
                mcap=recording_path(mesh, ann, ann_run).read_bytes(),
            )
            try:
                report = fuzz(attacker.z, targets, seed=SEED, count=COUNT, deadline_s=DEADLINE_S)
            finally:
                bystander.done.set()
                bystander.join(40)
            print(f"fuzz seed {SEED}: {report.summary()}")
            print("runs in the attacker's sessions:", *report.own_runs, sep="\n  ")
            time.sleep(0.5)  # anything the last messages could still cause
    problems += answer_problems(report)

    dead = {name: proc.returncode for name, proc in mesh.procs.items() if proc.poll() is not None}
    for name, code in dead.items():
        problems.append(f"node {name} died (exit code {code}); its log ends:\n{mesh.log(name)[-1500:]}")
    live = client.live_nodes(timeout=2.0)
    missing = [node for node in nodes if node not in live]
    if missing:
        problems.append(f"nodes no longer live after the fuzz: {missing}")

    # The victim's session, results and recording are as they were.
    after = look(mesh, ann, ann_run)
    for what in before:
        if before[what] != after[what]:
            problems.append(
                f"victim's {what} changed:\n  before {before[what]!r:.600}\n  after  {after[what]!r:.600}"
            )
    state, values = before["snapshot"].state, before["snapshot"].values
    for sample in published:  # the latched values, sent again unchanged at most
        unchanged = (
            sample == state
            if isinstance(sample, m.SessionState)
            else sample.values == values
            if isinstance(sample, m.ParamValues)
            else sample.run_id == ann_run
        )
        if not unchanged:
            problems.append(f"the service published on the victim's session during the fuzz: {sample!r:.600}")

    # The bystander's runs ended as if nothing had happened.
    if bystander.error or not bystander.ends:
        problems.append(f"the bystander could not run: {bystander.error or 'no run ended'}")
    close_by = time.monotonic() + CLOSE_WAIT_S
    for run_id, end in zip(bystander.runs, bystander.ends, strict=False):
        problems += bystander_problems(mesh, bea, run_id, end, close_by)

    # The service still serves a new user.
    try:
        carl = prepared(client, "carl", 0.2, "fast")
        carl_run = carl.run()
        phase = carl.wait_for(FINAL, 60, carl_run).phase
        if phase != "finished":
            problems.append(f"a fresh run after the fuzz ended {phase}")
    except Exception as exc:
        problems.append(f"a fresh run after the fuzz could not be made: {type(exc).__name__}: {exc}")

    assert not problems, f"fuzz seed {SEED}: {report.summary()}\n\n" + "\n\n".join(problems)


def bystander_problems(
    mesh: Mesh, s: SessionClient, run_id: str, end: m.SessionState, close_by: float
) -> list[str]:
    """A run of the bystander is what it would have been without the fuzz."""
    if end.phase != "finished" or end.sim_time != BYSTANDER_STOP_S or end.warnings:
        return [f"the bystander's run {run_id} did not finish untouched: {end!r:.600}"]
    problems = []
    _columns, rows = s.results(run_id)
    samples = round(BYSTANDER_STOP_S / 0.002) + 1
    if rows.shape[0] != samples or not np.all(np.diff(rows[:, 0]) > 0) or 7.0 in rows[:5, 1:]:
        problems.append(f"the bystander's run {run_id} has results not its own: {rows.shape} rows")
    path = recording_path(mesh, s, run_id)
    try:
        wait_file_closed(path, timeout=max(0.5, close_by - time.monotonic()))
    except TimeoutError:
        return [*problems, f"the recording of the bystander's run {run_id} was not closed ({path.name})"]
    rec = mcapread.load(path)
    if not np.array_equal(rec.rows, rows) or rec.metadata["simecs.end"]["gaps"] != "0":
        end_meta = rec.metadata.get("simecs.end")
        problems.append(f"the recording of the bystander's run {run_id} is not its results: {end_meta}")
    return problems
