"""A controller in the loop: the worker's side of the lockstep exchange of PROTOCOL.md §6.3.

Each control period the worker puts the sensors of the period's start on `hil/sensors` and simulates
the period only once the actuator frame with the same `seq` has come back on `hil/actuators`: the
simulated time never runs ahead of the controller, however slow it is. A paced run (realtime, scaled)
also starts each period at its wall time and counts the answers that come later than one period
(misses, worst lateness); a controller silent for `hil_timeout` fails the run. The simulator keeps
the drive (current loops, motor, gear): the controller's output is each joint's current set point.
The exchange runs inside the solver's call for a whole chunk (`Simulation.set_period_hook`): a call
per period cost more than the period's own solver steps.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import zenoh
from simecs.mesh.process.seal import Seal, SealedPublisher
from simecs.mesh.protocol import hil, keys
from simecs.mesh.protocol import messages as m

from .pacing import Pacer

if TYPE_CHECKING:
    from simecs.models import Simulation

log = logging.getLogger("simecs.worker")
MISS_NOTICE_S = 5.0  # wall seconds between two notices about missed deadlines


class ControllerSilent(ValueError):
    """No usable actuator frame within the run's hil_timeout: the run fails with this text."""


def external_joints(settings: m.RunSettings, joints: list[str]) -> np.ndarray:
    """Which joints the external controller drives; ValueError naming an unknown joint."""
    if not settings.external_joints:
        return np.ones(len(joints), dtype=bool)
    mask = np.zeros(len(joints), dtype=bool)
    for i, name in enumerate(settings.external_joints):
        if name not in joints:
            raise ValueError(f"settings.external_joints[{i}]: {name!r} is not a joint ({', '.join(joints)})")
        mask[joints.index(name)] = True
    return mask


class Lockstep:
    """The exchange for one run; `advance` replaces the source's own."""

    def __init__(
        self,
        z: zenoh.Session,
        req: m.RunRequest,
        sim: Simulation,
        joints: list[str],
        pacer: Pacer,
        tell: Callable[[str], None],
        stopped: Callable[[], bool],
        seal: Seal,
    ) -> None:
        st = req.settings
        self.sim, self.pacer, self.tell, self.stopped = sim, pacer, tell, stopped
        self.n = len(joints)
        self.run_index, self.attempt = req.run_index, req.attempt
        self.period = st.control_period
        self.timeout = st.hil_timeout
        ratio = self.period / sim.h
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(
                f"settings.control_period: {self.period:g} s is not a whole number of solver steps "
                f"({sim.h:g} s)"
            )
        sim.set_points.set_external(external_joints(st, joints))
        sim.set_period_hook(round(ratio), self._period)
        self.row = np.empty(1 + len(hil.SENSOR_JOINT_FIELDS) * self.n)
        self.seq = 0
        self.aborted = False
        self.stats = m.HilStats()
        self._expect = -1
        self._answer: np.ndarray | None = None
        self._arrived = 0.0
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._problems: list[str] = []  # refused frames not told yet (a few: each is told once)
        self._last_problem = ""
        self._last_miss_notice = -math.inf
        u, s = req.user, req.session
        sensors = keys.hil_sensors(u, s)  # sealed, as every key a worker writes
        self.pub = SealedPublisher(z.declare_publisher(sensors, express=True), sensors, seal)
        self.sub = z.declare_subscriber(keys.hil_actuators(u, s), self._on_actuators)

    def _on_actuators(self, sample: zenoh.Sample) -> None:
        """A zenoh callback: returns at once. Frames of other runs and repeats are dropped silently."""
        arrived = time.perf_counter()
        try:
            got = hil.read_actuators(sample.payload.to_bytes(), self.run_index, self.n, self.attempt)
        except hil.ActuatorProblem as exc:
            with self._lock:
                self._last_problem = str(exc)
                if len(self._problems) < 8:
                    self._problems.append(str(exc))
            return
        if got is None:
            return
        seq, values = got
        with self._lock:
            if seq != self._expect or self._answer is not None:
                return
            self._answer, self._arrived = values, arrived
        self._event.set()

    def advance(self, until: float) -> np.ndarray:
        """Simulate up to `until`, exchanging a frame with the controller at the start of every control
        period on the way; rows as `Simulation.advance` gives them. Once the run is aborted the rest of
        the call goes without exchange or pacing (its rows are not the run's)."""
        return self.sim.advance(until)

    def _period(self) -> None:
        """The simulation's period hook: this period's exchange at its start, in the solver's call."""
        if self.aborted:
            return
        sim = self.sim
        t = sim.time
        ahead = self.pacer.ahead(t)
        if ahead > 0:
            time.sleep(ahead)
        sim.sensors(self.row)
        i_ref = self._exchange(t)
        if i_ref is None:
            self.aborted = True
            return
        sim.set_points.set_actuators(i_ref)
        self.seq += 1

    def _exchange(self, t: float) -> np.ndarray | None:
        """Put this period's sensor frame and wait for its answer (None: the run was aborted)."""
        with self._lock:
            self._expect, self._answer = self.seq, None
        self._event.clear()
        frame = hil.sensor_frame(self.run_index, self.seq, time.time_ns(), self.row, self.attempt)
        sent = time.perf_counter()
        self.pub.put(frame)
        give_up = sent + self.timeout
        while not self._event.wait(min(hil.RESEND_S, max(give_up - time.perf_counter(), 0.0))):
            self._tell_problem()
            if self.stopped():
                return None
            if time.perf_counter() >= give_up:
                with self._lock:
                    problem = self._last_problem
                raise ControllerSilent(
                    f"external controller silent: no actuator frame for period {self.seq} "
                    f"(t = {t:.4f} s) within hil_timeout = {self.timeout:g} s"
                    + (f"; the last frame refused: {problem}" if problem else "")
                )
            self.pub.put(frame)  # the same seq again: a late joiner or a lost frame costs one repeat
        with self._lock:
            answer, arrived = self._answer, self._arrived
        self.stats.periods += 1
        if self.pacer.paced:
            late = arrived - (sent + self.period / self.pacer.speed)
            if late > 0:
                self._missed(t, late)
        self._tell_problem()
        return answer

    def _missed(self, t: float, late: float) -> None:
        st = self.stats
        st.misses += 1
        st.worst_late_ms = max(st.worst_late_ms, late * 1e3)
        now = time.monotonic()
        if now - self._last_miss_notice >= MISS_NOTICE_S:
            self._last_miss_notice = now
            self.tell(
                f"external controller late at t = {t:.3f} s: {st.misses} of {st.periods} periods so far "
                f"answered after their {self.period * 1e3:g} ms deadline "
                f"(worst {st.worst_late_ms:.2f} ms late)"
            )

    def _tell_problem(self) -> None:
        if not self._problems:  # read without the lock: a miss is caught at the next call
            return
        with self._lock:
            problems, self._problems = self._problems, []
        for problem in problems:
            log.warning("hil/actuators frame refused: %s", problem)
            self.tell(f"hil/actuators frame refused: {problem}")

    def summary(self) -> str:
        """The closing word on timeliness, '' when every answer was in time."""
        st = self.stats
        if not st.misses:
            return ""
        return (
            f"external controller: {st.misses} of {st.periods} periods answered late "
            f"(worst {st.worst_late_ms:.2f} ms past the deadline)"
        )

    def close(self) -> None:
        self.sim.set_period_hook(0, None)
        for e in (self.sub, self.pub):
            try:
                e.undeclare()
            except Exception:
                pass
