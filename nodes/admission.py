"""Admission: a run starts as soon as some simulator host can hold it at its pacing; the others wait
in the queue, in order, each told its position and an estimate of its wait.

Whether a host can hold a run, and which host is least loaded, is the simulators' own measured load
(nodes/placement.py, mesh/rules/load.py): a real-time run needs a fraction of a core, a run as fast as
possible a whole one. A configured `max_running` caps the runs of the whole service besides.

The chosen host gets the `RunRequest` in a thread of its own: a host that is slow to answer (up to the
query timeout) holds up no other session's commands. The run counts on that host while it is handed
over. A host that answers busy (its status was stale) gets no offer until its next status; the run
goes back to the head of the queue. The outcome (which host took it, or why none did) goes back to
the proxy.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
from simecs.mesh.process.hublink import HubLink
from simecs.mesh.process.runtime import RequestError
from simecs.mesh.process.seal import Seal
from simecs.mesh.protocol import codec, keys, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import load

from .placement import GoingRun, Hosts
from .sessions import SessionRecord, SessionStore

HANDOVER_TIMEOUT_S = 10.0
HUB_WAIT_S = 60.0  # a hand-over that met a hub restart waits this long for the hub, then tries again
BUSY = '"code":"busy"'
QUEUE_WAITS_AFTER_HUB_S = 10.0  # queued runs wait this long after a hub restart for the simulators to be back
#: ... and this long after the last simulator host left: a node restarted (its start, its first worker
#: warmed: up to ~10 s on a loaded 2-core machine), or whose link to the hub was cut for longer than
#: the lease (a host starved of CPU), comes back within it. PROTOCOL.md §5.2 says it.
QUEUE_WAITS_FOR_HOST_S = 30.0
#: A queued run's wait estimate is published again when it moved by this much (and this fraction).
WAIT_CHANGE_S = 1.0

#: (request, host that took it or "", hosts tried, their refusals), called with the proxy's lock held.
Outcome = Callable[[m.RunRequest, str, list[str], list[str]], None]


class Admission:
    def __init__(
        self,
        store: SessionStore,
        zenoh_session: Callable[[], zenoh.Session],
        seal: Callable[[], Seal],
        lock: threading.RLock,
        outcome: Outcome,
        max_running: int | None = None,
        max_queue: int = 16,
        hosts: Hosts | None = None,
        host_wait_s: float = QUEUE_WAITS_FOR_HOST_S,
    ) -> None:
        self.store = store
        self.host_wait_s = host_wait_s  # the proxy's --host-wait-s
        self._z = zenoh_session
        self._seal = seal
        self.lock = lock
        self.outcome = outcome
        self.max_running = max_running or 0  # 0: no ceiling beyond what the hosts can carry
        self.max_queue = max_queue
        self.hosts = hosts or Hosts()
        self.queue: collections.deque[str] = collections.deque()
        self.pending: dict[str, m.RunRequest] = {}  # session -> the request of its queued run
        self.hub: HubLink | None = None  # set once the proxy's session is open
        #: Runs of closed sessions still ending (the run tracker's): they hold a slot until then.
        self.orphans: dict[str, tuple[str, str]] = {}

    def occupied(self) -> int:
        """Runs going, runs being handed to a simulator, and runs of closed sessions that were told
        to abort and have not ended yet."""
        return sum(1 for s in self.store if s.phase in phases.GOING or s.starting) + len(self.orphans)

    def enqueue(self, rec: SessionRecord, request: m.RunRequest) -> None:
        """Queue a run, or refuse it with `busy` when the queue is full."""
        if len(self.queue) >= self.max_queue:
            raise RequestError(
                "busy",
                f"server full: {self.occupied()} runs going and {len(self.queue)} waiting, the most "
                f"that may wait (run_queue = {self.max_queue}): run again when a run has ended, or "
                "abort one of yours",
            )
        self.pending[rec.id] = request
        self.queue.append(rec.id)

    def withdraw(self, rec: SessionRecord) -> bool:
        """Take a session's run out of the queue (aborted or closed); whether it was queued."""
        self.pending.pop(rec.id, None)
        if rec.id in self.queue:
            self.queue.remove(rec.id)
            return True
        return False

    def requeue(self, rec: SessionRecord, request: m.RunRequest, first: bool = False) -> None:
        """A run takes its place in the queue again: after a proxy restart (at the end), or when its
        host was lost or every host offered was busy (`first`: at the head)."""
        self.pending[rec.id] = request
        if rec.id in self.queue:
            self.queue.remove(rec.id)
        if first:
            self.queue.appendleft(rec.id)
        else:
            self.queue.append(rec.id)

    def update(self) -> None:
        """Start queued runs, in order, while a host can take the next one; tell the others their
        position and their estimated wait."""
        while self.queue:
            if self.max_running and self.occupied() >= self.max_running:
                break
            sid = self.queue[0]
            rec = self.store.records.get(sid)
            request = self.pending.get(sid)
            if rec is None or request is None or rec.phase != "queued":
                self.queue.popleft()
                self.pending.pop(sid, None)
                continue
            if not self.hosts.live:
                if self.hub is not None and self.hub.lost_since(time.monotonic() - QUEUE_WAITS_AFTER_HUB_S):
                    break  # the hub went away lately: its simulators come back with it
                if self.hosts.left_lately(self.host_wait_s):
                    break  # the proxy's tick asks again until it is back or the wait is over
                self._fail_head(request, "no simulator node is on the mesh")
                continue
            if not self.hosts.offers(request.model_id) and not request.recording:
                self._fail_head(request, f"no simulator host offers model {request.model_id}")
                continue
            host, _why = self.hosts.choose(request)
            if not host:
                break
            self.queue.popleft()
            self.pending.pop(sid, None)
            self._start(rec, request, host)
        self._publish_positions()

    def _fail_head(self, request: m.RunRequest, why: str) -> None:
        self.queue.popleft()
        self.pending.pop(request.session, None)
        self.outcome(request, "", [], [why])

    def _publish_positions(self) -> None:
        queued = [(sid, self.pending[sid]) for sid in self.queue if sid in self.pending]
        waits = self.hosts.wait_estimates(self._going(), [r for _, r in queued]) if queued else []
        for pos, ((sid, _), wait) in enumerate(zip(queued, waits, strict=True), start=1):
            rec = self.store.records[sid]
            wait = round(wait, 1) if math.isfinite(wait) else 0.0  # 0: unknown
            moved = abs(wait - rec.state.wait_s) >= max(WAIT_CHANGE_S, 0.2 * rec.state.wait_s)
            if rec.state.queue_position != pos or moved:
                rec.state.queue_position, rec.state.wait_s = pos, wait
                self.store.publish_state(rec)

    def _going(self) -> list[GoingRun]:
        """Runs going or being handed over, as the wait estimate needs them: where, how big, how
        long still (paced: at their speed; fast: at their RTF so far, or their model's cost)."""
        out = []
        for rec in self.store:
            host = rec.state.host
            view = self.hosts.views.get(host)
            if not host or view is None or (rec.phase not in phases.GOING and not rec.starting):
                continue
            info = rec.run_info(rec.state.run_id)
            replay = bool(info is not None and info.recording)
            cost = load.model_cost(view.load, rec.model_id, replay)
            stop = info.stop_time if info is not None else rec.settings.stop_time
            speed = rec.settings.speed
            if not math.isfinite(speed):
                if rec.state.rtf > 0:
                    speed = rec.state.rtf
                else:  # not stepping yet: its model's cost says how fast it will go, once measured
                    measured = load.measured_cost(view.load, rec.model_id, replay, fast=True)
                    speed = 1.0 / max(measured, 1e-6) if measured is not None else math.nan
            left = max(stop - rec.state.sim_time, 0.0) / speed
            out.append(GoingRun(host, load.demand(rec.settings, cost, replay), left))
        return out

    def _start(self, rec: SessionRecord, request: m.RunRequest, host: str) -> None:
        rec.starting, rec.abort_run = True, ""
        rec.state.queue_position, rec.state.wait_s, rec.state.host = 0, 0.0, host
        self.store.publish_state(rec)
        self.hosts.reserve(host, request)
        threading.Thread(
            target=self._dispatch, args=(request, host), name=f"dispatch:{rec.id[:8]}", daemon=True
        ).start()

    def _dispatch(self, request: m.RunRequest, host: str) -> None:
        """Offer the run to its host (without the lock), then report the outcome. A hand-over that
        failed because the hub went away is tried again once the hub is back."""
        errors: list[str] = []
        accepted, busy = "", False
        try:
            payload = codec.dumps(request)
            for _attempt in range(3):
                began = time.monotonic()
                errors = []
                accepted = self._offer(host, payload, errors)
                busy = not accepted and bool(errors) and all(BUSY in e for e in errors)
                if accepted or busy or self.hub is None or not self.hub.lost_since(began):
                    break
                if not self.hub.wait_back(HUB_WAIT_S):
                    errors.append(f"the hub has been unreachable for {HUB_WAIT_S:g} s")
                    break
        except Exception as exc:  # never leave the run half handed over
            errors.append(f"{type(exc).__name__}: {exc}")
        with self.lock:
            rec = self.store.records.get(request.session)
            if rec is not None:
                rec.starting = False
            if not accepted:
                self.hosts.release(host, request.session, request.run_id)
                if rec is not None and rec.state.run_id == request.run_id:
                    rec.state.host = ""
            waiting = rec is not None and rec.phase == "queued" and rec.abort_run != request.run_id
            if not accepted and waiting and (busy or host not in self.hosts.live):
                # Its status was stale, or it left meanwhile: another host, or this one's next status.
                assert rec is not None
                if busy:
                    self.hosts.refused(host)
                self.requeue(rec, request, first=True)
            else:
                self.outcome(request, accepted, [host], errors)
            self.update()

    def _offer(self, host: str, payload: bytes, errors: list[str]) -> str:
        """Hand the run to `host`: sealed, so the host knows it comes from the proxy; and only a sealed
        answer counts (a peer that merely declared itself a simulator does not get the run)."""
        key, seal = keys.simulator_run(host), self._seal()
        try:
            replies: list[Any] = list(
                self._z().get(
                    key, payload=payload, attachment=seal.mac(key, payload), timeout=HANDOVER_TIMEOUT_S
                )
            )
        except zenoh.ZError as exc:
            errors.append(f"{host}: {exc}")
            return ""
        for reply in replies:
            if reply.ok is not None:
                if seal.sample_valid(reply.ok):
                    return host
                errors.append(f"{host}: its answer carries no valid service seal (not a service node)")
                continue
            errors.append(f"{host}: {reply.err.payload.to_bytes().decode('utf-8', 'replace')[:300]}")
        if not replies:
            errors.append(f"{host}: no answer")
        return ""
