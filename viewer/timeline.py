"""One timeline for finished runs (issue 32, as Foxglove plays a recording): a time cursor with play,
pause, speed and a scrubber, in the run bar beside the arm. It drives the 3D arm, every plot's cursor
line and the values read there together (the compare panel does the drawing, compare_panel.py), from
what the tab already holds: nothing is replayed on the server.

Playing moves the cursor on the tab's loop, FRAME_S apart, by FRAME_S × speed of the run's time.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

FRAME_S = 1 / 20  # the cursor steps 20 times a wall second while it plays
SPEEDS = {"0.25×": 0.25, "0.5×": 0.5, "1×": 1.0, "2×": 2.0, "4×": 4.0}
TRANSPORT = ("▶ Play", "❚❚ Pause", "To start")


class Timeline:
    """The cursor's widgets and its playing. `on_toggle()` when the cursor is turned on or off by the
    user, `on_move()` whenever its time changes; `after(s, job)` runs `job` later on the tab's loop."""

    def __init__(
        self,
        gui: Any,
        on_toggle: Callable[[], None],
        on_move: Callable[[], None],
        after: Callable[[float, Callable[[], None]], None],
        warn: Callable[[str], None],
    ) -> None:
        self.after = after
        self.warn = warn
        self.on_toggle = on_toggle
        self.on_move = on_move
        self.playing = 0  # the playing pass (0: paused); a new pass or a pause ends the last one
        # folded at first: the run bar it sits in stays small over the arm until a run is to be scrubbed
        self.folder = gui.add_folder("Timeline", expand_by_default=False)
        with self.folder:
            self.cursor_on = gui.add_checkbox(
                "Time cursor",
                False,
                hint="a finished run only: the arm, every plot and the values at the cursor show that time",
            )
            self.cursor = gui.add_slider("Cursor [s]", min=0.0, max=1.0, step=0.001, initial_value=0.0)
            self.transport = gui.add_button_group("Play", TRANSPORT, hint="play the runs from the cursor on")
            self.speed = gui.add_dropdown("Speed", tuple(SPEEDS), initial_value="1×", hint="x the run's time")
        self.cursor_on.on_update(self._toggled)
        self.cursor.on_update(self._moved)
        self.transport.on_click(lambda e: self._transport(str(e.target.value)))

    @property
    def on(self) -> bool:
        return bool(self.cursor_on.value)

    @property
    def at(self) -> float:
        return float(self.cursor.value)

    def _toggled(self, event: Any) -> None:
        if event.client is None:
            return
        if not self.on:
            self.pause()
        self.on_toggle()

    def _moved(self, event: Any) -> None:
        if event.client is not None:
            self.pause()  # the user took the cursor: no more playing
        self.on_move()

    def _transport(self, choice: str) -> None:
        if choice == TRANSPORT[1]:
            self.pause()
            return
        if not self.on or self.cursor.disabled:
            self.warn("turn the time cursor on over a finished run first (Time cursor)")
            return
        if choice == TRANSPORT[2]:
            self.pause()
            self.cursor.value = 0.0
            return
        if self.at >= float(self.cursor.max) - 1e-9:
            self.cursor.value = 0.0  # played to the end: from the start again
        self.playing += 1
        mine = self.playing
        self.after(FRAME_S, lambda: self._step(mine))

    def _step(self, mine: int) -> None:
        if mine != self.playing or not self.on:
            return
        end = float(self.cursor.max)
        at = min(end, self.at + FRAME_S * SPEEDS.get(str(self.speed.value), 1.0))
        self.cursor.value = at  # its callback moves the arm, the plots and the values
        if at < end - 1e-9:
            self.after(FRAME_S, lambda: self._step(mine))
        else:
            self.playing = 0

    def pause(self) -> None:
        self.playing = 0

    def set_end(self, end: float) -> None:
        """The longest run in view ends at `end` s: the scrubber's range."""
        if end > 0 and abs(float(self.cursor.max) - end) > 1e-9:
            self.cursor.max = end
            if self.at > end:
                self.cursor.value = end

    def enable(self, usable: bool, busy: bool) -> None:
        """`usable`: a run's poses are in for the cursor; `busy`: a run goes on (the arm is live)."""
        self.cursor_on.disabled = busy
        if busy and self.on:
            self.cursor_on.value = False
            self.pause()
        on = self.on
        self.cursor.disabled = not on or not usable

    def turn_off(self) -> None:
        self.pause()
        if self.on:
            self.cursor_on.value = False

    def remove(self) -> None:
        self.pause()
        self.folder.remove()
