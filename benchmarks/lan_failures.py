"""`simecs bench lan`, parts 4-8: a slow subscriber, and the recorder, a worker, the simulator node and
the hub killed during runs. lan.py says what each figure is.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from simecs.mesh.client import MeshClient, SessionClient
from simecs.mesh.process.config import MeshConfig, open_session
from simecs.mesh.protocol import frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.local_mesh import LocalMesh, clean_env, wait_until

from .lan_mesh import (
    ENDED,
    OUTPUT,
    LanMesh,
    closed_recordings,
    live_nodes,
    prepared,
    recording_matches,
    sim_time_above,
)
from .service import age_ms

SLOW_SLEEP_S = 0.2
SLOW_STOP = 6.0
CRASH_STOP, CRASH_AT = 8.0, 3.0


# -- 4. a slow subscriber ---------------------------------------------------------------------------------
def slow_main(endpoint: str, status_file: str, seconds: float) -> None:
    """The slow subscriber's process: every session's sample streams, 200 ms per sample, until SIGTERM."""
    stop = threading.Event()
    seen = [0]

    def sleepy(_sample: zenoh.Sample) -> None:
        seen[0] += 1
        if not stop.is_set():
            time.sleep(SLOW_SLEEP_S)

    def terminate(*_: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, terminate)
    z = open_session(MeshConfig(connect=[endpoint]))
    subs = [z.declare_subscriber(keys.ALL_FULL, sleepy), z.declare_subscriber(keys.ALL_LIVE, sleepy)]
    Path(status_file).write_text(json.dumps({"ready": True}))
    try:
        stop.wait(seconds)
    finally:
        stop.set()
        for sub in subs:
            sub.undeclare()
        z.close()
        Path(status_file).write_text(json.dumps({"ready": True, "seen": seen[0]}))


class LiveLatency:
    """A plain subscriber of one session's `vars/live` on the measuring host: each frame's age when it
    arrives (now - the frame's `wall_ns`), as any client of the protocol gets it."""

    def __init__(self, client: MeshClient, s: SessionClient) -> None:
        self.ms: list[float] = []
        self.sub = client.z.declare_subscriber(keys.vars_live(s.user, s.id), self.on_live)

    def on_live(self, sample: zenoh.Sample) -> None:
        self.ms.append(age_ms(frames.decode(sample.payload.to_bytes())))

    def close(self) -> list[float]:
        self.sub.undeclare()
        return self.ms


def pair_of_runs(
    client: MeshClient,
) -> tuple[m.SessionState, m.SessionState, list[m.SessionState], list[float]]:
    """slowpoke's run as fast as possible beside ann's real-time run: both ends, ann's states, and the
    ages of ann's live frames."""
    mine = prepared(client, "slowpoke", SLOW_STOP, "fast")  # floods the slow subscriber's link
    other = prepared(client, "ann", SLOW_STOP, "realtime")
    states: list[m.SessionState] = []
    live = LiveLatency(client, other)
    try:
        with other.watch(on_state=states.append):
            time.sleep(0.3)  # the subscriptions reach the hub before the first frame
            r_mine, r_other = mine.run(), other.run()
            st_other = other.wait_for(ENDED, SLOW_STOP * 5 + 30, r_other)
        st_mine = mine.wait_for(ENDED, 120, r_mine)
    finally:
        ages = live.close()
        mine.close()
        other.close()
    return st_mine, st_other, [s for s in states if s.run_id == r_other], ages


def slow_trial(mesh: LanMesh) -> dict[str, Any]:
    """The same pair of runs without the slow subscriber, with it, and without it again: ann's live
    latency with it against the two runs around it (the baseline, on the same machine and load)."""
    client = mesh.client()
    before = pair_of_runs(client)[3]
    status = mesh.folder / "slow.json"
    argv = [*mesh.hosts.prefixes["slow"], sys.executable, "-m", "simecs.benchmarks.lan"]
    argv += ["--slow-subscriber", mesh.endpoint, "--status-file", str(status), "--seconds", "120"]
    with open(mesh.folder / "slow.log", "ab") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=clean_env())
    try:
        wait_until(status.exists, 20, what="slow subscriber ready")
        st_mine, st_other, states, slowed = pair_of_runs(client)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    after = pair_of_runs(client)[3]
    running = [s.sim_time for s in states if s.phase == "running"]
    seen = json.loads(status.read_text()).get("seen", -1) if status.exists() else -1
    base_p99 = float(np.percentile(before + after, 99)) if before and after else None
    slow_p99 = float(np.percentile(slowed, 99)) if slowed else None
    return {
        "slow_subscriber_other_session_rtf": st_other.rtf,
        "slow_subscriber_failed_runs": sum(st.phase != "finished" for st in (st_mine, st_other)),
        "slow_subscriber_live_p99_ratio": round(slow_p99 / base_p99, 3) if base_p99 and slow_p99 else None,
        "slow_subscriber_live_ms_p50": round(float(np.percentile(slowed, 50)), 2) if slowed else None,
        "slow_subscriber_live_ms_p99": round(slow_p99, 2) if slow_p99 else None,
        "slow_subscriber_live_ms_max": round(max(slowed), 2) if slowed else None,
        "baseline_live_ms_p50": round(float(np.percentile(before + after, 50)), 2) if base_p99 else None,
        "baseline_live_ms_p99": round(base_p99, 2) if base_p99 else None,
        "baseline_live_ms_max": round(max(before + after), 2) if base_p99 else None,
        "slow_subscriber_live_frames": [len(before), len(slowed), len(after)],
        "slow_subscriber_fast_run_rtf": st_mine.rtf,
        "slow_subscriber_max_progress_step_s": float(np.max(np.diff([0.0, *running]))) if running else None,
        "slow_subscriber_samples_seen": seen,
    }


# -- 5. the recorder crashes ------------------------------------------------------------------------------
def recorder_crash_trial(mesh: LanMesh) -> dict[str, Any]:
    from simecs.nodes.recording import mcapread

    client = mesh.client()
    s = prepared(client, "carol", CRASH_STOP, "realtime")
    run = s.run()
    wait_until(sim_time_above(s, CRASH_AT), 30, what="run under way")
    killed_at = s.snapshot().state.sim_time
    t0 = time.monotonic()
    mesh.stop("recorder", signal.SIGKILL)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"), name="recorder2")
    restart_s = time.monotonic() - t0
    end = s.wait_for(ENDED, 60, run)
    paths = closed_recordings(mesh, s, run, 2, 45.0)
    _cols, rows = s.results(run)
    got = np.concatenate([mcapread.load(p).rows[:, 0] for p in paths])
    missing = rows[~np.isin(rows[:, 0], got), 0]
    return {
        "recorder_crash_loss_s": float(missing.size * OUTPUT),
        "recorder_crash_missing": [round(float(missing.min()), 4), round(float(missing.max()), 4)]
        if missing.size
        else [],
        "recorder_killed_at_s": round(killed_at, 3),
        "recorder_restart_s": round(restart_s, 2),
        "recorder_crash_run": end.phase,
        "recorder_crash_files": [p.name.split("_", 1)[1] for p in paths],
    }


# -- 6, 7. a worker and the simulator node die -------------------------------------------------------------
SIM_CRASH_STOP, SIM_CRASH_AT = 4.0, 1.0


def worker_of(mesh: LocalMesh, s: SessionClient, run_id: str) -> int:
    line = re.compile(rf"run {re.escape(s.id)}/{re.escape(run_id)} handed to (?:warm|cold) worker pid (\d+)")
    hit = wait_until(lambda: line.search(mesh.log("simulator")), 30, what=f"the worker of {run_id}")
    return int(hit.group(1))


def frames_after_end(s: SessionClient, run_id: str, ended: list[float], count: list[int]) -> Any:
    """Watch `s`: the time its run `run_id` was shown failed, and the live frames of it after that."""

    def on_state(st: m.SessionState) -> None:
        if st.run_id == run_id and st.phase == "failed" and not ended:
            ended.append(time.monotonic())

    def on_live(_frame: frames.Frame) -> None:  # the session has this run only
        if ended:
            count[0] += 1

    return s.watch(on_state=on_state, on_live=on_live)


def simulator_crash_trial(mesh: LanMesh) -> dict[str, Any]:
    """Two users' real-time runs; their simulator node killed alone (SIGKILL: its workers live on) and
    started again at once under the same name, as `make up`'s supervisor does."""
    client = mesh.client()
    sessions = [prepared(client, user, SIM_CRASH_STOP, "realtime") for user in ("fay", "gus")]
    runs = {s.user: s.run() for s in sessions}
    for s in sessions:
        wait_until(sim_time_above(s, SIM_CRASH_AT), 30, what="runs under way")
    joined = mesh.log("proxy").count("simulator host simulator-t joined")
    os.kill(mesh.procs["simulator"].pid, signal.SIGKILL)
    mesh.start("simulator", "--results-dir", str(mesh.folder / "data" / "results"), "--warm", "2")
    ends = {s.user: s.wait_for(ENDED, 60, runs[s.user]) for s in sessions}

    # the next trial's runs need the host back: the proxy says when it has it again
    def back() -> bool:
        return mesh.log("proxy").count("simulator host simulator-t joined") > joined

    wait_until(back, 60, what="the restarted simulator taken by the proxy")
    whole = 0
    for s in sessions:
        _cols, rows = s.results(runs[s.user])
        whole += int(rows.shape[0] == round(SIM_CRASH_STOP / OUTPUT) + 1)
    return {
        "simulator_crash_runs_lost": sum(st.phase != "finished" or st.attempt != 1 for st in ends.values()),
        "simulator_crash_results_whole": whole,
        "simulator_crash_phases": {u: st.phase for u, st in ends.items()},
    }


def worker_crash_trial(mesh: LanMesh) -> dict[str, Any]:
    """A worker killed mid real-time run: the run fails at once, what it computed is kept, and no frame
    of it comes after it was shown failed."""
    client = mesh.client()
    s = prepared(client, "hal", CRASH_STOP, "realtime")
    run = s.run()
    worker = worker_of(mesh, s, run)
    wait_until(sim_time_above(s, CRASH_AT), 30, what="run under way")
    ended: list[float] = []
    after = [0]
    with frames_after_end(s, run, ended, after):
        reached = s.snapshot().state.sim_time
        t0 = time.monotonic()
        os.kill(worker, signal.SIGKILL)
        end = s.wait_for(ENDED, 30, run)
        failed_s = time.monotonic() - t0
        time.sleep(1.0)
    _cols, rows = wait_until(lambda: results_or_none(s, run), 10, what="the results it left")
    return {
        "worker_crash_results_kept": bool(rows.shape[0] > 0 and rows[-1, 0] >= reached - 0.3),
        "worker_crash_results_end_s": round(float(rows[-1, 0]), 3) if rows.shape[0] else None,
        "worker_crash_failed_after_s": round(failed_s, 2),
        "worker_crash_phase": end.phase,
        "frames_after_failed": after[0],
    }


def results_or_none(s: SessionClient, run_id: str) -> tuple[list[str], np.ndarray] | None:
    try:
        return s.results(run_id)
    except Exception:  # not stored yet
        return None


# -- 8. the hub restarts ----------------------------------------------------------------------------------
def hub_restart_trial(mesh: LanMesh) -> dict[str, Any]:
    client = mesh.client()
    through = prepared(client, "dave", 4.0, "realtime")  # goes on through the restart
    ended = prepared(client, "erin", 1.5, "realtime")  # ends while the hub is away
    runs = {through.user: through.run(), ended.user: ended.run()}
    for s in (through, ended):
        wait_until(sim_time_above(s, 0.3), 30, what="runs under way")
    mesh.stop("hub", signal.SIGKILL)
    time.sleep(2.0)
    mesh.start_hub()  # this client's session reconnects by itself
    wait_until(lambda: ("proxy", "proxy-t") in live_nodes(client), 20, what="proxy back")
    phases = {s.user: s.wait_for(ENDED, 60, runs[s.user]) for s in (through, ended)}
    bad = [s.user for s in (through, ended) if not recording_matches(mesh, s, runs[s.user])]
    return {
        "hub_restart_failed_runs": sum(st.phase != "finished" for st in phases.values()),
        "hub_restart_phases": {u: st.phase for u, st in phases.items()},
        "hub_restart_incomplete_recordings": len(bad),
    }
