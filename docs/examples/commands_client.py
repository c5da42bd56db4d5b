"""A Cartesian line and a saved task, from docs/PROTOCOL.md and docs/protocol.schema.json alone: plain
zenoh, json, struct and a JSON Schema validator (`pip install eclipse-zenoh jsonschema`), no simecs code.

    python docs/examples/commands_client.py                      # this machine's private hub (simecs up)
    python docs/examples/commands_client.py tcp/127.0.0.1:7447    # an open hub (simecs up --open)

It creates a session on the Spider, places the arm, asks the server where that puts the tool (the
plan of a joint path that stays put), moves the tool 10 cm along x and 5 cm down on a straight line,
reads the tool's last pose back at full resolution, then saves a task (line back, wait, joint move),
loads it from the library, runs it and prints which action the session state said was running.
tests/test_examples.py runs it against real nodes.
"""

from __future__ import annotations

import json
import math
import struct
import sys
import threading
from pathlib import Path
from typing import Any

import jsonschema
import zenoh
from joining import join

USER = "integrator"
SCHEMA = json.loads((Path(__file__).resolve().parent.parent / "protocol.schema.json").read_text())
SEAL_BYTES = 16  # a binary reply's attachment: its seal, then its JSON description (PROTOCOL.md §4)
HEADER = struct.Struct(
    "<"
    + "".join(
        "4s" if f["field"] == "magic" else {2: "H", 4: "I", 8: "Q"}[f["size"]]
        for f in SCHEMA["x-simecs-frame"]["header"]
    )
)
POSTURE = [0.5, 0.2, -0.3, -0.5, -0.3, -0.2, 0.7]  # rad, one per joint of the Spider


def check(schema: dict[str, Any], value: Any) -> None:
    jsonschema.Draft202012Validator({**schema, "$defs": SCHEMA["$defs"]}).validate(value)


def request(z: zenoh.Session, key: str, body: dict | None = None, timeout: float = 30.0) -> Any:
    """`data` of the Ok reply (request and reply validated against the schema); raises on an Error."""
    reply_schema = None
    if body is not None and body.get("op") in SCHEMA["x-simecs-commands"]:
        command = SCHEMA["x-simecs-commands"][body["op"]]
        check(command["request"], body)
        reply_schema = command["reply"]
    payload = json.dumps(body).encode() if body is not None else None
    for reply in z.get(key, payload=payload, timeout=timeout):
        if reply.ok is not None:
            ok = json.loads(reply.ok.payload.to_bytes())
            if reply_schema is not None:
                check(reply_schema, ok)
            return ok["data"]
        error = json.loads(reply.err.payload.to_bytes())
        check({"$ref": "#/$defs/Error"}, error)
        raise RuntimeError(f"{error['code']} ({error['field']}): {error['message']}")
    raise RuntimeError(f"nobody answered {key}")


def last_row(z: zenoh.Session, key: str) -> dict[str, float]:
    for reply in z.get(key, timeout=10):
        if reply.ok is None:
            raise RuntimeError(reply.err.payload.to_bytes().decode())
        columns = json.loads(reply.ok.attachment.to_bytes()[SEAL_BYTES:])["columns"]
        payload = reply.ok.payload.to_bytes()
        *_, n_rows, n_cols = HEADER.unpack_from(payload)
        values = struct.unpack_from(f"<{n_cols}d", payload, HEADER.size + 8 * n_cols * (n_rows - 1))
        return dict(zip(columns, values, strict=True))
    raise RuntimeError(f"nobody answered {key}")


def run(z: zenoh.Session, space: str) -> tuple[str, list[tuple[str, str]]]:
    """Run the session's command to its end; the run id and the (task, action) pairs the state named."""
    seen: dict[str, Any] = {"steps": []}
    ended = threading.Event()

    def on_state(sample: zenoh.Sample) -> None:
        state = json.loads(sample.payload.to_bytes())
        check({"$ref": "#/$defs/SessionState"}, state)
        if state["run_id"] != seen.get("run"):
            return
        step = (state["task"], state["action"])
        if state["step"] and (not seen["steps"] or seen["steps"][-1] != step):
            seen["steps"].append(step)
        if state["phase"] in ("finished", "aborted", "failed"):
            seen["phase"] = state["phase"]
            ended.set()

    with z.declare_subscriber(f"{space}/state", on_state):
        seen["run"] = request(z, f"{space}/cmd", {"op": "run", "v": 1})["run_id"]
        ended.wait(120)
    if seen.get("phase") != "finished":
        raise RuntimeError(f"run {seen['run']} ended {seen.get('phase', 'never')}")
    return seen["run"], seen["steps"]


def main(endpoint: str | None) -> int:
    config, user = join(endpoint, USER)
    with zenoh.open(config) as z:
        snap = request(z, f"simecs/u/{user}/sessions", {"op": "create", "v": 1, "model_id": "spider"})
        space = f"simecs/u/{user}/sessions/{snap['session']}"
        cmd = f"{space}/cmd"
        request(z, cmd, {"op": "set_initial", "v": 1, "joints": POSTURE})
        stay = {"kind": "joint_path", "nodes": [{"q": POSTURE}]}
        start = request(z, cmd, {"op": "set_command", "v": 1, "command": stay})["start_pose"]
        x, y, zz, roll, pitch, yaw = start
        print("tool at", [round(v, 4) for v in start])

        target = [x + 0.10, y, zz - 0.05]
        line = {
            "kind": "cartesian_path",
            "nodes": [{"position": target, "rpy": [roll, pitch, yaw], "move": "lin"}],
        }
        plan = request(z, cmd, {"op": "set_command", "v": 1, "command": line})
        settings = {"stop_time": round(plan["duration"] + 1.0, 3), "output_interval": 0.002, "pacing": "fast"}
        request(z, cmd, {"op": "set_settings", "v": 1, "settings": settings})
        run_id, _ = run(z, space)
        end = last_row(z, f"{space}/results/{run_id}?vars=pose.tool.x,pose.tool.y,pose.tool.z")
        miss = math.dist(target, [end["pose.tool.x"], end["pose.tool.y"], end["pose.tool.z"]])
        print(f"line {run_id}: {plan['duration']:.3f} s planned, ends {miss * 1000:.2f} mm from its target")

        task = {
            "kind": "task",
            "name": "back",
            "actions": [
                {
                    "kind": "action",
                    "primitive": "move_linear",
                    "name": "retreat",
                    "args": {"position": [x, y, zz]},
                },
                {"kind": "action", "primitive": "wait", "args": {"duration": 0.2}},
                {"kind": "action", "primitive": "move_joints", "name": "settle", "args": {"q": POSTURE}},
            ],
        }
        request(z, cmd, {"op": "save_program", "v": 1, "name": "back", "program": task})
        saved = request(z, cmd, {"op": "list_programs", "v": 1, "kind": "task"})
        loaded = request(z, cmd, {"op": "load_program", "v": 1, "kind": "task", "name": "back"})
        print("saved:", [p["name"] for p in saved])
        # The line starts where the last run ended: from the session's initial pose plus the line.
        request(z, cmd, {"op": "set_initial", "v": 1, "joints": plan["final_q"]})
        plan = request(z, cmd, {"op": "set_command", "v": 1, "command": loaded})
        settings["stop_time"] = round(plan["duration"] + 0.5, 3)
        settings["pacing"] = "realtime"  # so the state shows every step as it runs
        request(z, cmd, {"op": "set_settings", "v": 1, "settings": settings})
        run_id, steps = run(z, space)
        print(f"task {run_id}: finished; steps seen: {', '.join(a for _, a in steps)}")
        request(z, cmd, {"op": "close_session", "v": 1})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
