"""Admission: at most N runs at once, the rest queued in order, each handed to a simulator host.

A run waits in the queue (its session `queued` with a position) until a slot is free, then its
`RunRequest` goes to a live simulator host, round robin, in a thread of its own: a host that is slow to
answer (up to the query timeout) holds up no other session's commands. The run holds its slot while it
is being handed over. The outcome (which host took it, or why none did) goes back to the proxy.
"""

from __future__ import annotations

import collections
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
from simecs.mesh import codec, keys, phases
from simecs.mesh import messages as m
from simecs.mesh.hublink import HubLink
from simecs.mesh.runtime import RequestError
from simecs.mesh.seal import Seal

from .sessions import SessionRecord, SessionStore

HANDOVER_TIMEOUT_S = 10.0
HUB_WAIT_S = 60.0  # a hand-over that met a hub restart waits this long for the hub, then tries again
#: Every host answered busy: offer again this often, this long (a run that reported its end may still
#: be leaving its process), before the run fails.
BUSY_RETRY_S = 0.2
BUSY_WAIT_S = 5.0
BUSY = '"code":"busy"'

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
    ) -> None:
        self.store = store
        self._z = zenoh_session
        self._seal = seal
        self.lock = lock
        self.outcome = outcome
        self.max_running = max_running or os.cpu_count() or 1
        self.max_queue = max_queue
        self.queue: collections.deque[str] = collections.deque()
        self.pending: dict[str, m.RunRequest] = {}  # session -> the request of its queued run
        self._rr = 0
        self.hub: HubLink | None = None  # set once the proxy's session is open
        #: Runs of closed sessions still ending (the run tracker's): they hold a slot until then.
        self.orphans: dict[str, tuple[str, str]] = {}

    def occupied(self) -> int:
        """Simulation slots in use: runs going, runs being handed to a simulator, and runs of closed
        sessions that were told to abort and have not ended yet."""
        return sum(1 for s in self.store if s.phase in phases.GOING or s.starting) + len(self.orphans)

    def enqueue(self, rec: SessionRecord, request: m.RunRequest) -> None:
        """Queue a run, or refuse it with `busy` when every slot and the whole queue are taken."""
        active = self.occupied()
        if active >= self.max_running and len(self.queue) >= self.max_queue:
            raise RequestError(
                "busy",
                f"server full: {active} runs going and {len(self.queue)} waiting (limit {self.max_queue})",
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

    def requeue(self, rec: SessionRecord, request: m.RunRequest) -> None:
        """After a proxy restart: a queued run takes its place again."""
        self.pending[rec.id] = request
        self.queue.append(rec.id)

    def update(self) -> None:
        """Start queued runs while there is a free slot; tell the others their position."""
        while self.queue and self.occupied() < self.max_running:
            sid = self.queue.popleft()
            rec = self.store.records.get(sid)
            request = self.pending.pop(sid, None)
            if rec is not None and request is not None and rec.phase == "queued":
                self._start(rec, request)
        for pos, sid in enumerate(self.queue, start=1):
            rec = self.store.records[sid]
            if rec.state.queue_position != pos:
                rec.state.queue_position = pos
                self.store.publish_state(rec)

    def _start(self, rec: SessionRecord, request: m.RunRequest) -> None:
        rec.starting, rec.abort_run = True, ""
        rec.state.queue_position = 0
        self.store.publish_state(rec)
        self._rr += 1
        threading.Thread(
            target=self._dispatch, args=(request, self._rr), name=f"dispatch:{rec.id[:8]}", daemon=True
        ).start()

    def simulators(self) -> list[str]:
        hosts = []
        for reply in self._z().liveliness().get(f"{keys.ROOT}/@node/simulator/*", timeout=1.0):
            if reply.ok is not None:
                token = keys.parse("node_token", reply.ok.key_expr)
                hosts.append(token["node"])
        return sorted(hosts)

    def _dispatch(self, request: m.RunRequest, rr: int) -> None:
        """Offer the run to the simulators in turn (without the lock), then report the outcome. A
        hand-over that failed because the hub went away is tried again once the hub is back."""
        hosts: list[str] = []
        errors: list[str] = []
        accepted = ""
        try:
            payload = codec.dumps(request)
            busy_until = time.monotonic() + BUSY_WAIT_S
            attempt = 0
            while attempt < 3:
                began = time.monotonic()
                hosts, errors = self.simulators(), []
                for i in range(len(hosts)):
                    host = hosts[(rr + i) % len(hosts)]
                    accepted = self._offer(host, payload, errors)
                    if accepted:
                        break
                if not accepted and hosts and all(BUSY in e for e in errors) and began < busy_until:
                    # Every host is full: a run that just ended may not have left its process yet.
                    time.sleep(BUSY_RETRY_S)
                    continue
                attempt += 1
                if accepted or self.hub is None or not self.hub.lost_since(began):
                    break
                if not self.hub.wait_back(HUB_WAIT_S):
                    errors.append(f"the hub has been unreachable for {HUB_WAIT_S:g} s")
                    break
        except Exception as exc:  # never leave the slot taken
            errors.append(f"{type(exc).__name__}: {exc}")
        with self.lock:
            rec = self.store.records.get(request.session)
            if rec is not None:
                rec.starting = False
            self.outcome(request, accepted, hosts, errors)
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
