"""A URDF collision solid as contact spheres: how an imported arm touches obstacles and itself.

The contact kernels see the arm as spheres (contact_geometry.py). A URDF's `<collision>` solids
(meshes, boxes, cylinders, spheres) become spheres here: candidate centres on a grid inside the
solid's convex hull, each with its distance to the hull's boundary plus an allowance (BULGE of the
solid's thickness, MIN_BULGE..MAX_BULGE), and a greedy cover that keeps adding the candidate reaching
the most still-uncovered points of the hull's surface (within REACH) until COVERED of them are reached
or the solid has MAX_SPHERES. No sphere reaches more than MAX_BULGE past its solid; sharp edges and
corners are rounded off (docs/MODELS.md gives the measured figures). trimesh reads the files, as for
drawing (meshes.py). A fit costs about 50 ms a solid, a model's a second and more, and every worker
would pay it at start: each fit is kept on disk (beside numba's cache, keyed by the solid's file and
this module's source) as well as in memory.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh.process import files

from .urdf import Geometry, UrdfError, resolve_uri

#: At most this many spheres per solid: a link's contact costs its spheres' count per step.
MAX_SPHERES = 48
#: m: no sphere is thinner (a sliver of a solid still touches).
MIN_RADIUS = 0.003
#: A sphere reaches past its hull by this fraction of the solid's thickness (its smallest extent),
#: at least MIN_BULGE and at most MAX_BULGE (m): its radius is its centre's distance to the hull's
#: boundary plus that.
BULGE = 0.25
MIN_BULGE = 0.005
MAX_BULGE = 0.015
#: m: a surface point this close to a sphere counts as covered.
REACH = 0.002
#: The cover stops once this fraction of the surface points is covered.
COVERED = 0.99
#: Surface points sampled per solid, and about how many candidate centres.
SAMPLES = 800
CANDIDATES = 3000


class CollisionError(ValueError):
    """A collision solid that cannot be turned into spheres (its file missing or unreadable)."""


_fitted: dict[tuple[object, ...], np.ndarray] = {}
_lock = threading.Lock()


def solid_spheres(geo: Geometry, near: Path | None) -> np.ndarray:
    """Spheres (rows x, y, z, r; the solid's link coordinates) inside the collision solid `geo` (kept:
    a model's tables are rebuilt whenever its values change)."""
    key = (geo.kind, geo.filename, str(near), geo.pose.tobytes(), geo.scale, geo.size, geo.radius, geo.length)
    with _lock:
        known = _fitted.get(key)
    if known is None:
        if geo.kind == "sphere":
            known = np.array([[*geo.pose[:3, 3], max(geo.radius, MIN_RADIUS)]])
        else:
            known = _kept_fit(geo, near, repr(key))
        with _lock:
            _fitted[key] = known
    return known.copy()


def _kept_fit(geo: Geometry, near: Path | None, key: str) -> np.ndarray:
    """The solid's fit from the disk cache, or fitted now and stored there (any failure to store is
    only a slower next start)."""
    digest = hashlib.sha256(key.encode())
    digest.update(_source())
    if geo.kind == "mesh":
        try:
            digest.update(resolve_uri(geo.filename, near or Path(".")).read_bytes())
        except (UrdfError, OSError):
            return fit_spheres(solid_hull(geo, near))  # says what is wrong with the file
    path = _cache_folder() / f"{digest.hexdigest()[:32]}.npy"
    try:
        known = np.load(path)
        if known.ndim == 2 and known.shape[1] == 4:
            return np.asarray(known, dtype=float)
    except (OSError, ValueError, EOFError):  # none yet, or cut short
        pass
    known = fit_spheres(solid_hull(geo, near))
    out = io.BytesIO()
    np.save(out, known)
    try:
        files.atomic_write(path, out.getvalue())  # whole or not at all: processes fit side by side
    except OSError:
        pass
    return known


@functools.cache
def _source() -> bytes:
    """This module's source: a changed fit makes new keys."""
    return Path(__file__).read_bytes()


def _cache_folder() -> Path:
    """Beside numba's cache of the drive kernels when the package's folder is writable, else the
    user's cache folder."""
    here = Path(__file__).parent / "__pycache__"
    if os.access(here if here.exists() else here.parent, os.W_OK):
        return here / "collision-spheres"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "simecs" / "collision-spheres"


def fit_spheres(hull: Any) -> np.ndarray:
    """Spheres covering the surface of the convex trimesh `hull` (rows x, y, z, r)."""
    import trimesh

    normals = np.asarray(hull.face_normals, dtype=float)
    offsets = np.einsum("ij,ij->i", normals, np.asarray(hull.triangles[:, 0], dtype=float))
    lo, hi = np.asarray(hull.bounds[0], dtype=float), np.asarray(hull.bounds[1], dtype=float)
    extent = hi - lo
    thickness = float(max(extent.min(), 2 * MIN_RADIUS))
    allowed = min(max(BULGE * thickness, MIN_BULGE), MAX_BULGE)
    step = max(float(np.prod(np.maximum(extent, 1e-4)) / CANDIDATES) ** (1 / 3), 1e-4)
    axes = [
        np.arange(lo[a] + step / 2, hi[a], step) if extent[a] > step else np.array([(lo[a] + hi[a]) / 2])
        for a in range(3)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    centres = np.vstack([grid, np.asarray(hull.centroid, dtype=float)[None, :]])
    inner = np.min(offsets[None, :] - centres @ normals.T, axis=1)  # distance to the hull's boundary
    keep = inner >= 0.0
    centres, radii = centres[keep], np.maximum(inner[keep] + allowed, MIN_RADIUS)
    spread, _faces = trimesh.sample.sample_surface(hull, SAMPLES, seed=0)
    points = np.vstack([np.asarray(hull.vertices, dtype=float), np.asarray(spread, dtype=float)])
    squared = (centres**2).sum(axis=1)[:, None] + (points**2).sum(axis=1)[None, :] - 2.0 * centres @ points.T
    reach = squared <= ((radii + REACH) ** 2)[:, None]
    gain = np.count_nonzero(reach, axis=1)
    covered = np.zeros(points.shape[0], dtype=bool)
    chosen: list[int] = []
    while len(chosen) < MAX_SPHERES and covered.mean() < COVERED:
        best = int(np.argmax(gain))
        if gain[best] == 0:
            break
        chosen.append(best)
        newly = reach[best] & ~covered
        covered |= newly
        gain -= np.count_nonzero(reach[:, newly], axis=1)
    return np.column_stack([centres[chosen], radii[chosen]])


def solid_hull(geo: Geometry, near: Path | None) -> Any:
    """The solid's convex hull as a trimesh, in its link's coordinates."""
    hull = _hull(geo, near)
    hull.apply_transform(geo.pose)
    return hull


def _hull(geo: Geometry, near: Path | None) -> Any:
    import trimesh

    if geo.kind == "box":
        return trimesh.creation.box(extents=[float(v) for v in geo.size])
    if geo.kind == "cylinder":
        return trimesh.creation.cylinder(radius=geo.radius, height=geo.length, sections=24)
    if geo.kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=2, radius=geo.radius)
    try:
        path = resolve_uri(geo.filename, near or Path("."))
    except UrdfError as exc:
        raise CollisionError(f"collision mesh {geo.filename}: {exc.reason}") from None
    try:
        mesh: Any = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh raises many kinds for a file it cannot read
        raise CollisionError(f"collision mesh {path.name}: cannot read it ({exc})") from None
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * np.asarray(geo.scale, dtype=np.float64)
    if vertices.shape[0] < 4:
        raise CollisionError(f"collision mesh {path.name}: has no volume ({vertices.shape[0]} vertices)")
    return trimesh.convex.convex_hull(vertices)


def coverage(hull: Any, spheres: np.ndarray, samples: int = 4000) -> tuple[float, float]:
    """(the largest distance of a surface point from the spheres, m; the fraction of points farther
    than 5 mm): how closely the spheres follow the hull (tests and docs/MODELS.md)."""
    import trimesh

    spread, _faces = trimesh.sample.sample_surface(hull, samples, seed=1)
    points = np.asarray(spread, dtype=float)
    gap = np.min(
        np.linalg.norm(points[:, None, :] - spheres[None, :, :3], axis=2) - spheres[None, :, 3], axis=1
    )
    gap = np.maximum(gap, 0.0)
    return float(gap.max()), float(np.mean(gap > 0.005))
