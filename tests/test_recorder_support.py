"""Helpers for the recorder and replay tests (no tests here): a small arm model and a run publisher.

`FakeRun` publishes a run exactly as a simulator worker does (latched layout, full frames, the last
one FLAG_FINAL) and `FakeProxy` answers the model and session queries the recorder makes: both are
clients of the protocol, so the recorder under test is the real node in its own process.
"""

from __future__ import annotations

import json
import struct
import time
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import zenoh
import zenoh.ext
from mcap.data_stream import ReadDataStream
from mcap.reader import SeekingReader
from mcap.records import Chunk, MessageIndex
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from simecs.mesh.process.seal import Seal, SealedPublisher
from simecs.mesh.protocol import codec, frames, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import Link, ModelDescription, Parameter, Shape, Variable
from simecs.mesh.rules import kinematics
from simecs.nodes.recording import mcapfmt as fmt
from simecs.nodes.recording import mcapread

MODEL_ID = "testarm"
USER = "ann"  # whose sessions the fake runs are (the recorder files them under recordings/ann/)


def arm_model() -> ModelDescription:
    links = [
        Link("link1", "joint1", [0.0, 0.0, 0.0], "link1.length", [0.0, 0.0, 0.0], -3.0, 3.0),
        Link("link2", "joint2", [1.5707963267948966, 0.0, 0.0], "link2.length", [0.0, 0.0, 0.05], -2.0, 2.0),
    ]
    params = [
        Parameter("link1.length", 0.4, "m", "length of link 1", 0.1, 1.0, "link1", appearance=True),
        Parameter("link2.length", 0.3, "m", "length of link 2", 0.1, 1.0, "link2", appearance=True),
    ]
    variables = []
    for j in ("joint1", "joint2"):
        for name, unit in (("q", "rad"), ("qd", "rad/s"), ("tau_gear", "N*m"), ("i_a", "A")):
            variables.append(Variable(f"{j}.{name}", unit, f"{j} {name}", j))
    shapes = [
        Shape("cylinder", 0, [0.0, 0.0, -0.05], "z", length=0.1, radius=0.06),
        Shape("pipe", 0, [0.0, 0.0, 0.0], "x", length=0.4, radius=0.04, inner_radius=0.03, resizable=True),
        Shape("pipe", 1, [0.0, 0.0, 0.0], "x", length=0.3, radius=0.03, inner_radius=0.02, resizable=True),
        Shape("beam", 1, [0.3, 0.0, 0.0], "z", length=0.05, width=0.04, height=0.04),
        Shape("sphere", 1, [0.3, 0.0, 0.05], "x", radius=0.03),
    ]
    env = [Shape("box", -1, [-0.5, 0.0, -0.02], "x", length=1.0, width=1.0, height=0.02)]
    return ModelDescription(
        id=MODEL_ID,
        name="Test arm",
        summary="two links",
        base_translation=[0.0, 0.0, 0.1],
        links=links,
        tool_translation=[0.05, 0.0, 0.0],
        shapes=shapes,
        parameters=params,
        variables=variables,
        init_equations=[],
        doc_root="testarm",
        docs=[],
        command_levels=["joint_path"],
        environment=env,
    )


def columns_of(model: ModelDescription) -> tuple[list[str], list[str]]:
    return model.run_columns()


def context_of(model: ModelDescription) -> m.RunContext:
    """What a worker carries with a run: who, with which values, pose, command and settings."""
    return m.RunContext(
        user="tester",
        values=model.default_values(),
        initial=[0.0, 0.3],
        command=m.JointPath([m.PathNode([0.5, 0.3])]),
        settings=m.RunSettings(stop_time=1.0, pacing="fast"),
    )


def make_rows(model: ModelDescription, n: int, dt: float = 0.002, t_start: float = 0.0) -> np.ndarray:
    """Plausible samples: joints move smoothly; poses from the model's own kinematics."""
    cols, _ = columns_of(model)
    values = model.default_values()
    rows = np.empty((n, len(cols)))
    rng = np.random.default_rng(int(t_start * 1000) + n)
    for i in range(n):
        t = t_start + i * dt
        q = [0.5 * np.sin(t), 0.3 * np.cos(2 * t)]
        row = [t]
        for j in range(2):
            row += [q[j], 0.5 * np.cos(t), float(rng.standard_normal()), float(rng.standard_normal()) / 3]
        row += kinematics.link_poses(model, values, q).ravel().tolist()
        row += [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]  # the grasped frame before any grasp: the origin
        rows[i] = row
    return rows


def layout_for(session: str, run_id: str = "r1", run_index: int = 1, stop_time: float = 1.0) -> m.RunLayout:
    cols, units = columns_of(arm_model())
    return m.RunLayout(
        session=session,
        run_id=run_id,
        run_index=run_index,
        model_id=MODEL_ID,
        columns=cols,
        units=units,
        live_columns=cols,
        live_rate_hz=50.0,
        stop_time=stop_time,
        output_interval=0.002,
        context=context_of(arm_model()),
    )


class FakeRun:
    """Publishes one run as a simulator worker does: with the service's seal of the mesh."""

    def __init__(
        self,
        z: zenoh.Session,
        seal: Seal,
        session: str,
        run_id: str = "r1",
        run_index: int = 1,
        user: str = USER,
    ) -> None:
        self.z = z
        self.seal = seal
        self.user = user
        self.layout = layout_for(session, run_id, run_index)
        layout_key, full_key = keys.layout(user, session), keys.vars_full(user, session)
        self.layout_pub = SealedPublisher(
            zenoh.ext.declare_advanced_publisher(
                z, layout_key, cache=zenoh.ext.CacheConfig(1), publisher_detection=True
            ),
            layout_key,
            seal,
        )
        self.full = SealedPublisher(
            z.declare_publisher(full_key, congestion_control=zenoh.CongestionControl.BLOCK), full_key, seal
        )
        self.token = z.liveliness().declare_token(keys.run_token(user, session, run_id))
        self.seq = 0
        self.sent: list[frames.Frame] = []

    def announce(self) -> None:
        self.layout_pub.put(codec.dumps(self.layout))

    def frame(self, rows: np.ndarray, final: bool = False) -> frames.Frame:
        fr = frames.Frame(
            self.layout.run_index, self.seq, time.time_ns(), rows, frames.FLAG_FINAL if final else 0
        )
        self.full.put(frames.encode(fr))
        self.sent.append(fr)
        self.seq += 1
        return fr

    def state(self, phase: str, sim_time: float = 0.0, reason: str = "") -> None:
        st = m.SessionState(
            self.layout.session, phase, run_id=self.layout.run_id, sim_time=sim_time, reason=reason
        )  # type: ignore[arg-type]
        key, payload = keys.state(self.user, self.layout.session), codec.dumps(st)
        self.z.put(key, payload, attachment=self.seal.mac(key, payload))

    def close(self) -> None:
        for e in (self.layout_pub, self.full, self.token):
            e.undeclare()


class FakeProxy:
    """Answers the model description query, as the proxy's library does (sealed: the recorder takes
    only a service node's answers)."""

    def __init__(self, z: zenoh.Session, seal: Seal) -> None:
        model = arm_model()
        self.model = model

        def on_model(q: zenoh.Query) -> None:
            body = codec.dumps(m.Ok(data=codec.to_obj(model)))
            q.reply(q.key_expr, body, attachment=seal.mac(str(q.key_expr), body))

        self.entities = [z.declare_queryable(keys.model(MODEL_ID), on_model)]

    def close(self) -> None:
        for e in self.entities:
            e.undeclare()


def check_file(path: Path | str) -> tuple[mcapread.Validation, mcapread.Recording]:
    """Strict CRC validation, then every JSON message against its vendored Foxglove schema."""
    v = mcapread.validate(path)
    sc = mcapread.scan(path, strict=True)
    validators: dict[int, Any] = {}
    for cid, ch in sc.channels.items():
        schema = sc.schemas[ch.schema_id]
        if ch.message_encoding == "json":
            assert schema.encoding == "jsonschema", ch.topic
            assert schema.data == fmt.foxglove_schema(schema.name), (
                f"{schema.name} differs from the vendored file"
            )
            validators[cid] = jsonschema.Draft202012Validator(json.loads(schema.data))
        else:
            assert (ch.topic, schema.encoding, ch.message_encoding) == (fmt.TOPIC_VARS, "ros2msg", "cdr")
    for msg in sc.messages:
        if msg.channel_id in validators:
            validators[msg.channel_id].validate(json.loads(msg.data))
    assert check_message_indexes(path) == v.messages
    return v, mcapread.load(path, strict=True)


def check_message_indexes(path: Path | str) -> int:
    """Every message index entry points at a message of its channel and log time (indexed reads work)."""
    checked = 0
    with open(path, "rb") as fh:
        reader = SeekingReader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        for ci in summary.chunk_indexes:
            fh.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(fh))
            data, size = get_chunk_data_stream(chunk, validate_crc=True)
            raw = data.read(size)
            for cid, offset in ci.message_index_offsets.items():
                fh.seek(offset)
                index = next(StreamReader(fh, skip_magic=True).records)
                assert isinstance(index, MessageIndex) and index.channel_id == cid
                for log_time, at in index.records:
                    op, _len, ch, _seq, t, _pub = struct.unpack_from("<BQHIQQ", raw, at)
                    assert (op, ch, t) == (0x05, cid, log_time), (path, cid, at)
                    checked += 1
        assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count
    return checked


def wait_file_closed(path: Path, timeout: float = 15.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and mcapread.has_footer(path):
            return
        time.sleep(0.05)
    raise TimeoutError(f"{path} not closed within {timeout} s (exists: {path.exists()})")
