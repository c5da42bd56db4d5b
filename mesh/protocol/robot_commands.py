"""The robot commands of paper §2.1, one message shape per level, and the action primitives.

Direct input (open loop: motor currents; closed loop: set points), movement (a joint path; a Cartesian
path) and high level (an action, a task of actions, a mission of tasks). They travel inside
`set_command` and are told apart by `kind`. A model lists the kinds it accepts in `command_levels`.

What a shape cannot say alone (a joint within its range, a pose the arm can reach, a current within
i_max) is checked by the server against the session's model, values and initial pose, before a run;
the refusal names the field (`command.tasks[1].actions[2].args.speed_pct`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
from msgspec import Meta

from .primitives import NAME_PATTERN, FieldProblem, Name, Record

#: The most nodes a path, actions a task and tasks a mission hold (the pendants refuse more first).
MAX_ITEMS = 1000
Percent = Annotated[float, Meta(gt=0.0, le=100.0, description="percent of the maxima, (0, 100]")]
Seconds = Annotated[float, Meta(ge=0.0, le=1e9)]
Vec3 = Annotated[list[float], Meta(min_length=3, max_length=3)]
#: A label a user may leave empty: "" or a name.
Label = Annotated[
    str,
    Meta(
        pattern=r"^([A-Za-z0-9][A-Za-z0-9_.-]{0,63})?$",
        description="the user's label: empty, or 1-64 letters, digits, '_', '-', '.' starting with a "
        "letter or digit (no spaces)",
    ),
]
#: Points of a piecewise-linear signal, and samples a generator may expand to (limits.reference_samples).
MAX_POINTS = 100_000


class RobotCommandBase(Record, tag_field="kind"):
    """One level of the paper's robot commands (§2.1), told apart by `kind`."""

    @property
    def kind(self) -> str:
        return str(type(self).__struct_config__.tag)


# -- movement: joint space -------------------------------------------------------------------------
class PathNode(Record):
    """A via point of a joint path (PDL2 MOVE-like): destination, speed and acceleration reductions."""

    q: Annotated[
        list[float], Meta(min_length=1, max_length=64, description="destination, rad, one per joint")
    ]
    speed_pct: Annotated[Percent, Meta(description="of each joint's traj.max_speed")] = 100.0
    acc_pct: Annotated[Percent, Meta(description="of each joint's traj.max_acc")] = 100.0


class JointPath(RobotCommandBase, tag="joint_path"):
    """Every node reached and stopped at, in order; each segment a synchronised trapezoidal move."""

    nodes: Annotated[list[PathNode], Meta(min_length=1, max_length=MAX_ITEMS)]


# -- movement: Cartesian space ---------------------------------------------------------------------
class CartesianNode(Record):
    """A tool pose to reach: position in m and orientation as roll-pitch-yaw in rad, both in the world
    frame (R = Rz(yaw) Ry(pitch) Rx(roll)). `lin`: a straight line in position with the orientation
    slerped, trapezoidal in path length; `ptp`: inverse kinematics of the pose, then a joint move."""

    position: Annotated[Vec3, Meta(description="m, world frame")]
    rpy: Annotated[Vec3, Meta(description="rad: roll, pitch, yaw about the fixed x, y, z axes")]
    move: Literal["lin", "ptp"] = "lin"
    speed_pct: Annotated[
        Percent, Meta(description="lin: of the cart.* speed maxima; ptp: of the joints'")
    ] = 100.0
    acc_pct: Annotated[Percent, Meta(description="lin: of the cart.* acc maxima; ptp: of the joints'")] = (
        100.0
    )
    force: Annotated[
        float,
        Meta(
            ge=0.0,
            le=1000.0,
            description="N: under control_system opspace_hybrid the tool pushes with this force along "
            "force_axis from this node's start until a node says otherwise; 0 = motion control only",
        ),
    ] = 0.0
    force_axis: Annotated[
        Vec3, Meta(description="the world direction the tool pushes along (normalised; not 0)")
    ] = msgspec.field(default_factory=lambda: [0.0, 0.0, -1.0])

    def __post_init__(self) -> None:
        norm = math.sqrt(sum(a * a for a in self.force_axis))
        if not (math.isfinite(norm) and norm > 1e-9):
            raise FieldProblem("force_axis", "a direction: finite, not 0")


class CartesianPath(RobotCommandBase, tag="cartesian_path"):
    """Every node reached and stopped at, in order, starting from the initial pose's tool pose."""

    nodes: Annotated[list[CartesianNode], Meta(min_length=1, max_length=MAX_ITEMS)]


# -- direct input: signals -------------------------------------------------------------------------
Point = Annotated[list[float], Meta(min_length=2, max_length=2, description="[t in s, value]")]


class TableSignal(Record, tag_field="type", tag="table"):
    """Piecewise linear through the points; the first value before them, the last after them. Two
    points at the same time make a jump."""

    points: Annotated[list[Point], Meta(min_length=1, max_length=MAX_POINTS)]

    def __post_init__(self) -> None:
        for k in range(1, len(self.points)):
            if self.points[k][0] < self.points[k - 1][0]:
                raise FieldProblem(f"points[{k}]", "times must not decrease")
        if self.points[0][0] < 0.0:
            raise FieldProblem("points[0]", "times start at 0 s or later")


class StepSignal(Record, tag_field="type", tag="step"):
    """`offset` before `start`, `offset + amplitude` from then on."""

    amplitude: float
    offset: float = 0.0
    start: Seconds = 0.0


class RampSignal(Record, tag_field="type", tag="ramp"):
    """`offset` until `start`, then rising by `slope` per second for `duration` s (0: to the end),
    then held."""

    slope: Annotated[float, Meta(description="units per s")]
    offset: float = 0.0
    start: Seconds = 0.0
    duration: Annotated[Seconds, Meta(description="s; 0 = until the run ends")] = 0.0


class SineSignal(Record, tag_field="type", tag="sine"):
    """`offset + amplitude sin(2 pi f (t - start) + phase)` for `duration` s from `start` (0: to the
    end); `offset` outside."""

    amplitude: float
    frequency_hz: Annotated[float, Meta(gt=0.0, le=500.0)]
    offset: float = 0.0
    phase: Annotated[float, Meta(description="rad")] = 0.0
    start: Seconds = 0.0
    duration: Annotated[Seconds, Meta(description="s; 0 = until the run ends")] = 0.0


class ChirpSignal(Record, tag_field="type", tag="chirp"):
    """A linear sweep from f0 to f1 over `duration` s from `start`: `offset + amplitude sin(phi(t))`,
    phi = 2 pi (f0 tau + (f1 - f0) tau^2 / (2 duration)); `offset` outside."""

    amplitude: float
    f0_hz: Annotated[float, Meta(ge=0.0, le=500.0)]
    f1_hz: Annotated[float, Meta(ge=0.0, le=500.0)]
    duration: Annotated[float, Meta(gt=0.0, le=3600.0, description="s")]
    offset: float = 0.0
    start: Seconds = 0.0


#: A direct input's unit: motor current (open loop), joint position or speed (closed loop).
SignalUnit = Literal["A", "rad", "rad/s"]
Signal = TableSignal | StepSignal | RampSignal | SineSignal | ChirpSignal
SIGNAL_TYPES = ("table", "step", "ramp", "sine", "chirp")


class DirectInput(RobotCommandBase, tag="direct_input"):
    """Signals straight into a joint's loops, keyed by joint name (`joint1`...).

    `open_loop`: the signal is the motor current amplitude set point (A) of the joint's current loop;
    its position and speed loops are bypassed. `closed_loop`: the signal is the joint's position (rad)
    or speed (rad/s, load side) set point, as `reference` says; the trajectory generator is bypassed
    (position: into the position loop, with the signal's slope as speed feed-forward; speed: into the
    speed loop, the position loop bypassed). Joints without a signal hold their initial position."""

    mode: Literal["open_loop", "closed_loop"]
    signals: Annotated[dict[Name, Signal], Meta(min_length=1, max_length=64)]
    reference: Annotated[
        Literal["position", "speed"], Meta(description="closed_loop: what the signals are")
    ] = "position"

    @property
    def unit(self) -> SignalUnit:
        """What the signals' values are in."""
        if self.mode == "open_loop":
            return "A"
        return "rad" if self.reference == "position" else "rad/s"


# -- high level: actions, tasks, missions ----------------------------------------------------------
Primitive = Literal[
    "move_joints", "move_linear", "move_to_pose", "wait", "home", "set_payload", "grasp", "release"
]
#: A plain `str`, not `Name`, in this union: msgspec 0.22 corrupts memory when a number out of range
#: (1e999) meets a union of a float and a pattern-constrained string (a hostile command crashed the
#: proxy); `Action.__post_init__` checks the name instead.
ArgValue = Annotated[
    float | list[float] | str,
    Meta(
        description="a number, a vector (q, position, rpy) or a name (grasp's object: 1-64 letters, "
        "digits, '_', '-', '.')"
    ),
]


class Action(RobotCommandBase, tag="action"):
    """One step: a primitive with its arguments (ACTION_ARGS); `name` is the user's label for it."""

    primitive: Primitive
    args: Annotated[dict[Name, ArgValue], Meta(max_length=16)] = {}
    name: Label = ""

    def __post_init__(self) -> None:
        for key, value in self.args.items():
            if isinstance(value, str) and not re.match(NAME_PATTERN, value):
                raise FieldProblem(
                    f"args.{key}", f"a name is 1-64 letters, digits, '_', '-', '.', not {value[:64]!r}"
                )


class Task(RobotCommandBase, tag="task"):
    """A named sequence of actions, run in order."""

    name: Name
    actions: Annotated[list[Action], Meta(min_length=1, max_length=MAX_ITEMS)]


class Mission(RobotCommandBase, tag="mission"):
    """A named sequence of tasks, run in order."""

    name: Name
    tasks: Annotated[list[Task], Meta(min_length=1, max_length=MAX_ITEMS)]


RobotCommand = JointPath | CartesianPath | DirectInput | Action | Task | Mission
#: A saved program of the user's library: an action, a task or a mission.
Program = Action | Task | Mission
ProgramKind = Literal["action", "task", "mission"]
COMMAND_LEVELS = ("direct_input", "joint_path", "cartesian_path", "action", "task", "mission")


@dataclass(frozen=True)
class ArgSpec:
    """One argument of a primitive: `size` 0 for a number, -1 for one value per joint, NAME_ARG for a
    name, else a vector."""

    size: int
    unit: str
    description: str
    default: float | None = None  # None: required (vectors: see `optional`)
    optional: bool = False  # a vector that may be left out (see its description)
    min: float = -1e300
    max: float = 1e300
    above_min: bool = False  # the value must be greater than `min`, not equal to it


#: ArgSpec.size of an argument that is a name (of an obstacle of the session).
NAME_ARG = -2
#: m: the farthest the tool point may be from an object's surface for `grasp` to take it.
GRASP_REACH = 0.01

_SPEED = ArgSpec(
    0, "%", "speed, percent of the maxima (joints' or cart.*)", 100.0, min=0.0, max=100.0, above_min=True
)
_ACC = ArgSpec(0, "%", "acceleration, percent of the maxima", 100.0, min=0.0, max=100.0, above_min=True)
_POSITION = ArgSpec(3, "m", "tool position, world frame")
_RPY = ArgSpec(
    3, "rad", "tool roll, pitch, yaw; left out: the orientation at the action's start", optional=True
)

#: Every primitive's arguments: the one table the server checks and the documentation shows.
ACTION_ARGS: dict[str, dict[str, ArgSpec]] = {
    "move_joints": {
        "q": ArgSpec(-1, "rad", "destination, one per joint"),
        "speed_pct": _SPEED,
        "acc_pct": _ACC,
    },
    "move_linear": {"position": _POSITION, "rpy": _RPY, "speed_pct": _SPEED, "acc_pct": _ACC},
    "move_to_pose": {"position": _POSITION, "rpy": _RPY, "speed_pct": _SPEED, "acc_pct": _ACC},
    "wait": {"duration": ArgSpec(0, "s", "time to hold still", min=0.0, max=3600.0)},
    "home": {"speed_pct": _SPEED, "acc_pct": _ACC},
    "set_payload": {
        "mass": ArgSpec(0, "kg", "the payload from now on (payload.mass)", min=0.0, max=500.0),
        "size": ArgSpec(
            0, "m", "its cube edge (payload.size); left out: unchanged", optional=True, min=0.01, max=2.0
        ),
    },
    "grasp": {"object": ArgSpec(NAME_ARG, "", "the obstacle to take: its name in the session's list")},
    "release": {},
}
#: What each primitive does, for the documentation and the pendant.
ACTION_DOC: dict[str, str] = {
    "move_joints": "a synchronised joint trapezoid to `q` (as a joint_path node)",
    "move_linear": "a straight tool line to the pose (as a `lin` cartesian_path node)",
    "move_to_pose": "inverse kinematics of the pose, then a joint trapezoid (as a `ptp` node)",
    "wait": "hold the current set point for `duration` s",
    "home": "a joint trapezoid to the model's home posture (`home` in its description)",
    "set_payload": "the payload changes at once (a known mass taken or put down without a shape)",
    "grasp": (
        "the tool takes the obstacle `object` (it needs a mass, and the tool point within "
        f"{GRASP_REACH * 1000:g} mm of it): from now on it moves with the tool, its mass and inertia "
        "are the tool's load and it touches the other obstacles"
    ),
    "release": "the tool lets go of what it holds: the object stays where it is, fixed, from now on",
}


def control_refusal(command: RobotCommand, control_system: str) -> str:
    """Why `command` cannot run under `control_system` ('' if it can): the operational-space
    controllers track positions, so direct input of currents or speeds needs the joint cascade; only
    the hybrid controller follows force set points."""
    if control_system != "opspace_hybrid" and isinstance(command, CartesianPath):
        for i, node in enumerate(command.nodes):
            if node.force > 0.0:
                return (
                    f"nodes[{i}] sets a force: it needs control_system opspace_hybrid, not {control_system}"
                )
    if control_system == "joint_independent" or not isinstance(command, DirectInput):
        return ""
    if command.mode == "open_loop":
        return f"{control_system} tracks positions: open-loop direct input needs joint_independent"
    if command.reference == "speed":
        return f"{control_system} tracks positions: direct input of speeds needs joint_independent"
    return ""
