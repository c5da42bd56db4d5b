"""The arm against itself: which of its links may touch each other, and where a motion makes two touch.

The links' contact spheres (contact_geometry.sphere_table, the tool probe included) and an imported
arm's base solids are checked pair by pair of links. As URDF tools do (MoveIt's allowed-collision
matrix), some pairs are never checked: neighbours in the chain (a joint holds them together, the base
counting as link 0), pairs that touch at the model's home pose, and pairs that touch at every one of
SAMPLE_POSES random poses (their spheres overlap by construction). The planner refuses a path whose
arm would touch itself (settings.collisions `refuse`); a run tells its user when two links touched.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .chain_dynamics import chain_frames
from .collision_spheres import solid_spheres
from .contact_geometry import SP_LINK, SP_R, SP_X
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .spec import ArmSpec

#: Random poses (within the joint ranges) over which a pair that always touches is found.
SAMPLE_POSES = 100
#: m: two links closer than this do not count as touching (the spheres hold their solids with room).
TOUCH_DEPTH = 0.001

# table columns: the group (0 the base, i + 1 link i), centre (the link's joint frame; the base: world),
# radius
ST_GROUP, ST_X, ST_R = 0, 1, 4


def link_name(group: int) -> str:
    return "the base" if group == 0 else f"link{group}"


def self_table(spec: ArmSpec, spheres: np.ndarray) -> np.ndarray:
    """The rows the kernels read: the base's solids (world), then the links' spheres as given (the
    tool probe included, a carried object's left out)."""
    rows: list[list[float]] = []
    for solid in spec.collisions:
        if solid.link < 0:
            rows.extend([0.0, *sphere] for sphere in solid_spheres(solid.geometry, solid.near))
    for s in spheres:
        rows.append([s[SP_LINK] + 1.0, *s[SP_X : SP_R + 1]])
    return np.array(rows, dtype=float).reshape(-1, 5)


def group_bounds(table: np.ndarray, groups: int) -> np.ndarray:
    """Per group (rows of GB_*): a sphere around its spheres (centre in the group's frame) and its rows
    in the table (the table lists the groups in order); a group without spheres has end == first."""
    out = np.zeros((groups, 6))
    for g in range(groups):
        rows = np.flatnonzero(table[:, ST_GROUP] == g)
        if rows.size == 0:
            continue
        centres = table[rows, ST_X : ST_X + 3]
        c = (centres.min(axis=0) + centres.max(axis=0)) / 2
        r = float(np.max(np.linalg.norm(centres - c, axis=1) + table[rows, ST_R]))
        out[g] = [*c, r, rows[0], rows[-1] + 1]
    return out


# group bound columns: centre, radius, the group's rows in the table
GB_X, GB_R, GB_FIRST, GB_END = 0, 3, 4, 5


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def _place(g, x, R_all, p_all, out):
    """out = the world point of x (3 values) given in group g's frame (the base's is the world)."""
    if g == 0:
        for a in range(3):
            out[a] = x[a]
    else:
        i = g - 1
        for a in range(3):
            out[a] = p_all[i, a] + R_all[i, a, 0] * x[0] + R_all[i, a, 1] * x[1] + R_all[i, a, 2] * x[2]


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def _touching(table, bounds, checked, R_all, p_all, work, placed, depths):
    """depths[g, h] = the deepest overlap (m) of checked groups g and h (0 if none); returns the
    deepest. Only groups whose bounds overlap are looked at sphere by sphere. `work`: a (table rows +
    groups) x 3 array; `placed`: one flag per table row."""
    groups = bounds.shape[0]
    deepest = 0.0
    for g in range(groups):
        for h in range(groups):
            depths[g, h] = 0.0
    m = table.shape[0]
    for g in range(groups):
        _place(g, bounds[g, GB_X : GB_X + 3], R_all, p_all, work[m + g])
    for s in range(m):
        placed[s] = False
    for g in range(groups):
        for h in range(g + 1, groups):
            if not checked[g, h]:
                continue
            dx = work[m + g, 0] - work[m + h, 0]
            dy = work[m + g, 1] - work[m + h, 1]
            dz = work[m + g, 2] - work[m + h, 2]
            if math.sqrt(dx * dx + dy * dy + dz * dz) >= bounds[g, GB_R] + bounds[h, GB_R]:
                continue
            for s in range(int(bounds[g, GB_FIRST]), int(bounds[g, GB_END])):
                if not placed[s]:
                    _place(g, table[s, ST_X : ST_X + 3], R_all, p_all, work[s])
                    placed[s] = True
                for t in range(int(bounds[h, GB_FIRST]), int(bounds[h, GB_END])):
                    if not placed[t]:
                        _place(h, table[t, ST_X : ST_X + 3], R_all, p_all, work[t])
                        placed[t] = True
                    dx = work[s, 0] - work[t, 0]
                    dy = work[s, 1] - work[t, 1]
                    dz = work[s, 2] - work[t, 2]
                    depth = table[s, ST_R] + table[t, ST_R] - math.sqrt(dx * dx + dy * dy + dz * dz)
                    if depth > depths[g, h]:
                        depths[g, h] = depth
                        depths[h, g] = depth
                        if depth > deepest:
                            deepest = depth
    return deepest


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def self_touches(table, bounds, checked, pre_R, pre_p, qs, limit, stop_at_first, found, counts):
    """Per row of qs, found[k] = (group, group, depth m) of its deepest overlap above `limit` (depth 0:
    none); counts[g, h] += the rows where g and h overlap. Stops after the first touching row when
    `stop_at_first`; returns the first touching row, or -1."""
    n = qs.shape[1]
    groups = bounds.shape[0]
    R_all = np.empty((n, 3, 3))
    p_all = np.empty((n, 3))
    work = np.empty((table.shape[0] + groups, 3))
    placed = np.empty(table.shape[0], dtype=np.bool_)
    depths = np.empty((groups, groups))
    first = -1
    for k in range(qs.shape[0]):
        found[k, 2] = 0.0
        chain_frames(pre_R, pre_p, qs[k], R_all, p_all)
        if _touching(table, bounds, checked, R_all, p_all, work, placed, depths) <= limit:
            continue
        best = 0.0
        for g in range(groups):
            for h in range(g + 1, groups):
                if depths[g, h] > limit:
                    counts[g, h] += 1
                    if depths[g, h] > best:
                        best = depths[g, h]
                        found[k, 0], found[k, 1], found[k, 2] = g, h, best
        if first < 0:
            first = k
            if stop_at_first:
                return first
    return first


@dataclass
class SelfCollision:
    """One arm's self-collision check at one set of parameter values."""

    table: np.ndarray
    bounds: np.ndarray
    checked: np.ndarray  # (n + 1) x (n + 1) bool: the pairs of groups looked at
    pre_R: np.ndarray
    pre_p: np.ndarray
    skipped: list[tuple[int, int, str]] = field(default_factory=list)  # (g, h, why) of pairs not checked

    @classmethod
    def of(
        cls,
        spec: ArmSpec,
        spheres: np.ndarray,
        pre_R: np.ndarray,
        pre_p: np.ndarray,
        home: Sequence[float],
    ) -> SelfCollision:
        n = len(spec.links)
        table = self_table(spec, spheres)
        bounds = group_bounds(table, n + 1)
        present = bounds[:, GB_END] > bounds[:, GB_FIRST]
        checked = np.outer(present, present)
        skipped: list[tuple[int, int, str]] = []
        for g in range(n):
            checked[g, g] = False
            checked[g, g + 1] = checked[g + 1, g] = False
            if present[g] and present[g + 1]:
                skipped.append((g, g + 1, "neighbours"))
        checked[n, n] = False
        probe = cls(table, bounds, checked, pre_R, pre_p)
        at_home = probe.counts(np.asarray(home, dtype=float)[None, :])
        lo = np.array([lk.joint_min for lk in spec.links])
        hi = np.array([lk.joint_max for lk in spec.links])
        always = probe.counts(lo + (hi - lo) * np.random.default_rng(0).random((SAMPLE_POSES, n)))
        for g in range(n + 1):
            for h in range(g + 1, n + 1):
                why = "touching at the home pose" if at_home[g, h] else ""
                if not why and always[g, h] == SAMPLE_POSES:
                    why = f"touching at all {SAMPLE_POSES} sampled poses"
                if why:
                    checked[g, h] = checked[h, g] = False
                    skipped.append((g, h, why))
        return cls(table, bounds, checked, pre_R, pre_p, skipped)

    def counts(self, qs: np.ndarray) -> np.ndarray:
        """counts[g, h] (g < h): the rows of qs at which groups g and h touch."""
        groups = self.bounds.shape[0]
        out = np.zeros((groups, groups), dtype=np.int64)
        self._run(qs, False, out)
        return out

    def touches(self, qs: np.ndarray) -> np.ndarray:
        """Per row of qs (group, group, depth m) of its deepest touch; depth 0: the arm is clear."""
        groups = self.bounds.shape[0]
        return self._run(qs, False, np.zeros((groups, groups), dtype=np.int64))[1]

    def first_touch(self, qs: np.ndarray) -> tuple[int, str, str, float] | None:
        """(row, link, link, depth m) of the first row of qs at which the arm touches itself."""
        groups = self.bounds.shape[0]
        k, found = self._run(qs, True, np.zeros((groups, groups), dtype=np.int64))
        if k < 0:
            return None
        g, h, depth = found[k]
        return k, link_name(int(g)), link_name(int(h)), float(depth)

    def _run(self, qs: np.ndarray, stop_at_first: bool, counts: np.ndarray) -> tuple[int, np.ndarray]:
        qs = np.ascontiguousarray(qs, dtype=float)
        found = np.zeros((qs.shape[0], 3))
        k = self_touches(
            self.table, self.bounds, self.checked, self.pre_R, self.pre_p, qs, TOUCH_DEPTH,
            stop_at_first, found, counts,
        )  # fmt: skip
        return int(k), found


#: s: a run's rows are looked at this often for links touching each other.
SCAN_PERIOD = 0.005


@dataclass
class SelfContactLog:
    """Turns a run's rows into notices: "link2 touched link6 at t = 1.234 s (8.0 mm deep)" once per
    contact (a pair told again only after it came apart). The first row of each SCAN_PERIOD is looked
    at."""

    check: SelfCollision
    q_columns: Sequence[int]
    _touching: set[tuple[int, int]] = field(default_factory=set)
    _last_slot: float = -math.inf

    def scan(self, rows: np.ndarray) -> list[str]:
        slots = np.floor(rows[:, 0] / SCAN_PERIOD)
        if slots.size == 0:
            return []
        first = np.flatnonzero(np.r_[True, slots[1:] != slots[:-1]])  # rows are in time order
        keep = first[slots[first] > self._last_slot]
        if keep.size == 0:
            return []
        self._last_slot = float(slots[keep[-1]])
        picked = rows[keep]
        found = self.check.touches(picked[:, list(self.q_columns)])
        out = []
        for k in range(picked.shape[0]):
            g, h, depth = int(found[k, 0]), int(found[k, 1]), float(found[k, 2])
            now = {(g, h)} if depth > 0.0 else set()
            if now and not now <= self._touching:
                when = f"t = {picked[k, 0]:.3f} s"
                out.append(f"{link_name(g)} touched {link_name(h)} at {when} ({depth * 1000:.1f} mm deep)")
            self._touching = now
        return out
