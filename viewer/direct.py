"""A direct input as data (paper §2.1, the lowest command level): one signal per joint, a table of
points or a generator (step, ramp, sine, chirp), all in one mode (motor currents in open loop, or
position or speed set points in closed loop), edited as the signal-editor pendant edits it.

The signals' shapes, bounds and defaults are the protocol's (`mesh.protocol.robot_commands`): a signal is
built by decoding it, so what this editor takes is what the server takes before its own checks
against the model (ranges, i_max, max_speed), which come back as a refusal naming the field. What
the run will follow is drawn from the server's expansion (`CommandPlan.signals`), never recomputed.

No GUI here: `direct_pendant.py` draws it, the session controller owns it, tests use it directly.
"""

from __future__ import annotations

import functools
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import msgspec
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.robot_commands import SIGNAL_TYPES, SignalUnit

from .path import PathError
from .tree import fmt, numbers_text, parse_numbers

#: The pendant's Mode dropdown: its labels and the (mode, reference) each stands for.
MODES: dict[str, tuple[str, str]] = {
    "Motor current (open loop)": ("open_loop", "position"),
    "Position set point (closed loop)": ("closed_loop", "position"),
    "Speed set point (closed loop)": ("closed_loop", "speed"),
}
NO_SIGNAL = "none"  # the Signal dropdown's entry for a joint left to hold its initial position
TABLE = "table"
GENERATORS = tuple(k for k in SIGNAL_TYPES if k != TABLE)
_CLASSES: dict[str, Any] = {cls.__struct_config__.tag: cls for cls in typing.get_args(m.Signal)}

#: How each generator field reads in the pendant: its label and its unit ("{u}": the signal's unit).
_FIELD_TEXT = {
    "amplitude": ("Amplitude", "{u}"),
    "offset": ("Offset", "{u}"),
    "slope": ("Slope", "{u}/s"),
    "start": ("Start", "s"),
    "duration": ("Duration", "s"),
    "frequency_hz": ("Frequency", "Hz"),
    "f0_hz": ("Start frequency", "Hz"),
    "f1_hz": ("End frequency", "Hz"),
    "phase": ("Phase", "rad"),
}
#: A first value for the fields the protocol requires (it has no default for them): small, so a
#: signal applied as it comes moves the arm a little.
_FIRST = {"amplitude": 0.1, "slope": 0.1, "frequency_hz": 1.0, "f0_hz": 0.5, "f1_hz": 5.0, "duration": 2.0}
FIRST_TABLE = "0, 0\n1, 0.1"  # what a new table starts as: one line per point


@dataclass(frozen=True)
class SignalField:
    """One number of a generator, as its pendant field shows it."""

    name: str
    label: str  # with "{u}" where the signal's unit goes
    first: float  # the value a new signal starts with
    hint: str


def _hint(cls: Any, name: str) -> str:
    info = typing.cast(msgspec.inspect.StructType, msgspec.inspect.type_info(cls))
    field = next(f for f in info.fields if f.name == name)
    extra = getattr(field.type, "extra_json_schema", None) or {}
    return str(extra.get("description", ""))


@functools.cache
def signal_fields(kind: str) -> tuple[SignalField, ...]:
    """The numbers of a generator (`step`, `ramp`, `sine`, `chirp`) in the protocol's order (read
    from the protocol's structs once: the pendant asks on every joint picked)."""
    cls = _CLASSES[kind]
    out = []
    for f in msgspec.structs.fields(cls):
        label, unit = _FIELD_TEXT.get(f.name, (f.name, ""))
        first = f.default if f.default is not msgspec.NODEFAULT else _FIRST.get(f.name, 0.0)
        hint = _hint(cls, f.name) or " ".join((cls.__doc__ or "").split())
        out.append(SignalField(f.name, f"{label} [{unit}]", float(first), hint))
    return tuple(out)


def unit_of(mode: str, reference: str) -> SignalUnit:
    return m.DirectInput(mode, {}, reference).unit  # type: ignore[arg-type]


def parse_points(text: str) -> list[list[float]]:
    """A table typed one point per line, `t, value` (commas, spaces or semicolons between; blank
    lines and lines starting with # left out). PathError names the line that is not two numbers."""
    points = []
    for k, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            point = parse_numbers(line)
        except ValueError:
            point = []
        if len(point) != 2:
            raise PathError(f"table line {k}: {line!r} is not two numbers (t in s, value)")
        points.append(point)
    if not points:
        raise PathError("the table is empty: one point per line, t in s and the value")
    return points


def points_text(points: Sequence[Sequence[float]]) -> str:
    return "\n".join(numbers_text(point) for point in points)


#: rad: how far a position set point at t = 0 may be from where its joint starts without a warning.
JUMP_TOLERANCE = 1e-3


class DirectInputEditor:
    """The signals being edited: a mode for all of them and at most one signal per joint.
    `initial()` gives where the joints start (the session's initial pose, rad): a new position set
    point starts there, so the arm does not jump at t = 0."""

    def __init__(self, joints: Sequence[str], initial: Callable[[], Sequence[float]] = lambda: ()) -> None:
        self.joints = list(joints)
        self.initial = initial
        self.mode = "open_loop"
        self.reference = "position"
        self.signals: dict[str, m.Signal] = {}

    @property
    def empty(self) -> bool:
        return not self.signals

    @property
    def unit(self) -> SignalUnit:
        return unit_of(self.mode, self.reference)

    @property
    def mode_label(self) -> str:
        return next(k for k, v in MODES.items() if v == (self.mode, self.reference))

    def set_mode(self, label: str) -> None:
        if label not in MODES:
            raise PathError(f"no mode {label!r}: one of {', '.join(MODES)}")
        self.mode, self.reference = MODES[label]

    def _joint(self, joint: str) -> str:
        if joint not in self.joints:
            raise PathError(f"no joint {joint!r}: the arm has {', '.join(self.joints)}")
        return joint

    def set_signal(self, joint: str, kind: str, numbers: dict[str, float], table: str = "") -> None:
        """The signal of `joint`: a generator from its numbers, or a table from its typed points.
        PathError names the field the protocol refuses (nothing changes then)."""
        self._joint(joint)
        if kind == TABLE:
            obj: dict[str, Any] = {"type": TABLE, "points": parse_points(table)}
        elif kind in GENERATORS:
            names = {f.name for f in signal_fields(kind)}
            obj = {"type": kind, **{k: float(v) for k, v in numbers.items() if k in names}}
        else:
            raise PathError(f"no signal type {kind!r}: one of {', '.join(SIGNAL_TYPES)}")
        try:
            self.signals[joint] = codec.from_obj(m.Signal, obj)  # type: ignore[arg-type]
        except codec.DecodeError as exc:
            raise PathError(f"{joint} {kind}: {exc}") from None

    def remove(self, joint: str) -> None:
        if self.signals.pop(self._joint(joint), None) is None:
            raise PathError(f"{joint} has no signal")

    def shown(self, joint: str) -> tuple[str, dict[str, dict[str, float]], str]:
        """What the pendant shows for `joint`: its signal type, every generator's numbers (the
        joint's own for its generator, the first values for the others) and a table as text."""
        sig = self.signals.get(joint)
        numbers = {kind: {f.name: f.first for f in signal_fields(kind)} for kind in GENERATORS}
        start = self.start_of(joint)
        if start is not None:  # a position set point: from where the joint starts
            for fields in numbers.values():
                if "offset" in fields:
                    fields["offset"] = round(start, 6)
        table = (
            FIRST_TABLE if start is None else points_text([[0.0, round(start, 6)], [1.0, round(start, 6)]])
        )
        if sig is None:
            return NO_SIGNAL, numbers, table
        obj = codec.to_obj(sig)
        kind = obj.pop("type")
        if kind == TABLE:
            return TABLE, numbers, points_text(obj["points"])
        numbers[kind].update({k: float(v) for k, v in obj.items()})
        return kind, numbers, table

    def start_of(self, joint: str) -> float | None:
        """Where `joint` starts (rad) when its signal is a position set point; None otherwise."""
        if (self.mode, self.reference) != ("closed_loop", "position"):
            return None
        q0 = list(self.initial())
        k = self.joints.index(joint) if joint in self.joints else -1
        return float(q0[k]) if 0 <= k < len(q0) else None

    def jumps(self, preview: m.SignalPreview | None) -> list[str]:
        """The joints whose position set point at t = 0, as the server expanded it, is not where the
        joint starts: the arm would jump there at once."""
        if preview is None or not preview.t or preview.unit != "rad":
            return []
        out = []
        for joint, values in preview.values.items():
            start = self.start_of(joint)
            if start is not None and values and abs(values[0] - start) > JUMP_TOLERANCE:
                out.append(
                    f"{joint} starts at {start:.4g} rad but its set point at t = 0 is {values[0]:.4g} rad: "
                    "the arm jumps there at once"
                )
        return out

    # -- protocol --------------------------------------------------------------------------------
    def to_command(self) -> m.DirectInput:
        if not self.signals:
            raise PathError("no joint has a signal: apply one to a joint first")
        ordered = {j: self.signals[j] for j in self.joints if j in self.signals}
        return m.DirectInput(self.mode, ordered, self.reference)  # type: ignore[arg-type]

    def load(self, cmd: m.DirectInput) -> None:
        """Take a direct input from the server (a restored session); joints the arm lacks are left out."""
        self.mode, self.reference = cmd.mode, cmd.reference
        self.signals = {j: s for j, s in cmd.signals.items() if j in self.joints}

    def describe(self, joint: str) -> str:
        """One signal in words: `sine 0.1 A at 1 Hz from 0 s`."""
        sig = self.signals.get(joint)
        if sig is None:
            return "holds its initial position"
        u = self.unit
        if isinstance(sig, m.TableSignal):
            end = sig.points[-1][0]
            return f"table of {len(sig.points)} points to {fmt(end)} s"
        if isinstance(sig, m.StepSignal):
            return f"step {fmt(sig.offset)} → {fmt(sig.offset + sig.amplitude)} {u} at {fmt(sig.start)} s"
        if isinstance(sig, m.RampSignal):
            return f"ramp {fmt(sig.slope)} {u}/s from {fmt(sig.start)} s"
        if isinstance(sig, m.SineSignal):
            return f"sine {fmt(sig.amplitude)} {u} at {fmt(sig.frequency_hz)} Hz from {fmt(sig.start)} s"
        if isinstance(sig, m.ChirpSignal):
            return (
                f"chirp {fmt(sig.amplitude)} {u}, {fmt(sig.f0_hz)} → {fmt(sig.f1_hz)} Hz "
                f"over {fmt(sig.duration)} s"
            )
        return type(sig).__name__

    def table_markdown(self, selected: str = "") -> str:
        """The signals as a table, the joint being edited marked."""
        if not self.signals:
            return "_No signal yet: pick a joint and a signal type, then **Apply signal**._"
        rows = ["| joint | signal |", "|---|---|"]
        for j in self.joints:
            if j in self.signals or j == selected:
                name = f"**▶{j}**" if j == selected else j
                rows.append(f"| {name} | {self.describe(j)} |")
        return "\n".join(rows) + f"\n\n{self.mode_label}; the other joints hold their initial position."
