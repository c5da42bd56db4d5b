"""A simecs client written from docs/PROTOCOL.md and docs/protocol.schema.json alone: plain zenoh, json,
struct and a JSON Schema validator (`pip install eclipse-zenoh jsonschema`), no simecs code.

    python docs/examples/plain_client.py                      # this machine's private hub (simecs up)
    python docs/examples/plain_client.py tcp/127.0.0.1:7447    # an open hub (simecs up --open)

It creates a session on the Spider, assigns a two-node joint path, runs it as fast as possible while
counting live frames, reloads two variables at full resolution, then replays the run's recording as a
second run of the same session. Every JSON message it sends or receives is validated against the
schema. tests/test_examples.py runs it against real nodes, so this document-as-code cannot rot.
"""

from __future__ import annotations

import json
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

import jsonschema
import zenoh
from joining import join

USER = "stranger"  # on an open hub; the user name is part of every key of the user's sessions
SCHEMA = json.loads((Path(__file__).resolve().parent.parent / "protocol.schema.json").read_text())
SEAL_BYTES = 16  # a binary reply's attachment: its seal, then its JSON description (PROTOCOL.md §4)
#: The frame header as the schema describes it (x-simecs-frame, PROTOCOL.md §6.1): "<4sHHIIQQII".
HEADER = struct.Struct(
    "<"
    + "".join(
        "4s" if f["field"] == "magic" else {2: "H", 4: "I", 8: "Q"}[f["size"]]
        for f in SCHEMA["x-simecs-frame"]["header"]
    )
)


def check(schema: dict[str, Any], value: Any) -> None:
    """Validate a message against a schema fragment that refers to the file's $defs."""
    jsonschema.Draft202012Validator({**schema, "$defs": SCHEMA["$defs"]}).validate(value)


def message(type_name: str, value: Any) -> Any:
    check({"$ref": f"#/$defs/{type_name}"}, value)
    return value


def request(z: zenoh.Session, key: str, body: dict | None = None, timeout: float = 10.0) -> Any:
    """A get with a JSON payload (validated as the command it is); returns `data` of the Ok reply,
    validated against that command's reply schema; raises on an Error reply."""
    reply_schema = None
    if body is not None:
        command = SCHEMA["x-simecs-commands"].get(body.get("op", ""))
        if command is not None:
            check(command["request"], body)
            reply_schema = command["reply"]
    payload = json.dumps(body).encode() if body is not None else None
    errors = []
    for reply in z.get(key, payload=payload, timeout=timeout):
        if reply.ok is not None:
            ok = json.loads(reply.ok.payload.to_bytes())
            if reply_schema is not None:
                check(reply_schema, ok)
            return ok["data"]
        errors.append(message("Error", json.loads(reply.err.payload.to_bytes())))
    raise RuntimeError(errors[0] if errors else f"nobody answered {key}")


def decode_frame(payload: bytes) -> tuple[int, list[list[float]]]:
    magic, _version, flags, _run, _res, _seq, _wall, n_rows, n_cols = HEADER.unpack_from(payload)
    assert magic == b"SMF1"
    values = struct.unpack_from(f"<{n_rows * n_cols}d", payload, HEADER.size)
    return flags, [list(values[r * n_cols : (r + 1) * n_cols]) for r in range(n_rows)]


def run_and_watch(z: zenoh.Session, space: str, command: dict) -> tuple[str, dict, int]:
    """Start a run (`run` or `replay`), count its live frames, wait for its end state."""
    seen: dict[str, Any] = {"frames": 0}
    done = threading.Event()

    def on_live(sample: zenoh.Sample) -> None:
        flags, _rows = decode_frame(sample.payload.to_bytes())
        seen["frames"] += 1
        if flags & 1:
            done.set()

    def on_state(sample: zenoh.Sample) -> None:
        state = message("SessionState", json.loads(sample.payload.to_bytes()))
        if state["run_id"] == seen.get("run") and state["phase"] in ("finished", "aborted", "failed"):
            seen["end"] = state

    def on_layout(sample: zenoh.Sample) -> None:
        seen["layout"] = message("RunLayout", json.loads(sample.payload.to_bytes()))

    with (
        z.declare_subscriber(f"{space}/vars/live", on_live),
        z.declare_subscriber(f"{space}/vars/layout", on_layout),
        z.declare_subscriber(f"{space}/state", on_state),
    ):
        seen["run"] = request(z, f"{space}/cmd", command)["run_id"]
        done.wait(60)
        end = time.monotonic() + 10
        while "end" not in seen and time.monotonic() < end:
            time.sleep(0.05)
    return seen["run"], seen.get("end", {}), seen["frames"]


def main(endpoint: str | None) -> int:
    config, user = join(endpoint, USER)
    with zenoh.open(config) as z:
        models = message("ModelList", request(z, "simecs/library"))["models"]
        print("models:", ", ".join(m["id"] for m in models))
        snap = request(z, f"simecs/u/{user}/sessions", {"op": "create", "v": 1, "model_id": "spider"})
        sid = snap["session"]
        space = f"simecs/u/{user}/sessions/{sid}"  # every key of the session is under it
        cmd = f"{space}/cmd"
        request(z, cmd, {"op": "set_initial", "v": 1, "joints": [0.0] * 7})
        path = {
            "kind": "joint_path",
            "nodes": [
                {"q": [0.4, 0.2, 0, 0, 0, 0, 0], "speed_pct": 100, "acc_pct": 100},
                {"q": [0.0, 0.0, 0, 0, 0, 0, 0], "speed_pct": 50, "acc_pct": 50},
            ],
        }
        request(z, cmd, {"op": "set_command", "v": 1, "command": path})
        settings = {"stop_time": 1.0, "output_interval": 0.01, "pacing": "fast"}
        request(z, cmd, {"op": "set_settings", "v": 1, "settings": settings})

        run_id, end, frames = run_and_watch(z, space, {"op": "run", "v": 1})
        print(f"run {run_id}: {end.get('phase')}, {frames} live frames")

        for reply in z.get(f"{space}/results/{run_id}?vars=joint1.q,joint2.q", timeout=10):
            if reply.ok is None:
                raise RuntimeError(message("Error", json.loads(reply.err.payload.to_bytes())))
            att = message("ResultsAttachment", json.loads(reply.ok.attachment.to_bytes()[SEAL_BYTES:]))
            _flags, rows = decode_frame(reply.ok.payload.to_bytes())
            print(f"{len(rows)} samples of {att['columns']}; last: {rows[-1]}")

        # The recorder keeps the run in the user's recordings as <session>_<run>; replaying it is a run
        # of the session too.
        recording = f"{sid}_{run_id}"
        for _ in range(50):  # the recorder closes the file a moment after the run ends
            try:
                message("RecordingInfo", request(z, f"simecs/u/{user}/recordings/{recording}/info"))
                break
            except RuntimeError:
                time.sleep(0.1)
        replay_id, replayed, _frames = run_and_watch(
            z, space, {"op": "replay", "v": 1, "recording": recording, "speed": 0}
        )
        print(f"replay {replay_id}: {replayed.get('phase')}")
        runs = message("RunList", request(z, f"{space}/results"))
        print(
            "runs:",
            ", ".join(f"{r['run_id']} {r['phase']}" + (" (replay)" if r["recording"] else "") for r in runs),
        )
        request(z, cmd, {"op": "close_session", "v": 1})
    return 0 if end.get("phase") == "finished" and replayed.get("phase") == "finished" else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
