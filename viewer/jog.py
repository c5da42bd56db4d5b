"""Jogging the arm from the browser as on a teach pendant (telemanipulation, PROTOCOL.md §5.4): one
axis at a time, a joint or a tool direction, at a speed override, while the user holds the button.

viser reports a held button as repeated hold messages (about 10 a second) and its release as a click;
it reports no key presses. So the jog goes on while hold messages keep coming (`hold`), and stops at
the release (`release`) or, should the release be lost, once they stop coming (`HELD_S`). While it
lasts the velocity is re-sent every RESEND_S, well within the server's deadman time, so a closed or
disconnected tab stops the arm by itself.

An idle arm is jogged too: the first hold starts a run until stopped (real time, holding the initial
pose), the jog moves it, and `finish` ends that run as finished; Teach then records where the jog
left the arm. Part of the session controller (it reads the tab's state only); no viser here.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import msgspec
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol import phases

from .tab_state import TabState

RESEND_S = 0.1
#: s without a hold message after which a jog counts as released (viser sends one every 0.1 s).
HELD_S = 0.35
CARTESIAN_AXES = ("x", "y", "z", "roll", "pitch", "yaw")
WALL_PACED = ("realtime", "scaled")
#: s a jog of the idle arm waits for the run until stopped it asked for before asking again.
OPENING_S = 5.0


class JogControl:
    """The jog of one tab's session: `view` its state, `closed()` the tab went away; `open_run()`
    starts a run until stopped and `finish_run()` ends it (on the controller's worker)."""

    def __init__(
        self,
        view: TabState,
        closed: Callable[[], bool],
        open_run: Callable[[], None] = lambda: None,
        finish_run: Callable[[], None] = lambda: None,
    ) -> None:
        self.c = view
        self.closed = closed
        self.open_run = open_run
        self.finish_run = finish_run
        self.speed_pct = 25.0
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        self.active: m.JogInput | None = None  # run_id filled in as each message goes
        self.held_until = 0.0
        self.label = ""
        self.asked_at = -1e9  # when a jog of the idle arm last asked for a run until stopped
        self._thread: threading.Thread | None = None

    def axes(self, space: str) -> list[str]:
        model = self.c.model
        if space == "joint":
            return [link.joint for link in model.links] if model is not None else []
        return list(CARTESIAN_AXES)

    def refusal(self) -> str:
        """Why a jog cannot start now ('' when it can: an idle arm gets a run until stopped)."""
        st, layout = self.c.state, self.c.stream.layout if self.c.stream is not None else None
        if self.c.session is None or self.c.model is None:
            return "load a model first (Models)"
        phase = st.phase if st is not None else "created"
        if phase in phases.EDITABLE:
            return ""  # idle: a run until stopped starts with the jog
        if phase == "paused":
            return "the run is paused: Resume it to jog"
        if layout is not None and st is not None and layout.run_id == st.run_id and layout.source == "replay":
            return "a replay plays its recording: it cannot be jogged"
        if phase == "running" and not self.c.until_stopped() and self.c.settings.pacing not in WALL_PACED:
            return "jogging needs a run paced in wall time (Settings: real time or N x real time)"
        return ""

    def hold(self, space: str, axis: str, sign: float) -> str:
        """The user holds the jog button of `axis` (`sign` + or -): jog it at speed_pct of its
        maximum for HELD_S more; '' or why not."""
        why = self.refusal()
        if why:
            return why
        c = self.c
        names = self.axes(space)
        if axis not in names:
            return f"no axis {axis!r} in {space} space"
        k = names.index(axis)
        if space == "joint":
            qd = [0.0] * len(names)
            qd[k] = sign * c.values.get(f"{axis}.traj.max_speed", 0.1)
            msg = m.JogInput(run_id="", space="joint", qd=qd, speed_pct=self.speed_pct)
        else:
            top = c.values.get("cart.max_speed" if k < 3 else "cart.max_rot_speed", 0.1)
            twist = [0.0] * 6
            twist[k] = sign * top * self.speed_pct / 100.0
            msg = m.JogInput(run_id="", space="cartesian", twist=twist, speed_pct=self.speed_pct)
        idle = c.phase in phases.EDITABLE
        with self.wake:
            now = time.monotonic()
            if idle and now - self.asked_at > OPENING_S:  # once, until the run has had time to start
                self.asked_at = now
                self.open_run()
            self.active = msg
            self.held_until = time.monotonic() + HELD_S
            self.label = f"{axis} {'+' if sign > 0 else '-'} at {self.speed_pct:g} %"
            self.wake.notify()
            if self._thread is None:
                self._thread = threading.Thread(target=self._send_while_held, daemon=True, name="jog")
                self._thread.start()
        return ""

    def release(self) -> None:
        """The button was let go: the arm stops at once (a zero velocity, not the deadman's wait)."""
        with self.wake:
            was, self.active, self.label = self.active, None, ""
            self.wake.notify()
        st = self.c.state
        if was is not None and st is not None and st.phase == "running":
            self._send(m.JogInput(run_id=st.run_id, space="joint", qd=[0.0] * len(self.axes("joint"))))

    def stop(self) -> None:
        """No more jogging (the tab closes, another space is picked)."""
        self.release()

    def finish(self) -> str:
        """End the run until stopped that jogging runs in, as finished ('' or why not)."""
        self.release()
        st = self.c.state
        if not self.c.until_stopped() or st is None or st.phase not in phases.GOING:
            return "no run until stopped goes on: a jog of an idle arm starts one (hold - or +)"
        self.finish_run()
        return ""

    def _send(self, msg: m.JogInput) -> None:
        sc = self.c.session
        if sc is not None:
            try:
                sc.jog(msg)
            except Exception:  # the mesh is gone: the deadman stops the arm
                pass

    def _send_while_held(self) -> None:
        while not self.closed():
            with self.wake:
                msg = self.active
                if msg is None:
                    self.wake.wait(1.0)
                    continue
                if time.monotonic() > self.held_until:  # no hold message lately: let go
                    released = True
                else:
                    released = False
            if released:
                self.release()
                continue
            st = self.c.state
            if st is not None and st.phase == "running":  # queued: the run until stopped is starting
                self._send(msgspec.structs.replace(msg, run_id=st.run_id))
            with self.wake:
                self.wake.wait(RESEND_S)
