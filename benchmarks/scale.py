"""`simecs bench scale`: how many runs the service carries, and how it spreads them over hosts.

- `realtime_sessions`: real-time Spider sessions (full drive train) added one at a time to a
  service started with its defaults (no --max-running), until one of them falls below RTF 0.99 over
  RTF_WINDOWS s (the workers' own 1 s windows, `SimulatorLoad.runs[].rtf`, averaged: one window
  jitters by about 1 % with the wake-ups' latency) or falls behind, the service stops admitting, or
  MAX_SESSIONS / the time limit is reached; the count of sessions held at RTF >= 0.99. Each count is
  measured once the simulator's spare workers are warm again: a run takes a warm worker and the host
  warms another in its place (about 1 s of one core), a transient of starting a run, not what the
  host holds;
- `realtime_sessions_per_core`: that count over the CPUs this machine gives the benchmark (`cores`),
  the figure that carries from one machine to another;
- `proxy_cmd_ms_p99_at_max` (and `_p50`): the proxy's answer time to a session command (`set_settings`
  of an idle session, PROXY_PROBES of them) while the most sessions that held their pace run, through
  the same hub: one proxy carries every session's commands, states and progress;
- `admitted_by_default`: how many of those the defaults admitted without queueing;
- `queue_wait_estimate_error`: |estimated - actual| / actual wait of runs queued behind runs as fast
  as possible on one host (the estimate is the first `wait_s` each queued run was told);
- `scale_ratio_2_hosts`: simulated s per wall s of FAST_RUNS runs as fast as possible with two
  simulator hosts (network namespaces, each pinned to one core) vs one;
- `host_loss_runs_lost`: runs lost when one of two simulator hosts is killed mid-run (0: each is
  restarted on the other host).
Every loop is bounded in count and time.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from typing import Any

import numpy as np
import zenoh
import zenoh.ext
from simecs.mesh.client import SessionClient
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.local_mesh import LocalMesh, wait_until
from simecs.testing import netns

PATH = [([0.4, -0.3, 0.5, 0.2, -0.2, 0.3, 0.1], 30.0, 30.0)]
MAX_SESSIONS = 64
TIME_LIMIT_S = 600.0
FAST_RUNS = 8
RTF_WINDOWS = 3  # a run's RTF is the mean of this many 1 s windows: one window's is +-1 % of jitter
PROXY_PROBES = 40  # commands timed at each count of sessions


def log(text: str) -> None:
    print(f"bench scale: {text}", file=sys.stderr, flush=True)


def session(mesh: LocalMesh, user: str, **settings: Any) -> SessionClient:
    s = mesh.client().create_session(user, "spider")
    s.set_joint_path(PATH)
    s.set_settings(**settings)
    return s


class Loads:
    """The simulators' loads, as their statuses come."""

    def __init__(self, mesh: LocalMesh) -> None:
        self.latest: dict[str, m.SimulatorLoad] = {}
        self.at: dict[str, float] = {}
        history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
        self.sub = zenoh.ext.declare_advanced_subscriber(
            mesh.client().z, keys.SIMULATOR_STATUS, self._on, history=history
        )

    def _on(self, sample: zenoh.Sample) -> None:
        status = codec.loads(m.NodeStatus, sample.payload.to_bytes())
        if status.load is not None:
            self.latest[status.node_id], self.at[status.node_id] = status.load, time.monotonic()

    def close(self) -> None:
        self.sub.undeclare()


def realtime_capacity() -> dict[str, Any]:
    with LocalMesh() as mesh:
        mesh.start_hub()
        data = mesh.folder / "data"
        mesh.start("proxy", "--data-dir", str(data))
        mesh.start("simulator", "--results-dir", str(data / "results"))
        mesh.start("hotfeedback")
        loads = Loads(mesh)
        held, admitted, began = 0, 0, time.monotonic()
        sessions: list[SessionClient] = []
        probe = mesh.new_client().create_session("probe", "spider")  # idle: its commands are timed
        answers: list[float] = []  # ms, at the count that held last
        try:
            while len(sessions) < MAX_SESSIONS and time.monotonic() - began < TIME_LIMIT_S:
                now = loads.latest.get("simulator-t")
                warm_before = now.warm if now is not None else 0
                s = session(mesh, f"rt{len(sessions)}", stop_time=600.0, output_interval=0.02)
                sessions.append(s)
                run_id = s.run()
                try:
                    s.wait_for(["running"], 60, run_id)
                except TimeoutError:
                    log(f"session {len(sessions)} was not admitted: {s.snapshot().state}")
                    break
                if s.snapshot().state.queue_position == 0 and admitted == len(sessions) - 1:
                    admitted = len(sessions)

                # A load in which every run (the newest too) has an RTF of a window of its own, and the
                # worker warmed in place of the one the new run took is warm (see the docstring).
                def measured(warm: int = warm_before) -> m.SimulatorLoad | None:
                    load = loads.latest.get("simulator-t")
                    if load is None or len(load.runs) != len(sessions) or load.warm < warm:
                        return None
                    return load if all(r.rtf > 0 for r in load.runs) else None

                wait_until(measured, 30, 0.1, what="the spare workers warm again")

                time.sleep(2.0)
                windows: dict[tuple[str, str], list[float]] = {}
                for _ in range(RTF_WINDOWS):  # the workers' 1 s windows, one apart
                    load = wait_until(measured, 15, 0.1, what="every run's RTF")
                    for r in load.runs:
                        windows.setdefault((r.session, r.run_id), []).append(r.rtf)
                    time.sleep(1.0)
                worst = min(sum(w) / len(w) for w in windows.values())
                used = f"{load.demand:.2f}/{load.capacity:.2f} cores"
                times = proxy_answers(probe)
                log(
                    f"{len(load.runs)} real-time runs: worst RTF {worst:.3f}, {used}; the proxy answers "
                    f"in p50 {np.percentile(times, 50):.1f} ms, p99 {np.percentile(times, 99):.1f} ms"
                )
                if worst < 0.99 or load.behind:
                    break
                held, answers = len(load.runs), times
        finally:
            loads.close()
            for s in sessions:
                try:
                    s.abort()
                except Exception:
                    pass
    cores = len(os.sched_getaffinity(0))
    at_max = np.array(answers) if answers else np.array([np.nan])
    return {
        "realtime_sessions": held,
        "cores": cores,
        "realtime_sessions_per_core": round(held / cores, 2),
        "proxy_cmd_ms_p50_at_max": round(float(np.percentile(at_max, 50)), 2),
        "proxy_cmd_ms_p99_at_max": round(float(np.percentile(at_max, 99)), 2),
        "admitted_by_default": min(admitted, held),
    }


def proxy_answers(probe: SessionClient) -> list[float]:
    """PROXY_PROBES `set_settings` of the idle session `probe`, one after the other: each answer's ms."""
    times = []
    for k in range(PROXY_PROBES):
        t0 = time.perf_counter()
        probe.set_settings(stop_time=1.0 + k % 2)  # a change each time: the proxy stores it
        times.append((time.perf_counter() - t0) * 1e3)
    return times


def queue_wait_error() -> dict[str, Any]:
    with LocalMesh() as mesh:
        mesh.start_hub()
        data = mesh.folder / "data"
        mesh.start("proxy", "--data-dir", str(data))
        mesh.start("simulator", "--results-dir", str(data / "results"), "--max-runs", "1")
        told: dict[str, float] = {}
        started: dict[str, float] = {}
        sessions = [session(mesh, f"q{i}", stop_time=20.0, pacing="fast") for i in range(4)]
        watches = []
        for s in sessions:

            def on_state(st: m.SessionState, sid: str = s.id) -> None:
                if st.phase == "queued" and st.wait_s > 0 and sid not in told:
                    told[sid] = time.monotonic() + st.wait_s
                if st.phase == "running" and sid not in started:
                    started[sid] = time.monotonic()

            watches.append(s.watch(on_state=on_state))
        queued_at = time.monotonic()
        for s in sessions:
            s.run()
        for s in sessions:
            s.wait_for(["finished", "failed"], 240)
        for w in watches:
            w.close()
    errors = [
        abs(told[sid] - started[sid]) / max(started[sid] - queued_at, 1e-3) for sid in told if sid in started
    ]
    pairs = [
        (round(told[sid] - queued_at, 1), round(started[sid] - queued_at, 1))
        for sid in told
        if sid in started
    ]
    rounded = [round(e, 2) for e in errors]
    log(f"queued runs' (estimated, actual) waits in s: {pairs}; relative errors {rounded}")
    return {"queue_wait_estimate_error": round(max(errors), 3) if errors else None}


def two_hosts() -> dict[str, Any]:
    try:
        lan = netns.Lan(("hub", "sim1", "sim2")).up()
    except netns.NetnsUnavailable as exc:
        log(f"no network namespaces here ({exc}): scale_ratio_2_hosts and host_loss_runs_lost skipped")
        return {}
    try:
        one = fast_throughput(lan, ["sim1"])
        two = fast_throughput(lan, ["sim1", "sim2"])
        lost = host_loss(lan)
    finally:
        lan.down()
    log(f"as fast as possible: {one:.1f} simulated s per wall s on one host, {two:.1f} on two")
    return {"scale_ratio_2_hosts": round(two / one, 2), "host_loss_runs_lost": lost}


def fast_throughput(lan: netns.Lan, hosts: list[str]) -> float:
    """Simulated s per wall s of FAST_RUNS fast runs, each host pinned to a core of its own."""
    placement = {h: h for h in hosts}
    mesh = netns.lan_mesh(lan, placement, cpus={h: i for i, h in enumerate(hosts)})
    try:
        mesh.start_hub()
        data = mesh.folder / "data"
        mesh.start("proxy", "--data-dir", str(data))
        for h in hosts:
            mesh.start("simulator", "--results-dir", str(data / h), name=h)
        sessions = [session(mesh, f"f{i}", stop_time=10.0, pacing="fast") for i in range(FAST_RUNS)]
        began = time.monotonic()
        threads = [
            threading.Thread(target=lambda s=s: s.wait_for(["finished", "failed"], 300, s.run()))
            for s in sessions
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join(320)
        return 10.0 * FAST_RUNS / (time.monotonic() - began)
    finally:
        mesh.close()


def host_loss(lan: netns.Lan) -> int:
    """Four real-time runs over two hosts; one host killed mid-run: how many do not finish."""
    mesh = netns.lan_mesh(lan, {"sim1": "sim1", "sim2": "sim2"})
    try:
        mesh.start_hub()
        data = mesh.folder / "data"
        mesh.start("proxy", "--data-dir", str(data))
        for h in ("sim1", "sim2"):
            mesh.start("simulator", "--results-dir", str(data / h), "--max-runs", "2", name=h)
        sessions = [session(mesh, f"h{i}", stop_time=4.0) for i in range(4)]
        for s in sessions:
            s.wait_for(["running"], 60, s.run())
        time.sleep(1.5)
        mesh.stop("sim1", signal.SIGKILL)
        ends = [s.wait_for(["finished", "failed", "aborted"], 120) for s in sessions]
        restarted = sum(1 for e in ends if e.attempt > 1)
        log(f"host lost mid-run: {restarted} of 4 runs restarted on the other host")
        return sum(1 for e in ends if e.phase != "finished")
    finally:
        mesh.close()


def run_scale_bench(as_json: bool = False) -> dict[str, Any]:
    results: dict[str, Any] = {}
    results.update(realtime_capacity())
    results.update(queue_wait_error())
    results.update(two_hosts())
    for key, value in results.items():
        print(f"{key:40s} {value}")
    if as_json:
        print(json.dumps(results))
    return results
