"""What an external controller reads each control period: the drives' sensors, compiled like them.

The row layout is the protocol's (simecs.mesh.protocol.hil.SENSOR_FIELDS): the time, then per joint the load
and motor resolvers (angle and speed, with their modelled errors), the two measured phase currents,
the command's set points at that time (jog included) and the joint's command mode (references.JM_*).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from simecs.mesh.protocol.hil import SENSOR_JOINT_FIELDS

from . import drive as dr
from . import references

PER_JOINT = len(SENSOR_JOINT_FIELDS)  # the kernel below writes them in that order
assert PER_JOINT == 9


@njit(cache=dr._CACHE, error_model="numpy", fastmath=dr._FAST)
def sensor_row(P, sp, X, q, qd, t, out):
    """out[0] = t, then PER_JOINT values per joint; False when a value is not finite. `sp`: the set
    points (references.SetPointArrays)."""
    n = q.shape[0]
    qr = np.empty(n)
    qdr = np.empty(n)
    references.ref_eval(sp, t, qr, qdr)
    sig = np.empty(dr.NO + 10)
    out[0] = t
    for j in range(n):
        dr.controlled_signals(P, j, X, q[j], qd[j], qr[j], qdr[j], sp, sig)
        ql, qdl = dr.load_resolver(P, j, q[j], qd[j])
        th, om = dr.motor_resolver(P, j, X[j, dr.S_TH], X[j, dr.S_OM])
        k = 1 + PER_JOINT * j
        out[k] = ql
        out[k + 1] = qdl
        out[k + 2] = th
        out[k + 3] = om
        out[k + 4] = sig[7] + P[j, dr.P_OFFA]  # i_a, i_b as the current loops measure them
        out[k + 5] = sig[8] + P[j, dr.P_OFFB]
        out[k + 6] = qr[j]
        out[k + 7] = qdr[j]
        out[k + 8] = sp.jmode[j]
    ok = True
    for c in range(out.shape[0]):
        if not np.isfinite(out[c]):
            ok = False
    return ok
