"""The hold case under gravity, shared by the tests and `simecs bench model`: a model's arm moved from
its home to a pose its drives must work to hold, then held; how far it strays once settled."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: The share of its holding capacity the most loaded drive needs at the pose (models.mechanics
#: `holding_capacity`): a pose far from rest that the drives still hold with room for the motion.
LOAD_SHARE = 0.6
#: Held this long after the arrival; the error is taken from SETTLE_S after it.
HOLD_S = 2.0
SETTLE_S = 1.0


@dataclass
class HoldResult:
    pose: np.ndarray  # the pose held (rad)
    load: float  # the most loaded drive's share of its capacity there
    arrival: float  # s: when the set points reached it
    error: float  # rad: the largest joint error from SETTLE_S after the arrival on
    gravity: float  # m/s^2: the size of the model's gravity in the run
    rows: np.ndarray
    columns: list[str]


def loaded_pose(sim: Any, seed: int = 1, tries: int = 400) -> tuple[np.ndarray, float]:
    """Of `tries` random poses within the joint ranges of the simulation `sim` (a fixed seed: the same
    pose every time), the one whose most loaded drive comes closest to LOAD_SHARE of its capacity from
    below: (pose, share)."""
    from simecs.mesh.protocol import messages as m
    from simecs.models.mechanics import holding_capacity
    from simecs.models.planner import Planner

    capacity = holding_capacity(sim.P)
    links = sim.package.spec.links
    lower = np.maximum([lk.joint_min for lk in links], -np.pi)
    upper = np.minimum([lk.joint_max for lk in links], np.pi)
    rng = np.random.default_rng(seed)
    candidates = []
    for _ in range(tries):
        q = rng.uniform(lower, upper)
        load = float(np.max(np.abs(sim.holding_torques(q)) / capacity))
        if load <= LOAD_SHARE:
            candidates.append((load, q))
    for load, q in sorted(candidates, key=lambda c: -c[0]):
        # free of the model's obstacles (a floor, a table would carry part of the weight)
        planner = Planner(sim.package, sim.values, q, 1.0, obstacles=sim.obstacles)
        if planner.checks.collision(planner.plan(m.JointPath([m.PathNode(list(q), 100.0, 100.0)]))) is None:
            return q, load
    raise ValueError("no pose of the tries is free of the obstacles")


def hold_case(model: str, values: Mapping[str, float] | None = None, output: float = 0.002) -> HoldResult:
    """The model moved from home to its `loaded_pose` at 100 % and held there HOLD_S."""
    from simecs.models import get_model

    package = get_model(model)
    sim = package.build(dict(values or {}))
    try:
        pose, load = loaded_pose(sim)
        sim.set_initial(list(package.home()))
        sim.set_joint_path([(list(pose), 100.0, 100.0)])
        # the move's duration, then the hold
        sim.start(60.0, output)
        rows = [sim.advance(0.0)]
        columns = list(sim.columns)
        q_ref = [columns.index(f"joint{j + 1}.q_ref") for j in range(sim.n)]
        arrival = None
        while not sim.finished:
            rows.append(sim.advance(sim.time + 0.25))
            last = rows[-1]
            if arrival is None and last.shape[0]:
                there = np.all(np.abs(last[:, q_ref] - pose) < 1e-12, axis=1)
                if there.any():
                    arrival = float(last[np.argmax(there), 0])
            if arrival is not None and sim.time >= arrival + HOLD_S:
                break
        data = np.vstack(rows)
        gravity = float(np.linalg.norm(sim.gravity))
    finally:
        sim.close()
    assert arrival is not None, f"{model}: the set points never reached the pose"
    q = [columns.index(f"joint{j + 1}.q") for j in range(pose.shape[0])]
    settled = data[:, 0] >= arrival + SETTLE_S
    error = float(np.max(np.abs(data[settled][:, q] - pose)))
    return HoldResult(pose, load, arrival, error, gravity, data, columns)
