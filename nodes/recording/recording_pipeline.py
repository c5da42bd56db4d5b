"""The recording pipeline: every run written as one MCAP file, crash-safe, without slowing the simulator.

No Python runs in zenoh's threads (a slow callback would stall the whole link, simulator included):
samples land in native ring buffers, a puller thread moves them to a bounded queue (`Ingest`), and one
writer thread, at a lower CPU priority, hands them to the run files (`recording_files.py`), which own
the MCAP files. If frames are ever dropped (queue full, ring overflow, or lost on the way: gaps in frame
numbers), the file says so on /log and in `simecs.end`, the session gets a `Notice`, and the node's
status counts them. Files are flushed about once a second, so a crash loses at most ~1 s. A lookup
thread fetches each new run's model description (for /scene and model.json) and, when a run with gaps
ends, the samples of its gaps from the run's results (recording_files.py).
"""

from __future__ import annotations

import collections
import math
import os
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh
import zenoh.ext
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process.seal import Seal
from simecs.mesh.protocol import codec, frames, keys, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription

from .recording_files import VIZ_RATE_HZ, Fill, Gap, Owner, RunFiles
from .recordings_library import RecordingsLibrary

FILL_TRIES = 10  # a run's results are stored a moment after its last frame: ask again this often
FILL_RETRY_S = 0.5
BATCH_MIN = 8  # frames: a smaller batch makes the writer wait BATCH_WAIT_S before the next one
BATCH_WAIT_S = 0.02
WRITER_NICE = 10  # how much lower the writer thread's CPU priority is than the node's
RING_FRAMES = 8192  # samples zenoh holds per subscription for the puller thread


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
        self.drops: dict[Owner, list[int]] = {}  # (user, session) -> [frames, rows, first ns, last ns]
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
            session = keys.owner_of(key)
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

    def take_drops(self) -> dict[Owner, list[int]]:
        with self.cv:
            drops, self.drops = self.drops, {}
            return drops

    def wake(self) -> None:
        with self.cv:
            self.cv.notify_all()


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
        self.log = log
        self.ingest = Ingest(queue_frames, int(queue_mb * 1024 * 1024))
        self._status_changed = status_changed
        self.files = RunFiles(library, node_id, log, self, viz_rate_hz, idle_timeout_s)
        self._stop = threading.Event()
        self._lookups: collections.deque[tuple[str, Owner, str, Any]] = collections.deque()
        self._lookup_cv = threading.Condition()
        self._threads: list[threading.Thread] = []
        self._subs: list[tuple[Any, str]] = []
        self.z: zenoh.Session | None = None
        self.seal: Seal | None = None
        self.unsealed = 0

    # -- threads ------------------------------------------------------------------------------------
    def start(self, z: zenoh.Session, declare: Callable[[Any], Any], seal: Seal) -> None:
        """Subscribe and start the threads. No Python runs in zenoh's threads (a slow callback, or one
        waiting for the GIL while the writer encodes, would stall the link and with it the simulator):
        samples land in native ring buffers (a full ring drops its oldest sample: for frames, seen as a
        gap in frame numbers) and a puller thread moves them into the writer's queue, keeping only
        samples with the service's seal (only workers and the proxy write these keys)."""
        self.z = z
        self.seal = seal

        def ring(key: str, latched: bool) -> Any:
            channel: Any = zenoh.handlers.RingChannel(RING_FRAMES)
            if latched:
                history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
                return declare(zenoh.ext.declare_advanced_subscriber(z, key, channel, history=history))
            return declare(z.declare_subscriber(key, channel))

        # Reports before states: a worker's last report reaches us before the state the proxy makes of it,
        # and the puller keeps that order (a state that ends a run may close its file).
        self._subs = [
            (ring(keys.ALL_LAYOUT, latched=True), "layout"),
            (ring(keys.ALL_RUN_STATUS, latched=False), "run"),
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
        assert self.seal is not None
        valid = self.seal.valid
        last_data = 0.0
        while not stop.is_set():
            moved = False
            for sub, kind in self._subs:
                for _ in range(256):
                    sample = sub.try_recv()
                    if sample is None:
                        break
                    key, payload, att = str(sample.key_expr), sample.payload.to_bytes(), sample.attachment
                    if valid(key, payload, att.to_bytes() if att is not None else None):
                        put(kind, key, payload)
                    else:
                        self._refuse(key)
                    moved = True
            now = time.monotonic()
            if moved:
                last_data = now
            else:  # poll often while data flows, seldom when idle (a 2 ms poll costs 3 % of a core)
                time.sleep(0.005 if now - last_data < 0.5 else 0.02)

    def _refuse(self, key: str) -> None:
        self.unsealed += 1
        if self.unsealed <= 10 or self.unsealed % 1000 == 0:
            self.log.warning(
                "ignored a sample on %s without a valid service seal (%d so far): only workers and "
                "the proxy write it",
                key,
                self.unsealed,
            )

    def _writer_loop(self) -> None:
        # Encoding and compressing yield the CPU to the simulator: only this thread is niced (Linux
        # priorities are per thread), so zenoh's receive threads and the puller keep up and the rings
        # and the queue absorb whatever the writer lags behind.
        try:
            tid = threading.get_native_id()
            os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + WRITER_NICE))
        except (OSError, AttributeError):
            pass
        files = self.files
        handlers: dict[str, Callable[[str, Any], None]] = {
            "layout": files.on_layout,
            "run": files.on_run_status,
            "state": files.on_state,
            "full": files.on_full,
            "model": files.on_model,
            "fill": files.on_fill,
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
                    files.housekeeping(now)
            if 0 < len(batch) < BATCH_MIN:
                # Waking per frame costs more than the frame: let a few accumulate (latency is free here).
                self._stop.wait(BATCH_WAIT_S)
            now = time.monotonic()
            if now >= next_house:
                next_house = now + 0.05
                try:
                    files.housekeeping(now)
                except Exception:
                    self.log.error("recorder housekeeping failed:\n%s", traceback.format_exc())
        files.close_all("recorder stopped")

    # -- the lookup thread: model descriptions of new runs, samples of the gaps of ended runs -------------
    def _lookup_loop(self) -> None:
        assert self.z is not None
        client = MeshClient(self.z, timeout=3.0, seal=self.seal)
        while not self._stop.is_set():
            with self._lookup_cv:
                if not self._lookups:
                    self._lookup_cv.wait(0.5)
                if not self._lookups:
                    continue
                kind, owner, run_id, arg = self._lookups.popleft()
            if kind == "model":
                if arg not in self.files.models:
                    try:
                        desc = client.describe(arg)
                        meshes = self._fetch_meshes(client, desc)
                        self.files.models[arg] = (desc, codec.dumps(desc), meshes)
                    except (RemoteError, NoReply, codec.DecodeError, ValueError, zenoh.ZError) as exc:
                        self.log.warning("model %s: %s", arg, exc)
                self.ingest.put("model", "", (owner, run_id, arg))
            elif kind == "state":
                try:
                    state = client.session(*owner).snapshot().state
                except (RemoteError, NoReply, codec.DecodeError, zenoh.ZError) as exc:
                    self.log.info("session %s of %s: state not read: %s", owner[1], owner[0], exc)
                    continue
                self.ingest.put("state", keys.state(*owner), codec.dumps(state))
            else:
                self.ingest.put("fill", "", self._fetch_gaps(client, owner, run_id, *arg))

    def _fetch_meshes(self, client: MeshClient, desc: ModelDescription) -> dict[str, bytes]:
        """The GLB of each mesh shape of a model, for its recordings' /scene (a missing one is logged)."""
        out = {}
        for name in desc.mesh_names():
            try:
                out[name] = client.model_mesh(desc.id, name)
            except (RemoteError, NoReply, zenoh.ZError) as exc:
                self.log.warning("model %s: mesh %s not in its recordings' /scene: %s", desc.id, name, exc)
        return out

    def _fetch_gaps(
        self, client: MeshClient, owner: Owner, run_id: str, gaps: list[Gap], columns: list[str]
    ) -> Fill:
        """The samples of each gap, from the run's results (by whichever host holds them)."""
        fill = Fill(owner, run_id, [])
        session = client.session(*owner)
        for gap in gaps:
            t0 = gap.after if math.isfinite(gap.after) else None
            t1 = gap.before if math.isfinite(gap.before) else None
            for attempt in range(FILL_TRIES):
                try:
                    att, rows = session.results_of(run_id, t0=t0, t1=t1)
                    break
                except NoReply:
                    fill.problem = "no node holds the run's results"
                except (RemoteError, codec.DecodeError, frames.FrameError, zenoh.ZError) as exc:
                    fill.problem = f"the run's results: {exc}"
                    return fill
                if attempt + 1 < FILL_TRIES and not self._stop.wait(FILL_RETRY_S):
                    continue
                return fill
            if att.columns != columns:
                fill.problem = "the run's results have other columns than its stream"
                return fill
            if att.run.phase in phases.ENDED:
                fill.ended = att.run
            inside = (rows[:, 0] > gap.after) & (rows[:, 0] < gap.before)
            fill.pieces.append((gap, np.ascontiguousarray(rows[inside])))
        fill.problem = ""
        return fill

    # -- what the run files ask of the mesh (recording_files.RecorderMesh) ------------------------------
    def lookup(self, owner: Owner, run_id: str, model_id: str) -> None:
        with self._lookup_cv:
            self._lookups.append(("model", owner, run_id, model_id))
            self._lookup_cv.notify()

    def fill(self, owner: Owner, run_id: str, gaps: list[Gap], columns: list[str]) -> None:
        with self._lookup_cv:
            self._lookups.append(("fill", owner, run_id, (gaps, columns)))
            self._lookup_cv.notify()

    def ask_state(self, owner: Owner) -> None:
        with self._lookup_cv:
            self._lookups.append(("state", owner, "", None))
            self._lookup_cv.notify()

    def worker_alive(self, user: str, session: str, run_id: str) -> bool:
        try:
            assert self.z is not None
            token = keys.run_token(user, session, run_id)
            return any(r.ok is not None for r in self.z.liveliness().get(token, timeout=1.0))
        except zenoh.ZError:
            return True

    def notify(self, user: str, notice: m.Notice) -> None:
        try:
            assert self.z is not None
            assert self.seal is not None
            key, payload = keys.notices(user, notice.session), codec.dumps(notice)
            self.z.put(key, payload, attachment=self.seal.mac(key, payload))
        except Exception as exc:  # the file still says it
            self.log.warning("could not publish a notice: %s", exc)

    def take_drops(self) -> dict[Owner, list[int]]:
        return self.ingest.take_drops()

    def status_changed(self) -> None:
        self._status_changed()
