"""When a paced run's simulated time is due in wall time: the worker's loop and a controller in the
loop (nodes/hil.py) pace against the same clock, so pausing or seeking resets both."""

from __future__ import annotations

import math
import time

from simecs.mesh import load


class Pacer:
    """When each simulated time is due in wall time, at the run's speed (math.inf: never waits)."""

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.reset(0.0)

    def reset(self, t: float) -> None:
        """Pacing starts again from simulated time t, now (after a pause or a seek)."""
        self.wall0, self.t0 = time.monotonic(), t

    @property
    def paced(self) -> bool:
        return math.isfinite(self.speed)

    def ahead(self, t: float) -> float:
        """Wall seconds until simulated time t is due (negative: late); 0 for an unpaced run."""
        if not self.paced:
            return 0.0
        return (t - self.t0) / self.speed - (time.monotonic() - self.wall0)


class PaceWatch:
    """Whether a paced run keeps its pace: its RTF over 1 s windows of wall time, and since when it has
    been below `load.BEHIND_RTF` of the pace. Falling behind is being below it for `BEHIND_GRACE_S`."""

    WINDOW_S = 1.0

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.rtf = 0.0  # the last window's
        self.behind = False
        self._slow_since: float | None = None
        self.reset(0.0)

    def reset(self, t: float) -> None:
        """After a pause or a seek: a new window starts, and the slow streak with it."""
        self._t0, self._wall0 = t, time.monotonic()
        self._slow_since = None

    def update(self, t: float) -> bool | None:
        """Simulated time t reached now; the new `behind` when it changed, else None."""
        now = time.monotonic()
        elapsed = now - self._wall0
        if elapsed < self.WINDOW_S:
            return None
        self.rtf = max(t - self._t0, 0.0) / elapsed
        self._t0, self._wall0 = t, now
        if not math.isfinite(self.speed):
            return None
        if self.rtf < load.BEHIND_RTF * self.speed:
            self._slow_since = self._slow_since if self._slow_since is not None else now - elapsed
        else:
            self._slow_since = None
        behind = self._slow_since is not None and now - self._slow_since >= load.BEHIND_GRACE_S
        if behind == self.behind:
            return None
        self.behind = behind
        return behind
