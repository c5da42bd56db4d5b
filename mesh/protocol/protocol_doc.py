"""The tables of docs/PROTOCOL.md that state facts of the protocol, written from the schema.

PROTOCOL.md explains; its tables of keys, commands, phases, message fields and frame header are
generated here between `<!-- generated:NAME -->` and `<!-- end generated:NAME -->` markers, so the
document and the nodes cannot drift apart (tests check the document is up to date).

    python -m simecs.mesh.protocol.protocol_doc          # rewrite the schema and PROTOCOL.md's tables
    python -m simecs.mesh.protocol.protocol_doc --check  # exit 1 if either is out of date (`make lint`)
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import Any

from . import keys, limits, phases
from .primitives import NAME_PATTERN, SESSION_ID_PATTERN
from .schema import protocol_schema, schema_text
from .session_commands import SESSION_COMMANDS, SESSION_REQUESTS


def _names(classes: list[Any]) -> list[str]:
    return [c.__name__ for c in classes]


#: Message tables, in the order the document explains them. Every $defs entry is in exactly one group.
GROUPS: list[tuple[str, list[str]]] = [
    ("replies", ["Ok", "Error"]),
    (
        "library",
        ["ModelList", "ModelSummary", "ModelDescription", "Link", "Shape", "Obstacle", "Parameter"]
        + ["Variable", "InitEquation", "DocPage"],
    ),
    (
        "commands",
        _names(SESSION_COMMANDS)
        + ["SessionCommand", "ProgramEntry", "RunSettings", "RunStarted", "CommandPlan", "PlanStep"]
        + ["SignalPreview", "PlannedMotion"],
    ),
    (
        "robot_commands",
        ["RobotCommand", "JointPath", "PathNode", "CartesianPath", "CartesianNode", "DirectInput", "Action"]
        + ["TableSignal", "StepSignal", "RampSignal", "SineSignal", "ChirpSignal", "Task", "Mission"],
    ),
    (
        "sessions",
        _names(SESSION_REQUESTS)
        + ["SessionRequest", "SessionEntry", "SessionSnapshot", "SessionState"]
        + ["HilStats", "ParamValues", "ObstacleValues", "CommandValue", "RunInfo", "RunList", "Notice"],
    ),
    (
        "runs",
        ["RunRequest", "Accepted", "RunControl", "RunStatus", "RunLayout", "RunContext", "ResultsAttachment"]
        + ["JogInput"],
    ),
    ("nodes", ["NodeStatus", "SimulatorLoad", "RunLoad", "RecordingList", "RecordingInfo"]),
]


def _ref_name(ref: str) -> str:
    return ref.removeprefix("#/$defs/")


def type_text(s: dict[str, Any]) -> str:
    """A JSON-schema fragment as a short type, in the document's notation."""
    if "$ref" in s:
        return _ref_name(s["$ref"])
    if "enum" in s:
        return " \\| ".join(f"`{v!r}`".replace("'", '"') for v in s["enum"])
    if "anyOf" in s:
        return " \\| ".join(type_text(x) for x in s["anyOf"])
    kind = s.get("type")
    if kind == "array":
        return f"[{type_text(s.get('items', {}))}]"
    if kind == "object":
        value = s.get("additionalProperties")
        return f"{{name: {type_text(value)}}}" if isinstance(value, dict) else "object"
    if kind == "string":
        if s.get("pattern") == NAME_PATTERN:
            return "name"
        if s.get("pattern") == SESSION_ID_PATTERN:
            return "session id"
        return "string"
    if kind == "null":
        return "null"
    return str(kind or "any")


def bounds_text(s: dict[str, Any]) -> str:
    parts = []
    for key, sign in (
        ("exclusiveMinimum", ">"),
        ("minimum", ">="),
        ("exclusiveMaximum", "<"),
        ("maximum", "<="),
    ):
        if key in s:
            parts.append(f"{sign} {s[key]:g}")
    for key, word in (("minItems", "items >="), ("maxItems", "items <="), ("minProperties", "entries >=")):
        if key in s:
            parts.append(f"{word} {s[key]}")
    if "maxProperties" in s:
        parts.append(f"entries <= {s['maxProperties']}")
    if "maxLength" in s:
        parts.append(f"length <= {s['maxLength']}")
    items = s.get("items")
    if isinstance(items, dict) and s.get("type") == "array":
        inner = bounds_text(items)
        if inner:
            parts.append(f"each {inner}")
    return ", ".join(parts)


def _cell(text: str) -> str:
    """One table cell: a docstring's line breaks and indentation become single spaces."""
    return " ".join(text.replace("|", "\\|").split())


def message_table(name: str, s: dict[str, Any]) -> str:
    lines = [f"**{name}**" + (f" — {_cell(s['description'])}" if s.get("description") else "")]
    if "anyOf" in s:
        tag = s.get("discriminator", {}).get("propertyName", "")
        members = ", ".join(f"`{_ref_name(x['$ref'])}`" for x in s["anyOf"])
        lines.append(f"\nOne of {members}" + (f", told apart by `{tag}`." if tag else "."))
        return "\n".join(lines) + "\n"
    if s.get("type") != "object":
        return "\n".join([*lines, f"\n{type_text(s)}"]) + "\n"
    lines += ["", "| field | type | required / default | bounds | meaning |", "|---|---|---|---|---|"]
    required = set(s.get("required", []))
    for field, fs in s.get("properties", {}).items():
        need = "required" if field in required else f"default `{_json(fs.get('default'))}`"
        meaning = _cell(fs.get("description", ""))
        lines.append(f"| `{field}` | {type_text(fs)} | {need} | {_cell(bounds_text(fs))} | {meaning} |")
    return "\n".join(lines) + "\n"


def _json(value: Any) -> str:
    import json

    return json.dumps(value, ensure_ascii=False)


def _key_tables() -> str:
    head = (
        "| key | kind | written by | answered by | payload | reply | meaning |\n|---|---|---|---|---|---|---|"
    )
    rows = [
        f"| `{k.pattern}` | {k.kind} | {k.writer} | {k.answerer or '—'} | {_cell(k.payload) or '—'} | "
        f"{_cell(k.reply) or '—'} | {_cell(k.meaning)} |"
        for k in keys.KEYS.values()
    ]
    return "\n".join([head, *rows]) + "\n"


def _command_table(schema: dict[str, Any]) -> str:
    rows = ["| op | request | reply `data` | accepted in phases |", "|---|---|---|---|"]
    for op, entry in schema["x-simecs-commands"].items():
        data = entry["reply"]["properties"]["data"]
        allowed = entry.get("allowed_in")
        if allowed is None:
            where = "— (not a session command)"
        else:
            where = "any open phase" if set(allowed) == set(phases.OPEN) else ", ".join(allowed)
        rows.append(f"| `{op}` | {_ref_name(entry['request']['$ref'])} | {type_text(data)} | {where} |")
    return "\n".join(rows) + "\n"


def _phase_table() -> str:
    rows = ["| event | from → to |", "|---|---|"]
    for event, moves in phases.TRANSITIONS.items():
        pairs = ", ".join(f"{a} → {b}" for a, b in moves.items())
        rows.append(f"| {event} | {pairs} |")
    return "\n".join(rows) + "\n"


def _frame_table(schema: dict[str, Any]) -> str:
    rows = ["| offset | size | field | meaning |", "|---|---|---|---|"]
    for f in schema["x-simecs-frame"]["header"]:
        rows.append(f"| {f['offset']} | {f['size']} | `{f['field']}` | {_cell(f['meaning'])} |")
    rows.append(
        f"| {schema['x-simecs-frame']['header_bytes']} | 8·n_rows·n_cols | data | float64, row after row |"
    )
    return "\n".join(rows) + "\n"


def _hil_table(schema: dict[str, Any]) -> str:
    rows = ["| frame | column | unit | meaning |", "|---|---|---|---|"]
    hil = schema["x-simecs-hil"]
    rows.append("| sensors | `time` | s | simulated time at the start of the period |")
    for f in hil["sensor_joint_fields"]:
        rows.append(f"| sensors, per joint | `{f['field']}` | {f['unit']} | {_cell(f['meaning'])} |")
    for f in hil["actuator_joint_fields"]:
        rows.append(f"| actuators, per joint | `{f['field']}` | {f['unit']} | {_cell(f['meaning'])} |")
    return "\n".join(rows) + "\n"


def _actions_table(schema: dict[str, Any]) -> str:
    rows = ["| primitive | what it does | argument | size | unit | required / default | bounds | meaning |"]
    rows.append("|---" * 8 + "|")
    for name, entry in schema["x-simecs-actions"].items():
        if not entry["args"]:  # a primitive without arguments still has its row
            rows.append(f"| `{name}` | {_cell(entry['does'])} | (none) |  |  |  |  |  |")
            continue
        first = True
        for arg, a in entry["args"].items():
            need = (
                "required"
                if a["required"]
                else (f"default `{_json(a['default'])}`" if "default" in a else "optional")
            )
            bounds = ", ".join(
                f"{op} {_json(a[k])}"
                for k, op in (("exclusiveMinimum", ">"), ("minimum", ">="), ("maximum", "<="))
                if k in a
            )
            head = f"`{name}` | {_cell(entry['does'])}" if first else " | "
            meaning = _cell(a["description"])
            rows.append(f"| {head} | `{arg}` | {a['size']} | {a['unit']} | {need} | {bounds} | {meaning} |")
            first = False
    return "\n".join(rows) + "\n"


def _limits_table() -> str:
    rows = ["| bound | value | enforced by | when exceeded | what it bounds | option |", "|---" * 6 + "|"]
    for lim in limits.LIMITS.values():
        rows.append(
            f"| `{lim.name}` | {limits.human(lim.value, lim.unit)} | {lim.enforcer} | {_cell(lim.refusal)} "
            f"| {_cell(lim.meaning)} | {f'`{lim.flag}`' if lim.flag else ''} |"
        )
    return "\n".join(rows) + "\n"


def sections() -> dict[str, str]:
    """Every generated section of PROTOCOL.md, by marker name."""
    schema = protocol_schema()
    defs = schema["$defs"]
    out = {
        "keys": _key_tables(),
        "commands": _command_table(schema),
        "phases": _phase_table(),
        "frame": _frame_table(schema),
        "hil": _hil_table(schema),
        "limits": _limits_table(),
        "actions": _actions_table(schema),
    }
    for group, names in GROUPS:
        out[f"messages:{group}"] = "\n".join(message_table(n, defs[n]) for n in names)
    return out


def update_document(text: str) -> str:
    """`text` with every generated section rewritten; a marker without a section is an error."""
    made = sections()
    seen: set[str] = set()

    def fill(match: re.Match[str]) -> str:
        name = match.group(2)
        if name not in made:
            raise KeyError(f"PROTOCOL.md has a marker generated:{name} that nothing generates")
        seen.add(name)
        return match.group(1) + made[name] + match.group(4)

    text = re.sub(r"(<!-- generated:([\w:]+) -->\n)(.*?)(<!-- end generated:\2 -->)", fill, text, flags=re.S)
    missing = sorted(set(made) - seen)
    if missing:
        raise KeyError(f"PROTOCOL.md lacks the generated sections {missing}")
    return text


def _repo() -> Path:
    return Path(__file__).resolve().parent.parent.parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m simecs.mesh.protocol.protocol_doc", description=__doc__)
    parser.add_argument("--check", action="store_true", help="only check that the files are up to date")
    parser.add_argument("--root", default=str(_repo()), help="the repository (default: this checkout)")
    args = parser.parse_args(argv)
    docs = Path(args.root) / "docs"
    targets = {
        docs / "protocol.schema.json": schema_text(),
        docs / "PROTOCOL.md": update_document((docs / "PROTOCOL.md").read_text()),
    }
    stale = [path for path, text in targets.items() if not path.exists() or path.read_text() != text]
    if args.check:
        for path in stale:
            print(f"{path} is out of date: run python -m simecs.mesh.protocol.protocol_doc", file=sys.stderr)
        return 1 if stale else 0
    for path in stale:
        path.write_text(targets[path])
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
