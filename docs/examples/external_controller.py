"""A controller in the loop, from docs/PROTOCOL.md §6.3 alone: plain zenoh, json, struct and numpy.

    python docs/examples/external_controller.py                     # this machine's hub (simecs up)
    python docs/examples/external_controller.py --session <id> [--runs 1]   # serve one of your sessions
    python docs/examples/external_controller.py tcp/127.0.0.1:7447  # an open hub (simecs up --open)

It reimplements the simulator's built-in joint-independent cascade as a digital controller: a P
position loop on the load resolver with speed feed-forward, then a PI speed loop on the motor resolver
with anti-windup, giving each joint's current set point; the simulator keeps the drive (current loops,
motor, gear). It runs once per control period on the sensor frame, and its answer is held for the
period (zero-order hold). Its gains are the run's parameter values, read from the run's layout.

Without --session it shows itself: it creates a session on the Spider, runs one joint path with the
built-in controller and once with itself in the loop, and prints how far apart the two runs are
(tests/test_examples.py runs it). With --session it serves that session's runs with controller
`external`, from any host of the mesh, until --runs runs have ended (0: until stopped).
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.ext
from joining import join

SCHEMA = json.loads((Path(__file__).resolve().parent.parent / "protocol.schema.json").read_text())
HIL = SCHEMA["x-simecs-hil"]
HEADER = struct.Struct(
    "<"
    + "".join(
        "4s" if f["field"] == "magic" else {2: "H", 4: "I", 8: "Q"}[f["size"]]
        for f in SCHEMA["x-simecs-frame"]["header"]
    )
)
SENSORS = [f["field"] for f in HIL["sensor_joint_fields"]]  # per joint, after the time
POSTURE = [0.3, -0.4, 0.2, 0.6, -0.3, 0.2, 0.1]
PATH = [{"q": [0.8, 0.1, 0.6, 1.0, -0.7, 0.6, 0.5]}, {"q": POSTURE}]
TOLERANCE_MRAD = 0.5  # why this much: docs/PROTOCOL.md §6.3


def frame(run_index: int, attempt: int, seq: int, row: np.ndarray) -> bytes:
    head = HEADER.pack(b"SMF1", 1, 0, run_index, attempt, seq, time.time_ns(), 1, row.size)
    return head + row.astype("<f8").tobytes()


class Cascade:
    """The controller of one run: gains from its layout, the speed integrators as state."""

    def __init__(self, layout: dict[str, Any], joints: list[str]) -> None:
        values, settings = layout["context"]["values"], layout["context"]["settings"]

        def gain(name: str) -> np.ndarray:
            return np.array([values[f"{j}.{name}"] for j in joints])

        self.run_index, self.run_id = layout["run_index"], layout["run_id"]
        self.attempt = layout["context"].get("attempt", 1)  # a run started again elsewhere: a new layout
        self.kp_pos, self.ff = gain("ctrl.kp_pos"), gain("ctrl.ff_vel")
        self.kp_vel, self.ki_vel = gain("ctrl.kp_vel"), gain("ctrl.ki_vel")
        self.ratio, self.i_max, self.poles = gain("gear.ratio"), gain("motor.i_max"), gain("motor.pole_pairs")
        self.back = np.divide(self.ki_vel, self.kp_vel, out=np.zeros(len(joints)), where=self.kp_vel > 0)
        self.period = settings["control_period"]
        self.x_v: np.ndarray | None = None  # the speed loops' integrators
        self.last: tuple[int, bytes] | None = None  # (seq, answer): a repeated frame gets it again

    def answer(self, seq: int, row: np.ndarray) -> bytes:
        if self.last is not None and self.last[0] == seq:
            return self.last[1]
        s = row[1:].reshape(len(self.kp_pos), len(SENSORS))  # one row per joint, SENSORS order
        q, theta_m, omega_m, q_ref, qd_ref, mode = s[:, 0], s[:, 2], s[:, 3], s[:, 6], s[:, 7], s[:, 8]
        if self.x_v is None:  # bumpless start: the integrators take the current that flows now
            angle = self.poles * theta_m
            self.x_v = -s[:, 4] * np.sin(angle) + s[:, 5] * np.cos(angle)
        w_ref = self.ratio * (self.kp_pos * (q_ref - q) + self.ff * qd_ref)  # mode 0 position, 3 hold
        e_v = np.where(mode == 1, self.ratio * qd_ref, w_ref) - omega_m  # mode 1: a speed set point
        i_unlimited = self.kp_vel * e_v + self.x_v
        i_ref = np.minimum(np.maximum(i_unlimited, -self.i_max), self.i_max)
        step = self.ki_vel * e_v + self.back * (i_ref - i_unlimited)  # PI with anti-windup
        current = mode == 2  # a current set point: straight through, the integrator frozen
        if current.any():
            i_ref = np.where(current, np.minimum(np.maximum(q_ref, -self.i_max), self.i_max), i_ref)
            step = np.where(current, 0.0, step)
        self.x_v = self.x_v + self.period * step
        out = frame(self.run_index, self.attempt, seq, i_ref)
        self.last = (seq, out)
        return out


class Controller:
    """Serves one session: every run of it with controller external gets a `Cascade`."""

    def __init__(self, z: zenoh.Session, space: str, joints: list[str], delay_s: float = 0.0) -> None:
        self.joints, self.delay_s = joints, delay_s
        self.runs: dict[int, Cascade] = {}
        self.ended: list[str] = []
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.pub = z.declare_publisher(f"{space}/hil/actuators", express=True)
        history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
        self.entities = [
            zenoh.ext.declare_advanced_subscriber(z, f"{space}/vars/layout", self.on_layout, history=history),
            zenoh.ext.declare_advanced_subscriber(z, f"{space}/state", self.on_state, history=history),
            z.declare_subscriber(f"{space}/hil/sensors", self.on_sensors),
        ]

    def on_layout(self, sample: zenoh.Sample) -> None:
        layout = json.loads(sample.payload.to_bytes())
        if layout["context"]["settings"].get("controller") == "external":
            with self.lock:
                self.runs[layout["run_index"]] = Cascade(layout, self.joints)

    def on_state(self, sample: zenoh.Sample) -> None:
        state = json.loads(sample.payload.to_bytes())
        with self.lock:
            served = {c.run_id for c in self.runs.values()}
            ended = state["phase"] in ("finished", "aborted", "failed")
            if ended and state["run_id"] in served and state["run_id"] not in self.ended:
                self.ended.append(state["run_id"])
                self.changed.notify_all()

    def on_sensors(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        magic, _v, _flags, run_index, attempt, seq, _wall, n_rows, n_cols = HEADER.unpack_from(payload)
        with self.lock:
            cascade = self.runs.get(run_index)
        if magic != b"SMF1" or cascade is None or n_rows != 1 or attempt != cascade.attempt:
            return  # a run (or attempt) this controller has no layout for yet: the worker repeats the frame
        row = np.frombuffer(payload, dtype="<f8", offset=HEADER.size, count=n_cols)
        answer = cascade.answer(seq, row)
        if self.delay_s:
            time.sleep(self.delay_s)
        self.pub.put(answer)

    def wait_ended(self, count: int, timeout: float) -> bool:
        with self.lock:
            return self.changed.wait_for(lambda: len(self.ended) >= count, timeout)

    def close(self) -> None:
        for e in (*self.entities, self.pub):
            e.undeclare()


def request(z: zenoh.Session, key: str, body: dict[str, Any] | None = None) -> Any:
    for reply in z.get(key, payload=json.dumps(body).encode() if body else None, timeout=30):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())["data"]
        raise RuntimeError(json.loads(reply.err.payload.to_bytes())["message"])
    raise RuntimeError(f"nobody answered {key}")


def joint_angles(z: zenoh.Session, space: str, run_id: str, joints: list[str]) -> np.ndarray:
    """The run's load angles at full resolution (rows of samples)."""
    names = ",".join(f"{j}.q" for j in joints)
    for reply in z.get(f"{space}/results/{run_id}?vars={names}", timeout=30):
        payload = reply.ok.payload.to_bytes()
        *_, n_rows, n_cols = HEADER.unpack_from(payload)
        data = np.frombuffer(payload, dtype="<f8", offset=HEADER.size, count=n_rows * n_cols)
        return data.reshape(n_rows, n_cols)[:, 1:]
    raise RuntimeError("no results")


def run(z: zenoh.Session, space: str, controller: Controller | None) -> str:
    ended = threading.Event()
    seen: dict[str, str] = {}

    def on_state(sample: zenoh.Sample) -> None:
        state = json.loads(sample.payload.to_bytes())
        if state["run_id"] == seen.get("run") and state["phase"] in ("finished", "aborted", "failed"):
            seen["phase"], seen["reason"] = state["phase"], state["reason"]
            ended.set()

    with z.declare_subscriber(f"{space}/state", on_state):
        seen["run"] = request(z, f"{space}/cmd", {"op": "run", "v": 1})["run_id"]
        ended.wait(120)
    if seen.get("phase") != "finished":
        raise RuntimeError(f"run {seen['run']} ended {seen.get('phase', 'never')}: {seen.get('reason', '')}")
    return seen["run"]


def demo(z: zenoh.Session, user: str) -> int:
    snap = request(z, f"simecs/u/{user}/sessions", {"op": "create", "v": 1, "model_id": "spider"})
    space = f"simecs/u/{user}/sessions/{snap['session']}"
    joints = [link["joint"] for link in request(z, "simecs/library/spider")["links"]]
    cmd = f"{space}/cmd"
    request(z, cmd, {"op": "set_initial", "v": 1, "joints": POSTURE})
    plan = request(z, cmd, {"op": "set_command", "v": 1, "command": {"kind": "joint_path", "nodes": PATH}})
    settings = {"stop_time": round(plan["duration"] + 0.3, 3), "output_interval": 0.001, "pacing": "fast"}
    request(z, cmd, {"op": "set_settings", "v": 1, "settings": settings})
    builtin = joint_angles(z, space, run(z, space, None), joints)
    controller = Controller(z, space, joints)
    request(z, cmd, {"op": "set_settings", "v": 1, "settings": {**settings, "controller": "external"}})
    t0 = time.perf_counter()
    run_id = run(z, space, controller)
    wall = time.perf_counter() - t0
    external = joint_angles(z, space, run_id, joints)
    controller.close()
    request(z, cmd, {"op": "close_session", "v": 1})
    error = float(np.max(np.abs(external - builtin))) * 1e3
    periods = round(settings["stop_time"] / 0.001)
    print(f"built-in vs external controller: {error:.4f} mrad at most (tolerance {TOLERANCE_MRAD} mrad)")
    print(f"{periods} control periods in {wall:.2f} s of wall time")
    return 0 if error <= TOLERANCE_MRAD else 1


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("endpoint", nargs="?", default=None, help="an open hub (default: this machine's)")
    parser.add_argument("--user", default="", help="whose session (default: yours, or integrator)")
    parser.add_argument("--session", default="", help="serve this session's runs (else: the demo)")
    parser.add_argument("--runs", type=int, default=0, help="stop after this many runs ended (0: never)")
    parser.add_argument("--delay-ms", type=float, default=0.0, help="answer this late on purpose")
    args = parser.parse_args()
    config, user = join(args.endpoint, "integrator")
    user = args.user or user
    with zenoh.open(config) as z:
        if not args.session:
            return demo(z, user)
        space = f"simecs/u/{user}/sessions/{args.session}"
        model = request(z, f"{space}/cmd", {"op": "get_session", "v": 1})["model_id"]
        joints = [link["joint"] for link in request(z, f"simecs/library/{model}")["links"]]
        controller = Controller(z, space, joints, args.delay_ms / 1e3)
        print(f"serving {space} ({model}, {len(joints)} joints)", flush=True)
        try:
            while not controller.wait_ended(args.runs or 1 << 30, 1.0):
                pass
        except KeyboardInterrupt:
            pass
        print(f"runs served: {', '.join(controller.ended)}", flush=True)
        controller.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
