"""The recorder node: every run saved as one MCAP file, crash-safe, without ever slowing the simulator.

It listens to every session's layout, full-rate frames, state and parameters. A `RunLayout` opens
`<dir>/<session>_<run>.mcap`; the run's final frame (or its ended state, or a silent worker) closes
it. No Python runs in zenoh's threads (a slow callback would stall the whole link, simulator
included): samples land in native ring buffers, a puller thread moves them to a bounded queue, and one
writer thread, at a lower CPU priority, owns the files. If frames are ever dropped (queue full, ring
overflow, or lost on the way: gaps in frame numbers), the file says so on /log and in `simecs.end`,
and the node's status says so.
Files are flushed about once a second, so a crash loses at most ~1 s; on start, torn files from a
crash are repaired (every complete chunk kept) and marked recovered.

It also serves the recordings: the list, downloads and uploads (`simecs/recordings/<name>`), and
replays (`simecs/recordings/<name>/replay` starts `simecs.nodes.replay` as a process).
"""

from __future__ import annotations

import argparse
import collections
import fcntl
import json
import os
import struct
import subprocess
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh
import zenoh.ext
from simecs.mesh import codec, files, frames, keys
from simecs.mesh import messages as m
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.model import ModelDescription
from simecs.mesh.runtime import Binary, Node, Request, RequestError, main_for, mesh_from_args

from . import mcapfmt as fmt
from . import mcapread

ENDED = ("finished", "aborted", "failed")
FINAL_GRACE_S = 0.3  # after the final frame: let the run's ended state arrive for the end phase
ENDED_GRACE_S = 2.0  # after an ended state without final frame: frames may still be on their way
DOWNLOAD_WAIT_S = 5.0  # a download of a run that is just ending waits this long for its file
MAX_FILE_BYTES = 1 << 30  # largest recording served or accepted over the mesh
BATCH_MIN = 8  # frames: a smaller batch makes the writer wait BATCH_WAIT_S before the next one
BATCH_WAIT_S = 0.02
WRITER_NICE = 10  # how much lower the writer thread's CPU priority is than the node's
RING_FRAMES = 8192  # samples zenoh holds per subscription for the puller thread
PENDING_FRAMES = 256  # frames kept per session while its layout has not arrived yet
LOG_LEVEL = {"running": fmt.LOG_INFO, "paused": fmt.LOG_INFO, "finished": fmt.LOG_INFO}


class Ingest:
    """The writer's bounded input queue, fed by the puller thread. Control messages are always kept;
    frames beyond `max_frames` or `max_bytes` are dropped (newest first) and counted per session."""

    def __init__(self, max_frames: int, max_bytes: int) -> None:
        self.q: collections.deque[tuple[str, str, Any]] = collections.deque()
        self.cv = threading.Condition()
        self.max_frames = max_frames
        self.max_bytes = max_bytes
        self.frames = 0
        self.bytes = 0
        self.drops: dict[str, list[int]] = {}  # session -> [frames, rows, first wall ns, last wall ns]
        self.dropped_total = 0

    def put(self, kind: str, key: str, payload: Any) -> None:
        with self.cv:
            if kind == "full":
                if self.frames >= self.max_frames or self.bytes + len(payload) > self.max_bytes:
                    self._drop(key, payload)
                    return
                self.frames += 1
                self.bytes += len(payload)
            self.q.append((kind, key, payload))
            self.cv.notify()

    def _drop(self, key: str, payload: bytes) -> None:
        parts = key.split("/")
        session = parts[1] if len(parts) > 1 else "?"
        rows = struct.unpack_from("<I", payload, 32)[0] if len(payload) >= 40 else 0
        now = time.time_ns()
        entry = self.drops.setdefault(session, [0, 0, now, now])
        entry[0] += 1
        entry[1] += rows
        entry[3] = now
        self.dropped_total += 1

    def get_all(self, timeout: float) -> list[tuple[str, str, Any]]:
        """Everything queued (waiting up to `timeout` for something): one wake-up per batch."""
        with self.cv:
            if not self.q:
                self.cv.wait(timeout)
            items = list(self.q)
            self.q.clear()
            self.frames = 0
            self.bytes = 0
            return items

    def take_drops(self) -> dict[str, list[int]]:
        with self.cv:
            drops, self.drops = self.drops, {}
            return drops

    def wake(self) -> None:
        with self.cv:
            self.cv.notify_all()


@dataclass
class Active:
    """A recording being written."""

    layout: m.RunLayout
    name: str
    path: Path
    writer: fmt.RunWriter
    last_data: float
    final_seen: bool = False
    final_rows: int = 0
    close_at: float | None = None
    end_phase: str = ""
    end_reason: str = ""
    last_phase: str = ""
    sim_time: float = 0.0
    dropped_frames: int = 0  # seen as gaps in frame numbers (misses frames lost after the last one)
    queue_drops: int = 0  # dropped by our own queue (misses frames lost before reaching it)
    dropped_rows: int = 0
    stray_frames: int = 0
    params_written: bool = False
    idle_checked: float = 0.0
    next_seq: int | None = 0  # None: accept any first frame (a continuation starts mid-run)
    noticed: set[str] = field(default_factory=set)  # kinds of Notice already sent for this run


@dataclass
class Child:
    proc: subprocess.Popen[bytes]
    log: Path
    session: str
    name: str
    started: float = field(default_factory=time.monotonic)


class Recorder(Node):
    """Records every run as an MCAP file; lists, serves, accepts and replays recordings."""

    role = "recorder"
    tick_s = 0.5

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        directory: str = "recordings",
        viz_rate_hz: float = 50.0,
        queue_frames: int = 4096,
        queue_mb: float = 256.0,
        idle_timeout_s: float = 30.0,
        mesh_config_path: str | None = None,
    ) -> None:
        super().__init__(mesh, node_id)
        self.dir = Path(directory).resolve()
        self.viz_rate_hz = viz_rate_hz
        self.idle_timeout_s = idle_timeout_s
        self.mesh_config_path = mesh_config_path
        self.ingest = Ingest(queue_frames, int(queue_mb * 1024 * 1024))
        self.active: dict[str, Active] = {}
        self.pending: dict[str, collections.deque[bytes]] = {}
        self.params: dict[str, m.ParamValues] = {}
        self.done: collections.OrderedDict[tuple[str, str], None] = collections.OrderedDict()
        self.ignored: set[str] = set()  # sessions that are replays: never re-recorded
        self.models: dict[str, tuple[ModelDescription, bytes]] = {}
        self.lock = threading.Condition()  # guards open_names and info_cache
        self.open_names: dict[str, m.RecordingInfo] = {}
        self.info_cache: dict[str, tuple[tuple[int, int], m.RecordingInfo | None]] = {}
        self.children: list[Child] = []
        self.stats = {"rows": 0, "messages": 0, "files": 0, "recovered": 0, "dropped_frames": 0}
        self._writer_stop = threading.Event()
        self._lookups: collections.deque[tuple[str, str, str]] = collections.deque()
        self._lookup_cv = threading.Condition()
        self._last_drop_status = 0.0

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--dir", default="recordings", help="where recordings are written (default recordings)"
        )
        parser.add_argument(
            "--viz-rate",
            type=float,
            default=100.0,
            help="max /tf and /joint_states samples per simulated second",
        )
        parser.add_argument("--queue-frames", type=int, default=4096, help="frames buffered before dropping")
        parser.add_argument(
            "--queue-mb", type=float, default=256.0, help="frame bytes buffered before dropping"
        )
        parser.add_argument(
            "--idle-timeout",
            type=float,
            default=30.0,
            help="close a run silent this long whose worker is gone",
        )

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Recorder:
        return cls(
            mesh_from_args(args),
            args.node_id,
            args.dir,
            args.viz_rate,
            args.queue_frames,
            args.queue_mb,
            args.idle_timeout,
            args.mesh_config,
        )

    def status_detail(self) -> dict[str, Any]:
        with self.lock:
            recording = sorted(self.open_names)
        return {
            "dir": str(self.dir),
            "recording": recording,
            **self.stats,
            "dropped_frames": self.ingest.dropped_total,
        }

    # -- startup -----------------------------------------------------------------------------------
    def run(self) -> int:
        """Repair torn files before joining the mesh: ready means every old file is whole again."""
        self.dir.mkdir(parents=True, exist_ok=True)
        self._recover_all()
        return super().run()

    def start(self) -> None:
        self._writer = threading.Thread(target=self._writer_loop, name="recorder-writer", daemon=True)
        self._writer.start()
        self._lookup = threading.Thread(target=self._lookup_loop, name="recorder-lookup", daemon=True)
        self._lookup.start()
        # No Python runs in zenoh's threads (a slow callback, or one waiting for the GIL while the
        # writer encodes, would stall the link and with it the simulator): samples land in native ring
        # buffers (a full ring drops its oldest sample: for frames, seen as a gap in frame numbers) and
        # a puller thread moves them into the writer's queue.
        self._subs = [
            (self._ring(keys.ALL_LAYOUT, latched=True), "layout"),
            (self._ring(keys.ALL_STATE, latched=True), "state"),
            (self._ring(keys.ALL_PARAMS, latched=True), "params"),
            (self._ring(keys.ALL_FULL, latched=False), "full"),
        ]
        self._puller = threading.Thread(target=self._pull_loop, name="recorder-puller", daemon=True)
        self._puller.start()
        self.serve(keys.RECORDINGS, self._on_list, threaded=True)
        self.serve(keys.ALL_RECORDINGS, self._on_file, threaded=True)
        self.serve(keys.ALL_REPLAYS, self._on_replay, threaded=True)

    def _ring(self, key: str, latched: bool) -> Any:
        ring = zenoh.handlers.RingChannel(RING_FRAMES)
        if latched:
            history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
            return self.declare(zenoh.ext.declare_advanced_subscriber(self.z, key, ring, history=history))
        return self.declare(self.z.declare_subscriber(key, ring))

    def _pull_loop(self) -> None:
        put, stop = self.ingest.put, self._writer_stop
        last_data = 0.0
        while not stop.is_set():
            moved = False
            for sub, kind in self._subs:
                for _ in range(256):
                    sample = sub.try_recv()
                    if sample is None:
                        break
                    put(kind, str(sample.key_expr), sample.payload.to_bytes())
                    moved = True
            now = time.monotonic()
            if moved:
                last_data = now
            else:  # poll often while data flows, seldom when idle (a 2 ms poll costs 3 % of a core)
                time.sleep(0.005 if now - last_data < 0.5 else 0.02)

    def _recover_all(self) -> None:
        """Repair every torn file left by a crash; skip files another writer holds locked."""
        for tmp in self.dir.glob(".*.tmp"):
            try:
                tmp.unlink()
            except OSError:
                pass
        for path in sorted(self.dir.glob("*.mcap")):
            if mcapread.has_footer(path) or self._locked(path):
                continue
            try:
                rec = mcapread.recover(path)
            except (mcapread.RecordingError, OSError) as exc:
                self.log.error("cannot recover %s (left as it is): %s", path, exc)
                continue
            if rec is not None:
                self.stats["recovered"] += 1
                self.log.warning(
                    "recovered torn recording %s: kept %d messages (%s)", path.name, rec.messages, rec.problem
                )

    @staticmethod
    def _locked(path: Path) -> bool:
        try:
            with open(path, "rb") as fh:
                try:
                    fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    return True
                fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
        except OSError:
            return True
        return False

    # -- the writer thread ---------------------------------------------------------------------------
    def _writer_loop(self) -> None:
        # Encoding and compressing yield the CPU to the simulator: only this thread is niced (Linux
        # priorities are per thread), so zenoh's receive threads and the puller keep up and the rings
        # and the queue absorb whatever the writer lags behind.
        try:
            tid = threading.get_native_id()
            os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + WRITER_NICE))
        except (OSError, AttributeError):
            pass
        next_house = 0.0
        while not self._writer_stop.is_set():
            batch = self.ingest.get_all(timeout=0.1)
            for kind, key, payload in batch:
                try:
                    getattr(self, f"_on_{kind}")(key, payload)
                except Exception:
                    self.log.error("recorder failed on %s %s:\n%s", kind, key, traceback.format_exc())
                now = time.monotonic()
                if now >= next_house:  # a long batch must not delay flushes
                    next_house = now + 0.05
                    self._housekeeping(now)
            if 0 < len(batch) < BATCH_MIN:
                # Waking per frame costs more than the frame: let a few accumulate (latency is free here).
                self._writer_stop.wait(BATCH_WAIT_S)
            now = time.monotonic()
            if now >= next_house:
                next_house = now + 0.05
                try:
                    self._housekeeping(now)
                except Exception:
                    self.log.error("recorder housekeeping failed:\n%s", traceback.format_exc())
        for rec in list(self.active.values()):
            self._close(rec, "recorder stopped")

    def _on_layout(self, key: str, payload: bytes) -> None:
        try:
            layout = codec.loads(m.RunLayout, payload)
            keys.recording_name(layout.session, layout.run_id)
            if layout.session != keys.session_of(key):
                raise ValueError(f"layout of session {layout.session} published under {key}")
        except (codec.DecodeError, ValueError) as exc:
            self.log.warning("ignoring bad layout on %s: %s", key, exc)
            return
        sid = layout.session
        cur = self.active.get(sid)
        if cur is not None:
            if cur.layout.run_id == layout.run_id and cur.layout.run_index == layout.run_index:
                return  # the same layout again (history and live)
            self._close(cur, f"superseded by run {layout.run_id}")
        if (sid, layout.run_id) in self.done or sid in self.ignored:
            return
        if layout.source == "replay":
            self.ignored.add(sid)
            self.pending.pop(sid, None)
            self.log.info("session %s is a replay: not recorded", sid)
            return
        self._open(layout)

    def _open(self, layout: m.RunLayout) -> None:
        base = keys.recording_name(layout.session, layout.run_id)
        name, k = base, 2
        while (self.dir / f"{name}.mcap").exists():
            name, k = f"{base}.{k}", k + 1
        path = self.dir / f"{name}.mcap"
        run_meta = {"recorder": self.node_id}
        if name != base:
            run_meta["continues"] = base
        try:
            writer = fmt.RunWriter(path, layout, viz_rate_hz=self.viz_rate_hz, run_meta=run_meta)
        except (OSError, fmt.FormatError) as exc:
            self.log.error("cannot record run %s of %s into %s: %s", layout.run_id, layout.session, path, exc)
            return
        rec = Active(
            layout, name, path, writer, last_data=time.monotonic(), next_seq=None if name != base else 0
        )
        self.active[layout.session] = rec
        info = m.RecordingInfo(name, layout.session, layout.run_id, layout.model_id, 0)
        with self.lock:
            self.open_names[name] = info
        self.stats["files"] += 1
        note = f" (continues {base}: the recorder restarted during the run)" if name != base else ""
        writer.write_log(
            fmt.LOG_INFO,
            f"recording started: session {layout.session} run {layout.run_id} model {layout.model_id}, "
            f"{len(layout.columns)} columns{note}",
            0.0,
        )
        pv = self.params.get(layout.session)
        if pv is not None and pv.model_id == layout.model_id:
            self._write_params(rec, pv.values)
        with self._lookup_cv:
            self._lookups.append((layout.session, layout.run_id, layout.model_id))
            self._lookup_cv.notify()
        self.log.info("recording %s", path.name)
        for payload in self.pending.pop(layout.session, ()):
            self._write(rec, payload)

    def _on_full(self, key: str, payload: bytes) -> None:
        try:
            sid = keys.session_of(key)
        except ValueError:
            return
        rec = self.active.get(sid)
        if rec is None:
            if sid not in self.ignored:
                if sid not in self.pending and len(self.pending) >= 64:
                    self.pending.pop(next(iter(self.pending)))  # the oldest session without a layout
                self.pending.setdefault(sid, collections.deque(maxlen=PENDING_FRAMES)).append(payload)
            return
        self._write(rec, payload)

    def _write(self, rec: Active, payload: bytes) -> None:
        try:
            frame = frames.decode(payload)
        except frames.FrameError as exc:
            rec.writer.write_log(fmt.LOG_WARNING, f"undecodable frame skipped: {exc}", rec.sim_time)
            return
        if frame.run_index != rec.layout.run_index:
            rec.stray_frames += 1
            return
        if rec.next_seq is not None and frame.seq > rec.next_seq:
            missing = frame.seq - rec.next_seq
            rec.dropped_frames += missing
            self._notice(rec, "gap", "frames were lost before reaching the recorder: the recording has gaps")
            rec.writer.write_log(
                fmt.LOG_ERROR,
                f"MISSING frames {rec.next_seq}..{frame.seq - 1} ({missing} frames): dropped before "
                f"they were "
                f"written (recorder overloaded or the network lost them); the file has a gap after t = "
                f"{rec.sim_time:.4f} s",
                rec.sim_time,
            )
        rec.next_seq = max(rec.next_seq or 0, frame.seq + 1)
        try:
            written = rec.writer.write_frame(frame)
        except fmt.FormatError as exc:
            rec.writer.write_log(fmt.LOG_WARNING, f"frame skipped: {exc}", rec.sim_time)
            return
        except OSError as exc:
            self._fail(rec, exc)
            return
        n = frame.rows.shape[0]
        self.stats["rows"] += n
        self.stats["messages"] += written
        rec.last_data = time.monotonic()
        if n:
            rec.sim_time = float(frame.rows[-1, 0])
        if frame.final:
            rec.final_seen = True
            rec.final_rows = n
            deadline = rec.last_data + (0.0 if rec.end_phase else FINAL_GRACE_S)
            rec.close_at = deadline if rec.close_at is None else min(rec.close_at, deadline)

    def _on_state(self, key: str, payload: bytes) -> None:
        try:
            st = codec.loads(m.SessionState, payload)
        except codec.DecodeError as exc:
            self.log.warning("ignoring bad state on %s: %s", key, exc)
            return
        if st.phase == "closed":
            self.params.pop(st.session, None)
            self.pending.pop(st.session, None)
        rec = self.active.get(st.session)
        if rec is None or st.run_id != rec.layout.run_id:
            return
        if st.phase != rec.last_phase:
            rec.last_phase = st.phase
            level = LOG_LEVEL.get(st.phase, fmt.LOG_WARNING if st.phase != "failed" else fmt.LOG_ERROR)
            text = f"run {st.run_id} {st.phase}" + (f": {st.reason}" if st.reason else "")
            if st.phase in ("running", "paused", *ENDED):
                text += f" at t = {st.sim_time:.4f} s"
            rec.writer.write_log(level, text, st.sim_time)
        if st.phase in ENDED:
            rec.end_phase, rec.end_reason = st.phase, st.reason
            deadline = time.monotonic() + (0.0 if rec.final_seen else ENDED_GRACE_S)
            rec.close_at = deadline if rec.close_at is None else min(rec.close_at, deadline)

    def _on_params(self, key: str, payload: bytes) -> None:
        try:
            pv = codec.loads(m.ParamValues, payload)
        except codec.DecodeError as exc:
            self.log.warning("ignoring bad params on %s: %s", key, exc)
            return
        self.params[pv.session] = pv
        rec = self.active.get(pv.session)
        if rec is not None and not rec.params_written and pv.model_id == rec.layout.model_id:
            self._write_params(rec, pv.values)

    def _write_params(self, rec: Active, values: dict[str, float]) -> None:
        rec.writer.write_metadata(fmt.META_PARAMS, {k: repr(float(v)) for k, v in values.items()})
        rec.params_written = True

    def _on_context(self, key: str, ctx: dict[str, Any]) -> None:
        """Model description and session snapshot of a run, fetched by the lookup thread."""
        rec = self.active.get(ctx["session"])
        if rec is None or rec.layout.run_id != ctx["run_id"]:
            return
        w = rec.writer
        values: dict[str, float] = {}
        snap: m.SessionSnapshot | None = ctx.get("snapshot")
        if snap is not None:
            values = dict(snap.values)
            w.write_metadata(
                fmt.META_SESSION,
                {
                    "user": snap.user,
                    "initial": json.dumps(snap.initial),
                    "command": codec.dumps(snap.command).decode(),
                    "settings": codec.dumps(snap.settings).decode(),
                },
            )
            if not rec.params_written:
                self._write_params(rec, values)
        elif ctx.get("snapshot_error"):
            w.write_log(fmt.LOG_WARNING, f"no command/settings metadata: {ctx['snapshot_error']}", 0.0)
        if not values and ctx["session"] in self.params:
            values = dict(self.params[ctx["session"]].values)
        model: tuple[ModelDescription, bytes] | None = ctx.get("model")
        if model is not None:
            desc, desc_json = model
            w.write_scene(desc, values or desc.default_values())
            w.write_attachment(fmt.ATTACH_MODEL, "application/json", desc_json)
        else:
            w.write_log(fmt.LOG_WARNING, f"no model description, no /scene: {ctx.get('model_error')}", 0.0)

    def _notice(self, rec: Any, kind: str, message: str) -> None:
        """Tell the session (its state lists it), once per run and kind; details are in the file's /log."""
        if kind in rec.noticed:
            return
        rec.noticed.add(kind)
        notice = m.Notice(
            session=rec.layout.session, run_id=rec.layout.run_id, source="recorder", message=message
        )
        try:
            self.z.put(keys.notices(rec.layout.session), codec.dumps(notice))
        except Exception as exc:  # the file still says it
            self.log.warning("could not publish a notice: %s", exc)

    def _housekeeping(self, now: float) -> None:
        drops = self.ingest.take_drops()
        for sid, (n, rows, first, last) in drops.items():
            self.stats["dropped_frames"] += n
            rec = self.active.get(sid)
            text = (
                f"DROPPED {n} frames ({rows} samples) received between wall times {first} and {last} ns: "
                "the recorder could not keep up (queue full); the file has a gap there"
            )
            self.log.warning("session %s: %s", sid, text)
            if rec is not None:
                rec.queue_drops += n
                rec.dropped_rows += rows
                self._notice(
                    rec, "queue", "the recorder could not keep up and dropped samples: the recording has gaps"
                )
                rec.writer.write_log(fmt.LOG_ERROR, text, rec.sim_time)
        if drops and now - self._last_drop_status > 1.0:
            self._last_drop_status = now
            self.publish_status("ready")
        for rec in list(self.active.values()):
            if rec.close_at is not None and now >= rec.close_at:
                self._close(rec, "final frame" if rec.final_seen else "run ended")
                continue
            if rec.writer.dirty and now - rec.writer.last_flush >= fmt.FLUSH_S:
                try:
                    rec.writer.flush()
                except OSError as exc:
                    self._fail(rec, exc)
                    continue
            if (
                now - rec.last_data > self.idle_timeout_s
                and now - rec.idle_checked > self.idle_timeout_s
                and rec.close_at is None
            ):
                rec.idle_checked = now
                if not self._worker_alive(rec):
                    self._close(rec, f"no data for {self.idle_timeout_s:g} s and the run's worker is gone")

    def _worker_alive(self, rec: Active) -> bool:
        token = keys.run_token(rec.layout.session, rec.layout.run_id)
        try:
            return any(r.ok is not None for r in self.z.liveliness().get(token, timeout=1.0))
        except zenoh.ZError:
            return True

    def _close(self, rec: Active, closed_by: str) -> None:
        self.active.pop(rec.layout.session, None)
        phase = rec.end_phase or ("finished" if rec.final_seen and rec.final_rows else "")
        phase = phase or ("ended" if rec.final_seen else "incomplete")
        w = rec.writer
        # Each count sees a subset of the losses; both are lower bounds, the larger one is reported.
        dropped = max(rec.dropped_frames, rec.queue_drops)
        try:
            summary = f"recording closed ({closed_by}): run {phase}, {w.rows} samples in {w.frames} frames"
            if dropped:
                summary += f"; at least {dropped} frames DROPPED"
            w.write_log(fmt.LOG_INFO if not dropped else fmt.LOG_ERROR, summary, rec.sim_time)
            w.close(
                {
                    "phase": phase,
                    "reason": rec.end_reason,
                    "closed_by": closed_by,
                    "dropped_frames": str(dropped),
                    "dropped_rows": str(rec.dropped_rows),
                    "stray_frames": str(rec.stray_frames),
                    "sim_time": repr(rec.sim_time),
                    "closed_ns": str(time.time_ns()),
                }
            )
            self.log.info("closed %s (%s, %s, %d samples)", rec.path.name, phase, closed_by, w.rows)
        except OSError as exc:
            self._fail(rec, exc)
        finally:
            self._forget(rec)

    def _fail(self, rec: Active, exc: BaseException) -> None:
        """Writing failed (disk full, ...): keep what is on disk, repaired if possible."""
        self.active.pop(rec.layout.session, None)
        rec.writer.abandon()
        self.log.error("recording %s failed: %s; repairing what was written", rec.path.name, exc)
        try:
            mcapread.recover(rec.path)
        except Exception as exc2:
            self.log.error("could not repair %s now (will retry on restart): %s", rec.path.name, exc2)
        self._forget(rec)

    def _forget(self, rec: Active) -> None:
        self.done[(rec.layout.session, rec.layout.run_id)] = None
        while len(self.done) > 4096:
            self.done.popitem(last=False)
        with self.lock:
            self.open_names.pop(rec.name, None)
            self.lock.notify_all()

    # -- the lookup thread: model description and session snapshot of each new run -----------------
    def _lookup_loop(self) -> None:
        client = MeshClient(self.z, timeout=3.0)
        while not self._writer_stop.is_set():
            with self._lookup_cv:
                if not self._lookups:
                    self._lookup_cv.wait(0.5)
                if not self._lookups:
                    continue
                session, run_id, model_id = self._lookups.popleft()
            ctx: dict[str, Any] = {"session": session, "run_id": run_id}
            try:
                if model_id not in self.models:
                    desc = client.describe(model_id)
                    self.models[model_id] = (desc, codec.dumps(desc))
                ctx["model"] = self.models[model_id]
            except (RemoteError, NoReply, codec.DecodeError, ValueError, zenoh.ZError) as exc:
                ctx["model_error"] = f"model {model_id}: {exc}"
            try:
                ctx["snapshot"] = client.session(session).snapshot()
            except (RemoteError, NoReply, codec.DecodeError, ValueError, zenoh.ZError) as exc:
                ctx["snapshot_error"] = f"session {session}: {exc}"
            self.ingest.put("context", "", ctx)

    # -- serving recordings ------------------------------------------------------------------------------
    def _path(self, name: str) -> Path:
        if name.endswith(".mcap"):
            name = name[: -len(".mcap")]
        try:
            keys.check_name(name, "recording name")
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "name") from None
        return self.dir / f"{name}.mcap"

    def _info(self, path: Path) -> m.RecordingInfo | None:
        name = path.name[: -len(".mcap")]
        with self.lock:
            if name in self.open_names:
                info = self.open_names[name]
                return m.RecordingInfo(
                    info.name, info.session, info.run_id, info.model_id, path.stat().st_size
                )
        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
        cached = self.info_cache.get(name)
        if cached is not None and cached[0] == stamp:
            return cached[1]
        try:
            info: m.RecordingInfo | None = mcapread.info(path)
        except (mcapread.RecordingError, OSError) as exc:
            self.log.warning("not listing %s: %s", path.name, exc)
            info = None
        with self.lock:
            self.info_cache[name] = (stamp, info)
        return info

    def _on_list(self, req: Request) -> m.RecordingList:
        paths = sorted(self.dir.glob("*.mcap"), key=lambda p: p.stat().st_mtime_ns, reverse=True)
        out = []
        for p in paths:
            try:
                info = self._info(p)
            except FileNotFoundError:
                continue
            if info is not None:
                out.append(info)
        return m.RecordingList(out)

    def _on_file(self, req: Request) -> Any:
        path = self._path(keys.last_chunk(req.key))
        if req.payload is not None:
            return self._upload(path, req.payload)
        name = path.name[: -len(".mcap")]
        end = time.monotonic() + DOWNLOAD_WAIT_S
        with self.lock:
            while name in self.open_names and time.monotonic() < end:
                self.lock.wait(0.1)
            if name in self.open_names:
                raise RequestError(
                    "conflict",
                    f"recording {name} is still being written (its run is going on): "
                    "download it when the run has ended",
                    "name",
                )
        if not path.is_file():
            raise RequestError("not_found", f"no recording {name!r} in {self.dir}", "name")
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise RequestError(
                "unsupported", f"recording {name} is {size} bytes, more than the {MAX_FILE_BYTES} served"
            )
        info = self._info(path)
        return Binary(path.read_bytes(), attachment=codec.to_obj(info) if info else {"name": name})

    def _upload(self, path: Path, data: bytes) -> m.RecordingInfo:
        name = path.name[: -len(".mcap")]
        if len(data) > MAX_FILE_BYTES:
            raise RequestError(
                "bad_request", f"upload {name}: {len(data)} bytes is more than {MAX_FILE_BYTES}"
            )
        try:
            mcapread.validate(data)
            rec = mcapread.load(data, strict=True)
        except mcapread.RecordingError as exc:
            raise RequestError(
                "bad_request",
                f"upload {name} refused: {str(exc).replace('uploaded file', 'the file', 1)}",
                "payload",
            ) from None
        with self.lock:
            if path.exists() or name in self.open_names:
                raise RequestError(
                    "conflict", f"a recording named {name!r} already exists; choose another name", "name"
                )
            files.atomic_write(path, data)
        self.log.info(
            "stored uploaded recording %s (%d bytes, %d samples)", path.name, len(data), len(rec.rows)
        )
        lay = rec.layout
        return m.RecordingInfo(name, lay.session, lay.run_id, lay.model_id, len(data), rec.recovered)

    def _on_replay(self, req: Request) -> dict[str, str]:
        parts = req.key.split("/")
        path = self._path(parts[2])
        request = req.json(m.ReplayRequest) if req.payload else m.ReplayRequest()
        name = path.name[: -len(".mcap")]
        if not path.is_file():
            raise RequestError("not_found", f"no recording {name!r} in {self.dir}", "name")
        with self.lock:
            if name in self.open_names:
                raise RequestError(
                    "conflict", f"recording {name} is still being written; replay it when the run ends"
                )
        sid = request.session or keys.new_session_id()
        if not keys.is_session_id(sid):
            raise RequestError(
                "bad_request", f"{sid!r} is not a session id (22 URL-safe characters)", "session"
            )
        if request.session and self._session_exists(sid):
            raise RequestError(
                "conflict", f"session {sid} already exists; leave session empty for a new one", "session"
            )
        argv = [
            sys.executable,
            "-m",
            "simecs.nodes.replay",
            str(path),
            f"--session={sid}",  # '=': an id may start with '-'
            "--speed",
            repr(request.speed),
        ]
        if request.paused:
            argv.append("--paused")
        for ep in self.mesh.connect or self.mesh.listen:
            argv += ["--connect", ep]
        if self.mesh_config_path:
            argv += ["--mesh-config", self.mesh_config_path]
        self.ignored.add(sid)  # never record our own replay
        log = self.dir / f".replay-{sid}.log"
        with open(log, "wb") as out:
            proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        self.children.append(Child(proc, log, sid, name))
        token = keys.node_token("replay", f"replay-{sid}")
        end = time.monotonic() + 20.0
        while time.monotonic() < end:
            if proc.poll() is not None:
                tail = log.read_text(errors="replace")[-800:] if log.exists() else ""
                raise RequestError(
                    "internal", f"replay of {name} exited with code {proc.returncode}: {tail.strip()}"
                )
            if any(r.ok is not None for r in self.z.liveliness().get(token, timeout=0.5)):
                self.log.info("replaying %s as session %s (pid %d)", name, sid, proc.pid)
                return {"session": sid}
            time.sleep(0.05)
        proc.kill()
        raise RequestError("internal", f"replay of {name} did not come up within 20 s")

    def _session_exists(self, sid: str) -> bool:
        try:
            for reply in self.z.get(keys.cmd(sid), payload=codec.dumps(m.GetSession()), timeout=2.0):
                if reply.ok is not None:
                    return True
        except zenoh.ZError:
            pass
        return False

    # -- lifecycle -----------------------------------------------------------------------------------
    def tick(self) -> None:
        for child in list(self.children):
            code = child.proc.poll()
            if code is None:
                continue
            self.children.remove(child)
            if code == 0:
                try:
                    child.log.unlink()
                except OSError:
                    pass
            else:
                self.log.warning(
                    "replay of %s (session %s) exited with %d; see %s",
                    child.name,
                    child.session,
                    code,
                    child.log,
                )

    def stop(self) -> None:
        self._writer_stop.set()
        self.ingest.wake()
        with self._lookup_cv:
            self._lookup_cv.notify_all()
        for thread in (getattr(self, "_puller", None), getattr(self, "_writer", None)):
            if thread is not None:
                thread.join(timeout=10.0)
        for child in self.children:
            if child.proc.poll() is None:
                child.proc.terminate()
        for child in self.children:
            try:
                child.proc.wait(timeout=3.0)
            except subprocess.TimeoutExpired:
                child.proc.kill()


def main(argv: list[str] | None = None) -> int:
    return main_for(Recorder, argv)


if __name__ == "__main__":
    main()
