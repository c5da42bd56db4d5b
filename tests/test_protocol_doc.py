"""docs/PROTOCOL.md documents every key built in mesh/keys.py and every message type of mesh/."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

import pytest
from simecs.mesh import keys, messages, model

DOC = (Path(__file__).resolve().parent.parent / "docs" / "PROTOCOL.md").read_text()

SESSION = keys.new_session_id()
PLACEHOLDERS = {
    "session": SESSION,
    "model_id": "m0del",
    "page": "p4ge",
    "run_id": "r9",
    "name": "n4me",
    "role": "r0le",
    "node_id": "n0de",
    "host_id": "n0de",
}
BACK = {
    SESSION: "<session>",
    "m0del": "<model>",
    "p4ge": "<page>",
    "r9": "<run>",
    "n4me": "<name>",
    "r0le": "<role>",
    "n0de": "<node>",
}


def documented_form(key: str) -> str:
    for value, placeholder in BACK.items():
        key = key.replace(value, placeholder)
    return key


def key_builders() -> list[tuple[str, str]]:
    out = []
    for name, fn in inspect.getmembers(keys, inspect.isfunction):
        if fn.__module__ != keys.__name__ or name in {
            "new_session_id",
            "is_session_id",
            "check_name",
            "session_of",
            "last_chunk",
            "recording_name",
        }:
            continue
        params = inspect.signature(fn).parameters
        args = {p: PLACEHOLDERS[p] for p in params if p in PLACEHOLDERS}
        out.append((name, documented_form(fn(**args))))
        if "run_id" in params and params["run_id"].default is None:
            out.append((f"{name}(run)", documented_form(fn(**{**args, "run_id": "r9"}))))
    return out


@pytest.mark.parametrize(("builder", "key"), key_builders())
def test_every_key_builder_is_documented(builder: str, key: str) -> None:
    assert f"`{key}`" in DOC, f"{builder} builds {key}, which docs/PROTOCOL.md does not list"


CONSTANTS = [
    (n, v)
    for n, v in vars(keys).items()
    if n.isupper() and n != "ROOT" and isinstance(v, str) and v.startswith("simecs")
]


@pytest.mark.parametrize(("name", "key"), CONSTANTS)
def test_every_key_constant_is_documented(name: str, key: str) -> None:
    assert f"`{key}`" in DOC, f"keys.{name} = {key} is not in docs/PROTOCOL.md"


MESSAGES = [
    c
    for mod in (messages, model)
    for c in vars(mod).values()
    if isinstance(c, type) and dataclasses.is_dataclass(c) and c.__module__ == mod.__name__
]


@pytest.mark.parametrize("cls", MESSAGES, ids=lambda c: c.__name__)
def test_every_message_is_documented_with_its_fields(cls: type) -> None:
    tags = [
        f.default for f in dataclasses.fields(cls) if f.name in {"op", "kind"} and isinstance(f.default, str)
    ]
    named = cls.__name__ in DOC or any(f"`{tag}`" in DOC for tag in tags)
    assert named, f"message {cls.__name__} is not in docs/PROTOCOL.md"
    for f in dataclasses.fields(cls):
        if f.name in {"type", "v", "op", "kind"}:
            continue
        assert f.name in DOC, f"field {cls.__name__}.{f.name} is not described in docs/PROTOCOL.md"
