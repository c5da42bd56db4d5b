"""Grasping (paper §6): an obstacle the tool takes moves with the last link until it is released.

While held, the object is part of the last link: its mass and inertia join the link's (the payload of
`mechanics.chain_arrays`), it touches the other obstacles through spheres inside it (added to the
arm's contact spheres, `SP_TOOL` = CARRIED) and nothing touches it as an obstacle. Released, it is
an obstacle again, fixed where the tool left it. The last link never touches an object the run grasps
(it holds the gripper, which closes around the object; no gripper is modelled).

The planner checks a grasp on the planned poses before the run; the simulation takes the object at the
pose the arm really has at the grasp's time (docs/MODELS.md, "Grasping").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.robot_commands import GRASP_REACH
from simecs.mesh.rules.kinematics import rot_rpy

from .chain_dynamics import quats_from_matrices
from .contact_geometry import CARRIED, GRASPED, HELD, OB_GRASP, obstacle_table, surface_contact
from .jit import CACHE as _CACHE

#: Spheres along one axis of a carried box or cylinder at most: a long thin object is covered by
#: spheres further apart than their radius (its envelope dips between them).
MAX_SPHERES_PER_AXIS = 6


#: Output columns (`grasp.*` variables): the object last taken (its number in the run's list, 1..;
#: 0: none yet) and whether the tool holds it; its pose is the `grasped` pose frame
#: (mesh/protocol/columns.py).
GRASP_OUTPUTS = ("object", "held")
# the grasp state the result rows read: object number, held, then its centre and frame (row-major): in
# the last joint's frame while held, in the world's once released (and before any grasp: the origin)
GS_OBJECT, GS_HELD, GS_P, GS_R = 0, 1, 2, 5
NGS = 14


def set_state(state: np.ndarray, number: float, held: bool, p: np.ndarray, R: np.ndarray) -> None:
    """Fill the grasp state (GS_*): the object's number, whether it is held, its centre and frame."""
    state[GS_OBJECT] = number
    state[GS_HELD] = 1.0 if held else 0.0
    state[GS_P : GS_P + 3] = p
    state[GS_R : GS_R + 9] = np.asarray(R).reshape(9)


def no_grasp() -> np.ndarray:
    """The grasp state before any grasp."""
    state = np.zeros(NGS)
    set_state(state, 0, False, np.zeros(3), np.eye(3))
    return state


@njit(cache=_CACHE)
def grasp_outputs(state, R_last, p_last, out, pose):
    """out = GRASP_OUTPUTS and pose = the object's world pose (x, y, z, qw, qx, qy, qz) from the grasp
    state and the last joint frame (R_last, p_last)."""
    out[0] = state[GS_OBJECT]
    out[1] = state[GS_HELD]
    Rs = np.empty((1, 3, 3))
    for a in range(3):
        if state[GS_HELD] > 0.5:
            pose[a] = p_last[a]
            for b in range(3):
                pose[a] += R_last[a, b] * state[GS_P + b]
                acc = 0.0
                for k in range(3):
                    acc += R_last[a, k] * state[GS_R + 3 * k + b]
                Rs[0, a, b] = acc
        else:
            pose[a] = state[GS_P + a]
            for b in range(3):
                Rs[0, a, b] = state[GS_R + 3 * a + b]
    quat = np.empty((1, 4))
    quats_from_matrices(Rs, quat)
    for a in range(4):
        pose[3 + a] = quat[0, a]


@dataclass(frozen=True)
class Held:
    """The object the tool holds: its index in the run's obstacle list and its pose in the last joint's
    frame (fixed from the grasp on)."""

    index: int
    p: np.ndarray  # (3,) its centre
    R: np.ndarray  # (3, 3) its frame


def reach_problem(ob: Obstacle, tool: np.ndarray) -> str:
    """Why the tool point at `tool` (world) cannot take `ob` ('' if within GRASP_REACH of it)."""
    nrm = np.empty(3)
    gap = -surface_contact(obstacle_table([ob])[0], np.asarray(tool, dtype=float), 0.0, nrm)
    if gap <= GRASP_REACH:
        return ""
    return (
        f"the tool point is {gap * 1000:.1f} mm from obstacle {ob.name} "
        f"(a grasp needs it within {GRASP_REACH * 1000:g} mm)"
    )


def take(index: int, ob: Obstacle, R_last: np.ndarray, p_last: np.ndarray) -> Held:
    """The object held from the last joint frame's pose (R_last, p_last) now on."""
    R_obj = rot_rpy(ob.rotation_rpy)
    p_obj = np.asarray(ob.position, dtype=float)
    return Held(index, R_last.T @ (p_obj - p_last), R_last.T @ R_obj)


def world_pose(held: Held, R_last: np.ndarray, p_last: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the held object is when the last joint frame is at (R_last, p_last): (centre, frame)."""
    return p_last + R_last @ held.p, R_last @ held.R


def body(ob: Obstacle) -> tuple[float, np.ndarray]:
    """Mass (kg) and inertia about its centre in its own frame (kg m^2) of a homogeneous obstacle."""
    m = float(ob.mass)
    if ob.kind == "box":
        a, b, c = (float(x) for x in ob.size)
        return m, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 12.0
    if ob.kind == "cylinder":
        r, L = float(ob.radius), float(ob.length)
        ixx = m * (3.0 * r * r + L * L) / 12.0
        return m, np.diag([ixx, ixx, 0.5 * m * r * r])
    if ob.kind == "sphere":
        return m, np.eye(3) * 0.4 * m * float(ob.radius) ** 2
    raise ValueError(f"a {ob.kind} has no body to carry")


def held_body(ob: Obstacle, held: Held) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass, centre, inertia about the centre) of the held object in the last joint's frame: the load
    `mechanics.chain_arrays` adds to the last link."""
    m, inertia = body(ob)
    return m, held.p.copy(), held.R @ inertia @ held.R.T


def carried_spheres(ob: Obstacle, held: Held, link: int) -> np.ndarray:
    """Spheres inside the held object (rows of contact_geometry's sphere table on joint frame `link`):
    a sphere is itself; a box is filled with spheres of half its thinnest edge, a cylinder with
    spheres of its radius along its axis (or of its half length across a flat one), at most their
    radius apart (MAX_SPHERES_PER_AXIS along an axis). Edges and corners come out rounded."""
    if ob.kind == "sphere":
        local = [(np.zeros(3), float(ob.radius))]
    elif ob.kind == "box":
        half = np.asarray(ob.size, dtype=float) / 2
        r = float(half.min())
        local = [(np.array(c), r) for c in _grid([_axis_points(h - r, r) for h in half])]
    elif ob.kind == "cylinder":
        rc, hl = float(ob.radius), float(ob.length) / 2
        if hl >= rc:
            local = [(np.array([0.0, 0.0, z]), rc) for z in _axis_points(hl - rc, rc)]
        else:
            span = _axis_points(rc - hl, hl)
            local = [
                (np.array([x, y, 0.0]), hl)
                for x, y in _grid([span, span])
                if math.hypot(x, y) <= rc - hl + 1e-12
            ]
    else:
        raise ValueError(f"a {ob.kind} cannot be carried")
    rows = []
    for c, r in local:
        centre = held.p + held.R @ c
        rows.append([link, *centre, r, CARRIED])
    return np.array(rows, dtype=float)


def world_tables(
    spheres: np.ndarray, obstacles: Sequence[Obstacle], taken: set[str], held: Held | None, link: int
) -> tuple[np.ndarray, np.ndarray]:
    """The contact tables of a world: the arm's `spheres` with those of the object held (on joint frame
    `link`, the last), and the obstacles' table with the objects of `taken` (the command grasps them)
    marked GRASPED and the one held HELD (contact_geometry.can_touch)."""
    obs = obstacle_table(obstacles)
    for k, ob in enumerate(obstacles):
        if ob.name in taken:
            obs[k, OB_GRASP] = GRASPED
    if held is not None:
        obs[held.index, OB_GRASP] = HELD
        spheres = np.vstack([spheres, carried_spheres(obstacles[held.index], held, link)])
    return spheres, obs


def _axis_points(half_span: float, r: float) -> list[float]:
    """Points from -half_span to half_span at most r apart (at most MAX_SPHERES_PER_AXIS of them)."""
    if half_span <= 1e-12:
        return [0.0]
    count = min(MAX_SPHERES_PER_AXIS, math.ceil(2.0 * half_span / r) + 1)
    return [float(x) for x in np.linspace(-half_span, half_span, count)]


def _grid(axes: Sequence[list[float]]) -> list[tuple[float, ...]]:
    mesh = np.meshgrid(*axes, indexing="ij")
    return [tuple(float(v) for v in point) for point in np.stack([g.ravel() for g in mesh], axis=1)]
