"""One run in its own process (Exudyn holds the GIL for a whole solve).

Started warm by the simulator node: it imports the models and compiles their drives first, says
`ready` on stdout, then waits for one `RunRequest` line on stdin. It runs that request in chunks
from its source (a simulation, or a recording played back), publishing every output sample as binary
frames on `vars/full`, its progress on `run`, and obeying pause / resume / abort / seek on `control`
between chunks. At the end it stores the full-resolution results where the simulator node serves
them from, and exits.
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.ext
from simecs.mesh.process import affinity
from simecs.mesh.process import seal as seals
from simecs.mesh.process.config import lossless_put, open_session
from simecs.mesh.process.logs import setup_logging
from simecs.mesh.process.runtime import mesh_from_args, node_arguments
from simecs.mesh.process.seal import Seal, SealedPublisher
from simecs.mesh.protocol import codec, columns, frames, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import load

from .hil import Lockstep
from .jogging import Jogging
from .pacing import (
    FRAMES_PER_SOLVE,
    Pacer,
    PaceWatch,
    frame_length,
    frame_parts,
    jog_frame_length,
)
from .results_store import PartialResults, ResultsStore, StoredRun
from .sources import RecordingSource, RunSource, SimulationSource, open_source

PAUSED_REPORT_S = 1.0  # a paused run reports too, that it is alive (runs.WORKER_REPORTS_S)
# Lines a worker writes on stdout for its simulator (nodes/host_load.py reads them):
READY = "ready"  # warm: send the run
COST = "cost"  # `cost {"model": CPU s per simulated s, ...}`, measured while warming up
PROGRESS = "progress"  # `progress <simulated s> <1 if falling behind its pace else 0> <RTF, last window>`
log = logging.getLogger("simecs.worker")


class Control:
    """Pause, resume, stop, abort and seek, as the proxy sends them on the session's control key."""

    def __init__(self, run_id: str, paused: bool, seal: Seal, attempt: int = 1) -> None:
        self.run_id, self.attempt = run_id, attempt
        self.seal = seal
        self.paused = threading.Event()
        if paused:
            self.paused.set()
        self.aborted = threading.Event()
        self.stopped = threading.Event()  # end the run as finished, its results kept
        self.wake = threading.Event()
        self.seek_to: float | None = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        if not self.seal.sample_valid(sample):  # only the proxy steers runs
            return
        try:
            ctl = codec.loads(m.RunControl, sample.payload.to_bytes())
        except codec.DecodeError:
            return
        if ctl.run_id != self.run_id or ctl.attempt not in (0, self.attempt):
            return  # another run, or this run's attempt on a host that was taken for lost
        if ctl.op == "pause":
            self.paused.set()
        elif ctl.op == "resume":
            self.paused.clear()
        elif ctl.op == "seek":
            self.seek_to = ctl.time
        elif ctl.op == "stop":
            self.stopped.set()
        else:
            self.aborted.set()
        self.wake.set()

    def sleep(self, seconds: float) -> None:
        self.wake.wait(seconds)
        self.wake.clear()


class Notifier:
    """Notices from the run to its user (at most 8 different texts, each said once)."""

    def __init__(self, z: zenoh.Session, req: m.RunRequest, seal: Seal) -> None:
        self.z, self.req, self.seal = z, req, seal
        self.told: set[str] = set()

    def tell(self, text: str) -> None:
        if text in self.told or len(self.told) >= 8:
            return
        self.told.add(text)
        notice = m.Notice(self.req.session, self.req.run_id, "simulator", text)
        key, payload = keys.notices(self.req.user, self.req.session), codec.dumps(notice)
        try:
            self.z.put(
                key,
                payload,
                attachment=self.seal.mac(key, payload),
                congestion_control=lossless_put(),  # each is said once (LOSSLESS_KEYS)
            )
        except zenoh.ZError:
            pass


class Run:
    def __init__(
        self, z: zenoh.Session, req: m.RunRequest, store: ResultsStore, seal: Seal, host: str = ""
    ) -> None:
        self.z, self.req, self.store, self.host, self.seal = z, req, store, host, seal
        self.control = Control(req.run_id, req.paused, seal, req.attempt)
        self.samples = 0
        self.chunks: list[np.ndarray] = []
        self.partial: PartialResults | None = None  # the rows on disk as they come (a kill keeps them)
        self.source: RunSource | None = None
        self.sim_time = 0.0
        self.rtf = 0.0
        self.jogged_s = 0.0  # simulated s with a jog velocity in force (a replay: the recorded run's)
        u, s = req.user, req.session
        # Every sample carries the service's seal: the proxy, recorder and hot-feedback act only on those.
        full_key, status_key, layout_key = keys.vars_full(u, s), keys.run_status(u, s), keys.layout(u, s)
        self.full = SealedPublisher(
            z.declare_publisher(full_key, congestion_control=lossless_put(), express=True),
            full_key,
            seal,
        )
        # Lossless like the frames it follows (LOSSLESS_KEYS): a report dropped on a busy link loses a step.
        self.status_pub = SealedPublisher(
            z.declare_publisher(status_key, congestion_control=lossless_put()),
            status_key,
            seal,
        )
        self.layout_pub = SealedPublisher(
            zenoh.ext.declare_advanced_publisher(
                z, layout_key, cache=zenoh.ext.CacheConfig(1), publisher_detection=True
            ),
            layout_key,
            seal,
        )
        self.control_sub = z.declare_subscriber(keys.control(u, s), self.control.on_sample)
        self.notifier = Notifier(z, req, seal)
        self.jogging = Jogging(z, req, self.notifier.tell, self.control.wake)
        self.pacer = Pacer(req.settings.speed, req.fast_until)
        self.pace_watch = PaceWatch(req.settings.speed)
        self.hil: Lockstep | None = None
        self.token = z.liveliness().declare_token(keys.run_token(u, s, req.run_id))
        self.seq = 0
        self.final_sent = False
        self.stopped_at: float | None = None  # simulated s where a stop ended the run

    @property
    def stop_time(self) -> float:
        return self.source.stop_time if self.source is not None else self.req.settings.stop_time

    def status(self, phase: str, reason: str = "") -> None:
        msg = m.RunStatus(
            session=self.req.session,
            run_id=self.req.run_id,
            phase=phase,  # type: ignore[arg-type]
            sim_time=max(self.sim_time, 0.0),
            stop_time=self.stop_time,
            rtf=self.rtf,
            samples=self.samples,
            reason=reason,
            attempt=self.req.attempt,
            jogged_s=self.jogged_s,
        )
        if self.source is not None:
            msg.step, msg.task, msg.action = self.source.step_at(self.sim_time)
        if self.hil is not None:
            msg.hil = self.hil.stats
        self.status_pub.put(codec.dumps(msg))

    def publish(self, rows: np.ndarray, final: bool = False) -> None:
        self.final_sent = self.final_sent or final
        flags = frames.FLAG_FINAL if final else 0
        frame = frames.Frame(self.req.run_index, self.seq, time.time_ns(), rows, flags, self.req.attempt)
        self.full.put(frames.encode(frame))
        self.seq += 1

    def execute(self) -> tuple[str, str]:
        """Run the request to its end; (phase, reason) of how it ended."""
        req = self.req
        self.source = source = open_source(req, self.z, self.seal)
        if isinstance(source, RecordingSource):  # its rows were jogged as the recording says
            self.jogged_s = source.rec.jogged_s
        try:
            layout = m.RunLayout(
                session=req.session,
                run_id=req.run_id,
                run_index=req.run_index,
                model_id=source.model_id,
                columns=source.columns,
                units=source.units,
                live_columns=columns.live_columns(source.columns, req.settings.live_vars),
                live_rate_hz=req.settings.live_rate_hz,
                stop_time=source.stop_time,
                output_interval=source.output_interval,
                context=source.context,
                source=source.kind,  # type: ignore[arg-type]
            )
            self.layout_pub.put(codec.dumps(layout))
            if isinstance(source, SimulationSource):  # a replay's rows are its recording's already
                empty = np.empty((0, len(source.columns)))
                self.partial = self.store.partial(req.user, req.session, self.described("running", "", empty))
            source.start()
            if req.settings.controller == "external" and isinstance(source, SimulationSource):
                self.hil = Lockstep(
                    self.z,
                    req,
                    source.sim,
                    source.joints,
                    self.pacer,
                    self.notifier.tell,
                    self.control.aborted.is_set,
                    self.seal,
                )
            self._loop(source)
            if self.control.aborted.is_set():
                return "aborted", "aborted by the user"
            if self.stopped_at is not None:
                return "finished", f"stopped by the user at t = {self.stopped_at:.3f} s"
            phase, reason = source.end()
            if req.until_stopped and phase == "finished" and not reason:
                reason = (
                    f"a run until stopped lasts at most {source.stop_time:g} s here (open_run_s, or what "
                    "results_bytes_per_run holds at its output_interval): it ended there"
                )
            return phase, reason
        finally:
            if self.hil is not None:
                summary = self.hil.summary()
                if summary:
                    self.notifier.tell(summary)
                self.hil.close()
            source.close()

    def _loop(self, source: RunSource) -> None:
        st, ctl, pacer = self.req.settings, self.control, self.pacer
        speed = st.speed
        usual_frame = frame_length(speed, source.output_interval)
        jog_frame = jog_frame_length(speed, source.output_interval)
        # paced runs simulate several frames per call (fewer when jogged); a lockstep with an external
        # controller keeps its own cadence: one frame per call
        several = pacer.paced and self.hil is None
        usual_solve = usual_frame * FRAMES_PER_SOLVE if several else usual_frame
        last_status = 0.0
        last_step = source.step_at(source.time)
        simulated = busy = 0.0  # over the run so far, pauses left out: the RTF
        pacer.reset(source.time)
        t = source.time
        if not ctl.paused.is_set():
            self.status("running")
        while not source.finished and not ctl.aborted.is_set() and self.stopped_at is None:
            moved = False
            if ctl.paused.is_set() and not ctl.stopped.is_set():
                self.status("paused")
                said = time.monotonic()
                while ctl.paused.is_set() and not ctl.aborted.is_set() and not ctl.stopped.is_set():
                    ctl.sleep(0.5)
                    sought = self._seek(source)
                    moved = moved or sought
                    if sought or time.monotonic() - said >= PAUSED_REPORT_S:
                        # A paused run says it is alive too: the proxy keeps a run whose simulator
                        # node was lost going as long as its worker reports (nodes/runs.py).
                        self.status("paused")
                        said = time.monotonic()
                if ctl.aborted.is_set():
                    break
                moved = True
                if not ctl.stopped.is_set():  # a stopped run goes from paused to its end
                    self.status("running")
            # Every pending seek goes before the next chunk: one that came with a resume too (the
            # thread descheduled between a look and the pause check must not play a chunk first).
            moved = self._seek(source) or moved
            if moved:  # pacing starts again from here
                pacer.reset(source.time)
                self.pace_watch.reset(source.time)
            step_wall, step_t = time.monotonic(), source.time
            jog_mode = several and (self.req.until_stopped or self.jogging.recent())
            frame, solve = (jog_frame, jog_frame) if jog_mode else (usual_frame, usual_solve)
            self.jogging.wakes = jog_mode
            # jogging is telemanipulation: runs paced in wall time only
            jogged = pacer.paced and self.jogging.apply(source, solve)
            # Told to stop: one more frame, the run's last (a finished run's final frame holds samples).
            until = min(source.time + (frame if ctl.stopped.is_set() else solve), source.stop_time)
            rows = self.hil.advance(until) if self.hil is not None else source.advance(until)
            t = source.time
            if rows.size and not np.all(np.isfinite(rows)):
                bad = source.columns[int(np.where(~np.isfinite(rows))[1][0])]
                raise FloatingPointError(f"{bad} became non-finite at t = {t:.4f} s")
            for text in source.notices(rows):
                self.notifier.tell(text)
            parts = frame_parts(rows, step_t, frame, t)
            for k, (part, t_part) in enumerate(parts):
                self.chunks.append(part)
                if self.partial is not None:
                    self.partial.append(part)
                self.samples += part.shape[0]
                # A stop that came ends the run with the call's last frame (its rows are the run's).
                last = k == len(parts) - 1 and (source.finished or ctl.stopped.is_set())
                self.publish(part, final=last)
                self.sim_time = t_part
                if last and not source.finished:  # stopped: the run lasted until its last sample
                    self.stopped_at = self.sim_time = float(part[-1, 0])
                    break
                step = source.step_at(t_part)
                if step != last_step:  # a step begins: said at once, however short
                    self.status("running")
                    last_step = step
                ahead = pacer.ahead(t_part)
                if ahead > 0:
                    ctl.sleep(ahead)
                    # Woken early by a jog (jog mode: one frame per call), the call that obeys it
                    # starts now if that keeps the run at most one frame (in wall time) ahead of its time.
                    frame_wall = frame / pacer.speed
                    while (late_wake := pacer.ahead(t_part) - frame_wall) > 0 and not ctl.aborted.is_set():
                        ctl.sleep(late_wake)
                if ctl.aborted.is_set():
                    break  # what the call simulated beyond the frames sent is not the run's
            if jogged:  # the velocity held for the whole call: as far as its frames went
                went = max((self.sim_time if parts else t) - step_t, 0.0)
                self.jogged_s = round(self.jogged_s + went, 9)  # 0.6, not 0.6000000000000001
            if self.stopped_at is not None:
                break
            if not parts:
                self.sim_time = t
            t = self.sim_time
            simulated += max(t - step_t, 0.0)
            busy += time.monotonic() - step_wall
            self.rtf = simulated / max(busy, 1e-9)
            now = time.monotonic()
            if now - last_status >= m.RUNNING_REPORT_S:
                self.status("running")
                self.watch_pace(t)
                last_status = now

    def watch_pace(self, t: float) -> None:
        """Tell the user when the run falls behind its pace (and when it catches up), and the simulator
        every time: it stops taking runs while one of its runs is behind."""
        changed = self.pace_watch.update(t)
        speed = self.req.settings.speed
        if changed is True:
            self.notifier.tell(
                f"run {self.req.run_id} falls behind its pace: {self.pace_watch.rtf / speed:.2f}x of it "
                f"for {load.BEHIND_GRACE_S:g} s (simulator {self.host} is overloaded); it takes no new run "
                "until this one catches up"
            )
        elif changed is False:
            self.notifier.tell(f"run {self.req.run_id} keeps its pace again")
        tell_simulator(f"{PROGRESS} {t:.6f} {int(self.pace_watch.behind)} {self.pace_watch.rtf:.4f}")

    def _seek(self, source: RunSource) -> bool:
        """Obey a pending seek (replays); True when one happened."""
        target, self.control.seek_to = self.control.seek_to, None
        if target is None:
            return False
        source.seek(target)
        self.sim_time = source.time
        return True

    def save(self, phase: str, reason: str) -> None:
        source = self.source
        data = source.results(self.chunks) if source is not None else np.empty((0, 1))
        run = self.described(phase, reason, data)
        self.store.save(self.req.user, self.req.session, run, data)
        if self.partial is not None:
            self.partial.discard()
        self.samples = run.samples

    def described(self, phase: str, reason: str, data: np.ndarray) -> StoredRun:
        """What the store keeps beside the run's rows `data`."""
        source = self.source
        cols = source.columns if source is not None else ["time"]
        return StoredRun(
            run_id=self.req.run_id,
            run_index=self.req.run_index,
            phase=phase,
            reason=reason,
            stop_time=self.stop_time,
            sim_time=float(data[-1, 0]) if data.shape[0] else 0.0,
            samples=int(data.shape[0]),
            columns=list(cols),
            units=list(source.units) if source is not None else ["s"],
            model_id=self.req.model_id,
            context=codec.to_obj(source.context) if source is not None else None,
            jogged_s=self.jogged_s,
        )

    def close(self) -> None:
        for e in (
            self.control_sub,
            self.jogging.sub,
            self.layout_pub,
            self.full,
            self.status_pub,
            self.token,
        ):
            try:
                e.undeclare()
            except Exception:
                pass


def tell_simulator(line: str) -> None:
    """One line to the simulator on stdout; dropped rather than waited for if the pipe is full."""
    try:
        os.write(sys.stdout.fileno(), (line + "\n").encode())
    except (BlockingIOError, BrokenPipeError, OSError):
        pass


def run_request(
    z: zenoh.Session, req: m.RunRequest, store: ResultsStore, seal: Seal, log: Any, host: str = ""
) -> int:
    run = Run(z, req, store, seal, host)
    phase, reason = "failed", ""
    try:
        phase, reason = run.execute()
    except Exception as exc:
        from simecs import models

        known = isinstance(exc, models.SimulationError | ValueError)
        reason = str(exc) if known else f"{type(exc).__name__}: {exc}"
        log.error("run %s/%s failed: %s", req.session, req.run_id, reason)
    try:
        if not run.final_sent:  # an aborted or failed run ends with an empty final frame
            run.publish(np.empty((0, len(run.source.columns) if run.source else 1)), final=True)
        run.save(phase, reason)
    except Exception as exc:  # the stream and status still tell the user
        log.error("could not store results of %s: %s", req.run_id, exc)
    run.status(phase, reason)
    time.sleep(0.05)  # let the last status leave before the token goes
    run.close()
    return 0 if phase != "failed" else 3


def worker_arguments(prog: str, description: str | None) -> argparse.ArgumentParser:
    """The flags of a worker, and of the process workers are forked from (nodes/worker_forks.py)."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    node_arguments(parser)
    parser.add_argument("--results-dir", required=True)
    parser.add_argument("--simulator", default="", help="the node id of the simulator that started it")
    return parser


def warm_up() -> str:
    """Import the models and load the drives' machine code (what makes a worker warm); returns the
    `cost` line: each model's CPU s per simulated s, measured here. Background work, at nice 10: it
    must not slow the runs going on."""
    os.nice(10)
    from simecs import models

    models.warmup()
    return f"{COST} {json.dumps(models.costs())}"


def main(argv: list[str] | None = None) -> None:
    args = worker_arguments("simecs-worker", __doc__).parse_args(argv)
    setup_logging("worker", args.log_level)
    faulthandler.enable()  # a crash in a native library leaves every thread's stack in the log
    try:
        cost = warm_up()
    except Exception as exc:
        log.error("worker failed to warm up: %s", exc)
        os._exit(1)
    serve(args, cost)


def serve(args: argparse.Namespace, cost: str) -> None:
    """A warm worker's life: say so (with `cost`), take one run from stdin, run it, exit. Once a run
    is ours we take normal priority back (possible as root or within RLIMIT_NICE)."""
    os.set_blocking(sys.stdout.fileno(), False)  # a simulator that does not read never stalls a run
    code = 0
    try:
        tell_simulator(cost)
        cfg = mesh_from_args(args)
        seal = seals.load(seals.key_file(cfg.service_key_file))  # the simulator's, made before us
        z = affinity.open_on_mesh_core(lambda: open_session(cfg), args.cpu)
        try:
            tell_simulator(READY)
            line = sys.stdin.readline()
            if line.strip():
                try:
                    affinity.renice_process(0)  # zenoh's threads too: they carry the frames
                except OSError:
                    log.info("running at nice 10: no right to raise the priority back")
                req = codec.loads(m.RunRequest, line)
                if req.settings.controller == "external":
                    # Lockstep: every period wakes this thread from a zenoh thread, and a wake-up
                    # across CPUs costs most of a period on a VM (mesh/process/affinity.py): all on one core.
                    affinity.place_on_mesh_core(args.cpu)
                elif req.settings.pacing == "fast":
                    # Throughput, not latency: on the mesh core its frames would take CPU time
                    # from the simulation whenever the OS puts both there.
                    affinity.pin_process(os.sched_getaffinity(0))
                store = ResultsStore(Path(args.results_dir))
                code = run_request(z, req, store, seal, log, args.simulator)
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
