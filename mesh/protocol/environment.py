"""What the arm can touch: obstacles as data, one geometry for the contact model, the viewer and /scene.

An obstacle is a solid fixed in the world (paper §6): a box, a cylinder, a sphere or a plane, with its
pose and its contact law (penalty stiffness and damping along the normal, Coulomb friction along the
surface). A model lists its own (`ModelDescription.obstacles`, e.g. the plate under the Spider); a
session starts with those and its user may add, move and remove obstacles (`set_obstacles`). The
contact model (models/contact.py) reads the same fields as the renderers, so what is drawn is what
the arm hits (shapes.obstacle_geometry). docs/MODELS.md, "Environment and contact".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated, Literal, get_args

import msgspec
from msgspec import Meta

from .primitives import FieldProblem, Name, Record

ObstacleKind = Literal["box", "cylinder", "sphere", "plane"]
OBSTACLE_KINDS: tuple[ObstacleKind, ...] = get_args(ObstacleKind)
#: Obstacles of one session (the model's included): each is checked against every contact sphere of
#: the arm on every step it comes near, so the list stays short.
MAX_OBSTACLES = 32
Position = Annotated[list[float], Meta(min_length=3, max_length=3, description="m, world frame")]
Angles = Annotated[list[float], Meta(min_length=3, max_length=3, description="rad, roll-pitch-yaw")]
Length = Annotated[float, Meta(ge=0.0, le=100.0, description="m")]


class Obstacle(Record):
    """A solid fixed in the world that the arm can touch.

    `position` is the centre of a box, cylinder or sphere, or a point of a plane; `rotation_rpy` turns
    the solid's frame from the world's. A box has edges `size` (x, y, z of its frame); a cylinder has
    `radius` and `length` along its frame's z; a sphere `radius`; a plane is the half-space below
    its frame's x-y plane (its normal is the frame's z, pointing out of the solid). The contact law:
    normal force `stiffness` x penetration + `damping` x penetration rate (never pulling), friction
    up to `friction` x normal force against the sliding velocity. An obstacle with a `mass` can be
    grasped: the tool carries it from a `grasp` action to a `release` (mesh/protocol/robot_commands.py)."""

    name: Annotated[Name, Meta(description="unique in the session; notices and refusals name it")]
    kind: ObstacleKind
    position: Position
    rotation_rpy: Angles = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    size: Annotated[
        list[Length], Meta(min_length=3, max_length=3, description="m, box: edge lengths along x, y, z")
    ] = msgspec.field(default_factory=lambda: [0.1, 0.1, 0.1])
    radius: Annotated[Length, Meta(description="m, cylinder and sphere")] = 0.05
    length: Annotated[Length, Meta(description="m, cylinder: along its frame's z")] = 0.1
    stiffness: Annotated[float, Meta(ge=1e2, le=1e7, description="N/m, normal penalty stiffness")] = 1e5
    damping: Annotated[float, Meta(ge=0.0, le=1e5, description="N*s/m, normal damping")] = 300.0
    friction: Annotated[float, Meta(ge=0.0, le=2.0, description="Coulomb coefficient")] = 0.3
    mass: Annotated[
        float, Meta(ge=0.0, le=500.0, description="kg, a homogeneous solid; 0: fixed, it cannot be grasped")
    ] = 0.0
    color: Annotated[list[Annotated[int, Meta(ge=0, le=255)]], Meta(min_length=3, max_length=3)] = (
        msgspec.field(default_factory=lambda: [150, 110, 90])
    )

    def __post_init__(self) -> None:
        for i, v in enumerate([*self.position, *self.rotation_rpy]):
            if not math.isfinite(v):
                raise FieldProblem("position" if i < 3 else "rotation_rpy", "every number must be finite")
        if any(abs(v) > 100.0 for v in self.position):
            raise FieldProblem("position", "coordinates are within +-100 m")
        if self.kind == "box" and min(self.size) <= 0.0:
            raise FieldProblem("size", "a box has three edge lengths above 0 m")
        if self.kind in ("cylinder", "sphere") and self.radius <= 0.0:
            raise FieldProblem("radius", f"a {self.kind} has a radius above 0 m")
        if self.kind == "cylinder" and self.length <= 0.0:
            raise FieldProblem("length", "a cylinder has a length above 0 m")


def grasp_problem(ob: Obstacle) -> str:
    """Why the tool cannot take `ob` ('' if it can): a plane is the world's, a massless solid is fixed."""
    if ob.kind == "plane":
        return f"obstacle {ob.name} is a plane: a plane cannot be grasped"
    if ob.mass <= 0.0:
        return f"obstacle {ob.name} has mass 0 (fixed to the world): give it its mass to grasp it"
    return ""


ObstacleList = Annotated[
    list[Obstacle], Meta(max_length=MAX_OBSTACLES, description="names unique; at most 32")
]


def check_obstacles(obstacles: Sequence[Obstacle], where: str = "obstacles") -> None:
    """Names unique: a notice or a refusal names one obstacle. FieldProblem names the second one."""
    if len(obstacles) > MAX_OBSTACLES:
        raise FieldProblem(where, f"{len(obstacles)} obstacles: at most {MAX_OBSTACLES}")
    seen: set[str] = set()
    for i, ob in enumerate(obstacles):
        if ob.name in seen:
            raise FieldProblem(f"{where}[{i}].name", f"{ob.name!r} names two obstacles")
        seen.add(ob.name)
