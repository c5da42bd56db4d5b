"""The recordings' Foxglove `/scene` (mcapfmt.py has the rest of the format): the model's solids as
frame-locked entities once per run (`scene_update`, the geometry the viewer draws, mesh/rules/shapes.py),
then the world around the arm as the run's rows move it (`WorldScene`: obstacles a grasp carries or
a release puts down, contact arrows).
"""

from __future__ import annotations

import base64
import bisect
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from simecs.mesh.protocol import columns
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.model import ModelDescription
from simecs.mesh.rules import scene_state, shapes

from .mcapfmt import WORLD_FRAME, FormatError, stamp


def _color(rgb: Sequence[int]) -> dict[str, float]:
    r, g, b = (list(rgb) + [200, 200, 200])[:3]
    return {"r": r / 255.0, "g": g / 255.0, "b": b / 255.0, "a": 1.0}


def _pose(center: Iterable[float], wxyz: Iterable[float]) -> dict[str, Any]:
    x, y, z = (float(v) for v in center)
    qw, qx, qy, qz = (float(v) for v in wxyz)
    return {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def scene_primitive(solid: shapes.Solid, meshes: Mapping[str, bytes]) -> tuple[str, dict[str, Any]] | None:
    """(entity list name, Foxglove primitive) of one solid, from the geometry the viewer draws too;
    None for a mesh whose GLB is not in `meshes`.

    Foxglove has no pipe: a pipe is drawn as a cylinder of its outer radius (the same outside). A mesh
    is a model primitive with its GLB embedded (its own colours, not overridden)."""
    g = solid.geometry
    color = _color(solid.shape.color)
    pose = _pose(g.position, g.wxyz)
    if g.kind == "mesh":
        data = meshes.get(g.mesh)
        if data is None:
            return None
        sx, sy, sz = g.dimensions
        return "models", {
            "pose": pose,
            "scale": {"x": sx, "y": sy, "z": sz},
            "color": color,
            "override_color": False,
            "url": "",
            "media_type": "model/gltf-binary",
            "data": base64.b64encode(data).decode("ascii"),
        }
    if g.kind in ("cylinder", "pipe"):
        d = 2 * g.radius
        size = {"x": d, "y": d, "z": g.length}
        return "cylinders", {
            "pose": pose,
            "size": size,
            "bottom_scale": 1.0,
            "top_scale": 1.0,
            "color": color,
        }
    if g.kind == "box":
        size = {"x": g.dimensions[0], "y": g.dimensions[1], "z": g.dimensions[2]}
        return "cubes", {"pose": pose, "size": size, "color": color}
    if g.kind == "sphere":
        d = 2 * g.radius
        return "spheres", {"pose": pose, "size": {"x": d, "y": d, "z": d}, "color": color}
    raise FormatError(f"shape kind {g.kind!r} has no Foxglove primitive")


def scene_update(
    model: ModelDescription,
    values: Mapping[str, float],
    stamp_ns: int,
    meshes: Mapping[str, bytes] | None = None,
    obstacles: Sequence[Obstacle] = (),
) -> dict[str, Any]:
    """foxglove.SceneUpdate: one frame-locked entity per link (frame = link name), plus the world's
    solids (environment and base) in one entity and the run's obstacles in another, all shaped by the
    run's parameter values; a mesh shape carries the GLB of `meshes` (left out when it is missing)."""
    entities: dict[str, dict[str, Any]] = {}
    drawn_solids = [(s, "") for s in shapes.solids(model, values)]
    drawn_solids += [(s, OBSTACLES_ENTITY) for s in shapes.obstacle_solids(obstacles)]
    for solid, group in drawn_solids:
        if not solid.geometry.visible:
            continue
        world = solid.frame == shapes.WORLD
        eid = group or ("environment" if world else solid.frame)
        if eid not in entities:
            entities[eid] = _entity(eid, WORLD_FRAME if world else solid.frame, stamp_ns, model.id)
        drawn = scene_primitive(solid, meshes or {})
        if drawn is not None:
            entities[eid][drawn[0]].append(drawn[1])
    return {"deletions": [], "entities": list(entities.values())}


def _entity(eid: str, frame: str, stamp_ns: int, model_id: str) -> dict[str, Any]:
    """An empty foxglove.SceneEntity; frame-locked unless its frame is the world."""
    return {
        "timestamp": stamp(stamp_ns),
        "frame_id": frame,
        "id": eid,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": frame != WORLD_FRAME,
        "metadata": [{"key": "model", "value": model_id}],
        "arrows": [],
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [],
    }


#: /scene entities of the world around the arm: the obstacles where they are, the one the tool holds
#: (locked to the `grasped` frame of /tf), the contact forces' arrows.
OBSTACLES_ENTITY, HELD_ENTITY, CONTACTS_ENTITY = "obstacles", "held", "contacts"
CONTACT_COLOR = {"r": 0.86, "g": 0.12, "b": 0.12, "a": 1.0}


class WorldScene:
    """The /scene updates that follow a run's rows (mesh/rules/scene_state.py): obstacles moved by a grasp
    or a release, and the contact arrows at the /tf rate. The first /scene (scene_update) drew the
    obstacles where the run's list puts them.

    Rows come in time order, except the ones that fill a gap after the run (`backfill`): those start
    from what the tool held at their own time, so a late gap never redraws an old grasp as the last
    word (readers order /scene by log time)."""

    def __init__(self, names: Sequence[str], obstacles: Sequence[Obstacle], model_id: str) -> None:
        self.world = scene_state.WorldColumns(names)
        self.obstacles = list(obstacles)
        self.model_id = model_id
        # (log time, (object, held), moved obstacles) from each grasp change on, in time order
        self._timeline: list[tuple[int, tuple[int, int], dict[int, np.ndarray]]] = [(-1, (0, 0), {})]
        self._arrows = 0  # arrows drawn by the last contact update in time order

    def grasp_updates(
        self, rows: np.ndarray, log_ns: Sequence[int], backfill: bool = False
    ) -> list[tuple[int, dict[str, Any]]]:
        """(log time, SceneUpdate) at each row where what the tool holds changes."""
        out: list[tuple[int, dict[str, Any]]] = []
        if not self.obstacles or rows.shape[0] == 0:
            return out
        before = self._at(int(log_ns[0])) if backfill else len(self._timeline) - 1
        _, state_before, moved_before = self._timeline[before]
        moved = dict(moved_before)
        for k, state in self.world.grasp_changes(rows, state_before):
            ns = int(log_ns[k])
            self.world.moved(rows[k : k + 1], moved)
            out.append((ns, self._obstacles_update(state, moved, ns)))
            bisect.insort(self._timeline, (ns, state, dict(moved)), key=lambda entry: entry[0])
        return out

    def _at(self, ns: int) -> int:
        """The index of the timeline's entry in force just before log time `ns`."""
        return bisect.bisect_left(self._timeline, ns, key=lambda entry: entry[0]) - 1

    def _obstacles_update(
        self, state: tuple[int, int], moved: dict[int, np.ndarray], ns: int
    ) -> dict[str, Any]:
        number, held = state
        here = scene_state.placed(self.obstacles, moved)
        carried = number - 1 if held else -1
        world = _entity(OBSTACLES_ENTITY, WORLD_FRAME, ns, self.model_id)
        _draw_obstacles(world, [ob for k, ob in enumerate(here) if k != carried])
        update: dict[str, Any] = {"deletions": [], "entities": [world]}
        if 0 <= carried < len(here):
            entity = _entity(HELD_ENTITY, columns.GRASPED_FRAME, ns, self.model_id)
            _draw_obstacles(entity, [scene_state.at_pose(here[carried], np.zeros(3), np.eye(3))])
            update["entities"].append(entity)
        else:
            update["deletions"].append({"timestamp": stamp(ns), "type": 0, "id": HELD_ENTITY})
        return update

    def contacts_updates(
        self, rows: np.ndarray, log_ns: Sequence[int], backfill: bool = False
    ) -> list[tuple[int, dict[str, Any]]]:
        """(log time, SceneUpdate) of the contact arrows at each of `rows` (the /tf samples), where they
        change from nothing to nothing are left out. A backfilled piece clears its arrows at its end:
        the live rows after the gap drew theirs, or none, on their own."""
        out: list[tuple[int, dict[str, Any]]] = []
        drawn = 0 if backfill else self._arrows
        for row, ns in zip(rows, log_ns, strict=True):
            arrows = self.world.arrows(row)
            if arrows.shape[0] == 0 and drawn == 0:
                continue
            drawn = arrows.shape[0]
            out.append((int(ns), self._contacts_entity(arrows, int(ns))))
        if backfill and drawn and len(log_ns):
            out.append((int(log_ns[-1]) + 1, self._contacts_entity(np.zeros((0, 2, 3)), int(log_ns[-1]) + 1)))
        elif not backfill:
            self._arrows = drawn
        return out

    def _contacts_entity(self, arrows: np.ndarray, ns: int) -> dict[str, Any]:
        entity = _entity(CONTACTS_ENTITY, WORLD_FRAME, ns, self.model_id)
        for start, end in arrows:
            entity["arrows"].append(_arrow(start, end))
        return {"deletions": [], "entities": [entity]}


def _draw_obstacles(entity: dict[str, Any], obstacles: Sequence[Obstacle]) -> None:
    """The obstacles' primitives into `entity` (the geometry scene_update draws them with)."""
    for solid in shapes.obstacle_solids(obstacles):
        drawn = scene_primitive(solid, {})
        if drawn is not None and solid.geometry.visible:
            entity[drawn[0]].append(drawn[1])


def _arrow(start: np.ndarray, end: np.ndarray) -> dict[str, Any]:
    """A foxglove.ArrowPrimitive from start to end (it points along its pose's +x)."""
    d = end - start
    length = float(np.linalg.norm(d))
    x = d / length if length > 0 else np.array([1.0, 0.0, 0.0])
    w = 1.0 + float(x[0])  # the rotation taking +x onto x: half-way quaternion (w, x cross v)
    q = np.array([w, 0.0, -float(x[2]), float(x[1])]) if w > 1e-9 else np.array([0.0, 0.0, 0.0, 1.0])
    q /= np.linalg.norm(q)
    head = min(0.025, 0.4 * length)
    return {
        "pose": _pose(start, q),
        "shaft_length": max(length - head, 0.0),
        "shaft_diameter": 0.008,
        "head_length": head,
        "head_diameter": 0.024,
        "color": CONTACT_COLOR,
    }
