"""The files of the runs being recorded: a `RunLayout` opens one, frames and states go into it, the
run's end (or a silent worker) closes it, and losses are written down where a reader will see them.

Only the recorder's writer thread calls these methods (recording_pipeline.py feeds it), so nothing here
locks. Replays are not recorded again; frames that come before their run's layout wait a little.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from simecs.mesh import codec, frames, keys, phases
from simecs.mesh import messages as m
from simecs.mesh.model import ModelDescription

from . import mcapfmt as fmt
from . import mcaprepair
from .mcapwriter import RunWriter
from .recordings_library import RecordingsLibrary

FINAL_GRACE_S = 0.3  # after the final frame: let the run's ended state arrive for the end phase
ENDED_GRACE_S = 2.0  # after an ended state without final frame: frames may still be on their way
PENDING_FRAMES = 256  # frames kept per session while its layout has not arrived yet
PENDING_SESSIONS = 64  # sessions whose frames wait for a layout
VIZ_RATE_HZ = 50.0  # /tf and /joint_states samples per simulated second
Owner = tuple[str, str]  # (user, session): where a session's keys are
LOG_LEVEL = {"running": fmt.LOG_INFO, "paused": fmt.LOG_INFO, "finished": fmt.LOG_INFO}


@dataclass
class Active:
    """A recording being written."""

    user: str
    layout: m.RunLayout
    name: str
    writer: RunWriter
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


class RunFiles:
    """Every recording being written, by session."""

    def __init__(
        self,
        library: RecordingsLibrary,
        node_id: str,
        log: Any,
        lookup: Callable[[Owner, str, str], None],
        notify: Callable[[str, m.Notice], None],
        worker_alive: Callable[[str, str, str], bool],
        take_drops: Callable[[], dict[Owner, list[int]]],
        status_changed: Callable[[], None],
        viz_rate_hz: float = VIZ_RATE_HZ,
        idle_timeout_s: float = 30.0,
    ) -> None:
        self.library = library
        self.node_id = node_id
        self.log = log
        self.lookup = lookup  # ask for a run's model description (it comes back through on_model)
        self.notify = notify
        self.worker_alive = worker_alive
        self.take_drops = take_drops
        self.status_changed = status_changed
        self.viz_rate_hz = viz_rate_hz
        self.idle_timeout_s = idle_timeout_s
        self.active: dict[Owner, Active] = {}
        self.pending: dict[Owner, collections.deque[bytes]] = {}
        self.done: collections.OrderedDict[tuple[Owner, str], None] = collections.OrderedDict()
        self.ignored: set[Owner] = set()  # sessions whose current run is a replay
        self.models: dict[str, tuple[ModelDescription, bytes]] = {}
        self.stats = {"rows": 0, "messages": 0, "files": 0, "dropped_frames": 0}
        self._last_drop_status = 0.0

    def close_all(self, closed_by: str) -> None:
        for rec in list(self.active.values()):
            self.close(rec, closed_by)

    # -- what arrives ---------------------------------------------------------------------------------
    def on_layout(self, key: str, payload: bytes) -> None:
        try:
            owner = keys.owner_of(key)
            layout = codec.loads(m.RunLayout, payload)
            keys.recording_name(layout.session, layout.run_id)
            if layout.session != owner[1]:
                raise ValueError(f"layout of session {layout.session} published under {key}")
        except (codec.DecodeError, ValueError) as exc:
            self.log.warning("ignoring bad layout on %s: %s", key, exc)
            return
        sid = owner
        cur = self.active.get(sid)
        if cur is not None:
            if cur.layout.run_id == layout.run_id and cur.layout.run_index == layout.run_index:
                return  # the same layout again (history and live)
            self.close(cur, f"superseded by run {layout.run_id}")
        if (sid, layout.run_id) in self.done:
            return
        if layout.source == "replay":
            self.ignored.add(sid)
            self.pending.pop(sid, None)
            self.log.info("session %s of %s: run %s is a replay: not recorded", sid[1], sid[0], layout.run_id)
            return
        self.ignored.discard(sid)
        self._open(owner[0], layout)

    def _open(self, user: str, layout: m.RunLayout) -> None:
        base = keys.recording_name(layout.session, layout.run_id)
        name = self.library.free_name(user, base)
        path = self.library.path_of(user, name)
        run_meta = {"recorder": self.node_id}
        if name != base:
            run_meta["continues"] = base
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            writer = RunWriter(path, layout, viz_rate_hz=self.viz_rate_hz, run_meta=run_meta)
        except (OSError, fmt.FormatError) as exc:
            self.log.error("cannot record run %s of %s into %s: %s", layout.run_id, layout.session, path, exc)
            return
        rec = Active(
            user, layout, name, writer, last_data=time.monotonic(), next_seq=None if name != base else 0
        )
        self.active[(user, layout.session)] = rec
        self.library.opened(
            path,
            m.RecordingInfo(name, layout.session, layout.run_id, layout.model_id, 0, False, layout.stop_time),
        )
        self.stats["files"] += 1
        note = f" (continues {base}: the recorder restarted during the run)" if name != base else ""
        writer.write_log(
            fmt.LOG_INFO,
            f"recording started: user {user} session {layout.session} run {layout.run_id} "
            f"model {layout.model_id}, "
            f"{len(layout.columns)} columns{note}",
            0.0,
        )
        self.lookup((user, layout.session), layout.run_id, layout.model_id)
        self.log.info("recording %s/%s", user, path.name)
        for payload in self.pending.pop((user, layout.session), ()):
            self._write(rec, payload)

    def on_full(self, key: str, payload: bytes) -> None:
        try:
            sid = keys.owner_of(key)
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

    def on_state(self, key: str, payload: bytes) -> None:
        try:
            st = codec.loads(m.SessionState, payload)
        except codec.DecodeError as exc:
            self.log.warning("ignoring bad state on %s: %s", key, exc)
            return
        try:
            sid = keys.owner_of(key)
        except ValueError:
            return
        if st.phase == "closed":
            self.pending.pop(sid, None)
            self.ignored.discard(sid)
        rec = self.active.get(sid)
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

    def on_model(self, key: str, lookup: tuple[Owner, str, str]) -> None:
        """The model description of a run, fetched by the lookup thread: the /scene and model.json."""
        owner, run_id, model_id = lookup
        rec = self.active.get(owner)
        if rec is None or rec.layout.run_id != run_id:
            return
        model = self.models.get(model_id)
        if model is None:
            rec.writer.write_log(fmt.LOG_WARNING, f"no model description of {model_id}: no /scene", 0.0)
            return
        desc, desc_json = model
        rec.writer.write_scene(desc, rec.layout.context.values or desc.default_values())
        rec.writer.write_attachment(fmt.ATTACH_MODEL, "application/json", desc_json)

    # -- closing ---------------------------------------------------------------------------------------
    def _notice(self, rec: Active, kind: str, message: str) -> None:
        """Tell the session (its state lists it), once per run and kind; details are in the file's /log."""
        if kind in rec.noticed:
            return
        rec.noticed.add(kind)
        self.notify(
            rec.user,
            m.Notice(
                session=rec.layout.session, run_id=rec.layout.run_id, source="recorder", message=message
            ),
        )

    def housekeeping(self, now: float) -> None:
        drops = self.take_drops()
        for sid, (n, rows, first, last) in drops.items():
            self.stats["dropped_frames"] += n
            rec = self.active.get(sid)
            text = (
                f"DROPPED {n} frames ({rows} samples) received between wall times {first} and {last} ns: "
                "the recorder could not keep up (queue full); the file has a gap there"
            )
            self.log.warning("session %s of %s: %s", sid[1], sid[0], text)
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
                self.close(rec, "final frame" if rec.final_seen else "run ended")
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
                if not self.worker_alive(rec.user, rec.layout.session, rec.layout.run_id):
                    self.close(rec, f"no data for {self.idle_timeout_s:g} s and the run's worker is gone")

    def close(self, rec: Active, closed_by: str) -> None:
        self.active.pop((rec.user, rec.layout.session), None)
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
        self.active.pop((rec.user, rec.layout.session), None)
        rec.writer.abandon()
        self.log.error("recording %s failed: %s; repairing what was written", rec.name, exc)
        try:
            mcaprepair.recover(rec.writer.path)
        except Exception as exc2:
            self.log.error("could not repair %s now (will retry on restart): %s", rec.name, exc2)
        self._forget(rec)

    def _forget(self, rec: Active) -> None:
        self.done[((rec.user, rec.layout.session), rec.layout.run_id)] = None
        while len(self.done) > 4096:
            self.done.popitem(last=False)
        self.library.closed(rec.writer.path)
