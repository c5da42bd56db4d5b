"""The checks a planned path passes before its run: the arm (and what it carries) against the
obstacles, the arm against itself, and the drives against gravity. Each samples the plan's set
points (plan.py) and answers (field, why): `initial` or the command's step the refusal names, and
the reason a user reads; None when the path is clear. A path that follows speeds or currents is not
known before its run and passes (the run's own contact and self-contact logs report it).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import numpy as np
from simecs.mesh.protocol.environment import Obstacle

from . import contact, contact_geometry, grasp
from . import drive as dr
from .chain_dynamics import gravity_torques
from .description import ArmDescription
from .mechanics import ChainArrays, chain_arrays, drive_array, gravity_of, holding_capacity
from .plan import Plan, World
from .self_collision import SelfCollision

#: s between the set points a path is checked at against the obstacles (before a run): at 1 m/s a
#: sphere moves 2 mm between two, a fifth of the thinnest one.
PATH_CHECK_PERIOD = 2e-3
#: m: how far a point of the arm may move between two of those checks of a reference table (whose
#: rows may be far apart in time on a slow move): the same 2 mm.
PATH_CHECK_STEP = 2e-3
#: s between the poses whose gravity load the hold check weighs, and rad the joints may turn together
#: between two of them (gravity changes slowly along a path)
HOLD_CHECK_PERIOD = 0.02
HOLD_CHECK_STEP = 0.02


class PathChecks:
    """The checks of one model at one set of values, from one initial pose, among `obstacles`."""

    def __init__(
        self,
        model: ArmDescription,
        values: Mapping[str, float],
        q0: np.ndarray,
        obstacles: Sequence[Obstacle],
        reach: float,
        arrays: ChainArrays,
        spheres: np.ndarray,
    ) -> None:
        """`reach`: the farthest a point of the arm is from its base; `arrays` and `spheres`: the
        chain's (mechanics.chain_arrays) and its contact spheres' (contact_geometry.sphere_table)."""
        self.model = model
        self.n = model.n
        self.values = dict(values)
        self.q0 = q0
        self.obstacles = list(obstacles)
        self.reach = reach
        self._arrays = arrays
        self._spheres = spheres

    def collision(self, plan: Plan) -> tuple[str, str] | None:
        """(field, why) when the planned path makes the arm (or what it carries) touch an obstacle: the
        field is `initial` or the step's path under `command`. A path that follows speeds or currents
        is not known before the run: None. While a node sets a force the tool may touch (it is meant
        to push); the last link (the gripper's) passes through the objects the command grasps."""
        sampled = plan.joint_samples(self.q0, PATH_CHECK_PERIOD, PATH_CHECK_STEP / self.reach)
        if sampled is None or not self.obstacles:
            return None
        times, qs = sampled
        pushing = plan.pushing(times)  # where the tool pushes, only the rest of the arm must not touch
        worlds = plan.worlds or [World(0.0, self.obstacles)]
        taken = {name for _t, name in plan.grasps if name}
        found = np.zeros(4)
        for w, world in enumerate(worlds):
            end = worlds[w + 1].t if w + 1 < len(worlds) else math.inf
            rows = np.flatnonzero((times >= world.t - 1e-12) & (times < end - 1e-12))
            if rows.size == 0:
                continue
            spheres, obs = grasp.world_tables(self._spheres, world.obstacles, taken, world.held, self.n - 1)
            hit = contact.first_touch(
                spheres,
                obs,
                self._arrays.pre_R,
                self._arrays.pre_p,
                np.ascontiguousarray(qs[rows]),
                pushing[rows],
                found,
            )
            if hit >= 0:
                return self._touch(plan, int(rows[hit]), float(times[rows[hit]]), world.obstacles, found)
        return None

    @functools.cached_property
    def self_check(self) -> SelfCollision:
        """The arm's check against itself at these values (self_collision.py), made when first asked."""
        spec = self.model.spec
        return SelfCollision.of(spec, self._spheres, self._arrays.pre_R, self._arrays.pre_p, spec.home)

    def self_touch(self, plan: Plan) -> tuple[str, str] | None:
        """(field, why) when the planned path makes two links of the arm touch (`initial`, or the step's
        path under `command`); a path that follows speeds or currents is not known: None."""
        sampled = plan.joint_samples(self.q0, PATH_CHECK_PERIOD, PATH_CHECK_STEP / self.reach)
        if sampled is None:
            return None
        times, qs = sampled
        hit = self.self_check.first_touch(qs)
        if hit is None:
            return None
        k, a, b, depth = hit
        what = f"{a} would touch {b} ({depth * 1000:.1f} mm deep)"
        if k == 0:
            return "initial", f"at the initial pose {what}: choose a pose where the arm is clear of itself"
        t = float(times[k])
        return (
            plan.field_at(t),
            f"{what} at t = {t:.3f} s of the planned path: change the path, or set settings.collisions to "
            "simulate",
        )

    def holding_problem(self, plan: Plan | None) -> tuple[str, str] | None:
        """(field, why) when a drive cannot hold the arm against gravity at the initial pose or at a
        pose of the planned path (`plan` None: a run without a command, which holds the initial pose):
        the joint's gravity torque there (payload and a grasped object included) exceeds what its
        drive gives at rest (mechanics.holding_capacity). The motion's own torques are not counted:
        the drives' current limit shapes them in the run."""
        gravity = gravity_of(self.values)
        if not np.any(gravity):
            return None
        P = drive_array(self.n, self.values)
        capacity = holding_capacity(P)
        sampled = None if plan is None else plan.joint_samples(self.q0, HOLD_CHECK_PERIOD, HOLD_CHECK_STEP)
        times, qs = sampled if sampled is not None else (np.zeros(1), self.q0[None, :])
        worlds = (plan.worlds if plan is not None else None) or [World(0.0, self.obstacles)]
        g = np.empty(self.n)
        for w, world in enumerate(worlds):
            end = worlds[w + 1].t if w + 1 < len(worlds) else math.inf
            carried = None
            arrays = self._arrays
            if world.held is not None:  # the grasped object joins the last link
                carried = world.obstacles[world.held.index]
                body = grasp.held_body(carried, world.held)
                arrays = chain_arrays(self.model.spec, self.values, body)
            for k in np.flatnonzero((times >= world.t - 1e-12) & (times < end - 1e-12)):
                gravity_torques(arrays, gravity, np.ascontiguousarray(qs[k]), g)
                over = np.flatnonzero(np.abs(g) > capacity)
                if over.size:
                    return self._unholdable(plan, float(times[k]), k == 0, g, capacity, P, over, carried)
        return None

    @staticmethod
    def _unholdable(
        plan: Plan | None,
        t: float,
        initial: bool,
        g: np.ndarray,
        capacity: np.ndarray,
        P: np.ndarray,
        over: np.ndarray,
        carried: Obstacle | None,
    ) -> tuple[str, str]:
        """The refusal of a pose whose gravity torque on joints `over` exceeds their drives'."""
        j = int(over[np.argmax(np.abs(g[over]) / capacity[over])])
        load = f" carrying {carried.name} ({carried.mass:g} kg)" if carried is not None else ""
        need = (
            f"joint{j + 1} cannot hold the arm{load} against gravity: it needs {abs(g[j]):.1f} N m, its "
            f"drive gives at most {capacity[j]:.1f} N m at rest (motor.i_max {P[j, dr.P_IMAX]:g} A, "
            f"motor.kt {P[j, dr.P_KT]:g} N m/A, gear.ratio {P[j, dr.P_N]:g})"
        )
        if initial:
            return "initial", f"at the initial pose {need}: choose another pose or a lighter payload"
        lighter = "carry a lighter object" if carried is not None else "lighten the payload"
        return (
            plan.field_at(t) if plan is not None else "command",
            f"at t = {t:.3f} s of the planned path {need}: change the path or {lighter}",
        )

    def _touch(
        self, plan: Plan, k: int, t: float, obstacles: Sequence[Obstacle], found: np.ndarray
    ) -> tuple[str, str]:
        hit = obstacles[int(found[1])].name
        world = next(w for w in reversed(plan.worlds or [World(0.0, [])]) if w.t <= t + 1e-12)
        if found[3] == contact_geometry.CARRIED and world.held is not None:
            what = f"the carried {world.obstacles[world.held.index].name} would touch obstacle {hit}"
        else:
            what = f"link{int(found[0]) + 1} would touch obstacle {hit}"
        depth = f"{found[2] * 1000:.1f} mm deep"
        if k == 0:
            return "initial", f"at the initial pose {what} ({depth}): move the arm or the obstacle clear"
        return (
            plan.field_at(t),
            f"{what} at t = {t:.3f} s of the planned path ({depth}): change the path, move the obstacle "
            "(set_obstacles), or set settings.collisions to simulate",
        )
