"""One result row of a run, from the drive states and the chain state at a sample's time: the time, every
joint's variables (drive.drive_outputs), the tool's error against its set-point pose, the contacts', the
grasp's, and the link, tool and grasped-object poses. No Exudyn call: the chain's frames are computed here
once and serve every part of the row.

The columns are `mesh.protocol.columns.run_columns`'; this kernel writes their values in that order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .chain_dynamics import pose_rows_at
from .chain_kinematics import rotation_vector, tool_frames
from .contact import contact_outputs, output_count
from .drive import NO, NT, drive_outputs
from .grasp import GRASP_OUTPUTS, grasp_outputs
from .jit import CACHE as _CACHE
from .jit import FAST as _FAST


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def output_row(P, sp, X, q, qd, t, chain, Rrpy, tool_local, contact, grasp, rows, k):
    """One result row into rows[k]: time, the variables of every joint, the tool's, the contacts', the
    grasp's, the link and tool poses and the grasped object's. `sp`: the set points
    (references.SetPointArrays); `chain`: mechanics.ChainArrays; `contact`: contact.ContactTables;
    `grasp` the grasp state of grasp.py.

    Returns 0, or 1 when the chain coordinates are not finite (row untouched), 2 when an output is not.
    """
    n = q.shape[0]
    for j in range(n):
        if not (math.isfinite(q[j]) and math.isfinite(qd[j])):
            return 1
    row = rows[k]
    row[0] = t
    out = np.empty((n, NO))
    drive_outputs(P, sp, X, q, qd, t, out)
    for j in range(n):
        for c in range(NO):
            row[1 + j * NO + c] = out[j, c]
    # the tool against the tool pose of the set points; the chain's frames serve the pose rows too
    frames = np.empty((2, n, 3, 3))  # at q and at the set points (one allocation per shape)
    origins = np.empty((2, n, 3))
    R_all, Rr_all, p_all, pr_all = frames[0], frames[1], origins[0], origins[1]
    threes = np.empty((3, 3))
    p, p_r, erot = threes[0], threes[1], threes[2]
    mats = np.empty((2, 3, 3))
    R, R_r = mats[0], mats[1]
    pre_R, pre_p = chain.pre_R, chain.pre_p
    tool_frames(pre_R, pre_p, Rrpy[n - 1], tool_local, q, R_all, p_all, p, R)
    tool_frames(pre_R, pre_p, Rrpy[n - 1], tool_local, out[:, 2].copy(), Rr_all, pr_all, p_r, R_r)
    k0 = 1 + n * NO
    row[k0] = p_r[0]
    row[k0 + 1] = p_r[1]
    row[k0 + 2] = p_r[2]
    row[k0 + 3] = math.sqrt((p_r[0] - p[0]) ** 2 + (p_r[1] - p[1]) ** 2 + (p_r[2] - p[2]) ** 2)
    row[k0 + 4] = rotation_vector(R, R_r, erot)
    k0 += NT
    spheres, bounds, obs, caps = contact.spheres, contact.bounds, contact.obs, contact.caps
    touch = np.empty(output_count(n))
    contact_outputs(spheres, bounds, obs, caps, R_all, p_all, qd, touch)
    for c in range(touch.shape[0]):
        row[k0 + c] = touch[c]
    k0 += touch.shape[0]
    held = np.empty(len(GRASP_OUTPUTS))
    poses = np.empty((n + 2, 7))
    grasp_outputs(grasp, R_all[n - 1], p_all[n - 1], held, poses[n + 1])
    for c in range(held.shape[0]):
        row[k0 + c] = held[c]
    k0 += held.shape[0]
    pose_rows_at(R_all, p_all, Rrpy, tool_local, poses)
    for i in range(n + 2):
        for c in range(7):
            row[k0 + 7 * i + c] = poses[i, c]
    for c in range(row.shape[0]):
        if not math.isfinite(row[c]):
            return 2
    return 0
