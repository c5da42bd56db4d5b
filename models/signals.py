"""Direct input: a `DirectInput` command expanded into the reference table the drive kernel reads.

Why a table: the compiled kernel cannot call back into Python at every step, so each signal (table,
step, ramp, sine, chirp) becomes breakpoints before the run, the breakpoints of all joints are merged
on one time grid and the kernel interpolates linearly between rows. Every limit (joint range,
motor.i_max, traj.max_speed, where a speed signal drives the joint, the row budget) is checked here,
before anything runs, and a refusal (`CommandError`) names the field of the command responsible.

Table layout, K rows by 1 + 2n columns: t, r_1..r_n, rd_1..rd_n. At time t the kernel takes k, the
RIGHTMOST row with t_k <= t, and interpolates every column linearly between rows k and k + 1 (row 0
before the table, the last row after it). Two rows at one time therefore make a jump: from that time
on the later row counts, and the earlier one only ends the piece before it.

What r and rd mean depends on the joint's mode (`jmode`):
  JM_POSITION  r = position set point (rad), rd = its slope (speed feed-forward, constant per piece)
  JM_SPEED     rd = speed set point (rad/s), r = q0 + its integral (for plots; the loop ignores it)
  JM_CURRENT   r = motor current amplitude set point (A), rd = 0
  JM_HOLD      r = q0, rd = 0 (joints without a signal hold their initial position)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from simecs.mesh.protocol.robot_commands import (
    ChirpSignal,
    DirectInput,
    RampSignal,
    Signal,
    SineSignal,
    StepSignal,
    TableSignal,
)

from .errors import CommandError
from .references import JM_CURRENT, JM_HOLD, JM_POSITION, JM_SPEED  # the references own the modes

#: Sampling of sines and chirps: points per period of the highest frequency in effect, and the
#: widest and narrowest spacing (a slow wave still gets 100 points per second; a 500 Hz one 1e5).
SAMPLES_PER_PERIOD = 200
MAX_SAMPLE_STEP = 0.01
MIN_SAMPLE_STEP = 1e-5
#: Relative slack of the bound checks, so that a value computed to exactly a bound (0.035 / 0.1 for a
#: max_speed of 0.35) is not refused for a rounding error.
_SLACK = 1e-9


@dataclass
class JointBounds:
    """What a joint may be asked for: per joint arrays, shape (n,)."""

    lower: np.ndarray  # rad, joint range
    upper: np.ndarray
    max_speed: np.ndarray  # rad/s load side (traj.max_speed)
    i_max: np.ndarray  # A (motor.i_max)


@dataclass
class _Breaks:
    """One signal as breakpoints (t, v): t non-decreasing, equal times a jump (the later value counts
    from then on). `src` says which command field each point comes from, for refusals: an index into
    `names`, or for a table (names None) the index of its point. `offset`: a generator's, so that a
    value refused because of the offset alone is charged to it."""

    t: np.ndarray
    v: np.ndarray
    src: np.ndarray
    names: tuple[str, ...] | None = None
    offset: float | None = None

    def field(self, k: int) -> str:
        i = int(self.src[k])
        return self.names[i] if self.names is not None else f"points[{i}]"


class _TooManySamples(Exception):
    """A generator would need more samples than a run may hold; raised before sampling it."""

    def __init__(self, samples: int) -> None:
        self.samples = samples


# ---- public entry ------------------------------------------------------------------------------------
def expand_direct_input(
    cmd: DirectInput,
    joint_names: Sequence[str],
    bounds: JointBounds,
    q0: np.ndarray,
    stop_time: float,
    max_rows: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The reference table of a direct input and each joint's mode: (tab, jmode).

    `tab` (K, 1 + 2n): t from 0 to stop_time, then r_j, then rd_j (see the module docstring); jmode
    (n,) int64 of JM_*. Every limit is checked first: CommandError names the field (`signals.joint2.
    points[3]`, `signals.joint2.amplitude`, ...) relative to the command.
    """
    if not (math.isfinite(stop_time) and stop_time >= 0.0):
        raise ValueError(f"stop_time must be a finite time >= 0, got {stop_time!r}")
    n = len(joint_names)
    q0 = np.asarray(q0, dtype=float)
    index = {name: j for j, name in enumerate(joint_names)}
    for name in cmd.signals:
        if name not in index:
            raise CommandError(
                f"signals.{name}", f"no joint {name!r}: the model has joints {_joint_list(joint_names)}"
            )
    if cmd.mode == "open_loop":
        mode = JM_CURRENT  # `reference` means nothing in open loop
    else:
        mode = JM_POSITION if cmd.reference == "position" else JM_SPEED

    signals: list[tuple[int, str, _Breaks, np.ndarray, np.ndarray]] = []
    for name, sig in cmd.signals.items():
        j = index[name]
        path = f"signals.{name}"
        _check_finite(sig, path)
        try:
            br = _clip(_breaks(sig, stop_time, max_rows), stop_time)
        except _TooManySamples as e:
            rows = e.samples * (2 if mode == JM_POSITION else 1)  # position: two rows per slope change
            raise CommandError(path, _too_many(rows, rows, max_rows)) from None
        _check_values(mode, br, j, name, path, bounds)
        if mode == JM_POSITION:
            _check_slopes(sig, br, j, name, path, bounds, stop_time)
        if mode == JM_SPEED:
            _check_integral(br, j, name, path, bounds, float(q0[j]), stop_time)
        grid = np.unique(np.append(br.t, stop_time))
        counts = _keep(mode, *_sides(br.t, br.v, grid)).sum(axis=1)
        signals.append((j, name, br, grid, counts))

    times, mult = _union(signals, stop_time)
    total = int(mult.sum())
    if total > max_rows:
        own = [int(c.sum()) for *_, c in signals]
        k = int(np.argmax(own))
        raise CommandError(f"signals.{signals[k][1]}", _too_many(own[k], total, max_rows))

    # Rows: each union time repeated by its multiplicity; `within` = row index inside its group.
    tab = np.empty((total, 1 + 2 * n))
    group = np.repeat(np.arange(len(times)), mult)
    within = np.arange(total) - np.repeat(np.cumsum(mult) - mult, mult)
    tab[:, 0] = times[group]
    tab[:, 1 : 1 + n] = q0
    tab[:, 1 + n :] = 0.0
    jmode = np.full(n, JM_HOLD, dtype=np.int64)
    for j, _name, br, _grid, _counts in signals:
        jmode[j] = mode
        r, rd = _columns(mode, br, times, group, within, float(q0[j]))
        tab[:, 1 + j] = r
        tab[:, 1 + n + j] = rd
    return tab, jmode


def preview(
    tab: np.ndarray, jmode: np.ndarray, joints: Sequence[int], points: int
) -> tuple[np.ndarray, np.ndarray]:
    """The signalled joints' set points as the run will follow them, in at most `points` rows of the
    table (t, values (rows, len(joints))): a client's preview plot, drawn from this module's own
    expansion rather than a copy of its rules. All rows when they fit (every jump exact); otherwise
    the table cut into equal spans of time, each keeping its first row and each joint's lowest and
    highest one, so a sine sampled densely keeps its envelope. The value is the column the joint's
    mode reads: the current (A) or position (rad) set point `r`, or the speed set point `rd`."""
    n = jmode.shape[0]
    cols = [1 + n + j if jmode[j] == JM_SPEED else 1 + j for j in joints]
    values = tab[:, cols]
    k = tab.shape[0]
    if k <= points:
        return tab[:, 0].copy(), values.copy()
    spans = max(1, (points - 1) // (1 + 2 * max(1, len(cols))))
    t = tab[:, 0]
    edges = np.searchsorted(t, np.linspace(t[0], t[-1], spans + 1)[1:-1], side="left")
    keep = {k - 1}
    for lo, hi in zip(np.concatenate([[0], edges]), np.concatenate([edges, [k]]), strict=True):
        if hi <= lo:
            continue
        keep.add(int(lo))
        block = values[lo:hi]
        keep.update(int(lo + i) for i in np.argmin(block, axis=0))
        keep.update(int(lo + i) for i in np.argmax(block, axis=0))
    rows = np.array(sorted(keep))
    return t[rows].copy(), values[rows].copy()


# ---- signals to breakpoints --------------------------------------------------------------------------
def _breaks(sig: Signal, stop: float, max_samples: int) -> _Breaks:
    """The signal's breakpoints up to stop_time (a wave is not sampled past it)."""
    if isinstance(sig, TableSignal):
        p = np.asarray(sig.points, dtype=float).reshape(-1, 2)
        return _Breaks(p[:, 0].copy(), p[:, 1].copy(), np.arange(len(p)))
    if isinstance(sig, StepSignal):
        t = np.array([sig.start, sig.start])
        v = np.array([sig.offset, sig.offset + sig.amplitude])
        return _Breaks(t, v, np.array([0, 1]), ("offset", "amplitude"), sig.offset)
    if isinstance(sig, RampSignal):
        d = sig.duration if sig.duration > 0.0 else max(stop - sig.start, 0.0)
        t = np.array([sig.start, sig.start + d])
        v = np.array([sig.offset, sig.offset + sig.slope * d])
        return _Breaks(t, v, np.array([0, 1]), ("offset", "slope"), sig.offset)
    if isinstance(sig, SineSignal):
        end = sig.start + sig.duration if sig.duration > 0.0 else max(stop, sig.start)
        w, ph, a, off = 2.0 * math.pi * sig.frequency_hz, sig.phase, sig.amplitude, sig.offset

        def sine(tau: np.ndarray) -> np.ndarray:
            return off + a * np.sin(w * tau + ph)

        return _wave(sig.start, end, sig.duration > 0.0, sig.frequency_hz, sine, off, stop, max_samples)
    if isinstance(sig, ChirpSignal):
        f0, df, dur, a, off = sig.f0_hz, sig.f1_hz - sig.f0_hz, sig.duration, sig.amplitude, sig.offset

        def chirp(tau: np.ndarray) -> np.ndarray:
            return off + a * np.sin(2.0 * math.pi * (f0 * tau + df * tau * tau / (2.0 * dur)))

        f_top = _chirp_top_frequency(sig, stop)
        return _wave(sig.start, sig.start + dur, True, f_top, chirp, off, stop, max_samples)
    raise TypeError(f"not a signal: {type(sig).__name__}")


def _chirp_top_frequency(sig: ChirpSignal, stop: float) -> float:
    """The highest instantaneous frequency a chirp reaches before the run ends (it sweeps linearly)."""
    tau = min(sig.duration, max(stop - sig.start, 0.0))
    return max(sig.f0_hz, sig.f0_hz + (sig.f1_hz - sig.f0_hz) * tau / sig.duration)


def _wave(
    start: float,
    end: float,
    returns: bool,
    f_top: float,
    fn: Callable[[np.ndarray], np.ndarray],
    offset: float,
    stop: float,
    max_samples: int,
) -> _Breaks:
    """A sine or chirp: `offset` until start, fn(t - start) sampled on [start, end] (at `end` exactly),
    back to `offset` at `end` if `returns`. Samples after stop_time are never made: the last one is
    the value at stop_time itself."""
    names = ("offset", "amplitude")
    if start > stop:  # starts after the run: only its offset is ever in force
        return _Breaks(np.array([0.0]), np.array([offset]), np.array([0]), names, offset)
    span = end - start
    if span <= 0.0:
        tau = np.zeros(1)
    else:
        step = MAX_SAMPLE_STEP if f_top <= 0.0 else min(MAX_SAMPLE_STEP, 1.0 / (SAMPLES_PER_PERIOD * f_top))
        n = math.ceil(span / step - 1e-9)
        n = max(1, min(n, math.floor(span / MIN_SAMPLE_STEP + 1e-9)))  # never closer than 1e-5 s
        last = n if end <= stop else min(n, math.floor((stop - start) / span * n) + 1)
        if last + 1 > max_samples:
            raise _TooManySamples(last + 1)
        tau = span * np.arange(last + 1) / n
        if last == n:
            tau[-1] = span
        tau = tau[start + tau <= stop]
        if end > stop and start + tau[-1] < stop:
            tau = np.append(tau, stop - start)
    t = start + tau
    if span > 0.0 and len(t) and tau[-1] == span:
        t[-1] = end  # ends exactly at start + duration
    v = fn(tau)
    src = np.ones(len(t), dtype=np.int64)
    t = np.concatenate([[start], t])
    v = np.concatenate([[offset], v])
    src = np.concatenate([[0], src])
    if returns and end <= stop:
        t = np.append(t, end)
        v = np.append(v, offset)
        src = np.append(src, 0)
    return _Breaks(t, v, src, names, offset)


def _clip(br: _Breaks, stop: float) -> _Breaks:
    """From t = 0 (the first value holds before the first point; of several points at 0 only the last
    is ever in force) to stop_time (later points cut, the value at stop_time kept and charged to the
    first point cut)."""
    t, v, src = br.t, br.v, br.src
    if t[0] > 0.0:
        t, v, src = np.append(0.0, t), np.append(v[0], v), np.append(src[0], src)
    first = int(np.searchsorted(t, 0.0, side="right")) - 1
    t, v, src = t[first:], v[first:], src[first:]
    keep = int(np.searchsorted(t, stop, side="right"))
    if keep < len(t):
        if t[keep - 1] < stop:
            w = (stop - t[keep - 1]) / (t[keep] - t[keep - 1])
            v_stop = v[keep - 1] + w * (v[keep] - v[keep - 1])
            t = np.append(t[:keep], stop)
            v = np.append(v[:keep], v_stop)
            src = np.append(src[:keep], src[keep])
        else:
            t, v, src = t[:keep], v[:keep], src[:keep]
    return _Breaks(t, v, src, br.names, br.offset)


# ---- evaluation --------------------------------------------------------------------------------------
def _sides(t: np.ndarray, v: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
    """The signal just before and at each time u: (v_left, v_right, slope_left, slope_right).

    Right: the rightmost point with t_k <= u counts (a jump takes effect at its time); left: the
    rightmost point with t_k < u. Values at a breakpoint are copied, not recomputed, so a continuous
    signal never shows a jump of one rounding error."""
    m = len(t)
    dt = np.diff(t)
    slope = np.zeros(m)
    np.divide(np.diff(v), dt, out=slope[:-1], where=dt > 0.0)

    def at(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        kc = np.clip(k, 0, m - 1)
        k1 = np.minimum(kc + 1, m - 1)
        inside = (k >= 0) & (k < m - 1)
        span = t[k1] - t[kc]
        w = np.zeros(len(u))
        np.divide(u - t[kc], span, out=w, where=inside & (span > 0.0))
        val = np.where(inside, v[kc] + w * (v[k1] - v[kc]), v[kc])
        val = np.where(inside & (t[k1] == u), v[k1], val)
        return val, np.where(inside, slope[kc], 0.0)

    v_right, s_right = at(np.searchsorted(t, u, side="right") - 1)
    v_left, s_left = at(np.searchsorted(t, u, side="left") - 1)
    return v_left, v_right, s_left, s_right


def _keep(mode: int, vl: np.ndarray, vr: np.ndarray, sl: np.ndarray, sr: np.ndarray) -> np.ndarray:
    """Which of the four candidate rows at each time a signal needs, (len(u), 4) bool.

    Candidates, in order: (v_left, left), (v_left, 0), (v_right, 0), (v_right, right), where the second
    column is rd (position: the slopes, so a slope change takes two rows and the zero-length piece of a
    jump has rd = 0; speed: the set point itself; current: 0). At t = 0 only the value at 0 counts."""
    ones = np.ones(len(vl), dtype=bool)
    jump = vl != vr
    if mode == JM_POSITION:
        keep = np.stack([ones, jump & (sl != 0.0), jump, np.where(jump, sr != 0.0, sr != sl)], axis=1)
    else:
        keep = np.stack([ones, ~ones, ~ones, jump], axis=1)
    if len(vl):
        keep[0] = (False, False, False, True)  # u[0] is always t = 0
    return keep


def _integral(q0: float, u: np.ndarray, vl: np.ndarray, vr: np.ndarray) -> np.ndarray:
    """q0 + the integral of a signal linear between the times u (trapezoids: exact)."""
    pieces = 0.5 * (vr[:-1] + vl[1:]) * np.diff(u)
    return q0 + np.concatenate([[0.0], np.cumsum(pieces)])


def _union(
    signals: list[tuple[int, str, _Breaks, np.ndarray, np.ndarray]], stop: float
) -> tuple[np.ndarray, np.ndarray]:
    """Every signal's times on one grid, with the rows each needs: the most any signal needs there
    (a signal has one row at a time that is not its breakpoint)."""
    if not signals:
        times = np.unique([0.0, stop])
        return times, np.ones(len(times), dtype=np.int64)
    all_u = np.concatenate([g for *_, g, _c in signals])
    all_c = np.concatenate([c for *_, c in signals])
    order = np.argsort(all_u, kind="stable")
    times, first = np.unique(all_u[order], return_index=True)
    return times, np.maximum.reduceat(all_c[order], first).astype(np.int64)


def _columns(
    mode: int, br: _Breaks, times: np.ndarray, group: np.ndarray, within: np.ndarray, q0: float
) -> tuple[np.ndarray, np.ndarray]:
    """The signal's r and rd columns on the union rows: at a time with more rows than the signal needs,
    its last row (the value from then on) is repeated."""
    vl, vr, sl, sr = _sides(br.t, br.v, times)
    keep = _keep(mode, vl, vr, sl, sr)
    zero = np.zeros(len(times))
    if mode == JM_POSITION:
        r4 = np.stack([vl, vl, vr, vr], axis=1)
        rd4 = np.stack([sl, zero, zero, sr], axis=1)
    elif mode == JM_SPEED:
        q = _integral(q0, times, vl, vr)
        r4 = np.stack([q, q, q, q], axis=1)
        rd4 = np.stack([vl, vl, vr, vr], axis=1)
    else:
        r4 = np.stack([vl, vl, vr, vr], axis=1)
        rd4 = np.stack([zero, zero, zero, zero], axis=1)
    order = np.argsort(~keep, axis=1, kind="stable")  # the kept candidates first, in order
    r4 = np.take_along_axis(r4, order, axis=1)
    rd4 = np.take_along_axis(rd4, order, axis=1)
    col = np.minimum(within, keep.sum(axis=1)[group] - 1)
    return r4[group, col], rd4[group, col]


# ---- limits ------------------------------------------------------------------------------------------
def _check_finite(sig: Signal, path: str) -> None:
    """NaN or infinity in a command is refused by field (JSON cannot carry them; Python callers can)."""
    if isinstance(sig, TableSignal):
        finite = np.isfinite(np.asarray(sig.points, dtype=float).reshape(-1, 2)).all(axis=1)
        if not finite.all():
            k = int(np.argmin(finite))
            raise CommandError(f"{path}.points[{k}]", f"must be finite numbers, got {list(sig.points[k])}")
        return
    for field in sig.__struct_fields__:
        x = getattr(sig, field)
        if isinstance(x, float | int) and not math.isfinite(x):
            raise CommandError(f"{path}.{field}", f"must be a finite number, got {x}")


def _over(x: np.ndarray, bound: float) -> np.ndarray:
    return ~(x <= bound + _SLACK * max(1.0, abs(bound)))


def _under(x: np.ndarray, bound: float) -> np.ndarray:
    return ~(x >= bound - _SLACK * max(1.0, abs(bound)))


def _check_values(mode: int, br: _Breaks, j: int, name: str, path: str, bounds: JointBounds) -> None:
    """Every breakpoint within the bound of the mode (the signal is linear between them)."""
    if mode == JM_CURRENT:
        i_max = float(bounds.i_max[j])
        unit, what = "A", f"exceeds {name}'s motor.i_max of {i_max:.6g} A"

        def bad(v: np.ndarray) -> np.ndarray:
            return _over(np.abs(v), i_max)

    elif mode == JM_SPEED:
        v_max = float(bounds.max_speed[j])
        unit, what = "rad/s", f"exceeds {name}'s traj.max_speed of {v_max:.6g} rad/s"

        def bad(v: np.ndarray) -> np.ndarray:
            return _over(np.abs(v), v_max)

    else:
        lo, hi = float(bounds.lower[j]), float(bounds.upper[j])
        unit, what = "rad", f"is outside {name}'s range [{lo:.6g}, {hi:.6g}] rad"

        def bad(v: np.ndarray) -> np.ndarray:
            return _under(v, lo) | _over(v, hi)

    out = bad(br.v)
    if out.any():
        k = int(np.argmax(out))
        field = br.field(k)
        if br.offset is not None and bad(np.array([br.offset]))[0]:
            field = "offset"  # out of bounds whatever the amplitude or slope
        raise CommandError(f"{path}.{field}", f"{br.v[k]:.6g} {unit} at t = {br.t[k]:.6g} s {what}")


def _check_slopes(
    sig: Signal, br: _Breaks, j: int, name: str, path: str, bounds: JointBounds, stop: float
) -> None:
    """A position set point may jump, but may not move faster than traj.max_speed in between: a
    ramp's slope, a sine's 2 pi f A, a chirp's at its top frequency, every piece of a table."""
    lim = float(bounds.max_speed[j])
    what = f"exceeds {name}'s traj.max_speed of {lim:.6g} rad/s"
    if isinstance(sig, TableSignal):
        dt = np.diff(br.t)
        slope = np.zeros(len(dt))
        np.divide(np.diff(br.v), dt, out=slope, where=dt > 0.0)
        bad = _over(np.abs(slope), lim) & (dt > 0.0)
        if bad.any():
            k = int(np.argmax(bad))
            raise CommandError(
                f"{path}.{br.field(k + 1)}",
                f"{abs(slope[k]):.6g} rad/s from t = {br.t[k]:.6g} s to {br.t[k + 1]:.6g} s {what}",
            )
        return
    if getattr(sig, "start", 0.0) >= stop:
        return  # starts when the run ends: only a jump, if anything
    if isinstance(sig, RampSignal):
        if _over(np.abs(np.array([sig.slope])), lim)[0]:
            raise CommandError(f"{path}.slope", f"a slope of {sig.slope:.6g} rad/s {what}")
    elif isinstance(sig, SineSignal | ChirpSignal):
        f = sig.frequency_hz if isinstance(sig, SineSignal) else _chirp_top_frequency(sig, stop)
        speed = 2.0 * math.pi * f * abs(sig.amplitude)
        if _over(np.array([speed]), lim)[0]:
            raise CommandError(
                f"{path}.amplitude",
                f"{sig.amplitude:.6g} rad at {f:.6g} Hz moves at up to 2*pi*f*amplitude = {speed:.6g} "
                f"rad/s, which {what}",
            )


def _check_integral(
    br: _Breaks, j: int, name: str, path: str, bounds: JointBounds, q0: float, stop: float
) -> None:
    """A speed set point must not drive the joint out of its range: the integral is checked at every
    breakpoint and where the speed crosses zero inside a piece (its extrema)."""
    lo, hi = float(bounds.lower[j]), float(bounds.upper[j])
    u = np.unique(np.append(br.t, stop))
    vl, vr, _, _ = _sides(br.t, br.v, u)
    q = _integral(q0, u, vl, vr)
    a, b, dt = vr[:-1], vl[1:], np.diff(u)
    turn = (a * b < 0.0) & (dt > 0.0)
    tau = np.zeros(len(dt))
    np.divide(a * dt, a - b, out=tau, where=turn)
    times = np.concatenate([u, (u[:-1] + tau)[turn]])
    qs = np.concatenate([q, (q[:-1] + 0.5 * a * tau)[turn]])
    bad = _under(qs, lo) | _over(qs, hi)
    if bad.any():
        k = int(np.argmin(np.where(bad, times, np.inf)))
        t = float(times[k])
        src = min(int(np.searchsorted(br.t, t, side="left")), len(br.t) - 1)  # the piece ending there
        raise CommandError(
            f"{path}.{br.field(src)}",
            f"would drive {name} to {qs[k]:.6g} rad at t = {t:.6g} s, outside [{lo:.6g}, {hi:.6g}] "
            f"(from {q0:.6g} rad at t = 0)",
        )


# ---- messages ----------------------------------------------------------------------------------------
def _too_many(own: int, total: int, max_rows: int) -> str:
    others = f" ({total:,} with the other signals)" if total != own else ""
    return (
        f"expands to {own:,} samples{others}, more than the {max_rows:,} a run may hold (reference_samples)"
    )


def _joint_list(names: Sequence[str]) -> str:
    """`joint1..joint7` for the usual names, else all of them."""
    if names and list(names) == [f"joint{i + 1}" for i in range(len(names))]:
        return f"joint1..joint{len(names)}"
    return ", ".join(names)
