"""The recording pipeline: every run written as one MCAP file, crash-safe, without slowing the simulator.

A `RunLayout` opens `<dir>/<session>_<run>.mcap` (its context gives the file's parameter and session
metadata at once); the run's final frame (or its ended state, or a silent worker) closes it. No Python
runs in zenoh's threads (a slow callback would stall the whole link, simulator included): samples land
in native ring buffers, a puller thread moves them to a bounded queue, and one writer thread, at a
lower CPU priority, owns the files. If frames are ever dropped (queue full, ring overflow, or lost on
the way: gaps in frame numbers), the file says so on /log and in `simecs.end`, the session gets a
`Notice`, and the node's status counts them. Files are flushed about once a second, so a crash loses
at most ~1 s. Replays are not recorded again.
"""

from __future__ import annotations

import collections
import os
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh
import zenoh.ext
from simecs.mesh import codec, frames, keys, phases
from simecs.mesh import messages as m
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.model import ModelDescription

from . import mcapfmt as fmt
from . import mcapread
from .recordings_library import RecordingsLibrary

FINAL_GRACE_S = 0.3  # after the final frame: let the run's ended state arrive for the end phase
ENDED_GRACE_S = 2.0  # after an ended state without final frame: frames may still be on their way
BATCH_MIN = 8  # frames: a smaller batch makes the writer wait BATCH_WAIT_S before the next one
BATCH_WAIT_S = 0.02
WRITER_NICE = 10  # how much lower the writer thread's CPU priority is than the node's
RING_FRAMES = 8192  # samples zenoh holds per subscription for the puller thread
PENDING_FRAMES = 256  # frames kept per session while its layout has not arrived yet
PENDING_SESSIONS = 64  # sessions whose frames wait for a layout
VIZ_RATE_HZ = 50.0  # /tf and /joint_states samples per simulated second
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
        try:
            session = keys.session_of(key)
            rows = frames.peek(payload).n_rows
        except (ValueError, frames.FrameError):
            return  # not a frame of a session: nothing a recording misses
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
    idle_checked: float = 0.0
    next_seq: int | None = 0  # None: accept any first frame (a continuation starts mid-run)
    noticed: set[str] = field(default_factory=set)  # kinds of Notice already sent for this run


class RecordingPipeline:
    """Subscriptions in, MCAP files out: one writer thread owns every open file."""

    def __init__(
        self,
        library: RecordingsLibrary,
        node_id: str,
        log: Any,
        status_changed: Callable[[], None],
        viz_rate_hz: float = VIZ_RATE_HZ,
        queue_frames: int = 4096,
        queue_mb: float = 256.0,
        idle_timeout_s: float = 30.0,
    ) -> None:
        self.library = library
        self.node_id = node_id
        self.log = log
        self.status_changed = status_changed
        self.viz_rate_hz = viz_rate_hz
        self.idle_timeout_s = idle_timeout_s
        self.ingest = Ingest(queue_frames, int(queue_mb * 1024 * 1024))
        self.active: dict[str, Active] = {}
        self.pending: dict[str, collections.deque[bytes]] = {}
        self.done: collections.OrderedDict[tuple[str, str], None] = collections.OrderedDict()
        self.ignored: set[str] = set()  # sessions whose current run is a replay
        self.models: dict[str, tuple[ModelDescription, bytes]] = {}
        self.stats = {"rows": 0, "messages": 0, "files": 0, "dropped_frames": 0}
        self._stop = threading.Event()
        self._lookups: collections.deque[tuple[str, str, str]] = collections.deque()
        self._lookup_cv = threading.Condition()
        self._last_drop_status = 0.0
        self._threads: list[threading.Thread] = []
        self._subs: list[tuple[Any, str]] = []
        self.z: zenoh.Session | None = None

    # -- threads ------------------------------------------------------------------------------------
    def start(self, z: zenoh.Session, declare: Callable[[Any], Any]) -> None:
        """Subscribe and start the threads. No Python runs in zenoh's threads (a slow callback, or one
        waiting for the GIL while the writer encodes, would stall the link and with it the simulator):
        samples land in native ring buffers (a full ring drops its oldest sample: for frames, seen as a
        gap in frame numbers) and a puller thread moves them into the writer's queue."""
        self.z = z

        def ring(key: str, latched: bool) -> Any:
            channel: Any = zenoh.handlers.RingChannel(RING_FRAMES)
            if latched:
                history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
                return declare(zenoh.ext.declare_advanced_subscriber(z, key, channel, history=history))
            return declare(z.declare_subscriber(key, channel))

        self._subs = [
            (ring(keys.ALL_LAYOUT, latched=True), "layout"),
            (ring(keys.ALL_STATE, latched=True), "state"),
            (ring(keys.ALL_FULL, latched=False), "full"),
        ]
        for target, name in (
            (self._writer_loop, "writer"),
            (self._lookup_loop, "lookup"),
            (self._pull_loop, "puller"),
        ):
            thread = threading.Thread(target=target, name=f"recorder-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self) -> None:
        self._stop.set()
        self.ingest.wake()
        with self._lookup_cv:
            self._lookup_cv.notify_all()
        for thread in self._threads:
            thread.join(timeout=10.0)

    def _pull_loop(self) -> None:
        put, stop = self.ingest.put, self._stop
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

    def _writer_loop(self) -> None:
        # Encoding and compressing yield the CPU to the simulator: only this thread is niced (Linux
        # priorities are per thread), so zenoh's receive threads and the puller keep up and the rings
        # and the queue absorb whatever the writer lags behind.
        try:
            tid = threading.get_native_id()
            os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + WRITER_NICE))
        except (OSError, AttributeError):
            pass
        handlers: dict[str, Callable[[str, Any], None]] = {
            "layout": self._on_layout,
            "state": self._on_state,
            "full": self._on_full,
            "model": self._on_model,
        }
        next_house = 0.0
        while not self._stop.is_set():
            batch = self.ingest.get_all(timeout=0.1)
            for kind, key, payload in batch:
                try:
                    handlers[kind](key, payload)
                except Exception:
                    self.log.error("recorder failed on %s %s:\n%s", kind, key, traceback.format_exc())
                now = time.monotonic()
                if now >= next_house:  # a long batch must not delay flushes
                    next_house = now + 0.05
                    self._housekeeping(now)
            if 0 < len(batch) < BATCH_MIN:
                # Waking per frame costs more than the frame: let a few accumulate (latency is free here).
                self._stop.wait(BATCH_WAIT_S)
            now = time.monotonic()
            if now >= next_house:
                next_house = now + 0.05
                try:
                    self._housekeeping(now)
                except Exception:
                    self.log.error("recorder housekeeping failed:\n%s", traceback.format_exc())
        for rec in list(self.active.values()):
            self._close(rec, "recorder stopped")

    # -- what arrives ---------------------------------------------------------------------------------
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
        if (sid, layout.run_id) in self.done:
            return
        if layout.source == "replay":
            self.ignored.add(sid)
            self.pending.pop(sid, None)
            self.log.info("session %s run %s is a replay: not recorded", sid, layout.run_id)
            return
        self.ignored.discard(sid)
        self._open(layout)

    def _open(self, layout: m.RunLayout) -> None:
        base = keys.recording_name(layout.session, layout.run_id)
        name = self.library.free_name(base)
        path = self.library.path_of(name)
        run_meta = {"recorder": self.node_id}
        if name != base:
            run_meta["continues"] = base
        try:
            writer = fmt.RunWriter(path, layout, viz_rate_hz=self.viz_rate_hz, run_meta=run_meta)
        except (OSError, fmt.FormatError) as exc:
            self.log.error("cannot record run %s of %s into %s: %s", layout.run_id, layout.session, path, exc)
            return
        rec = Active(layout, name, writer, last_data=time.monotonic(), next_seq=None if name != base else 0)
        self.active[layout.session] = rec
        self.library.opened(
            m.RecordingInfo(name, layout.session, layout.run_id, layout.model_id, 0, False, layout.stop_time)
        )
        self.stats["files"] += 1
        note = f" (continues {base}: the recorder restarted during the run)" if name != base else ""
        writer.write_log(
            fmt.LOG_INFO,
            f"recording started: session {layout.session} run {layout.run_id} model {layout.model_id}, "
            f"{len(layout.columns)} columns{note}",
            0.0,
        )
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
                if sid not in self.pending and len(self.pending) >= PENDING_SESSIONS:
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
                f"MISSING frames {rec.next_seq}..{frame.seq - 1} ({missing} frames): dropped before they "
                f"were written (recorder overloaded or the network lost them); the file has a gap after t = "
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
            self.pending.pop(st.session, None)
            self.ignored.discard(st.session)
        rec = self.active.get(st.session)
        if rec is None or st.run_id != rec.layout.run_id:
            return
        if st.phase != rec.last_phase:
            rec.last_phase = st.phase
            level = LOG_LEVEL.get(st.phase, fmt.LOG_WARNING if st.phase != "failed" else fmt.LOG_ERROR)
            text = f"run {st.run_id} {st.phase}" + (f": {st.reason}" if st.reason else "")
            if st.phase in (*phases.GOING, *phases.ENDED):
                text += f" at t = {st.sim_time:.4f} s"
            rec.writer.write_log(level, text, st.sim_time)
        if st.phase in phases.ENDED:
            rec.end_phase, rec.end_reason = st.phase, st.reason
            deadline = time.monotonic() + (0.0 if rec.final_seen else ENDED_GRACE_S)
            rec.close_at = deadline if rec.close_at is None else min(rec.close_at, deadline)

    def _on_model(self, key: str, lookup: tuple[str, str, str]) -> None:
        """The model description of a run, fetched by the lookup thread: the /scene and model.json."""
        session, run_id, model_id = lookup
        rec = self.active.get(session)
        if rec is None or rec.layout.run_id != run_id:
            return
        model = self.models.get(model_id)
        if model is None:
            rec.writer.write_log(fmt.LOG_WARNING, f"no model description of {model_id}: no /scene", 0.0)
            return
        desc, desc_json = model
        rec.writer.write_scene(desc, rec.layout.context.values or desc.default_values())
        rec.writer.write_attachment(fmt.ATTACH_MODEL, "application/json", desc_json)

    # -- the lookup thread: the model description of each new run ------------------------------------
    def _lookup_loop(self) -> None:
        assert self.z is not None
        client = MeshClient(self.z, timeout=3.0)
        while not self._stop.is_set():
            with self._lookup_cv:
                if not self._lookups:
                    self._lookup_cv.wait(0.5)
                if not self._lookups:
                    continue
                lookup = self._lookups.popleft()
            model_id = lookup[2]
            if model_id not in self.models:
                try:
                    desc = client.describe(model_id)
                    self.models[model_id] = (desc, codec.dumps(desc))
                except (RemoteError, NoReply, codec.DecodeError, ValueError, zenoh.ZError) as exc:
                    self.log.warning("model %s: %s", model_id, exc)
            self.ingest.put("model", "", lookup)

    # -- closing ---------------------------------------------------------------------------------------
    def _notice(self, rec: Active, kind: str, message: str) -> None:
        """Tell the session (its state lists it), once per run and kind; details are in the file's /log."""
        if kind in rec.noticed or self.z is None:
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
            self.status_changed()
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
            assert self.z is not None
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
            self.log.info("closed %s (%s, %s, %d samples)", rec.name, phase, closed_by, w.rows)
        except OSError as exc:
            self._fail(rec, exc)
        finally:
            self._forget(rec)

    def _fail(self, rec: Active, exc: BaseException) -> None:
        """Writing failed (disk full, ...): keep what is on disk, repaired if possible."""
        self.active.pop(rec.layout.session, None)
        rec.writer.abandon()
        self.log.error("recording %s failed: %s; repairing what was written", rec.name, exc)
        try:
            mcapread.recover(rec.writer.path)
        except Exception as exc2:
            self.log.error("could not repair %s now (will retry on restart): %s", rec.name, exc2)
        self._forget(rec)

    def _forget(self, rec: Active) -> None:
        self.done[(rec.layout.session, rec.layout.run_id)] = None
        while len(self.done) > 4096:
            self.done.popitem(last=False)
        self.library.closed(rec.name)
