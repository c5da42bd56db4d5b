"""The specification of an arm model: the data a model author writes (see spider.py, puma.py).

Everything else (parameters, variables, shapes, docs, the Exudyn chain, the drives) is derived from an
`ArmSpec`, so adding a model is writing a spec, not editing the simulator. Every spec is built with
named arguments only: a link has nine numbers and names, and a positional slip would go unnoticed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.model import Shape

from .urdf import Geometry

Vec3 = tuple[float, float, float]


@dataclass(kw_only=True)
class ParamInfo:
    """Default, unit, description and bounds of one drive parameter (per joint)."""

    value: float
    unit: str
    description: str
    min: float
    max: float
    integer: bool = False


@dataclass(kw_only=True)
class LinkSpec:
    """Joint i and link i in the Link convention (paper §5.1), with its default length, mass and look."""

    name: str
    rpy: Vec3  # initial rotation (roll, pitch, yaw), none about the joint axis
    length: float  # central translation along x (the `linkN.length` default)
    final: Vec3  # final translation, no x component
    joint_min: float
    joint_max: float
    mass: float
    radius: float
    drive: str  # key into ArmSpec.drives
    length_max: float = 3.0
    com: Vec3 | None = None  # fixed COM in the link frame; None: uniform tube
    # inertia at the COM in link axes: (ixx, iyy, izz) or (ixx, iyy, izz, ixy, ixz, iyz); None: tube
    inertia: tuple[float, ...] | None = None
    color: tuple[int, int, int] = (200, 200, 210)
    source_joint: str = ""  # the joint's name in the file it came from (a URDF), for the docs

    def __post_init__(self) -> None:
        if (self.com is None) != (self.inertia is None):
            raise ValueError(f"{self.name}: com and inertia are given together or not at all")
        if self.inertia is not None and len(self.inertia) not in (3, 6):
            raise ValueError(f"{self.name}: inertia has 3 (principal) or 6 (ixx iyy izz ixy ixz iyz) values")

    def inertia_matrix(self) -> tuple[tuple[float, float, float], ...] | None:
        """The inertia at the COM in link axes as a 3x3 (rows), or None for a tube."""
        if self.inertia is None:
            return None
        ixx, iyy, izz, ixy, ixz, iyz = (*self.inertia, 0.0, 0.0, 0.0)[:6]
        return ((ixx, ixy, ixz), (ixy, iyy, iyz), (ixz, iyz, izz))


@dataclass(kw_only=True)
class Visual:
    """One drawn part of an imported model (a URDF <visual>): on link `link` (-1: fixed to the world),
    its pose in that frame in `geometry.pose`; meshes.py makes its GLB, named `name` on the mesh."""

    link: int
    name: str
    geometry: Geometry
    near: Path  # the URDF's folder: where relative mesh paths start
    color: tuple[int, int, int]


@dataclass(kw_only=True)
class ArmSpec:
    """A whole model: its links, its drive size classes, defaults of the run and documentation text."""

    id: str
    name: str
    summary: str
    links: list[LinkSpec]
    drives: dict[str, dict[str, ParamInfo]]  # size class -> DRIVE_PARAMS name -> info
    base_translation: Vec3 = (0.0, 0.0, 0.0)
    base_rpy: Vec3 = (0.0, 0.0, 0.0)  # joint 1's frame in the world (its z is joint 1's axis)
    tool_translation: Vec3 = (0.0, 0.0, 0.0)
    payload_mass: float = 0.0
    payload_size: float = 0.2
    gravity: Vec3 = (0.0, 0.0, -9.81)  # m/s^2 in world axes (the `gravity.*` parameters' defaults)
    default_step: float = 1e-3
    substeps: int = 5
    assumptions: str = ""
    chain_doc: str = ""
    standard_target: tuple[float, ...] = ()
    home: tuple[float, ...] = ()  # the `home` action's posture, rad; () = every joint at 0
    # Cartesian maxima of a `lin` move at 100 % (the `cart.*` parameters' defaults)
    cart_max_speed: float = 0.25  # m/s of the tool point
    cart_max_acc: float = 0.5  # m/s^2
    cart_max_rot_speed: float = 0.5  # rad/s of the tool orientation
    cart_max_rot_acc: float = 1.0  # rad/s^2
    environment: list[Shape] = field(default_factory=list)  # drawn only
    obstacles: list[Obstacle] = field(default_factory=list)  # what the arm can touch
    source: Path | None = None  # the model directory it was read from
    visuals: list[Visual] = field(default_factory=list)  # drawn instead of a link's tubes where given
    collisions: list[Visual] = field(default_factory=list)  # a URDF's <collision> solids, for contact
