"""The jog pendant (paper §6 telemanipulation): pick joint or Cartesian space and an axis, click - or +
to move the running arm that way at the speed override, Stop to stop. `jog.JogControl` does the rest."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .jog import JogControl


class JogPanel:
    def __init__(self, gui: Any, jog: JogControl, on_error: Callable[[str], None]) -> None:
        self.jog = jog
        self.on_error = on_error
        gui.add_markdown(
            "Move the **running** arm by hand (a run paced in real time). Click **-** or **+** to jog the "
            "axis, **Stop** to stop; jogging also stops if this page loses the server."
        )
        self.space = gui.add_dropdown("Space", ("joint", "cartesian"), hint="joint speeds, or the tool's")
        self.axis = gui.add_dropdown("Axis", tuple(jog.axes("joint")) or ("-",))
        self.speed = gui.add_slider("Speed [%]", min=1.0, max=100.0, step=1.0, initial_value=jog.speed_pct)
        self.buttons = gui.add_button_group("Jog", ("-", "Stop", "+"))
        self.status = gui.add_markdown("_Not jogging._")
        self.space.on_update(self._space)
        self.speed.on_update(self._speed)
        self.buttons.on_click(self._clicked)

    def _space(self, _event: Any) -> None:
        self.jog.stop()
        self.axis.options = tuple(self.jog.axes(str(self.space.value)))
        self._show()

    def _speed(self, _event: Any) -> None:
        self.jog.speed_pct = float(self.speed.value)

    def _clicked(self, event: Any) -> None:
        action = event.target.value
        if action == "Stop":
            self.jog.stop()
        else:
            why = self.jog.start(str(self.space.value), str(self.axis.value), -1.0 if action == "-" else 1.0)
            if why:
                self.on_error(why)
        self._show()

    def _show(self) -> None:
        label = self.jog.label
        self.status.content = f"Jogging **{label}**." if label else "_Not jogging._"
