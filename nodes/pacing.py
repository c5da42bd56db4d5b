"""When a paced run's simulated time is due in wall time, and how a run is cut into frames: the
worker's loop and a controller in the loop (nodes/hil.py) pace against the same clock, so pausing or
seeking resets both."""

from __future__ import annotations

import math
import time

import numpy as np
from simecs.mesh.rules import load

# Simulated seconds per frame at real-time pacing: 25 ms gives 40 frames per wall second, below the
# default live rate of 50 Hz: the hot-feedback rate limit then never holds frames back in steady real
# time. Abort acts between frames.
FRAME_S = 0.025
MAX_FRAME_S = 0.1  # faster pacing: bigger frames (fewer, larger), still a few ms of wall time
# A paced run simulates this many frames per solver call and sends them each at its time. Every wake-up
# of a sleeping worker costs its simulation cold caches: measured on our 2-core VMs, a paced Spider run
# takes 42-44 ms of CPU per simulated s in 25 ms calls, 35.5 in 50 ms calls (and 28 never sleeping).
# Jogging, pause and seek act between calls (50 ms in real time); abort and stop between frames.
FRAMES_PER_SOLVE = 2


# A jog acts at the next solver call and shows in the frames of that call, each sent at its time: in
# 50 ms calls of 25 ms frames a jog took 23-25 ms (p50) to show, more than a pendant's user accepts
# (~10 ms). While a paced run is jogged (from a jog message for it until JOG_MODE_S after the last one)
# and throughout a run until stopped (an idle arm jogged to teach poses), each call simulates one frame
# of JOG_FRAME_S in wall time. Each call costs its solver start-up: a run costs more CPU so, only then.
JOG_FRAME_S = 0.005
JOG_MODE_S = 2.0


def frame_length(speed: float, output_interval: float) -> float:
    """About 40 frames per wall second: 25 ms simulated in real time, up to 100 ms when faster."""
    return max(min(FRAME_S * speed, MAX_FRAME_S), FRAME_S, output_interval)


def jog_frame_length(speed: float, output_interval: float) -> float:
    """A jogged run's frame (and solver call): JOG_FRAME_S of wall time, at least one output interval."""
    return min(max(JOG_FRAME_S * speed, output_interval), frame_length(speed, output_interval))


def frame_parts(rows: np.ndarray, t0: float, frame: float, t_end: float) -> list[tuple[np.ndarray, float]]:
    """The rows of a solver call from t0 to t_end, cut every `frame` s of simulated time: (rows, the
    simulated time the part ends at). A row on a cut belongs to the part it ends; parts without rows
    are left out, so the last part, which ends at t_end, holds the call's last row."""
    times, parts, first = rows[:, 0], [], 0
    cut = t0 + frame
    while cut < t_end - 1e-9:
        last = int(np.searchsorted(times, cut + 1e-9, side="right"))
        if last > first:
            parts.append((rows[first:last], cut))
            first = last
        cut += frame
    if first < rows.shape[0]:
        parts.append((rows[first:], t_end))
    return parts


class Pacer:
    """When each simulated time is due in wall time, at the run's speed (math.inf: never waits).
    Up to `fast_until` nothing is due (a continued run catching up), and pacing starts there, then."""

    def __init__(self, speed: float, fast_until: float = 0.0) -> None:
        self.speed = speed
        self.fast_until = fast_until
        self.reset(0.0)

    def reset(self, t: float) -> None:
        """Pacing starts again from simulated time t, now (after a pause or a seek)."""
        self.wall0, self.t0 = time.monotonic(), t

    @property
    def paced(self) -> bool:
        return math.isfinite(self.speed)

    def ahead(self, t: float) -> float:
        """Wall seconds until simulated time t is due (negative: late); 0 for an unpaced run."""
        if not self.paced or t <= self.fast_until:
            return 0.0
        if self.t0 < self.fast_until:  # caught up: paced from where the catching up ended, now
            self.reset(self.fast_until)
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
