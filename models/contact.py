"""Contact between the arm and the obstacles (mesh/environment.py): a compiled penalty model.

The arm touches the world through spheres: per link a row of spheres along the link's segment (its
central translation, then its final translation) with the link's radius, the first one at the joint
as wide as the joint housing, and a thin probe from the last link's end to the tool point whose last
sphere is the tool tip. An obstacle pushes a sphere out along the surface normal with
`stiffness` x penetration + `damping` x penetration rate (never pulling) and rubs it with Coulomb
friction, regularised to a viscous law below a small sliding speed (sticking, without a state).
Forces act at the sphere centres; their joint torques are J^T F.

The step is that of the drives (drive.drive_prestep): at the step start every sphere near an obstacle
becomes a *pair*, with its centre and its Jacobian; within the step the drive substeps move it with
the predicted joint motion (c = c0 + J (q - q0)), so the contact is integrated at the substep, as stiff
as the gear, and the chain receives the step's mean torque. The substeps follow the stiffest pair
(docs/MODELS.md, "Environment and contact"). Why a penalty model of our own and not Exudyn's
GeneralContact: docs/MODELS.md says, with the figures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from simecs.mesh.environment import OBSTACLE_KINDS, Obstacle
from simecs.mesh.kinematics import rot_rpy

from .chain_dynamics import bias_forces_at, chain_frames, mass_matrix_at
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .spec import ArmSpec

#: m: the tool is a probe of this radius from the last link's end to the tool point.
TOOL_RADIUS = 0.01
#: m/s: sliding speed below which friction is viscous (the regularised Coulomb law).
SLIP_SPEED = 0.005
#: m: a sphere closer than this (plus twice what it can move in the step) to an obstacle is a pair.
PAIR_MARGIN = 0.002
#: contact rate x substep that the substeps keep (RK4 is stable to about 2.8, on a decay as on an
#: oscillation: 0.5 keeps it accurate too); the friction's viscous rate is capped to it as well.
CONTACT_RATE_STEP = 0.5

# sphere table columns: the joint frame it hangs on, its centre in that frame, radius, on the tool
SP_LINK, SP_X, SP_Y, SP_Z, SP_R, SP_TOOL = range(6)
NSP = 6
# obstacle table columns: kind (index into OBSTACLE_KINDS), centre, rotation (row-major), dimensions
# (box: half edges; cylinder: radius, half length; sphere: radius), the contact law
OB_KIND, OB_P, OB_R, OB_DIM, OB_K, OB_D, OB_MU = 0, 1, 4, 13, 16, 17, 18
NOB = 19
K_BOX, K_CYLINDER, K_SPHERE, K_PLANE = (
    OBSTACLE_KINDS.index(k) for k in ("box", "cylinder", "sphere", "plane")
)
# pair row columns: sphere, obstacle, the friction's viscous cap (N*s/m), c0, then J (3 x n) row-major
PR_SPHERE, PR_OBST, PR_CAP, PR_C = 0, 1, 2, 3
PR_J = 6


def pair_width(n: int) -> int:
    return PR_J + 3 * n


#: Output columns of the contact model (`contact.*` variables), after the per-link ones.
CONTACT_OUTPUTS = ("depth", "tool_fx", "tool_fy", "tool_fz", "tool_fn")
PER_LINK_OUTPUTS = ("force", "obstacle")


NPL, NCO = len(PER_LINK_OUTPUTS), len(CONTACT_OUTPUTS)


@njit(cache=_CACHE)
def output_count(n: int) -> int:
    return NPL * n + NCO


def sphere_table(spec: ArmSpec, values: Mapping[str, float]) -> np.ndarray:
    """The arm's contact spheres at these link lengths and radii (rows of SP_*)."""
    rows: list[list[float]] = []
    n = len(spec.links)
    for i, lk in enumerate(spec.links):
        Rr = rot_rpy(lk.rpy)
        r = float(values[f"link{i + 1}.radius"])
        L = float(values[f"link{i + 1}.length"])
        end = np.array([L, 0.0, 0.0])
        final = end + np.asarray(lk.final, dtype=float)
        rows.append([i, 0.0, 0.0, 0.0, 1.25 * r, 0.0])  # the joint housing
        for a, b in ((np.zeros(3), end), (end, final)):
            _row_of_spheres(rows, i, Rr, a, b, r, 0.0, skip_first=True)
    lk = spec.links[-1]
    Rr = rot_rpy(lk.rpy)
    L = float(values[f"link{n}.length"])
    start = np.array([L, 0.0, 0.0]) + np.asarray(lk.final, dtype=float)
    tip = start + np.asarray(spec.tool_translation, dtype=float)
    if np.linalg.norm(tip - start) < 1e-9:
        rows.append([n - 1, *(Rr @ tip), TOOL_RADIUS, 1.0])
    else:
        _row_of_spheres(rows, n - 1, Rr, start, tip, TOOL_RADIUS, 1.0, skip_first=False)
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


# ---- geometry -----------------------------------------------------------------------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
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
        near[o] = surface_contact(obs[o], c, bound[LB_R], nrm) >= -margin
        anything = anything or near[o]
    return anything


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def contact_force(ob, depth, nrm, v, cap, F):
    """The force on a sphere touching obstacle `ob` (depth > 0) moving at v: normal penalty with
    damping, never pulling, and friction against the sliding velocity, viscous up to `cap` N*s/m and
    at most friction x normal force. Returns the normal force."""
    vn = v[0] * nrm[0] + v[1] * nrm[1] + v[2] * nrm[2]
    fn = ob[OB_K] * depth - ob[OB_D] * vn
    if fn < 0.0:
        fn = 0.0
    tx = v[0] - vn * nrm[0]
    ty = v[1] - vn * nrm[1]
    tz = v[2] - vn * nrm[2]
    vt = math.sqrt(tx * tx + ty * ty + tz * tz)
    fmax = ob[OB_MU] * fn
    ct = min(fmax / SLIP_SPEED, cap)
    if ct * vt > fmax:
        ct = fmax / vt
    F[0] = fn * nrm[0] - ct * tx
    F[1] = fn * nrm[1] - ct * ty
    F[2] = fn * nrm[2] - ct * tz
    return fn


# ---- the step: pairs at its start, torques at every substep -----------------------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def find_pairs(spheres, bounds, obs, R_all, p_all, qd, Minv, h, pairs, scratch):
    """The sphere-obstacle pairs that may touch within the step from now: (count, the stiffest pair's
    rate in 1/s). Each row gets the sphere's centre and Jacobian; PR_CAP holds 1 / m_eff for now
    (m_eff: the lightest mass the sphere can show, from J M^-1 J^T). Links whose bound no obstacle
    comes near are passed over whole. scratch: 4 x 3 work rows (it runs at every step)."""
    n = qd.shape[0]
    count = 0
    rate = 0.0
    c = scratch[0]
    cb = scratch[1]
    nrm = scratch[2]
    near = np.empty(obs.shape[0], dtype=np.bool_)
    for b in range(bounds.shape[0]):
        bound = bounds[b]
        link = int(bound[LB_LINK])
        sphere_centre(bound, R_all, p_all, cb)
        margin = PAIR_MARGIN + 2.0 * h * speed_bound(cb, bound[LB_R], link, p_all, qd)
        if not near_obstacles(bound, obs, R_all, p_all, margin, near, cb, nrm):
            continue
        for s in range(int(bound[LB_FIRST]), int(bound[LB_END])):
            sp = spheres[s]
            sphere_centre(sp, R_all, p_all, c)
            margin = PAIR_MARGIN + 2.0 * h * speed_bound(c, 0.0, link, p_all, qd)
            jac_done = False
            first = 0
            inv_m = 0.0
            for o in range(obs.shape[0]):
                if (
                    not near[o]
                    or surface_contact(obs[o], c, sp[SP_R], nrm) < -margin
                    or count >= pairs.shape[0]
                ):
                    continue
                row = pairs[count]
                row[PR_SPHERE] = s
                row[PR_OBST] = o
                for a in range(3):
                    row[PR_C + a] = c[a]
                if not jac_done:
                    for a in range(3 * n):
                        row[PR_J + a] = 0.0
                    for j in range(link + 1):
                        z0, z1, z2 = R_all[j, 0, 2], R_all[j, 1, 2], R_all[j, 2, 2]
                        r0 = c[0] - p_all[j, 0]
                        r1 = c[1] - p_all[j, 1]
                        r2 = c[2] - p_all[j, 2]
                        row[PR_J + j] = z1 * r2 - z2 * r1
                        row[PR_J + n + j] = z2 * r0 - z0 * r2
                        row[PR_J + 2 * n + j] = z0 * r1 - z1 * r0
                    inv_m = 0.0  # trace of J M^-1 J^T: at least the largest 1 / m_eff
                    for a in range(3):
                        for j in range(n):
                            acc = 0.0
                            for k in range(n):
                                acc += Minv[j, k] * row[PR_J + a * n + k]
                            inv_m += row[PR_J + a * n + j] * acc
                    first = count
                    jac_done = True
                else:  # the same sphere near a second obstacle: the same Jacobian
                    for a in range(3 * n):
                        row[PR_J + a] = pairs[first, PR_J + a]
                row[PR_CAP] = inv_m
                ob = obs[o]
                rate = max(rate, math.sqrt(ob[OB_K] * inv_m), ob[OB_D] * inv_m)
                count += 1
    return count, rate


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def set_caps(pairs, count, hs, caps):
    """The friction's viscous cap of each pair: its rate x substep stays at CONTACT_RATE_STEP; kept in
    caps[sphere, obstacle] for the result rows."""
    for p in range(count):
        inv_m = pairs[p, PR_CAP]
        cap = CONTACT_RATE_STEP / (hs * inv_m) if inv_m > 0.0 else 1e300
        pairs[p, PR_CAP] = cap
        caps[int(pairs[p, PR_SPHERE]), int(pairs[p, PR_OBST])] = cap


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def pair_torques(pairs, count, spheres, obs, q0, ql, qdl, tc, scratch):
    """tc = sum over pairs of J^T F, each sphere moved with the joints from q0 to ql (speeds qdl).
    `scratch` (4 x 3): work rows (called at every RK4 stage: no allocation here)."""
    n = ql.shape[0]
    for j in range(n):
        tc[j] = 0.0
    c = scratch[0]
    v = scratch[1]
    nrm = scratch[2]
    F = scratch[3]
    for p in range(count):
        row = pairs[p]
        for a in range(3):
            pos = row[PR_C + a]
            vel = 0.0
            for j in range(n):
                Jaj = row[PR_J + a * n + j]
                pos += Jaj * (ql[j] - q0[j])
                vel += Jaj * qdl[j]
            c[a] = pos
            v[a] = vel
        ob = obs[int(row[PR_OBST])]
        depth = surface_contact(ob, c, spheres[int(row[PR_SPHERE]), SP_R], nrm)
        if depth <= 0.0:
            continue
        contact_force(ob, depth, nrm, v, row[PR_CAP], F)
        for j in range(n):
            tc[j] += row[PR_J + j] * F[0] + row[PR_J + n + j] * F[1] + row[PR_J + 2 * n + j] * F[2]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def tool_force(spheres, bounds, obs, caps, pre_R, pre_p, q, qd, F):
    """The contact force on the tool now (N, world) into F: what a force sensor at the tool reads."""
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    chain_frames(pre_R, pre_p, q, R_all, p_all)
    touch = np.empty(output_count(n))
    contact_outputs(spheres, bounds, obs, caps, R_all, p_all, qd, touch)
    for a in range(3):
        F[a] = touch[NPL * n + 1 + a]


# ---- before the run: does the planned path touch? ------------------------------------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def first_touch(spheres, obs, pre_R, pre_p, qs, tool_free, found):
    """The first row of qs (joint positions) at which a sphere touches an obstacle, or -1; found =
    (link index, obstacle index, depth m) of the deepest touch in that row. The tool's spheres may
    touch in the rows where tool_free is set (it pushes there on purpose)."""
    n = qs.shape[1]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    c = np.empty(3)
    nrm = np.empty(3)
    for k in range(qs.shape[0]):
        chain_frames(pre_R, pre_p, qs[k], R_all, p_all)
        deepest = 0.0
        for s in range(spheres.shape[0]):
            if tool_free[k] and spheres[s, SP_TOOL] > 0.5:
                continue
            sphere_centre(spheres[s], R_all, p_all, c)
            for o in range(obs.shape[0]):
                depth = surface_contact(obs[o], c, spheres[s, SP_R], nrm)
                if depth > deepest:
                    deepest = depth
                    found[0] = spheres[s, SP_LINK]
                    found[1] = o
                    found[2] = depth
        if deepest > 0.0:
            return k
    return -1


# ---- the result rows: the contact state at a sample, from the chain state -----------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def contact_outputs(spheres, bounds, obs, caps, R_all, p_all, qd, out):
    """out = per link (force N, obstacle number 1.. or 0), then depth m (the deepest), the tool's force
    (x, y, z) and its normal part. Evaluated at the state itself; `caps` (spheres x obstacles) holds
    the friction caps of the last step (0: none yet, the pure Coulomb law)."""
    n = qd.shape[0]
    for k in range(out.shape[0]):
        out[k] = 0.0
    F_link = np.zeros((n, 3))
    best = np.zeros(n)
    near = np.empty(obs.shape[0], dtype=np.bool_)
    c = np.empty(3)
    nrm = np.empty(3)
    for b in range(bounds.shape[0]):
        if near_obstacles(bounds[b], obs, R_all, p_all, 0.0, near, c, nrm):
            _link_outputs(spheres, bounds[b], obs, caps, R_all, p_all, qd, near, F_link, best, out)
    for i in range(n):
        out[2 * i] = math.sqrt(F_link[i, 0] ** 2 + F_link[i, 1] ** 2 + F_link[i, 2] ** 2)


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _link_outputs(spheres, bound, obs, caps, R_all, p_all, qd, near, F_link, best, out):
    """contact_outputs' sums over one link's spheres."""
    c = np.empty(3)
    v = np.empty(3)
    nrm = np.empty(3)
    F = np.empty(3)
    base = NPL * qd.shape[0]
    for s in range(int(bound[LB_FIRST]), int(bound[LB_END])):
        sp = spheres[s]
        sphere_centre(sp, R_all, p_all, c)
        link = int(sp[SP_LINK])
        for o in range(obs.shape[0]):
            if not near[o]:
                continue
            depth = surface_contact(obs[o], c, sp[SP_R], nrm)
            if depth <= 0.0:
                continue
            for a in range(3):
                v[a] = 0.0
            for j in range(link + 1):
                z0, z1, z2 = R_all[j, 0, 2], R_all[j, 1, 2], R_all[j, 2, 2]
                r0 = c[0] - p_all[j, 0]
                r1 = c[1] - p_all[j, 1]
                r2 = c[2] - p_all[j, 2]
                v[0] += (z1 * r2 - z2 * r1) * qd[j]
                v[1] += (z2 * r0 - z0 * r2) * qd[j]
                v[2] += (z0 * r1 - z1 * r0) * qd[j]
            cap = caps[s, o] if caps[s, o] > 0.0 else 1e300
            fn = contact_force(obs[o], depth, nrm, v, cap, F)
            for a in range(3):
                F_link[link, a] += F[a]
            if fn > best[link]:
                best[link] = fn
                out[2 * link + 1] = o + 1
            out[base] = max(out[base], depth)
            if sp[SP_TOOL] > 0.5:
                for a in range(3):
                    out[base + 1 + a] += F[a]
                out[base + 4] += fn


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def contact_prestep(pre_R, pre_p, masses, coms, inertias, gravity, tables, q, qd, h, nsub, tau_out):
    """The step's mean contact torque into tau_out when the drives are off (nothing else acts on the
    joints): the load side predicted over RK4 substeps as in drive.drive_prestep. `tables`: as there."""
    spheres, bounds, obs, pairs, caps, _cw, scratch = tables
    n = q.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    chain_frames(pre_R, pre_p, q, R_all, p_all)
    M = np.empty((n, n))
    mass_matrix_at(R_all, p_all, masses, coms, inertias, M)
    Minv = np.linalg.inv(M)
    for j in range(n):
        tau_out[j] = 0.0
    npairs, rate = find_pairs(spheres, bounds, obs, R_all, p_all, qd, Minv, h, pairs, scratch)
    if npairs == 0:
        return
    bias = np.empty(n)
    bias_forces_at(R_all, p_all, masses, coms, inertias, gravity, qd, bias)
    nsub = max(nsub, min(int(math.ceil(rate * h / CONTACT_RATE_STEP)), 64 * nsub))
    hs = h / nsub
    set_caps(pairs, npairs, hs, caps)
    x = np.empty((2, n))  # q, qd
    xt = np.empty((2, n))
    k = np.empty((4, 2, n))
    tc = np.empty(n)
    for j in range(n):
        x[0, j] = q[j]
        x[1, j] = qd[j]
    weights = (1.0, 2.0, 2.0, 1.0)
    for _s in range(nsub):
        for stage in range(4):
            if stage == 0:
                for j in range(n):
                    xt[0, j] = x[0, j]
                    xt[1, j] = x[1, j]
            else:
                f = 1.0 if stage == 3 else 0.5
                for j in range(n):
                    xt[0, j] = x[0, j] + f * hs * k[stage - 1, 0, j]
                    xt[1, j] = x[1, j] + f * hs * k[stage - 1, 1, j]
            pair_torques(pairs, npairs, spheres, obs, q, xt[0], xt[1], tc, scratch)
            for j in range(n):
                acc = 0.0
                for i in range(n):
                    acc += Minv[j, i] * (tc[i] - bias[i])
                k[stage, 0, j] = xt[1, j]
                k[stage, 1, j] = acc
                tau_out[j] += weights[stage] * hs / 6.0 * tc[j] / h
        for j in range(n):
            for a in range(2):
                x[a, j] += hs / 6.0 * (k[0, a, j] + 2.0 * k[1, a, j] + 2.0 * k[2, a, j] + k[3, a, j])


# ---- notices ------------------------------------------------------------------------------------------
#: N: a link touching with more than this starts a contact the user is told about.
NOTICE_FORCE = 1.0


@dataclass
class ContactLog:
    """Turns the result rows into notices: "link5 hit obstacle box1 at t = 2.310 s, 140 N" once per
    contact, told at the end of the chunk it started in with the largest force up to there."""

    columns: Sequence[str]
    obstacle_names: Sequence[str]
    n: int
    _touching: dict[int, bool] = field(default_factory=dict)

    def __post_init__(self) -> None:
        index = {c: k for k, c in enumerate(self.columns)}
        self._force = [index[f"contact.link{i + 1}.force"] for i in range(self.n)]
        self._obstacle = [index[f"contact.link{i + 1}.obstacle"] for i in range(self.n)]

    def scan(self, rows: np.ndarray) -> list[str]:
        out = []
        for i in range(self.n):
            f = rows[:, self._force[i]]
            touching = self._touching.get(i, False)
            start = -1
            for k in range(rows.shape[0]):  # rows of one chunk: a few hundred at most
                if not touching and f[k] > NOTICE_FORCE:
                    touching, start = True, k
                elif touching and f[k] <= 0.0:
                    touching = False
                    if start >= 0:
                        out.append(self._text(i, rows, start, k))
                        start = -1
            if start >= 0:
                out.append(self._text(i, rows, start, rows.shape[0]))
            self._touching[i] = touching
        return out

    def _text(self, i: int, rows: np.ndarray, start: int, end: int) -> str:
        number = int(rows[start, self._obstacle[i]])
        name = self.obstacle_names[number - 1] if 1 <= number <= len(self.obstacle_names) else "?"
        peak = float(np.max(rows[start:end, self._force[i]]))
        return f"link{i + 1} hit obstacle {name} at t = {rows[start, 0]:.3f} s, {peak:.0f} N"
