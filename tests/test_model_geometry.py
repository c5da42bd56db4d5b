"""The drawn arm holds together (issue 32, item 7): for every model of the library, in several
postures, each link's solids touch or overlap the solids of the link before it (the first link's, the
solids fixed to the world), as the viewer and the recordings draw them: the geometry of
`simecs.mesh.rules.shapes` on the link frames of `simecs.mesh.rules.kinematics`.

The gap between two groups of solids is the least distance from points on the surface of one group
(every 2 mm) to the solids of the other, exact for cylinders, pipes (as solid cylinders), boxes and
spheres, and to points on the surface of meshes (every few mm, URDF visuals read with trimesh). A point
inside the other group counts as distance 0: overlapping solids have no gap.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from scipy.spatial import cKDTree
from simecs import models
from simecs.mesh.protocol.model import ModelDescription
from simecs.mesh.rules import shapes
from simecs.mesh.rules.kinematics import link_frames, matrix_from_quat

#: m: the widest gap allowed between consecutive links' solids (surface sampling adds about 1.5 mm).
MAX_GAP = 5e-3
#: m: the spacing of surface points on a primitive solid.
STEP = 2e-3
MODELS = [m.id for m in models.list_models()]


@dataclass
class Placed:
    """One solid where it stands: its geometry, its frame in the world, its mesh's points if any."""

    geometry: shapes.ShapeGeometry
    position: np.ndarray  # the parent frame in the world
    rotation: np.ndarray
    mesh_points: np.ndarray | None = None  # in the mesh's own coordinates

    def to_world(self, local: np.ndarray) -> np.ndarray:
        g = self.geometry
        inner = local @ matrix_from_quat(g.wxyz).T + g.position
        return inner @ self.rotation.T + self.position

    def to_local(self, world: np.ndarray) -> np.ndarray:
        g = self.geometry
        inner = (world - self.position) @ self.rotation
        return (inner - g.position) @ matrix_from_quat(g.wxyz)

    def surface(self) -> np.ndarray:
        """Points on its surface, in the world."""
        g = self.geometry
        if g.kind == "mesh":
            assert self.mesh_points is not None
            return self.to_world(self.mesh_points * np.asarray(g.dimensions))
        return self.to_world(primitive_surface(g))

    def distance(self, world: np.ndarray) -> np.ndarray:
        """Distance of each point to a primitive solid (0 inside)."""
        g = self.geometry
        p = self.to_local(world)
        if g.kind == "sphere":
            d = np.linalg.norm(p, axis=1) - g.radius
        elif g.kind == "box":
            q = np.abs(p) - np.asarray(g.dimensions) / 2
            d = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
        else:  # cylinder, pipe: axis along local z
            q = np.column_stack([np.hypot(p[:, 0], p[:, 1]) - g.radius, np.abs(p[:, 2]) - g.length / 2])
            d = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
        return np.maximum(d, 0.0)


def _grid(a: float, b: float) -> np.ndarray:
    return np.linspace(a, b, max(2, math.ceil((b - a) / STEP) + 1))


def primitive_surface(g: shapes.ShapeGeometry) -> np.ndarray:
    """Points every STEP or closer on the surface of a primitive, in its own frame."""
    if g.kind == "sphere":
        n = max(8, math.ceil(math.pi * g.radius / STEP))
        theta, phi = np.meshgrid(np.linspace(0, math.pi, n), np.linspace(0, 2 * math.pi, 2 * n))
        unit = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
        return g.radius * unit.reshape(-1, 3)
    if g.kind == "box":
        half = np.asarray(g.dimensions) / 2
        faces = []
        for k in range(3):
            a, b = (k + 1) % 3, (k + 2) % 3
            u, v = np.meshgrid(_grid(-half[a], half[a]), _grid(-half[b], half[b]))
            for side in (-half[k], half[k]):
                face = np.zeros((u.size, 3))
                face[:, a], face[:, b], face[:, k] = u.ravel(), v.ravel(), side
                faces.append(face)
        return np.concatenate(faces)
    r, h = g.radius, g.length / 2  # cylinder, pipe
    angles = np.linspace(0, 2 * math.pi, max(12, math.ceil(2 * math.pi * r / STEP)), endpoint=False)
    z = _grid(-h, h)
    wall = np.stack(
        [
            np.repeat(r * np.cos(angles), len(z)),
            np.repeat(r * np.sin(angles), len(z)),
            np.tile(z, len(angles)),
        ],
        axis=1,
    )
    caps = []
    for radius in _grid(0.0, r):
        ring = np.linspace(0, 2 * math.pi, max(6, math.ceil(2 * math.pi * radius / STEP)), endpoint=False)
        for side in (-h, h):
            caps.append(
                np.column_stack([radius * np.cos(ring), radius * np.sin(ring), np.full(len(ring), side)])
            )
    return np.concatenate([wall, *caps])


_MESH_POINTS: dict[tuple[str, str], np.ndarray] = {}


def mesh_points(model_id: str, name: str) -> np.ndarray:
    """Points on the surface of one of a model's meshes (its vertices and samples), in its frame."""
    key = (model_id, name)
    if key not in _MESH_POINTS:
        import trimesh

        glb = models.get_model(model_id).mesh_store().glb(name)
        scene: Any = trimesh.load(io.BytesIO(glb), file_type="glb", force="scene")
        mesh = scene.to_geometry() if hasattr(scene, "to_geometry") else scene.dump(concatenate=True)
        samples = trimesh.sample.sample_surface(mesh, 8000, seed=1)[0]
        _MESH_POINTS[key] = np.concatenate([np.asarray(mesh.vertices), np.asarray(samples)])
    return _MESH_POINTS[key]


def placed_groups(model: ModelDescription, q: Sequence[float]) -> list[list[Placed]]:
    """The visible solids fixed to the world, then each link's, posed at `q` with default values."""
    values = model.default_values()
    frames = link_frames(model, values, q)
    names = {link.name: i for i, link in enumerate(model.links)}
    groups: list[list[Placed]] = [[] for _ in range(len(model.links) + 1)]
    for solid in shapes.solids(model, values):
        g = solid.geometry
        if not g.visible:
            continue
        k = 0 if solid.frame == shapes.WORLD else names[solid.frame] + 1
        p, R = (np.zeros(3), np.eye(3)) if k == 0 else frames[k - 1]
        points = mesh_points(model.id, g.mesh) if g.kind == "mesh" else None
        groups[k].append(Placed(g, p, R, points))
    return groups


def gap(a: list[Placed], b: list[Placed]) -> float:
    """Least distance between two groups of solids (0 when they touch or overlap)."""
    points = np.concatenate([s.surface() for s in a])
    least = [float(s.distance(points).min()) for s in b if s.geometry.kind != "mesh"]
    meshes = [s.surface() for s in b if s.geometry.kind == "mesh"]
    if meshes:
        least.append(float(cKDTree(np.concatenate(meshes)).query(points)[0].min()))
    return min(least)


def postures(model_id: str) -> list[tuple[str, list[float]]]:
    """Home, the standard target and three random postures within the joint ranges."""
    pkg = models.get_model(model_id)
    rng = np.random.default_rng(32)
    out = [("home", list(pkg.home())), ("standard target", list(pkg.spec.standard_target))]
    for k in range(3):
        out.append((f"random {k}", [float(rng.uniform(lk.joint_min, lk.joint_max)) for lk in pkg.spec.links]))
    return out


def chain_gaps(model: ModelDescription, q: Sequence[float]) -> list[tuple[str, float]]:
    """(link name, its gap to the solids before it) for each link with solids: the solids before it
    are the nearest earlier link's that has some, or the world's."""
    groups = placed_groups(model, q)
    out = []
    before = 0 if groups[0] else -1
    for k in range(1, len(groups)):
        if not groups[k]:
            continue
        if before >= 0:
            out.append((model.links[k - 1].name, gap(groups[k], groups[before])))
        before = k
    return out


@pytest.mark.parametrize("model_id", MODELS)
def test_each_link_is_drawn_joined_to_the_one_before(model_id: str) -> None:
    model = models.get_model(model_id).describe()
    worst: list[str] = []
    for what, q in postures(model_id):
        gaps = chain_gaps(model, q)
        assert len(gaps) >= len(model.links) - 1, f"{model_id}: links without solids: {gaps}"
        worst += [f"{name} {d * 1000:.1f} mm ({what})" for name, d in gaps if d > MAX_GAP]
    assert not worst, f"{model_id}: links drawn apart from the one before: {worst}"


def test_the_gap_measure() -> None:
    """Solids 10 mm apart measure 10 mm (to the surface sampling), touching or overlapping ones 0,
    whatever their kinds and the frames they hang on."""
    turn = matrix_from_quat([math.cos(0.3), 0.0, math.sin(0.3), 0.0])

    def cylinder(z: float, frame: np.ndarray) -> Placed:  # 0.1 long along its z, from z - 0.05
        g = shapes.ShapeGeometry(
            "cylinder", np.array([0.0, 0.0, z]), shapes.AXIS_WXYZ["z"], radius=0.04, length=0.1
        )
        return Placed(g, np.array([0.2, -0.1, 0.3]), frame)

    def box(x: float) -> Placed:  # 0.06 wide, from x - 0.03
        g = shapes.ShapeGeometry(
            "box", np.array([x, 0.0, 0.0]), shapes.AXIS_WXYZ["z"], dimensions=(0.06, 0.06, 0.06)
        )
        return Placed(g, np.array([0.2, -0.1, 0.3]), turn)

    base = cylinder(0.0, turn)
    assert gap([cylinder(0.11, turn)], [base]) == pytest.approx(0.010, abs=1.5e-3)
    assert gap([base], [cylinder(0.11, turn)]) == pytest.approx(0.010, abs=1.5e-3)
    assert gap([cylinder(0.1, turn)], [base]) == pytest.approx(0.0, abs=1e-9)  # end to end
    assert gap([cylinder(0.03, turn)], [base]) == 0.0
    assert gap([box(0.04 + 0.03 + 0.01)], [base]) == pytest.approx(0.010, abs=1.5e-3)  # beside the wall
    assert gap([box(0.0)], [base]) == 0.0  # inside it


@pytest.mark.parametrize("model_id", [m for m in MODELS if models.get_model(m).describe().mesh_names()])
def test_a_glb_box_holds_every_vertex(model_id: str) -> None:
    """`shapes.glb_bounds` (what the View presets frame a mesh by) holds each of the model's meshes,
    no more than a few cm wider than its vertices (a turned part's box is a little larger)."""
    import trimesh

    store = models.get_model(model_id).mesh_store()
    for name in store.names():
        glb = store.glb(name)
        bounds = shapes.glb_bounds(glb)
        assert bounds is not None, name
        scene: Any = trimesh.load(io.BytesIO(glb), file_type="glb", force="scene")
        lo, hi = scene.bounds
        assert np.all(bounds[0] <= lo + 1e-6) and np.all(bounds[1] >= hi - 1e-6), name
        assert np.all(lo - bounds[0] < 0.03) and np.all(bounds[1] - hi < 0.03), name
    assert shapes.glb_bounds(b"not a glb") is None and shapes.glb_bounds(b"glTF" + bytes(16)) is None
