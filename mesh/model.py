"""A robot model as data: what every client receives instead of importing models/.

The kinematic chain follows the paper's Link convention (SIMECS-RI §5.1): joint i turns its frame about
the local z axis by q_i; then the link applies an *initial rotation* (roll-pitch-yaw, no component about
the joint axis), a *central translation* along x equal to the link length, and a *final translation*
with no x component. Shapes hang on link frames; at most one per link is resizable along the link axis,
so a changed length reshapes the arm without a new model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from .codec import DecodeError

VERSION = 1

ShapeKind = Literal["cylinder", "pipe", "box", "beam", "sphere"]


@dataclass
class Parameter:
    """One tunable value. `name` is a dotted path whose prefix is its `component`."""

    name: str
    value: float
    unit: str
    description: str
    min: float
    max: float
    component: str
    appearance: bool = False  # True: changing it reshapes the 3D arm (e.g. a link length)
    integer: bool = False  # True: only whole numbers (e.g. a switch 0/1)

    def validate(self) -> None:
        if not self.min <= self.value <= self.max:
            raise DecodeError("value", f"{self.value} outside [{self.min}, {self.max}]")


@dataclass
class Variable:
    """One scalar output, as a column of the result frames."""

    name: str
    unit: str
    description: str
    component: str


@dataclass
class Shape:
    """A solid attached to a link frame (or to the base when `link` is -1).

    Sizes in metres: cylinder/pipe use `radius` (`inner_radius` for pipe) and `length` along `axis`;
    box/beam use `length` along `axis` and `width`, `height` across it; sphere uses `radius`.
    `origin` is the start point in the link frame; the solid extends from there along `axis`.
    If `resizable` is true its `length` is the link length parameter of that link at every moment.
    `scales_with` maps a dimension (length, radius, inner_radius, width, height) to a parameter: the
    dimension is multiplied by value / default of that parameter. With `anchor` "end", the x of
    `origin` is measured from the end of the link at its default length.
    """

    kind: ShapeKind
    link: int
    origin: list[float]
    axis: Literal["x", "y", "z"] = "x"
    length: float = 0.0
    radius: float = 0.0
    inner_radius: float = 0.0
    width: float = 0.0
    height: float = 0.0
    color: list[int] = field(default_factory=lambda: [180, 180, 190])
    resizable: bool = False
    # Appearance that follows parameters beyond the link length: each listed dimension is scaled by
    # value / default of the named parameter; anchor "end" measures `origin` x from the link's end, so
    # the shape moves with the link length (a flange, a payload).
    scales_with: dict[str, str] = field(default_factory=dict)
    anchor: Literal["start", "end"] = "start"


@dataclass
class Link:
    """Joint i (about local z) followed by link i, in the paper's Link convention."""

    name: str
    joint: str
    initial_rotation_rpy: list[float]
    length_param: str  # name of the Parameter holding the central translation along x
    final_translation: list[float]
    joint_min: float  # rad
    joint_max: float  # rad


@dataclass
class InitEquation:
    """How an internal state follows from joint positions at rest (paper §5.2), e.g. q_m = n * q_l."""

    state: str
    expression: str
    description: str


@dataclass
class DocPage:
    """One page of read-only hypertext documentation; markdown links `doc:<id>` go to other pages."""

    id: str
    title: str
    markdown: str
    parent: str = ""
    children: list[str] = field(default_factory=list)


@dataclass
class ModelSummary:
    id: str
    name: str
    summary: str
    joints: int
    command_levels: list[str]


@dataclass
class ModelDescription:
    """Everything a client needs to show, animate, parametrise and command a model."""

    id: str
    name: str
    summary: str
    base_translation: list[float]
    links: list[Link]
    tool_translation: list[float]
    shapes: list[Shape]
    parameters: list[Parameter]
    variables: list[Variable]
    init_equations: list[InitEquation]
    doc_root: str
    docs: list[DocPage]
    command_levels: list[str]  # e.g. ["joint_path"]; see docs/PROTOCOL.md for every level
    environment: list[Shape] = field(default_factory=list)  # floor, bench, obstacles (link = -1)
    type: Literal["model"] = "model"
    v: int = VERSION

    def summary_entry(self) -> ModelSummary:
        return ModelSummary(self.id, self.name, self.summary, len(self.links), list(self.command_levels))

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    def default_values(self) -> dict[str, float]:
        return {p.name: p.value for p in self.parameters}


def check_values(
    model: ModelDescription, changes: dict[str, object], base: dict[str, float] | None = None
) -> dict[str, float]:
    """Validate `changes` against the model's parameters and return the whole new value set.

    All or nothing: the first bad entry raises DecodeError naming it, and nothing is applied.
    """
    import math

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
