"""The columns of a run's sample frames: their names, and which of them a consumer picks.

A run's columns are `time`, then every variable of the model's catalog, then the pose of every link
frame, of the tool and of the object the tool grasped last (`pose.<frame>.<field>`, fields in
`POSE_FIELDS` order). The simulator writes
them in this order, the viewer poses the arm from them, the recorder turns them into Foxglove
transforms and joint states: all through this module.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

TIME = "time"
#: Position in m, then the orientation quaternion w first.
POSE_FIELDS = ("x", "y", "z", "qw", "qx", "qy", "qz")
POSE_UNITS = ("m", "m", "m", "-", "-", "-", "-")
TOOL_FRAME = "tool"
#: The object the tool holds (or the last one it released, where it left it; the world origin before
#: any grasp): `grasp.object` says which obstacle it is, `grasp.held` whether the tool holds it.
GRASPED_FRAME = "grasped"
#: Frames every run has besides its links, in this order after them (ModelDescription.pose_frames): a
#: link cannot take these names.
RESERVED_FRAMES = (TOOL_FRAME, GRASPED_FRAME)
#: The per-joint quantities Foxglove JointStates shows: position, velocity, and the first effort found.
JOINT_POSITION, JOINT_VELOCITY = "q", "qd"
JOINT_EFFORTS = ("tau_gear", "tau", "effort")


#: The grasp's columns (models/grasp.py): the obstacle the tool took last (1.. in the run's list, 0:
#: none yet) and whether it holds it.
GRASP_OBJECT = "grasp.object"
GRASP_HELD = "grasp.held"
#: A link's contact columns (models/contact.py): `force` (N) and `obstacle` (1.., 0 = none), the force
#: vector `fx fy fz` (N, world) and the point it acts at `px py pz` (m, world).
CONTACT_FORCE, CONTACT_OBSTACLE = "force", "obstacle"
CONTACT_VECTOR, CONTACT_POINT = ("fx", "fy", "fz"), ("px", "py", "pz")


def contact_column(link: int, field: str) -> str:
    """The contact column `field` of link number `link` (1-based, as the variables name it)."""
    return f"contact.link{link}.{field}"


#: What every link pose column's name starts with (`pose.<frame>.<field>`).
POSE_PREFIX = "pose."


def pose_column(frame: str, field: str) -> str:
    return f"{POSE_PREFIX}{frame}.{field}"


def is_pose(column: str) -> bool:
    return column.startswith("pose.")


def is_scene(column: str) -> bool:
    """Whether the 3D scene draws from `column`: poses, the grasp, the contact forces' vectors and
    points (mesh/rules/scene_state.py)."""
    if is_pose(column) or column in (GRASP_OBJECT, GRASP_HELD):
        return True
    head, _, field = column.rpartition(".")
    return head.startswith("contact.link") and field in (*CONTACT_VECTOR, *CONTACT_POINT)


def live_columns(columns: Sequence[str], live_vars: Sequence[str]) -> list[str]:
    """What a run forwards live: time, the chosen variables (all when none are chosen) that the run
    has, and every column the 3D scene draws from (the arm always moves, its contacts show)."""
    present = set(columns)
    variables = [c for c in columns[1:] if not is_pose(c)]
    chosen = [v for v in live_vars if v in present] if live_vars else variables
    taken = set(chosen)
    return [TIME, *chosen, *[c for c in columns if is_scene(c) and c not in taken]]


def joint_column(joint: str, quantity: str) -> str:
    return f"{joint}.{quantity}"


def pose_indices(columns: Sequence[str], frames: Sequence[str]) -> np.ndarray | None:
    """Column indices (len(frames), 7) of each frame's pose in `columns`, fields in POSE_FIELDS order;
    None if any is missing."""
    where = {c: i for i, c in enumerate(columns)}
    out = np.empty((len(frames), len(POSE_FIELDS)), dtype=int)
    for r, frame in enumerate(frames):
        for c, field in enumerate(POSE_FIELDS):
            idx = where.get(pose_column(frame, field))
            if idx is None:
                return None
            out[r, c] = idx
    return out


def posed_frames(columns: Sequence[str]) -> list[str]:
    """The frames that have all seven pose columns in `columns`, in column order."""
    present = set(columns)
    frames = []
    for c in columns:
        if is_pose(c) and c.endswith(".x"):
            frame = c[len("pose.") : -len(".x")]
            if frame and all(pose_column(frame, f) in present for f in POSE_FIELDS):
                frames.append(frame)
    return frames


def joint_state_columns(columns: Sequence[str]) -> list[tuple[str, str, str, str | None]]:
    """(joint, position column, velocity column, effort column or None) of every joint that has a
    position and a velocity column."""
    present = set(columns)
    out = []
    for c in columns:
        if is_pose(c) or not c.endswith(f".{JOINT_POSITION}"):
            continue
        joint = c[: -len(JOINT_POSITION) - 1]
        velocity = joint_column(joint, JOINT_VELOCITY)
        if not joint or velocity not in present:
            continue
        effort = next(
            (joint_column(joint, e) for e in JOINT_EFFORTS if joint_column(joint, e) in present), None
        )
        out.append((joint, c, velocity, effort))
    return out
