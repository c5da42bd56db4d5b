"""Inverse kinematics of the chain the simulator integrates (the tool pose and Jacobian kernels are in
chain_kinematics.py).

The chain is built from `mechanics.chain_arrays` and `mechanics.tool_point` and evaluated with
`chain_dynamics.chain_frames`, so the poses here are the `pose.*` rows of a run
(`chain_dynamics.pose_rows`, row n): the
tool point in the last joint frame, the tool orientation that of the last link frame,
`R_all[n-1] @ rot_rpy(spec.links[-1].rpy)`. Cartesian commands go through `ArmKinematics.walk_line`
(a straight line: the joint solutions along it, one compiled call), `ArmKinematics.solve` (local, from
a seed: resolved-rate steps) and `ArmKinematics.solve_near` (global: the goal of a point-to-point move).

When the seed's own attempt fails, `solve` tries a few seeds around it (N_LOCAL, fixed) and
`solve_near` a fixed set of seeds over the whole joint space (N_RESTARTS, fixed RNG seed), letting
joints whose range holds a full turn pass a limit by a turn; where a seed stops at a limit, the same
seed without limits finds a branch (elbow, wrist flip) that may lie inside them once turned. Both keep
the converged solution nearest the seed.

If nothing converges, the result is the closest pose within the limits: position first, orientation
second (rotation weight W_PRIORITY), from the kernel and then L-BFGS-B (beyond reach the residual is
large and Gauss-Newton crawls), with a reason: the joint a limit stops ("joint limits: ..."), the
distance the arm cannot close ("out of reach: ...", and whether the limits bind), or the orientation
it cannot reach at the target position.

The compiled solver is ik_solver.py, the line's walk line_walk.py.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from simecs.mesh.rules.kinematics import rot_rpy

from .chain_kinematics import rotation_vector, rotvec_exp, tool_frames, tool_jacobian
from .ik_solver import ST_STALLED, cost_grad, solve_kernel, tool_positions_of
from .line_walk import LineWalk, line_kernel
from .mechanics import chain_arrays, tool_point
from .spec import ArmSpec

# ---- seeds and the closest pose ---------------------------------------------------------------------------
W_PRIORITY = 1e-3  # rotation weight of the "closest pose" search: position first, orientation second
N_RESTARTS = 16  # extra seeds of solve_near
N_LOCAL = 4  # extra seeds of solve when the seed itself fails: the seed moved by up to LOCAL_SPREAD
LOCAL_SPREAD = 0.3  # rad
RESTART_RNG = 20240611  # fixed: solve_near is deterministic
BIG = 1e300  # "no limit"


@dataclass
class IKResult:
    """One inverse-kinematics answer; `q` is within the joint limits even when `ok` is False."""

    q: np.ndarray  # the joint solution (always within the joint limits)
    ok: bool  # position error <= tol_pos and rotation error <= tol_rot
    position_error: float  # m, |p(q) - target|
    rotation_error: float  # rad, angle of R(q)^T R_target
    iterations: int  # solver iterations, summed over every attempt (restarts, diagnosis)
    reason: str  # '' when ok; else a short sentence saying why not and how far the closest pose is


class _Run(NamedTuple):
    q: np.ndarray
    position_error: float
    rotation_error: float
    iterations: int
    status: int
    ok: bool


def orientation_error(R_now: np.ndarray, R_target: np.ndarray) -> np.ndarray:
    """Rotation vector (3,), world frame, that turns R_now into R_target: exp([e]x) R_now = R_target.

    Its norm is the rotation error of `IKResult`; it is the rotation part of the solver's error."""
    e = np.empty(3)
    rotation_vector(np.ascontiguousarray(R_now, dtype=float), np.ascontiguousarray(R_target, dtype=float), e)
    return e


def turned(r: np.ndarray, R: np.ndarray) -> np.ndarray:
    """exp([r]x) R: the orientation R turned by the rotation vector r (world frame), the inverse of
    `orientation_error` (turned(orientation_error(R0, R1), R0) = R1)."""
    out = np.empty((3, 3))
    rotvec_exp(np.ascontiguousarray(r, dtype=float), np.ascontiguousarray(R, dtype=float), out)
    return out


class ArmKinematics:
    """Kinematics of one model at one parameter set (link lengths matter; masses do not).

    Build it once per value set: the chain arrays are computed here, every call after that runs the
    compiled kernels only."""

    def __init__(self, spec: ArmSpec, values: Mapping[str, float]) -> None:
        self.spec = spec
        self.n = len(spec.links)
        chain = chain_arrays(spec, values)
        self.pre_R = np.ascontiguousarray(chain.pre_R)
        self.pre_p = np.ascontiguousarray(chain.pre_p)
        self.tool_local = np.ascontiguousarray(tool_point(spec, values), dtype=float)
        self.R_last = np.ascontiguousarray(rot_rpy(spec.links[-1].rpy))
        self.lower = np.array([lk.joint_min for lk in spec.links], dtype=float)
        self.upper = np.array([lk.joint_max for lk in spec.links], dtype=float)
        # the reach bound: position errors are divided by it so they weigh like radians
        self.reach = float(np.sum(np.linalg.norm(self.pre_p[1:], axis=1)) + np.linalg.norm(self.tool_local))
        self.reach = max(self.reach, 1e-3)
        self._no_lower = np.full(self.n, -BIG)
        self._no_upper = np.full(self.n, BIG)
        # joints whose range holds a full turn: solve_near lets them pass a limit by a turn
        self._turn = np.where(self.upper - self.lower >= 2 * math.pi, 2 * math.pi, 0.0)
        self._no_turn = np.zeros(self.n)
        rng = np.random.default_rng(RESTART_RNG)
        lo = np.where(np.isfinite(self.lower), self.lower, -math.pi)
        hi = np.where(np.isfinite(self.upper), self.upper, math.pi)
        self.restarts = lo + (hi - lo) * rng.random((N_RESTARTS, self.n))
        self.local_offsets = rng.uniform(-LOCAL_SPREAD, LOCAL_SPREAD, (N_LOCAL, self.n))

    # ---- forward kinematics ----
    def _q(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        qv = np.ascontiguousarray(q, dtype=float)
        if qv.shape != (self.n,):
            raise ValueError(f"expected {self.n} joint positions, got shape {qv.shape}")
        return qv

    def tool_pose(self, q: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool position (3,) and rotation matrix (3, 3) in the world frame: the `pose.*` tool row."""
        p = np.empty(3)
        R = np.empty((3, 3))
        R_all = np.empty((self.n, 3, 3))
        p_all = np.empty((self.n, 3))
        tool_frames(self.pre_R, self.pre_p, self.R_last, self.tool_local, self._q(q), R_all, p_all, p, R)
        return p, R

    def tool_positions(self, qs: np.ndarray) -> np.ndarray:
        """(k, 3): the tool position at each row of qs (k, n), in one compiled call (a planned path)."""
        qv = np.ascontiguousarray(qs, dtype=float)
        if qv.ndim != 2 or qv.shape[1] != self.n:
            raise ValueError(f"expected rows of {self.n} joint positions, got shape {qv.shape}")
        out = np.empty((qv.shape[0], 3))
        tool_positions_of(self.pre_R, self.pre_p, self.R_last, self.tool_local, qv, out)
        return out

    def jacobian(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        """(6, n): rows 0-2 the tool point's linear velocity, rows 3-5 the angular velocity per unit
        joint speed, world frame (what a resolved-rate controller inverts)."""
        p = np.empty(3)
        R = np.empty((3, 3))
        R_all = np.empty((self.n, 3, 3))
        p_all = np.empty((self.n, 3))
        tool_frames(self.pre_R, self.pre_p, self.R_last, self.tool_local, self._q(q), R_all, p_all, p, R)
        J = np.empty((6, self.n))
        tool_jacobian(R_all, p_all, p, J)
        return J

    @property
    def base(self) -> np.ndarray:
        """The origin of joint 1 (world): no tool point is farther from it than `reach`."""
        return np.asarray(self.pre_p[0], dtype=float)

    def from_base(self, position: Sequence[float] | np.ndarray) -> float:
        """m from the arm's base (joint 1's origin) to a position: beyond `reach` it is out of reach."""
        return float(np.linalg.norm(np.asarray(position, dtype=float) - self.base))

    def sigma_min(self, q: Sequence[float] | np.ndarray) -> float:
        """Smallest singular value of the 6 x n Jacobian: near 0 the arm is near a singularity, where
        small Cartesian moves need large joint speeds."""
        return float(np.linalg.svd(self.jacobian(q), compute_uv=False)[-1])

    # ---- inverse kinematics ----
    def _target(
        self, position: Sequence[float] | np.ndarray, R: np.ndarray, seed: Sequence[float] | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p_t = np.ascontiguousarray(position, dtype=float)
        R_t = np.ascontiguousarray(R, dtype=float)
        q0 = self._q(seed)
        if p_t.shape != (3,) or R_t.shape != (3, 3):
            raise ValueError("expected a position (3,) and a rotation matrix (3, 3)")
        if not (np.all(np.isfinite(p_t)) and np.all(np.isfinite(R_t)) and np.all(np.isfinite(q0))):
            raise ValueError("position, rotation and seed must be finite")
        return p_t, R_t, np.clip(q0, self.lower, self.upper)

    def _run(
        self,
        p_t: np.ndarray,
        R_t: np.ndarray,
        start: np.ndarray,
        pull: np.ndarray,
        tol_pos: float,
        tol_rot: float,
        max_iter: int,
        *,
        w_rot: float = 1.0,
        limits: bool = True,
        turns: bool = False,
    ) -> _Run:
        q = np.empty(self.n)
        info = np.zeros(4)
        it = solve_kernel(
            self.pre_R,
            self.pre_p,
            self.R_last,
            self.tool_local,
            self.lower if limits else self._no_lower,
            self.upper if limits else self._no_upper,
            self._turn if turns and limits else self._no_turn,
            p_t,
            R_t,
            np.ascontiguousarray(start, dtype=float),
            np.ascontiguousarray(pull, dtype=float),
            1.0 / self.reach,
            w_rot,
            tol_pos,
            tol_rot,
            self.n > 6,
            max_iter,
            q,
            info,
        )
        pe, re = float(info[0]), float(info[1])
        return _Run(q, pe, re, int(it), int(info[2]), pe <= tol_pos and re <= tol_rot)

    def solve(
        self,
        position: Sequence[float] | np.ndarray,
        R: np.ndarray,
        seed: Sequence[float] | np.ndarray,
        *,
        tol_pos: float = 1e-9,
        tol_rot: float = 1e-9,
        max_iter: int = 200,
    ) -> IKResult:
        """The joint vector that puts the tool at (position, R), found locally from `seed` (clamped to
        the limits): the resolved-rate step of a straight-line move and the refinement of a good guess.

        For a redundant arm the answer is the solution nearest the seed (module docstring). On failure
        `q` is the closest pose found from this seed (position first, then orientation) and `reason`
        says how far it is and whether a joint limit is in the way."""
        p_t, R_t, q0 = self._target(position, R, seed)
        best, runs, total = self._local(p_t, R_t, q0, tol_pos, tol_rot, max_iter)
        if best is not None:
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        return self._failure(p_t, R_t, q0, runs, None, tol_pos, tol_rot, max_iter, local=True, spent=total)

    def _local(
        self, p_t: np.ndarray, R_t: np.ndarray, q0: np.ndarray, tol_pos: float, tol_rot: float, max_iter: int
    ) -> tuple[_Run | None, list[_Run], int]:
        """The seed's attempt, and if it fails a few seeds around it (stuck, typically at a joint limit
        between the seed and the nearest solution): the converged run nearest the seed (or None), every
        run and the iterations."""
        r = self._run(p_t, R_t, q0, q0, tol_pos, tol_rot, max_iter)
        if r.ok:
            return r, [r], r.iterations
        runs = [r]
        for off in self.local_offsets:
            start = np.clip(q0 + off, self.lower, self.upper)
            runs.append(self._run(p_t, R_t, start, q0, tol_pos, tol_rot, max_iter))
        found = [r for r in runs if r.ok]
        total = sum(r.iterations for r in runs)
        best = min(found, key=lambda r: float(np.linalg.norm(r.q - q0))) if found else None
        return best, runs, total

    def solve_near(
        self,
        position: Sequence[float] | np.ndarray,
        R: np.ndarray,
        seed: Sequence[float] | np.ndarray,
        *,
        tol_pos: float = 1e-9,
        tol_rot: float = 1e-9,
    ) -> IKResult:
        """`solve`, and if that fails from `seed`, from a fixed set of extra seeds (deterministic): the
        goal of a point-to-point move given as a pose. Of the converged solutions the one closest to
        `seed` (Euclidean in joint space) is returned; if none converges, the closest pose the arm
        reaches, with `reason` saying how far it is and whether joint limits were binding."""
        max_iter = 200
        p_t, R_t, q0 = self._target(position, R, seed)
        best, runs, total = self._local(p_t, R_t, q0, tol_pos, tol_rot, max_iter)
        if best is not None:  # what `solve` answers
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        # then the pose wherever it is: joints with a full turn of range may pass their limits by a
        # turn, and the extra seeds cover the other branches (elbow, wrist flips)
        found: list[_Run] = []
        for s in [q0, *self.restarts]:
            r = self._run(p_t, R_t, s, q0, tol_pos, tol_rot, max_iter, turns=True)
            total += r.iterations
            runs.append(r)
            if not r.ok:
                # stuck at a limit: the branch it heads for is outside the limits, but from the
                # same seed, without limits, the solver may reach one that (turned) lies inside
                free = self._run(p_t, R_t, s, q0, tol_pos, tol_rot, max_iter, limits=False)
                total += free.iterations
                qw = self._wrap(free.q)
                if free.ok and self._inside(qw):
                    r = self._run(p_t, R_t, qw, q0, tol_pos, tol_rot, max_iter, turns=True)
                    total += r.iterations
                    runs.append(r)
            if r.ok:
                found.append(r)
        if found:
            best = min(found, key=lambda r: float(np.linalg.norm(r.q - q0)))
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        return self._failure(p_t, R_t, q0, runs, None, tol_pos, tol_rot, max_iter, local=False, spent=total)

    def walk_line(
        self,
        q_start: Sequence[float] | np.ndarray,
        position: Sequence[float] | np.ndarray,
        R: np.ndarray,
        *,
        tol_pos: float,
        tol_rot: float,
        step: float,
        turn: float,
        sigma_min: float,
        max_knots: int,
    ) -> LineWalk:
        """The joint solutions along the straight line from the tool pose at `q_start` to (position,
        R): position linear, orientation slerped (exp(s rot) R0), in one compiled call.

        Each knot is the solution nearest the previous one (as a resolved-rate walk finds it); knots
        are at most `step` m and `turn` rad apart and closer where the cubic Hermite curve through
        them and their rates would leave the line by more than (tol_pos, tol_rot) at a middle, so
        their number follows the line's geometry, not its speed. The walk ends early, saying where
        and why, at a pose the solver cannot reach from there, at a posture whose smallest singular
        value is below `sigma_min`, where the joints would have to jump (the curve cannot follow
        the line however short the step: the joint speed needed is unbounded), or after `max_knots`."""
        q0 = np.clip(self._q(q_start), self.lower, self.upper)
        p0, R0 = self.tool_pose(q0)
        p_t, R_t, _ = self._target(position, R, q0)
        dp = p_t - p0
        rot = orientation_error(R0, R_t)
        size = max(float(np.linalg.norm(dp)) / step, float(np.linalg.norm(rot)) / turn)
        fine = max(float(np.linalg.norm(dp)) / tol_pos, float(np.linalg.norm(rot)) / tol_rot)
        h_max = 1.0 / max(size, 1.0)
        h_min = min(h_max, 1.0 / max(fine, 1.0))
        S = np.empty(max_knots)
        Q = np.empty((max_knots, self.n))
        D = np.empty((max_knots, self.n))
        C = np.zeros((max_knots, 2))
        q_at = np.empty(self.n)
        info = np.zeros(6)
        k = line_kernel(
            self.pre_R,
            self.pre_p,
            self.R_last,
            self.tool_local,
            self.lower,
            self.upper,
            np.ascontiguousarray(p0),
            np.ascontiguousarray(dp),
            np.ascontiguousarray(R0),
            np.ascontiguousarray(rot),
            q0,
            1.0 / self.reach,
            h_max,
            h_min,
            tol_pos,
            tol_rot,
            sigma_min,
            S,
            Q,
            D,
            C,
            q_at,
            info,
        )
        return LineWalk(
            S[:k].copy(),
            Q[:k].copy(),
            D[:k].copy(),
            C[: max(k - 1, 0)].copy(),
            int(info[0]),
            float(info[1]),
            float(info[2]),
            float(info[3]),
            float(info[4]),
            q_at,
            int(info[5]),
        )

    # ---- failure diagnosis ----
    def _wrap(self, q: np.ndarray) -> np.ndarray:
        """Each joint moved by whole turns into its limits where a turn fits there (same pose)."""
        out = q.copy()
        for j in range(self.n):
            lo, hi = self.lower[j], self.upper[j]
            if not lo <= q[j] <= hi and np.isfinite(lo):
                w = lo + math.fmod(q[j] - lo, 2 * math.pi)
                if w < lo:
                    w += 2 * math.pi
                if w <= hi:
                    out[j] = w
        return out

    def _inside(self, q: np.ndarray) -> bool:
        return bool(np.all(q >= self.lower) and np.all(q <= self.upper))

    def _cost(self, r: _Run) -> float:
        """What the closest-pose search minimises: position first, orientation second."""
        return (r.position_error / self.reach) ** 2 + (W_PRIORITY * r.rotation_error) ** 2

    def _polish(
        self, p_t: np.ndarray, R_t: np.ndarray, q: np.ndarray, limits: bool, tol_pos: float, tol_rot: float
    ) -> _Run:
        """The closest-pose objective minimised with L-BFGS-B (bounds = the limits) from q.

        Gauss-Newton (the kernel) crawls here: beyond reach the residual is large, and its curvature,
        which Gauss-Newton leaves out, dominates (e.g. a wrist orienting a short tool offset)."""
        # Imported here: scipy.optimize takes 0.45 s to import, and only a pose out of reach needs it (every
        # process that plans would pay it at its start).
        from scipy.optimize import minimize

        args = (self.pre_R, self.pre_p, self.R_last, self.tool_local, p_t, R_t, 1.0 / self.reach, W_PRIORITY)
        grad = np.empty(self.n)

        def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
            f = cost_grad(*args, np.ascontiguousarray(x, dtype=float), grad)
            return float(f), grad.copy()

        bounds = list(zip(self.lower, self.upper, strict=True)) if limits else None
        res = minimize(
            fun,
            q,
            jac=True,
            method="L-BFGS-B",
            bounds=bounds,
            options={"maxiter": 2000, "ftol": 1e-16, "gtol": 1e-13},
        )
        x = np.clip(res.x, self.lower, self.upper) if limits else np.asarray(res.x, dtype=float)
        p, R = self.tool_pose(x)
        pe = float(np.linalg.norm(p - p_t))
        re = float(np.linalg.norm(orientation_error(R, R_t)))
        return _Run(x, pe, re, int(res.nit), ST_STALLED, pe <= tol_pos and re <= tol_rot)

    def _closest(
        self,
        p_t: np.ndarray,
        R_t: np.ndarray,
        starts: list[np.ndarray],
        q0: np.ndarray,
        tol_pos: float,
        tol_rot: float,
        max_iter: int,
        limits: bool,
    ) -> tuple[_Run, int]:
        """The closest pose (position first, then orientation) from these starts, and the iterations."""
        best: _Run | None = None
        total = 0
        for s in starts:
            c = self._run(p_t, R_t, s, q0, tol_pos, tol_rot, max_iter, w_rot=W_PRIORITY, limits=limits)
            total += c.iterations
            if best is None or self._cost(c) < self._cost(best):
                best = c
        assert best is not None
        if not best.ok:
            polished = self._polish(p_t, R_t, best.q, limits, tol_pos, tol_rot)
            total += polished.iterations
            if self._cost(polished) < self._cost(best):
                best = polished
        return best, total

    def _failure(
        self,
        p_t: np.ndarray,
        R_t: np.ndarray,
        q0: np.ndarray,
        runs: list[_Run],
        free: _Run | None,
        tol_pos: float,
        tol_rot: float,
        max_iter: int,
        *,
        local: bool,
        spent: int,
    ) -> IKResult:
        """The closest pose within the limits (position first, then orientation) and why the target
        was not reached: a joint limit in the way, out of reach, or an orientation out of reach."""
        total = spent
        starts = [q0] + [r.q for r in sorted(runs, key=self._cost)[:4]]
        closest, its = self._closest(p_t, R_t, starts, q0, tol_pos, tol_rot, max_iter, True)
        total += its
        best = min([*runs, closest], key=self._cost)
        if best.ok:  # the position-first search met both tolerances after all
            return IKResult(best.q, True, best.position_error, best.rotation_error, total, "")
        if free is None:
            free = self._run(p_t, R_t, q0, q0, tol_pos, tol_rot, max_iter, limits=False)
            total += free.iterations
        dist = f"{best.position_error:.3g} m and {best.rotation_error:.3g} rad away"
        where = "found from this seed" if local else "the arm reaches"
        reason = ""
        if free.ok:
            qw = self._wrap(free.q)
            out = [j for j in range(self.n) if not self.lower[j] <= qw[j] <= self.upper[j]]
            if out:
                need = ", ".join(
                    f"joint{j + 1} would need {free.q[j]:.4g} rad (limits {self.lower[j]:.4g} .. "
                    f"{self.upper[j]:.4g})"
                    for j in out
                )
                reason = f"joint limits: {need}; the closest pose {where} within the limits is {dist}"
            elif local:
                turned = ", ".join(
                    f"joint{j + 1} at {qw[j]:.4g} rad" for j in range(self.n) if qw[j] != free.q[j]
                )
                reason = (
                    f"joint limits: from this seed the target needs a joint past its limit; the same pose "
                    f"is reached with {turned}, a full turn away (solve_near finds it); the closest pose "
                    f"{where} is {dist}"
                )
        if not reason:
            unlimited, its = self._closest(p_t, R_t, [best.q], q0, tol_pos, tol_rot, max_iter, False)
            total += its
            if best.position_error > tol_pos:
                reason = f"out of reach: the closest pose {where} is {best.position_error:.3g} m away"
                d_free = unlimited.position_error
                if d_free < best.position_error - 1e-6 * (1.0 + best.position_error):
                    at = [
                        f"joint{j + 1}"
                        for j in range(self.n)
                        if best.q[j] <= self.lower[j] or best.q[j] >= self.upper[j]
                    ]
                    reason += (
                        f" (joint limits bind{': ' + ', '.join(at) + ' at a limit' if at else ''}; "
                        f"without them {d_free:.3g} m)"
                    )
                else:
                    reason += " (joint limits are not the binding constraint)"
                reason += f", and {best.rotation_error:.3g} rad off in orientation"
            else:
                reason = (
                    f"orientation out of reach: at the target position the closest orientation {where} is "
                    f"{best.rotation_error:.3g} rad off"
                )
                if (
                    unlimited.position_error <= tol_pos
                    and unlimited.rotation_error < best.rotation_error - 1e-6
                ):
                    reason += f" (joint limits bind: without them {unlimited.rotation_error:.3g} rad)"
        return IKResult(best.q, False, best.position_error, best.rotation_error, total, reason)
