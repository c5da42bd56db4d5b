"""When a paced run's simulated time is due in wall time: the worker's loop and a controller in the
loop (nodes/hil.py) pace against the same clock, so pausing or seeking resets both."""

from __future__ import annotations

import math
import time


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
