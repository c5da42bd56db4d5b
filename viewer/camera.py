"""Where the camera looks from: the presets of the toolbar's View buttons (fit the arm, front, top,
side), for an arm that reaches `reach` metres from its base, z up. A reloaded tab gets back the
camera it had (`CameraPose`, kept in the tab's memory by `browser.remember_view`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

VIEWS = ("Fit arm", "Front", "Top", "Side")


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


def preset(view: str, reach: float) -> CameraPose:
    """The camera of a View button; the whole arm in sight, whatever its pose."""
    r = max(reach, 0.1)
    centre = (0.0, 0.0, 0.25 * r)
    if view == "Front":  # looking along +y at the arm's front (its x axis to the right)
        return CameraPose((0.0, -2.6 * r, 0.25 * r), centre)
    if view == "Side":  # looking along -x
        return CameraPose((2.6 * r, 0.0, 0.25 * r), centre)
    if view == "Top":  # from above, a hair off the vertical so "up" stays defined
        return CameraPose((0.0, -0.01 * r, 2.8 * r), (0.0, 0.0, 0.0))
    return CameraPose((1.3 * r, -1.4 * r, 1.0 * r), centre)  # "Fit arm"


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
