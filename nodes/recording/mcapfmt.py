"""The simecs recording format: one MCAP file per run (mcapwriter.py writes it, mcapread.py reads it).

docs/RECORDINGS.md describes the format for readers; this module is its single source. Channels:

- `/vars`: every column of the run at full resolution, one message per output sample. Encoded as ROS 2
  CDR (schema encoding `ros2msg`): the payload is a 4-byte header and the row's float64 values, so
  values are bit-exact and a row costs ~2 us to encode. Full-precision JSON of ~150 numbers costs
  ~100 us per row in Python, more than the simulator spends computing it. Foxglove plots these
  fields (`/vars.joint1.q`). The MCAP `sequence` of each message is the frame number it came in,
  so a replay can republish the frames exactly as they were.
- `/tf` (`foxglove.FrameTransforms`), `/joint_states` (`foxglove.JointStates`): Foxglove JSON at
  most `viz_rate_hz` samples per simulated second (3D and joint panels need no more; the exact
  values are in `/vars`).
- `/scene` (`foxglove.SceneUpdate`): the arm's solid shapes as frame-locked entities, once per run, then
  the obstacles and contacts as the run moves them (mcapscene.py).
- `/log` (`foxglove.Log`): lifecycle events, dropped data, recovery notes.
Metadata records, all written when the file opens except the last two: `simecs.run` (layout with the
run's context, ids, format version), `simecs.params` (the values the run used), `simecs.session` (user,
initial pose, command, settings, replayed recording), `simecs.end` (how the file was closed),
`simecs.recovery` (set when a torn file was repaired). Attachment `model.json`: the model description.
"""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh.protocol import columns
from simecs.mesh.rules import shapes

#: 2: the layout in `simecs.run` carries the run's context (user, values, pose, command, settings).
FORMAT_VERSION = "2"
#: Versions this reader reads (1: the context is only in `simecs.params` and `simecs.session`).
READABLE_VERSIONS = ("1", "2")
LIBRARY = f"simecs-recorder/{FORMAT_VERSION}"
SCHEMA_DIR = Path(__file__).resolve().with_name("schemas")

TOPIC_VARS = "/vars"
TOPIC_TF = "/tf"
TOPIC_JOINTS = "/joint_states"
TOPIC_SCENE = "/scene"
TOPIC_LOG = "/log"
WORLD_FRAME = shapes.WORLD
VARS_SCHEMA = "simecs/msg/Sample"

META_RUN = "simecs.run"
META_PARAMS = "simecs.params"
META_SESSION = "simecs.session"
META_END = "simecs.end"
META_RECOVERY = "simecs.recovery"
ATTACH_MODEL = "model.json"

#: Little-endian plain CDR encapsulation header.
CDR_HEADER = b"\x00\x01\x00\x00"
#: Uncompressed bytes per chunk: a crash loses at most one open chunk (and at most ~1 s: flush).
CHUNK_SIZE = 512 * 1024
FLUSH_S = 1.0

LOG_DEBUG, LOG_INFO, LOG_WARNING, LOG_ERROR = 1, 2, 3, 4

#: Foxglove schema name -> vendored file (nodes/schemas, MIT, see LICENSE-foxglove).
FOXGLOVE_SCHEMAS = {
    "foxglove.FrameTransforms": "FrameTransforms.json",
    "foxglove.JointStates": "JointStates.json",
    "foxglove.SceneUpdate": "SceneUpdate.json",
    "foxglove.Log": "Log.json",
}


class FormatError(ValueError):
    """Data does not fit the recording format; the message names what and where."""


@functools.cache
def foxglove_schema(name: str) -> bytes:
    """The vendored JSON Schema of a Foxglove message type, as stored in every file."""
    try:
        return (SCHEMA_DIR / FOXGLOVE_SCHEMAS[name]).read_bytes()
    except KeyError:
        raise FormatError(f"no vendored schema for {name!r}") from None


def split_ns(ns: int) -> tuple[int, int]:
    ns = max(int(ns), 0)
    return ns // 1_000_000_000, ns % 1_000_000_000


def stamp(ns: int) -> dict[str, int]:
    sec, nsec = split_ns(ns)
    return {"sec": sec, "nsec": nsec}


def _json_key(text: str) -> str:
    """A JSON string literal safe inside a %-template."""
    return json.dumps(text).replace("%", "%%")


# -- /vars: the columns as a nested ROS 2 message --------------------------------------------------
_FIELD_BAD = re.compile(r"[^a-z0-9_]+")


def _field_name(text: str, taken: set[str]) -> str:
    """A ROS 2 field name (lowercase, digits, single underscores, starting with a letter)."""
    name = _FIELD_BAD.sub("_", text.lower())
    name = re.sub(r"_+", "_", name).strip("_") or "x"
    if not name[0].isalpha():
        name = "f" + name
    base, k = name, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def _type_name(path: Sequence[str], taken: set[str]) -> str:
    name = "Sample" + "".join(p[:1].upper() + p[1:] for p in re.split(r"[^A-Za-z0-9]+", "_".join(path)) if p)
    base, k = name, 2
    while name in taken:
        name, k = f"{base}{k}", k + 1
    taken.add(name)
    return name


@dataclass
class VarsCodec:
    """Columns <-> `/vars` messages. `order[k]` is the column index of the k-th value in a message."""

    columns: list[str]
    order: np.ndarray
    fields: list[str]  # message path of each value, in message order, e.g. "joint1.q"
    schema: str  # ros2msg text of simecs/msg/Sample and its nested types

    def encode(self, rows: np.ndarray) -> list[bytes]:
        """One CDR payload per row."""
        block = np.ascontiguousarray(rows[:, self.order], dtype="<f8")
        return [CDR_HEADER + row.tobytes() for row in block]

    def records(
        self, rows: np.ndarray, channel_id: int, sequence: int, log_ns: np.ndarray, publish_ns: int
    ) -> Any:
        """Complete MCAP Message records of every row, built in one numpy pass (packed, unaligned):
        opcode, record length, channel, sequence, log time, publish time, CDR header, values."""
        n = len(self.order)
        dtype = np.dtype(
            [("op", "u1"), ("len", "<u8"), ("ch", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")]
            + [("cdr", "<u4"), ("v", "<f8", (n,))]
        )
        rec = np.empty(rows.shape[0], dtype)
        rec["op"] = 0x05
        rec["len"] = 2 + 4 + 8 + 8 + len(CDR_HEADER) + 8 * n
        rec["ch"] = channel_id
        rec["seq"] = sequence
        rec["log"] = log_ns
        rec["pub"] = publish_ns
        rec["cdr"] = int.from_bytes(CDR_HEADER, "little")
        rec["v"] = rows[:, self.order]
        return rec

    def decode_into(self, payload: bytes, out: np.ndarray) -> None:
        """Write one message's values into `out` (a row in column order)."""
        expected = len(CDR_HEADER) + 8 * len(self.order)
        if len(payload) != expected or payload[:4] != CDR_HEADER:
            raise FormatError(f"{TOPIC_VARS} message of {len(payload)} bytes, expected {expected}")
        out[self.order] = np.frombuffer(payload, dtype="<f8", offset=4)


def build_vars_codec(columns: Sequence[str], units: Sequence[str] = ()) -> VarsCodec:
    """Group dotted column names into nested messages (`joint1.q` -> field q of field joint1)."""
    if not columns:
        raise FormatError("a run needs at least one column")
    if len(set(columns)) != len(columns):
        dup = next(c for c in columns if list(columns).count(c) > 1)
        raise FormatError(f"column {dup!r} appears twice in the layout")
    # tree: name -> column index (leaf) or dict (group); a name both leaf and group stays flat.
    tree: dict[str, Any] = {}
    for idx, col in enumerate(columns):
        parts = col.split(".")
        node = tree
        ok = all(parts)
        for p in parts[:-1]:
            child = node.get(p) if ok else None
            if child is None and ok:
                child = node.setdefault(p, {})
            if not isinstance(child, dict):
                ok = False
                break
            node = child
        if ok and parts[-1] not in node:
            node[parts[-1]] = idx
        else:
            tree[f"\0{col}"] = idx  # flat fallback, named from the whole column
    order: list[int] = []
    fields: list[str] = []
    types_taken: set[str] = set()
    sections: list[str] = []

    def emit(node: dict[str, Any], path: list[str], field_path: list[str]) -> str:
        lines = []
        taken: set[str] = set()
        for key, val in node.items():
            name = _field_name(key.lstrip("\0"), taken)
            if isinstance(val, dict):
                tname = _type_name([*path, key], types_taken)
                body = emit(val, [*path, key], [*field_path, name])
                sections.append(f"MSG: simecs/{tname}\n{body}")
                lines.append(f"simecs/{tname} {name}")
            else:
                order.append(val)
                fields.append(".".join([*field_path, name]))
                lines.append(f"float64 {name}")
        return "\n".join(lines) + "\n"

    top = emit(tree, [], [])
    sep = "=" * 80 + "\n"
    schema = top + "".join(sep + s for s in sections)
    return VarsCodec(list(columns), np.array(order, dtype=np.int64), fields, schema)


# -- /tf and /joint_states: Foxglove JSON from %-templates (json.dumps is ~10x slower) ---------------
#: Foxglove's order of a pose: translation x, y, z, then the quaternion x, y, z, w.
FOXGLOVE_POSE = ("x", "y", "z", "qx", "qy", "qz", "qw")
_NUM = "%.9g"  # 9 significant digits: nanometres at a metre, for display only (/vars is exact)
_TS = "\x00TS\x00"


class PoseEncoder:
    """`pose.<frame>.<x,y,z,qw,qx,qy,qz>` columns -> foxglove.FrameTransforms (parent: world)."""

    def __init__(self, names: Sequence[str]) -> None:
        index = {c: i for i, c in enumerate(names)}
        self.frames = columns.posed_frames(names)
        idx = [index[columns.pose_column(frame, f)] for frame in self.frames for f in FOXGLOVE_POSE]
        self.idx = np.array(idx, dtype=np.int64)
        parts = []
        for name in self.frames:
            parts.append(
                '{"timestamp":' + _TS + ',"parent_frame_id":' + _json_key(WORLD_FRAME) + ',"child_frame_id":'
                f"{_json_key(name)}"
                f',"translation":{{"x":{_NUM},"y":{_NUM},"z":{_NUM}}}'
                f',"rotation":{{"x":{_NUM},"y":{_NUM},"z":{_NUM},"w":{_NUM}}}}}'
            )
        self.template = '{"transforms":[' + ",".join(parts) + "]}"

    def __bool__(self) -> bool:
        return bool(self.frames)

    def encode(self, values: list[float], ts: str) -> bytes:
        return (self.template.replace(_TS, ts) % tuple(values)).encode()


class JointEncoder:
    """`<joint>.q`, `.qd` and the joint torque column -> foxglove.JointStates."""

    def __init__(self, names: Sequence[str]) -> None:
        index = {c: i for i, c in enumerate(names)}
        self.joints: list[str] = []
        idx: list[int] = []
        parts = []
        for joint, position, velocity, effort in columns.joint_state_columns(names):
            self.joints.append(joint)
            idx += [index[position], index[velocity]]
            entry = f'{{"name":{_json_key(joint)},"position":{_NUM},"velocity":{_NUM}'
            if effort is not None:
                idx.append(index[effort])
                entry += f',"effort":{_NUM}'
            parts.append(entry + "}")
        self.idx = np.array(idx, dtype=np.int64)
        self.template = '{"timestamp":' + _TS + ',"joints":[' + ",".join(parts) + "]}"

    def __bool__(self) -> bool:
        return bool(self.joints)

    def encode(self, values: list[float], ts: str) -> bytes:
        return (self.template.replace(_TS, ts) % tuple(values)).encode()


def ts_json(ns: int) -> str:
    sec, nsec = split_ns(ns)
    return f'{{"sec":{sec},"nsec":{nsec}}}'


def ros2_field_paths(codec_: VarsCodec) -> dict[str, str]:
    """Column name -> Foxglove message path under /vars (for docs and the viewer)."""
    return {
        codec_.columns[i]: f"{TOPIC_VARS}.{f}"
        for i, f in zip(codec_.order.tolist(), codec_.fields, strict=True)
    }
