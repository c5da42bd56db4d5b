"""Live jogging of a run (PROTOCOL.md §5.4): the newest jog message for the run, held for its deadman
time, and whether the run is being jogged (its worker then simulates in short calls, nodes/pacing.py)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m

from .pacing import JOG_MODE_S
from .sources import RunSource

log = logging.getLogger("simecs.worker")


class Jogging:
    """The session's jog key: the newest message for this run, held for JOG_DEADMAN_S (PROTOCOL.md
    §5.4). A message for this run that is not usable stops the jog, and the user is told once what was
    wrong; one that does not decode names no run, so it is only logged."""

    def __init__(
        self, z: zenoh.Session, req: m.RunRequest, tell: Callable[[str], None], wake: threading.Event
    ) -> None:
        self.req, self.tell = req, tell
        self.lock = threading.Lock()
        self.latest: m.JogInput | None = None
        self.at = 0.0
        self.active = False
        # In jog mode a message wakes the run's loop, so that the call that obeys it starts at once.
        self.wake, self.wakes = wake, False
        self.sub = z.declare_subscriber(keys.jog(req.user, req.session), self.on_sample)

    def on_sample(self, sample: zenoh.Sample) -> None:
        try:
            msg = codec.loads(m.JogInput, sample.payload.to_bytes())
        except codec.DecodeError as exc:  # not known to be for this run: logged, nothing changes
            log.warning("jog for session %s ignored: %s", self.req.session, exc)
            return
        if msg.run_id != self.req.run_id:
            return
        with self.lock:
            self.latest, self.at, self.active = msg, time.monotonic(), True
        if self.wakes:
            self.wake.set()

    def recent(self) -> bool:
        """Whether a jog message for this run came within JOG_MODE_S (the run is being jogged)."""
        with self.lock:
            return self.at > 0.0 and time.monotonic() - self.at < JOG_MODE_S

    def apply(self, source: RunSource, horizon: float) -> bool:
        """Before a chunk: the held velocity, or none once the deadman time has passed. Whether a
        velocity other than zero is in force for the chunk (its simulated time counts as jogged)."""
        with self.lock:
            if not self.active:
                return False
            fresh = time.monotonic() - self.at < m.JOG_DEADMAN_S
            msg = self.latest if fresh else None
            self.active = fresh
        problem = source.jog(msg, horizon)
        if problem:
            self.tell(f"jog ignored: {problem}")
            return False
        return msg is not None and any(msg.qd if msg.space == "joint" else msg.twist)
