"""Jogging the running run from the browser (telemanipulation, PROTOCOL.md §5.4): one axis at a time,
a joint or a tool direction, at a speed override. viser buttons report clicks, not holds, so a click
starts the jog and Stop (or another axis) ends it; while it lasts, the velocity is re-sent every
RESEND_S, well within the server's deadman time, so a closed or disconnected tab stops the arm by
itself. Part of the session controller (it reads the tab's state only); no viser here.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from simecs.mesh import messages as m

from .tab_state import TabState

RESEND_S = 0.1
CARTESIAN_AXES = ("x", "y", "z", "roll", "pitch", "yaw")
WALL_PACED = ("realtime", "scaled")


class JogControl:
    """The jog of one tab's session (`view`: its state; `closed()`: the tab went away)."""

    def __init__(self, view: TabState, closed: Callable[[], bool]) -> None:
        self.c = view
        self.closed = closed
        self.speed_pct = 25.0
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        self.active: m.JogInput | None = None
        self.label = ""
        self._thread: threading.Thread | None = None

    def axes(self, space: str) -> list[str]:
        model = self.c.model
        if space == "joint":
            return [link.joint for link in model.links] if model is not None else []
        return list(CARTESIAN_AXES)

    def refusal(self) -> str:
        """Why a jog cannot start now ('' when it can)."""
        st, layout = self.c.state, self.c.stream.layout if self.c.stream is not None else None
        if self.c.session is None or self.c.model is None:
            return "load a model first (Models)"
        if st is None or st.phase != "running":
            return "jogging moves a running run: press Run first"
        if layout is not None and layout.source == "replay":
            return "a replay plays its recording: it cannot be jogged"
        if self.c.settings.pacing not in WALL_PACED:
            return "jogging needs a run paced in wall time (Settings: real time or N x real time)"
        return ""

    def start(self, space: str, axis: str, sign: float) -> str:
        """Jog one axis at speed_pct of its maximum, until stop(); '' or why not."""
        why = self.refusal()
        if why:
            return why
        c = self.c
        assert c.state is not None
        names = self.axes(space)
        if axis not in names:
            return f"no axis {axis!r} in {space} space"
        k = names.index(axis)
        if space == "joint":
            qd = [0.0] * len(names)
            qd[k] = sign * c.values.get(f"{axis}.traj.max_speed", 0.1)
            msg = m.JogInput(run_id=c.state.run_id, space="joint", qd=qd, speed_pct=self.speed_pct)
        else:
            top = c.values.get("cart.max_speed" if k < 3 else "cart.max_rot_speed", 0.1)
            twist = [0.0] * 6
            twist[k] = sign * top * self.speed_pct / 100.0
            msg = m.JogInput(run_id=c.state.run_id, space="cartesian", twist=twist, speed_pct=self.speed_pct)
        with self.wake:
            self.active = msg
            self.label = f"{axis} {'+' if sign > 0 else '-'} at {self.speed_pct:g} %"
            self.wake.notify()
            if self._thread is None:
                self._thread = threading.Thread(target=self._send_while_active, daemon=True, name="jog")
                self._thread.start()
        return ""

    def stop(self) -> None:
        with self.wake:
            was, self.active, self.label = self.active, None, ""
            self.wake.notify()
        if was is not None:  # say it at once rather than after the deadman time
            stop = m.JogInput(run_id=was.run_id, space="joint", qd=[0.0] * len(self.axes("joint")))
            self._send(stop)

    def _send(self, msg: m.JogInput) -> None:
        sc = self.c.session
        if sc is not None:
            try:
                sc.jog(msg)
            except Exception:  # the mesh is gone: the deadman stops the arm
                pass

    def _send_while_active(self) -> None:
        while not self.closed():
            with self.wake:
                msg = self.active
                if msg is None:
                    self.wake.wait(1.0)
                    continue
            st = self.c.state
            if st is None or st.run_id != msg.run_id or st.phase != "running":
                with self.wake:
                    if self.active is msg:
                        self.active, self.label = None, ""
                continue
            self._send(msg)
            with self.wake:
                self.wake.wait(RESEND_S)
