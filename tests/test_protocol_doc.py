"""The protocol is one schema: docs/protocol.schema.json and PROTOCOL.md's tables are generated from
mesh/ and up to date; every message is documented; keys, frames and phases have one owner each."""

from __future__ import annotations

import inspect
import json
import re
import typing
from pathlib import Path

import jsonschema
import pytest
from simecs.mesh.protocol import codec, frames, keys, phases, protocol_doc, schema, session_commands
from simecs.mesh.protocol import messages as m

ROOT = Path(__file__).resolve().parent.parent
DOC = (ROOT / "docs" / "PROTOCOL.md").read_text()
SCHEMA = json.loads((ROOT / "docs" / "protocol.schema.json").read_text())
CODE = ("mesh", "models", "nodes", "viewer", "testing", "benchmarks")


def test_schema_and_document_are_generated_from_mesh_and_current() -> None:
    assert protocol_doc.main(["--check", "--root", str(ROOT)]) == 0, (
        "run: python -m simecs.mesh.protocol.protocol_doc"
    )
    assert json.loads(schema.schema_text()) == SCHEMA


def test_every_message_type_is_in_the_document_once() -> None:
    grouped = [name for _group, names in protocol_doc.GROUPS for name in names]
    assert len(grouped) == len(set(grouped))
    assert sorted(grouped) == sorted(SCHEMA["$defs"]), "a message type is missing from protocol_doc.GROUPS"
    for name in grouped:
        assert f"**{name}**" in DOC


def test_every_key_of_the_table_is_built_and_parsed_by_the_table() -> None:
    sid = keys.new_session_id()
    chunks = {
        "user": "ann",
        "session": sid,
        "model": "m0",
        "page": "p0",
        "name": "n0",
        "run": "r3",
        "role": "proxy",
        "node": "n1",
        "mesh": "link1.0",
    }
    for name, spec in keys.KEYS.items():
        key = keys.build(name, **{c: chunks[c] for c in spec.chunks})
        assert keys.parse(name, key) == {c: chunks[c] for c in spec.chunks}
        assert f"`{spec.pattern}`" in DOC
    builders = [f for n, f in inspect.getmembers(keys, inspect.isfunction) if f.__module__ == keys.__name__]
    assert {"cmd", "state", "results", "run_token", "node_status"} <= {f.__name__ for f in builders}


def lines_matching(pattern: re.Pattern[str], owner: Path) -> list[str]:
    """`file:line` of every line of the code (outside `owner`) that matches `pattern`."""
    return [
        f"{path.relative_to(ROOT)}:{n}"
        for folder in CODE
        for path in (ROOT / folder).rglob("*.py")
        if path != owner
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if pattern.search(line)
    ]


def test_keys_are_taken_apart_only_in_mesh_keys() -> None:
    offenders = lines_matching(
        re.compile(r"""\.r?split\(\s*["']/["']"""), ROOT / "mesh" / "protocol" / "keys.py"
    )
    assert not offenders, f"keys split by hand (use keys.parse): {offenders}"


def test_frame_headers_are_read_only_in_mesh_frames() -> None:
    by_offset = re.compile(r"HEADER\.unpack|unpack_from\([^)]*,\s*(8|16|24|32|36)\)")
    offenders = lines_matching(by_offset, ROOT / "mesh" / "protocol" / "frames.py")
    assert not offenders, f"frame header read by byte offset (use frames.peek): {offenders}"


def test_the_frame_header_table_is_the_struct() -> None:
    offset = 0
    for _name, at, size, _meaning in frames.HEADER_FIELDS:
        assert at == offset
        offset += size
    assert offset == frames.HEADER.size == SCHEMA["x-simecs-frame"]["header_bytes"]


def test_phase_table_is_closed_and_every_command_has_its_phases() -> None:
    for event, moves in phases.TRANSITIONS.items():
        assert set(moves) <= set(phases.PHASES) and set(moves.values()) <= set(phases.PHASES), event
    for cls in session_commands.SESSION_COMMANDS:
        assert cls.accepted_in and set(cls.accepted_in) <= set(phases.PHASES), cls.__name__
        assert cls in m.REPLIES and m.REPLIES[cls] is cls.reply, cls.__name__
    # every command on the cmd key, and only those, is in the union the proxy decodes
    union = set(typing.get_args(m.SessionCommand))
    assert union == set(session_commands.SESSION_COMMANDS) and len(union) == len(m.REPLIES) - 2
    assert session_commands.refusal("pause", "finished") == "nothing to pause: the session is finished"
    assert session_commands.refusal("run", "created") == ""
    assert (
        session_commands.refusal("save_param_set", "closed") == "save_param_set is not possible while closed"
    )


def validator(name: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator({"$ref": f"#/$defs/{name}", "$defs": SCHEMA["$defs"]})


def test_what_the_codec_accepts_the_schema_accepts_and_refuses_alike() -> None:
    sid = keys.new_session_id()
    good = [
        ("SessionCommand", m.SetParams({"joint1.ctrl.kp_pos": 60.0})),
        ("SessionCommand", m.Replay("x_r1", speed=2.0)),
        ("SessionCommand", m.SetCommand(m.JointPath([m.PathNode([0.1, 0.2])]))),
        ("SessionState", m.SessionState(sid, "running", progress=0.5)),
        ("RunSettings", m.RunSettings(stop_time=2.0)),
    ]
    for name, msg in good:
        validator(name).validate(codec.to_obj(msg))
    bad = [
        ("SessionCommand", {"op": "set_params", "values": {"a": 1}}),  # no v
        ("SessionCommand", {"op": "run", "v": 1, "extra": 1}),
        ("SessionCommand", {"op": "set_settings", "v": 1, "settings": {"stop_time": 0}}),
        ("SessionState", {"type": "state", "v": 1, "session": "short", "phase": "created"}),
        ("SessionCommand", {"op": "save_param_set", "v": 1, "name": "-bad"}),
    ]
    for name, value in bad:
        assert not validator(name).is_valid(value), value
        with pytest.raises(codec.DecodeError):
            codec.from_obj(m.SessionCommand if name == "SessionCommand" else getattr(m, name), value)


def test_each_commands_reply_is_in_the_schema() -> None:
    commands = SCHEMA["x-simecs-commands"]
    assert set(commands) == {c.__struct_config__.tag for c in m.REPLIES}
    ok = commands["run"]["reply"]
    jsonschema.Draft202012Validator({**ok, "$defs": SCHEMA["$defs"]}).validate(
        {"type": "ok", "v": 1, "data": {"run_id": "r1", "phase": "queued", "queue_position": 0}}
    )
