"""`simecs bench control`: the control systems of paper §5 on the Spider's full drive train.

- `rtf_opspace`: simulated s per wall s of the standard LIN move (benchmarks/commands.py: 0.5 m at
  50 %, and 1 s after it) under operational-space motion control, as fast as possible on one core,
  best of 3; `rtf_joint_independent` the same under the joint cascade, for scale;
- `opspace_tracking_error_mm`: the largest distance of the tool from its set point (`tool.e_pos`, the
  tool pose of the joint set points) over that run, operational-space control;
  `joint_independent_tracking_error_mm` the same move under the joint cascade, in the same bench run;
  `*_rms_mm` their RMS, `*_orientation_error_mrad` the largest `tool.e_rot`;
- `*_hold_error_mm`: the largest `tool.e_pos` over the last 0.5 s (the target held at rest);
- `rtf_contact`: the Spider's tool tip pressed 5 mm into a plane above it (k = 1e5 N/m, friction 0.3)
  while joint 1 turns 0.3 rad at 20 % and holds, 3 s, joint cascade; the tool slides on the plane
  throughout (`contact_sliding_force_n`: its mean normal force, `contact_fraction`: of the samples in
  contact); `rtf_no_contact` the same run without the plane;
- `rtf_hybrid`: the Spider's tool touching a plane above it slides 0.1 m along x at 20 % under
  operational-space hybrid control, pushing up with 20 N (a Cartesian node's `force`), and 1 s after;
  `hybrid_force_error_n`: the RMS of the measured normal force (`contact.tool_fn`) less 20 N while it
  slides, after the first 0.5 s; `hybrid_force_error_rest_n` over the last 0.5 s (at rest);
  `hybrid_path_error_mm`: the largest distance of the tool from the line across the axis;
- `rtf_contact_urdf`: the Panda (imported from URDF) with the lowest corner of its hand's collision
  solids pressed 3 mm into a box (k = 1e5 N/m, friction 0.3) while joint 7 turns the hand 0.5 rad on
  it at 20 % and holds, 3 s, under gravity; `contact_urdf_force_n` the mean of link7's contact force,
  `contact_urdf_fraction` of the samples in contact;
- `self_collision_detected`: 1 when, for each of the `self_collision_models` arms (Spider, Panda,
  UR5, Jaco2), the single-joint motion from home that folds it into itself (testing/collision.py) is
  refused by the planner naming the two links;
- `contact_energy_drift`: drives off (a free chain), the Spider turning on joint 1 at 0.5 rad/s into
  a frictionless, undamped wall (an elastic impact): |E after - E before| / E before, E = qd^T M qd / 2
  out of contact.

Per model in `per_model` (Spider and PUMA 560); the top-level keys are the Spider's.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from .commands import print_per_model, run_line, standard_line

SYSTEMS = ("opspace", "joint_independent")
SYSTEM_NAMES = {"opspace": "opspace_motion", "joint_independent": "joint_independent"}
MODELS = ("spider", "puma560")
HOLD_WINDOW_S = 0.5


def _figures(model_id: str) -> dict[str, float]:
    line = standard_line(model_id)
    out: dict[str, float] = {}
    for short in SYSTEMS:
        cols, rows, wall = run_line(line, SYSTEM_NAMES[short])
        e_pos = rows[:, cols.index("tool.e_pos")]
        e_rot = rows[:, cols.index("tool.e_rot")]
        hold = rows[:, 0] >= rows[-1, 0] - HOLD_WINDOW_S
        out[f"rtf_{short}"] = float(rows[-1, 0] / wall)
        out[f"{short}_tracking_error_mm"] = float(e_pos.max() * 1e3)
        out[f"{short}_tracking_rms_mm"] = float(np.sqrt(np.mean(e_pos**2)) * 1e3)
        out[f"{short}_orientation_error_mrad"] = float(e_rot.max() * 1e3)
        out[f"{short}_hold_error_mm"] = float(e_pos[hold].max() * 1e3)
    return out


def _run(sim: Any, stop: float) -> tuple[np.ndarray, float]:
    """Rows of a started simulation to `stop` in 50 ms chunks, and the wall time it took."""
    t0 = time.perf_counter()
    rows = [sim.advance(0.0)]
    while not sim.finished:
        rows.append(sim.advance(sim.time + 0.05))
    return np.vstack(rows), time.perf_counter() - t0


def _best_of_three(
    pkg: Any, values: Any, obstacles: list[Any], q0: np.ndarray, goal: np.ndarray, stop: float
) -> tuple[list[str], np.ndarray, float]:
    """A joint move from q0 to goal at 20 % among `obstacles`, `stop` s, run 3 times: the columns, the
    last run's rows and the best real-time factor."""
    walls = []
    for _ in range(3):
        sim = pkg.build(values)
        sim.set_obstacles(obstacles)
        sim.set_initial(q0)
        sim.set_joint_path([(list(goal), 20.0, 20.0)])
        sim.start(stop, 0.002)
        rows, wall = _run(sim, stop)
        walls.append(wall)
        cols = list(sim.columns)
        sim.close()
    return cols, rows, stop / min(walls)


def _contact_figures() -> dict[str, float]:
    from simecs import models
    from simecs.mesh.protocol import messages as m
    from simecs.models.contact_geometry import TOOL_RADIUS
    from simecs.models.ik import ArmKinematics

    pkg = models.get_model("spider")
    values = pkg.describe().default_values()
    q0 = np.zeros(pkg.n)
    p, _R = ArmKinematics(pkg.spec, values).tool_pose(q0)  # the tool points up at q = 0
    lid = m.Obstacle("lid", "plane", [*p[:2], p[2] + TOOL_RADIUS - 0.005], [math.pi, 0.0, 0.0])
    goal = q0.copy()
    goal[0] = 0.3
    out: dict[str, float] = {}
    stop = 3.0
    for name, obstacles in (("contact", [lid]), ("no_contact", [])):
        cols, rows, out[f"rtf_{name}"] = _best_of_three(pkg, values, obstacles, q0, goal, stop)
        if obstacles:
            fn = rows[:, cols.index("contact.tool_fn")]
            out["contact_sliding_force_n"] = float(fn.mean())
            out["contact_fraction"] = float(np.mean(fn > 0))
    # An elastic impact of the free chain: the energy it keeps.
    v_dir = np.cross([0.0, 0.0, 1.0], p)
    v_dir /= np.linalg.norm(v_dir)
    barrier = m.Obstacle(
        "wall",
        "plane",
        list(p + 0.1 * v_dir),
        [0.0, math.pi / 2, math.atan2(-v_dir[1], -v_dir[0])],  # its normal faces the arm
        damping=0.0,
        friction=0.0,
    )
    sim = pkg.build({**values, "drives.enabled": 0.0})
    sim.set_obstacles([barrier])
    qd0 = np.zeros(pkg.n)
    qd0[0] = 0.5
    sim.set_initial(q0, list(qd0))
    sim.start(1.5, 0.001)
    rows, _ = _run(sim, 1.5)
    cols = list(sim.columns)
    q = rows[:, [cols.index(f"joint{j}.q") for j in range(1, pkg.n + 1)]]
    qd = rows[:, [cols.index(f"joint{j}.qd") for j in range(1, pkg.n + 1)]]
    depth = rows[:, cols.index("contact.depth")]
    energy = np.array([0.5 * qd[k] @ sim.mass_matrix(q[k]) @ qd[k] for k in range(len(rows))])
    sim.close()
    touched = np.flatnonzero(depth > 0)
    assert touched.size and touched[-1] < len(rows) - 1, "the chain did not bounce off the wall"
    before, after = energy[touched[0] - 1], energy[touched[-1] + 1 :]
    out["contact_energy_drift"] = float(np.max(np.abs(after - before)) / before)
    out["contact_impact_s"] = float(rows[touched[-1], 0] - rows[touched[0], 0])
    return out


def _urdf_figures() -> dict[str, float]:
    """An imported arm's contact through its URDF collision solids, and every arm against itself."""
    from simecs import models
    from simecs.mesh.protocol import messages as m
    from simecs.testing.collision import fold_target, link_hull_points

    pkg = models.get_model("panda")
    values = pkg.describe().default_values()
    q0 = np.array(pkg.spec.home)
    hand = link_hull_points(pkg, q0, pkg.n - 1)
    k = int(np.argmin(hand[:, 2]))
    top = float(hand[k, 2]) + URDF_PRESS_M  # the hand's lowest corner pressed into the box
    box = m.Obstacle(
        "table", "box", [float(hand[k, 0]), float(hand[k, 1]), top - 0.05], size=[0.25, 0.25, 0.1]
    )
    goal = q0.copy()
    goal[-1] += 0.5  # the hand turns on the box about its own axis
    stop = 3.0
    cols, rows, rtf = _best_of_three(pkg, values, [box], q0, goal, stop)
    force = rows[:, cols.index(f"contact.link{pkg.n}.force")]
    out = {
        "rtf_contact_urdf": rtf,
        "contact_urdf_force_n": float(force.mean()),
        "contact_urdf_fraction": float(np.mean(force > 0)),
    }
    folds = {model_id: fold_target(models.get_model(model_id)) for model_id in SELF_COLLISION_MODELS}
    out["self_collision_models"] = float(len(folds))
    out["self_collision_detected"] = float(all(found is not None for found in folds.values()))
    return out


#: m: how far the Panda's hand is pressed into the box in `rtf_contact_urdf`.
URDF_PRESS_M = 0.003
#: The models with a single-joint motion from home that folds them into themselves (the PUMA has
#: none within its ranges: its forearm sits beside the upper arm).
SELF_COLLISION_MODELS = ("spider", "panda", "ur5", "jaco2")
HYBRID_FORCE_N = 20.0
SETTLE_S = 0.5


def _hybrid_figures() -> dict[str, float]:
    from simecs import models
    from simecs.mesh.protocol import messages as m
    from simecs.mesh.rules.kinematics import rpy_of
    from simecs.models.contact_geometry import TOOL_RADIUS
    from simecs.models.planner import Planner

    pkg = models.get_model("spider")
    values = pkg.describe().default_values()
    q0 = np.zeros(pkg.n)
    planner = Planner(pkg, values, q0, 5.0)
    p, R = planner.kin.tool_pose(q0)  # the tool points up at q = 0: the plane is just above its tip
    lid = m.Obstacle("lid", "plane", [*p[:2], p[2] + TOOL_RADIUS], [math.pi, 0.0, 0.0])
    end = p + np.array([0.1, 0.0, 0.0])
    node = m.CartesianNode(list(end), list(rpy_of(R)), "lin", 20.0, 20.0, HYBRID_FORCE_N, [0.0, 0.0, 1.0])
    plan = planner.plan(m.CartesianPath([node]))
    stop = plan.duration + 1.0
    walls = []
    for _ in range(3):
        sim = pkg.build(values)
        sim.set_obstacles([lid])
        sim.set_initial(q0)
        plan.apply(sim)
        sim.set_control("opspace_hybrid", 0.001)
        sim.start(stop, 0.002)
        rows, wall = _run(sim, stop)
        walls.append(wall)
        cols = list(sim.columns)
        sim.close()
    t = rows[:, 0]
    error = rows[:, cols.index("contact.tool_fn")] - HYBRID_FORCE_N
    sliding = (t >= SETTLE_S) & (t <= plan.duration)
    tip = rows[:, [cols.index(f"pose.tool.{a}") for a in "xy"]]
    return {
        "rtf_hybrid": stop / min(walls),
        "hybrid_force_error_n": float(np.sqrt(np.mean(error[sliding] ** 2))),
        "hybrid_force_error_rest_n": float(np.sqrt(np.mean(error[t >= stop - SETTLE_S] ** 2))),
        "hybrid_path_error_mm": float(np.max(np.abs(tip[:, 1] - p[1])) * 1e3),
    }


def run_control_bench(as_json: bool = False) -> dict[str, Any]:
    from simecs.models import warmup

    warmup()
    per_model = {model_id: _figures(model_id) for model_id in MODELS}
    result: dict[str, Any] = dict(per_model["spider"])
    contact = {**_hybrid_figures(), **_contact_figures(), **_urdf_figures()}
    per_model["spider"].update(contact)
    result.update(contact)
    result["per_model"] = per_model
    print_per_model(result, as_json, 40)
    return result
