"""The arm's contact geometry and the obstacles' (contact.py uses them): the tables the kernels read and
the distance of a sphere from an obstacle's surface.

The arm touches the world through spheres. An imported arm's come from its URDF collision solids
(collision_spheres.py); a drawn arm has per link a row of spheres along the link's segment (its
central translation, then its final translation) with the link's radius, at most one radius apart,
the first one at the joint as wide as the joint housing. Both end in a thin probe from the last link's
end to the tool point whose last sphere is the tool tip. Each link has a bound sphere around its spheres: a
step looks at a link's spheres only when an obstacle comes near its bound.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit
from simecs.mesh.protocol.environment import OBSTACLE_KINDS, Obstacle
from simecs.mesh.rules.kinematics import rot_rpy

from .collision_spheres import solid_spheres
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .spec import ArmSpec

#: m: the tool is a probe of this radius from the last link's end to the tool point.
TOOL_RADIUS = 0.01

# sphere table columns: the joint frame it hangs on, its centre in that frame, radius, what it is on
SP_LINK, SP_X, SP_Y, SP_Z, SP_R, SP_TOOL = range(6)
NSP = 6
#: SP_TOOL values: on a link, on the tool probe, inside an object the tool carries (grasp.py). The
#: probe and a carried object are what the tool's force sensor feels.
ON_LINK, PROBE, CARRIED = 0.0, 1.0, 2.0
# obstacle table columns: kind (index into OBSTACLE_KINDS), centre, rotation (row-major), dimensions
# (box: half edges; cylinder: radius, half length; sphere: radius), the contact law, grasp state
OB_KIND, OB_P, OB_R, OB_DIM, OB_K, OB_D, OB_MU, OB_GRASP = 0, 1, 4, 13, 16, 17, 18, 19
NOB = 20
#: OB_GRASP values: a plain obstacle; one the run grasps (the last link, the gripper's, passes through
#: it); one the tool holds now (nothing touches it: it is part of the last link).
FREE, GRASPED, HELD = 0.0, 1.0, 2.0
K_BOX, K_CYLINDER, K_SPHERE, K_PLANE = (
    OBSTACLE_KINDS.index(k) for k in ("box", "cylinder", "sphere", "plane")
)
# pair row columns: sphere, obstacle, the friction's viscous cap (N*s/m), c0, then J (3 x n) row-major


def link_axes(spec: ArmSpec, link: int) -> np.ndarray:
    """Rotation from link `link`'s own coordinates (x along the link; a URDF solid's pose is given in
    them) to its joint frame, the frame the sphere table's centres are in."""
    return rot_rpy(spec.links[link].rpy)


def sphere_table(spec: ArmSpec, values: Mapping[str, float]) -> np.ndarray:
    """The arm's contact spheres (rows of SP_*): an imported arm's from its URDF collision solids, a
    drawn arm's at these link lengths and radii; then the tool probe."""
    rows: list[list[float]] = []
    n = len(spec.links)
    if spec.collisions:
        for i in range(n):
            Rr = link_axes(spec, i)
            for solid in spec.collisions:
                if solid.link == i:
                    for *c, r in solid_spheres(solid.geometry, solid.near):
                        rows.append([i, *(Rr @ np.asarray(c)), r, ON_LINK])
    else:
        for i, lk in enumerate(spec.links):
            Rr = link_axes(spec, i)
            r = float(values[f"link{i + 1}.radius"])
            L = float(values[f"link{i + 1}.length"])
            end = np.array([L, 0.0, 0.0])
            final = end + np.asarray(lk.final, dtype=float)
            rows.append([i, 0.0, 0.0, 0.0, 1.25 * r, ON_LINK])  # the joint housing
            for a, b in ((np.zeros(3), end), (end, final)):
                _row_of_spheres(rows, i, Rr, a, b, r, ON_LINK, skip_first=True)
    lk = spec.links[-1]
    Rr = link_axes(spec, n - 1)
    L = float(values[f"link{n}.length"])
    start = np.array([L, 0.0, 0.0]) + np.asarray(lk.final, dtype=float)
    tip = start + np.asarray(spec.tool_translation, dtype=float)
    if np.linalg.norm(tip - start) < 1e-9:
        rows.append([n - 1, *(Rr @ tip), TOOL_RADIUS, PROBE])
    else:
        _row_of_spheres(rows, n - 1, Rr, start, tip, TOOL_RADIUS, PROBE, skip_first=False)
    return np.array(rows, dtype=float)


def _row_of_spheres(
    rows: list[list[float]],
    link: int,
    Rr: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    r: float,
    tool: float,
    skip_first: bool,
) -> None:
    """Spheres of radius r from a to b (link-frame points), at most r apart: the row's envelope dips
    by under 0.14 r between two spheres."""
    length = float(np.linalg.norm(b - a))
    if length < 1e-9 or r <= 0.0:
        return
    count = max(1, math.ceil(length / r))
    for k in range(0 if not skip_first else 1, count + 1):
        c = Rr @ (a + (b - a) * k / count)
        rows.append([link, float(c[0]), float(c[1]), float(c[2]), r, tool])


# link bound columns: a sphere holding every contact sphere of a link (centre in its joint frame, radius)
# and the link's rows in the sphere table (the table lists the links in order)
LB_LINK, LB_X, LB_Y, LB_Z, LB_R, LB_FIRST, LB_END = range(7)


def link_bounds(spheres: np.ndarray) -> np.ndarray:
    """One bound per link of `sphere_table`'s rows: a step looks at a link's spheres only when an
    obstacle comes near its bound."""
    out = []
    for link in np.unique(spheres[:, SP_LINK]).astype(int):
        rows = np.flatnonzero(spheres[:, SP_LINK] == link)
        centres = spheres[rows][:, SP_X : SP_Z + 1]
        c = (centres.min(axis=0) + centres.max(axis=0)) / 2
        r = float(np.max(np.linalg.norm(centres - c, axis=1) + spheres[rows, SP_R]))
        out.append([link, *c, r, rows[0], rows[-1] + 1])
        assert rows[-1] - rows[0] + 1 == rows.size, "a link's spheres follow each other"
    return np.array(out, dtype=float)


def obstacle_table(obstacles: Sequence[Obstacle]) -> np.ndarray:
    """The obstacles as rows of OB_* (what the kernels read)."""
    out = np.zeros((len(obstacles), NOB))
    for k, ob in enumerate(obstacles):
        row = out[k]
        row[OB_KIND] = OBSTACLE_KINDS.index(ob.kind)
        row[OB_P : OB_P + 3] = ob.position
        row[OB_R : OB_R + 9] = rot_rpy(ob.rotation_rpy).reshape(9)
        if ob.kind == "box":
            row[OB_DIM : OB_DIM + 3] = np.asarray(ob.size, dtype=float) / 2
        elif ob.kind == "cylinder":
            row[OB_DIM : OB_DIM + 2] = (ob.radius, ob.length / 2)
        elif ob.kind == "sphere":
            row[OB_DIM] = ob.radius
        row[OB_K], row[OB_D], row[OB_MU] = ob.stiffness, ob.damping, ob.friction
    return out


@njit(cache=_CACHE)
def can_touch(ob, sp, last):
    """Whether sphere row `sp` touches obstacle row `ob` at all, by the obstacle's grasp state: the
    last link (`last`: its joint frame), which holds the gripper, passes through an object the run
    grasps; what the tool carries touches it."""
    state = ob[OB_GRASP]
    if state == FREE:
        return True
    if state == HELD:
        return False
    return sp[SP_LINK] != last or sp[SP_TOOL] == CARRIED


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def surface_contact(ob, c, r, nrm):
    """Penetration depth (> 0: touching) of a sphere (centre c, radius r) into obstacle row `ob`, and
    the outward surface normal at the nearest point into nrm (world)."""
    R = ob[OB_R : OB_R + 9]
    d0 = c[0] - ob[OB_P]
    d1 = c[1] - ob[OB_P + 1]
    d2 = c[2] - ob[OB_P + 2]
    # local coordinates: R^T d
    lx = R[0] * d0 + R[3] * d1 + R[6] * d2
    ly = R[1] * d0 + R[4] * d1 + R[7] * d2
    lz = R[2] * d0 + R[5] * d1 + R[8] * d2
    kind = int(ob[OB_KIND])
    nx, ny, nz = 0.0, 0.0, 1.0
    if kind == K_PLANE:
        depth = r - lz
    elif kind == K_SPHERE:
        dist = math.sqrt(lx * lx + ly * ly + lz * lz)
        depth = r + ob[OB_DIM] - dist
        if dist > 1e-12:
            nx, ny, nz = lx / dist, ly / dist, lz / dist
    elif kind == K_BOX:
        hx, hy, hz = ob[OB_DIM], ob[OB_DIM + 1], ob[OB_DIM + 2]
        if abs(lx) <= hx and abs(ly) <= hy and abs(lz) <= hz:  # centre inside: out by the nearest face
            ex, ey, ez = hx - abs(lx), hy - abs(ly), hz - abs(lz)
            if ex <= ey and ex <= ez:
                depth = r + ex
                nx, ny, nz = math.copysign(1.0, lx), 0.0, 0.0
            elif ey <= ez:
                depth = r + ey
                nx, ny, nz = 0.0, math.copysign(1.0, ly), 0.0
            else:
                depth = r + ez
                nx, ny, nz = 0.0, 0.0, math.copysign(1.0, lz)
        else:
            vx = lx - min(max(lx, -hx), hx)
            vy = ly - min(max(ly, -hy), hy)
            vz = lz - min(max(lz, -hz), hz)
            dist = math.sqrt(vx * vx + vy * vy + vz * vz)
            depth = r - dist
            nx, ny, nz = vx / dist, vy / dist, vz / dist
    else:  # cylinder along local z
        rc, hz = ob[OB_DIM], ob[OB_DIM + 1]
        rho = math.sqrt(lx * lx + ly * ly)
        ux, uy = (lx / rho, ly / rho) if rho > 1e-12 else (1.0, 0.0)
        if rho <= rc and abs(lz) <= hz:
            er, ez = rc - rho, hz - abs(lz)
            if er < ez:
                depth = r + er
                nx, ny, nz = ux, uy, 0.0
            else:
                depth = r + ez
                nx, ny, nz = 0.0, 0.0, math.copysign(1.0, lz)
        else:
            rr = min(rho, rc)
            vx = lx - ux * rr
            vy = ly - uy * rr
            vz = lz - min(max(lz, -hz), hz)
            dist = math.sqrt(vx * vx + vy * vy + vz * vz)
            depth = r - dist
            nx, ny, nz = vx / dist, vy / dist, vz / dist
    nrm[0] = R[0] * nx + R[1] * ny + R[2] * nz
    nrm[1] = R[3] * nx + R[4] * ny + R[5] * nz
    nrm[2] = R[6] * nx + R[7] * ny + R[8] * nz
    return depth


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def sphere_centre(sp, R_all, p_all, c):
    """World centre of sphere row `sp` (or of a link bound's row: the same first columns)."""
    i = int(sp[SP_LINK])
    for a in range(3):
        c[a] = p_all[i, a] + R_all[i, a, 0] * sp[SP_X] + R_all[i, a, 1] * sp[SP_Y] + R_all[i, a, 2] * sp[SP_Z]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def speed_bound(c, r, link, p_all, qd):
    """A bound on the speed of any point within r of c on joint frame `link` (m/s)."""
    v = 0.0
    for j in range(link + 1):
        dx = c[0] - p_all[j, 0]
        dy = c[1] - p_all[j, 1]
        dz = c[2] - p_all[j, 2]
        v += abs(qd[j]) * (math.sqrt(dx * dx + dy * dy + dz * dz) + r)
    return v


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def near_obstacles(bound, obs, R_all, p_all, margin, near, c, nrm):
    """near[o] = obstacle o comes within `margin` of the link bound; returns whether any does (c, nrm:
    3-vectors to work in: it runs for every link at every step, so nothing is allocated here)."""
    sphere_centre(bound, R_all, p_all, c)
    anything = False
    for o in range(obs.shape[0]):
        near[o] = obs[o, OB_GRASP] != HELD and surface_contact(obs[o], c, bound[LB_R], nrm) >= -margin
        anything = anything or near[o]
    return anything
