"""The proxy's view of the simulator hosts: which are up (their liveliness tokens), what each carries
and can carry (the `SimulatorLoad` of their sealed status), and the runs on their way to each. From it:
which host takes a run (the least loaded that can hold it, mesh/rules/load.py), and how long a queued run
will wait.

A run handed to a host is *reserved* there until the host's status lists it, so a burst of runs does
not all go to the host that looked emptiest a second ago. A host that refused a run as busy gets no
other offer until its next status.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field

from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import load

#: s: a run on its way to a host that never lists it stops counting against the host after this (the
#: proxy's --reservation-s). A run that ended is released at once, listed or not.
RESERVATION_S = 15.0


@dataclass
class HostView:
    node_id: str
    load: m.SimulatorLoad | None = None
    seen_at: float = 0.0
    refused_at: float = -math.inf  # the last busy answer: no offer until a newer status
    reserved: dict[tuple[str, str], tuple[float, float]] = field(default_factory=dict)  # run -> (demand, at)

    def reserved_demand(self) -> float:
        return sum(d for d, _ in self.reserved.values())


@dataclass
class GoingRun:
    """What the proxy knows of a run going, for the wait estimate."""

    host: str
    demand: float
    remaining_s: float  # wall seconds until it ends, as it goes (math.nan: not known yet)


class Hosts:
    """Simulator hosts as the proxy sees them. Called with the proxy's lock held."""

    def __init__(self, reservation_s: float = RESERVATION_S) -> None:
        self.views: dict[str, HostView] = {}
        self.live: set[str] = set()
        self.reservation_s = reservation_s  # the proxy's --reservation-s
        self._last_left = -math.inf  # monotonic s: when a host last left the mesh

    # -- what the mesh says ---------------------------------------------------------------------------
    def joined(self, node_id: str) -> None:
        self.live.add(node_id)
        self.views.setdefault(node_id, HostView(node_id))

    def left(self, node_id: str) -> None:
        self.live.discard(node_id)
        self.views.pop(node_id, None)
        self._last_left = time.monotonic()

    def left_lately(self, within_s: float) -> bool:
        """No host is live, and the last one left less than `within_s` ago (it may be coming back)."""
        return not self.live and time.monotonic() - self._last_left < within_s

    def status(self, node_id: str, status: m.SimulatorLoad) -> None:
        view = self.views.setdefault(node_id, HostView(node_id))
        view.load, view.seen_at = status, time.monotonic()
        listed = {(r.session, r.run_id) for r in status.runs}
        now = time.monotonic()
        view.reserved = {
            run: (d, at)
            for run, (d, at) in view.reserved.items()
            if run not in listed and now - at < self.reservation_s
        }

    def reserve(self, node_id: str, request: m.RunRequest) -> None:
        view = self.views.get(node_id)
        if view is not None:
            need = load.request_demand(request, view.load)
            view.reserved[(request.session, request.run_id)] = (need, time.monotonic())

    def release(self, node_id: str, session: str, run_id: str) -> None:
        """The run is no longer on its way to `node_id`: refused there, or already over (a short run
        can end before the host's next status lists it)."""
        view = self.views.get(node_id)
        if view is not None:
            view.reserved.pop((session, run_id), None)

    def refused(self, node_id: str) -> None:
        view = self.views.get(node_id)
        if view is not None:
            view.refused_at = time.monotonic()

    # -- decisions ------------------------------------------------------------------------------------
    def usable(self) -> list[HostView]:
        """Live hosts whose load is known."""
        return [v for n, v in sorted(self.views.items()) if n in self.live and v.load is not None]

    def choose(
        self, request: m.RunRequest, exclude: set[str] | frozenset[str] = frozenset()
    ) -> tuple[str, str]:
        """(the host to take the run, '') or ('', why none can now)."""
        best: tuple[float, int, str] | None = None
        reasons = []
        for view in self.usable():
            assert view.load is not None
            if view.node_id in exclude:
                continue
            if view.refused_at >= view.seen_at:
                reasons.append(f"{view.node_id}: busy (waiting for its next status)")
                continue
            why = load.refusal(view.load, request, view.reserved_demand(), len(view.reserved))
            if why:
                reasons.append(f"{view.node_id}: {why}")
                continue
            spare = load.free_cores(view.load, view.reserved_demand()) - load.request_demand(
                request, view.load
            )
            rank = (-spare, len(view.load.runs) + len(view.reserved), view.node_id)
            if best is None or rank < best:
                best = rank
        if best is not None:
            return best[2], ""
        return "", "; ".join(reasons) or "no simulator host has reported its load yet"

    def offers(self, model_id: str) -> bool:
        """Whether some live host can run the model at all (a host that has not said yet may)."""
        return any(load.offers(v.load, model_id) for n, v in self.views.items() if n in self.live)

    def wait_estimates(self, going: list[GoingRun], queued: list[m.RunRequest]) -> list[float]:
        """Seconds each queued run (in queue order) will wait before it starts: the going runs end as
        they progress, and each queued run takes the first host where its demand fits (and its
        `max_runs` allows) once enough runs have ended (runs start in queue order). math.inf when no
        host could ever hold it; math.nan when it hangs on a run whose length is not known yet (its
        model's cost not yet measured on its host: a guess would be off several times over)."""
        free: dict[str, float] = {v.node_id: v.load.capacity for v in self.usable() if v.load is not None}
        slots = {h: self._max_runs(h) for h in free}
        warm = {h: [0.0] * self._status(h).warm for h in free}  # when each warm worker is ready
        ends: list[tuple[float, bool, str, float]] = []  # (when, known, host, demand freed)
        for run in going:
            if run.host in free:
                free[run.host] -= run.demand
                slots[run.host] -= 1
                known = math.isfinite(run.remaining_s)
                heapq.heappush(ends, (run.remaining_s if known else 0.0, known, run.host, run.demand))
        now, known_now, out = 0.0, True, []
        for request in queued:
            while True:
                fits = [
                    h
                    for h, f in free.items()
                    if slots[h] > 0
                    and (f + 1e-9 >= self._demand(h, request) or f >= self._capacity(h) - 1e-9)
                ]
                if fits:
                    host = max(fits, key=lambda h: free[h])
                    need = self._demand(host, request)
                    free[host] -= need
                    slots[host] -= 1
                    took = self._duration(host, request, self._start_s(host, warm[host], now))
                    took_known = known_now and took is not None
                    heapq.heappush(ends, (now + (took or 0.0), took_known, host, need))
                    out.append(now if known_now else math.nan)
                    break
                if not ends:
                    out.append(math.inf)
                    break
                now, known, host, freed = heapq.heappop(ends)
                known_now = known_now and known
                free[host] += freed
                slots[host] += 1
        return out

    def _status(self, host: str) -> m.SimulatorLoad:
        status = self.views[host].load
        assert status is not None  # only usable hosts are simulated
        return status

    def _max_runs(self, host: str) -> int:
        status = self._status(host)
        return status.max_runs if status.max_runs > 0 else 1 << 30

    def _demand(self, host: str, request: m.RunRequest) -> float:
        return load.request_demand(request, self.views[host].load)

    def _capacity(self, host: str) -> float:
        return self._status(host).capacity

    def _start_s(self, host: str, warm: list[float], now: float) -> float:
        """How long a run handed to `host` at `now` takes to start: on a warm worker, the measured
        hand-over; else until the next worker is warm. The worker it takes is replaced, warm after the
        host's measured warm-up."""
        status = self._status(host)
        ready = heapq.heappop(warm) if warm else math.inf
        heapq.heappush(warm, now + status.cold_start_s)
        return status.start_s + min(max(ready - now, 0.0), status.cold_start_s)

    def _duration(self, host: str, request: m.RunRequest, start_s: float) -> float | None:
        """Wall seconds the run will take on `host` from its hand-over: its start, then stop time over
        its speed (fast: over the RTF its model's measured cost allows; None while that is unmeasured)."""
        speed = request.settings.speed
        if not math.isfinite(speed):
            cost = load.measured_cost(
                self._status(host), request.model_id, bool(request.recording), fast=True
            )
            if cost is None:
                return None
            speed = 1.0 / max(cost, 1e-6)
        return start_s + request.settings.stop_time / speed
