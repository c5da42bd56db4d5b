"""Runs compared (paper §3.2 trend presentation, issue 12 "runs compared for real"): what a shared
time cursor shows of each run and how the runs differ. No widgets here (compare_panel.py draws them).

A run is scrubbed from its `RunTrack`: the link poses the server computed, fetched once per run (at
most `TRACK_POINTS` samples), so moving the cursor redraws the arm without asking the server again.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from simecs.mesh.protocol import columns
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription

from .markup import escape_html
from .series import value_at
from .units import labelled

#: A recording compared with the session's runs goes by its name behind this mark: the key the panel,
#: the plots' legends and the tracks know it by (a run id never holds a space; plain text, because an
#: emoji needs a font not every browser's machine has).
RECORDING_MARK = "rec "

TRACK_POINTS = 4000  # samples of a run's poses kept for scrubbing (about 1 ms apart over 5 s)
MAX_DIFF_ROWS = 40  # parameters listed as differing at most (the rest are counted)


@dataclass
class RunTrack:
    """A finished run's link poses over time, the context it ran with and what the server says of it
    (its RunInfo: how long it was jogged)."""

    run_id: str
    t: np.ndarray  # (n,) s
    poses: np.ndarray  # (n, frames, 7): x y z qw qx qy qz per link frame
    context: m.RunContext | None = None
    info: m.RunInfo | None = None
    q: np.ndarray | None = None  # (n, joints) rad: the joint positions at each sample, when streamed

    @property
    def end(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0

    def _nearest(self, time: float) -> int | None:
        if not len(self.t):
            return None
        k = int(np.searchsorted(self.t, time))
        if k >= len(self.t) or (k > 0 and time - self.t[k - 1] <= self.t[k] - time):
            k -= 1
        return max(k, 0)

    def at(self, time: float) -> np.ndarray | None:
        """The poses of the sample nearest `time` (the server's own, never interpolated); None for a
        run without samples."""
        k = self._nearest(time)
        return None if k is None else np.asarray(self.poses[k])

    def q_at(self, time: float) -> list[float] | None:
        """The joint positions of the sample nearest `time` (what the readout shows there)."""
        k = self._nearest(time)
        return None if k is None or self.q is None else [float(x) for x in self.q[k]]


def recording_key(name: str) -> str:
    return RECORDING_MARK + name


def recording_label(info: m.RecordingInfo) -> str:
    """A recording as the compare list offers it: when it was made, which run of which session, how
    long (its name alone is an opaque id: `<session>_<run>`)."""
    when = info.created.replace("T", " ").removesuffix("Z")[:16] + " UTC" if info.created else "recording"
    session = f"session {info.session[:6]}…" if info.session else info.name
    return f"{when} · {info.run_id} of {session} · {info.stop_time:g} s"


def recording_of_key(key: str) -> str:
    """The recording a compared key names ('' for a run of the session)."""
    return key[len(RECORDING_MARK) :] if key.startswith(RECORDING_MARK) else ""


def track_columns(model: ModelDescription) -> list[str]:
    """The columns a track is made of: every link frame's pose, in the scene's order, then the joint
    positions."""
    frames = model.pose_frames()[: len(model.links)]
    poses = [columns.pose_column(f, field) for f in frames for field in columns.POSE_FIELDS]
    return poses + model.joint_position_columns()


def track_of(
    run_id: str,
    names: Sequence[str],
    rows: np.ndarray,
    context: m.RunContext | None,
    info: m.RunInfo | None = None,
) -> RunTrack:
    """A results reply of `track_columns` (time first) as a track."""
    where = {name: k for k, name in enumerate(names)}
    pose_names = [n for n in names[1:] if n in where and n.startswith(columns.POSE_PREFIX)]
    frames = len(pose_names) // len(columns.POSE_FIELDS)
    poses = np.asarray(rows[:, [where[n] for n in pose_names]], dtype=float)
    joints = [n for n in names[1:] if not n.startswith(columns.POSE_PREFIX)]
    q = np.asarray(rows[:, [where[n] for n in joints]], dtype=float) if joints else None
    t = np.asarray(rows[:, 0], dtype=float)
    return RunTrack(run_id, t, poses.reshape(len(rows), frames, -1), context, info, q)


def track_every(samples: int) -> int:
    return max(1, math.ceil(samples / TRACK_POINTS))


def _number(value: float | None, unit: str = "") -> str:
    if value is None or not math.isfinite(value):
        return "—"
    text = f"{value:.6g}"
    return f"{text} {unit}" if unit and unit != "-" else text


def values_table(
    at: float,
    runs: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]],
    variables: Sequence[str],
    units: dict[str, str],
) -> str:
    """Markdown: each plotted variable's value at the cursor, a column per run (run → variable →
    (t, y) as the plots hold them); "—" where a run has no sample, e.g. after it ended."""
    if not runs or not variables:
        return "_Load a run's full resolution into a plot to read its values at the cursor._"
    lines = [f"| at {at:.3f} s | " + " | ".join(runs) + " |", "|---|" + "---:|" * len(runs)]
    for name in variables:
        cells = [_number(value_at(*data[name], at) if name in data else None) for data in runs.values()]
        label = labelled(name, units.get(name, ""))
        lines.append(f"| {escape_html(label)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def differences(
    contexts: dict[str, m.RunContext | None],
    model: ModelDescription,
    jogged: dict[str, float] | None = None,
) -> str:
    """Markdown: what differs between the runs' contexts (parameters, initial pose, command, settings,
    obstacles) and how long each was jogged (`jogged`: run -> s; a jog moves the arm beyond its
    command), a column per run; says so when they ran with the same inputs."""
    runs = list(contexts)
    if len(runs) < 2:
        return "_Pick a run to compare with: its differences from the shown run are listed here._"
    missing = [r for r, ctx in contexts.items() if ctx is None]
    if missing:
        return f"_Not known what produced {', '.join(missing)} (kept from an older server)._"
    ctxs = [c for c in contexts.values() if c is not None]
    units = {p.name: p.unit for p in model.parameters}
    head = "| differs | " + " | ".join(runs) + " |"
    lines = [head, "|---|" + "---:|" * len(runs)]
    names = sorted({n for c in ctxs for n in c.values})
    rows = 0
    for name in names:
        vals = [c.values.get(name) for c in ctxs]
        if _same_numbers(vals):
            continue
        rows += 1
        if rows <= MAX_DIFF_ROWS:
            row = " | ".join(_number(v, units.get(name, "")) for v in vals)
            lines.append(f"| {escape_html(name)} | {row} |")
    if rows > MAX_DIFF_ROWS:
        lines.append(f"| … {rows - MAX_DIFF_ROWS} more parameters | " + " | ".join("" for _ in runs) + " |")
    if not _same_numbers_lists([list(c.initial) for c in ctxs]):
        deg = [" ".join(f"{math.degrees(q):.1f}" for q in c.initial) for c in ctxs]
        lines.append("| initial pose [deg] | " + " | ".join(deg) + " |")
    for label, value in (
        ("stop time [s]", lambda c: f"{c.settings.stop_time:g}"),
        ("control system", lambda c: c.settings.control_system),
        ("pacing", lambda c: c.settings.pacing),
        ("obstacles", lambda c: str(len(c.obstacles))),
        ("replay of", lambda c: c.recording or "—"),
    ):
        cells = [value(c) for c in ctxs]
        if len(set(cells)) > 1:
            lines.append(f"| {label} | " + " | ".join(escape_html(x) for x in cells) + " |")
    jogs = [float((jogged or {}).get(r, 0.0)) for r in runs]
    if any(abs(j - jogs[0]) > 1e-9 for j in jogs):
        lines.append("| jogged [s] | " + " | ".join(f"{j:.2f}" if j else "no" for j in jogs) + " |")
    commands = [c.command for c in ctxs]
    if any(x != commands[0] for x in commands):
        labels = [_command_label(x) for x in commands]
        mark = "" if len(set(labels)) > 1 else " · edited"  # same kind and size, other targets
        lines.append("| command | " + " | ".join(escape_html(x) + mark for x in labels) + " |")
    if len(lines) == 2:
        same = f"_{', '.join(runs)} ran with the same parameters, initial pose, command and settings"
        return same + (", and each was jogged._" if any(jogs) else ", none jogged._")
    return "\n".join(lines)


def _same_numbers(vals: Sequence[float | None]) -> bool:
    first = vals[0]
    return all(
        (v is None and first is None)
        or (v is not None and first is not None and math.isclose(v, first, rel_tol=1e-12, abs_tol=0.0))
        for v in vals
    )


def _same_numbers_lists(lists: Sequence[list[float]]) -> bool:
    return all(len(x) == len(lists[0]) and np.allclose(x, lists[0], rtol=1e-12, atol=1e-12) for x in lists)


def _command_label(command: m.RobotCommand | None) -> str:
    return command_summary(command) if command is not None else "none"


def command_summary(command: m.RobotCommand | None) -> str:
    """What a command did, in a few words a run list can carry: `joint path, 2 nodes`."""
    if command is None:
        return "no command (held its pose)"
    if isinstance(command, m.JointPath | m.CartesianPath):
        kind = "joint path" if isinstance(command, m.JointPath) else "Cartesian path"
        return f"{kind}, {_count(len(command.nodes), 'node')}"
    if isinstance(command, m.DirectInput):
        mode = "currents" if command.mode == "open_loop" else f"{command.reference} set points"
        return f"direct input, {_count(len(command.signals), 'signal')} ({mode})"
    if isinstance(command, m.Task):
        return f"task {command.name}, {_count(len(command.actions), 'action')}"
    if isinstance(command, m.Mission):
        return f"mission {command.name}, {_count(len(command.tasks), 'task')}"
    if isinstance(command, m.Action):
        return f"action {command.primitive}"
    return type(command).__name__


def _count(n: int, thing: str) -> str:
    return f"{n} {thing}{'s' * (n != 1)}"


def run_summary(info: m.RunInfo, context: m.RunContext | None) -> str:
    """What a run did, for the lists that offer it (Results, Compare runs): its command (or the
    recording it replays), the control system when not the default, whether it ran until stopped,
    and how long it was jogged."""
    parts = []
    if info.recording:
        parts.append(f"replay of {info.recording}")
    elif context is not None:
        parts.append(command_summary(context.command))
        if context.settings.control_system != "joint_independent":
            parts.append(context.settings.control_system)
    if info.until_stopped:
        parts.append("until stopped")
    if info.jogged_s > 0:
        parts.append(f"jogged {info.jogged_s:.1f} s")
    return " · ".join(parts)
