"""Where an arm's collision solids are, and a motion that folds it into itself: shared by the tests
and `simecs bench control`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def link_hull_points(pkg: Any, q: Sequence[float] | np.ndarray, link: int) -> np.ndarray:
    """The corners of link `link`'s collision solids' hulls in the world at pose q (an imported arm)."""
    from simecs.models.chain_dynamics import chain_frames
    from simecs.models.collision_spheres import solid_hull
    from simecs.models.contact_geometry import link_axes
    from simecs.models.mechanics import chain_arrays

    arrays = chain_arrays(pkg.spec, pkg.describe().default_values())
    R_all, p_all = np.empty((pkg.n, 3, 3)), np.empty((pkg.n, 3))
    chain_frames(arrays.pre_R, arrays.pre_p, np.asarray(q, dtype=float), R_all, p_all)
    R = R_all[link] @ link_axes(pkg.spec, link)
    solids = [s for s in pkg.spec.collisions if s.link == link]
    points = np.vstack([np.asarray(solid_hull(s.geometry, s.near).vertices) for s in solids])
    return points @ R.T + p_all[link]


def fold_target(pkg: Any, steps: int = 41, depth: float = 0.005) -> tuple[list[float], str] | None:
    """The pose nearest the model's home, one joint turned, where two of its links overlap by more than
    `depth` (m), reached by a path the drives hold and that touches no obstacle; with the refusal the
    planner gives for it. None when no single joint folds the arm into itself."""
    from simecs.mesh.protocol import messages as m
    from simecs.models.planner import Planner

    values = pkg.describe().default_values()
    home = np.array(pkg.spec.home)
    planner = Planner(pkg, values, home, 30.0, obstacles=pkg.spec.obstacles)
    best: tuple[float, list[float], str] | None = None
    for j, link in enumerate(pkg.spec.links):
        for value in np.linspace(link.joint_min, link.joint_max, steps):
            q = home.copy()
            q[j] = value
            hit = planner.checks.self_check.first_touch(q[None, :])
            if hit is None or hit[3] <= depth or (best is not None and abs(value - home[j]) >= best[0]):
                continue
            plan = planner.plan(m.JointPath([m.PathNode(list(q))]))
            refusal = planner.checks.self_touch(plan)
            if (
                refusal is not None
                and planner.checks.collision(plan) is None
                and planner.checks.holding_problem(plan) is None
            ):
                best = (abs(value - home[j]), [float(x) for x in q], refusal[1])
    return None if best is None else (best[1], best[2])
