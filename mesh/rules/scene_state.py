"""What a run's rows say about the world around the arm: where the obstacles are (an object the tool
grasped moves with it, and stays where it was released) and the contact forces as arrows.

The viewer's 3D scene and the recordings' Foxglove /scene both draw from here, so they agree with each
other and with the columns the simulator writes (mesh/protocol/columns.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import msgspec
import numpy as np

from ..protocol import columns
from ..protocol.environment import Obstacle
from .kinematics import matrix_from_quat, rpy_of

#: m per N of a contact arrow's length, and its bounds (a 1 N touch stays visible, 1 kN stays in view).
ARROW_M_PER_N = 0.001
ARROW_MIN_M, ARROW_MAX_M = 0.03, 0.3
#: N: a link touching with less is drawn without an arrow.
ARROW_MIN_FORCE = 0.5


class WorldColumns:
    """Where a run's grasp and contact columns sit in one list of columns (a layout's, or the live
    subset); `ok` is False when any is missing (a run of a simecs before grasping, or a live stream
    that left them out)."""

    def __init__(self, names: Sequence[str]) -> None:
        where = {c: i for i, c in enumerate(names)}
        n_links = 0
        while columns.contact_column(n_links + 1, columns.CONTACT_VECTOR[0]) in where:
            n_links += 1
        pose = columns.pose_indices(names, [columns.GRASPED_FRAME])
        self.pose = pose[0] if pose is not None else None
        self.object = where.get(columns.GRASP_OBJECT)
        self.held = where.get(columns.GRASP_HELD)
        fields = [*columns.CONTACT_VECTOR, *columns.CONTACT_POINT]
        links = [[where.get(columns.contact_column(i + 1, f)) for f in fields] for i in range(n_links)]
        complete = bool(links) and all(k is not None for row in links for k in row)
        self.contacts = np.array(links, dtype=int) if complete else None

    @property
    def grasps(self) -> bool:
        return self.pose is not None and self.object is not None

    def moved(self, rows: np.ndarray, into: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        """`into` updated with where each grasped obstacle is after `rows` (its index in the run's
        list -> x, y, z, qw, qx, qy, qz): the pose of the last row that names it."""
        if not self.grasps or rows.shape[0] == 0:
            return into
        assert self.object is not None and self.pose is not None
        numbers = rows[:, self.object].astype(int)
        for number in np.unique(numbers[numbers > 0]):
            last = int(np.flatnonzero(numbers == number)[-1])
            into[int(number) - 1] = rows[last, self.pose].astype(float)
        return into

    def arrows(self, row: np.ndarray) -> np.ndarray:
        """The contact forces of one row as arrows (k, 2, 3): from where each touching link is pushed,
        along the force, ARROW_M_PER_N long (within ARROW_MIN_M and ARROW_MAX_M)."""
        if self.contacts is None:
            return np.zeros((0, 2, 3))
        values = row[self.contacts]  # (links, 6): force vector, point
        force = values[:, :3]
        size = np.linalg.norm(force, axis=1)
        touching = size >= ARROW_MIN_FORCE
        if not np.any(touching):
            return np.zeros((0, 2, 3))
        start = values[touching, 3:]
        length = np.clip(size[touching] * ARROW_M_PER_N, ARROW_MIN_M, ARROW_MAX_M)
        end = start + force[touching] / size[touching, None] * length[:, None]
        return np.stack([start, end], axis=1)

    def grasp_changes(self, rows: np.ndarray, before: tuple[int, int]) -> list[tuple[int, tuple[int, int]]]:
        """The rows where what the tool holds changes ((object, held) unlike the row before; `before`:
        the state ahead of `rows`), with the state from there on."""
        if not self.grasps or rows.shape[0] == 0:
            return []
        assert self.object is not None and self.held is not None
        state = rows[:, self.object].astype(int) * 2 + (rows[:, self.held] > 0.5)
        previous = np.concatenate([[before[0] * 2 + before[1]], state[:-1]])
        return [(int(k), (int(state[k]) // 2, int(state[k]) % 2)) for k in np.flatnonzero(state != previous)]


def at_pose(ob: Obstacle, centre: Sequence[float] | np.ndarray, frame: np.ndarray) -> Obstacle:
    """`ob` moved: its centre to `centre`, its frame to `frame` (3 x 3, world): where a grasp and a
    release leave it."""
    rpy = rpy_of(frame)
    return msgspec.structs.replace(
        ob, position=[float(v) for v in centre], rotation_rpy=[float(v) for v in rpy]
    )


def placed(obstacles: Sequence[Obstacle], moved: Mapping[int, np.ndarray]) -> list[Obstacle]:
    """`obstacles` with the moved ones at their poses (index -> x, y, z, qw, qx, qy, qz)."""
    out = list(obstacles)
    for index, pose in moved.items():
        if 0 <= index < len(out):
            out[index] = at_pose(out[index], pose[:3], matrix_from_quat(pose[3:7]))
    return out
