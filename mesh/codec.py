"""Strict JSON codec for the protocol's dataclasses.

Every control message is a dataclass; decoding checks each field against its type hint and raises a
`DecodeError` that names the field path and what was wrong, so an error reply can tell a stranger's
client exactly which part of its message to fix.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

T = TypeVar("T")

#: Upper bounds that keep a hostile message from costing memory or time.
MAX_MESSAGE_BYTES = 4 * 1024 * 1024
MAX_LIST_LEN = 100_000
MAX_STR_LEN = 100_000


class DecodeError(ValueError):
    """A message did not match its declared type; `field` is the dotted path of the culprit."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}" if field else problem)


_hints_cache: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    hints = _hints_cache.get(cls)
    if hints is None:
        hints = get_type_hints(cls)
        _hints_cache[cls] = hints
    return hints


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _decode(tp: Any, value: Any, path: str) -> Any:
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin is Literal:
        allowed = get_args(tp)
        if value not in allowed or type(value) is not type(allowed[0]):
            raise DecodeError(path, f"must be one of {list(allowed)}, got {value!r:.80}")
        return value
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        non_none = [a for a in args if a is not type(None)]
        if len(non_none) == 1:
            return _decode(non_none[0], value, path)
        return _decode_tagged(non_none, value, path)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DecodeError(path, f"must be a number, got {type(value).__name__}")
        value = float(value)
        if not math.isfinite(value):
            raise DecodeError(path, "must be a finite number (NaN and infinity are refused)")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise DecodeError(path, f"must be an integer, got {type(value).__name__}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise DecodeError(path, f"must be true or false, got {type(value).__name__}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise DecodeError(path, f"must be a string, got {type(value).__name__}")
        if len(value) > MAX_STR_LEN:
            raise DecodeError(path, f"string longer than {MAX_STR_LEN} characters")
        return value
    if origin is list or origin is tuple:
        if not isinstance(value, list):
            raise DecodeError(path, f"must be a list, got {type(value).__name__}")
        if len(value) > MAX_LIST_LEN:
            raise DecodeError(path, f"list longer than {MAX_LIST_LEN} items")
        (item_tp, *_rest) = get_args(tp) or (Any,)
        return [_decode(item_tp, v, f"{path}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise DecodeError(path, f"must be an object, got {type(value).__name__}")
        if len(value) > MAX_LIST_LEN:
            raise DecodeError(path, f"object with more than {MAX_LIST_LEN} entries")
        _key_tp, val_tp = get_args(tp)
        return {str(k): _decode(val_tp, v, f"{path}.{k}") for k, v in value.items()}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _decode_dataclass(tp, value, path)
    raise DecodeError(path, f"unsupported type {_type_name(tp)}")  # pragma: no cover - a bug in mesh/


def _decode_tagged(options: list[Any], value: Any, path: str) -> Any:
    """Unions of dataclasses are told apart by their `kind` (or `type`) field."""
    if not isinstance(value, dict):
        raise DecodeError(path, f"must be an object, got {type(value).__name__}")
    for tag in ("kind", "type", "op"):
        if tag in value:
            allowed: list[str] = []
            for cls in options:
                if isinstance(cls, type) and dataclasses.is_dataclass(cls):
                    field = next((f for f in dataclasses.fields(cls) if f.name == tag), None)
                    if field is None or not isinstance(field.default, str):
                        continue
                    if field.default == value[tag]:
                        return _decode_dataclass(cls, value, path)
                    allowed.append(field.default)
            raise DecodeError(
                f"{path}.{tag}" if path else tag,
                f"unknown {tag} {value[tag]!r:.60} (known: {', '.join(allowed)})",
            )
    raise DecodeError(path, "object has no 'kind' to tell which variant it is")


def _decode_dataclass(cls: type[T], value: Any, path: str) -> T:
    if not isinstance(value, dict):
        raise DecodeError(path, f"must be an object, got {type(value).__name__}")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = [k for k in value if k not in fields]
    if unknown:
        where = f"{path}.{unknown[0]}" if path else str(unknown[0])
        raise DecodeError(where, f"unknown field (allowed: {', '.join(sorted(fields))})")
    kwargs = {}
    for name, f in fields.items():
        sub = f"{path}.{name}" if path else name
        if name in value:
            kwargs[name] = _decode(hints[name], value[name], sub)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise DecodeError(sub, "missing required field")
    version = fields.get("v")
    if version is not None and "v" in kwargs and kwargs["v"] != version.default:
        raise DecodeError(
            f"{path}.v" if path else "v",
            f"version {kwargs['v']} not supported (this node speaks {version.default})",
        )
    obj = cls(**kwargs)
    check = getattr(obj, "validate", None)
    if check is not None:
        try:
            check()
        except DecodeError as exc:
            raise DecodeError(
                f"{path}.{exc.field}" if path and exc.field else exc.field or path, exc.problem
            ) from None
    return obj


def from_obj(cls: type[T], value: Any) -> T:
    """Decode an already-parsed JSON value into `cls`, strictly."""
    return _decode(cls, value, "")


def loads(cls: type[T], payload: bytes | str) -> T:
    """Parse and decode one JSON message into `cls`; every failure is a `DecodeError`."""
    if isinstance(payload, bytes | bytearray | memoryview):
        if len(payload) > MAX_MESSAGE_BYTES:
            raise DecodeError("", f"message larger than {MAX_MESSAGE_BYTES} bytes")
        try:
            text = bytes(payload).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise DecodeError("", f"not UTF-8 text: {exc.reason} at byte {exc.start}") from None
    else:
        text = payload
    try:
        value = json.loads(text, parse_constant=_refuse_constant)
    except DecodeError:
        raise
    except (json.JSONDecodeError, RecursionError) as exc:
        raise DecodeError("", f"not valid JSON: {exc}") from None
    return from_obj(cls, value)


def _refuse_constant(name: str) -> Any:
    raise DecodeError("", f"{name} is not valid JSON (numbers must be finite)")


def to_obj(obj: Any) -> Any:
    """Plain JSON value of a dataclass tree (fields in declaration order)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_obj(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, list | tuple):
        return [to_obj(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): to_obj(v) for k, v in obj.items()}
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ValueError("refusing to encode a non-finite number")
    if hasattr(obj, "tolist"):  # numpy scalars and arrays
        return to_obj(obj.tolist())
    return obj


def dumps(obj: Any) -> bytes:
    """Encode a dataclass tree as compact UTF-8 JSON."""
    return json.dumps(to_obj(obj), separators=(",", ":"), allow_nan=False).encode("utf-8")


__all__ = ["DecodeError", "dumps", "loads", "from_obj", "to_obj"]
