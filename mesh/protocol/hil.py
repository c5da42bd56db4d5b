"""The controller-in-the-loop exchange (PROTOCOL.md §6.3): what a sensor frame and an actuator frame
hold, column by column, and how an actuator frame is checked.

Both are ordinary binary frames (frames.py) of one row: the worker puts a sensor frame on
`hil/sensors` at the start of every control period (`seq` = the period's number, from 0) and waits
for the actuator frame with the same `run_index` and `seq` on `hil/actuators`. Columns are fixed by
this module, in joint order, so a controller needs no message to read them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import frames

#: Per joint, after the time column: (name, unit, meaning). The worker's kernel writes them in this order.
SENSOR_JOINT_FIELDS = (
    ("q", "rad", "load-side resolver angle (with its modelled error)"),
    ("qd", "rad/s", "load-side speed: the derivative of that reading"),
    ("theta_m", "rad", "motor resolver angle, motor shaft (with its modelled error)"),
    ("omega_m", "rad/s", "motor resolver speed, motor shaft"),
    ("i_a", "A", "phase a current as the current loop measures it (offset included)"),
    ("i_b", "A", "phase b current as the current loop measures it (offset included)"),
    ("q_ref", "rad", "the command's set point now (jog included); a current in A for a joint in mode 2"),
    ("qd_ref", "rad/s", "the command's speed set point now (jog included)"),
    ("mode", "-", "what the command asks of the joint: 0 position, 1 speed, 2 current, 3 hold"),
)
#: Per joint, the actuator row: what replaces the built-in cascade of an external joint.
ACTUATOR_JOINT_FIELDS = (
    (
        "i_ref",
        "A",
        "current amplitude set point of the joint's current loops (limited to motor.i_max); "
        "ignored for a joint the built-in controller keeps",
    ),
)
#: While it waits for an answer, the worker repeats the period's sensor frame this often (same seq):
#: a controller that joins late, or a frame lost on the way, costs one repeat, not the run.
RESEND_S = 0.05


def sensor_frame(run_index: int, seq: int, wall_ns: int, row: np.ndarray, attempt: int) -> bytes:
    return frames.encode(frames.Frame(run_index, seq, wall_ns, row.reshape(1, -1), attempt=attempt))


def actuator_frame(
    run_index: int, seq: int, wall_ns: int, i_ref: Sequence[float] | np.ndarray, attempt: int = 0
) -> bytes:
    """An answer to the sensor frame (`run_index`, `seq`, `attempt`): echo its attempt (0: not said)."""
    row = np.asarray(i_ref, dtype=float).reshape(1, -1)
    return frames.encode(frames.Frame(run_index, seq, wall_ns, row, attempt=attempt))


class ActuatorProblem(ValueError):
    """An actuator frame the worker cannot use; the text names what is wrong."""


def read_actuators(
    payload: bytes, run_index: int, n_joints: int, attempt: int = 0
) -> tuple[int, np.ndarray] | None:
    """(seq, i_ref per joint) of an actuator frame for run `run_index`'s `attempt`; None for a frame of
    another run (a controller still answering the previous one) or of another attempt of this one (a
    host taken for lost that goes on, frames.belongs); ActuatorProblem naming what is wrong."""
    try:
        frame = frames.decode(payload)
    except frames.FrameError as exc:
        raise ActuatorProblem(f"not a frame: {exc}") from None
    if not frames.belongs(frame.run_index, frame.attempt, run_index, attempt):
        return None
    if frame.rows.shape != (1, n_joints * len(ACTUATOR_JOINT_FIELDS)):
        rows, cols = frame.rows.shape
        raise ActuatorProblem(
            f"{rows}x{cols} values: an actuator frame is 1 row of {n_joints} (one per joint)"
        )
    values = frame.rows[0]
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ActuatorProblem(f"i_ref of joint {int(bad[0]) + 1} is not a finite number")
    return frame.seq, values.copy()
