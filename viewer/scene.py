"""The 3D virtual prototype (paper §2.2, §5.1): solid shapes on link frames, in an environment.

Everything comes from the `ModelDescription` the server sends: link frames follow the paper's Link
convention and are posed either by the kinematic simulation of the sliders (`mesh.kinematics`) or by
the `pose.*` columns of the live stream; each shape hangs on its link frame, and the one resizable
shape per link takes the link length parameter, so an edited length reshapes the arm at once.

Shape conventions (mesh/model.py `Shape`): a solid starts at `origin` (in its link frame) and extends
`length` along `axis`, centred across it. Boxes and beams put `width` and `height` on the two axes
that follow `axis` cyclically (axis x: width along y, height along z; y: width z, height x; z: width x,
height y). A sphere is centred on `origin`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from simecs.mesh.kinematics import link_poses
from simecs.mesh.model import ModelDescription, Shape

_S = math.sqrt(0.5)
#: Rotation that takes the local z axis onto each shape axis (w, x, y, z).
AXIS_WXYZ: dict[str, tuple[float, float, float, float]] = {
    "z": (1.0, 0.0, 0.0, 0.0),
    "x": (_S, 0.0, _S, 0.0),  # +90 deg about y: z -> x
    "y": (_S, -_S, 0.0, 0.0),  # -90 deg about x: z -> y
}
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


@dataclass
class ShapeGeometry:
    """Where and how big one solid is, in its parent frame: what the scene needs to draw it."""

    kind: str  # cylinder | pipe | box | sphere
    position: np.ndarray  # centre of the solid
    wxyz: tuple[float, float, float, float]
    radius: float = 0.0
    inner_ratio: float = 0.0  # pipe: inner radius / radius
    length: float = 0.0  # along the axis (cylinder, pipe)
    dimensions: tuple[float, float, float] = (0.0, 0.0, 0.0)  # box: x, y, z in the parent frame


def shape_length(shape: Shape, model: ModelDescription, values: Mapping[str, float]) -> float:
    """The drawn length of a shape: the link length parameter for the resizable shape of a link."""
    if shape.resizable and 0 <= shape.link < len(model.links):
        return float(values.get(model.links[shape.link].length_param, shape.length))
    return float(shape.length)


#: Dimensions a shape may tie to a parameter (see `effective_shape`).
SCALABLE = ("length", "radius", "inner_radius", "width", "height")


def effective_shape(
    shape: Shape, model: ModelDescription, values: Mapping[str, float], defaults: Mapping[str, float]
) -> Shape:
    """The shape as parameter values make it: what a changed appearance parameter reshapes.

    The protocol ties the resizable shape's length to its link length, and two further ties
    (PROTOCOL.md §5.1): `scales_with` ({dimension: parameter}) scales a dimension by value / default
    of the parameter, and `anchor = "end"` measures the origin from the link's end, so the shape
    moves with its length.
    """
    out = replace(shape, origin=list(shape.origin))
    out.length = shape_length(shape, model, values)
    for dim, name in shape.scales_with.items():
        base = defaults.get(name)
        if dim in SCALABLE and base and name in values:
            setattr(out, dim, getattr(shape, dim) * float(values[name]) / float(base))
    if shape.anchor == "end" and 0 <= shape.link < len(model.links):
        param = model.links[shape.link].length_param
        out.origin[0] += float(values.get(param, 0.0)) - float(defaults.get(param, 0.0))
    return out


def shape_geometry(shape: Shape, length: float) -> ShapeGeometry:
    """Centre, orientation and size of `shape` drawn with `length` along its axis."""
    origin = np.asarray(shape.origin, dtype=float)
    axis = shape.axis if shape.axis in _AXIS_INDEX else "x"
    k = _AXIS_INDEX[axis]
    length = max(float(length), 0.0)
    centre = origin.copy()
    if shape.kind == "sphere":
        return ShapeGeometry("sphere", centre, AXIS_WXYZ["z"], radius=float(shape.radius))
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
    # cylinder, and a pipe without a usable bore, are drawn solid
    return ShapeGeometry("cylinder", centre, AXIS_WXYZ[axis], radius=float(shape.radius), length=length)


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


def shape_bottom(geom: ShapeGeometry) -> float:
    """Lowest z of a solid whose parent frame is the world (for placing the floor grid)."""
    z = float(geom.position[2])
    if geom.kind == "box":
        return z - geom.dimensions[2] / 2
    if geom.kind == "sphere":
        return z - geom.radius
    if geom.wxyz == AXIS_WXYZ["z"]:
        return z - geom.length / 2
    return z - geom.radius


def pose_indices(columns: Sequence[str], model: ModelDescription) -> np.ndarray | None:
    """Column indices (n_links, 7) of every link's pose in a frame with `columns`; None if any is missing."""
    where = {c: i for i, c in enumerate(columns)}
    out = np.empty((len(model.links), 7), dtype=int)
    for r, link in enumerate(model.links):
        for c, f in enumerate(("x", "y", "z", "qw", "qx", "qy", "qz")):
            idx = where.get(f"pose.{link.name}.{f}")
            if idx is None:
                return None
            out[r, c] = idx
    return out


class ArmScene:
    """One tab's 3D prototype: environment, link frames with their solids, and their poses."""

    def __init__(
        self,
        scene: Any,
        model: ModelDescription,
        values: Mapping[str, float],
        root: str = "/arm",
        shadows: bool = False,
    ):
        self.scene = scene
        self.model = model
        self.root = root
        self.shadows = shadows
        self.values = dict(values)
        self.defaults = model.default_values()
        self.frames: list[Any] = []
        self.solids: list[tuple[Shape, Any, str]] = []  # (shape, handle, kind) of link shapes
        self._pipe_meshes: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._env: list[Any] = []
        self.q: list[float] = [0.0] * len(model.links)

    # -- building ------------------------------------------------------------------------------
    def build(self) -> None:
        """Add the environment, then one frame per link with its solids (all in one batch)."""
        # Shadows cost a shadow-map pass per frame: several times the frame time on a machine
        # without a GPU (software WebGL), where they would stall the whole page.
        self.scene.configure_default_lights(enabled=True, cast_shadow=self.shadows)
        if not self.shadows:  # an environment map costs as much again; plain lights instead
            self.scene.configure_environment_map(None)
            self._env.append(
                self.scene.add_light_hemisphere(
                    "/env/sky", sky_color=(255, 255, 255), ground_color=(160, 160, 170), intensity=2.0
                )
            )
        floor_z = 0.0
        bottoms = []
        for k, shape in enumerate(self.model.environment):
            geom = shape_geometry(shape, shape.length)
            self._env.append(self._add_solid(f"/env/s{k}", shape, geom)[0])
            bottoms.append(shape_bottom(geom))
        base = [s for s in self.model.shapes if s.link < 0]
        for k, shape in enumerate(base):
            geom = shape_geometry(shape, shape.length)
            self._env.append(self._add_solid(f"/env/base{k}", shape, geom)[0])
            bottoms.append(shape_bottom(geom))
        if bottoms:
            floor_z = min(bottoms) - 1e-3
        reach = sum(abs(self.values.get(link.length_param, 0.0)) for link in self.model.links)
        size = max(4.0, 2.5 * reach)
        self._env.append(
            self.scene.add_grid(
                "/env/floor",
                width=size,
                height=size,
                cell_size=0.25,
                section_size=1.0,
                position=(0.0, 0.0, floor_z),
                plane_color=(236, 238, 242),
                plane_opacity=1.0,
                shadow_opacity=0.2 if self.shadows else 0.0,
            )
        )
        for link in self.model.links:
            frame = self.scene.add_frame(
                f"{self.root}/{link.name}", show_axes=False, axes_length=0.1, axes_radius=0.004
            )
            self.frames.append(frame)
        for k, shape in enumerate(s for s in self.model.shapes if s.link >= 0):
            name = f"{self.root}/{self.model.links[shape.link].name}/s{k}"
            now = effective_shape(shape, self.model, self.values, self.defaults)
            handle, kind = self._add_solid(name, now, shape_geometry(now, now.length))
            self.solids.append((shape, handle, kind))
        self.show_q(self.q)

    def _add_solid(self, name: str, shape: Shape, geom: ShapeGeometry) -> tuple[Any, str]:
        color = tuple(int(c) for c in shape.color[:3])
        light = {"cast_shadow": self.shadows, "receive_shadow": self.shadows}
        if geom.kind == "box":
            h = self.scene.add_box(
                name, color=color, dimensions=geom.dimensions, position=geom.position, **light
            )
        elif geom.kind == "sphere":
            h = self.scene.add_icosphere(
                name, radius=geom.radius, color=color, position=geom.position, **light
            )
        elif geom.kind == "pipe":
            verts, faces = self._pipe(geom.inner_ratio)
            h = self.scene.add_mesh_simple(
                name,
                verts,
                faces,
                color=color,
                scale=(geom.radius, geom.radius, max(geom.length, 1e-6)),
                wxyz=geom.wxyz,
                position=geom.position,
                flat_shading=False,
                **light,
            )
        else:
            h = self.scene.add_cylinder(
                name,
                radius=geom.radius,
                height=max(geom.length, 1e-6),
                color=color,
                wxyz=geom.wxyz,
                position=geom.position,
                **light,
            )
        h.visible = geom.kind == "sphere" or geom.length > 1e-6 or geom.kind == "box"
        return h, geom.kind

    def _pipe(self, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        key = round(ratio, 4)
        if key not in self._pipe_meshes:
            self._pipe_meshes[key] = pipe_mesh(key)
        return self._pipe_meshes[key]

    # -- updating --------------------------------------------------------------------------------
    def set_values(self, values: Mapping[str, float]) -> bool:
        """Take new parameter values; reshape the solids they change and re-pose the arm.

        Returns whether anything in the 3D prototype changed.
        """
        appearance = {p.name for p in self.model.parameters if p.appearance}
        appearance |= {link.length_param for link in self.model.links}
        changed = any(self.values.get(n) != values.get(n) for n in appearance)
        self.values = dict(values)
        if not changed:
            return False
        for shape, handle, kind in self.solids:
            now = effective_shape(shape, self.model, self.values, self.defaults)
            geom = shape_geometry(now, now.length)
            length = max(geom.length, 1e-6)
            if kind == "pipe":
                handle.scale = (geom.radius, geom.radius, length)
            elif kind == "cylinder":
                handle.radius = geom.radius
                handle.height = length
            elif kind == "box":
                handle.dimensions = geom.dimensions
            elif kind == "sphere":
                handle.radius = geom.radius
            handle.position = geom.position
            handle.visible = kind in ("box", "sphere") or geom.length > 1e-6
        self.show_q(self.q)
        return True

    def show_q(self, q: Sequence[float]) -> None:
        """Kinematic simulation: pose every link frame for joint positions `q` (rad)."""
        self.q = [float(x) for x in q]
        self.apply_poses(link_poses(self.model, self.values, self.q))

    def apply_poses(self, poses: np.ndarray) -> None:
        """Set link frame poses from rows of x, y, z, qw, qx, qy, qz (the `pose.*` column layout)."""
        for frame, row in zip(self.frames, poses, strict=False):
            frame.position = row[:3]
            frame.wxyz = row[3:7]

    def extent(self) -> float:
        """About how far the arm reaches from the origin (for placing the camera)."""
        poses = link_poses(self.model, self.values, [0.0] * len(self.model.links))
        far = float(np.max(np.linalg.norm(poses[:, :3], axis=1))) if len(poses) else 0.0
        biggest = max([max(s.length, 2 * s.radius, s.width, s.height) for s in self.model.shapes] or [0.0])
        return max(far + biggest, 0.5)

    def remove(self) -> None:
        for handle in [*self._env, *self.frames]:
            try:
                handle.remove()
            except Exception:
                pass
        self._env.clear()
        self.frames.clear()
        self.solids.clear()
