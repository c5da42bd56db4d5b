"""Where the camera looks from: the presets of the toolbar's View buttons (fit the arm, front, top,
side), z up. Each frames the arm as it stands now: the camera looks along the view's direction at the
arm's bounding box and stands just far enough for the box to fill `FILL` of the 3D view's height or
width, whichever binds, with the lens and picture size the browser last reported. A reloaded tab gets
back the camera it had (`CameraPose`, kept in the tab's memory by `browser.remember_view`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

VIEWS = ("Fit arm", "Front", "Top", "Side")
#: The share of the 3D view (its height or width, whichever binds) the arm fills after a preset.
FILL = 0.7
#: viser's lens until the browser reports its own: vertical field of view (rad), width / height.
DEFAULT_FOV = math.radians(75.0)
DEFAULT_ASPECT = 1.0
#: Where each view looks from, seen from the arm (the camera's up is +z).
DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "Fit arm": (1.3, -1.4, 1.0),  # three-quarter view from the front right, above
    "Front": (0.0, -1.0, 0.0),  # looking along +y at the arm's front (its x axis to the right)
    "Side": (1.0, 0.0, 0.0),  # looking along -x
    "Top": (0.0, -0.004, 1.0),  # from above, a hair off the vertical so "up" stays defined
}
#: m, and share of the box's diagonal: the nearest the camera comes to the arm's box (seen end on, a
#: tall arm from above, the box would otherwise fill the view only at the camera's lens).
NEAREST = 0.05
NEAREST_SHARE = 0.2


@dataclass(frozen=True)
class CameraPose:
    position: tuple[float, float, float]
    look_at: tuple[float, float, float]

    def to_obj(self) -> dict[str, list[float]]:
        return {"position": list(self.position), "look_at": list(self.look_at)}

    @staticmethod
    def from_obj(obj: Any) -> CameraPose | None:
        """A pose the browser kept, or None when it is not one (a tab's memory is not trusted)."""
        try:
            position = tuple(float(x) for x in obj["position"])
            look_at = tuple(float(x) for x in obj["look_at"])
        except (KeyError, TypeError, ValueError):
            return None
        if len(position) != 3 or len(look_at) != 3 or position == look_at:
            return None
        if not all(abs(x) < 1e4 for x in (*position, *look_at)):
            return None
        return CameraPose(position, look_at)  # type: ignore[arg-type]


def preset(
    view: str,
    points: Sequence[Sequence[float]] | np.ndarray,
    fov: float = DEFAULT_FOV,
    aspect: float = DEFAULT_ASPECT,
    fill: float = FILL,
) -> CameraPose:
    """The camera of a View button for an arm whose solids' corners are `points` (world, n x 3): it
    looks along the view's direction and the arm's box fills `fill` of the picture's binding side.

    For a camera at distance D along the unit direction d from the look-at point, a point at (x, y)
    across the view and z towards the camera (relative to the look-at point) is seen at y / (D - z)
    on the picture's half height tan(fov / 2). Keeping every point within `fill` of both halves
    needs D >= (max(y + t z) - min(y - t z)) / (2 t) with t = fill tan(fov / 2) (and the same
    across with the picture's aspect), with the look-at point shifted across by the midpoint of
    those bounds: the box is centred and fills `fill` of the side that binds. The camera stays a
    fifth of the box's diagonal off its nearest corner (a box seen end on then fills less)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        pts = np.zeros((1, 3))
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    d = np.asarray(DIRECTIONS.get(view, DIRECTIONS["Fit arm"]), dtype=float)
    d /= np.linalg.norm(d)
    right = np.cross(-d, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, -d)
    rel = pts - centre
    x, y, z = rel @ right, rel @ up, rel @ d
    fov = fov if math.isfinite(fov) and 0.05 < fov < 3.0 else DEFAULT_FOV
    aspect = aspect if math.isfinite(aspect) and 0.05 < aspect < 20.0 else DEFAULT_ASPECT
    fill = min(max(fill, 0.05), 1.0)
    t_up = fill * math.tan(fov / 2)
    t_across = t_up * aspect
    distance, shift = NEAREST, np.zeros(3)
    for coord, axis, t in ((y, up, t_up), (x, right, t_across)):
        high, low = float(np.max(coord + t * z)), float(np.min(coord - t * z))
        distance = max(distance, (high - low) / (2 * t))
        shift += axis * (high + low) / 2
    diagonal = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    distance = max(distance, float(np.max(z)) + max(NEAREST, NEAREST_SHARE * diagonal))
    target = centre + shift
    position = target + distance * d
    return CameraPose(
        (float(position[0]), float(position[1]), float(position[2])),
        (float(target[0]), float(target[1]), float(target[2])),
    )


def lens(camera: Any) -> tuple[float, float]:
    """(vertical field of view in rad, width / height) of the browser's 3D view as it last reported
    them; viser's defaults before it has."""
    try:
        fov = float(camera.fov)
        aspect = float(camera.image_width) / float(camera.image_height)
    except Exception:  # the tab has not reported its camera yet (or is no browser)
        return DEFAULT_FOV, DEFAULT_ASPECT
    if not (math.isfinite(fov) and fov > 0 and math.isfinite(aspect) and aspect > 0):
        return DEFAULT_FOV, DEFAULT_ASPECT
    return fov, aspect


def apply(camera: Any, pose: CameraPose) -> None:
    camera.position = pose.position
    camera.look_at = pose.look_at


def current(camera: Any) -> CameraPose | None:
    """What the browser's camera shows now (viser keeps the last pose the tab reported)."""
    try:
        return CameraPose(
            tuple(float(x) for x in camera.position),  # type: ignore[arg-type]
            tuple(float(x) for x in camera.look_at),  # type: ignore[arg-type]
        )
    except Exception:  # the tab has not reported its camera yet
        return None
