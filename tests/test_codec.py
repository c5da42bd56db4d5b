"""Codec round trips for every message type, and hostile input that must give named errors."""

from __future__ import annotations

import json
import subprocess
import sys
import typing

import msgspec
import msgspec.inspect as mi
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simecs.mesh.protocol import codec, messages, primitives, schema
from simecs.mesh.protocol import model as model_types

#: Every Struct of the protocol (the schema's own list of them).
MESSAGE_TYPES = schema.message_types()
SESSION = "A" * 22
OPS = {cls.__struct_config__.tag: cls for cls in typing.get_args(messages.SessionCommand)}


def example_of(info: mi.Type) -> typing.Any:
    """A valid JSON value of an inspected type, within its bounds."""
    if isinstance(info, mi.Metadata):
        return example_of(info.type)
    if isinstance(info, mi.FloatType):
        lo = info.ge if info.ge is not None else (info.gt + 1e-3 if info.gt is not None else 1.0)
        hi = info.le if info.le is not None else (info.lt - 1e-3 if info.lt is not None else lo + 1.0)
        return float(min(max(1.0, lo), hi))
    if isinstance(info, mi.IntType):
        lo = info.ge if info.ge is not None else 1
        return int(max(lo, 1) if info.le is None or info.le >= 1 else lo)
    if isinstance(info, mi.StrType):
        if info.pattern == primitives.SESSION_ID_PATTERN:
            return SESSION
        return "x"
    if isinstance(info, mi.BoolType):
        return True
    if isinstance(info, mi.AnyType):
        return {"a": [1, 2]}
    if isinstance(info, mi.LiteralType):
        return info.values[0]
    if isinstance(info, mi.UnionType):
        return example_of(next(t for t in info.types if not isinstance(t, mi.NoneType)))
    if isinstance(info, mi.ListType):
        n = max(info.min_length or 0, 1)
        n = min(n, info.max_length) if info.max_length is not None else n
        return [example_of(info.item_type) for _ in range(n)]
    if isinstance(info, mi.DictType):
        return {"k": example_of(info.value_type)}
    if isinstance(info, mi.StructType):
        out: dict[str, typing.Any] = {}
        if info.tag_field is not None:
            out[info.tag_field] = info.tag
        for f in info.fields:
            if f.required or f.name == "v":
                out[f.encode_name] = example_of(f.type)
        return out
    raise AssertionError(f"no example for {info}")


def example(cls: type) -> typing.Any:
    value = example_of(mi.type_info(cls))
    if cls is messages.RunSettings:
        value.update(stop_time=1.0, output_interval=0.01)
    return value


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.__name__)
def test_round_trip(cls: type) -> None:
    obj = codec.from_obj(cls, example(cls))
    assert codec.loads(cls, codec.dumps(obj)) == obj


def test_every_standalone_message_carries_its_tag_and_version() -> None:
    for cls in MESSAGE_TYPES:
        config = cls.__struct_config__
        if config.tag_field is not None and config.tag_field != "kind":
            assert "v" in cls.__struct_fields__, f"{cls.__name__} has no version field"


@pytest.mark.parametrize(
    ("payload", "field", "words"),
    [
        (b'{"op":"explode","v":1}', "op", "unknown op 'explode' (known: set_params"),
        (b'{"op":"set_params","values":{"a":"1"},"v":1}', "values.a", "must be a number, got a string"),
        (b'{"op":"set_params","values":{"a":NaN},"v":1}', "", "not valid JSON"),
        (b'{"op":"set_params","values":{"a":1e999},"v":1}', "values.a", "finite"),
        (b'{"op":"set_params","v":1}', "values", "missing required field"),
        (b'{"op":"set_params","values":{}}', "v", "missing required field"),
        (b'{"values":{},"v":1}', "op", "missing required field"),
        (b'{"op":"run","extra":1,"v":1}', "extra", "unknown field"),
        (b'{"op":"run","v":7}', "v", "version 7 not supported"),
        (b'{"op":"set_initial","joints":[true],"v":1}', "joints[0]", "must be a number"),
        (b'{"op":"set_initial","joints":[' + b"0," * 64 + b'0],"v":1}', "joints", "length <= 64"),
        (b'{"op":"set_command","command":{"kind":"teleport"},"v":1}', "command.kind", "unknown kind"),
        (
            b'{"op":"set_command","command":{"kind":"joint_path","nodes":[{"q":[0],"acc_pct":0}]},"v":1}',
            "command.nodes[0].acc_pct",
            "> 0",
        ),
        (b'{"op":"set_settings","settings":{"pacing":"warp"},"v":1}', "settings.pacing", "must be one of"),
        (b'{"op":"set_settings","settings":{"output_interval":0},"v":1}', "settings.output_interval", ">="),
        (
            b'{"op":"set_settings","settings":{"output_interval":9},"v":1}',
            "settings.output_interval",
            "stop_time",
        ),
        (b'{"op":"save_param_set","name":"a b","v":1}', "name", "letters, digits"),
        (b'{"op":"set_params","values":{"-x":1},"v":1}', "values.-x", "letters, digits"),
        (b'{"op":"save_param_set","name":"\\ud800","v":1}', "", "lone UTF-16 surrogate"),
        (b'{"op":"set_initial","joints":[1' + b"0" * 5000 + b'],"v":1}', "joints[0]", "number out of range"),
        (b'{"op":"set_initial","joints":[1e99999],"v":1}', "joints[0]", "number out of range"),
        (b"\xff\xfe", "", "not UTF-8"),
        (b"[]", "", "must be an object"),
        (b"{", "", "not valid JSON"),
        (b'"run"', "", "must be an object"),
    ],
)
def test_hostile_commands_name_the_field(payload: bytes, field: str, words: str) -> None:
    with pytest.raises(codec.DecodeError) as info:
        codec.loads(messages.SessionCommand, payload)
    assert info.value.field == field
    assert words in str(info.value)


def test_a_single_message_type_needs_its_tag_and_the_right_one() -> None:
    good = {"type": "state", "session": SESSION, "phase": "created", "v": 1}
    assert codec.from_obj(messages.SessionState, good).phase == "created"
    for bad, field in (
        ({**good, "type": "params"}, "type"),
        ({k: v for k, v in good.items() if k != "type"}, "type"),
    ):
        with pytest.raises(codec.DecodeError) as info:
            codec.loads(messages.SessionState, json.dumps(bad))
        assert info.value.field == field


def test_oversized_message_refused() -> None:
    big = b'{"op":"set_params","v":1,"values":{"a":' + b"1" * codec.MAX_MESSAGE_BYTES + b"}}"
    with pytest.raises(codec.DecodeError, match="larger than message_bytes = 4194304 bytes"):
        codec.loads(messages.SessionCommand, big)


def test_too_many_samples_refused_naming_the_bound_and_the_way_out() -> None:
    settings = {"op": "set_settings", "v": 1, "settings": {"stop_time": 3600.0, "output_interval": 0.0001}}
    with pytest.raises(codec.DecodeError) as info:
        codec.loads(messages.SessionCommand, json.dumps(settings))
    assert "samples_per_run = 2,000,000" in str(info.value) and "raise output_interval" in str(info.value)


def test_deep_nesting_and_huge_numbers_are_errors_not_crashes() -> None:
    with pytest.raises(codec.DecodeError):
        codec.loads(messages.SessionCommand, "[" * 100_000 + "]" * 100_000)
    with pytest.raises(codec.DecodeError):
        codec.loads(messages.Ok, '{"type":"ok","v":1,"data":' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(codec.DecodeError, match="out of range"):
        codec.loads(messages.Ok, '{"type":"ok","v":1,"data":' + "9" * 5000 + "}")


def test_non_finite_numbers_are_never_encoded() -> None:
    state = messages.SessionState(SESSION, "running", rtf=float("inf"))
    with pytest.raises(ValueError, match="non-finite number at rtf"):
        codec.dumps(state)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: (
        st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=10), children, max_size=5)
    ),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(value=json_values)
def test_any_json_decodes_or_raises_decode_error(value: typing.Any) -> None:
    for cls in (
        messages.SessionCommand,
        messages.SessionRequest,
        messages.RunRequest,
        model_types.ModelDescription,
    ):
        try:
            codec.from_obj(cls, value)
        except codec.DecodeError:
            pass


@settings(max_examples=300, deadline=None)
@given(
    op=st.sampled_from(["set_params", "set_initial", "set_command", "set_settings", "run", "replay", "seek"]),
    body=st.dictionaries(
        st.sampled_from(["values", "joints", "command", "settings", "name", "v", "recording", "time"]),
        json_values,
    ),
)
def test_mutated_commands_decode_or_name_what_was_wrong(op: str, body: dict[str, typing.Any]) -> None:
    """Every refusal names a field of the message (or says "" for the message as a whole)."""
    payload = {"op": op, **body}
    try:
        codec.from_obj(messages.SessionCommand, payload)
    except codec.DecodeError as exc:
        assert str(exc)
        head = exc.field.split(".")[0].split("[")[0]
        cls = OPS[op]
        required = {f.name for f in msgspec.structs.fields(cls) if f.required} | {"v", "op"}
        assert head == "" or head in payload or head in required, (exc.field, payload)


@settings(max_examples=200, deadline=None)
@given(blob=st.binary(max_size=200))
def test_random_bytes_decode_or_raise_decode_error(blob: bytes) -> None:
    try:
        codec.loads(messages.SessionCommand, blob)
    except codec.DecodeError:
        pass


def test_a_number_out_of_range_in_an_action_argument_is_refused_again_and_again() -> None:
    """msgspec 0.22 corrupted memory decoding 1e999 into a union of a float and a pattern-constrained
    string (an action's argument): a hostile command crashed the proxy on its next message. The
    decode runs in a child process so that a crash fails this test instead of the test runner."""
    script = """
import gc
from simecs.mesh.protocol import codec, messages as m
p = b'{"op":"save_program","v":1,"name":"x","program":{"kind":"task","name":"t","actions":['
p += b'{"kind":"action","primitive":"wait","args":{"duration":1e999}}]}}'
for _ in range(3000):
    try:
        codec.loads(m.SessionCommand, p)
    except codec.DecodeError as exc:
        assert exc.field == "program.actions[0].args.duration", exc.field
    else:
        raise AssertionError("1e999 was taken")
gc.collect()
print("refused 3000 times")
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "refused 3000 times" in done.stdout


def test_an_action_argument_that_is_a_name_is_checked_as_one() -> None:
    good = codec.loads(messages.Action, b'{"kind":"action","primitive":"grasp","args":{"object":"box1"}}')
    assert good.args == {"object": "box1"}
    with pytest.raises(codec.DecodeError) as refused:
        codec.loads(messages.Action, b'{"kind":"action","primitive":"grasp","args":{"object":"two words"}}')
    assert refused.value.field == "args.object" and "not 'two words'" in str(refused.value)


def test_threads_decoding_into_new_types_at_once_do_not_crash_the_process() -> None:
    """msgspec builds a type's decoding information on first use; two threads doing it at once killed
    `simecs sweep` and a viewer reopening two tabs (SIGSEGV). codec makes each first use alone: 60 fresh
    types, 8 threads each, switching as often as the interpreter can (without it, every run crashed)."""
    done = subprocess.run(
        [sys.executable, "-m", "tests.codec_race", "60", "8"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "decoded 60 fresh types" in done.stdout
