"""The hot-feedback node: the paper's Hot Feedback Manager.

It takes every session's full-rate frames and forwards at most R frames per wall second per session
(R from the run's layout): forwarded frames are at least 1/R apart, from the first frame of a run on, so
no one-second window holds more than R of them (plus the final frame, which always goes). Each carries
the newest sample's live columns; a sample held back by the limit goes out the moment its turn comes.
The final frame of a finished run holds its last sample; that of an aborted or failed run holds none.
A session nobody subscribes to live gets nothing forwarded but its final frame (zenoh's matching
status of its publisher, once zenoh has had time to learn it).
Its work per full frame is a few microseconds (header, one row, at most one put), done right in
zenoh's callback to save a thread wake-up; slow consumers downstream have their own queues, so
nothing stalls the simulator (a slow zenoh callback would stall every other sample on the link).
A forwarded frame keeps the `wall_ns` of the full frame it came from, so any subscriber can measure
the end-to-end latency from the simulator.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh
from simecs.mesh.process.runtime import Node, main_for
from simecs.mesh.protocol import codec, frames, keys
from simecs.mesh.protocol import messages as m

#: Tokens a stream may save up. One: every forwarded frame waits a whole period after the last one,
#: so the limit holds in every window, the start of a run included. (The simulator's 40 frames per
#: wall second at real-time pacing stay below the default R = 50: they pass at once.)
BURST = 1.0
#: Sessions whose newest frame waits for its layout (a bounded few: a frame for no session ages out).
EARLY_SESSIONS = 64
#: How long an ended stream keeps its publisher, in case the session runs again.
STREAM_LINGER_NS = 60 * 10**9
#: How long a new publisher forwards whatever zenoh's matching status says. The status is false until
#: the hub has answered the publisher's declaration (about a millisecond; seconds on a loaded machine,
#: while zenoh does send the puts): a viewer that subscribed before the run must not lose its start.
MATCHING_SETTLE_NS = 2 * 10**9


@dataclass
class Stream:
    layout: m.RunLayout
    live_idx: np.ndarray
    period_ns: int
    tokens: float = BURST
    refilled_ns: int = 0
    pending: frames.Frame | None = None
    ended_ns: int = 0  # when the final frame went out
    sent: int = 0
    seq: int = 0
    publisher: Any = field(default=None)
    declared_ns: int = 0  # when its publisher was declared

    def watched(self, now: int) -> bool:
        """Whether someone subscribes to the session's live key, or zenoh may not know yet."""
        return now - self.declared_ns < MATCHING_SETTLE_NS or bool(self.publisher.matching)


class HotFeedback(Node):
    """Decimates full-rate frames to at most R Hz per session."""

    role = "hotfeedback"
    live_path = True
    tick_s = 1.0

    def __init__(self, mesh: Any, node_id: str | None = None) -> None:
        super().__init__(mesh, node_id)
        self.lock = threading.Lock()
        self.wakeup = threading.Condition(self.lock)
        self.streams: dict[tuple[str, str], Stream] = {}  # by (user, session)
        #: The newest frame of a session whose layout has not been handled yet (frames are taken in
        #: zenoh's callback, layouts on a worker thread: a short run's frames can come first).
        self.early: collections.OrderedDict[tuple[str, str], frames.Frame] = collections.OrderedDict()
        self.forwarded = 0
        self.unwatched = 0  # frames of sessions nobody watched live: not forwarded
        self.stale = 0  # frames of an earlier attempt of a run: not forwarded

    def status_detail(self) -> dict[str, Any]:
        return {
            "streams": len(self.streams),
            "forwarded": self.forwarded,
            "unwatched": self.unwatched,
            "stale": self.stale,
        }

    def start(self) -> None:
        # Only workers write these keys: samples without the service's seal are ignored.
        self.subscribe(keys.ALL_LAYOUT, self._on_layout, maxlen=256, latched=True, sealed=True)
        # Per frame: check the seal, parse a header, copy one row, maybe one put: tens of
        # microseconds, so no thread hop. The seal is checked in _on_full, for what it acts on.
        self.subscribe(keys.ALL_FULL, self._on_full, inline=True)
        threading.Thread(target=self._release_held, name="hotfeedback:release", daemon=True).start()

    def _on_layout(self, sample: zenoh.Sample) -> None:
        try:
            user, session = keys.owner_of(sample.key_expr)
            layout = codec.loads(m.RunLayout, sample.payload.to_bytes())
            if layout.session != session:
                raise ValueError(f"a layout of session {layout.session} on a key of session {session}")
            idx = np.array([layout.columns.index(c) for c in layout.live_columns], dtype=int)
        except (codec.DecodeError, ValueError) as exc:
            self.log.warning("bad layout on %s: %s", sample.key_expr, exc)
            return
        with self.lock:
            old = self.streams.get((user, session))
            if old is not None:
                pub, declared_ns = old.publisher, old.declared_ns
            else:
                pub = self.publisher(keys.vars_live(user, session), express=True)
                declared_ns = time.time_ns()
            period_ns = int(1e9 / layout.live_rate_hz)
            stream = Stream(layout, idx, period_ns, publisher=pub, declared_ns=declared_ns)
            self.streams[(user, session)] = stream
            early = self.early.pop((user, session), None)
            if early is not None and early.of(layout.run_index, layout.context.attempt):
                self._take(stream, early)

    def _take(self, stream: Stream, frame: frames.Frame) -> None:
        """A frame of the stream's run: its newest sample waits for its turn; the final one goes now.
        A session nobody watches live (no subscriber on its live key: zenoh's matching status) gets
        only its final frame: forwarding one costs this node and the hub a put each, 40 times a second
        a run. The final one is one put a run, and ends the stream for a watcher zenoh was slow to see."""
        if not frame.final and not stream.watched(time.time_ns()):
            stream.pending = None
            self.unwatched += 1
            return
        if frame.final and not frame.rows.shape[0]:
            stream.pending = frame  # aborted or failed: the run ends with no sample, not a stale one
        elif frame.rows.shape[0]:
            if frame.rows.shape[1] != len(stream.layout.columns):
                self.log.warning(
                    "frame of %s has %d columns, layout %d",
                    stream.layout.session,
                    frame.rows.shape[1],
                    len(stream.layout.columns),
                )
                return
            frame.rows = frame.rows[-1:, stream.live_idx]
            stream.pending = frame
        if frame.final and stream.pending is not None:
            stream.pending.flags |= frames.FLAG_FINAL
        self._maybe_send(stream, time.time_ns(), force=frame.final)
        if stream.pending is not None:
            self.wakeup.notify()  # held back: the releaser sends it when its token is due

    def _on_full(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        if self._unwatched(str(sample.key_expr), payload) or not self.sealed(sample, payload):
            return
        try:
            owner = keys.owner_of(sample.key_expr)
            frame = frames.decode(payload, last_row_only=True)
        except (ValueError, frames.FrameError) as exc:
            self.log.warning("bad frame on %s: %s", sample.key_expr, exc)
            return
        with self.lock:
            stream = self.streams.get(owner)
            if stream is not None and frames.superseded(
                frame.run_index, frame.attempt, stream.layout.run_index, stream.layout.context.attempt
            ):
                self.stale += 1  # an earlier attempt's (a host taken for lost that goes on): nobody's
                return
            if stream is None or not frame.of(stream.layout.run_index, stream.layout.context.attempt):
                # Its layout is not handled yet: keep the newest frame (a final one stays final).
                before = self.early.pop(owner, None)
                if before is not None and before.run_index == frame.run_index and before.final:
                    frame.flags |= frames.FLAG_FINAL
                self.early[owner] = frame
                while len(self.early) > EARLY_SESSIONS:
                    self.early.popitem(last=False)
                return
            self._take(stream, frame)

    def _unwatched(self, key: str, payload: bytes) -> bool:
        """A frame this node does nothing with, so whoever sent it changes nothing: not a final one,
        of the run going in a session nobody watches live. Its seal is not even checked (the seal
        and the decode were most of this node's work for such a frame)."""
        try:
            owner = keys.owner_of(key)
            head = frames.peek(payload)
        except (ValueError, frames.FrameError):
            return False
        if head.flags & frames.FLAG_FINAL:
            return False
        with self.lock:
            stream = self.streams.get(owner)
            of_run = stream is not None and frames.belongs(
                head.run_index, head.attempt, stream.layout.run_index, stream.layout.context.attempt
            )
            if stream is None or not of_run or stream.watched(time.time_ns()):
                return False
            stream.pending = None
            self.unwatched += 1
            return True

    def _maybe_send(self, stream: Stream, now: int, force: bool = False) -> None:
        """Token bucket: one token per period, at most BURST saved; the final frame always goes."""
        if stream.refilled_ns:
            stream.tokens = min(BURST, stream.tokens + (now - stream.refilled_ns) / stream.period_ns)
        stream.refilled_ns = now
        pending = stream.pending
        if pending is None or (not force and stream.tokens < 1.0):
            return
        stream.tokens = max(0.0, stream.tokens - 1.0)
        live = frames.Frame(
            pending.run_index,
            stream.seq,
            pending.wall_ns,
            pending.rows,
            pending.flags | frames.FLAG_LIVE,
            pending.attempt,
        )
        stream.publisher.put(frames.encode(live))
        stream.seq += 1
        stream.sent += 1
        stream.pending = None
        self.forwarded += 1
        if live.final:
            stream.ended_ns = now

    def _release_held(self) -> None:
        """Forward each sample held back by the rate limit the moment its token is due.

        When frames arrive at about R Hz the bucket is marginal and a sample may be held for the
        jitter's worth of a token: waking exactly then (not on a fixed tick) keeps that to the jitter.
        """
        with self.wakeup:
            while not self.stop_event.is_set():
                now = time.time_ns()
                wait = 0.5
                for stream in self.streams.values():
                    self._maybe_send(stream, now)
                    if stream.pending is not None:
                        wait = min(wait, max(2e-4, (1.0 - stream.tokens) * stream.period_ns / 1e9))
                self.wakeup.wait(wait)

    def tick(self) -> None:
        """Free the publishers of streams that ended a while ago (no leak per session)."""
        now = time.time_ns()
        with self.lock:
            for session, stream in list(self.streams.items()):
                if stream.ended_ns and now - stream.ended_ns > STREAM_LINGER_NS:
                    del self.streams[session]
                    self._declared.remove(stream.publisher)
                    stream.publisher.undeclare()

    def stop(self) -> None:
        with self.wakeup:
            self.wakeup.notify()


def main(argv: list[str] | None = None) -> int:
    return main_for(HotFeedback, argv)


if __name__ == "__main__":
    main()
