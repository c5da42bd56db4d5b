"""A simecs client written from docs/PROTOCOL.md alone: plain zenoh, json and struct, no simecs code.

    python docs/examples/plain_client.py tcp/127.0.0.1:7447

It creates a session on the Spider, assigns a two-node joint path, runs it as fast as possible while
counting live frames, then reloads two variables at full resolution and prints their last values.
tests/test_examples.py runs it against real nodes, so this document-as-code cannot rot.
"""

from __future__ import annotations

import json
import struct
import sys
import threading
import time

import zenoh

HEADER = struct.Struct("<4sHHIIQQII")  # PROTOCOL.md §6.1


def request(z: zenoh.Session, key: str, body: dict | None = None, timeout: float = 10.0) -> object:
    """A get with a JSON payload; returns `data` of the first Ok reply, raises on an Error reply."""
    payload = json.dumps(body).encode() if body is not None else None
    errors = []
    for reply in z.get(key, payload=payload, timeout=timeout):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())["data"]
        errors.append(json.loads(reply.err.payload.to_bytes()))
    raise RuntimeError(errors[0] if errors else f"nobody answered {key}")


def decode_frame(payload: bytes) -> tuple[int, list[list[float]]]:
    magic, _version, flags, _run, _res, _seq, _wall, n_rows, n_cols = HEADER.unpack_from(payload)
    assert magic == b"SMF1"
    values = struct.unpack_from(f"<{n_rows * n_cols}d", payload, HEADER.size)
    return flags, [list(values[r * n_cols : (r + 1) * n_cols]) for r in range(n_rows)]


def main(endpoint: str) -> int:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(config) as z:
        models = request(z, "simecs/library")["models"]
        print("models:", ", ".join(m["id"] for m in models))
        snap = request(
            z, "simecs/sessions", {"op": "create", "v": 1, "user": "stranger", "model_id": "spider"}
        )
        sid = snap["session"]
        cmd = f"simecs/{sid}/cmd"
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

        live = {"frames": 0}
        done = threading.Event()

        def on_live(sample: zenoh.Sample) -> None:
            flags, _rows = decode_frame(sample.payload.to_bytes())
            live["frames"] += 1
            if flags & 1:
                done.set()

        def on_state(sample: zenoh.Sample) -> None:
            state = json.loads(sample.payload.to_bytes())
            if state["phase"] in ("finished", "aborted", "failed"):
                live["end"] = state

        with (
            z.declare_subscriber(f"simecs/{sid}/vars/live", on_live),
            z.declare_subscriber(f"simecs/{sid}/state", on_state),
        ):
            run_id = request(z, cmd, {"op": "run", "v": 1})["run_id"]
            done.wait(60)
            end = time.monotonic() + 10
            while "end" not in live and time.monotonic() < end:
                time.sleep(0.05)
        print(f"run {run_id}: {live.get('end', {}).get('phase')}, {live['frames']} live frames")

        for reply in z.get(f"simecs/{sid}/results/{run_id}?vars=joint1.q,joint2.q", timeout=10):
            if reply.ok is None:
                raise RuntimeError(json.loads(reply.err.payload.to_bytes()))
            columns = json.loads(reply.ok.attachment.to_bytes())["columns"]
            _flags, rows = decode_frame(reply.ok.payload.to_bytes())
            print(f"{len(rows)} samples of {columns}; last: {rows[-1]}")
        request(z, cmd, {"op": "close_session", "v": 1})
    return 0 if live.get("end", {}).get("phase") == "finished" else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "tcp/127.0.0.1:7447"))
