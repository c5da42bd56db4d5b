"""models/signals.py: a direct input expanded into the drive kernel's reference table (no processes).

Every table is read back with `kernel_eval`, a small copy of the kernel's interpolation rule, so the
tests check what a run would see, not how the table happens to be laid out.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from simecs.mesh.protocol.robot_commands import (
    ChirpSignal,
    DirectInput,
    RampSignal,
    SineSignal,
    StepSignal,
    TableSignal,
)
from simecs.models import get_model
from simecs.models.errors import CommandError
from simecs.models.signals import (
    JM_CURRENT,
    JM_HOLD,
    JM_POSITION,
    JM_SPEED,
    MAX_SAMPLE_STEP,
    MIN_SAMPLE_STEP,
    JointBounds,
    expand_direct_input,
    preview,
)

N = 7
NAMES = [f"joint{j + 1}" for j in range(N)]
Q0 = np.array([0.3, -0.4, 0.5, 1.1, -0.6, 0.7, -0.2])
ROWS = 200_000
RNG = np.random.default_rng(1234)


@pytest.fixture(scope="module")
def bounds() -> JointBounds:
    """The Spider's own bounds: joint2 range [-2.6, 2.6], i_max 6 A (joints 1-4) / 4 A, max_speed
    0.35 rad/s (joints 1-4) / 0.5 rad/s."""
    pkg = get_model("spider")
    values = pkg.check_values({})
    links = pkg.spec.links
    return JointBounds(
        lower=np.array([links[j].joint_min for j in range(N)]),
        upper=np.array([links[j].joint_max for j in range(N)]),
        max_speed=np.array([values[f"joint{j + 1}.traj.max_speed"] for j in range(N)]),
        i_max=np.array([values[f"joint{j + 1}.motor.i_max"] for j in range(N)]),
    )


def kernel_eval(tab: np.ndarray, t: float) -> np.ndarray:
    """The kernel's rule: k = rightmost row with t_k <= t, linear to row k + 1; row 0 before, the last
    row after. Returns every column but time."""
    times = tab[:, 0]
    k = int(np.searchsorted(times, t, side="right")) - 1
    if k < 0:
        return tab[0, 1:].copy()
    if k >= len(times) - 1:
        return tab[-1, 1:].copy()
    w = (t - times[k]) / (times[k + 1] - times[k])
    return tab[k, 1:] + w * (tab[k + 1, 1:] - tab[k, 1:])


def table_ref(points: list[list[float]], t: float) -> float:
    """A table signal by its docstring: piecewise linear, the later of equal times counts, the first
    value before the points and the last after them."""
    ts = np.array([p[0] for p in points])
    vs = np.array([p[1] for p in points])
    k = int(np.searchsorted(ts, t, side="right")) - 1
    if k < 0:
        return float(vs[0])
    if k == len(ts) - 1:
        return float(vs[-1])
    return float(vs[k] + (t - ts[k]) / (ts[k + 1] - ts[k]) * (vs[k + 1] - vs[k]))


def expand(bounds, mode, signals, stop=5.0, reference="position", max_rows=ROWS, q0=Q0):
    cmd = DirectInput(mode=mode, signals=signals, reference=reference)
    return expand_direct_input(cmd, NAMES, bounds, q0, stop, max_rows)


def r_at(tab, j, t):
    return kernel_eval(tab, t)[j]


def rd_at(tab, j, t):
    return kernel_eval(tab, t)[N + j]


def check_layout(tab, stop):
    assert tab.shape[1] == 1 + 2 * N
    assert tab[0, 0] == 0.0 and tab[-1, 0] == stop
    assert np.all(np.diff(tab[:, 0]) >= 0.0)
    assert np.all(np.isfinite(tab))


def random_times(stop, k=300):
    return np.concatenate([RNG.uniform(0.0, stop, k), [0.0, stop, stop + 1.0]])


# ---- each generator reproduces its formula ---------------------------------------------------------
def test_table_open_loop_exact(bounds):
    pts = [[0.2, 1.0], [0.7, -2.5], [1.0, 3.0], [1.0, -1.0], [2.5, 0.5], [4.0, 0.5], [4.2, 5.9]]
    tab, jmode = expand(bounds, "open_loop", {"joint3": TableSignal(points=pts)})
    check_layout(tab, 5.0)
    assert jmode[2] == JM_CURRENT
    for t in np.concatenate([random_times(5.0), [p[0] for p in pts]]):
        assert r_at(tab, 2, t) == pytest.approx(table_ref(pts, t), rel=1e-12, abs=1e-12)
        assert rd_at(tab, 2, t) == 0.0


def test_step_exact(bounds):
    sig = StepSignal(amplitude=-2.0, offset=1.5, start=1.25)
    tab, _ = expand(bounds, "open_loop", {"joint5": sig}, stop=3.0)
    for t in random_times(3.0):
        assert r_at(tab, 4, t) == (1.5 if t < 1.25 else -0.5)
    assert r_at(tab, 4, 1.25) == -0.5  # the jump: the later value at its time


def test_ramp_exact(bounds):
    sig = RampSignal(slope=0.3, offset=-0.5, start=0.5, duration=2.0)
    tab, jmode = expand(bounds, "closed_loop", {"joint2": sig}, stop=4.0)
    check_layout(tab, 4.0)
    assert jmode[1] == JM_POSITION

    def ref(t):
        return -0.5 + 0.3 * min(max(t - 0.5, 0.0), 2.0)

    for t in random_times(4.0):
        assert r_at(tab, 1, t) == pytest.approx(ref(t), rel=1e-12, abs=1e-12)
        assert rd_at(tab, 1, t) == (0.3 if 0.5 <= t < 2.5 else 0.0)


def test_ramp_until_the_end(bounds):
    tab, _ = expand(bounds, "closed_loop", {"joint1": RampSignal(slope=-0.2, start=1.0)}, stop=3.0)
    assert r_at(tab, 0, 3.0) == pytest.approx(-0.4, abs=1e-12)
    assert rd_at(tab, 0, 2.999) == pytest.approx(-0.2)


@pytest.mark.parametrize("freq,duration,phase", [(0.3, 0.0, 0.0), (50.0, 1.5, 0.7), (500.0, 0.2, -1.0)])
def test_sine_within_1e3(bounds, freq, duration, phase):
    sig = SineSignal(amplitude=3.0, frequency_hz=freq, offset=0.5, phase=phase, start=0.4, duration=duration)
    stop = 2.0
    tab, _ = expand(bounds, "open_loop", {"joint1": sig}, stop=stop)
    check_layout(tab, stop)
    end = 0.4 + duration if duration > 0 else stop

    def ref(t):
        inside = 0.4 <= t < end or (duration == 0.0 and t >= 0.4)
        return 0.5 + 3.0 * math.sin(2 * math.pi * freq * (t - 0.4) + phase) if inside else 0.5

    for t in np.concatenate([RNG.uniform(0.0, stop, 2000), [0.0, 0.4, end, stop]]):
        assert abs(r_at(tab, 0, t) - ref(t)) <= 1e-3 * 3.0, t


def test_chirp_within_1e3(bounds):
    sig = ChirpSignal(amplitude=2.0, f0_hz=1.0, f1_hz=40.0, duration=3.0, offset=-1.0, start=0.5)
    stop = 4.0
    tab, _ = expand(bounds, "open_loop", {"joint6": sig}, stop=stop)
    check_layout(tab, stop)

    def ref(t):
        tau = t - 0.5
        if not 0.0 <= tau < 3.0:
            return -1.0
        return -1.0 + 2.0 * math.sin(2 * math.pi * (1.0 * tau + 39.0 * tau * tau / 6.0))

    for t in random_times(stop, 3000):
        assert abs(r_at(tab, 5, t) - ref(t)) <= 1e-3 * 2.0, t


def test_position_sine_and_chirp_within_1e3(bounds):
    """Position mode too (two rows per sample); the feed-forward follows the derivative closely."""
    sine = SineSignal(amplitude=0.05, frequency_hz=1.0, offset=0.2)
    chirp = ChirpSignal(amplitude=0.02, f0_hz=0.5, f1_hz=2.0, duration=4.0)
    tab, _ = expand(bounds, "closed_loop", {"joint1": sine, "joint5": chirp}, stop=4.0)
    check_layout(tab, 4.0)
    for t in RNG.uniform(0.0, 3.99, 500):
        assert abs(r_at(tab, 0, t) - (0.2 + 0.05 * math.sin(2 * math.pi * t))) <= 1e-3 * 0.05
        # a chord's slope is off the derivative by at most |f''| h = (2 pi)^2 A h, h = 5 ms
        assert (
            abs(rd_at(tab, 0, t) - 0.1 * math.pi * math.cos(2 * math.pi * t))
            <= (2 * math.pi) ** 2 * 0.05 * 0.005
        )
        phi = 2 * math.pi * (0.5 * t + 1.5 * t * t / 8.0)
        assert abs(r_at(tab, 4, t) - 0.02 * math.sin(phi)) <= 1e-3 * 0.02


def test_wave_sampling_spacing(bounds):
    """200 points per period, at most 10 ms, at least 1e-5 s apart, ending exactly at start + duration."""
    cases = [
        (SineSignal(amplitude=1.0, frequency_hz=0.1, start=0.3, duration=1.7), MAX_SAMPLE_STEP),
        (SineSignal(amplitude=1.0, frequency_hz=20.0, start=0.3, duration=1.7), 1 / 4000),
        (SineSignal(amplitude=1.0, frequency_hz=500.0, start=0.3, duration=0.0123), MIN_SAMPLE_STEP),
        (ChirpSignal(amplitude=1.0, f0_hz=10.0, f1_hz=2.0, duration=1.7, start=0.3), 1 / 2000),
    ]
    for sig, step in cases:
        tab, _ = expand(bounds, "open_loop", {"joint1": sig}, stop=3.0)
        times = np.unique(tab[:, 0])
        end = sig.start + sig.duration
        assert end in times and sig.start in times
        inside = times[(times >= sig.start) & (times <= end)]
        gaps = np.diff(inside)
        assert gaps.max() <= step * (1 + 1e-9)
        assert gaps.min() >= min(step, MIN_SAMPLE_STEP) * (1 - 1e-9)
        assert len(times) < 1 + (end - sig.start) / step * 1.01 + 4


# ---- jumps, slopes, integrals, held joints ---------------------------------------------------------
def test_jumps_take_the_later_value(bounds):
    pts = [[0.0, 0.1], [1.0, 0.1], [1.0, 0.9], [1.0, 0.4], [2.0, 0.5], [2.0, -0.3]]
    tab, _ = expand(bounds, "closed_loop", {"joint2": TableSignal(points=pts)}, stop=3.0)
    assert r_at(tab, 1, 1.0) == 0.4
    assert r_at(tab, 1, 2.0) == -0.3
    assert r_at(tab, 1, 1.0 - 1e-9) == pytest.approx(0.1)
    assert r_at(tab, 1, 2.0 - 1e-9) == pytest.approx(0.5, abs=1e-8)
    step = StepSignal(amplitude=2.0, start=0.0)
    tab, _ = expand(bounds, "closed_loop", {"joint2": step}, stop=1.0)
    assert r_at(tab, 1, 0.0) == 2.0  # from start on, t = 0 included
    assert tab[0, 2] == 2.0


def test_position_rd_is_the_piece_slope(bounds):
    pts = [[0.0, 0.0], [1.0, 0.3], [2.0, 0.3], [2.0, -0.2], [3.0, 0.0], [3.5, -0.1]]
    tab, _ = expand(bounds, "closed_loop", {"joint3": TableSignal(points=pts)}, stop=4.0)
    slopes = [(0.0, 1.0, 0.3), (1.0, 2.0, 0.0), (2.0, 3.0, 0.2), (3.0, 3.5, -0.2), (3.5, 9.0, 0.0)]
    for t in random_times(4.0, 500):
        if t in (1.0, 2.0, 3.0, 3.5):
            continue
        expect = next(s for a, b, s in slopes if a <= t < b)
        assert rd_at(tab, 2, t) == pytest.approx(expect, rel=1e-12, abs=1e-15)
    # the rows at t = 2: end of the flat piece, the zero-length jump with rd = 0, the next slope
    at2 = tab[tab[:, 0] == 2.0][:, [3, 3 + N]]
    assert at2[0].tolist() == [0.3, 0.0] and at2[-1].tolist() == [-0.2, pytest.approx(0.2)]
    assert all(row[1] == 0.0 for row in at2[:-1])
    # at t = 1 the slope changes without a jump: two rows, left slope then right slope
    at1 = tab[tab[:, 0] == 1.0][:, [3, 3 + N]]
    assert at1.tolist() == [[0.3, pytest.approx(0.3)], [0.3, 0.0]]


def test_speed_mode_integral_exact(bounds):
    pts = [[0.0, 0.1], [1.0, 0.3], [2.0, 0.3], [2.0, -0.2], [4.0, 0.2]]
    ramp = RampSignal(slope=0.1, offset=-0.1, start=0.5, duration=3.0)
    tab, jmode = expand(
        bounds,
        "closed_loop",
        {"joint1": TableSignal(points=pts), "joint5": ramp},
        reference="speed",
        stop=4.5,
    )
    assert jmode[0] == JM_SPEED and jmode[4] == JM_SPEED

    def table_integral(t):  # exact: trapezoids on the breakpoints, the last piece partial
        q = Q0[0]
        knots = [0.0, 1.0, 2.0, 4.0, 10.0]
        left = {0.0: 0.1, 1.0: 0.3, 2.0: -0.2, 4.0: 0.2}
        right = {1.0: 0.3, 2.0: 0.3, 4.0: 0.2, 10.0: 0.2}
        for a, b in zip(knots[:-1], knots[1:], strict=True):
            if t <= a:
                break
            e = min(t, b)
            va = left[a]
            ve = va + (right[b] - va) * (e - a) / (b - a)
            q += 0.5 * (va + ve) * (e - a)
        return q

    def ramp_integral(t):
        q = Q0[4] - 0.1 * t
        tau = min(max(t - 0.5, 0.0), 3.0)
        q += 0.05 * tau * tau + 0.3 * max(t - 3.5, 0.0)
        return q

    for row in tab:
        t = row[0]
        assert row[1] == pytest.approx(table_integral(t), abs=1e-12)
        assert row[5] == pytest.approx(ramp_integral(t), abs=1e-12)
    for t in random_times(4.5):
        assert rd_at(tab, 0, t) == pytest.approx(table_ref(pts, t), abs=1e-12)
        assert rd_at(tab, 4, t) == pytest.approx(-0.1 + 0.1 * min(max(t - 0.5, 0.0), 3.0), abs=1e-12)


def test_held_joints_and_merged_grid(bounds):
    sine = SineSignal(amplitude=2.0, frequency_hz=3.0)
    pts = [[0.5, 1.0], [0.5, -1.0], [1.5, 2.0]]
    tab, jmode = expand(bounds, "open_loop", {"joint2": sine, "joint7": TableSignal(points=pts)}, stop=2.0)
    check_layout(tab, 2.0)
    assert jmode.dtype == np.int64
    assert jmode.tolist() == [JM_HOLD, JM_CURRENT, JM_HOLD, JM_HOLD, JM_HOLD, JM_HOLD, JM_CURRENT]
    for j in (0, 2, 3, 4, 5):
        assert np.all(tab[:, 1 + j] == Q0[j]) and np.all(tab[:, 1 + N + j] == 0.0)
    for t in random_times(2.0, 1000):
        assert abs(r_at(tab, 1, t) - 2.0 * math.sin(6 * math.pi * t)) <= 2e-3
        assert r_at(tab, 6, t) == pytest.approx(table_ref(pts, t), abs=1e-12)
    # the table's jump sits on the sine's grid too, without disturbing either signal
    assert r_at(tab, 6, 0.5) == -1.0


def test_stop_time_cuts(bounds):
    pts = [[0.0, 0.0], [1.0, 0.2], [3.0, 0.4], [3.0, 1.0], [6.0, 2.0]]
    tab, _ = expand(bounds, "closed_loop", {"joint4": TableSignal(points=pts)}, stop=2.0)
    check_layout(tab, 2.0)
    assert tab[-1, 4] == pytest.approx(0.3)
    assert tab[-1, 4 + N] == 0.0  # the cut table is held after stop_time
    assert np.all(tab[:, 0] <= 2.0)
    # a point exactly at stop_time, with a jump there: the later value is the last row
    pts = [[0.0, 0.0], [2.0, 0.2], [2.0, 0.5], [3.0, 9.0]]
    tab, _ = expand(bounds, "closed_loop", {"joint4": TableSignal(points=pts)}, stop=2.0)
    assert tab[-1, 0] == 2.0 and tab[-1, 4] == 0.5
    # a wave running past the end is sampled to stop_time and no further
    tab, _ = expand(bounds, "open_loop", {"joint1": SineSignal(amplitude=1.0, frequency_hz=1.0)}, stop=1.2345)
    assert tab[-1, 0] == 1.2345 and tab[-1, 1] == pytest.approx(math.sin(2 * math.pi * 1.2345))


def test_starting_after_the_run_has_no_effect(bounds):
    signals = {
        "joint1": ChirpSignal(
            amplitude=50.0, f0_hz=100.0, f1_hz=400.0, duration=100.0, offset=0.1, start=9.0
        ),
        "joint2": SineSignal(amplitude=50.0, frequency_hz=300.0, start=6.0, offset=-0.2),
        "joint3": RampSignal(slope=20.0, start=5.5, offset=0.3),
        "joint4": StepSignal(amplitude=40.0, start=8.0),
    }
    tab, _ = expand(bounds, "closed_loop", signals, stop=5.0)
    check_layout(tab, 5.0)
    assert len(tab) <= 4
    for t in random_times(5.0, 50):
        assert kernel_eval(tab, t)[:4].tolist() == [0.1, -0.2, 0.3, 0.0]


def test_open_loop_ignores_reference(bounds):
    tab, jmode = expand(bounds, "open_loop", {"joint1": StepSignal(amplitude=1.0)}, reference="speed")
    assert jmode[0] == JM_CURRENT and r_at(tab, 0, 1.0) == 1.0


# ---- refusals ----------------------------------------------------------------------------------------
def refused(bounds, mode, signals, reference="position", stop=5.0, max_rows=ROWS) -> CommandError:
    with pytest.raises(CommandError) as e:
        expand(bounds, mode, signals, stop=stop, reference=reference, max_rows=max_rows)
    return e.value


REFUSALS = [
    # open loop: currents above motor.i_max (joint2: 6 A, joint6: 4 A)
    (
        "open_loop",
        "position",
        {"joint2": TableSignal(points=[[0, 1], [1, 2], [1.2, 6.5]])},
        "joint2.points[2]",
    ),
    ("open_loop", "position", {"joint2": StepSignal(amplitude=7.0)}, "joint2.amplitude"),
    ("open_loop", "position", {"joint2": StepSignal(amplitude=-1.0, offset=6.5, start=1)}, "joint2.offset"),
    ("open_loop", "position", {"joint6": RampSignal(slope=1.0, offset=1.0)}, "joint6.slope"),
    ("open_loop", "position", {"joint6": RampSignal(slope=0.0, offset=-4.5)}, "joint6.offset"),
    ("open_loop", "position", {"joint6": SineSignal(amplitude=4.5, frequency_hz=2.0)}, "joint6.amplitude"),
    ("open_loop", "position", {"joint6": SineSignal(amplitude=1, frequency_hz=2, offset=5)}, "joint6.offset"),
    (
        "open_loop",
        "position",
        {"joint6": ChirpSignal(amplitude=5.0, f0_hz=1.0, f1_hz=2.0, duration=2.0)},
        "joint6.amplitude",
    ),
    # even a late start keeps its offset in force
    (
        "open_loop",
        "position",
        {"joint6": SineSignal(amplitude=1, frequency_hz=2, offset=5, start=99)},
        "joint6.offset",
    ),
    # closed-loop position: outside the joint range (joint2 [-2.6, 2.6])
    (
        "closed_loop",
        "position",
        {"joint2": TableSignal(points=[[0, 0], [1, 0], [1, 2.7]])},
        "joint2.points[2]",
    ),
    ("closed_loop", "position", {"joint2": StepSignal(amplitude=-2.7, start=1.0)}, "joint2.amplitude"),
    ("closed_loop", "position", {"joint2": StepSignal(amplitude=0.0, offset=3.0)}, "joint2.offset"),
    ("closed_loop", "position", {"joint2": RampSignal(slope=0.3, offset=2.0)}, "joint2.slope"),
    # closed-loop position: moving faster than traj.max_speed (joint2 0.35 rad/s)
    (
        "closed_loop",
        "position",
        {"joint2": TableSignal(points=[[0, 0], [1, 0.3], [1.5, 0.6], [2, 0.6]])},
        "joint2.points[2]",
    ),
    ("closed_loop", "position", {"joint2": RampSignal(slope=-0.4, duration=0.5)}, "joint2.slope"),
    ("closed_loop", "position", {"joint2": SineSignal(amplitude=0.1, frequency_hz=1.0)}, "joint2.amplitude"),
    (
        "closed_loop",
        "position",
        {"joint2": ChirpSignal(amplitude=0.01, f0_hz=1.0, f1_hz=10.0, duration=5.0)},
        "joint2.amplitude",
    ),
    # closed-loop speed: above traj.max_speed, or driving the joint out of its range
    ("closed_loop", "speed", {"joint2": StepSignal(amplitude=0.4, start=1.0)}, "joint2.amplitude"),
    ("closed_loop", "speed", {"joint2": TableSignal(points=[[0, 0], [2, -0.36]])}, "joint2.points[1]"),
    (
        "closed_loop",
        "speed",
        {"joint2": SineSignal(amplitude=0.1, frequency_hz=1, offset=0.3)},
        "joint2.amplitude",
    ),
    ("closed_loop", "speed", {"joint2": StepSignal(amplitude=0.35)}, "joint2.amplitude"),
    ("closed_loop", "speed", {"joint2": RampSignal(slope=0.1, offset=0.0)}, "joint2.slope"),
    (
        "closed_loop",
        "speed",
        {"joint2": TableSignal(points=[[0, 0.3], [1, 0.3], [5, 0.3], [8, 0.34]])},
        "joint2.points[3]",
    ),
    # unknown joint, non-finite numbers
    ("closed_loop", "position", {"joint9": StepSignal(amplitude=0.1)}, "joint9"),
    ("open_loop", "position", {"joint1": TableSignal(points=[[0, 0], [1, math.nan]])}, "joint1.points[1]"),
    ("open_loop", "position", {"joint1": TableSignal(points=[[0, 0], [math.inf, 1]])}, "joint1.points[1]"),
    ("open_loop", "position", {"joint1": StepSignal(amplitude=math.inf)}, "joint1.amplitude"),
    (
        "closed_loop",
        "position",
        {"joint1": SineSignal(amplitude=0.1, frequency_hz=1, phase=math.nan)},
        "joint1.phase",
    ),
]


@pytest.mark.parametrize("mode,reference,signals,field", REFUSALS)
def test_refusals_name_the_field(bounds, mode, reference, signals, field):
    e = refused(bounds, mode, signals, reference=reference, stop=10.0)
    assert e.field == f"signals.{field}", e


def test_refusal_reasons(bounds):
    e = refused(bounds, "open_loop", {"joint2": TableSignal(points=[[0, 1], [1.2, 6.5]])})
    assert e.reason == "6.5 A at t = 1.2 s exceeds joint2's motor.i_max of 6 A"
    e = refused(bounds, "closed_loop", {"joint2": RampSignal(slope=0.5)})
    assert "0.5 rad/s" in e.reason and "joint2's traj.max_speed of 0.35 rad/s" in e.reason
    e = refused(bounds, "closed_loop", {"joint2": SineSignal(amplitude=0.1, frequency_hz=1.0)})
    assert "0.628319 rad/s" in e.reason and "traj.max_speed of 0.35" in e.reason
    e = refused(bounds, "closed_loop", {"joint2": TableSignal(points=[[0, 0], [1, 0], [1, 2.7]])})
    assert e.reason == "2.7 rad at t = 1 s is outside joint2's range [-2.6, 2.6] rad"
    e = refused(bounds, "closed_loop", {"joint2": StepSignal(amplitude=0.35)}, reference="speed", stop=10.0)
    assert e.reason.startswith("would drive joint2 to 3.1 rad at t = 10 s, outside [-2.6, 2.6]")
    e = refused(bounds, "closed_loop", {"joint8": StepSignal(amplitude=0.1)})
    assert "joint1..joint7" in e.reason
    e = refused(bounds, "open_loop", {"joint1": StepSignal(amplitude=math.nan)})
    assert "finite" in e.reason


def test_allowed_at_the_bounds(bounds):
    """Jumps of any size, slopes and values exactly at their bounds, speed that turns back in time."""
    signals = {
        "joint1": StepSignal(amplitude=3.0, offset=-3.0, start=1.0),
        "joint2": TableSignal(points=[[0, 0], [0.1, 0.035], [0.1, 2.6], [1.0, 2.6], [1.0, -2.6]]),
        "joint3": RampSignal(slope=0.35, duration=2.0),
        "joint5": SineSignal(amplitude=0.5 / (2 * math.pi), frequency_hz=1.0),
    }
    tab, _ = expand(bounds, "closed_loop", signals, stop=3.0)
    check_layout(tab, 3.0)
    # speed: q0 = -0.4 rad, 0.35 rad/s for 8 s reaches 2.4 rad, then back
    pts = [[0, 0.35], [8, 0.35], [8, -0.35]]
    tab, _ = expand(bounds, "closed_loop", {"joint2": TableSignal(points=pts)}, reference="speed", stop=20.0)
    assert tab[:, 2].max() == pytest.approx(2.4)


def test_speed_integral_turning_point_is_checked(bounds):
    """The integral peaks between breakpoints, where the speed crosses zero: that peak is checked."""
    # q0 = -0.4: 0.3 rad/s falling linearly to -0.3 over 20 s peaks at -0.4 + 0.3 * 10 / 2 = 1.1
    pts = [[0.0, 0.3], [20.0, -0.3]]
    tab, _ = expand(bounds, "closed_loop", {"joint2": TableSignal(points=pts)}, reference="speed", stop=20.0)
    assert tab[-1, 2] == pytest.approx(-0.4)
    q0 = Q0.copy()
    q0[1] = 1.6  # peak 3.1 > 2.6, while both ends are at 1.6 rad
    e = refused_q0(bounds, {"joint2": TableSignal(points=pts)}, q0)
    assert e.field == "signals.joint2.points[1]" and "t = 10 s" in e.reason


def refused_q0(bounds, signals, q0):
    with pytest.raises(CommandError) as e:
        expand(bounds, "closed_loop", signals, reference="speed", stop=20.0, q0=q0)
    return e.value


# ---- the row limit -----------------------------------------------------------------------------------
def test_row_limit_names_the_largest_contributor(bounds):
    signals = {
        "joint1": SineSignal(amplitude=1.0, frequency_hz=7.0),  # 1400 samples/s
        "joint2": SineSignal(amplitude=1.0, frequency_hz=40.0),  # 8000 samples/s
    }
    tab, _ = expand(bounds, "open_loop", signals, stop=1.0, max_rows=20_000)
    assert 9000 < len(tab) < 9410
    e = refused(bounds, "open_loop", signals, stop=1.0, max_rows=9000)
    assert e.field == "signals.joint2"
    assert e.reason.startswith("expands to 8,001 samples (9,")
    assert "with the other signals), more than the 9,000 a run may hold (reference_samples)" in e.reason
    # one table alone
    pts = [[k * 0.001, 0.0] for k in range(1000)]
    e = refused(bounds, "open_loop", {"joint3": TableSignal(points=pts)}, stop=5.0, max_rows=500)
    assert e.field == "signals.joint3"


def test_row_limit_refuses_before_sampling(bounds):
    """A 500 Hz chirp for an hour would be 3.6e8 samples: refused from the arithmetic alone."""
    sig = ChirpSignal(amplitude=1.0, f0_hz=500.0, f1_hz=500.0, duration=3600.0)
    e = refused(bounds, "open_loop", {"joint1": sig}, stop=3600.0)
    assert e.field == "signals.joint1" and "360,000,001 samples" in e.reason
    e = refused(
        bounds, "closed_loop", {"joint1": SineSignal(amplitude=1e-5, frequency_hz=500.0)}, stop=3600.0
    )
    assert "720,000,002 samples" in e.reason  # position: two rows per sample


def test_position_rows_fit_the_default_limit(bounds):
    """A position sine takes two rows per sample: a 1 Hz sine for 400 s is 160,000 rows."""
    sig = SineSignal(amplitude=0.05, frequency_hz=1.0)
    tab, _ = expand(bounds, "closed_loop", {"joint1": sig}, stop=400.0)
    assert 159_000 < len(tab) <= ROWS


def test_a_short_table_is_previewed_row_for_row(bounds):
    """Every row when they fit: the jump of a step is exact, the value column the joint's mode reads."""
    step = {"joint2": StepSignal(amplitude=0.2, start=1.0)}
    tab, jmode = expand(bounds, "closed_loop", step, reference="speed")
    t, values = preview(tab, jmode, [1], 1000)
    assert np.array_equal(t, tab[:, 0]) and np.array_equal(values[:, 0], tab[:, 1 + N + 1])
    tab, jmode = expand(bounds, "open_loop", {"joint3": StepSignal(amplitude=1.5, start=1.0)})
    t, values = preview(tab, jmode, [2], 1000)
    assert values[0, 0] == 0.0 and values[-1, 0] == 1.5 and np.count_nonzero(t == 1.0) == 2


@pytest.mark.parametrize("points", [1000, 101, 12])
def test_a_dense_preview_keeps_its_bound_its_envelope_and_its_ends(bounds, points):
    """A chirp to 40 Hz on two joints is ~50k rows: the preview holds at most `points` rows, keeps
    each joint's extremes, the first and last rows, and only rows of the table itself."""
    signals = {
        "joint1": ChirpSignal(amplitude=2.0, f0_hz=1.0, f1_hz=40.0, duration=4.0, offset=0.5),
        "joint4": SineSignal(amplitude=1.0, frequency_hz=3.0, start=0.5),
    }
    tab, jmode = expand(bounds, "open_loop", signals)
    assert tab.shape[0] > 10 * points
    t, values = preview(tab, jmode, [0, 3], points)
    assert len(t) <= points and np.all(np.diff(t) >= 0.0)
    assert t[0] == 0.0 and t[-1] == tab[-1, 0]
    for k, j in enumerate([0, 3]):
        column = tab[:, 1 + j]
        assert values[:, k].max() == column.max() and values[:, k].min() == column.min()
    rows = {(float(a), float(b), float(c)) for a, b, c in tab[:, [0, 1, 4]]}
    assert all((float(a), float(b), float(c)) in rows for a, (b, c) in zip(t, values, strict=True))
