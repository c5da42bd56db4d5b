"""The files of the runs being recorded: a `RunLayout` opens one, frames and states go into it, the
run's end (or a silent worker) closes it, and losses are written down where a reader will see them.

Frames lost on the way (a hub restart, the hub dropping for a slow link, our own full queue) leave gaps
in the frame numbers. When the run ends, the samples of every gap are fetched from the simulator's
results of the run and written into the file before it is closed, so a recording holds every sample
however the stream went; only what cannot be fetched stays marked as lost.

Only the recorder's writer thread calls these methods (recording_pipeline.py feeds it), so nothing here
locks. Replays are not recorded again; frames that come before their run's layout wait a little.
"""

from __future__ import annotations

import collections
import math
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import codec, frames, keys, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription

from . import mcapfmt as fmt
from . import mcapread, mcaprepair
from .mcapwriter import RunWriter
from .recordings_library import RecordingsLibrary

#: A run whose frames stopped this long, its end unknown, has its session's state asked of the proxy
#: (then every QUIET_ASK_AGAIN_S): its final frame and its ended state, put once each, may both have
#: been dropped on a link that was full, and nothing would close its file until the idle timeout.
QUIET_ASK_S = 1.0
QUIET_ASK_AGAIN_S = 5.0
FINAL_GRACE_S = 0.3  # after the final frame: let the run's ended state arrive for the end phase
ENDED_GRACE_S = 2.0  # after an ended state without final frame: frames may still be on their way
PENDING_FRAMES = 256  # frames kept per session while its layout has not arrived yet
PENDING_SESSIONS = 64  # sessions whose frames wait for a layout
VIZ_RATE_HZ = 50.0  # /tf and /joint_states samples per simulated second
FILL_WAIT_S = 20.0  # how long a run's file waits for the samples of its gaps before it closes anyway
#: How long a run's file waits for its model (description and meshes: the /scene) before it closes
#: anyway; a short run can end before the first ask for a model's meshes is answered.
MODEL_WAIT_S = 15.0
Owner = tuple[str, str]  # (user, session): where a session's keys are
LOG_LEVEL = {"running": fmt.LOG_INFO, "paused": fmt.LOG_INFO, "finished": fmt.LOG_INFO}


@dataclass
class Gap:
    """Frames lost on the way: the samples after time `after` and before time `before`."""

    seq: int  # the first missing frame number (the filled samples are written under it)
    after: float = -math.inf
    before: float = math.inf


@dataclass
class Fill:
    """The answer to a run's gaps: the samples of each (from the run's results), why some could not be
    had, and how the run ended when its results say it has (what the stream may have lost too)."""

    owner: Owner
    run_id: str
    pieces: list[tuple[Gap, np.ndarray]]
    problem: str = ""
    ended: m.RunInfo | None = None


class RecorderMesh(Protocol):
    """What the run files ask of the mesh; recording_pipeline.py answers (from its own threads, the
    answers come back as items of the writer's queue)."""

    def lookup(self, owner: Owner, run_id: str, model_id: str) -> None:
        """Fetch the run's model description; it comes back through `RunFiles.on_model`."""

    def fill(self, owner: Owner, run_id: str, gaps: list[Gap], columns: list[str]) -> None:
        """Fetch the samples of `gaps` (rows of `columns`) from the run's results; they come back
        through `on_fill`."""

    def ask_state(self, owner: Owner) -> None:
        """Ask the proxy for the session's state; it comes back through `on_state`."""

    def notify(self, user: str, notice: m.Notice) -> None: ...

    def worker_alive(self, user: str, session: str, run_id: str) -> bool: ...

    def take_drops(self) -> dict[Owner, list[int]]:
        """Frames our own queue dropped since the last call, per session."""
        return {}

    def status_changed(self) -> None: ...


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
    state_asked: float = 0.0  # when the session's state was last asked (its stream had gone quiet)
    next_seq: int | None = 0  # None: accept any first frame (a continuation starts mid-run)
    noticed: set[str] = field(default_factory=set)  # kinds of Notice already sent for this run
    gaps: list[Gap] = field(default_factory=list)
    filled_rows: int = 0
    closing_by: str = ""  # set while the file waits for the samples of its gaps
    fill_deadline: float = 0.0
    model_pending: bool = True  # its model lookup (the /scene) has not come back yet
    jogged_s: float = 0.0  # simulated s jogged, as the run's newest report (RunStatus) says


class RunFiles:
    """Every recording being written, by session."""

    def __init__(
        self,
        library: RecordingsLibrary,
        node_id: str,
        log: Any,
        mesh: RecorderMesh,
        viz_rate_hz: float = VIZ_RATE_HZ,
        idle_timeout_s: float = 30.0,
    ) -> None:
        self.library = library
        self.node_id = node_id
        self.log = log
        self.mesh = mesh
        self.viz_rate_hz = viz_rate_hz
        self.idle_timeout_s = idle_timeout_s
        self.active: dict[Owner, Active] = {}
        self.filling: dict[tuple[Owner, str], Active] = {}  # ended runs waiting for their gaps' samples
        self.pending: dict[Owner, collections.deque[bytes]] = {}
        self.done: collections.OrderedDict[tuple[Owner, str], None] = collections.OrderedDict()
        self.ignored: set[Owner] = set()  # sessions whose current run is not recorded (replay, quota)
        # model id -> description, its JSON, the GLB of each of its mesh shapes
        self.models: dict[str, tuple[ModelDescription, bytes, dict[str, bytes]]] = {}
        self.stats = {"rows": 0, "messages": 0, "files": 0, "dropped_frames": 0, "filled_rows": 0}
        self._last_drop_status = 0.0

    def close_all(self, closed_by: str) -> None:
        for rec in [*self.active.values(), *self.filling.values()]:
            self._finish(rec, rec.closing_by or closed_by)

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
            same_run = cur.layout.run_id == layout.run_id and cur.layout.run_index == layout.run_index
            if same_run and layout.context.attempt <= cur.layout.context.attempt:
                return  # the same layout again (history and live)
            if not same_run:
                self.close(cur, f"superseded by run {layout.run_id}")
        if layout.context.attempt > 1:
            self._drop_earlier_attempts(owner[0], layout)
        if (sid, layout.run_id) in self.done or (sid, layout.run_id) in self.filling:
            return
        if layout.source == "replay":
            self.ignored.add(sid)
            self.pending.pop(sid, None)
            self.log.info("session %s of %s: run %s is a replay: not recorded", sid[1], sid[0], layout.run_id)
            return
        self.ignored.discard(sid)
        full = self.library.over_quota(owner[0])
        if full:
            self.ignored.add(sid)
            self.pending.pop(sid, None)
            self.log.warning("run %s of %s not recorded: %s", layout.run_id, layout.session, full)
            notice = f"run {layout.run_id} is not recorded: {full}"
            self.mesh.notify(
                owner[0],
                m.Notice(session=layout.session, run_id=layout.run_id, source="recorder", message=notice),
            )
            return
        self._open(owner[0], layout)

    def _drop_earlier_attempts(self, user: str, layout: m.RunLayout) -> None:
        """The run restarted from the start on another host (its host was lost): what was recorded of
        its earlier attempt is a prefix of what comes now, so the new recording replaces it."""
        sid = (user, layout.session)
        earlier = [r for r in (self.active.get(sid), self.filling.get((sid, layout.run_id))) if r is not None]
        for rec in earlier:
            if rec.layout.run_id == layout.run_id and rec.layout.context.attempt < layout.context.attempt:
                self._finish(rec, f"its run restarted (attempt {layout.context.attempt})")
        if (sid, layout.run_id) in self.done:
            del self.done[(sid, layout.run_id)]
            name = keys.recording_name(layout.session, layout.run_id)
            try:
                if self.library.path_of(user, name).exists():
                    self.library.delete(user, name)
            except RequestError as exc:
                self.log.warning("could not replace %s of an earlier attempt: %s", name, exc.message)

    def _open(self, user: str, layout: m.RunLayout) -> None:
        base = keys.recording_name(layout.session, layout.run_id)
        name = self.library.free_name(user, base)
        path = self.library.path_of(user, name)
        run_meta = {"recorder": self.node_id}
        if layout.context.attempt > 1:
            run_meta["attempt"] = str(layout.context.attempt)
            run_meta["restarted"] = layout.context.restarted
        if name != base:
            run_meta["continues"] = base
        info = m.RecordingInfo(
            name,
            layout.session,
            layout.run_id,
            layout.model_id,
            0,
            False,
            layout.stop_time,
            created=mcapread.iso_utc(time.time_ns()),
        )
        # Open before the file exists: a download that finds the file (a quick run's client asks at once)
        # then waits for its end instead of taking the bytes written so far.
        self.library.opened(path, info)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            writer = RunWriter(path, layout, viz_rate_hz=self.viz_rate_hz, run_meta=run_meta)
        except (OSError, fmt.FormatError) as exc:
            self.library.closed(path)
            self.log.error("cannot record run %s of %s into %s: %s", layout.run_id, layout.session, path, exc)
            return
        rec = Active(
            user, layout, name, writer, last_data=time.monotonic(), next_seq=None if name != base else 0
        )
        self.active[(user, layout.session)] = rec
        self.stats["files"] += 1
        note = f" (continues {base}: the recorder restarted during the run)" if name != base else ""
        if layout.context.attempt > 1:
            note += f" (attempt {layout.context.attempt}, from the start: {layout.context.restarted})"
        writer.write_log(
            fmt.LOG_INFO,
            f"recording started: user {user} session {layout.session} run {layout.run_id} "
            f"model {layout.model_id}, "
            f"{len(layout.columns)} columns{note}",
            0.0,
        )
        self.mesh.lookup((user, layout.session), layout.run_id, layout.model_id)
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
        if not frame.of(rec.layout.run_index, rec.layout.context.attempt):  # another run's, or attempt's
            rec.stray_frames += 1
            return
        if rec.next_seq is None and frame.rows.shape[0] and not rec.writer.rows:
            # A continuation (the recorder restarted during the run): what came before its first frame
            # is fetched from the run's results at its end, so this file holds the whole run.
            first = float(frame.rows[0, 0])
            rec.gaps.append(Gap(frame.seq, -math.inf, first))
            rec.writer.write_log(
                fmt.LOG_WARNING,
                f"MISSING the samples before t = {first:.4f} s: the recorder restarted during the run; "
                "they are fetched from the run's results when it ends",
                first,
            )
        if rec.next_seq is not None and frame.seq > rec.next_seq:
            missing = frame.seq - rec.next_seq
            rec.dropped_frames += missing
            after = rec.sim_time if rec.writer.rows else -math.inf
            before = float(frame.rows[0, 0]) if frame.rows.shape[0] else math.inf
            rec.gaps.append(Gap(rec.next_seq, after, before))
            rec.writer.write_log(
                fmt.LOG_WARNING,
                f"MISSING frames {rec.next_seq}..{frame.seq - 1} ({missing} frames): lost before they "
                f"reached the recorder (hub restart, slow link, or our queue full) after t = "
                f"{rec.sim_time:.4f} s; their samples are fetched from the run's results when it ends",
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

    def on_run_status(self, key: str, payload: bytes) -> None:
        """A worker's report: how long its run has been jogged so far (written in `simecs.end`). The
        final report comes after the final frame, so a run waiting for its gaps' samples takes it too."""
        try:
            st = codec.loads(m.RunStatus, payload)
            owner = keys.owner_of(key)
        except (codec.DecodeError, ValueError):
            return  # the proxy logs bad reports; nothing in a file depends on one
        for rec in (self.active.get(owner), self.filling.get((owner, st.run_id))):
            if (
                rec is not None
                and rec.layout.session == st.session
                and rec.layout.run_id == st.run_id
                and rec.layout.context.attempt == st.attempt
            ):
                rec.jogged_s = max(rec.jogged_s, st.jogged_s)  # a lost worker's report says 0

    def on_model(self, key: str, lookup: tuple[Owner, str, str]) -> None:
        """The model description of a run, fetched by the lookup thread: the /scene and model.json."""
        owner, run_id, model_id = lookup
        rec = self.active.get(owner)
        if rec is None or rec.layout.run_id != run_id:
            return
        rec.model_pending = False
        model = self.models.get(model_id)
        if model is None:
            rec.writer.write_log(fmt.LOG_WARNING, f"no model description of {model_id}: no /scene", 0.0)
            return
        desc, desc_json, meshes = model
        context = rec.layout.context
        rec.writer.write_scene(desc, context.values or desc.default_values(), meshes, context.obstacles)
        rec.writer.write_attachment(fmt.ATTACH_MODEL, "application/json", desc_json)

    # -- closing ---------------------------------------------------------------------------------------
    def _notice(self, rec: Active, kind: str, message: str) -> None:
        """Tell the session (its state lists it), once per run and kind; details are in the file's /log."""
        if kind in rec.noticed:
            return
        rec.noticed.add(kind)
        self.mesh.notify(
            rec.user,
            m.Notice(
                session=rec.layout.session, run_id=rec.layout.run_id, source="recorder", message=message
            ),
        )

    def housekeeping(self, now: float) -> None:
        drops = self.mesh.take_drops()
        for sid, (n, rows, first, last) in drops.items():
            self.stats["dropped_frames"] += n
            rec = self.active.get(sid)
            text = (
                f"DROPPED {n} frames ({rows} samples) received between wall times {first} and {last} ns: "
                "the recorder could not keep up (queue full); they are fetched from the run's results "
                "when it ends"
            )
            self.log.warning("session %s of %s: %s", sid[1], sid[0], text)
            if rec is not None:
                rec.queue_drops += n
                rec.dropped_rows += rows
                rec.writer.write_log(fmt.LOG_WARNING, text, rec.sim_time)
        if drops and now - self._last_drop_status > 1.0:
            self._last_drop_status = now
            self.mesh.status_changed()
        for rec in list(self.active.values()):
            if rec.close_at is not None and now >= rec.close_at:
                if rec.model_pending and now < rec.close_at + MODEL_WAIT_S:
                    continue  # its /scene is on the way
                self.close(rec, "final frame" if rec.final_seen else "run ended")
                continue
            if rec.writer.dirty and now - rec.writer.last_flush >= fmt.FLUSH_S:
                try:
                    rec.writer.flush()
                except OSError as exc:
                    self._fail(rec, exc)
                    continue
            quiet = now - rec.last_data
            if (
                rec.close_at is None
                and quiet >= QUIET_ASK_S
                and now - rec.state_asked
                >= (QUIET_ASK_S if rec.state_asked < rec.last_data else QUIET_ASK_AGAIN_S)
            ):
                rec.state_asked = now
                self.mesh.ask_state((rec.user, rec.layout.session))
            if (
                now - rec.last_data > self.idle_timeout_s
                and now - rec.idle_checked > self.idle_timeout_s
                and rec.close_at is None
            ):
                rec.idle_checked = now
                if not self.mesh.worker_alive(rec.user, rec.layout.session, rec.layout.run_id):
                    self.close(rec, f"no data for {self.idle_timeout_s:g} s and the run's worker is gone")
        for rec in list(self.filling.values()):
            if now >= rec.fill_deadline:
                rec.writer.write_log(
                    fmt.LOG_ERROR,
                    f"the run's results did not come within {FILL_WAIT_S:g} s: its gaps stay",
                    rec.sim_time,
                )
                self._finish(rec, rec.closing_by)

    def _inactive(self, rec: Active) -> None:
        """`rec` no longer takes its session's frames: a run that ended, or failed. Its session's
        next run may be active already (a superseded run is finished after its gaps are filled)."""
        owner = (rec.user, rec.layout.session)
        if self.active.get(owner) is rec:
            del self.active[owner]

    def close(self, rec: Active, closed_by: str) -> None:
        """The run is over: fill its gaps from its results first (they come back through `on_fill`)."""
        self._inactive(rec)
        if not rec.final_seen and rec.next_seq is not None:  # the end of the stream was lost too
            rec.gaps.append(Gap(rec.next_seq, rec.sim_time if rec.writer.rows else -math.inf))
        if not rec.gaps:
            self._finish(rec, closed_by)
            return
        rec.closing_by = closed_by
        rec.fill_deadline = time.monotonic() + FILL_WAIT_S
        self.filling[((rec.user, rec.layout.session), rec.layout.run_id)] = rec
        self.mesh.fill((rec.user, rec.layout.session), rec.layout.run_id, list(rec.gaps), rec.layout.columns)

    def on_fill(self, key: str, answer: Fill) -> None:
        """The samples of a run's gaps, fetched from its results (or why they could not be)."""
        problem = answer.problem
        rec = self.filling.pop((answer.owner, answer.run_id), None)
        if rec is None:
            return
        ended = answer.ended
        if ended is not None and not rec.end_phase:  # its end was lost on the way too (or came late)
            rec.end_phase, rec.end_reason = ended.phase, ended.reason
        if ended is not None:  # what the run stored: its final word, if its last report was lost
            rec.jogged_s = max(rec.jogged_s, ended.jogged_s)
        for gap, rows in answer.pieces:
            if rows.shape[0] == 0:
                if ended is not None and math.isinf(gap.before):  # only its end marker was lost
                    rec.gaps.remove(gap)
                continue
            try:
                frame = frames.Frame(rec.layout.run_index, gap.seq, time.time_ns(), rows, 0)
                rec.writer.write_frame(frame, backfill=True)
            except fmt.FormatError as exc:
                problem = f"the results do not fit the recording: {exc}"
                break
            except OSError as exc:
                self._fail(rec, exc)
                return
            rec.filled_rows += rows.shape[0]
            rec.sim_time = max(rec.sim_time, float(rows[-1, 0]))
            rec.gaps.remove(gap)
            rec.writer.write_log(
                fmt.LOG_INFO,
                f"FILLED {rows.shape[0]} samples from t = {rows[0, 0]:.4f} to {rows[-1, 0]:.4f} s (frames "
                f"from {gap.seq} lost on the way) from the run's results",
                float(rows[0, 0]),
            )
        self.stats["filled_rows"] += rec.filled_rows
        if rec.gaps and problem:
            rec.writer.write_log(fmt.LOG_ERROR, f"gaps not filled: {problem}", rec.sim_time)
        self._finish(rec, rec.closing_by)

    def _finish(self, rec: Active, closed_by: str) -> None:
        self._inactive(rec)
        self.filling.pop(((rec.user, rec.layout.session), rec.layout.run_id), None)
        phase = rec.end_phase or ("finished" if rec.final_seen and rec.final_rows else "")
        phase = phase or ("ended" if rec.final_seen else "incomplete")
        w = rec.writer
        lost = len(rec.gaps)
        if lost:
            self._notice(rec, "gap", "samples were lost on the way to the recorder: the recording has gaps")
        try:
            summary = f"recording closed ({closed_by}): run {phase}, {w.rows} samples in {w.frames} frames"
            if rec.filled_rows:
                summary += f"; {rec.filled_rows} of them filled in from the run's results"
            if lost:
                summary += f"; {lost} gaps LEFT (at least {max(rec.dropped_frames, rec.queue_drops)} frames)"
            w.write_log(fmt.LOG_INFO if not lost else fmt.LOG_ERROR, summary, rec.sim_time)
            w.close(
                {
                    "phase": phase,
                    "reason": rec.end_reason,
                    "closed_by": closed_by,
                    # Each count sees a subset of the losses: both are lower bounds, the larger is kept.
                    "dropped_frames": str(max(rec.dropped_frames, rec.queue_drops)),
                    "dropped_rows": str(rec.dropped_rows),
                    "filled_rows": str(rec.filled_rows),
                    "gaps": str(lost),
                    "stray_frames": str(rec.stray_frames),
                    "sim_time": repr(rec.sim_time),
                    "jogged_s": repr(rec.jogged_s),
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
        self._inactive(rec)
        self.filling.pop(((rec.user, rec.layout.session), rec.layout.run_id), None)
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
