"""A command as the server planned it: the reply of `set_command`, which every pendant draws (its steps,
the tool's path, a preview of the motion or of a direct input's signals)."""

from __future__ import annotations

from typing import Annotated

from msgspec import Meta

from .primitives import Name, Numbers, Record, Text
from .robot_commands import SignalUnit


class PlanStep(Record):
    """One step of an expanded command: where it sits in the command and when it runs."""

    step: Annotated[Text, Meta(description="its path in the command, e.g. tasks[1].actions[2]; nodes[3]")]
    what: Annotated[Text, Meta(description="the primitive or move type: move_linear, lin, ptp, joint, ...")]
    start: Annotated[float, Meta(ge=0.0, description="s of simulated time")]
    end: Annotated[float, Meta(ge=0.0, description="s")]
    task: Annotated[str, Meta(max_length=64, description="the task's name ('' outside a task)")] = ""
    action: Annotated[str, Meta(max_length=64, description="the action's label, else its primitive")] = ""
    q_end: Annotated[
        list[float],
        Meta(
            max_length=64,
            description="rad, the joint set points when the step ends (a pendant draws the arm there); "
            "[] when not known before the run (a direct input of motor currents)",
        ),
    ] = []
    slowed: Annotated[
        float,
        Meta(
            ge=1.0,
            description="how much longer the step takes than its Cartesian speed and acceleration "
            "percentages asked, because a joint's traj.max_speed or traj.max_acc would be exceeded: "
            "the line was time-scaled to them (1.0 = not slowed; only lin moves are)",
        ),
    ] = 1.0


#: Rows of a direct input's preview in a plan (SignalPreview).
PREVIEW_POINTS = 1000


class SignalPreview(Record):
    """A direct input's signals as the server expanded them (what the run follows), for a preview plot.
    At most 1000 samples (PREVIEW_POINTS) of the full table: all its rows when they fit, else each span of
    time's first row and each joint's lowest and highest (a dense sine keeps its envelope)."""

    unit: Annotated[
        SignalUnit,
        Meta(description="open_loop: A (motor current); closed_loop: rad (position) or rad/s (speed)"),
    ]
    t: Annotated[list[float], Meta(max_length=PREVIEW_POINTS, description="s, non-decreasing")]
    values: Annotated[
        dict[Name, Annotated[list[float], Meta(max_length=PREVIEW_POINTS)]],
        Meta(max_length=64, description="per signalled joint (joint1...), one value per t"),
    ]


#: Samples of a plan's motion (PlannedMotion) at most.
MOTION_POINTS = 200


class PlannedMotion(Record):
    """The joint set points of a command over its duration, for a preview of the move before it runs
    (a client animates its arm along them): evenly spaced in time, at most 200 (MOTION_POINTS)."""

    t: Annotated[list[float], Meta(max_length=MOTION_POINTS, description="s, increasing from 0")]
    q: Annotated[
        list[Annotated[list[float], Meta(max_length=64)]],
        Meta(max_length=MOTION_POINTS, description="rad, the joint set points at each t, one per joint"),
    ]


class CommandPlan(Record):
    """Reply data of `set_command`: the command as the server expanded it for the session's model,
    values and initial pose."""

    kind: Name
    duration: Annotated[float, Meta(ge=0.0, description="s until the last step ends")]
    steps: list[PlanStep]
    final_q: Annotated[Numbers, Meta(description="rad, the joint set points once the command is done")]
    tool_path: Annotated[
        list[Annotated[list[float], Meta(min_length=3, max_length=3)]],
        Meta(max_length=1000, description="m, the planned tool positions, at most 1000 (movement levels)"),
    ] = []
    stop_time_cuts: Annotated[bool, Meta(description="the run's stop_time ends before the command")] = False
    start_pose: Annotated[
        list[float],
        Meta(max_length=6, description="the tool at the initial pose: x, y, z (m), roll, pitch, yaw (rad)"),
    ] = []
    end_pose: Annotated[list[float], Meta(max_length=6, description="the tool once the command is done")] = []
    signals: Annotated[
        SignalPreview | None, Meta(description="direct_input: its signals as expanded; null otherwise")
    ] = None
    slowed: Annotated[
        float,
        Meta(
            ge=1.0,
            description="the largest PlanStep.slowed: how much the joint limits slowed the step they "
            "slowed most (1.0 = every step as fast as its percentages asked)",
        ),
    ] = 1.0
    motion: Annotated[
        PlannedMotion | None,
        Meta(
            description="the joint set points over the command, for a preview; null when positions are "
            "not known before the run (a joint follows a speed or a motor current)"
        ),
    ] = None
