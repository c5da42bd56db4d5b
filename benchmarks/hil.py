"""`simecs bench hil`: a controller in the loop, live jogging and batch sweeps, on a private mesh.

- `lockstep_hz`: control periods per wall second of a Spider joint path (6 s simulated, pacing fast)
  with the reference external controller (docs/examples/external_controller.py) in another process,
  every exchange crossing the hub twice (worker -> hub -> controller -> hub -> worker);
- `deadline_miss_ratio`: answers later than one period over all periods of a 5 s real-time run at
  1 kHz with the same controller (the worker's own count, `SessionState.hil`);
- `external_vs_builtin_max_error_mrad`: the largest joint-angle difference between the lockstep run
  and the same command under the built-in controller;
- `jog_latency_ms_p50` / `_p99`: a jog message put -> the first live frame (as a client receives it)
  in which joint 1 has moved 0.05 mrad from where it stood, over 30 jogs of a real-time run being jogged
  (PROTOCOL.md §5.4: 5 ms solver calls from its first jog message); `jog_setpoint_latency_ms_p50` /
  `_p99`: the same to the first live frame in which its set point moved (the service's part; the joint
  follows through its drive's dynamics, 4-6 ms of simulated time for the Spider's); `jog_first_latency_ms`:
  the run's first jog, which finds the run in its usual 50 ms calls;
- `sweep_runs_per_s_1sim` / `_all_sims` / `sweep_scaling`: 32 short runs (0.5 s simulated, fast)
  through `mesh.batch.sweep`, with one simulator taking one run at a time, and with one simulator
  per core each taking one.
Every loop here is bounded in count and time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh import batch
from simecs.mesh.client import MeshClient, SessionClient
from simecs.mesh.process import affinity
from simecs.mesh.protocol import frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.local_mesh import LocalMesh, clean_env, wait_until

EXAMPLE = Path(__file__).resolve().parent.parent / "docs" / "examples" / "external_controller.py"
POSTURE = [0.3, -0.4, 0.2, 0.6, -0.3, 0.2, 0.1]
PATH = [([0.8, 0.1, 0.6, 1.0, -0.7, 0.6, 0.5], 100.0, 100.0), (POSTURE, 100.0, 100.0)]
JOGS, JOG_MOVE = 30, 5e-5
SWEEP_RUNS = 32


def log(text: str) -> None:
    print(f"bench hil: {text}", file=sys.stderr, flush=True)


def start_controller(mesh: LocalMesh, session: SessionClient, runs: int) -> subprocess.Popen[bytes]:
    """The reference controller in a process of its own, serving `session` for `runs` runs."""
    argv = [sys.executable, str(EXAMPLE), mesh.endpoint, "--user", session.user, "--session", session.id]
    cpu = affinity.mesh_core(os.environ.get("SIMECS_CPU", "auto"))
    proc = subprocess.Popen(
        [*argv, "--runs", str(runs)],
        stdout=subprocess.PIPE,
        env=clean_env(),
        # placed like the viewer: on the mesh core, beside the hub (mesh/process/affinity.py)
        preexec_fn=(lambda: os.sched_setaffinity(0, {cpu})) if cpu is not None else None,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().decode()  # "serving ...": its subscriptions are declared
    if not line.startswith("serving"):
        raise RuntimeError(f"the external controller did not start: {line!r}")
    return proc


def run_to_end(session: SessionClient, timeout: float = 120.0) -> m.SessionState:
    run_id = session.run()

    def ended() -> m.SessionState | None:
        st = session.snapshot().state
        return st if st.run_id == run_id and st.phase in ("finished", "aborted", "failed") else None

    st = wait_until(ended, timeout, 0.05, f"run {run_id} to end")
    if st.phase != "finished":
        raise RuntimeError(f"run {run_id} {st.phase}: {st.reason}")
    return st


def angles(session: SessionClient, run_id: str) -> np.ndarray:
    cols, rows = session.results(run_id, [f"joint{j + 1}.q" for j in range(7)])
    return rows[:, 1:]


def lockstep(mesh: LocalMesh) -> dict[str, float]:
    client = mesh.client()
    session = client.create_session("bench", "spider")
    session.set_initial(POSTURE)
    session.set_joint_path(PATH * 2)
    fast = m.RunSettings(stop_time=6.0, output_interval=0.001, pacing="fast")
    session.command(m.SetSettings(fast))
    builtin = run_to_end(session)
    ctl = start_controller(mesh, session, runs=2)
    try:
        session.command(m.SetSettings(m.RunSettings(**{**_fields(fast), "controller": "external"})))
        ext = run_to_end(session)
        realtime = m.RunSettings(stop_time=5.0, output_interval=0.002, controller="external")
        session.set_joint_path([(POSTURE, 50.0, 50.0)] + PATH)
        session.command(m.SetSettings(realtime))
        rt = run_to_end(session, timeout=60.0)
        ctl.wait(30)
    finally:
        if ctl.poll() is None:
            ctl.kill()
    error = float(np.max(np.abs(angles(session, ext.run_id) - angles(session, builtin.run_id))))
    hil = rt.hil or m.HilStats()
    session.close()
    log(f"lockstep at {ext.rtf / fast.control_period:.0f} Hz; real time: {hil.misses} of {hil.periods} late")
    return {
        "lockstep_hz": round(ext.rtf / fast.control_period, 1),
        "deadline_miss_ratio": round(hil.misses / max(hil.periods, 1), 5),
        "deadline_worst_late_ms": round(hil.worst_late_ms, 3),
        "external_vs_builtin_max_error_mrad": round(error * 1e3, 4),
    }


def _fields(settings: m.RunSettings) -> dict[str, Any]:
    return {f: getattr(settings, f) for f in settings.__struct_fields__}


def jog_latency(mesh: LocalMesh) -> dict[str, float]:
    """Jog joint 1 back and forth during a real-time run holding still; time to the first live frame
    in which it moved, and in which its set point moved (the service's part: the joint then follows
    its set point through the drive's dynamics, several ms of simulated time)."""
    client = mesh.new_client()
    session = client.create_session("bench", "spider")
    session.set_initial(POSTURE)
    session.set_joint_path([(POSTURE, 100.0, 100.0)])
    session.command(m.SetSettings(m.RunSettings(stop_time=60.0, live_rate_hz=1000.0)))
    layout: dict[str, Any] = {}
    got = threading.Condition()
    latest: list[tuple[float, float, float]] = []  # (arrival, joint1.q, joint1.q_ref) per live frame

    def on_live(sample: Any) -> None:
        if "q" not in layout:
            return
        frame = frames.decode(sample.payload.to_bytes(), last_row_only=True)
        if frame.rows.shape[0]:
            row = frame.rows[0]
            with got:
                latest.append((time.perf_counter(), float(row[layout["q"]]), float(row[layout["q_ref"]])))
                got.notify_all()

    def on_layout(lay: m.RunLayout) -> None:
        layout["q_ref"] = lay.live_columns.index("joint1.q_ref")
        layout["q"] = lay.live_columns.index("joint1.q")

    z = client.z
    sub = z.declare_subscriber(keys.vars_live(session.user, session.id), on_live)
    latencies: list[float] = []
    set_point: list[float] = []
    with session.watch(on_layout=on_layout):
        run_id = session.run()
        wait_until(lambda: "q" in layout and latest, 30.0, 0.05, "the first live frame")
        sign = 1.0
        end = time.monotonic() + 90.0
        for _ in range(JOGS + 1):  # the first: the run not jogged yet
            if time.monotonic() > end:
                break
            time.sleep(0.3)  # still again
            with got:
                _, start_q, start_ref = latest[-1]
                seen = len(latest)
            qd = [0.0] * 7
            qd[0] = 0.3 * sign
            t0 = time.perf_counter()
            session.jog(m.JogInput(run_id=run_id, space="joint", qd=qd))
            moved = ref_moved = None
            deadline = t0 + 1.0
            while moved is None and time.perf_counter() < deadline:
                with got:
                    got.wait(0.05)
                    for arrival, q, ref in latest[seen:]:
                        if ref_moved is None and abs(ref - start_ref) > 1e-9 and arrival > t0:
                            ref_moved = arrival
                        if abs(q - start_q) > JOG_MOVE and arrival > t0:
                            moved = arrival
                            break
                    seen = len(latest)
                if time.perf_counter() - t0 > 0.08:
                    session.jog(m.JogInput(run_id=run_id, space="joint", qd=qd))
            session.jog(m.JogInput(run_id=run_id, space="joint", qd=[0.0] * 7))
            if moved is not None and ref_moved is not None:
                latencies.append((moved - t0) * 1e3)
                set_point.append((ref_moved - t0) * 1e3)
            sign = -sign
        session.abort()
    sub.undeclare()
    session.close()

    def spread(values: list[float]) -> tuple[float, float]:
        a = np.array(values) if values else np.array([np.nan])
        return round(float(np.percentile(a, 50)), 2), round(float(np.percentile(a, 99)), 2)

    first = latencies[0] if latencies else float("nan")
    (p50, p99), (ref50, ref99) = spread(latencies[1:]), spread(set_point[1:])
    log(
        f"jog latency over {len(latencies[1:])} jogs: p50 {p50:.1f} ms, p99 {p99:.1f} ms (the set point: "
        f"p50 {ref50:.1f}, p99 {ref99:.1f}); the run's first jog {first:.1f} ms"
    )
    return {
        "jog_latency_ms_p50": p50,
        "jog_latency_ms_p99": p99,
        "jog_setpoint_latency_ms_p50": ref50,
        "jog_setpoint_latency_ms_p99": ref99,
        "jog_first_latency_ms": round(first, 2),
        "jogs_measured": len(latencies[1:]),
    }


def sweep_rate(simulators: int) -> float:
    """Runs per wall second of SWEEP_RUNS short runs with `simulators` simulators of one slot each."""
    with LocalMesh() as mesh:
        mesh.start_hub()
        data = mesh.start_service(max_running=simulators, simulator_args=("--max-runs", "1"))
        for k in range(1, simulators):
            mesh.start(
                "simulator", "--results-dir", str(data / "results"), "--max-runs", "1", name=f"simulator{k}"
            )
        client = MeshClient.open(mesh.config, timeout=30.0)
        command = m.JointPath(nodes=[m.PathNode(q=PATH[0][0])])
        settings = m.RunSettings(stop_time=0.5, output_interval=0.01, pacing="fast")
        cases = [{"joint1.ctrl.kp_pos": 20.0 + k} for k in range(SWEEP_RUNS)]
        t0 = time.perf_counter()
        rows = batch.sweep(
            client,
            "bench",
            "spider",
            command,
            cases,
            ["max_abs:joint1.i_ref"],
            initial=POSTURE,
            settings=settings,
            parallel=2 * simulators,
            timeout=300.0,
        )
        wall = time.perf_counter() - t0
        client.close()
    failed = [r.error for r in rows if r.error]
    if failed:
        raise RuntimeError(f"{len(failed)} sweep runs failed, e.g. {failed[0]}")
    return SWEEP_RUNS / wall


def run_hil_bench(as_json: bool = False) -> dict[str, Any]:
    results: dict[str, Any] = {}
    with LocalMesh() as mesh:
        mesh.start_hub()
        mesh.start_service()
        results.update(lockstep(mesh))
        results.update(jog_latency(mesh))
    cores = max(1, len(os.sched_getaffinity(0)))
    one = sweep_rate(1)
    every = sweep_rate(cores)
    results.update(
        {
            "sweep_runs_per_s_1sim": round(one, 2),
            "sweep_runs_per_s_all_sims": round(every, 2),
            "sweep_simulators": cores,
            "sweep_scaling": round(every / one, 2),
        }
    )
    for key, value in results.items():
        print(f"{key:40s} {value}")
    if as_json:
        print(json.dumps(results))
    return results
