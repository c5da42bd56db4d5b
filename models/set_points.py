"""What the drives of a run follow, as the arrays the compiled kernels read (references.ref_eval): a
joint path's trapezoid segments from the held positions, or a sampled reference with each joint's
mode; the hybrid controller's force profile; and the live inputs changed between solver calls (a jog
superposed on the reference, an external controller's current set points)."""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import numpy as np
from simecs.mesh.protocol.model import Link

from . import drive as dr
from . import references
from .mechanics import vec

Node = tuple[np.ndarray, float, float]


class SetPoints:
    """The set points of a simulation's runs; `P` is its drive array (shared, changed in place)."""

    def __init__(self, links: Sequence[Link], P: np.ndarray) -> None:
        self.n = n = len(links)
        self._links = list(links)
        self._P = P
        self.hold = np.zeros(n)  # the held positions a joint path starts from
        self.seg = np.zeros((0, 3 + 2 * n))  # a joint path's segments (references.plan_segment)
        self.tab = np.zeros((0, 1 + 2 * n))  # a sampled reference (planner.py), when not a joint path
        self.jmode = np.zeros(n, dtype=np.int64)
        self.forces = np.zeros((0, 5))  # the hybrid controller's force profile (opspace.FP_*)
        #: Live inputs per joint (references.LV_*): the jog, superposed on the reference, and the current
        #: set points of an external controller for the joints it drives.
        self.live = np.zeros((n, references.NLIVE))
        self.external = np.zeros(n, dtype=bool)  # the joints an external controller drives
        self._nodes: list[Node] = []

    def arrays(self) -> references.SetPointArrays:
        """What every kernel reads the set points from (references.ref_eval), as they are now (a new
        command replaces arrays: ask again after one)."""
        return references.SetPointArrays(self.seg, self.hold, self.tab, self.jmode, self.live)

    def follow_path(self, nodes: Sequence[tuple[Sequence[float], float, float]], t0: float | None) -> None:
        """A joint path: every node (destination in rad, speed %, acceleration %) is reached and stopped
        at, from t0 (None: a run's start, from the held positions; else from where the set points are
        at t0 of a run going on). Checked here, so a bad node fails early."""
        parsed: list[Node] = []
        for k, node in enumerate(nodes):
            try:
                dest_in, sp, ac = node
            except (TypeError, ValueError):
                raise ValueError(f"path node {k}: expected (joint vector, speed %, acc %)") from None
            dest = vec(dest_in)
            if dest.shape != (self.n,) or not np.all(np.isfinite(dest)):
                raise ValueError(f"path node {k}: expected {self.n} finite joint positions")
            for i, lk in enumerate(self._links):
                if not lk.joint_min <= dest[i] <= lk.joint_max:
                    raise ValueError(
                        f"path node {k}: {lk.joint} {dest[i]:g} rad outside "
                        f"[{lk.joint_min:g}, {lk.joint_max:g}]"
                    )
            for what, v in (("speed", sp), ("acc", ac)):
                if isinstance(v, bool) or not (isinstance(v, numbers.Real) and 0 < float(v) <= 100):
                    raise ValueError(f"path node {k}: {what} % must be in (0, 100], got {v!r}")
            parsed.append((dest, float(sp), float(ac)))
        self._nodes = parsed
        self.seg = self._plan(t0)
        self.tab = np.zeros((0, 1 + 2 * self.n))
        self.jmode = np.zeros(self.n, dtype=np.int64)
        self.forces = np.zeros((0, 5))

    def follow_reference(self, tab: np.ndarray, jmode: np.ndarray) -> None:
        """A sampled reference (rows [t, r, rd]) with each joint in its mode (references.JM_*)."""
        tab = np.ascontiguousarray(tab, dtype=float)
        if tab.ndim != 2 or tab.shape[1] != 1 + 2 * self.n or tab.shape[0] < 1:
            raise ValueError(f"a reference table has rows of {1 + 2 * self.n} numbers")
        if not np.all(np.isfinite(tab)) or np.any(np.diff(tab[:, 0]) < 0):
            raise ValueError("a reference table needs finite numbers and times that do not decrease")
        self.tab = tab
        self.jmode = np.ascontiguousarray(jmode, dtype=np.int64)
        self._nodes = []
        self.seg = np.zeros((0, 3 + 2 * self.n))
        self.forces = np.zeros((0, 5))

    def hold_at(self, hold: np.ndarray) -> None:
        """The arm rests at `hold` (a new initial pose or a run's start): the joint path starts there."""
        self.hold = hold
        self.seg = self._plan(None) if self._nodes else np.zeros((0, 3 + 2 * self.n))

    def _plan(self, t0: float | None) -> np.ndarray:
        vmax = self._P[:, dr.P_VMAX]
        amax = self._P[:, dr.P_AMAX]
        if t0 is not None:  # during a run: from where the set points are now
            qr = np.empty(self.n)
            qdr = np.empty(self.n)
            references.traj_eval(self.seg, self.hold, t0, qr, qdr)
            self.hold = qr.copy()
            q = qr
        else:
            q = self.hold.copy()
        rows = []
        t = t0 or 0.0
        for dest, sp, ac in self._nodes:
            # The set point is the destination as commanded: the controller compares it with what its
            # load resolver reads, so a resolver error shows as an error of the pose reached, as on
            # a real arm (no controller knows its own sensor's error).
            row = references.plan_segment(q, dest, vmax * sp / 100.0, amax * ac / 100.0, t)
            rows.append(row)
            t += row[1]
            q = dest
        return np.array(rows) if rows else np.zeros((0, 3 + 2 * self.n))

    def jog(self, rates: np.ndarray, horizon: float, t: float) -> np.ndarray:
        """Move the set points at `rates` (rad/s per joint) from time t on, on top of the command; a
        rate is cut so its joint's set point stays within the joint's range for `horizon` s. Joints in
        current mode do not jog. Returns the rates applied."""
        js = self.live
        js[:, references.LV_OFFSET] += js[:, references.LV_RATE] * (t - js[:, references.LV_T0])
        js[:, references.LV_T0] = t
        qr, qdr = np.empty(self.n), np.empty(self.n)
        references.ref_nominal(self.arrays(), t, qr, qdr)
        now = qr + js[:, references.LV_OFFSET]
        applied = np.asarray(rates, dtype=float).copy()
        for j, lk in enumerate(self._links):
            if self.jmode[j] == references.JM_CURRENT or not math.isfinite(applied[j]):
                applied[j] = 0.0
            elif applied[j] > 0:
                applied[j] = min(applied[j], max(0.0, (lk.joint_max - now[j]) / horizon))
            else:
                applied[j] = max(applied[j], min(0.0, (lk.joint_min - now[j]) / horizon))
        js[:, references.LV_RATE] = applied
        return applied

    def set_external(self, joints: Sequence[bool] | np.ndarray) -> None:
        """Hand the control of the marked joints to an external controller (from now on, and for the
        runs that follow): their current set point is what `set_actuators` gives, 0 until then."""
        mask = np.asarray(joints, dtype=bool)
        if mask.shape != (self.n,):
            raise ValueError(f"expected {self.n} flags, one per joint")
        self.external = mask.copy()
        self.live[:, references.LV_EXTERNAL] = mask
        self.live[:, references.LV_IREF] = 0.0

    def set_actuators(self, i_ref: np.ndarray) -> None:
        """The external controller's current set points (A), held until the next call (zero-order
        hold); the entries of joints the built-in controller keeps are not used."""
        self.live[:, references.LV_IREF] = i_ref

    def set_forces(self, forces: np.ndarray) -> None:
        """The force set points of the next run (rows of opspace.FP_*: from t, push along an axis with
        f N), for the hybrid controller; the planner makes them from the Cartesian nodes' `force`."""
        table = np.ascontiguousarray(forces, dtype=float).reshape(-1, 5)
        if not np.all(np.isfinite(table)) or np.any(table[:, 4] < 0) or np.any(np.diff(table[:, 0]) < 0):
            raise ValueError("a force profile needs finite rows, forces >= 0 and times that do not decrease")
        self.forces = table

    def start_run(self, controlled: bool) -> None:
        """A run starts: no jog, no current set point; the built-in operational-space controller
        (`controlled`) drives every joint's current, else the external controller its joints."""
        live = self.live
        live[:, [references.LV_OFFSET, references.LV_RATE, references.LV_T0, references.LV_IREF]] = 0.0
        live[:, references.LV_EXTERNAL] = True if controlled else self.external

    def path_duration(self) -> float:
        """Seconds from the first segment's start to the last one's end (0 without a path)."""
        if self.seg.shape[0] == 0:
            return 0.0
        return float(self.seg[-1, 0] + self.seg[-1, 1] - (self.seg[0, 0]))
