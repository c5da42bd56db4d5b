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
- `/scene` (`foxglove.SceneUpdate`): the arm's solid shapes as frame-locked entities, once per run.
- `/log` (`foxglove.Log`): lifecycle events, dropped data, recovery notes.
Metadata records, all written when the file opens except the last two: `simecs.run` (layout with the
run's context, ids, format version), `simecs.params` (the values the run used), `simecs.session` (user,
initial pose, command, settings, replayed recording), `simecs.end` (how the file was closed),
`simecs.recovery` (set when a torn file was repaired). Attachment `model.json`: the model description.
"""

from __future__ import annotations

import base64
import bisect
import functools
import json
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh import columns, scene_state, shapes
from simecs.mesh.environment import Obstacle
from simecs.mesh.model import ModelDescription

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


# -- /scene: the model's solids as frame-locked entities -------------------------------------------
def _color(rgb: Sequence[int]) -> dict[str, float]:
    r, g, b = (list(rgb) + [200, 200, 200])[:3]
    return {"r": r / 255.0, "g": g / 255.0, "b": b / 255.0, "a": 1.0}


def _pose(center: Iterable[float], wxyz: Iterable[float]) -> dict[str, Any]:
    x, y, z = (float(v) for v in center)
    qw, qx, qy, qz = (float(v) for v in wxyz)
    return {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def scene_primitive(solid: shapes.Solid, meshes: Mapping[str, bytes]) -> tuple[str, dict[str, Any]] | None:
    """(entity list name, Foxglove primitive) of one solid, from the geometry the viewer draws too;
    None for a mesh whose GLB is not in `meshes`.

    Foxglove has no pipe: a pipe is drawn as a cylinder of its outer radius (the same outside). A mesh
    is a model primitive with its GLB embedded (its own colours, not overridden)."""
    g = solid.geometry
    color = _color(solid.shape.color)
    pose = _pose(g.position, g.wxyz)
    if g.kind == "mesh":
        data = meshes.get(g.mesh)
        if data is None:
            return None
        sx, sy, sz = g.dimensions
        return "models", {
            "pose": pose,
            "scale": {"x": sx, "y": sy, "z": sz},
            "color": color,
            "override_color": False,
            "url": "",
            "media_type": "model/gltf-binary",
            "data": base64.b64encode(data).decode("ascii"),
        }
    if g.kind in ("cylinder", "pipe"):
        d = 2 * g.radius
        size = {"x": d, "y": d, "z": g.length}
        return "cylinders", {
            "pose": pose,
            "size": size,
            "bottom_scale": 1.0,
            "top_scale": 1.0,
            "color": color,
        }
    if g.kind == "box":
        size = {"x": g.dimensions[0], "y": g.dimensions[1], "z": g.dimensions[2]}
        return "cubes", {"pose": pose, "size": size, "color": color}
    if g.kind == "sphere":
        d = 2 * g.radius
        return "spheres", {"pose": pose, "size": {"x": d, "y": d, "z": d}, "color": color}
    raise FormatError(f"shape kind {g.kind!r} has no Foxglove primitive")


def scene_update(
    model: ModelDescription,
    values: Mapping[str, float],
    stamp_ns: int,
    meshes: Mapping[str, bytes] | None = None,
    obstacles: Sequence[Obstacle] = (),
) -> dict[str, Any]:
    """foxglove.SceneUpdate: one frame-locked entity per link (frame = link name), plus the world's
    solids (environment and base) in one entity and the run's obstacles in another, all shaped by the
    run's parameter values; a mesh shape carries the GLB of `meshes` (left out when it is missing)."""
    entities: dict[str, dict[str, Any]] = {}
    drawn_solids = [(s, "") for s in shapes.solids(model, values)]
    drawn_solids += [(s, OBSTACLES_ENTITY) for s in shapes.obstacle_solids(obstacles)]
    for solid, group in drawn_solids:
        if not solid.geometry.visible:
            continue
        world = solid.frame == shapes.WORLD
        eid = group or ("environment" if world else solid.frame)
        if eid not in entities:
            entities[eid] = _entity(eid, WORLD_FRAME if world else solid.frame, stamp_ns, model.id)
        drawn = scene_primitive(solid, meshes or {})
        if drawn is not None:
            entities[eid][drawn[0]].append(drawn[1])
    return {"deletions": [], "entities": list(entities.values())}


def _entity(eid: str, frame: str, stamp_ns: int, model_id: str) -> dict[str, Any]:
    """An empty foxglove.SceneEntity; frame-locked unless its frame is the world."""
    return {
        "timestamp": stamp(stamp_ns),
        "frame_id": frame,
        "id": eid,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": frame != WORLD_FRAME,
        "metadata": [{"key": "model", "value": model_id}],
        "arrows": [],
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [],
    }


#: /scene entities of the world around the arm: the obstacles where they are, the one the tool holds
#: (locked to the `grasped` frame of /tf), the contact forces' arrows.
OBSTACLES_ENTITY, HELD_ENTITY, CONTACTS_ENTITY = "obstacles", "held", "contacts"
CONTACT_COLOR = {"r": 0.86, "g": 0.12, "b": 0.12, "a": 1.0}


class WorldScene:
    """The /scene updates that follow a run's rows (mesh/scene_state.py): obstacles moved by a grasp
    or a release, and the contact arrows at the /tf rate. The first /scene (scene_update) drew the
    obstacles where the run's list puts them.

    Rows come in time order, except the ones that fill a gap after the run (`backfill`): those start
    from what the tool held at their own time, so a late gap never redraws an old grasp as the last
    word (readers order /scene by log time)."""

    def __init__(self, names: Sequence[str], obstacles: Sequence[Obstacle], model_id: str) -> None:
        self.world = scene_state.WorldColumns(names)
        self.obstacles = list(obstacles)
        self.model_id = model_id
        # (log time, (object, held), moved obstacles) from each grasp change on, in time order
        self._timeline: list[tuple[int, tuple[int, int], dict[int, np.ndarray]]] = [(-1, (0, 0), {})]
        self._arrows = 0  # arrows drawn by the last contact update in time order

    def grasp_updates(
        self, rows: np.ndarray, log_ns: Sequence[int], backfill: bool = False
    ) -> list[tuple[int, dict[str, Any]]]:
        """(log time, SceneUpdate) at each row where what the tool holds changes."""
        out: list[tuple[int, dict[str, Any]]] = []
        if not self.obstacles or rows.shape[0] == 0:
            return out
        before = self._at(int(log_ns[0])) if backfill else len(self._timeline) - 1
        _, state_before, moved_before = self._timeline[before]
        moved = dict(moved_before)
        for k, state in self.world.grasp_changes(rows, state_before):
            ns = int(log_ns[k])
            self.world.moved(rows[k : k + 1], moved)
            out.append((ns, self._obstacles_update(state, moved, ns)))
            bisect.insort(self._timeline, (ns, state, dict(moved)), key=lambda entry: entry[0])
        return out

    def _at(self, ns: int) -> int:
        """The index of the timeline's entry in force just before log time `ns`."""
        return bisect.bisect_left(self._timeline, ns, key=lambda entry: entry[0]) - 1

    def _obstacles_update(
        self, state: tuple[int, int], moved: dict[int, np.ndarray], ns: int
    ) -> dict[str, Any]:
        number, held = state
        here = scene_state.placed(self.obstacles, moved)
        carried = number - 1 if held else -1
        world = _entity(OBSTACLES_ENTITY, WORLD_FRAME, ns, self.model_id)
        _draw_obstacles(world, [ob for k, ob in enumerate(here) if k != carried])
        update: dict[str, Any] = {"deletions": [], "entities": [world]}
        if 0 <= carried < len(here):
            entity = _entity(HELD_ENTITY, columns.GRASPED_FRAME, ns, self.model_id)
            _draw_obstacles(entity, [scene_state.at_pose(here[carried], np.zeros(3), np.eye(3))])
            update["entities"].append(entity)
        else:
            update["deletions"].append({"timestamp": stamp(ns), "type": 0, "id": HELD_ENTITY})
        return update

    def contacts_updates(
        self, rows: np.ndarray, log_ns: Sequence[int], backfill: bool = False
    ) -> list[tuple[int, dict[str, Any]]]:
        """(log time, SceneUpdate) of the contact arrows at each of `rows` (the /tf samples), where they
        change from nothing to nothing are left out. A backfilled piece clears its arrows at its end:
        the live rows after the gap drew theirs, or none, on their own."""
        out: list[tuple[int, dict[str, Any]]] = []
        drawn = 0 if backfill else self._arrows
        for row, ns in zip(rows, log_ns, strict=True):
            arrows = self.world.arrows(row)
            if arrows.shape[0] == 0 and drawn == 0:
                continue
            drawn = arrows.shape[0]
            out.append((int(ns), self._contacts_entity(arrows, int(ns))))
        if backfill and drawn and len(log_ns):
            out.append((int(log_ns[-1]) + 1, self._contacts_entity(np.zeros((0, 2, 3)), int(log_ns[-1]) + 1)))
        elif not backfill:
            self._arrows = drawn
        return out

    def _contacts_entity(self, arrows: np.ndarray, ns: int) -> dict[str, Any]:
        entity = _entity(CONTACTS_ENTITY, WORLD_FRAME, ns, self.model_id)
        for start, end in arrows:
            entity["arrows"].append(_arrow(start, end))
        return {"deletions": [], "entities": [entity]}


def _draw_obstacles(entity: dict[str, Any], obstacles: Sequence[Obstacle]) -> None:
    """The obstacles' primitives into `entity` (the geometry scene_update draws them with)."""
    for solid in shapes.obstacle_solids(obstacles):
        drawn = scene_primitive(solid, {})
        if drawn is not None and solid.geometry.visible:
            entity[drawn[0]].append(drawn[1])


def _arrow(start: np.ndarray, end: np.ndarray) -> dict[str, Any]:
    """A foxglove.ArrowPrimitive from start to end (it points along its pose's +x)."""
    d = end - start
    length = float(np.linalg.norm(d))
    x = d / length if length > 0 else np.array([1.0, 0.0, 0.0])
    w = 1.0 + float(x[0])  # the rotation taking +x onto x: half-way quaternion (w, x cross v)
    q = np.array([w, 0.0, -float(x[2]), float(x[1])]) if w > 1e-9 else np.array([0.0, 0.0, 0.0, 1.0])
    q /= np.linalg.norm(q)
    head = min(0.025, 0.4 * length)
    return {
        "pose": _pose(start, q),
        "shaft_length": max(length - head, 0.0),
        "shaft_diameter": 0.008,
        "head_length": head,
        "head_diameter": 0.024,
        "color": CONTACT_COLOR,
    }


def ros2_field_paths(codec_: VarsCodec) -> dict[str, str]:
    """Column name -> Foxglove message path under /vars (for docs and the viewer)."""
    return {
        codec_.columns[i]: f"{TOPIC_VARS}.{f}"
        for i, f in zip(codec_.order.tolist(), codec_.fields, strict=True)
    }
