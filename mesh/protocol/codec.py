"""Strict JSON codec for the protocol's msgspec Structs.

Decoding refuses unknown fields, wrong types, values out of the bounds the types declare, a message
without its `v` (or, for a single message type, without its tag) and any text that is not valid
Unicode, and raises a `DecodeError` naming the field path (`settings.stop_time`, `values.joint1.q`,
`command.nodes[0].acc_pct`; "" means the whole message), so an error reply tells a stranger's client
exactly which part of its message to fix. Encoding refuses non-finite numbers.
"""

from __future__ import annotations

import json
import math
import re
import threading
import types
import typing
from typing import Any, TypeVar, Union, get_args, get_origin

import msgspec

from .limits import limit
from .primitives import NAME_PATTERN, SESSION_ID_PATTERN, FieldProblem

T = TypeVar("T")

#: Largest JSON message a node decodes: a hostile message costs at most this much.
MAX_MESSAGE_BYTES = limit("message_bytes")


class DecodeError(ValueError):
    """A message did not match its declared type; `field` is the dotted path of the culprit ("" =
    the whole message)."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}" if field else problem)


# -- encoding --------------------------------------------------------------------------------------
def _encode_numpy(obj: Any) -> Any:
    """numpy scalars and arrays (simulation results) as plain numbers and lists."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"cannot encode {type(obj).__name__} as protocol JSON")


_encoder = msgspec.json.Encoder(enc_hook=_encode_numpy)


def dumps(obj: Any) -> bytes:
    """Compact UTF-8 JSON of a message (or any value of message types)."""
    data = _encoder.encode(obj)
    # msgspec writes a non-finite float as null: a null is rare in our messages, so look closer then.
    if b"null" in data:
        _refuse_non_finite(msgspec.to_builtins(obj, enc_hook=_encode_numpy), "")
    return data


def _refuse_non_finite(value: Any, path: str) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"refusing to encode a non-finite number at {path or 'the top'}")
    if isinstance(value, dict):
        for k, v in value.items():
            _refuse_non_finite(v, f"{path}.{k}" if path else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _refuse_non_finite(v, f"{path}[{i}]")


def to_obj(obj: Any) -> Any:
    """Plain JSON value (dicts, lists, numbers, strings) of a message."""
    return msgspec.to_builtins(obj, enc_hook=_encode_numpy)


# -- decoding --------------------------------------------------------------------------------------
# msgspec builds a Struct type's decoding information on its first use, running Python code (the
# annotations' evaluation) while the half-built information is already attached to the class: a second
# thread decoding into the same type then reads it and the process dies (SIGSEGV, msgspec 0.22; seen
# in `simecs sweep` and in a viewer reopening two tabs). So the first use of each type is made here,
# one thread at a time, before any decoding into it.
_types_lock = threading.Lock()
_decoders: dict[Any, msgspec.json.Decoder[Any]] = {}


def _decoder(tp: Any) -> msgspec.json.Decoder[Any]:  # tp: a class or a union, both hashable
    """The decoder of `tp`, made (with msgspec's information for every type within it) once."""
    found = _decoders.get(tp)
    if found is None:
        with _types_lock:
            found = _decoders.get(tp)
            if found is None:
                found = _decoders[tp] = msgspec.json.Decoder(tp)
    return found


Payload = bytes | bytearray | memoryview | str


@typing.overload
def loads(tp: type[T], payload: Payload) -> T: ...
@typing.overload
def loads(tp: Any, payload: Payload) -> Any: ...
def loads(tp: Any, payload: Payload) -> Any:
    """Parse and decode one JSON message into `tp` (a Struct or a union of them), strictly; every
    failure is a DecodeError."""
    if isinstance(payload, str):
        payload = payload.encode("utf-8", "surrogatepass")
    if len(payload) > MAX_MESSAGE_BYTES:
        raise DecodeError(
            "", f"message of {len(payload)} bytes is larger than message_bytes = {MAX_MESSAGE_BYTES} bytes"
        )
    try:  # the whole text, unknown fields included: nothing that is not UTF-8 gets through
        bytes(payload).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DecodeError("", f"not UTF-8 text: {exc.reason} at byte {exc.start}") from None
    try:
        obj = _decoder(typing.cast(Any, tp)).decode(payload)
    except msgspec.ValidationError as exc:
        raise _validation_error(tp, exc, lambda: json.loads(bytes(payload))) from None
    except msgspec.DecodeError as exc:
        raise DecodeError("", _syntax_problem(bytes(payload), str(exc))) from None
    except RecursionError:
        raise DecodeError("", "the message is nested too deeply") from None
    _require_envelope(tp, msgspec.json.decode(payload, type=dict[str, msgspec.Raw]))
    return obj


@typing.overload
def from_obj(tp: type[T], value: Any) -> T: ...
@typing.overload
def from_obj(tp: Any, value: Any) -> Any: ...
def from_obj(tp: Any, value: Any) -> Any:
    """Decode an already-parsed JSON value into `tp`, as strictly as `loads`."""
    _decoder(tp)  # msgspec's information for tp is complete before convert reads it
    try:
        obj = msgspec.convert(value, tp)
    except msgspec.ValidationError as exc:
        raise _validation_error(tp, exc, lambda: value) from None
    except RecursionError:
        raise DecodeError("", "the message is nested too deeply") from None
    if isinstance(value, dict):
        _require_envelope(tp, value)
    return obj


def _require_envelope(tp: Any, top: dict[str, Any]) -> None:
    """`v` is required on the wire (the classes give it a default for the code that builds them), and
    so is the tag of a single message type (msgspec requires it only in unions)."""
    classes = [c for c in _members(tp) if isinstance(c, type) and issubclass(c, msgspec.Struct)]
    if not classes:
        return
    config = classes[0].__struct_config__
    if len(classes) == 1 and config.tag_field is not None and config.tag_field not in top:
        raise DecodeError(config.tag_field, f"missing required field (it must be {config.tag!r})")
    if any("v" in c.__struct_fields__ for c in classes) and "v" not in top:
        raise DecodeError("v", "missing required field (the protocol version, 1)")


# -- naming what was wrong ------------------------------------------------------------------------------
_AT = re.compile(r"^(?P<problem>.*?) - at `(?P<path>[^`]*)`$", re.S)
_KEY_AT = re.compile(r"^(?P<problem>.*?) - at `key` in `(?P<path>[^`]*)`$", re.S)
_SEGMENT = re.compile(r"\.([^.\[\]]+)|\[(\d+)\]|\[(\.\.\.)\]")
_WORDS = {
    "float": "a number",
    "int": "an integer",
    "str": "a string",
    "bool": "true or false",
    "array": "a list",
    "object": "an object",
    "null": "null",
}


def _validation_error(tp: Any, exc: msgspec.ValidationError, raw: typing.Callable[[], Any]) -> DecodeError:
    text = str(exc)
    key_error = _KEY_AT.match(text)
    at = key_error or _AT.match(text)
    problem, path = (at.group("problem"), at.group("path")) if at else (text, "$")
    try:
        field, at_type = _resolve_path(tp, raw(), path, key_error is not None)
    except Exception:  # locating is a courtesy: never let it hide the refusal itself
        field, at_type = path.removeprefix("$").lstrip("."), None
    cause = exc.__cause__
    if isinstance(cause, FieldProblem):
        return DecodeError(f"{field}.{cause.field}" if field else cause.field, cause.problem)
    missing = re.match(r"Object missing required field `(\w+)`", problem)
    if missing:
        return DecodeError(_join(field, missing.group(1)), "missing required field")
    unknown = re.match(r"Object contains unknown field `([^`]*)`", problem)
    if unknown:
        return DecodeError(_join(field, unknown.group(1)), "unknown field")
    return DecodeError(field, _readable(tp, at_type, problem, field))


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _readable(tp: Any, at_type: Any, problem: str, field: str) -> str:
    """msgspec's wording, in the protocol's terms."""
    bad_value = re.match(r"Invalid (?:enum )?value (.+)$", problem)
    allowed = get_args(_strip(at_type)) if get_origin(_strip(at_type)) is typing.Literal else ()
    if bad_value and allowed and not (field == "v" or field.endswith(".v")):
        return f"must be one of {', '.join(map(str, allowed))}; got {bad_value.group(1)}"
    if bad_value:
        if field == "v" or field.endswith(".v"):
            return f"version {bad_value.group(1)} not supported (this node speaks 1)"
        name = field.rsplit(".", 1)[-1]
        known = _tags_for(tp, name)
        if known:
            return f"unknown {name} {bad_value.group(1)} (known: {', '.join(known)})"
        return f"{bad_value.group(1)} is not allowed here"
    if NAME_PATTERN in problem:
        return "must be 1-64 characters of letters, digits, '_', '-', '.' (not starting with '_', '-', '.')"
    if SESSION_ID_PATTERN in problem:
        return "must be a session id (22 characters of A-Z a-z 0-9 _ -, the first a letter or digit)"
    if problem == "Number out of range":
        return "number out of range (numbers must be finite, and integers fit in 64 bits)"
    problem = re.sub(r"`(\w+)`", lambda m: _WORDS.get(m.group(1), m.group(1)), problem)
    problem = problem.replace("Expected ", "must be ", 1)
    return problem


def _syntax_problem(payload: bytes, text: str) -> str:
    lone = re.search(
        rb"\\u[dD][89abAB][0-9a-fA-F]{2}(?!\\u[dD][c-fC-F])|(?<![0-9a-fA-F]{4})\\u[dD][c-fC-F][0-9a-fA-F]{2}",
        payload,
    )
    if lone is not None:
        return (
            f"a string holds the lone UTF-16 surrogate {lone.group().decode()}: not valid Unicode "
            "(texts must be valid UTF-8)"
        )
    if "invalid character" in text or "truncated" in text or "malformed" in text:
        return f"not valid JSON: {text}"
    if "utf" in text.lower():
        return f"not UTF-8 text: {text}"
    return f"not valid JSON: {text}"


# -- walking a type along a path (to name a dict key, or list the variants of a union) ------------
def _strip(tp: Any) -> Any:
    while get_origin(tp) is typing.Annotated:
        tp = get_args(tp)[0]
    return tp


def _members(tp: Any) -> list[Any]:
    tp = _strip(tp)
    if get_origin(tp) in (Union, types.UnionType):
        return [_strip(a) for a in get_args(tp)]
    return [tp]


def _pick(tp: Any, raw: Any) -> Any:
    """The member of a union that `raw` is meant to be (by its tag), or the type itself."""
    options = [m for m in _members(tp) if m is not type(None)]
    if len(options) == 1:
        return options[0]
    for option in options:
        config = getattr(option, "__struct_config__", None)
        if config is not None and isinstance(raw, dict) and raw.get(config.tag_field) == config.tag:
            return option
    return options[0] if options else tp


def _field_type(cls: Any, name: str) -> Any:
    for f in msgspec.structs.fields(cls):
        if f.encode_name == name:
            return f.type
    raise KeyError(name)


def _tags_for(tp: Any, name: str) -> list[str]:
    """The tags allowed where a union told apart by field `name` is expected (searched in `tp`)."""
    seen: set[int] = set()

    def search(t: Any) -> list[str]:
        t = _strip(t)
        if id(t) in seen:
            return []
        seen.add(id(t))
        structs = [m for m in _members(t) if isinstance(m, type) and issubclass(m, msgspec.Struct)]
        tags = [str(m.__struct_config__.tag) for m in structs if m.__struct_config__.tag_field == name]
        if tags:
            return tags
        for m in structs:
            for f in msgspec.structs.fields(m):
                found = search(f.type)
                if found:
                    return found
        for m in _members(t):
            for arg in get_args(m):
                found = search(arg)
                if found:
                    return found
        return []

    return search(tp)


def _resolve_path(tp: Any, raw: Any, path: str, key_error: bool) -> tuple[str, Any]:
    """msgspec's `$.values[...].q[0]` as `values.<the key>.q[0]`: dict keys are found by checking
    each entry of the dict against its value (or key) type."""
    out = ""
    tp = _pick(tp, raw)
    segments = [(m.group(1), m.group(2), m.group(3)) for m in _SEGMENT.finditer(path.removeprefix("$"))]
    for name, index, dots in segments:
        tp = _pick(tp, raw)
        if name is not None:
            tp, raw = _field_type(tp, name), raw[name]
            out = _join(out, name)
        elif index is not None:
            tp, raw = get_args(_strip(tp))[0], raw[int(index)]
            out += f"[{index}]"
        elif dots is not None:
            key_tp, value_tp = get_args(_strip(tp))
            key = _first_bad(raw, value_tp)
            tp, raw = value_tp, raw[key]
            out = _join(out, key)
    if key_error:
        key_tp = get_args(_strip(_pick(tp, raw)))[0]
        bad = next((k for k in raw if not _fits(k, key_tp)), None)
        if bad is not None:
            out = _join(out, bad)
    return out, tp


def _fits(value: Any, tp: Any) -> bool:
    """Whether a JSON value decodes as `tp` (numbers out of range, read as infinities, do not)."""
    try:
        msgspec.convert(value, tp)
        _refuse_non_finite(value, "")
    except (msgspec.ValidationError, ValueError):
        return False
    return True


def _first_bad(mapping: dict[str, Any], value_tp: Any) -> str:
    return next(k for k, v in mapping.items() if not _fits(v, value_tp))


__all__ = ["DecodeError", "dumps", "loads", "from_obj", "to_obj", "MAX_MESSAGE_BYTES"]
