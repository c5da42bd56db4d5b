"""A model's visual meshes as binary glTF (GLB): what the viewer draws and the recordings embed.

An imported model's links are drawn with their URDF visuals: mesh files (STL, COLLADA, OBJ, ... as
trimesh reads them) and URDF boxes, cylinders and spheres, each turned into one GLB that the proxy
serves at `simecs/library/<model>/mesh/<name>`. Meshes finer than MAX_FACES are decimated first
(fast-simplification): a Panda's visuals are 10 MB as shipped, about 2 MB after, which a browser on
a machine without a GPU still draws smoothly and a recording can carry. The colour of a part that
its file does not give is the shape's colour. trimesh is imported here only, on first use.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from .spec import Visual
from .urdf import UrdfError, resolve_uri

#: Triangles a whole mesh file keeps, about (its parts decimated in proportion, none below 100).
MAX_FACES = 4000


class MeshError(ValueError):
    """A visual mesh that cannot be read: `name` is the mesh, `reason` says why."""


class MeshStore:
    """The GLBs of one model, made on first request and kept."""

    def __init__(self, meshes: Sequence[Visual]) -> None:
        self._meshes = {m.name: m for m in meshes}
        self._glb: dict[str, bytes] = {}
        self._lock = threading.Lock()

    def names(self) -> list[str]:
        return list(self._meshes)

    def glb(self, name: str) -> bytes:
        """The GLB of mesh `name`; KeyError if the model has no such mesh, MeshError if it cannot be read."""
        mesh = self._meshes[name]
        with self._lock:
            if name not in self._glb:
                self._glb[name] = make_glb(mesh)
            return self._glb[name]


def make_glb(mesh: Visual) -> bytes:
    """The GLB of one visual: its file's meshes (decimated to MAX_FACES), or the URDF primitive."""
    import trimesh

    geo = mesh.geometry
    if geo.kind == "box":
        scene = trimesh.Scene(trimesh.creation.box(extents=geo.size))
    elif geo.kind == "cylinder":
        scene = trimesh.Scene(trimesh.creation.cylinder(radius=geo.radius, height=geo.length, sections=32))
    elif geo.kind == "sphere":
        scene = trimesh.Scene(trimesh.creation.icosphere(subdivisions=2, radius=geo.radius))
    else:
        try:
            path = resolve_uri(geo.filename, mesh.near)
        except UrdfError as exc:
            raise MeshError(f"mesh {mesh.name}: {exc}") from None
        try:
            scene = trimesh.load_scene(str(path))
        except Exception as exc:  # trimesh raises many kinds for a file it cannot read
            raise MeshError(f"mesh {mesh.name}: cannot read {path.name} ({exc})") from None
    _decimate(scene, mesh.color)
    return bytes(scene.export(file_type="glb"))


def _decimate(scene: Any, color: tuple[int, int, int]) -> None:
    """Every part at most its share of MAX_FACES, and a colour on every part."""
    import trimesh

    total = sum(len(g.faces) for g in scene.geometry.values()) or 1
    for key, part in list(scene.geometry.items()):
        if not isinstance(part, trimesh.Trimesh):
            continue
        rgba = _part_color(part, color)
        # COLLADA files repeat a vertex per face: joined first, else the decimation tears the surface
        # into loose triangles (holes everywhere).
        part.merge_vertices(merge_tex=True, merge_norm=True)
        if total > MAX_FACES and len(part.faces) > 200:
            target = max(int(len(part.faces) * MAX_FACES / total), 100)
            try:
                part = part.simplify_quadric_decimation(face_count=target)
            except Exception:  # a part the decimation cannot take stays as it is
                pass
        part.visual = trimesh.visual.ColorVisuals(part, face_colors=np.tile(rgba, (len(part.faces), 1)))
        scene.geometry[key] = part


def _part_color(part: Any, fallback: tuple[int, int, int]) -> np.ndarray:
    """The part's main colour as its file gives it (material or vertex colours), else `fallback`."""
    try:
        visual = part.visual
        if getattr(visual, "kind", None) == "texture" and getattr(visual, "material", None) is not None:
            main = np.asarray(visual.material.main_color, dtype=np.uint8)
        elif getattr(visual, "kind", None) in ("face", "vertex"):
            main = np.asarray(visual.main_color, dtype=np.uint8)
        else:
            main = None
    except Exception:
        main = None
    if main is None or main.shape[0] < 3:
        return np.array([*fallback, 255], dtype=np.uint8)
    return np.array([*main[:3], 255], dtype=np.uint8)
