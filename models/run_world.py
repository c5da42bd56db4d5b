"""What the arm can touch during a run: the obstacles as set, the run's own copy of them (an object
released where the tool left it), the object the tool holds, and the contact tables the compiled
kernels read of all that (contact.py, step.chain_step, output_row)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from simecs.mesh.protocol.environment import Obstacle, check_obstacles
from simecs.mesh.rules import scene_state

from . import grasp
from .contact import ContactTables, pair_width
from .contact_geometry import link_bounds, sphere_table
from .spec import ArmSpec


class RunWorld:
    """The obstacles of a simulation and what a run does to them (grasps and releases)."""

    def __init__(self, spec: ArmSpec, obstacles: Sequence[Obstacle]) -> None:
        self._spec = spec
        self._last_link = len(spec.links) - 1
        self._set: list[Obstacle] = list(obstacles)
        self._objects: list[Obstacle] = list(obstacles)
        self.held: grasp.Held | None = None
        self._taken: set[str] = set()
        #: the grasp state the result rows carry (grasp.GS_*)
        self.grasp_state = grasp.no_grasp()
        self._notices: list[str] = []
        self.obstacle_table = np.zeros((0, 0))
        self.caps = np.zeros((0, 0))

    @property
    def obstacles(self) -> list[Obstacle]:
        """The obstacles as set (the model's own until `set_obstacles`)."""
        return list(self._set)

    @property
    def objects(self) -> list[Obstacle]:
        """The run's obstacles now: those set, a released object where the tool left it."""
        return list(self._objects)

    @property
    def names(self) -> set[str]:
        return {ob.name for ob in self._set}

    def set_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        """What the arm can touch in the runs that follow; checked here."""
        check_obstacles(obstacles)
        self._set = list(obstacles)

    def reset(self, grasped: set[str]) -> bool:
        """The world of a coming run that grasps the objects named `grasped`: the obstacles as set,
        nothing held. True when the tool held something (the chain carried it: rebuild it)."""
        was_holding = self.held is not None
        self._objects = list(self._set)
        self.held = None
        self._taken = set(grasped)
        self.grasp_state = grasp.no_grasp()
        return was_holding

    def carried(self) -> tuple[float, np.ndarray, np.ndarray] | None:
        """The held object as a load of the last link (mechanics.chain_arrays), None when nothing is held."""
        held = self.held
        return None if held is None else grasp.held_body(self._objects[held.index], held)

    def build_tables(self, values: Mapping[str, float]) -> ContactTables:
        """The arm's contact spheres at `values` (with the object it holds), the obstacles' table
        (grasp states marked) and the kernels' work arrays: what the kernels read of the contacts
        (step.chain_step, output_row), valid until the next call."""
        n = self._last_link + 1
        arm = sphere_table(self._spec, dict(values))
        spheres, obs = grasp.world_tables(arm, self._objects, self._taken, self.held, self._last_link)
        ns, no = spheres.shape[0], obs.shape[0]
        self.obstacle_table = obs
        self.caps = np.zeros((ns, no))
        pairs = np.zeros((ns * no, pair_width(n)))
        bounds = link_bounds(spheres)
        return ContactTables(spheres, bounds, obs, pairs, self.caps, np.zeros((4, n)), np.zeros((4, 3)))

    def grasp(self, name: str, R_last: np.ndarray, p_last: np.ndarray, tool: np.ndarray, t: float) -> None:
        """Take obstacle `name` ('': release what the tool holds) with the last joint frame at (R_last,
        p_last) and the tool point at `tool` (world). A grasp whose object is out of the tool's reach
        (the arm did not get there) takes nothing: the user is told (`take_notices`)."""
        if not name:
            if self.held is not None:
                k = self.held.index
                centre, frame = grasp.world_pose(self.held, R_last, p_last)
                self._objects[k] = scene_state.at_pose(self._objects[k], centre, frame)
                self.held = None
                grasp.set_state(self.grasp_state, k + 1, False, centre, frame)
            return
        k = next(i for i, ob in enumerate(self._objects) if ob.name == name)
        why = grasp.reach_problem(self._objects[k], tool)
        if why:
            self._notices.append(f"the grasp at t = {t:.3f} s took nothing: {why}")
            return
        self.held = grasp.take(k, self._objects[k], R_last, p_last)
        grasp.set_state(self.grasp_state, k + 1, True, self.held.p, self.held.R)

    def take_notices(self) -> list[str]:
        """What the run has to tell its user since the last call (a grasp that missed its object)."""
        out, self._notices = self._notices, []
        return out
