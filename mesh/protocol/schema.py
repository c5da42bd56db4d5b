"""The protocol as one machine-readable schema: `docs/protocol.schema.json`, made from the Structs of
messages.py and model.py, the key table of key_table.py, the phase table of phases.py, the commands of
session_commands.py and the frame header of frames.py, so it can never say something the nodes do not do.

    python -m simecs.mesh.protocol.protocol_doc          # rewrite the schema and PROTOCOL.md's tables
    python -m simecs.mesh.protocol.protocol_doc --check  # exit 1 if either is out of date (the tests too)

A client validates a message it sends or receives against `$defs/<Type>`; the key table says which
type travels on which key (`x-simecs-keys`), and `x-simecs-commands` gives each command's reply.
"""

from __future__ import annotations

import json
from typing import Any

import msgspec

from . import (
    frames,
    hil,
    keys,
    node_messages,
    phases,
    plans,
    replies,
    run_messages,
    run_settings,
    session_commands,
    session_state,
)
from . import messages as m
from . import model as md
from .robot_commands import ACTION_ARGS, ACTION_DOC, NAME_ARG

_ARG_SIZES = {0: "number", -1: "one per joint", NAME_ARG: "a name"}

#: Named unions: they get a $defs entry of their own, like the Structs.
UNIONS = {
    "SessionCommand": m.SessionCommand,
    "SessionRequest": m.SessionRequest,
    "RobotCommand": m.RobotCommand,
}
#: Named reply types that are not Structs.
ALIASES = {"RunList": m.RunList}
#: Payload tokens of the key table that are not JSON.
BINARY = {
    "frame": "a binary sample frame (PROTOCOL.md §6): a 40-byte header (x-simecs-frame), then float64 rows",
    "mcap": "the bytes of an MCAP file (docs/RECORDINGS.md)",
    "glb": "a triangle mesh as binary glTF 2.0 (a GLB file: magic 'glTF', version 2)",
    "bundle": "a model directory as a gzip-compressed tar (docs/MODELS.md, 'A host's own models')",
}
REF = "#/$defs/{name}"
#: Base classes that are not messages of their own.
_BASES = ("Command", "SessionCommandBase", "SessionRequestBase", "RobotCommandBase")


def message_types() -> list[type]:
    """Every Struct of the protocol, in the order the modules define them."""
    out: list[type] = []
    modules = (md, replies, run_settings, session_commands, plans, session_state, run_messages, node_messages)
    for module in modules:
        for obj in vars(module).values():
            ours = (
                isinstance(obj, type)
                and issubclass(obj, msgspec.Struct)
                and obj.__module__ == module.__name__
            )
            if ours and obj.__name__ not in _BASES and obj not in out:
                out.append(obj)
    return out


def _type_of(token: str) -> Any:
    if token in UNIONS:
        return UNIONS[token]
    if token in ALIASES:
        return ALIASES[token]
    found = getattr(m, token, None) or getattr(md, token, None)
    if found is None:
        raise KeyError(f"the key table names {token!r}, which is no message type")
    return found


def _with_required_version(defs: dict[str, Any]) -> None:
    """`v` is required on the wire (the Python classes default it for the code that builds them)."""
    for schema in defs.values():
        props = schema.get("properties", {})
        if "v" in props:
            props["v"].pop("default", None)
            schema["required"] = sorted(set(schema.get("required", [])) | {"v"}, key=list(props).index)


def _with_factory_defaults(defs: dict[str, Any]) -> None:
    """A field whose default is made by a factory (a vector, a colour, a list) has that default on
    the wire too: the schema states it, as it does a plain default."""
    classes: dict[str, type] = {}
    pending: list[type] = [msgspec.Struct]
    while pending:
        cls = pending.pop()
        classes.setdefault(cls.__name__, cls)
        pending.extend(cls.__subclasses__())
    for name, schema in defs.items():
        struct = classes.get(name)
        props = schema.get("properties", {})
        if struct is None or not props:
            continue
        for f in msgspec.structs.fields(struct):  # type: ignore[arg-type]
            if f.default_factory is not msgspec.NODEFAULT and f.encode_name in props:
                props[f.encode_name].setdefault("default", msgspec.to_builtins(f.default_factory()))


def _ok(data_schema: dict[str, Any]) -> dict[str, Any]:
    return {
        "type": "object",
        "properties": {"type": {"enum": ["ok"]}, "v": {"enum": [1]}, "data": data_schema},
        "required": ["type", "v", "data"],
        "additionalProperties": False,
    }


def _tokens(text: str, as_reply: bool, types: dict[str, Any]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for token in (t.strip() for t in text.split("|") if t.strip()):
        if token in BINARY:
            out.append({"x-binary": token, "description": BINARY[token]})
        elif token == "per command":
            out.append({"x-per-command": True, "description": "see x-simecs-commands"})
        else:
            ref = types[token]
            out.append(_ok(ref) if as_reply else ref)
    return out


def protocol_schema() -> dict[str, Any]:
    """The whole schema as a JSON value."""
    structs = message_types()
    replies = list({repr(t): t for t in m.REPLIES.values()}.values())
    every = [*structs, *UNIONS.values(), *ALIASES.values(), *replies]
    schemas, defs = msgspec.json.schema_components(every, ref_template=REF)
    schema_of = {repr(t): schema for t, schema in zip(every, schemas, strict=True)}
    for name, t in [*UNIONS.items(), *ALIASES.items()]:
        defs[name] = schema_of[repr(t)]
    _with_required_version(defs)
    _with_factory_defaults(defs)
    types: dict[str, Any] = {name: {"$ref": REF.format(name=name)} for name in defs}
    key_table = [
        {
            "name": k.name,
            "key": k.pattern,
            "kind": k.kind,
            "writer": k.writer,
            **({"answerer": k.answerer} if k.answerer else {}),
            **({"payload": _tokens(k.payload, False, types)} if k.payload else {}),
            **({"reply": _tokens(k.reply, True, types)} if k.reply else {}),
            "meaning": k.meaning,
        }
        for k in keys.KEYS.values()
    ]
    commands = {
        str(cls.__struct_config__.tag): {
            "request": {"$ref": REF.format(name=cls.__name__)},
            "reply": _ok(schema_of[repr(cls.reply)]),
            **({"allowed_in": list(cls.accepted_in)} if cls in session_commands.SESSION_COMMANDS else {}),
        }
        for cls in (*session_commands.SESSION_COMMANDS, *session_commands.SESSION_REQUESTS)
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://simecs.invalid/protocol/v1/schema.json",
        "title": "simecs protocol, version 1",
        "description": (
            "Every JSON message of the simecs protocol ($defs), which key carries which (x-simecs-keys), "
            "each command's reply (x-simecs-commands), the session phases (x-simecs-phases), the action "
            "primitives' arguments (x-simecs-actions), the binary "
            "frame header (x-simecs-frame) and the controller-in-the-loop rows (x-simecs-hil). "
            "Refusals are Zenoh error replies carrying $defs/Error. "
            "Generated from mesh/protocol/ by `python -m simecs.mesh.protocol.protocol_doc`; "
            "docs/PROTOCOL.md explains it."
        ),
        "x-simecs-version": m.VERSION,
        "x-simecs-keys": key_table,
        "x-simecs-commands": commands,
        "x-simecs-phases": {
            "phases": list(phases.PHASES),
            "worker_phases": list(phases.WORKER_PHASES),
            "transitions": phases.TRANSITIONS,
        },
        "x-simecs-actions": {
            name: {
                "does": ACTION_DOC[name],
                "args": {
                    arg: {
                        "size": _ARG_SIZES.get(spec.size, f"{spec.size} numbers"),
                        "unit": spec.unit,
                        "description": spec.description,
                        **({"default": spec.default} if spec.default is not None else {}),
                        "required": spec.default is None and not spec.optional,
                        **(
                            {"exclusiveMinimum" if spec.above_min else "minimum": spec.min}
                            if spec.min > -1e300
                            else {}
                        ),
                        **({"maximum": spec.max} if spec.max < 1e300 else {}),
                    }
                    for arg, spec in args.items()
                },
            }
            for name, args in ACTION_ARGS.items()
        },
        "x-simecs-frame": {
            "byte_order": "little-endian",
            "header_bytes": frames.HEADER.size,
            "header": [
                {"field": name, "offset": offset, "size": size, "meaning": meaning}
                for name, offset, size, meaning in frames.HEADER_FIELDS
            ],
            "data": "float64 values, n_rows x n_cols, row after row",
        },
        "x-simecs-hil": {
            "sensor_row": "1 row: time, then per joint (in the model's joint order) these fields",
            "sensor_joint_fields": [
                {"field": f, "unit": u, "meaning": meaning} for f, u, meaning in hil.SENSOR_JOINT_FIELDS
            ],
            "actuator_row": "1 row: per joint these fields; seq and run_index those of the sensor frame",
            "actuator_joint_fields": [
                {"field": f, "unit": u, "meaning": meaning} for f, u, meaning in hil.ACTUATOR_JOINT_FIELDS
            ],
            "resend_s": hil.RESEND_S,
        },
        "$defs": dict(sorted(defs.items())),
    }


def schema_text() -> str:
    return json.dumps(protocol_schema(), indent=1, ensure_ascii=False) + "\n"
