"""Codec round trips for every message type, and hostile input that must give named errors."""

from __future__ import annotations

import dataclasses
import json
import typing

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simecs.mesh import codec, messages
from simecs.mesh import model as model_types

MESSAGE_TYPES = [
    obj
    for obj in vars(messages).values()
    if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == messages.__name__
]


def example(tp: typing.Any) -> typing.Any:
    """A valid example value of a type, built from its hints."""
    origin = typing.get_origin(tp)
    if tp is float:
        return 1.0
    if tp is int:
        return 1
    if tp is str:
        return "x"
    if tp is bool:
        return True
    if tp is typing.Any:
        return {"a": [1, 2]}
    if origin is typing.Literal:
        return typing.get_args(tp)[0]
    if origin in (typing.Union, __import__("types").UnionType):
        return example(next(a for a in typing.get_args(tp) if a is not type(None)))
    if origin is list:
        return [example(typing.get_args(tp)[0])] * 3
    if origin is dict:
        return {"k": example(typing.get_args(tp)[1])}
    if dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp)
        kwargs = {}
        for f in dataclasses.fields(tp):
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                kwargs[f.name] = example(hints[f.name])
        return tp(**kwargs)
    raise AssertionError(f"no example for {tp}")


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.__name__)
def test_round_trip(cls: type) -> None:
    obj = example(cls)
    if hasattr(obj, "validate"):
        try:
            obj.validate()
        except codec.DecodeError:
            pytest.skip("example value not valid for this type's bounds")
    assert codec.loads(cls, codec.dumps(obj)) == obj


def test_every_standalone_message_carries_version() -> None:
    for cls in MESSAGE_TYPES:
        names = {f.name for f in dataclasses.fields(cls)}
        if "type" in names or "op" in names:
            assert "v" in names, f"{cls.__name__} has no version field"


def test_model_description_round_trip() -> None:
    desc = example(model_types.ModelDescription)
    assert codec.loads(model_types.ModelDescription, codec.dumps(desc)) == desc


@pytest.mark.parametrize(
    ("payload", "field", "words"),
    [
        (b'{"op":"explode"}', "op", "unknown op"),
        (b'{"op":"set_params","values":{"a":"1"}}', "values.a", "must be a number"),
        (b'{"op":"set_params","values":{"a":NaN}}', "", "NaN"),
        (b'{"op":"set_params","values":{"a":1e999}}', "values.a", "finite"),
        (b'{"op":"set_params"}', "values", "missing required field"),
        (b'{"op":"run","extra":1}', "extra", "unknown field"),
        (b'{"op":"run","v":7}', "v", "version 7 not supported"),
        (b'{"op":"set_initial","joints":[true]}', "joints[0]", "must be a number"),
        (b'{"op":"set_command","command":{"kind":"teleport"}}', "command.kind", "unknown kind"),
        (
            b'{"op":"set_command","command":{"kind":"joint_path","nodes":[{"q":[0],"acc_pct":0}]}}',
            "command.nodes[0].acc_pct",
            "percentage",
        ),
        (b'{"op":"set_settings","settings":{"pacing":"warp"}}', "settings.pacing", "must be one of"),
        (b'{"op":"set_settings","settings":{"output_interval":0}}', "settings.output_interval", "outside"),
        (b"\xff\xfe", "", "UTF-8"),
        (b"[]", "", "must be an object"),
        (b"{", "", "not valid JSON"),
        (b'"run"', "", "must be an object"),
    ],
)
def test_hostile_commands_name_the_field(payload: bytes, field: str, words: str) -> None:
    with pytest.raises(codec.DecodeError) as info:
        codec.loads(messages.Command, payload)
    assert info.value.field == field
    assert words in str(info.value)


def test_oversized_message_refused() -> None:
    big = b'{"op":"set_initial","joints":[' + b"0," * (codec.MAX_MESSAGE_BYTES // 2) + b"0]}"
    with pytest.raises(codec.DecodeError, match="larger than"):
        codec.loads(messages.Command, big)


def test_long_lists_refused() -> None:
    payload = json.dumps({"op": "set_initial", "joints": [0] * (codec.MAX_LIST_LEN + 1)})
    with pytest.raises(codec.DecodeError, match="list longer"):
        codec.loads(messages.Command, payload)


def test_deep_nesting_is_an_error_not_a_crash() -> None:
    with pytest.raises(codec.DecodeError):
        codec.loads(messages.Command, "[" * 100_000 + "]" * 100_000)


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
    for cls in (messages.Command, messages.SessionRequest, messages.RunRequest, model_types.ModelDescription):
        try:
            codec.from_obj(cls, value)
        except codec.DecodeError:
            pass


@settings(max_examples=200, deadline=None)
@given(
    op=st.sampled_from(["set_params", "set_initial", "set_command", "set_settings", "run", "save_param_set"]),
    body=st.dictionaries(
        st.sampled_from(["values", "joints", "command", "settings", "name", "v"]), json_values
    ),
)
def test_mutated_commands_decode_or_raise_decode_error(op: str, body: dict[str, typing.Any]) -> None:
    try:
        codec.from_obj(messages.Command, {"op": op, **body})
    except codec.DecodeError as exc:
        assert str(exc)


@settings(max_examples=200, deadline=None)
@given(blob=st.binary(max_size=200))
def test_random_bytes_decode_or_raise_decode_error(blob: bytes) -> None:
    try:
        codec.loads(messages.Command, blob)
    except codec.DecodeError:
        pass
