"""A spec and parameter values as the arrays the compiled kernels and Exudyn use, and the initial state.

`chain_arrays` gives the link data that both the Exudyn KinematicTree and the numba mass matrix and
forward kinematics are built from (so they cannot disagree); `drive_array` the per-joint parameter
array P of drive.py; `init_states` the initialisation equations of paper §5.2 (a robot at rest).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
from simecs.mesh.rules.kinematics import rot_rpy

from . import drive as dr
from .spec import ArmSpec

# parameters whose change alters the chain (masses, lengths, radii, payload): Exudyn items are updated
MECH_PREFIXES = ("link", "payload.")
#: The parameters of the gravity vector (m/s^2, world axes).
GRAVITY_PARAMS = ("gravity.x", "gravity.y", "gravity.z")


class ChainArrays(NamedTuple):
    """Link data of the chain, one row per joint; the joint frames are those of the Link convention."""

    pre_R: np.ndarray  # (n, 3, 3) rotation of joint i's frame in joint i-1's frame
    pre_p: np.ndarray  # (n, 3) origin of joint i's frame in joint i-1's frame
    masses: np.ndarray  # (n,) link mass, the payload included in the last link
    coms: np.ndarray  # (n, 3) centre of mass in the joint frame
    inertias: np.ndarray  # (n, 3, 3) inertia about the COM in the joint frame


def vec(a: Sequence[float] | np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=float)


#: A body the last link carries besides its payload (a grasped object, grasp.held_body): mass (kg),
#: centre and inertia about it (kg m^2), both in the last joint's frame.
Carried = tuple[float, np.ndarray, np.ndarray]


def chain_arrays(spec: ArmSpec, values: Mapping[str, float], carried: Carried | None = None) -> ChainArrays:
    """Joint frames, masses, COMs and inertias of the chain at these link lengths, masses and radii,
    with the body the last link `carried` (a grasped object) added to it."""
    n = len(spec.links)
    pre_R = np.zeros((n, 3, 3))
    pre_p = np.zeros((n, 3))
    masses = np.zeros(n)
    coms = np.zeros((n, 3))
    inertias = np.zeros((n, 3, 3))
    prev_R = rot_rpy(spec.base_rpy)
    prev_off = vec(spec.base_translation)
    for i, lk in enumerate(spec.links):
        pre_R[i] = prev_R
        pre_p[i] = prev_off
        Rr = rot_rpy(lk.rpy)
        L = float(values[f"link{i + 1}.length"])
        m = float(values[f"link{i + 1}.mass"])
        r = float(values[f"link{i + 1}.radius"])
        if lk.com is None or lk.inertia is None:
            c_l = np.array([L / 2, 0.0, 0.0])
            # thin-walled tube (wall 20 % of the radius): Ixx = m r^2 (1+0.64)/2 ...
            ri2 = (0.8 * r) ** 2
            ixx = 0.5 * m * (r * r + ri2)
            iyy = m * (3 * (r * r + ri2) + L * L) / 12.0
            I_l = np.diag([ixx, iyy, iyy])
        else:
            c_l = vec(lk.com)
            I_l = np.asarray(lk.inertia_matrix(), dtype=float)
        if i == n - 1:
            mp = float(values["payload.mass"])
            if mp > 0:
                a = float(values["payload.size"])
                cp = np.array([L, 0, 0]) + vec(lk.final) + vec(spec.tool_translation)
                m, c_l, I_l = _joined((m, c_l, I_l), (mp, cp, np.eye(3) * mp * a * a / 6.0))
        masses[i] = m
        coms[i] = Rr @ c_l
        inertias[i] = Rr @ I_l @ Rr.T
        if i == n - 1 and carried is not None and carried[0] > 0.0:
            masses[i], coms[i], inertias[i] = _joined(
                (m, coms[i], inertias[i]), (carried[0], np.asarray(carried[1]), np.asarray(carried[2]))
            )
        prev_R = Rr
        prev_off = Rr @ (np.array([L, 0.0, 0.0]) + vec(lk.final))
    return ChainArrays(pre_R, pre_p, masses, coms, inertias)


def _joined(*bodies: Carried) -> Carried:
    """One rigid body of several (mass, centre, inertia about the centre; one frame): parallel axes."""
    mt = float(sum(b[0] for b in bodies))
    if mt <= 0:
        return bodies[0]
    ct = np.sum([b[0] * b[1] for b in bodies], axis=0) / mt
    inertia = np.zeros((3, 3))
    for mk, ck, Ik in bodies:
        d = ck - ct
        inertia += Ik + mk * (d @ d * np.eye(3) - np.outer(d, d))
    return mt, ct, inertia


def tool_point(spec: ArmSpec, values: Mapping[str, float]) -> np.ndarray:
    """The tool point in the last joint's frame (where the tool sensor and the pose rows look)."""
    lk = spec.links[-1]
    L = values[f"link{len(spec.links)}.length"]
    return rot_rpy(lk.rpy) @ (np.array([L, 0, 0]) + vec(lk.final) + vec(spec.tool_translation))


def drive_array(n: int, values: Mapping[str, float]) -> np.ndarray:
    """The drive parameters as P[joint, k] in `drive.DRIVE_PARAMS` order: what the kernels read."""
    P = np.zeros((n, dr.NP))
    for j in range(n):
        for k, name in enumerate(dr.DRIVE_PARAMS):
            P[j, k] = values[f"joint{j + 1}.{name}"]
    return P


def gravity_of(values: Mapping[str, float]) -> np.ndarray:
    """The gravity vector (m/s^2, world axes) of a value set."""
    return np.array([float(values[name]) for name in GRAVITY_PARAMS])


def gear_twist(P: np.ndarray, j: int, tau: float) -> float:
    """The output twist (rad) at which joint j's gear carries the static torque tau: tau / stiffness,
    plus half the backlash on the side the load pushes (none without load: centred)."""
    if tau == 0.0:
        return 0.0
    return tau / P[j, dr.P_K] + math.copysign(0.5 * P[j, dr.P_BL], tau)


def holding_capacity(P: np.ndarray) -> np.ndarray:
    """Per joint, the largest static torque (N m) its drive holds: the motor's peak current through
    the gear at rest, i_max kt n / f (f: the efficiency's switch at rest, drive.resting_gear_factor)."""
    return np.array(
        [
            P[j, dr.P_IMAX] * P[j, dr.P_KT] * P[j, dr.P_N] / dr.resting_gear_factor(P[j, dr.P_ETA])
            for j in range(P.shape[0])
        ]
    )


def init_states(
    P: np.ndarray, q: np.ndarray, load: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Initialisation equations (paper §5.2): drive states and held reference of a robot at rest at q,
    its gears carrying the static joint torques `load` (gravity's g(q); None: none).

    Every derivative is zero, so the run starts without transients; description.py lists the same
    equations for clients and docs.py explains them."""
    n = q.shape[0]
    X = np.zeros((n, dr.NL))
    hold = np.zeros(n)
    tau = np.zeros(n) if load is None else load
    for j in range(n):
        nn = P[j, dr.P_N]
        p = P[j, dr.P_POLES]
        th = nn * (q[j] + gear_twist(P, j, float(tau[j])))
        th_meas = th + P[j, dr.P_EM] * math.sin(p * th)
        te = p * th
        tem = p * th_meas
        sa, sb = dr.phase_shapes(P[j, dr.P_H3], math.sin(te), math.cos(te))
        ka = P[j, dr.P_KT] * (1 - 0.5 * P[j, dr.P_UNB])
        kb = P[j, dr.P_KT] * (1 + 0.5 * P[j, dr.P_UNB])
        ideal = P[j, dr.P_IDEAL] > 0.5
        offa = 0.0 if ideal else P[j, dr.P_OFFA]
        offb = 0.0 if ideal else P[j, dr.P_OFFB]
        A = -ka * sa * math.sin(tem) + kb * sb * math.cos(tem)
        B = -(ka * sa * offa + kb * sb * offb)
        tau_det = P[j, dr.P_DET] * math.sin(4 * p * th)
        tau_in = tau[j] / nn * dr.resting_gear_factor(P[j, dr.P_ETA])  # the load at the motor shaft
        iref = (tau_in - tau_det - B) / A if abs(A) > 1e-12 else 0.0
        iref = float(np.clip(iref, -P[j, dr.P_IMAX], P[j, dr.P_IMAX]))
        ia = -iref * math.sin(tem) - offa
        ib = iref * math.cos(tem) - offb
        q_meas = q[j] + P[j, dr.P_EL] * math.sin(q[j])
        X[j, dr.S_TH] = th
        X[j, dr.S_IA] = ia
        X[j, dr.S_IB] = ib
        ua, ub = P[j, dr.P_R] * ia, P[j, dr.P_R] * ib  # the phase voltages at rest
        if P[j, dr.P_FOC] > 0.5:  # the current PIs' integrators hold them in the rotor's frame
            sm, cm = math.sin(tem), math.cos(tem)
            ua, ub = ua * cm + ub * sm, -ua * sm + ub * cm
        X[j, dr.S_XA] = ua
        X[j, dr.S_XB] = ub
        i_ff = P[j, dr.P_FFG] * tau_in / P[j, dr.P_KT]  # the gravity feed-forward's share of it
        if P[j, dr.P_KIV] > 0:
            X[j, dr.S_XV] = iref - i_ff
            hold[j] = q_meas
        else:  # P-only speed loop: the rest of the current comes from a standing position error
            g = P[j, dr.P_KPV] * nn * P[j, dr.P_KPP]
            hold[j] = q_meas + ((iref - i_ff) / g if g > 0 else 0.0)
    return X, hold
