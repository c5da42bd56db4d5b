"""A seeded, bounded fuzz of every key of the protocol, sent by a peer without the service key.

What any client of an open mesh can send (issue 14): hostile JSON on every session command and on the
other queryables (wrong types, missing and extra fields, numbers beyond float64, NaN, lone surrogates,
deep nesting, very long texts, bytes that are not UTF-8, truncated or binary payloads, valid-looking
commands with values out of range), forged and garbage samples on every key only service nodes write,
and liveliness tokens of runs and nodes that are not its own. The service must refuse each with an
`Error` (never `internal`: that is a bug of the node that answered), keep every node up, and leave every
other session's state, results and recordings as they were.

The messages are a function of the seed and the targets alone (`messages()`; only the forgeries of
testing/forgery.py stamp frames with the clock), so a problem found once is found again; `fuzz()` sends
them one by one and counts the answers by error code. Used by tests/test_fuzz.py; a benchmark can call
`fuzz()` on any mesh it can reach.
"""

from __future__ import annotations

import io
import json
import random
import re
import struct
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import zenoh
from mcap.reader import make_reader
from mcap.writer import Writer
from simecs.mesh import codec, frames, keys
from simecs.mesh import messages as m
from simecs.mesh.model import ModelDescription
from simecs.testing import forgery

QUERY_TIMEOUT_S = 5.0
#: Characters of a request or reply kept in a report: enough to reproduce, not to flood a log.
EXCERPT = 240
#: Session commands that change nothing: the only ones that decode which the fuzz sends to a victim.
READ_ONLY = frozenset({"get_session", "list_param_sets"})
#: Runs and sessions the fuzz may start in the attacker's name: every one holds a worker or a slot.
RUN_BUDGET = 8
CREATE_BUDGET = 4
UPLOAD_BUDGET = 2
#: Names the attacker uploads recordings under (and replays them from): few, so names collide too.
UPLOAD_NAMES = tuple(f"fzu{i}" for i in range(24))
#: Outstanding fake liveliness tokens at most (all are undeclared before `fuzz()` returns).
MAX_TOKENS = 6


@dataclass(frozen=True)
class Victim:
    """A session of another user that the fuzz aims at: nothing it sends may change it."""

    user: str
    session: str
    run_id: str = "r1"
    run_index: int = 1


@dataclass(frozen=True)
class FuzzTargets:
    """Who the attacker is and what it aims at.

    `attacker_sessions` are the attacker's own sessions (every command goes there); the victim's
    session and its run `victim_run_id` (frames of `width` columns) get forgeries and refused commands
    only; `bystanders` are more victims (e.g. one whose runs go on during the fuzz). Run ids are
    predictable (r1, r2, ...): forgeries and tokens aim at each victim's run and its next three too.
    `simulators` and
    `nodes` (role, node id) name the live service nodes, for their run and status keys; `mcap` is a
    valid recording, mutated for uploads (none: uploads of garbage only)."""

    attacker_user: str
    attacker_sessions: tuple[str, ...]
    victim_user: str
    victim_session: str
    victim_run_id: str
    victim_run_index: int
    width: int
    model_id: str = "spider"
    simulators: tuple[str, ...] = ()
    nodes: tuple[tuple[str, str], ...] = ()
    bystanders: tuple[Victim, ...] = ()
    mcap: bytes = b""

    @property
    def victim(self) -> Victim:
        return Victim(self.victim_user, self.victim_session, self.victim_run_id, self.victim_run_index)

    @property
    def victims(self) -> tuple[Victim, ...]:
        return (self.victim, *self.bystanders)


@dataclass
class FuzzReport:
    """What was sent and how the service answered. A reply is counted under its error code, `ok`,
    `timeout` (no answer within QUERY_TIMEOUT_S), or `malformed` (an error reply that is no `Error`);
    a query nobody answered counts as `unanswered`."""

    sent: int = 0
    replies_by_code: dict[str, int] = field(default_factory=dict)
    #: (key, request excerpt, reply excerpt) of every `internal` answer.
    internal: list[tuple[str, str, str]] = field(default_factory=list)
    #: The same for `malformed` and `timeout` answers, and for queries answered more than once.
    malformed: list[tuple[str, str, str]] = field(default_factory=list)
    timeouts: list[tuple[str, str, str]] = field(default_factory=list)
    multiple: list[tuple[str, str, str]] = field(default_factory=list)
    #: Requests that the local zenoh session refused to send (counted, not sent).
    unsendable: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    #: Replies by code for each kind of request ("cmd mutated set_params": {"bad_request": 40, ...}).
    by_request: dict[str, dict[str, int]] = field(default_factory=dict)
    elapsed_s: float = 0.0
    out_of_time: bool = False
    created_sessions: list[str] = field(default_factory=list)
    #: How the runs started in the attacker's own sessions ended: "<session> <run>: <phase> <reason>".
    own_runs: list[str] = field(default_factory=list)

    @property
    def internal_replies(self) -> int:
        return self.replies_by_code.get("internal", 0)

    def summary(self) -> str:
        codes = ", ".join(f"{k} {v}" for k, v in sorted(self.replies_by_code.items()))
        kinds = ", ".join(f"{k} {v}" for k, v in sorted(self.by_kind.items()))
        return (
            f"sent {self.sent} messages in {self.elapsed_s:.1f} s ({kinds}); replies: {codes}; "
            f"unsendable {self.unsendable}{'; OUT OF TIME' if self.out_of_time else ''}"
        )


@dataclass(frozen=True)
class Message:
    """One thing the attacker does: a query, a put, or declaring/undeclaring a liveliness token."""

    kind: str  # cmd | query | put | token
    key: str  # a key expression; a query's may carry `?parameters`
    payload: bytes | None = None
    attachment: bytes | None = None
    what: str = ""  # how it was made, for reports


# -- JSON texts nothing in Python's json module would write -------------------------------------------
class Raw(str):
    """A JSON text put in verbatim: numbers beyond float64, NaN, deep nesting..."""


def to_json(value: Any) -> bytes:
    """`value` as JSON text; `Raw` parts verbatim, strings with lone surrogates as `\\ud800` escapes."""
    return _text(value).encode("utf-8")


def _text(value: Any) -> str:
    if isinstance(value, Raw):
        return str(value)
    if isinstance(value, dict):
        return "{" + ",".join(f"{_text(str(k))}:{_text(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ",".join(_text(v) for v in value) + "]"
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)  # json.dumps refuses ints of more than 4300 digits
    return json.dumps(value)  # ensure_ascii: a lone surrogate becomes an escape, never invalid UTF-8


# -- what the model offers (for valid-looking values out of range) ----------------------------------
@dataclass(frozen=True)
class ModelFacts:
    model_id: str
    params: tuple[tuple[str, float, float, bool], ...]  # name, min, max, integer
    joints: tuple[tuple[float, float], ...]
    variables: tuple[str, ...]
    command_levels: tuple[str, ...]
    pages: tuple[str, ...]

    @classmethod
    def of(cls, desc: ModelDescription) -> ModelFacts:
        return cls(
            desc.id,
            tuple((p.name, p.min, p.max, p.integer) for p in desc.parameters),
            tuple((link.joint_min, link.joint_max) for link in desc.links),
            tuple(v.name for v in desc.variables),
            tuple(desc.command_levels),
            tuple(p.id for p in desc.docs),
        )

    @classmethod
    def fallback(cls, model_id: str) -> ModelFacts:
        """When the library does not answer: enough to build every command."""
        joints = ((-3.14, 3.14),) * 7
        return cls(model_id, (("joint1.ctrl.kp_pos", 0.0, 1e4, False),), joints, ("joint1.q",), (), ())


def model_facts(attacker: zenoh.Session, model_id: str) -> ModelFacts:
    """The model's description, asked as any client would."""
    try:
        for reply in attacker.get(keys.model(model_id), timeout=QUERY_TIMEOUT_S):
            if reply.ok is not None:
                data = codec.loads(m.Ok, reply.ok.payload.to_bytes()).data
                return ModelFacts.of(codec.from_obj(ModelDescription, data))
    except Exception:
        pass
    return ModelFacts.fallback(model_id)


# -- hostile values ---------------------------------------------------------------------------------
_HUGE_DIGITS = "1" + "0" * 5000
_NUMBERS = [
    Raw("NaN"),
    Raw("Infinity"),
    Raw("-Infinity"),
    Raw("1e999"),
    Raw("-1e999"),
    Raw(_HUGE_DIGITS),
    Raw("-" + "9" * 5000),
    Raw("1" + "0" * 400 + ".5"),
    Raw("0." + "0" * 5000 + "1"),
    Raw("1e-400"),
    Raw("-0"),
    Raw("1E+309"),
    Raw("0x10"),
    Raw("01"),
    Raw(".5"),
    Raw("1."),
    Raw("+1"),
    Raw("1e"),
    2**63,
    -(2**63) - 1,
    2**64,
    10**30,
    -1,
    0,
    1.5,
    -1e308,
]
_STRINGS = [
    "\ud800",
    "a\udfffb",
    "\udc00\ud800",
    "",
    " ",
    "\u0000",
    "x" * 65,
    "../../../../etc/passwd",
    "a/b",
    "*",
    "**",
    "$*",
    "@x",
    "-lead",
    "_lead",
    ".",
    "..",
    "\U0001f600",
    "é" * 64,
    "op",
    "null",
    "r1",
    "\\",
    '"',
    "\n",
]


def _many(item: str, n: int) -> Raw:
    return Raw("[" + ",".join([item] * n) + "]")


# Built once: lists and maps past every bound of §5 (64 joints, 1000 nodes, 100000 entries).
_BIG = [_many("0", n) for n in (65, 1001, 100_001)]
_BIG_MAPS = [Raw("{" + ",".join(f'"p{i}":1.0' for i in range(n)) + "}") for n in (65, 100_001)]
_BIG_FLOATS = _many("1.0", 100_001)
_MANY_LISTS = _many("[]", 1001)


def _deep_list(n: int) -> Raw:
    return Raw("[" * n + "]" * n)


def _deep_object(n: int) -> Raw:
    return Raw('{"a":' * n + "1" + "}" * n)


class _McapTemplate:
    """A valid recording taken apart, to be written again with hostile content and correct CRCs: what
    an upload must survive beyond torn and bit-flipped bytes."""

    def __init__(self, data: bytes) -> None:
        reader = make_reader(io.BytesIO(data))
        summary = reader.get_summary()
        if summary is None:
            raise ValueError("a recording without a summary")
        header = reader.get_header()
        self.profile, self.library = header.profile, header.library
        self.schemas = {i: (sc.name, sc.encoding, sc.data) for i, sc in summary.schemas.items()}
        self.channels = {
            i: (ch.topic, ch.message_encoding, ch.schema_id, dict(ch.metadata))
            for i, ch in summary.channels.items()
        }
        self.messages = [
            (ch.id, msg.log_time, msg.data, msg.publish_time, msg.sequence)
            for _sc, ch, msg in reader.iter_messages(log_time_order=False)
        ]
        self.metadata = {md.name: dict(md.metadata) for md in reader.iter_metadata()}
        self.attachments = [
            (a.create_time, a.log_time, a.name, a.media_type, a.data) for a in reader.iter_attachments()
        ]

    def write(
        self,
        metadata: dict[str, dict[str, str]],
        channel_metadata: dict[str, dict[str, str]] | None = None,
        edits: dict[str, Callable[[int, bytes], bytes | None]] | None = None,
    ) -> bytes:
        """The recording with `metadata`, more metadata on the channels of some topics, and the messages
        of some topics through `edits[topic](i, data)` (None drops the message)."""
        channel_metadata, edits = channel_metadata or {}, edits or {}
        out = io.BytesIO()
        writer = Writer(out)
        writer.start(self.profile, self.library)
        schema_ids = {i: writer.register_schema(*sc) for i, sc in self.schemas.items()}
        channel_ids = {}
        for i, (topic, encoding, schema, meta) in self.channels.items():
            meta = {**meta, **channel_metadata.get(topic, {})}
            channel_ids[i] = writer.register_channel(topic, encoding, schema_ids.get(schema, 0), meta)
        counts: Counter[int] = Counter()
        for channel, log_time, data, publish_time, seq in self.messages:
            edit = edits.get(self.channels[channel][0])
            if edit is not None:
                edited = edit(counts[channel], data)
                counts[channel] += 1
                if edited is None:
                    continue
                data = edited
            writer.add_message(channel_ids[channel], log_time, data, publish_time, seq)
        for attachment in self.attachments:
            writer.add_attachment(*attachment)
        for name, meta in metadata.items():
            writer.add_metadata(name, meta)
        writer.finish()
        return out.getvalue()


_DEEP = [_deep_list(64), _deep_list(2000), _deep_list(100_000), _deep_object(5000)]
_DEEP_BYTES = _deep_list(200_000).encode()


#: Key chunks zenoh accepts that are no name or session id (some are names, but not session ids).
_WEIRD_CHUNKS = (
    "a b",
    "ü",
    "x" * 65,
    "-x",
    "_x",
    ".x",
    "a%2Fb",
    "a:b",
    "'",
    '"',
    "<x>",
    "\\",
    "A" * 21,
    "A" * 23,
    "A" * 21 + "=",
    "\u200b",
    "nul\u0000",
    "\U0001f600",
    "x" * 300,
    "@x",
)


def _next_runs(run_id: str, more: int = 3) -> list[str]:
    """`run_id` and the ids the next runs of its session will get."""
    try:
        n = int(run_id[1:])
    except ValueError:
        return [run_id]
    return [f"r{i}" for i in range(n, n + more + 1)]


class _Generator:
    """Makes the messages of one seed; every choice comes from `self.rng`."""

    def __init__(self, targets: FuzzTargets, facts: ModelFacts, seed: int, count: int) -> None:
        self.t = targets
        self.facts = facts
        self.rng = random.Random(seed)
        self.count = count
        self.runs_left = RUN_BUDGET
        self.creates_left = CREATE_BUDGET
        self.uploads_left = UPLOAD_BUDGET
        self.index = 0
        self.tokens: list[str] = []
        self.pending: list[Message] = []
        own = targets.attacker_sessions
        self.closable = own[-1] if len(own) > 1 else ""
        self.forged: list[tuple[str, bytes]] = []
        for v in targets.victims:
            for i, run_id in enumerate(_next_runs(v.run_id)):
                self.forged += forgery.forged_messages(
                    v.user, v.session, run_id, v.run_index + i, targets.width
                )
        for sid in own:
            self.forged += forgery.forged_messages(targets.attacker_user, sid, "r1", 1, targets.width)
        self.mcap: _McapTemplate | None = None
        if targets.mcap:
            try:
                self.mcap = _McapTemplate(targets.mcap)
            except Exception:  # not a recording this fuzz can take apart: bytes-level uploads only
                self.mcap = None

    # -- small choices ----------------------------------------------------------------------------
    def pick(self, seq: Any) -> Any:
        return seq[self.rng.randrange(len(seq))]

    def chance(self, p: float) -> bool:
        return self.rng.random() < p

    def hostile(self, depth: int = 0) -> Any:
        r = self.rng.random()
        if r < 0.35:
            return self.pick(_NUMBERS)
        if r < 0.6:
            return self.pick(_STRINGS)
        if r < 0.7:
            return "x" * self.pick([1000, 100_001, 300_000])
        if r < 0.8:
            return self.pick(_DEEP)
        if r < 0.85:
            return self.pick(_BIG)
        if r < 0.9 and depth < 2:
            return {self.pick(_STRINGS): self.hostile(depth + 1)}
        if r < 0.95 and depth < 2:
            return [self.hostile(depth + 1) for _ in range(self.rng.randrange(1, 4))]
        return self.pick([True, False, None, [], {}])

    def weird_chunk(self) -> str:
        return str(self.pick(_WEIRD_CHUNKS))

    def bad_name(self) -> str:
        """A chunk that is no name: refused whatever the payload."""
        return str(self.pick([c for c in _WEIRD_CHUNKS if not keys.NAME_RE.match(c)]))

    def random_sid(self) -> str:
        alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-"
        return "Z" + "".join(self.pick(alphabet) for _ in range(21))

    # -- commands ---------------------------------------------------------------------------------
    def joints(self) -> list[float]:
        return [round(self.rng.uniform(lo, hi) * 0.5, 3) for lo, hi in self.facts.joints]

    def settings(self) -> dict[str, Any]:
        return {
            "stop_time": self.pick([0.05, 0.1, 0.2]),
            "output_interval": 0.01,
            "step": 0.0,
            "pacing": "fast",
            "factor": 1.0,
            "live_rate_hz": 20.0,
            "live_vars": list(self.facts.variables[:2]),
        }

    def valid_command(self, op: str) -> dict[str, Any]:
        """A well-formed command of `op` (what a correct client sends), as a JSON object."""
        facts, rng = self.facts, self.rng
        body: dict[str, Any] = {"op": op, "v": 1}
        if op == "set_params" and facts.params:
            chosen = [self.pick(facts.params) for _ in range(rng.randrange(1, 4))]
            body["values"] = {
                n: (round(rng.uniform(lo, hi)) if integer else rng.uniform(lo, hi))
                for n, lo, hi, integer in chosen
            }
        elif op == "reset_params":
            body["names"] = [self.pick(facts.params)[0]] if facts.params and self.chance(0.5) else []
        elif op == "set_initial":
            body["joints"] = self.joints()
        elif op == "set_command":
            nodes = [
                {"q": self.joints(), "speed_pct": rng.uniform(1, 100), "acc_pct": rng.uniform(1, 100)}
                for _ in range(rng.randrange(1, 4))
            ]
            body["command"] = {"kind": "joint_path", "nodes": nodes}
        elif op == "set_settings":
            body["settings"] = self.settings()
        elif op == "replay":
            name = self.pick(
                [*UPLOAD_NAMES[:8], keys.recording_name(self.t.victim_session, self.t.victim_run_id)]
            )
            body.update(recording=name, speed=self.pick([0, 1.0, 10.0]), paused=self.chance(0.3))
        elif op == "seek":
            body["time"] = rng.uniform(0, 2)
        elif op in ("save_param_set", "load_param_set", "delete_param_set"):
            body["name"] = self.pick(["fz1", "fz2", "default"])
        elif op == "create":
            body["model_id"] = facts.model_id
        return body

    def out_of_range(self, op: str) -> dict[str, Any] | None:
        """A command of `op` that decodes but that the service must refuse (bad value, unknown name,
        wrong level): safe to send to a victim, since any acceptance is a bug."""
        facts, rng = self.facts, self.rng
        body = self.valid_command(op)
        if op == "set_params" and facts.params:
            name, lo, hi, integer = self.pick(facts.params)
            bad = self.pick(
                [hi + max(1.0, abs(hi)), lo - max(1.0, abs(lo)), 1e308, -1e308]
                + ([lo + 0.5] if integer else [])
            )
            values = dict(body["values"])
            values[name] = bad
            if self.chance(0.3):
                values = {**body["values"], "no.such.param": 1.0}
            body["values"] = values
        elif op == "reset_params":
            body["names"] = [*body["names"], self.pick(["no.such.param", "joint99.q", "a"])]
        elif op == "set_initial":
            joints = self.joints()
            r = rng.random()
            if r < 0.3:
                joints = joints[:-1]
            elif r < 0.5:
                joints = [*joints, 0.0]
            elif r < 0.6:
                joints = []
            else:
                i = rng.randrange(len(joints))
                lo, hi = facts.joints[i]
                joints[i] = self.pick([hi + 0.01, lo - 0.01, 1e300, -1e300])
            body["joints"] = joints
        elif op == "set_command":
            r = rng.random()
            others = ("cartesian_path", "direct_input", "action", "task", "mission")
            unsupported = [level for level in others if level not in facts.command_levels]
            if r < 0.4 and unsupported:
                body["command"] = self.other_level(self.pick(unsupported))
            else:
                node = body["command"]["nodes"][0]
                if r < 0.7:
                    node["q"] = node["q"][:-1]
                else:
                    lo, hi = facts.joints[0]
                    node["q"][0] = self.pick([hi + 0.5, lo - 0.5])
        elif op == "set_settings":
            s = body["settings"]
            r = rng.random()
            if r < 0.35:
                s["output_interval"] = s["stop_time"] * 2
            elif r < 0.6:
                s["live_vars"] = ["no.such.variable"]
            elif r < 0.8:
                s["step"] = 1e-6
            else:
                s["stop_time"], s["output_interval"] = 3600.0, 1e-4  # too many samples
        elif op == "seek":
            pass  # a simulation cannot seek (unsupported), a finished session has no run (conflict)
        elif op in ("load_param_set", "delete_param_set"):
            body["name"] = f"fz-none-{rng.randrange(10**6)}"
        elif op == "replay":
            body["recording"] = self.pick([f"fz-none-{rng.randrange(10**6)}", "x" * 64])
        elif op == "create":
            body["model_id"] = self.pick(["no-such-model", "x" * 64, "spider2"])
        else:
            return None
        return body

    def other_level(self, level: str) -> dict[str, Any]:
        action: dict[str, Any] = {"kind": "action", "name": "reach", "args": {"a": 1.0}}
        task: dict[str, Any] = {"kind": "task", "name": "t", "actions": [action]}
        levels: dict[str, dict[str, Any]] = {
            "cartesian_path": {
                "kind": "cartesian_path",
                "nodes": [{"position": [0.5, 0.1, 0.2], "rpy": [0.0, 0.0, 0.0]}],
            },
            "direct_input": {"kind": "direct_input", "mode": "closed_loop", "signals": {"joint1": [[0, 1]]}},
            "action": action,
            "task": task,
            "mission": {"kind": "mission", "name": "m", "tasks": [task]},
        }
        return levels[level]

    def mutate_object(self, obj: Any) -> Any:
        """One structural change somewhere in a JSON object: a value swapped for a hostile one, a field
        dropped or added, the tag or version changed, a list or map grown past its bound."""
        paths: list[tuple[Any, Any]] = []  # (container, key or index)

        def walk(node: Any, depth: int) -> None:
            if depth > 5:
                return
            if isinstance(node, dict):
                for k in list(node):
                    paths.append((node, k))
                    walk(node[k], depth + 1)
            elif isinstance(node, list):
                for i in range(len(node)):
                    paths.append((node, i))
                    walk(node[i], depth + 1)

        walk(obj, 0)
        r = self.rng.random()
        if not paths or r < 0.08:
            return self.hostile()
        container, where = self.pick(paths)
        if r < 0.45:
            container[where] = self.hostile()
        elif r < 0.6 and isinstance(container, dict):
            del container[where]
        elif r < 0.72:
            dicts = [c for c, _ in paths if isinstance(c, dict)]
            if dicts:
                self.pick(dicts)[self.pick([*_STRINGS, "extra", "v", "type", "kind"])] = self.hostile()
        elif r < 0.8 and isinstance(obj, dict):
            obj[self.pick(["op", "v", "type", "kind"])] = self.pick(
                ["", "run", "set_params", "create", "nope", "error", 2, 0, -1, "1", 1.0, True, None]
                + ["x" * 100_001, "\U0001f600" * 100_001]
                + [Raw(_HUGE_DIGITS), Raw("NaN"), "\ud800", [], {}]
            )
        elif r < 0.88:
            big_map = _BIG_MAPS[1] if self.chance(0.1) else _BIG_MAPS[0]  # 1.3 MB: rarely
            container[where] = self.pick([_BIG_FLOATS, big_map, [self.joints()] * 3, _MANY_LISTS])
        else:
            container[where] = self.pick(_NUMBERS)
        return obj

    def mutate_text(self, text: bytes) -> bytes:
        """A change to the bytes of a JSON text: truncated, bytes that are not UTF-8, a flipped byte,
        trailing garbage, duplicate keys, a BOM, JSON5 syntax, a payload over the size limit."""
        rng = self.rng
        r = rng.random()
        cut = rng.randrange(len(text) + 1) if text else 0
        if r < 0.2:
            return text[:cut]
        if r < 0.4:
            bad = self.pick(
                [b"\xff", b"\xc0\xaf", b"\xed\xa0\x80", b"\xf8\x88\x80\x80\x80", b"\x00", b"\x80"]
            )
            quote = text.find(b'"', cut)
            at = quote + 1 if quote >= 0 else cut
            return text[:at] + bad + text[at:]
        if r < 0.5 and text:
            i = rng.randrange(len(text))
            return text[:i] + bytes([text[i] ^ (1 << rng.randrange(8))]) + text[i + 1 :]
        if r < 0.58:
            return text + self.pick([b"}", b" x", b"{}", b"\x00", b'{"op":"run","v":1}'])
        if r < 0.66 and text.startswith(b"{"):
            return b'{"op":"run","v":1,' + text[1:]  # a duplicate tag
        if r < 0.72:
            return b"\xef\xbb\xbf" + text
        if r < 0.8:
            return self.pick(
                [
                    text.replace(b'"', b"'"),
                    text[:-1] + b",}" if text.endswith(b"}") else text + b",",
                    b"/* c */" + text,
                    text.replace(b":", b" : ", 1),
                    text.replace(b"1", b"1_0"),
                ]
            )
        if r < 0.82 and text.endswith(b"}"):  # just past the 4 MiB a message may have
            pad = 4 * 1024 * 1024 + 16 - len(text)
            return text[:-1] + b',"pad":"' + b"a" * max(pad, 1) + b'"}'
        if r < 0.9:
            return b"[" + text + b"]"
        return b" " * rng.randrange(1, 64) + text + b"\n" * rng.randrange(1, 64)

    def garbage(self) -> bytes | None:
        rng = self.rng
        return self.pick(
            [
                None,
                b"",
                b"null",
                b"[]",
                b'"op"',
                b"1",
                b"true",
                b"{",
                b"}",
                b"{}",
                b'{"v":1}',
                b'{"op":null}',
                bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 2048))),
                b"\x00" * rng.randrange(1, 64),
                b"\xff\xfe" + "{}".encode("utf-16-le"),
                _DEEP_BYTES,
                b"SMF1" + bytes(36),
            ]
        )

    def hostile_payload(self, valid: dict[str, Any]) -> tuple[bytes | None, str]:
        r = self.rng.random()
        if r < 0.55:
            obj = json.loads(json.dumps(valid))
            for _ in range(self.rng.randrange(1, 3)):
                obj = self.mutate_object(obj)
            return to_json(obj), "mutated"
        if r < 0.85:
            return self.mutate_text(to_json(valid)), "text"
        return self.garbage(), "garbage"

    # -- the guard: what may go where ---------------------------------------------------------------
    def guard_cmd(
        self, owner: str, key: str, payload: bytes | None, trusted_bad: bool
    ) -> tuple[str, bytes | None]:
        """A command that decodes goes to a victim only if it changes nothing or must be refused; runs,
        replays, new sessions and closing the attacker's sessions are rationed (each holds a worker,
        a slot or a session)."""
        try:
            cmd = codec.loads(m.SessionCommand, payload) if payload is not None else None
        except Exception:  # refused by the decoder (or a decoder bug: the node will tell)
            return key, payload
        if cmd is None:
            return key, payload
        t = self.t
        if key.split("?", 1)[0] in {keys.cmd(t.attacker_user, s) for s in t.attacker_sessions}:
            owner = "own"
        if owner == "victim" and not (trusted_bad or cmd.op in READ_ONLY):
            key = keys.cmd(t.attacker_user, self.pick(t.attacker_sessions))
            owner = "own"
        if owner == "own" and cmd.op in ("run", "replay") and not trusted_bad:
            if self.runs_left <= 0:
                return key, to_json({"op": "get_session", "v": 1})
            self.runs_left -= 1
        if cmd.op == "close_session" and not (
            owner == "own"
            and key.split("?", 1)[0] == keys.cmd(t.attacker_user, self.closable)
            and self.index > self.count * 0.9
        ):
            return key, to_json({"op": "list_param_sets", "v": 1})
        return key, payload

    # -- the kinds of messages --------------------------------------------------------------------
    OPS = (
        "set_params",
        "reset_params",
        "set_initial",
        "set_command",
        "set_settings",
        "run",
        "replay",
        "pause",
        "resume",
        "abort",
        "seek",
        "save_param_set",
        "load_param_set",
        "delete_param_set",
        "list_param_sets",
        "get_session",
        "close_session",
    )

    def cmd(self) -> Message:
        t, r = self.t, self.rng.random()
        victim = self.pick(t.victims)
        if r < 0.55:
            owner, key = "own", keys.cmd(t.attacker_user, self.pick(t.attacker_sessions))
        elif r < 0.8:
            owner, key = "victim", keys.cmd(victim.user, victim.session)
        elif r < 0.87:  # someone else's session under the attacker's name: not_found
            owner, key = "cross", keys.cmd(t.attacker_user, victim.session)
        elif r < 0.93:
            owner, key = "cross", keys.cmd(victim.user, self.random_sid())
        else:
            owner = "cross"
            user = self.pick([self.weird_chunk(), t.attacker_user])
            sid = self.pick([self.weird_chunk(), self.pick(t.attacker_sessions)])
            key = f"simecs/u/{user}/sessions/{sid}/cmd"
        op = self.pick(self.OPS)
        mode = self.rng.random()
        trusted_bad = False
        if mode < 0.08:
            payload: bytes | None = to_json(self.valid_command(op))
            what = f"valid {op}"
        elif mode < 0.25 and (bad := self.out_of_range(op)) is not None:
            payload, what, trusted_bad = to_json(bad), f"out of range {op}", True
        else:
            payload, how = self.hostile_payload(self.valid_command(op))
            what = f"{how} {op}"
        if self.chance(0.03):
            key += "?" + self.selector()
        key, payload = self.guard_cmd(owner, key, payload, trusted_bad)
        return Message("cmd", key, payload, self.query_attachment(), what)

    def sessions_query(self) -> Message:
        t = self.t
        user = self.pick([t.attacker_user, t.attacker_user, t.victim_user, self.weird_chunk()])
        key = f"simecs/u/{user}/sessions"
        op = self.pick(["create", "list"])
        if self.chance(0.15):
            body = self.out_of_range("create") if op == "create" else {"op": "list", "v": 1}
            payload: bytes | None = to_json(body)
            what = f"out of range {op}"
        elif self.chance(0.1):
            payload, what = to_json(self.valid_command(op)), f"valid {op}"
        else:
            payload, how = self.hostile_payload(self.valid_command(op))
            what = f"{how} {op}"
        try:
            request = codec.loads(m.SessionRequest, payload) if payload is not None else None
        except Exception:
            request = None
        if isinstance(request, m.CreateSession):
            if user != t.attacker_user:
                key = keys.sessions(t.attacker_user)
            if self.creates_left <= 0:
                payload = to_json({"op": "list", "v": 1})
            else:
                self.creates_left -= 1
        return Message("query", key, payload, self.query_attachment(), what)

    def selector(self) -> str:
        params = [
            "vars="
            + ",".join(self.pick([*self.facts.variables[:5], "time", "nope", "a b"]) for _ in range(3)),
            "vars=" + ",".join(["joint1.q"] * 5000),
            "vars=",
            "vars=" + "x" * 70,
            "vars=time,time,time",
            "t0=" + self.pick(["nan", "inf", "-inf", "1e999", "-1e999", "1e400", "", "x", "0x10", "1e-400"]),
            "t1=" + self.pick(["nan", "-1", "1e308", "0", "--1", "1" + "0" * 5000]),
            "t0=2;t1=1",
            "every=" + self.pick(["0", "-1", "1.5", "99999999999999999999999", "", "nan", "1e3", "+1", " 1"]),
            "every=1;every=2",
            "x=1",
            "=",
            ";;;",
            "%ff",
            "vars=\u00e9",
            "t0",
            "_time=[..]",
        ]
        return ";".join(self.pick(params) for _ in range(self.rng.randrange(1, 4)))

    def query_attachment(self) -> bytes | None:
        if self.chance(0.8):
            return None
        return self.pick([b"", bytes(16), self.rng.randbytes(16), self.rng.randbytes(100), b"\xff" * 4096])

    def other_query(self) -> Message:
        t, r = self.t, self.rng.random()
        victim = self.pick(t.victims)
        user = self.pick([t.attacker_user, victim.user, self.weird_chunk()])
        rec_name = keys.recording_name(victim.session, victim.run_id)
        payload: bytes | None = None if self.chance(0.7) else self.garbage()
        what = "garbage"
        if r < 0.06:
            key = keys.LIBRARY
        elif r < 0.14:
            key = f"simecs/library/{self.pick([self.facts.model_id, 'nope', self.weird_chunk()])}"
        elif r < 0.22:
            page = self.pick([*self.facts.pages[:3], "nope", self.weird_chunk()])
            key = f"simecs/library/{self.pick([self.facts.model_id, self.weird_chunk()])}/doc/{page}"
        elif r < 0.3:
            key = f"simecs/u/{user}/recordings"
        elif r < 0.38:
            name = self.pick([rec_name, self.pick(UPLOAD_NAMES[:8]), "nope", self.weird_chunk()])
            key = f"simecs/u/{user}/recordings/{name}/info"
        elif r < 0.45:  # download (no payload)
            name = self.pick([rec_name, self.pick(UPLOAD_NAMES[:8]), "nope", self.weird_chunk()])
            key = f"simecs/u/{user}/recordings/{name}"
            payload = None
        elif r < 0.7:  # upload: garbage, a torn, mutated or hostile recording
            payload, what = self.upload_payload()
            user = t.attacker_user if self.chance(0.75) else user  # elsewhere only names are checked
            if user == t.attacker_user:
                # Mostly the few names replays ask for, so that accepted hostile files get replayed.
                r = self.rng.random()
                name = (
                    self.pick(UPLOAD_NAMES[:8])
                    if r < 0.6
                    else self.pick(UPLOAD_NAMES)
                    if r < 0.85
                    else self.pick([rec_name, self.weird_chunk()])
                )
                if payload == t.mcap and t.mcap:
                    if self.uploads_left <= 0:
                        payload = payload[: len(payload) // 2]
                    else:
                        self.uploads_left -= 1
            else:  # in another user's space only names the service must refuse
                name = self.pick([rec_name, self.bad_name()])
            key = f"simecs/u/{user}/recordings/{name}"
        elif r < 0.8:
            sim = self.pick(
                [*t.simulators, forgery.FAKE_SIMULATOR, self.weird_chunk()] if t.simulators else ["x"]
            )
            key = f"simecs/simulators/{sim}/run"
            payload, what = self.run_request(victim)
        elif r < 0.86:
            key = (
                keys.results(victim.user, victim.session)
                if self.chance(0.7)
                else f"simecs/u/{user}/sessions/{self.random_sid()}/results"
            )
        else:
            owner = self.pick([victim, Victim(t.attacker_user, self.pick(t.attacker_sessions))])
            run = self.pick(
                [owner.run_id, "r2", "r3", "r0", "r999999999999999999999", "r-1", self.weird_chunk()]
            )
            key = f"simecs/u/{owner.user}/sessions/{owner.session}/results/{run}"
            key += "?" + self.selector() if self.chance(0.8) else ""
            what = "results selector"
        if self.chance(0.05) and "?" not in key:
            key += "?" + self.selector()
        return Message("query", key, payload, self.query_attachment(), what)

    def upload_payload(self) -> tuple[bytes | None, str]:
        data, rng = self.t.mcap, self.rng
        if not data or self.chance(0.1):
            return self.garbage() or b"", "garbage upload"
        r = rng.random()
        if r < 0.05:
            return data, "valid upload"
        if r < 0.5 and self.mcap is not None:
            return self.hostile_recording()
        if r < 0.6:
            return data[: rng.randrange(len(data))], "torn upload"
        if r < 0.8:
            # Records outside chunks (metadata, summary, footer) carry no CRC of their own: aim there.
            spots = [i for i in range(len(data)) if data.startswith(b"simecs.", i)] if r < 0.7 else []
            spots = spots or [len(data) - rng.randrange(1, min(len(data), 30_000))]
            out = bytearray(data)
            for _ in range(rng.randrange(1, 6)):
                i = min(len(out) - 1, max(0, self.pick(spots) + rng.randrange(-64, 400)))
                out[i] = rng.getrandbits(8)
            return bytes(out), "bit-flipped upload"
        if r < 0.8:
            i = rng.randrange(len(data))
            return data[:i] + rng.randbytes(rng.randrange(1, 512)) + data[i:], "spliced upload"
        if r < 0.9:
            return data + rng.randbytes(rng.randrange(1, 512)), "trailing garbage upload"
        i = rng.randrange(8, len(data))
        return data[:i] + data[i - 8 : i] * 3 + data[i:], "repeated record upload"

    def hostile_recording(self) -> tuple[bytes, str]:
        """A structurally valid MCAP (every CRC right) whose simecs content is hostile: the layout, the
        run's context, the columns or the rows lie, or the format is another one."""
        assert self.mcap is not None
        rng = self.rng
        meta = {name: dict(values) for name, values in self.mcap.metadata.items()}
        run = meta.setdefault("simecs.run", {})
        layout: Any = json.loads(run.get("layout", "{}"))
        channels: dict[str, dict[str, str]] = {}
        edits: dict[str, Callable[[int, bytes], bytes | None]] = {}
        # Often JSON nested past any parser's depth, in each JSON text the file carries (json.loads then
        # raises RecursionError, which a reader catching ValueError does not expect).
        deep = self.pick(["[" * 100_000, "[" * 3000 + "]" * 3000, '{"a":' * 3000 + "1" + "}" * 3000])
        nested = self.chance(0.4)
        r = rng.random()
        if r < 0.22:
            for _ in range(rng.randrange(1, 3)):
                layout = self.mutate_object(layout)
            what = "recording with a mutated layout"
        elif r < 0.4:
            what = "recording with a lying layout: " + self.lying_layout(layout)
        elif r < 0.54:
            run["format_version"] = "1"
            session = meta.setdefault("simecs.session", {})
            field_name = self.pick(["initial", "command", "settings", "user"])
            session[field_name] = (
                deep
                if nested
                else self.pick(
                    [
                        "[1e999]",
                        '["a"]',
                        "{}",
                        "nan",
                        "{",
                        "[]",
                        '{"kind":"nope"}',
                        '{"stop_time":-1}',
                        "x" * 70,
                    ]
                    + [
                        deep,
                        deep,
                        "null",
                        '{"stop_time":1,"output_interval":1e-9}',
                        "",
                        "[" + "1," * 100_000 + "1]",
                    ]
                )
            )
            if self.chance(0.5):
                params = meta.setdefault("simecs.params", {})
                params[self.pick(self.facts.params)[0] if self.facts.params else "p"] = self.pick(
                    ["nan", "inf", "-inf", "1e999", "x", "", "0x10", "1_000"]
                )
            what = f"format 1 recording with a hostile {field_name}"
        elif r < 0.66:
            columns = (
                deep
                if nested
                else self.pick(
                    [
                        '["time"]',
                        '"x"',
                        "[1,2]",
                        '{"a":1}',
                        "null",
                        "[]",
                        '["time","time"]',
                        '["\\ud800"]',
                        deep,
                        deep,
                    ]
                )
            )
            channels["/vars"] = {"columns": columns}
            what = "recording whose /vars columns lie"
        elif r < 0.74:
            text = deep.encode() if nested else self.pick([b"\xff\xfe", b"[]", b"1e999", b'"x"', b"{" * 10])
            edits["/log"] = lambda i, data: text if i % 2 == 0 else data
            what = "recording with hostile /log messages"
        elif r < 0.86:
            how = self.pick(["nan time", "backwards", "one short", "no rows", "huge time", "same time"])

            def edit(i: int, data: bytes, how: str = how) -> bytes | None:
                values = list(struct.unpack(f"<{(len(data) - 4) // 8}d", data[4:]))
                if how == "nan time":
                    values[0] = float("nan")
                elif how == "backwards":
                    values[0] = -values[0]
                elif how == "huge time":
                    values[0] = 1e300 * (i + 1)
                elif how == "same time":
                    values[0] = 0.0
                elif how == "no rows":
                    return None
                elif how == "one short" and i == 3:
                    values = values[:-1]
                return data[:4] + struct.pack(f"<{len(values)}d", *values)

            edits["/vars"] = edit
            what = f"recording whose rows lie ({how})"
        else:
            what = "recording with hostile run metadata"
            target = self.pick(["simecs.run", "simecs.end", "simecs.recovery", "simecs.run"])
            values = meta.setdefault(target, {})
            values[self.pick([*list(values)[:12], "format_version", "gaps", "x"])] = self.pick(
                ["", "3", "-1", "nan", "x" * 100_001, "\u0000", "1e999", "r1"]
            )
            if self.chance(0.2):
                meta.pop("simecs.run", None)
        if "layout" in run or layout:
            run["layout"] = to_json(layout).decode("utf-8")
        return self.mcap.write(meta, channels, edits), what

    def lying_layout(self, layout: Any) -> str:
        """A change to a well-formed layout that a reader must notice (or survive)."""
        if not isinstance(layout, dict):
            return "not an object"
        found = layout.get("context")
        ctx: dict[str, Any] = found if isinstance(found, dict) else {}
        first = self.facts.params[0][0] if self.facts.params else "p"
        edits: list[tuple[str, Callable[[], None]]] = [
            ("model puma560", lambda: layout.update(model_id="puma560")),
            ("unknown model", lambda: layout.update(model_id="nope")),
            ("one column less", lambda: layout.update(columns=layout["columns"][:-1])),
            ("only time", lambda: layout.update(columns=["time"], units=["s"])),
            ("unknown live column", lambda: layout.update(live_columns=["time", "nope"])),
            ("stop time 0", lambda: layout.update(stop_time=0.0)),
            ("stop time 1e300", lambda: layout.update(stop_time=1e300)),
            ("output interval 0", lambda: layout.update(output_interval=0.0)),
            ("largest run index", lambda: layout.update(run_index=2**32 - 1)),
            ("source replay", lambda: layout.update(source="replay")),
            ("no values", lambda: ctx.update(values={})),
            ("unknown value", lambda: ctx.update(values={"nope": 1.0})),
            ("value 1e300", lambda: ctx.update(values={**ctx.get("values", {}), first: 1e300})),
            ("no joints", lambda: ctx.update(initial=[])),
            ("100 joints", lambda: ctx.update(initial=[0.0] * 100)),
            ("joints 1e300", lambda: ctx.update(initial=[1e300] * len(self.facts.joints))),
            ("no command", lambda: ctx.update(command=None)),
            (
                "command out of range",
                lambda: ctx.update(command={"kind": "joint_path", "nodes": [{"q": [9.0] * 7}]}),
            ),
            ("another user", lambda: ctx.update(user="ann")),
            ("realtime, an hour", lambda: ctx.update(settings={"stop_time": 3600.0, "pacing": "realtime"})),
        ]
        what, edit = self.pick(edits)
        edit()
        return what

    def run_request(self, victim: Victim) -> tuple[bytes | None, str]:
        settings = m.RunSettings(stop_time=0.05, output_interval=0.01, pacing="fast")
        req = m.RunRequest(
            victim.session, "r77", 77, victim.user, self.facts.model_id, {}, [0.0] * 7, None, settings
        )
        valid = json.loads(codec.dumps(req))
        if self.chance(0.3):
            return to_json(valid), "unsealed run request"
        payload, how = self.hostile_payload(valid)
        return payload, f"{how} run request"

    # -- puts ---------------------------------------------------------------------------------------
    def put(self) -> Message:
        t, r = self.t, self.rng.random()
        if r < 0.35:
            key, payload = self.pick(self.forged)
            what = "forged"
        else:
            owner = self.pick([*t.victims, Victim(t.attacker_user, self.pick(t.attacker_sessions))])
            u, s = owner.user, owner.session
            writers = [
                keys.run_status(u, s),
                keys.layout(u, s),
                keys.vars_full(u, s),
                keys.vars_live(u, s),
                keys.state(u, s),
                keys.params(u, s),
                keys.notices(u, s),
                keys.control(u, s),
                keys.jog(u, s),
                keys.results(u, s),
                keys.results(u, s, owner.run_id),
                keys.cmd(u, s),
                keys.sessions(u),
                *[keys.simulator_run(sim) for sim in t.simulators],
                *[keys.node_status(role, node) for role, node in t.nodes],
                keys.node_status("simulator", forgery.FAKE_SIMULATOR),
                f"simecs/u/{u}/sessions/{self.random_sid()}/run",
            ]
            key = self.pick(writers)
            if r < 0.6:
                json_forged = [(k, p) for k, p in self.forged if p[:1] == b"{"]
                base = [p for k, p in json_forged if k == key] or [p for _k, p in json_forged]
                payload, how = self.hostile_payload(json.loads(self.pick(base)))
                what = f"{how} json"
            elif r < 0.85:
                payload, what = self.frame(owner), "frame"
            else:
                payload, what = self.garbage() or b"", "garbage"
        attachment = self.pick([None, None, b"", self.rng.randbytes(16), bytes(16), self.rng.randbytes(64)])
        return Message("put", key, payload if payload is not None else b"", attachment, what)

    def frame(self, owner: Victim) -> bytes:
        """A stream frame, usually lying about itself: sizes, magic, version, run, values."""
        rng, width = self.rng, self.t.width
        rows = [[rng.uniform(-1, 1) for _ in range(width)] for _ in range(rng.randrange(0, 4))]
        for row in rows:
            if self.chance(0.3):
                row[rng.randrange(width)] = self.pick([float("nan"), float("inf"), -float("inf"), 1e308])
        data = b"".join(struct.pack(f"<{width}d", *row) for row in rows)
        magic, version = b"SMF1", 1
        n_rows, n_cols = len(rows), width
        run_index, flags = owner.run_index, self.pick([0, 1, 2, 3, 0xFFFF])
        r = rng.random()
        if r < 0.15:
            magic = self.pick([b"SMF2", b"\x00\x00\x00\x00", b"smf1"])
        elif r < 0.25:
            version = self.pick([0, 2, 0xFFFF])
        elif r < 0.45:
            n_rows = self.pick([2**32 - 1, n_rows + 1, 2**31])
        elif r < 0.6:
            n_cols = self.pick([0, 1, 2**32 - 1, width + 1, width - 1])
        elif r < 0.7:
            run_index = self.pick([0, 2**32 - 1, run_index + 1])
        wall_ns = 1_700_000_000_000_000_000 + self.index * 1_000_000  # no clock: the same every time
        head = frames.HEADER.pack(magic, version, flags, run_index, 0, 0, wall_ns, n_rows, n_cols)
        body = head + data
        if self.chance(0.2):
            body = body[: rng.randrange(len(body) + 1)]
        return body

    # -- tokens -----------------------------------------------------------------------------------
    def token(self) -> Message:
        """Declare a liveliness token of a run or a node that is not the attacker's, or drop one."""
        t = self.t
        if self.tokens and (len(self.tokens) >= MAX_TOKENS or self.chance(0.5)):
            key = self.tokens.pop(self.rng.randrange(len(self.tokens)))
            return Message("token", key, None, None, "undeclare")
        victim = self.pick(t.victims)
        run_id = self.pick(_next_runs(victim.run_id))  # run ids are predictable: r1, r2, ...
        # Mostly the tokens that decide other users' runs; sometimes nodes' and the attacker's own.
        key = self.pick(
            [
                *[keys.run_token(victim.user, victim.session, run_id)] * 8,
                keys.run_token(t.attacker_user, self.pick(t.attacker_sessions), "r1"),
                *[keys.node_token(role, node) for role, node in t.nodes],
                keys.node_token("simulator", forgery.FAKE_SIMULATOR),
                keys.node_token("proxy", "evil-proxy"),
            ]
        )
        if key in self.tokens:
            return Message("token", key, None, None, "undeclare")
        if self.chance(0.7):  # most go as quickly as they came
            self.pending.append(Message("token", key, None, None, "undeclare"))
        else:
            self.tokens.append(key)
        return Message("token", key, None, None, "declare")

    def next(self) -> Message:
        self.index += 1
        if self.pending:
            return self.pending.pop(0)
        r = self.rng.random()
        if r < 0.45:
            return self.cmd()
        if r < 0.5:
            return self.sessions_query()
        if r < 0.65:
            return self.other_query()
        if r < 0.96:
            return self.put()
        return self.token()


def messages(targets: FuzzTargets, facts: ModelFacts, seed: int = 1, count: int = 3000) -> Iterator[Message]:
    """The messages of `seed`, in order: the same targets and seed give the same messages."""
    gen = _Generator(targets, facts, seed, count)
    for _ in range(count):
        yield gen.next()


# -- sending -----------------------------------------------------------------------------------------
_RUN_OF_BYTES = re.compile(rb"(.)\1{15,}", re.S)


def _excerpt(data: bytes | None) -> str:
    """The start of `data`, with long runs of one byte shortened (`x` * 100000 reads `xxx<*100000>`)."""
    if data is None:
        return "<no payload>"
    if data.startswith(b"\x89MCAP"):  # what was wrong with it is in the request's description
        return f"<an MCAP file of {len(data)} bytes>"
    short = _RUN_OF_BYTES.sub(lambda g: g.group(1) * 3 + b"<*%d>" % len(g.group(0)), data[: EXCERPT * 100])
    shown = repr(short[:EXCERPT])
    return f"{shown}{'…' if len(short) > EXCERPT else ''} ({len(data)} bytes)"


def _code_of(reply: zenoh.Reply) -> tuple[str, bytes, str]:
    """(code, payload, why an error reply is no Error) of one reply."""
    if reply.ok is not None:
        return "ok", reply.ok.payload.to_bytes(), ""
    assert reply.err is not None
    body = reply.err.payload.to_bytes()
    try:
        return codec.loads(m.Error, body).code, body, ""
    except Exception as exc:
        # zenoh's own answer when nobody replied in time is a bare text
        if body.strip().lower().startswith(b"timeout"):
            return "timeout", body, ""
        return "malformed", body, f"{type(exc).__name__}: {str(exc)[:EXCERPT]} in "


def fuzz(
    attacker: zenoh.Session,
    targets: FuzzTargets,
    seed: int = 1,
    count: int = 3000,
    deadline_s: float = 60.0,
) -> FuzzReport:
    """Send the `count` messages of `seed` from `attacker` (a session without the service key), one by
    one, until `deadline_s`; then undeclare its tokens and end the runs and sessions it started.
    Returns what was sent and how the service answered."""
    report = FuzzReport()
    replies: Counter[str] = Counter()
    kinds: Counter[str] = Counter()
    tokens: dict[str, Any] = {}
    t0 = time.monotonic()
    end = t0 + deadline_s
    facts = model_facts(attacker, targets.model_id)
    own_sessions = keys.sessions(targets.attacker_user)
    try:
        for msg in messages(targets, facts, seed, count):
            if time.monotonic() > end:
                report.out_of_time = True
                break
            kinds[msg.kind] += 1
            report.sent += 1
            try:
                if msg.kind == "put":
                    attacker.put(msg.key, msg.payload or b"", attachment=msg.attachment)
                    continue
                if msg.kind == "token":
                    if msg.what == "declare":
                        if msg.key in tokens:
                            tokens.pop(msg.key).undeclare()
                        tokens[msg.key] = attacker.liveliness().declare_token(msg.key)
                    elif msg.key in tokens:
                        tokens.pop(msg.key).undeclare()
                    continue
                timeout = max(0.5, min(QUERY_TIMEOUT_S, end - time.monotonic()))
                answers = list(
                    attacker.get(msg.key, payload=msg.payload, attachment=msg.attachment, timeout=timeout)
                )
            except zenoh.ZError:
                report.unsendable += 1
                continue
            entry_of = (msg.key, f"{msg.what}: {_excerpt(msg.payload)}")
            if not answers:
                replies["unanswered"] += 1
            if len(answers) > 1:
                report.multiple.append((*entry_of, "; ".join(_code_of(a)[0] for a in answers)))
            family = report.by_request.setdefault(f"{msg.kind} {msg.what}", {})
            for answer in answers:
                code, body, why = _code_of(answer)
                replies[code] += 1
                family[code] = family.get(code, 0) + 1
                entry = (*entry_of, why + _excerpt(body))
                if code == "internal":
                    report.internal.append(entry)
                elif code == "malformed":
                    report.malformed.append(entry)
                elif code == "timeout":
                    report.timeouts.append(entry)
                elif code == "ok" and msg.key == own_sessions:
                    try:
                        snap = codec.loads(m.Ok, body).data
                        if isinstance(snap, dict) and "session" in snap:
                            report.created_sessions.append(str(snap["session"]))
                    except Exception:
                        pass
    finally:
        for token in tokens.values():
            try:
                token.undeclare()
            except Exception:
                pass
        _clean_up(attacker, targets, report)
        report.replies_by_code = dict(replies)
        report.by_kind = dict(kinds)
        report.elapsed_s = time.monotonic() - t0
    return report


def _clean_up(attacker: zenoh.Session, targets: FuzzTargets, report: FuzzReport) -> None:
    """End what the fuzz started in the attacker's name: its runs, and the sessions it created."""
    user = targets.attacker_user
    for sid in targets.attacker_sessions:
        try:
            for reply in attacker.get(keys.results(user, sid), timeout=QUERY_TIMEOUT_S):
                if reply.ok is not None:
                    runs = codec.from_obj(
                        list[m.RunInfo], codec.loads(m.Ok, reply.ok.payload.to_bytes()).data
                    )
                    report.own_runs += [f"{sid} {r.run_id}: {r.phase} {r.reason}".strip() for r in runs]
        except Exception:
            pass
    for sid, op in [(s, "abort") for s in targets.attacker_sessions] + [
        (s, "close_session") for s in report.created_sessions
    ]:
        try:
            list(
                attacker.get(
                    keys.cmd(user, sid), payload=to_json({"op": op, "v": 1}), timeout=QUERY_TIMEOUT_S
                )
            )
        except Exception:
            pass
