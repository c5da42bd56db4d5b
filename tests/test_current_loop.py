"""The drive's current loop keeps its torque at speed (issue 34, 3): field-oriented PIs in the rotor's
frame by default, the paper's stationary-frame PIs as a documented choice that loses torque when the
motor turns fast."""

from __future__ import annotations

import numpy as np
import pytest
from simecs.mesh.protocol import messages as m
from simecs.models import get_model
from simecs.models.planner import Planner


def torque_per_ampere(model_id: str, joint: int, rotor_frame: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(motor speed rad/s, tau_motor / (kt i)) every 10 ms of a 1 A open-loop current step on `joint`,
    the arm free to turn (zero gravity: the step alone speeds the motor up), averaged over 10 ms so
    the ripple's harmonics average out; and the motor's rated speed (traj.max_speed x gear.ratio)."""
    package = get_model(model_id)
    n = len(package.spec.links)
    values = package.check_values(
        {"gravity.z": 0.0, **{f"joint{j + 1}.current.rotor_frame": rotor_frame for j in range(n)}}
    )
    q0 = list(package.home())
    planner = Planner(package, values, q0, 0.6)
    plan = planner.plan(m.DirectInput("open_loop", {f"joint{joint}": m.StepSignal(amplitude=1.0)}))
    sim = package.build(values)
    try:
        sim.set_initial(q0)
        plan.apply(sim)
        sim.start(0.6, 0.0005)
        data = sim.advance(1.0)
        columns = list(sim.columns)
    finally:
        sim.close()
    ratio = data[:, columns.index(f"joint{joint}.tau_motor")] / values[f"joint{joint}.motor.kt"]
    speed = np.abs(data[:, columns.index(f"joint{joint}.qd_motor")])
    windows = (data[:, 0] // 0.01).astype(int)
    keep = windows >= 1  # from 10 ms on (the step's first edge is the current loop's own transient)
    means = []
    for w in np.unique(windows[keep]):
        here = keep & (windows == w)
        means.append((speed[here].mean(), ratio[here].mean()))
    rated = values[f"joint{joint}.traj.max_speed"] * values[f"joint{joint}.gear.ratio"]
    return np.array([s for s, _ in means]), np.array([r for _, r in means]), rated


@pytest.mark.parametrize(("model_id", "joint"), [("spider", 1), ("puma560", 3)])
def test_the_rotor_frame_loop_keeps_its_torque_per_ampere_to_rated_speed(model_id: str, joint: int) -> None:
    """Up to the motor's rated speed (beyond it the back-EMF meets the bus voltage: no loop helps)."""
    speed, ratio, rated = torque_per_ampere(model_id, joint, 1.0)
    assert speed.max() > 0.8 * rated, f"the motor reached {speed.max():.0f} of {rated:.0f} rad/s only"
    within = speed <= rated
    seen = list(zip(speed.round(), ratio.round(3), strict=True))
    assert ratio[within].min() >= 0.9 and ratio[within].max() <= 1.1, seen


def test_the_papers_stationary_loops_lose_torque_when_the_motor_turns_fast() -> None:
    speed, ratio, rated = torque_per_ampere("spider", 1, 0.0)
    slow, fast = ratio[speed < 0.2 * rated], ratio[(speed > 0.7 * rated) & (speed <= rated)]
    assert slow.size and fast.size
    assert slow.mean() > 0.95 and fast.min() < 0.8, list(zip(speed.round(), ratio.round(3), strict=True))
