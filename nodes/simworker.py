"""One simulation run in its own process (Exudyn holds the GIL for a whole solve: STACK-NOTES).

Started warm by the simulator node: it imports the models and compiles their drives first, then
waits for one `RunRequest` line on stdin. It runs that request in chunks, publishing every output
sample as binary frames on `vars/full`, its progress on `run`, and obeying pause / resume / abort on
`control` between chunks. At the end it stores the full-resolution results where the simulator node
serves them from, and exits.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.ext
from simecs.mesh import affinity, codec, files, frames, keys
from simecs.mesh import messages as m
from simecs.mesh.runtime import mesh_from_args, node_arguments, open_session, setup_logging

# Simulated seconds per chunk at real-time pacing: pause/abort act within one chunk. 25 ms gives
# 40 frames per wall second, below the default live rate of 50 Hz: the hot-feedback rate limit then
# never holds frames back in steady real time (at a frame rate equal to R it would, after any burst).
CHUNK_S = 0.025
MAX_CHUNK_S = 0.1  # faster pacing: bigger chunks (fewer, larger frames), still a few ms of wall time


def chunk_length(speed: float, output_interval: float) -> float:
    """About 40 chunks per wall second: 25 ms simulated in real time, up to 100 ms when faster."""
    return max(min(CHUNK_S * speed, MAX_CHUNK_S), CHUNK_S, output_interval)


STATUS_PERIOD_S = 0.1  # at most 10 progress reports per wall second


def results_paths(results_dir: Path, session: str, run_id: str) -> tuple[Path, Path]:
    folder = results_dir / session
    return folder / f"{run_id}.npy", folder / f"{run_id}.json"


class Run:
    def __init__(self, z: zenoh.Session, req: m.RunRequest, results_dir: Path) -> None:
        self.z, self.req, self.results_dir = z, req, results_dir
        self.paused = threading.Event()
        self.aborted = threading.Event()
        self.wake = threading.Event()
        self.samples = 0
        self.chunks: list[np.ndarray] = []
        s = req.session
        self.full = z.declare_publisher(
            keys.vars_full(s), congestion_control=zenoh.CongestionControl.BLOCK, express=True
        )
        self.status_pub = z.declare_publisher(keys.run_status(s))
        self.layout_pub = zenoh.ext.declare_advanced_publisher(
            z, keys.layout(s), cache=zenoh.ext.CacheConfig(1), publisher_detection=True
        )
        self.control_sub = z.declare_subscriber(keys.control(s), self._on_control)
        self.token = z.liveliness().declare_token(keys.run_token(s, req.run_id))
        self.seq = 0
        self.columns: list[str] = []
        self.units: list[str] = []

    def _on_control(self, sample: zenoh.Sample) -> None:
        try:
            ctl = codec.loads(m.RunControl, sample.payload.to_bytes())
        except codec.DecodeError:
            return
        if ctl.run_id != self.req.run_id:
            return
        if ctl.op == "pause":
            self.paused.set()
        elif ctl.op == "resume":
            self.paused.clear()
        else:
            self.aborted.set()
        self.wake.set()

    def status(self, phase: str, sim_time: float, rtf: float, reason: str = "") -> None:
        msg = m.RunStatus(
            session=self.req.session,
            run_id=self.req.run_id,
            phase=phase,  # type: ignore[arg-type]
            sim_time=sim_time,
            stop_time=self.req.settings.stop_time,
            rtf=rtf,
            samples=self.samples,
            reason=reason,
        )
        self.status_pub.put(codec.dumps(msg))

    def publish(self, rows: np.ndarray, final: bool = False) -> None:
        flags = frames.FLAG_FINAL if final else 0
        frame = frames.Frame(self.req.run_index, self.seq, time.time_ns(), rows, flags)
        self.full.put(frames.encode(frame))
        self.seq += 1

    def execute(self) -> None:
        from simecs import models

        req, st = self.req, self.req.settings
        sim = models.get_model(req.model_id).build(req.values)
        try:
            self.columns, self.units = list(sim.columns), list(sim.units)
            var_names = [c for c in self.columns[1:] if not c.startswith("pose.")]
            poses = [c for c in self.columns if c.startswith("pose.")]
            live = ["time"] + (list(st.live_vars) if st.live_vars else var_names) + poses
            layout = m.RunLayout(
                session=req.session,
                run_id=req.run_id,
                run_index=req.run_index,
                model_id=req.model_id,
                columns=self.columns,
                units=self.units,
                live_columns=live,
                live_rate_hz=st.live_rate_hz,
                stop_time=st.stop_time,
                output_interval=st.output_interval,
            )
            self.layout_pub.put(codec.dumps(layout))
            sim.set_initial(req.initial)
            if not isinstance(req.command, m.JointPath):
                raise ValueError(f"this simulator runs joint paths, not {req.command.kind}")
            sim.set_joint_path([(n.q, n.speed_pct, n.acc_pct) for n in req.command.nodes])
            sim.start(st.stop_time, st.output_interval, st.step or None)
            self._loop(sim)
        finally:
            sim.close()

    def _loop(self, sim: Any) -> None:
        st = self.req.settings
        speed = st.speed
        chunk = chunk_length(speed, st.output_interval)
        wall0 = time.monotonic()
        paused_total = 0.0
        last_status = 0.0
        t = 0.0
        self.status("running", 0.0, 0.0)
        while not sim.finished:
            if self.aborted.is_set():
                break
            if self.paused.is_set():
                p0 = time.monotonic()
                self.status("paused", t, t / max(p0 - wall0 - paused_total, 1e-9))
                while self.paused.is_set() and not self.aborted.is_set():
                    self.wake.wait(0.5)
                    self.wake.clear()
                paused_total += time.monotonic() - p0
                if self.aborted.is_set():
                    break
                self.status("running", t, 0.0)
            until = min(t + chunk, st.stop_time)
            rows = sim.advance(until)
            t = sim.time
            if rows.size and not np.all(np.isfinite(rows)):
                bad = self.columns[int(np.where(~np.isfinite(rows))[1][0])]
                raise FloatingPointError(f"{bad} became non-finite at t = {t:.4f} s")
            if rows.shape[0]:
                self.chunks.append(rows)
                self.samples += rows.shape[0]
                self.publish(rows, final=sim.finished)
            elapsed = time.monotonic() - wall0 - paused_total
            if math.isfinite(speed):
                ahead = t / speed - elapsed
                if ahead > 0:
                    self.wake.wait(ahead)
                    self.wake.clear()
                    elapsed = time.monotonic() - wall0 - paused_total
            now = time.monotonic()
            if now - last_status >= STATUS_PERIOD_S:
                self.status("running", t, t / max(elapsed, 1e-9))
                last_status = now
        elapsed = max(time.monotonic() - wall0 - paused_total, 1e-9)
        self.rtf = t / elapsed
        self.sim_time = t

    def save(self, phase: str, reason: str) -> None:
        data = np.concatenate(self.chunks) if self.chunks else np.empty((0, max(len(self.columns), 1)))
        npy, meta = results_paths(self.results_dir, self.req.session, self.req.run_id)
        npy.parent.mkdir(parents=True, exist_ok=True)
        tmp = npy.with_suffix(".tmp.npy")
        np.save(tmp, data)
        os.replace(tmp, npy)
        info = {
            "run_id": self.req.run_id,
            "phase": phase,
            "reason": reason,
            "stop_time": self.req.settings.stop_time,
            "sim_time": float(data[-1, 0]) if data.shape[0] else 0.0,
            "samples": int(data.shape[0]),
            "columns": self.columns,
            "units": self.units,
            "model_id": self.req.model_id,
            "saved": time.time(),
        }
        files.write_json(meta, info)

    def close(self) -> None:
        for e in (self.control_sub, self.layout_pub, self.full, self.status_pub, self.token):
            try:
                e.undeclare()
            except Exception:
                pass


def run_request(z: zenoh.Session, req: m.RunRequest, results_dir: Path, log: Any) -> int:
    run = Run(z, req, results_dir)
    phase, reason = "failed", ""
    try:
        run.execute()
        phase = "aborted" if run.aborted.is_set() else "finished"
        if phase == "aborted":
            reason = "aborted by the user"
    except Exception as exc:
        from simecs import models

        reason = str(exc) if isinstance(exc, models.SimulationError) else f"{type(exc).__name__}: {exc}"
        log.error("run %s/%s failed: %s", req.session, req.run_id, reason)
    try:
        if phase != "finished":
            run.publish(np.empty((0, max(len(run.columns), 1))), final=True)
        run.save(phase, reason)
    except Exception as exc:  # the stream and status still tell the user
        log.error("could not store results of %s: %s", req.run_id, exc)
    t = float(run.chunks[-1][-1, 0]) if run.chunks else 0.0
    run.status(phase, t, getattr(run, "rtf", 0.0), reason)
    time.sleep(0.05)  # let the last status leave before the token goes
    run.close()
    return 0 if phase != "failed" else 3


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="simecs-worker", description=__doc__)
    node_arguments(parser)
    parser.add_argument("--results-dir", required=True)
    args = parser.parse_args(argv)
    setup_logging("simworker", args.log_level)
    import logging

    log = logging.getLogger("simecs.simworker")
    code = 0
    # Warming up (imports, compiling) is background work: it must not slow the runs going on.
    # Once a run is ours we take normal priority back (possible as root or within RLIMIT_NICE).
    os.nice(10)
    try:
        from simecs import models

        warm = getattr(models, "warmup", None)
        if warm is not None:
            warm()
        cfg = mesh_from_args(args)
        z = affinity.open_on_mesh_core(lambda: open_session(cfg), args.cpu)
        try:
            line = sys.stdin.readline()
            if line.strip():
                try:
                    affinity.renice_process(0)  # zenoh's threads too: they carry the frames
                except OSError:
                    log.info("running at nice 10: no right to raise the priority back")
                req = codec.loads(m.RunRequest, line)
                if req.settings.pacing == "fast":
                    # Throughput, not latency: on the mesh core its frames would take CPU time
                    # from the simulation whenever the OS puts both there.
                    affinity.pin_process(os.sched_getaffinity(0))
                code = run_request(z, req, Path(args.results_dir), log)
        finally:
            z.close()
    except Exception as exc:
        log.error("worker failed: %s", exc)
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
