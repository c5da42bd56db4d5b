"""A robot model as data: what every client receives instead of importing models/.

The kinematic chain follows the paper's Link convention (SIMECS-RI §5.1): joint i turns its frame about
the local z axis by q_i; then the link applies an *initial rotation* (roll-pitch-yaw, no component about
the joint axis), a *central translation* along x equal to the link length, and a *final translation*
with no x component. Shapes hang on link frames; at most one per link is resizable along the link axis,
so a changed length reshapes the arm without a new model. `shapes.py` says how a shape is drawn.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from typing import Annotated, Literal, get_args

import msgspec
from msgspec import Meta

from . import columns
from .codec import DecodeError
from .columns import RESERVED_FRAMES
from .environment import ObstacleList, check_obstacles
from .primitives import NAME_PATTERN, FieldProblem, Message, Name, Record, Text

NAME_RE = re.compile(NAME_PATTERN)
ShapeKind = Literal["cylinder", "pipe", "box", "beam", "sphere", "mesh"]
Vec3 = Annotated[list[float], Meta(min_length=3, max_length=3)]
Size = Annotated[float, Meta(ge=0.0, le=1000.0, description="m")]


class Parameter(Record):
    """One tunable value. `name` is a dotted path whose prefix is its `component`."""

    name: Name
    value: float
    unit: Annotated[str, Meta(max_length=64)]
    description: Text
    min: float
    max: float
    component: Annotated[str, Meta(max_length=256)]
    appearance: Annotated[bool, Meta(description="changing it reshapes the 3D arm")] = False
    integer: Annotated[bool, Meta(description="only whole numbers (e.g. a switch 0/1)")] = False

    def __post_init__(self) -> None:
        if not self.min <= self.value <= self.max:
            raise FieldProblem("value", f"{self.value:g} is outside [{self.min:g}, {self.max:g}]")


class Variable(Record):
    """One scalar output, as a column of the result frames."""

    name: Name
    unit: Annotated[str, Meta(max_length=64)]
    description: Text
    component: Annotated[str, Meta(max_length=256)]


class Shape(Record):
    """A solid attached to a link frame (or to the world when `link` is -1); `shapes.py` draws it.

    Sizes in metres: cylinder/pipe use `radius` (`inner_radius` for pipe) and `length` along `axis`;
    box/beam use `length` along `axis` and `width`, `height` across it; sphere uses `radius`.
    `origin` is the start point in the link frame; the solid extends from there along `axis`.
    A mesh is the triangle mesh `mesh` of the model (binary glTF at simecs/library/<model>/mesh/<mesh>),
    its frame at `origin` turned by `rotation_rpy` and its coordinates multiplied by `scale`.
    If `resizable` is true its `length` is the link length parameter of that link at every moment.
    `scales_with` maps a dimension (length, radius, inner_radius, width, height) to a parameter: the
    dimension is multiplied by value / default of that parameter. With `anchor` "end", the x of
    `origin` is measured from the end of the link at its default length.
    """

    kind: ShapeKind
    link: Annotated[int, Meta(ge=-1, le=63, description="0-based index into links; -1: the world")]
    origin: Vec3
    axis: Literal["x", "y", "z"] = "x"
    length: Size = 0.0
    radius: Size = 0.0
    inner_radius: Size = 0.0
    width: Size = 0.0
    height: Size = 0.0
    color: Annotated[list[Annotated[int, Meta(ge=0, le=255)]], Meta(min_length=3, max_length=3)] = (
        msgspec.field(default_factory=lambda: [180, 180, 190])
    )
    resizable: bool = False
    scales_with: Annotated[
        dict[Literal["length", "radius", "inner_radius", "width", "height"], Name], Meta(max_length=5)
    ] = {}
    anchor: Literal["start", "end"] = "start"
    mesh: Annotated[str, Meta(max_length=64, description="kind mesh: the mesh's name in the model")] = ""
    rotation_rpy: Annotated[Vec3, Meta(description="kind mesh: rad, its frame in the link frame")] = (
        msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    )
    scale: Annotated[Vec3, Meta(description="kind mesh: factors on its x, y, z")] = msgspec.field(
        default_factory=lambda: [1.0, 1.0, 1.0]
    )

    def __post_init__(self) -> None:
        if self.kind == "mesh" and not NAME_RE.match(self.mesh):
            raise FieldProblem("mesh", "a mesh shape names its mesh (letters, digits, _ . -)")


class Link(Record):
    """Joint i (about local z) followed by link i, in the paper's Link convention."""

    name: Name
    joint: Name
    initial_rotation_rpy: Vec3
    length_param: Name  # the Parameter holding the central translation along x
    final_translation: Vec3
    joint_min: Annotated[float, Meta(description="rad")]
    joint_max: Annotated[float, Meta(description="rad")]


class InitEquation(Record):
    """How an internal state follows from joint positions at rest (paper §5.2), e.g. q_m = n * q_l."""

    state: Text
    expression: Text
    description: Text


class DocPage(Record):
    """One page of read-only hypertext documentation; markdown links `doc:<id>` go to other pages."""

    id: Name
    title: Text
    markdown: Text
    parent: Annotated[str, Meta(max_length=64)] = ""
    children: list[Name] = []


#: The motion control systems of paper §5 a run may choose (RunSettings.control_system); a model lists
#: the ones it offers in ModelDescription.control_systems. docs/MODELS.md, "Control systems".
ControlSystem = Literal["joint_independent", "opspace_motion", "opspace_hybrid"]
CONTROL_SYSTEMS: tuple[ControlSystem, ...] = get_args(ControlSystem)
CONTROL_SYSTEM_TITLES = {
    "joint_independent": "joint-independent control",
    "opspace_motion": "operational-space motion control",
    "opspace_hybrid": "operational-space hybrid (force/motion) control",
}


class ModelSummary(Record):
    id: Name
    name: Text
    summary: Text
    joints: Annotated[int, Meta(ge=1, le=64)]
    command_levels: list[Name]
    control_systems: Annotated[
        list[ControlSystem], Meta(description="the control systems a run of it may choose")
    ] = msgspec.field(default_factory=lambda: ["joint_independent"])


class ModelList(Message, tag="models"):
    """The model library (reply of `simecs/library`)."""

    models: list[ModelSummary]


class ModelDescription(Message, tag="model"):
    """Everything a client needs to show, animate, parametrise and command a model."""

    id: Name
    name: Text
    summary: Text
    base_translation: Vec3
    links: Annotated[list[Link], Meta(min_length=1, max_length=64)]
    tool_translation: Vec3
    shapes: list[Shape]
    parameters: list[Parameter]
    variables: list[Variable]
    init_equations: list[InitEquation]
    doc_root: Name
    docs: list[DocPage]
    command_levels: Annotated[list[Name], Meta(description="the robot command kinds the model accepts")]
    environment: Annotated[
        list[Shape], Meta(description="drawn only, never touched: pedestal, decoration (link -1)")
    ] = []
    home: Annotated[
        list[float],
        Meta(max_length=64, description="rad: the `home` action's posture and a new session's initial pose"),
    ] = []
    base_rotation_rpy: Annotated[
        Vec3, Meta(description="rad: joint 1's frame turned from the world's (roll, pitch, yaw)")
    ] = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    control_systems: Annotated[
        list[ControlSystem],
        Meta(description="the motion control systems a run may choose (RunSettings.control_system)"),
    ] = msgspec.field(default_factory=lambda: ["joint_independent"])
    obstacles: Annotated[
        ObstacleList, Meta(description="what the arm can touch; a new session starts with these")
    ] = []

    def __post_init__(self) -> None:
        check_obstacles(self.obstacles)
        for i, link in enumerate(self.links):
            if link.name in RESERVED_FRAMES:
                raise FieldProblem(
                    f"links[{i}].name", f"{link.name!r} is a frame of every run: rename the link"
                )

    def mesh_names(self) -> list[str]:
        """The meshes its mesh shapes name (each fetched from simecs/library/<model>/mesh/<name>)."""
        return sorted({s.mesh for s in [*self.shapes, *self.environment] if s.kind == "mesh"})

    def summary_entry(self) -> ModelSummary:
        return ModelSummary(
            self.id,
            self.name,
            self.summary,
            len(self.links),
            list(self.command_levels),
            list(self.control_systems),
        )

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    def default_values(self) -> dict[str, float]:
        return {p.name: p.value for p in self.parameters}

    # -- the columns of its runs (the rules are columns.py's) --
    def pose_frames(self) -> list[str]:
        """The frames whose pose a run streams: every link, then the tool, then the grasped object."""
        return [link.name for link in self.links] + list(RESERVED_FRAMES)

    def pose_column_names(self) -> list[str]:
        return [columns.pose_column(frame, f) for frame in self.pose_frames() for f in columns.POSE_FIELDS]

    def run_columns(self) -> tuple[list[str], list[str]]:
        """Every column of a run of this model and its unit, in frame order."""
        names = [columns.TIME] + [v.name for v in self.variables] + self.pose_column_names()
        units = ["s"] + [v.unit for v in self.variables] + list(columns.POSE_UNITS) * len(self.pose_frames())
        return names, units

    def joint_position_columns(self) -> list[str]:
        """Each joint's position column (always streamed: it tells the pose after a run)."""
        names = {v.name for v in self.variables}
        found = (columns.joint_column(link.joint, columns.JOINT_POSITION) for link in self.links)
        return [c for c in found if c in names]


def check_values(
    model: ModelDescription, changes: Mapping[str, object], base: Mapping[str, float] | None = None
) -> dict[str, float]:
    """Validate `changes` against the model's parameters and return the whole new value set.

    All or nothing: the first bad entry raises DecodeError naming it, and nothing is applied.
    """
    values = dict(base if base is not None else model.default_values())
    params = {p.name: p for p in model.parameters}
    for name, raw in changes.items():
        where = f"values.{name}"
        p = params.get(name)
        if p is None:
            raise DecodeError(where, f"unknown parameter of model {model.id}")
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise DecodeError(where, f"must be a number, got {type(raw).__name__}")
        value = float(raw)
        if not math.isfinite(value):
            raise DecodeError(where, "must be a finite number")
        if not p.min <= value <= p.max:
            raise DecodeError(where, f"{value:g} {p.unit} is outside [{p.min:g}, {p.max:g}] {p.unit}".strip())
        if p.integer and not value.is_integer():
            raise DecodeError(where, f"{value:g} must be a whole number")
        values[name] = value
    return values


def check_joints(model: ModelDescription, q: Sequence[float], where: str) -> None:
    """Refuse joint positions that do not fit the arm: their count, or one outside its joint's range."""
    if len(q) != len(model.links):
        raise DecodeError(where, f"{len(q)} joint positions for a {len(model.links)}-joint arm")
    for i, (qi, link) in enumerate(zip(q, model.links, strict=True)):
        if not link.joint_min <= qi <= link.joint_max:
            raise DecodeError(
                f"{where}[{i}]",
                f"{link.joint} = {qi:.4g} rad is outside its range "
                f"[{link.joint_min:.4g}, {link.joint_max:.4g}] rad",
            )
