"""How a model's shapes are drawn: one geometry for the viewer's 3D arm and the recordings' /scene.

A shape (model.py `Shape`) starts at `origin` in its link frame and extends `length` along `axis`,
centred across it; a sphere is centred on `origin`. Boxes and beams put `width` and `height` on the
two axes that follow `axis` cyclically (axis x: width along y, height along z; y: width z, height x;
z: width x, height y). Parameters reshape shapes in three ways (PROTOCOL.md §5.1): the resizable
shape of a link takes its link length, `scales_with` scales a dimension by value / default of a
parameter, and `anchor = "end"` measures the origin from the link's end.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from ..protocol.environment import Obstacle
from ..protocol.model import ModelDescription, Shape
from .kinematics import matrix_from_quat, quat_from_matrix, rot_rpy

WORLD = "world"
_S = math.sqrt(0.5)
#: Rotation that takes the local z axis onto each shape axis (w, x, y, z).
AXIS_WXYZ: dict[str, tuple[float, float, float, float]] = {
    "z": (1.0, 0.0, 0.0, 0.0),
    "x": (_S, 0.0, _S, 0.0),  # +90 deg about y: z -> x
    "y": (_S, -_S, 0.0, 0.0),  # -90 deg about x: z -> y
}
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
#: m: the side of the square a plane obstacle is drawn as (it is unbounded for contact).
PLANE_DRAWN_SIZE = 4.0
#: Dimensions a shape may tie to a parameter.
SCALABLE = ("length", "radius", "inner_radius", "width", "height")


@dataclass
class ShapeGeometry:
    """Where and how big one solid is in its parent frame: what a renderer needs to draw it.

    `kind` is cylinder, pipe, box, sphere or mesh (a beam is a box; a pipe without a usable bore a
    cylinder). Cylinders and pipes have their axis along the local z of `wxyz`, boxes their edges
    along its axes (the identity for a model's shapes, turned for an obstacle); a mesh's frame is at
    `position` turned by `wxyz`, its coordinates scaled by `dimensions`."""

    kind: str
    position: np.ndarray  # centre of the solid
    wxyz: tuple[float, float, float, float]
    radius: float = 0.0
    inner_ratio: float = 0.0  # pipe: inner radius / radius
    length: float = 0.0  # along the axis (cylinder, pipe)
    dimensions: tuple[float, float, float] = (0.0, 0.0, 0.0)  # box: x, y, z in the parent frame; mesh: scale
    mesh: str = ""  # mesh: its name in the model

    @property
    def visible(self) -> bool:
        return self.kind in ("box", "sphere", "mesh") or self.length > 1e-6


def effective_shape(
    shape: Shape, model: ModelDescription, values: Mapping[str, float], defaults: Mapping[str, float]
) -> Shape:
    """The shape as parameter values make it: what a changed appearance parameter reshapes."""
    out = msgspec.structs.replace(shape, origin=list(shape.origin))
    if shape.resizable and 0 <= shape.link < len(model.links):
        out.length = float(values.get(model.links[shape.link].length_param, shape.length))
    for dim, name in shape.scales_with.items():
        base = defaults.get(name)
        if dim in SCALABLE and base and name in values:
            setattr(out, dim, getattr(shape, dim) * float(values[name]) / float(base))
    if shape.anchor == "end" and 0 <= shape.link < len(model.links):
        param = model.links[shape.link].length_param
        out.origin[0] += float(values.get(param, 0.0)) - float(defaults.get(param, 0.0))
    return out


def shape_geometry(shape: Shape) -> ShapeGeometry:
    """Centre, orientation and size of `shape` (already made effective)."""
    origin = np.asarray(shape.origin, dtype=float)
    axis = shape.axis if shape.axis in _AXIS_INDEX else "x"
    k = _AXIS_INDEX[axis]
    length = max(float(shape.length), 0.0)
    centre = origin.copy()
    if shape.kind == "sphere":
        return ShapeGeometry("sphere", centre, AXIS_WXYZ["z"], radius=float(shape.radius))
    if shape.kind == "mesh":
        q = quat_from_matrix(rot_rpy(shape.rotation_rpy))
        scale = (float(shape.scale[0]), float(shape.scale[1]), float(shape.scale[2]))
        wxyz = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        return ShapeGeometry("mesh", centre, wxyz, dimensions=scale, mesh=shape.mesh)
    centre[k] += length / 2.0
    if shape.kind in ("box", "beam"):
        dims = [0.0, 0.0, 0.0]
        dims[k] = length
        dims[(k + 1) % 3] = float(shape.width)
        dims[(k + 2) % 3] = float(shape.height)
        return ShapeGeometry("box", centre, AXIS_WXYZ["z"], dimensions=(dims[0], dims[1], dims[2]))
    if shape.kind == "pipe" and 0.0 < shape.inner_radius < shape.radius:
        ratio = float(shape.inner_radius) / float(shape.radius)
        return ShapeGeometry(
            "pipe", centre, AXIS_WXYZ[axis], radius=float(shape.radius), inner_ratio=ratio, length=length
        )
    return ShapeGeometry("cylinder", centre, AXIS_WXYZ[axis], radius=float(shape.radius), length=length)


@dataclass
class Solid:
    """One drawn solid: the shape as described, the frame it hangs on, and its geometry now."""

    index: int  # position in model.shapes (or in model.environment for the world)
    frame: str  # a link name, or WORLD
    shape: Shape
    geometry: ShapeGeometry


def solids(model: ModelDescription, values: Mapping[str, float]) -> Iterator[Solid]:
    """Every solid of the model as `values` shape it: the environment and base shapes in the world
    frame, then each link's shapes on its link frame."""
    defaults = model.default_values()
    for k, shape in enumerate(model.environment):
        yield Solid(k, WORLD, shape, shape_geometry(shape))
    for k, shape in enumerate(model.shapes):
        if shape.link < 0:
            yield Solid(k, WORLD, shape, shape_geometry(shape))
    for k, shape in enumerate(model.shapes):
        if 0 <= shape.link < len(model.links):
            now = effective_shape(shape, model, values, defaults)
            yield Solid(k, model.links[shape.link].name, shape, shape_geometry(now))


def box_corners(lo: Sequence[float] | np.ndarray, hi: Sequence[float] | np.ndarray) -> np.ndarray:
    """The 8 corners (8 x 3) of the axis-aligned box from `lo` to `hi`."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    pick = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=bool)
    return np.where(pick, hi, lo)


def solid_corners(
    geom: ShapeGeometry, mesh_bounds: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """The corners (8 x 3) of a box around the solid, in its parent frame: what framing it in a view
    needs. A mesh's box is `mesh_bounds` (the low and high corners of its coordinates, `glb_bounds`)
    scaled and turned as drawn; without them the mesh stands for its origin (one row)."""
    if geom.kind == "mesh":
        if mesh_bounds is None:
            return np.asarray(geom.position, dtype=float).reshape(1, 3)
        scale = np.asarray(geom.dimensions, dtype=float)
        box = box_corners(np.asarray(mesh_bounds[0]) * scale, np.asarray(mesh_bounds[1]) * scale)
    elif geom.kind == "box":
        box = box_corners(-np.asarray(geom.dimensions) / 2, np.asarray(geom.dimensions) / 2)
    elif geom.kind == "sphere":
        box = box_corners(np.full(3, -geom.radius), np.full(3, geom.radius))
    else:  # cylinder, pipe: the axis along the local z of wxyz
        half = np.array([geom.radius, geom.radius, geom.length / 2])
        box = box_corners(-half, half)
    return box @ matrix_from_quat(geom.wxyz).T + np.asarray(geom.position, dtype=float)


def glb_bounds(data: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """Low and high corners of a box holding a binary glTF's vertices in its own frame, or None when
    it has none or is not one. Read from the `min` and `max` every POSITION accessor carries (glTF 2.0
    requires them), turned by the transforms of the nodes that place each mesh (so a turned part's box
    is a little larger than the tightest); no vertex is decoded."""
    corners: list[np.ndarray] = []
    try:
        magic, _version, _length, size, kind = struct.unpack_from("<4sIII4s", data, 0)
        if magic != b"glTF" or kind != b"JSON":
            return None
        doc = json.loads(data[20 : 20 + size])
        accessors, meshes, nodes = doc.get("accessors", []), doc.get("meshes", []), doc.get("nodes", [])
        scenes = doc.get("scenes", [])
        roots = scenes[doc.get("scene", 0)].get("nodes", []) if scenes else []
        todo = [(int(n), np.eye(4)) for n in roots]
        seen: set[int] = set()  # a glTF node has one parent at most: a node met again is a loop
        while todo:
            index, parent = todo.pop()
            if index in seen:
                continue
            seen.add(index)
            node = nodes[index]
            here = parent @ _node_matrix(node)
            for prim in meshes[node["mesh"]].get("primitives", []) if "mesh" in node else []:
                acc = accessors[prim["attributes"]["POSITION"]]
                box = box_corners(acc["min"][:3], acc["max"][:3])
                corners.append(box @ here[:3, :3].T + here[:3, 3])
            todo += [(int(c), here) for c in node.get("children", [])]
    except (struct.error, ValueError, KeyError, IndexError, TypeError, AttributeError):
        return None
    if not corners:
        return None
    every = np.concatenate(corners)
    return every.min(axis=0), every.max(axis=0)


def _node_matrix(node: Mapping[str, Any]) -> np.ndarray:
    """A glTF node's local transform (4 x 4): its `matrix` (column-major), or T R S."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=float).reshape(4, 4).T
    out = np.eye(4)
    x, y, z, w = (float(v) for v in node.get("rotation", (0.0, 0.0, 0.0, 1.0)))
    scale = np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=float)
    out[:3, :3] = matrix_from_quat((w, x, y, z)) * scale
    out[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return out


def obstacle_solids(obstacles: Sequence[Obstacle]) -> Iterator[Solid]:
    """Each obstacle as a solid in the world (its index: its place in the list)."""
    for k, ob in enumerate(obstacles):
        geom = obstacle_geometry(ob)
        kind: Any = geom.kind
        yield Solid(k, WORLD, Shape(kind, -1, list(ob.position), color=list(ob.color)), geom)


def appearance_parameters(model: ModelDescription) -> set[str]:
    """Parameters whose change reshapes the 3D arm."""
    names = {p.name for p in model.parameters if p.appearance}
    return names | {link.length_param for link in model.links}


def shape_bottom(geom: ShapeGeometry) -> float:
    """Lowest z of a solid whose parent frame is the world (for placing the floor)."""
    z = float(geom.position[2])
    if geom.kind == "box":
        return z - geom.dimensions[2] / 2
    if geom.kind == "sphere":
        return z - geom.radius
    if geom.kind == "mesh":  # its extent is in the mesh data: its origin stands for it
        return z
    if geom.wxyz == AXIS_WXYZ["z"]:
        return z - geom.length / 2
    return z - geom.radius


def pipe_mesh(inner_ratio: float, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A hollow tube of unit outer radius and unit length along z, centred on the origin.

    Scaled by (radius, radius, length) it is any pipe of that bore ratio; the walls and the two end
    rings have their own vertices so the edges stay crisp.
    """
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    outer, inner = ring, ring * inner_ratio
    verts = []
    for radius_ring in (outer, inner):  # walls: bottom ring then top ring
        for z in (-0.5, 0.5):
            verts.append(np.column_stack([radius_ring, np.full(segments, z)]))
    for z in (-0.5, 0.5):  # end rings: outer then inner
        verts.append(np.column_stack([outer, np.full(segments, z)]))
        verts.append(np.column_stack([inner, np.full(segments, z)]))
    v = np.concatenate(verts).astype(np.float32)
    i = np.arange(segments)
    j = (i + 1) % segments
    n = segments
    faces = []
    # outer wall (normals outward): bottom 0..n-1, top n..2n-1
    faces += [np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)]
    # inner wall (normals inward): bottom 2n.., top 3n..
    b, t = 2 * n, 3 * n
    faces += [np.stack([b + i, t + j, b + j], 1), np.stack([b + i, t + i, t + j], 1)]
    # bottom ring (normal -z): outer 4n.., inner 5n..
    o, q = 4 * n, 5 * n
    faces += [np.stack([o + i, q + j, o + j], 1), np.stack([o + i, q + i, q + j], 1)]
    # top ring (normal +z): outer 6n.., inner 7n..
    o, q = 6 * n, 7 * n
    faces += [np.stack([o + i, o + j, q + j], 1), np.stack([o + i, q + j, q + i], 1)]
    return v, np.concatenate(faces).astype(np.uint32)


def obstacle_rotation(ob: Obstacle) -> np.ndarray:
    """The obstacle's frame in the world (3 x 3)."""
    return rot_rpy(ob.rotation_rpy)


def obstacle_geometry(ob: Obstacle) -> ShapeGeometry:
    """How a renderer draws it: a plane as a thin square slab just under its surface."""
    R = obstacle_rotation(ob)
    q = quat_from_matrix(R)
    wxyz = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
    centre = np.asarray(ob.position, dtype=float)
    if ob.kind == "sphere":
        return ShapeGeometry("sphere", centre, AXIS_WXYZ["z"], radius=float(ob.radius))
    if ob.kind == "cylinder":
        return ShapeGeometry("cylinder", centre, wxyz, radius=float(ob.radius), length=float(ob.length))
    if ob.kind == "plane":
        slab = 0.01
        centre = centre - R[:, 2] * slab / 2
        return ShapeGeometry("box", centre, wxyz, dimensions=(PLANE_DRAWN_SIZE, PLANE_DRAWN_SIZE, slab))
    return ShapeGeometry("box", centre, wxyz, dimensions=(ob.size[0], ob.size[1], ob.size[2]))
