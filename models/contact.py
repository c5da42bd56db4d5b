"""Contact between the arm and the obstacles (mesh/protocol/environment.py): a compiled penalty model.

The arm touches the world through spheres (contact_geometry.py). An obstacle pushes a sphere out
along the surface normal with `stiffness` x penetration + `damping` x penetration rate (never
pulling) and rubs it with Coulomb friction, regularised to a viscous law below a small sliding speed
(sticking, without a state).
Forces act at the sphere centres; their joint torques are J^T F.

The step is that of the drives (drive_integrator.drive_step): at the step start every sphere near an obstacle
becomes a *pair*, with its centre and its Jacobian; within the step the drive substeps move it with
the predicted joint motion (c = c0 + J (q - q0)), so the contact is integrated at the substep, as stiff
as the gear, and the chain receives the step's mean torque. The substeps follow the stiffest pair
(docs/MODELS.md, "Environment and contact"). Why a penalty model of our own and not Exudyn's
GeneralContact: docs/MODELS.md says, with the figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit
from simecs.mesh.protocol import columns

from .chain_dynamics import chain_frames, chain_state
from .chain_kinematics import spd_inverse
from .contact_geometry import (
    LB_END,
    LB_FIRST,
    LB_LINK,
    LB_R,
    OB_D,
    OB_K,
    OB_MU,
    SP_LINK,
    SP_R,
    SP_TOOL,
    can_touch,
    near_obstacles,
    speed_bound,
    sphere_centre,
    surface_contact,
)
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST

#: m/s: sliding speed below which friction is viscous (the regularised Coulomb law).
SLIP_SPEED = 0.005
#: m: a sphere closer than this (plus twice what it can move in the step) to an obstacle is a pair.
PAIR_MARGIN = 0.002
#: contact rate x substep that the substeps keep (RK4 is stable to about 2.8, on a decay as on an
#: oscillation: 0.5 keeps it accurate too); the friction's viscous rate is capped to it as well.
CONTACT_RATE_STEP = 0.5
#: A step takes at most this many times the model's substeps (contact or friction); beyond, the drives'
#: bound check tells the user (drive.substeps_for).
MAX_SUBSTEP_FACTOR = 64
# pair row columns: sphere, obstacle, the friction's viscous cap (N*s/m), c0, then J (3 x n) row-major
PR_SPHERE, PR_OBST, PR_CAP, PR_C = 0, 1, 2, 3
PR_J = 6


def pair_width(n: int) -> int:
    return PR_J + 3 * n


class ContactTables(NamedTuple):
    """What the kernels read of the contacts (run_world.RunWorld builds it): the tables, then the work
    arrays a step fills."""

    spheres: np.ndarray  # the arm's and a held object's contact spheres (rows per sphere)
    bounds: np.ndarray  # each link's bounding sphere of its spheres (link_bounds)
    obs: np.ndarray  # the obstacles
    pairs: np.ndarray  # work: a step's close sphere-obstacle pairs (rows PR_*)
    caps: np.ndarray  # the contact friction's viscous caps per (sphere, obstacle), set each step
    cw: np.ndarray  # work: 4 x n (rows 2, 3: the stage's contact torques and impulses)
    scratch: np.ndarray  # work: 4 x 3


#: Output columns of the contact model (`contact.*` variables), after the per-link ones.
CONTACT_OUTPUTS = ("depth", "tool_fx", "tool_fy", "tool_fz", "tool_fn")
PER_LINK_OUTPUTS = (
    columns.CONTACT_FORCE,
    columns.CONTACT_OBSTACLE,
    *columns.CONTACT_VECTOR,
    *columns.CONTACT_POINT,
)
# per-link output offsets: force magnitude, obstacle number, force vector, the point it acts at
PL_FORCE, PL_OBST, PL_F, PL_P = 0, 1, 2, 5
NPL, NCO = len(PER_LINK_OUTPUTS), len(CONTACT_OUTPUTS)


@njit(cache=_CACHE)
def output_count(n: int) -> int:
    return NPL * n + NCO


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
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
def contact_substeps(rate, h, nsub):
    """RK4 substeps over a step of h: at least nsub, more while the stiffest pair's rate (1/s) needs
    them (rate x substep <= CONTACT_RATE_STEP), at most MAX_SUBSTEP_FACTOR x nsub."""
    return max(nsub, min(int(math.ceil(rate * h / CONTACT_RATE_STEP)), nsub * MAX_SUBSTEP_FACTOR))


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def find_pairs(spheres, bounds, obs, R_all, p_all, qd, Minv, h, pairs, scratch):
    """The sphere-obstacle pairs that may touch within the step from now: (count, the stiffest pair's
    rate in 1/s). Each row gets the sphere's centre and Jacobian; PR_CAP holds 1 / m_eff for now
    (m_eff: the lightest mass the sphere can show, from J M^-1 J^T). Links whose bound no obstacle
    comes near are passed over whole; the spheres of the others take their bound's margin (what any
    point of the bound can move in two steps). scratch: 4 x 3 work rows (it runs at every step)."""
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
        for s in range(int(bound[LB_FIRST]), int(bound[LB_END])):  # the bound's margin holds for each
            sp = spheres[s]
            sphere_centre(sp, R_all, p_all, c)
            jac_done = False
            first = 0
            inv_m = 0.0
            for o in range(obs.shape[0]):
                if (
                    not near[o]
                    or not can_touch(obs[o], sp, n - 1)
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
def tool_force_at(spheres, bounds, obs, caps, R_all, p_all, qd, F):
    """The contact force on the tool now (N, world) into F: what a force sensor at the tool reads.
    Only the last link's spheres are looked at (the tool's are among them). R_all, p_all: the joint
    frames now."""
    n = qd.shape[0]
    touch = np.empty(output_count(n))
    contact_outputs(spheres, bounds[bounds.shape[0] - 1 :], obs, caps, R_all, p_all, qd, touch)
    for a in range(3):
        F[a] = touch[NPL * n + 1 + a]


# ---- before the run: does the planned path touch? ------------------------------------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def first_touch(spheres, obs, pre_R, pre_p, qs, tool_free, found):
    """The first row of qs (joint positions) at which a sphere touches an obstacle, or -1; found =
    (link index, obstacle index, depth m, what the sphere is on: SP_TOOL) of the deepest touch there.
    The tool's spheres may touch in the rows where tool_free is set (it pushes there on purpose)."""
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
                if not can_touch(obs[o], spheres[s], n - 1):
                    continue
                depth = surface_contact(obs[o], c, spheres[s, SP_R], nrm)
                if depth > deepest:
                    deepest = depth
                    found[0] = spheres[s, SP_LINK]
                    found[1] = o
                    found[2] = depth
                    found[3] = spheres[s, SP_TOOL]
        if deepest > 0.0:
            return k
    return -1


# ---- the result rows: the contact state at a sample, from the chain state -----------------------------
@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def contact_outputs(spheres, bounds, obs, caps, R_all, p_all, qd, out):
    """out = per link (PER_LINK_OUTPUTS: force N, obstacle number 1.. or 0, the force vector N and the
    point it acts at m, world), then depth m (the deepest), the tool's force (x, y, z) and its normal
    part. The point is the mean of the link's contact points on the obstacles' surfaces, weighted by
    their normal forces. Evaluated at the state itself; `caps` (spheres x obstacles) holds the friction
    caps of the last step (0: none yet, the pure Coulomb law)."""
    n = qd.shape[0]
    for k in range(out.shape[0]):
        out[k] = 0.0
    sums = np.zeros((2, n))
    weight, best = sums[0], sums[1]
    near = np.empty(obs.shape[0], dtype=np.bool_)
    work = np.empty((4, 3))  # c, v, nrm, F (a row costs one allocation per call)
    for b in range(bounds.shape[0]):
        if near_obstacles(bounds[b], obs, R_all, p_all, 0.0, near, work[0], work[2]):
            _link_outputs(spheres, bounds[b], obs, caps, R_all, p_all, qd, near, weight, best, work, out)
    for i in range(n):
        row = NPL * i
        out[row + PL_FORCE] = math.sqrt(
            out[row + PL_F] ** 2 + out[row + PL_F + 1] ** 2 + out[row + PL_F + 2] ** 2
        )
        if weight[i] > 0.0:
            for a in range(3):
                out[row + PL_P + a] /= weight[i]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _link_outputs(spheres, bound, obs, caps, R_all, p_all, qd, near, weight, best, work, out):
    """contact_outputs' sums over one link's spheres (the points still multiplied by their weights);
    work: 4 x 3 rows to work in."""
    c, v, nrm, F = work[0], work[1], work[2], work[3]
    base = NPL * qd.shape[0]
    for s in range(int(bound[LB_FIRST]), int(bound[LB_END])):
        sp = spheres[s]
        sphere_centre(sp, R_all, p_all, c)
        link = int(sp[SP_LINK])
        for o in range(obs.shape[0]):
            if not near[o] or not can_touch(obs[o], sp, qd.shape[0] - 1):
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
            row = NPL * link
            for a in range(3):
                out[row + PL_F + a] += F[a]
                out[row + PL_P + a] += fn * (c[a] - nrm[a] * (sp[SP_R] - depth))  # on the surface
            weight[link] += fn
            if fn > best[link]:
                best[link] = fn
                out[row + PL_OBST] = o + 1
            out[base] = max(out[base], depth)
            if sp[SP_TOOL] > 0.5:
                for a in range(3):
                    out[base + 1 + a] += F[a]
                out[base + 4] += fn


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def contact_prestep(chain, gravity, tables, q, qd, h, nsub, tau_out):
    """The step's mean contact torque into tau_out when the drives are off (nothing else acts on the
    joints): the load side predicted over RK4 substeps as in drive_integrator.drive_step. `chain`:
    mechanics.ChainArrays; `tables`: ContactTables."""
    spheres, bounds, obs, pairs, caps, _cw, scratch = tables
    n = q.shape[0]
    R_all, p_all, M, bias = chain_state(chain, gravity, q, qd)
    Minv = spd_inverse(M)
    for j in range(n):
        tau_out[j] = 0.0
    npairs, rate = find_pairs(spheres, bounds, obs, R_all, p_all, qd, Minv, h, pairs, scratch)
    if npairs == 0:
        return
    nsub = contact_substeps(rate, h, nsub)
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
        self._force = [index[columns.contact_column(i + 1, columns.CONTACT_FORCE)] for i in range(self.n)]
        self._obstacle = [
            index[columns.contact_column(i + 1, columns.CONTACT_OBSTACLE)] for i in range(self.n)
        ]

    def scan(self, rows: np.ndarray) -> list[str]:
        if not any(self._touching.values()) and not (rows[:, self._force] > NOTICE_FORCE).any():
            return []  # nothing touched in the chunk (most chunks): one look, not a loop per row
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
