"""Forward kinematics of a `ModelDescription` in plain numpy.

Clients use it for the kinematic simulation of the initialisation sliders (paper §5.2) without
importing any physics; the models use it to check that the chain they build in Exudyn is the one
they describe. Quaternions are (w, x, y, z).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from ..protocol.model import ModelDescription


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_rpy(rpy: Sequence[float]) -> np.ndarray:
    """R = Rz(yaw) @ Ry(pitch) @ Rx(roll): rotations about fixed x, then y, then z."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rpy_of(R: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw with R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2]: the inverse of
    `rot_rpy`, for poses given to clients and docs as rpy.

    Yaw comes from the first column, roll and pitch from R with the yaw taken out, so the three angles
    rebuild R to rounding even at pitch = +-pi/2 (where only roll - yaw or roll + yaw is defined and
    yaw is set to 0)."""
    M = np.asarray(R, dtype=float)
    if M.shape != (3, 3):
        raise ValueError(f"expected a 3 x 3 rotation matrix, got shape {M.shape}")
    if math.hypot(M[0, 0], M[1, 0]) < 1e-12:
        yaw = 0.0
    else:
        yaw = math.atan2(M[1, 0], M[0, 0])
    cy, sy = math.cos(yaw), math.sin(yaw)
    # Rz(-yaw) R = Ry(pitch) Rx(roll) = [[cp, sp sr, sp cr], [0, cr, -sr], [-sp, cp sr, cp cr]]
    m00 = cy * M[0, 0] + sy * M[1, 0]
    m11 = -sy * M[0, 1] + cy * M[1, 1]
    m12 = -sy * M[0, 2] + cy * M[1, 2]
    pitch = math.atan2(-M[2, 0], m00)
    roll = math.atan2(-m12, m11)
    return np.array([roll, pitch, yaw])


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix."""
    t = np.trace(m)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = np.array([(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s])
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = np.array([(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s])
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = np.array([(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def matrix_from_quat(q: Sequence[float] | np.ndarray) -> np.ndarray:
    """The rotation matrix of a quaternion (w, x, y, z), normalised first: a `pose.*` row's turn."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def link_frames(
    model: ModelDescription, values: Mapping[str, float], q: Sequence[float]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """World (position, rotation matrix) of every link frame, then of the tool frame.

    Link frame i sits at joint i after its rotation q_i and the link's initial rotation: its x axis
    points along the link, which is where the link's shapes are drawn.
    """
    if len(q) != len(model.links):
        raise ValueError(f"expected {len(model.links)} joint positions, got {len(q)}")
    pos = np.asarray(model.base_translation, dtype=float)
    rot = rot_rpy(model.base_rotation_rpy)
    frames = []
    for link, qi in zip(model.links, q, strict=True):
        rot = rot @ rot_z(float(qi)) @ rot_rpy(link.initial_rotation_rpy)
        frames.append((pos.copy(), rot.copy()))
        length = float(values[link.length_param])
        pos = pos + rot @ (np.array([length, 0.0, 0.0]) + np.asarray(link.final_translation, dtype=float))
    pos = pos + rot @ np.asarray(model.tool_translation, dtype=float)
    frames.append((pos, rot))
    return frames


def link_poses(model: ModelDescription, values: Mapping[str, float], q: Sequence[float]) -> np.ndarray:
    """Array (n_links + 1, 7) in `columns.POSE_FIELDS` order (x, y, z, qw, qx, qy, qz): the layout of
    the `pose.*` columns."""
    out = np.empty((len(model.links) + 1, 7))
    for i, (p, r) in enumerate(link_frames(model, values, q)):
        out[i, :3] = p
        out[i, 3:] = quat_from_matrix(r)
    return out
