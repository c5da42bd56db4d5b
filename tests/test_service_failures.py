"""The simulation service when its parts fail or refuse: a killed worker or simulator node, a simulator
that does not answer, an abort during a hand-over, admission's queue, a proxy restart during a run."""

from __future__ import annotations

import os
import re
import signal
import threading
import time

import numpy as np
import pytest
from simecs.mesh.client import NoReply, RemoteError, SessionClient
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.runs import WORKER_REPORTS_S

from .conftest import Mesh, Service, children, start_service, wait_until, worker_forks_of, worker_pids
from .test_service import prepare

HOST_WAIT_S = 10.0  # the proxy's --host-wait-s in the test that waits it out (30 s by default)

TARGET = [0.3, -0.2, 0.2, 0.1, -0.1, 0.1, 0.0]


def worker_of(service: Service, sid: str, run_id: str) -> int:
    """The pid of the worker the simulator handed this run to, from its own log line (CPU use cannot
    tell a realtime-paced run from a warm idle worker on a busy machine)."""
    line = re.compile(rf"run {re.escape(sid)}/{re.escape(run_id)} handed to (?:warm|cold) worker pid (\d+)")
    hit = wait_until(
        lambda: line.search(service.mesh.log("simulator")), timeout=30, what=f"the worker of {run_id}"
    )
    return int(hit.group(1))


def results_or_none(s: SessionClient, run_id: str) -> tuple[list[str], np.ndarray] | None:
    try:
        return s.results(run_id)
    except (RemoteError, NoReply):  # not stored yet
        return None


def test_killed_simulation_fails_its_session_within_a_second(service: Service) -> None:
    c = service.client
    sim_pid = service.mesh.procs["simulator"].pid
    a = c.create_session("ann", "spider")
    b = c.create_session("bob", "spider")
    prepare(a, stop_time=5.0, pacing="realtime")
    prepare(b, stop_time=1.5, pacing="realtime")
    ra = a.run()
    a.wait_for(["running"], 30, ra)
    victim = worker_of(service, a.id, ra)
    assert victim in worker_pids(sim_pid)
    rb = b.run()
    b.wait_for(["running"], 30, rb)
    wait_until(lambda: a.snapshot().state.sim_time > 0.2, timeout=30, what="run a under way")
    failed = threading.Event()
    seen: list[m.SessionState] = []

    def on_state(st: m.SessionState) -> None:
        seen.append(st)
        if st.phase == "failed":
            failed.set()

    with a.watch(on_state=on_state):
        time.sleep(0.3)
        t0 = time.monotonic()
        os.kill(victim, signal.SIGKILL)
        assert failed.wait(5.0), service.mesh.log("proxy") + service.mesh.log("simulator")
        assert time.monotonic() - t0 < 1.0
    assert "disappeared" in seen[-1].reason
    # what its worker computed is kept: the results end where the worker was killed (issue 33, 1)
    reached = max(st.sim_time for st in seen if st.run_id == ra)
    _columns, rows = wait_until(lambda: results_or_none(a, ra), timeout=10, what="the results it left")
    assert rows.shape[0] > 100 and reached - 0.3 <= rows[-1, 0] < 5.0, (rows[-1, 0], reached)
    assert np.all(np.diff(rows[:, 0]) > 0)  # whole rows, in order
    assert b.wait_for(["finished", "failed"], 60, rb).phase == "finished"
    assert c.live_nodes().count(("simulator", "simulator-t")) == 1
    # the partial files are gone: one turned into a's results, the other replaced by b's stored results
    assert not list((service.data_dir / "results").rglob(".*.partial*"))

    # the failed run goes on from where its results end: the same inputs, fast up to there, then in real
    # time; its results are the whole run, the first part the same samples (issue 33, 1)
    a.set_settings(stop_time=0.5)  # what the session says now is not what the run was made of
    with pytest.raises(RemoteError) as refused:
        b.continue_run(rb)
    assert refused.value.code == "conflict" and "it finished" in str(refused.value)
    rc = a.continue_run(ra)
    end = a.wait_for(["finished", "failed", "aborted"], 60, rc)
    assert end.phase == "finished" and end.sim_time == pytest.approx(5.0), end.reason
    _columns, whole = a.results(rc)
    assert whole[-1, 0] == pytest.approx(5.0) and np.all(np.diff(whole[:, 0]) > 0)
    assert np.array_equal(whole[: rows.shape[0]], rows)  # deterministic: where the crash left it
    assert "continues run r1" in service.mesh.log("proxy")


def test_runs_go_on_when_the_worker_fork_server_is_lost(service: Service) -> None:
    """Workers are forked warm from one process (nodes/worker_forks.py): killed, it costs no run; the
    simulator says so and starts each new worker as a process of its own."""
    sim_pid = service.mesh.procs["simulator"].pid
    s = service.client.create_session("ann", "spider")
    prepare(s, stop_time=0.3)
    first = s.run()
    assert s.wait_for(["finished", "failed"], 60, first).phase == "finished"
    assert worker_of(service, s.id, first) not in {pid for pid, _ in children(sim_pid)}  # a fork's
    forks = worker_forks_of(sim_pid)
    assert len(forks) == 1
    os.kill(forks[0], signal.SIGKILL)
    gone = "worker fork server is gone"
    wait_until(lambda: gone in service.mesh.log("simulator"), 10, what="the fork server's loss seen")
    for _ in range(3):  # the warm workers forked before, then workers of their own
        run_id = s.run()
        end = s.wait_for(["finished", "failed"], 120, run_id)
        assert end.phase == "finished", end.reason
    assert worker_of(service, s.id, run_id) in {pid for pid, _ in children(sim_pid)}


def test_a_simulator_that_does_not_answer_holds_up_no_other_session(service: Service) -> None:
    """The proxy hands a run to a simulator without holding its lock: a stopped simulator (it
    answers after its lease ran out, if ever) delays only that run, never other commands."""
    c = service.client
    a = c.create_session("ann", "spider")
    b = c.create_session("bob", "spider")
    prepare(a)
    sim = service.mesh.procs["simulator"]
    os.kill(sim.pid, signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        reply = a.command(m.Run())
        took_run = time.monotonic() - t0
        t0 = time.monotonic()
        b.set_params({"joint2.ctrl.kp_pos": 33.0})
        took_other = time.monotonic() - t0
        assert reply.phase == "queued"
        assert took_run < 0.5 and took_other < 0.5, (took_run, took_other)
        with pytest.raises(RemoteError) as err:
            a.run()
        assert err.value.code == "conflict"
        state = a.wait_for(["failed", "running"], 30, reply.run_id)
        assert state.phase == "failed" and "simulator" in state.reason, state
    finally:
        os.kill(sim.pid, signal.SIGCONT)


def test_abort_while_a_run_is_being_handed_over_stops_it(service: Service) -> None:
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=5.0, pacing="realtime")
    reports: list[m.RunStatus] = []
    sub = c.z.declare_subscriber(
        keys.run_status(s.user, s.id),
        lambda smp: reports.append(codec.loads(m.RunStatus, smp.payload.to_bytes())),
    )
    sim = service.mesh.procs["simulator"]
    os.kill(sim.pid, signal.SIGSTOP)  # the hand-over waits for it (within its 1 s lease)
    try:
        run_id = s.run()
        s.abort()
        state = s.snapshot().state
        assert state.phase == "aborted" and "handed" in state.reason, state
    finally:
        os.kill(sim.pid, signal.SIGCONT)
    # The simulator then takes the run; the proxy stops it at once.
    ended = wait_until(
        lambda: [r for r in reports if r.run_id == run_id and r.phase == "aborted"],
        timeout=20,
        what="the worker to abort the run",
    )
    assert ended[-1].sim_time < 2.0
    sub.undeclare()
    assert s.snapshot().state.phase == "aborted"
    # The session is usable again.
    again = s.run()
    assert s.wait_for(["running", "finished"], 30, again).phase in ("running", "finished")


def test_admission_queues_and_refuses(mesh: Mesh) -> None:
    mesh.start("proxy", "--data-dir", str(mesh.folder / "d"), "--max-running", "1", "--max-queue", "1")
    mesh.start("simulator", "--results-dir", str(mesh.folder / "d" / "results"))
    c = mesh.client()
    sessions = [c.create_session(f"u{i}", "spider") for i in range(3)]
    for i, s in enumerate(sessions):
        prepare(s, stop_time=1.0 if i == 0 else 0.2, pacing="realtime")
    r0 = sessions[0].run()
    sessions[0].wait_for(["running"], 30, r0)
    reply = sessions[1].command(m.Run())
    assert reply.phase == "queued" and reply.queue_position == 1
    with pytest.raises(RemoteError) as err:
        sessions[2].run()
    assert err.value.code == "busy" and "run_queue = 1" in err.value.error.message
    assert "abort one of yours" in err.value.error.message  # how a place frees
    assert sessions[1].snapshot().state.phase == "queued"
    assert sessions[0].wait_for(["finished"], 60, r0).phase == "finished"
    assert sessions[1].wait_for(["finished"], 60, reply.run_id).phase == "finished"


def test_proxy_restart_during_a_run_loses_nothing(mesh: Mesh) -> None:
    svc = start_service(mesh)
    c = svc.client
    a = c.create_session("ann", "spider")
    b = c.create_session("bob", "spider")
    prepare(a, stop_time=0.6, pacing="realtime")
    prepare(b, stop_time=3.0, pacing="realtime")
    ra, rb = a.run(), b.run()
    wait_until(lambda: b.snapshot().state.sim_time > 0.1, timeout=30, what="runs under way")
    mesh.stop("proxy", signal.SIGKILL)
    # what a kill in the middle of a write leaves (files.atomic_write): gone when the proxy is back
    leftover = svc.data_dir / "sessions" / f".{a.id}.json.x1y2.tmp"
    leftover.write_text('{"half": ')
    time.sleep(1.0)  # run a ends while the proxy is down; run b goes on
    mesh.start("proxy", "--data-dir", str(svc.data_dir), name="proxy2")
    assert not leftover.exists() and "removed 1 temporary files" in mesh.log("proxy2")
    state_a = a.snapshot().state
    assert (state_a.run_id, state_a.phase, state_a.sim_time) == (ra, "finished", pytest.approx(0.6))
    assert b.wait_for(["finished", "failed"], 60, rb).phase == "finished"


def running(pid: int) -> bool:
    """The process is there and not a zombie (an orphan may wait for a reaper)."""
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_simulator_node_killed_alone_costs_no_run(service: Service) -> None:
    """The simulator node killed alone (its worker lives on) while its run is paused, longer paused
    than a worker's report interval: the run goes on in its worker, is resumed and finishes; the node,
    started again, serves its full results; the session never shows it failed or restarted (issue 33,
    1: simulator_crash_runs_lost 0)."""
    c = service.client
    sim_pid = service.mesh.procs["simulator"].pid
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=2.0, pacing="realtime")
    run_id = s.run()
    s.wait_for(["running"], 30, run_id)
    worker = worker_of(service, s.id, run_id)
    wait_until(lambda: s.snapshot().state.sim_time > 0.3, timeout=30, what="the run under way")
    seen: list[m.SessionState] = []
    with s.watch(on_state=lambda st: seen.append(st) if st.run_id == run_id else None):
        s.pause()
        s.wait_for(["paused"], 10, run_id)
        time.sleep(WORKER_REPORTS_S + 0.5)  # paused: the worker says it lives all the same
        os.kill(sim_pid, signal.SIGKILL)  # the node alone: its worker goes on
        lost = "simulator host simulator-t left"
        wait_until(lambda: lost in service.mesh.log("proxy"), 10, what="the node's loss seen")
        time.sleep(1.0)
        st = s.snapshot().state
        assert (st.phase, st.attempt, st.host) == ("paused", 1, "simulator-t"), service.mesh.log("proxy")
        assert running(worker)
        service.mesh.start("simulator", "--results-dir", str(service.data_dir / "results"))
        s.resume()
        end = s.wait_for(["finished", "failed", "aborted"], 60, run_id)
    assert end.phase == "finished" and end.attempt == 1, end.reason
    assert not [st for st in seen if st.phase in ("failed", "queued")], [st.phase for st in seen]
    _columns, rows = wait_until(lambda: results_or_none(s, run_id), timeout=30, what="its results")
    assert rows.shape[0] == 1001 and rows[-1, 0] == pytest.approx(2.0)  # whole: 0..2 s every 2 ms
    wait_until(lambda: not running(worker), timeout=10, what="the worker ended")


def test_a_run_asked_for_while_the_simulator_node_is_away_waits_for_it(mesh: Mesh) -> None:
    """A run asked for while no simulator host is on the mesh (its node restarting, or its link cut
    for longer than the lease by a starved CPU) waits for one and runs; only when none comes back
    within the wait (--host-wait-s: 10 s here, 30 by default) does it fail, saying why."""
    service = start_service(mesh, extra_proxy=("--host-wait-s", str(HOST_WAIT_S)))
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s)
    lost = "simulator host simulator-t left"
    service.mesh.stop("simulator", signal.SIGKILL)
    wait_until(lambda: service.mesh.log("proxy").count(lost) == 1, 10, what="the node's loss seen")
    run_id = s.run()
    assert s.snapshot().state.phase == "queued"
    time.sleep(2.0)
    assert s.snapshot().state.phase == "queued"  # not failed: the host may be back in a moment
    service.mesh.start("simulator", "--results-dir", str(service.data_dir / "results"))
    end = s.wait_for(["finished", "failed", "aborted"], 60, run_id)
    assert end.phase == "finished", end.reason
    service.mesh.stop("simulator", signal.SIGKILL)
    wait_until(lambda: service.mesh.log("proxy").count(lost) == 2, 10, what="the node's second loss seen")
    run_id = s.run()
    asked = time.monotonic()
    end = s.wait_for(["failed"], HOST_WAIT_S + 10, run_id)
    assert end.reason == "no simulator node is on the mesh", end.reason
    assert time.monotonic() - asked > HOST_WAIT_S - 3.0  # it waited, from the loss seen
