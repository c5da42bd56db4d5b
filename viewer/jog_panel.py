"""The jog pendant (paper §6 telemanipulation): pick joint or Cartesian space and an axis, hold - or +
to move the arm that way at the speed override, let go to stop. An idle arm is jogged in a run until
stopped, which **Stop jogging** ends (Teach then records where the arm was left). `jog.JogControl`
does the rest.

viser reports a held button as hold messages, about 10 a second, and its release as a click: the
buttons here take both (`on_hold` moves, `on_click` stops). It reports no key presses."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .jog import JogControl

HOLD_HZ = 10.0  # hold messages a second while a jog button is held (each one keeps the jog going)
JOG_HELP = (
    "**Hold** − or + to move the axis, **let go** to stop (a page that loses the server stops the arm "
    "too). An idle arm is jogged in a real-time run that lasts until **Stop jogging**; **Teach** in a "
    "pendant then records where you left it. A running run is jogged on top of its command."
)


class JogPanel:
    def __init__(self, gui: Any, jog: JogControl, on_error: Callable[[str], None]) -> None:
        self.jog = jog
        self.on_error = on_error
        gui.add_markdown(JOG_HELP)
        self.space = gui.add_dropdown("Space", ("joint", "cartesian"), hint="joint speeds, or the tool's")
        self.axis = gui.add_dropdown("Axis", tuple(jog.axes("joint")) or ("-",))
        self.speed = gui.add_slider("Speed [%]", min=1.0, max=100.0, step=1.0, initial_value=jog.speed_pct)
        self.minus = gui.add_button("Jog −", hint="hold to move the axis the negative way")
        self.plus = gui.add_button("Jog +", hint="hold to move the axis the positive way")
        self.finish = gui.add_button(
            "Stop jogging", color="gray", hint="end the run until stopped that jogging an idle arm started"
        )
        self.status = gui.add_markdown("_Not jogging._")
        self.space.on_update(self._space)
        self.speed.on_update(self._speed)
        for button, sign in ((self.minus, -1.0), (self.plus, 1.0)):
            button.on_hold(lambda _e, sign=sign: self._held(sign), callback_hz=HOLD_HZ)
            button.on_click(lambda _e: self._released())
        self.finish.on_click(lambda _e: self._finish())

    def _space(self, _event: Any) -> None:
        self.jog.stop()
        self.axis.options = tuple(self.jog.axes(str(self.space.value)))
        self._show()

    def _speed(self, _event: Any) -> None:
        self.jog.speed_pct = float(self.speed.value)

    def _held(self, sign: float) -> None:
        was = self.jog.label
        why = self.jog.hold(str(self.space.value), str(self.axis.value), sign)
        if why:
            if not was:  # said once per press, not ten times a second
                self.on_error(why)
            return
        if self.jog.label != was:
            self._show()

    def _released(self) -> None:
        self.jog.release()
        self._show()

    def _finish(self) -> None:
        why = self.jog.finish()
        if why:
            self.on_error(why)
        self._show()

    def _show(self) -> None:
        label = self.jog.label
        text = f"Jogging **{label}**." if label else "_Not jogging._"
        if self.status.content != text:
            self.status.content = text
