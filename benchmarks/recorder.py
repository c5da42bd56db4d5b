"""`simecs bench recorder [--json]`: how much the recorder absorbs, what recording costs a run, replay speed.

Everything runs on private meshes (LocalMesh: hub on a unix socket, real node processes):
1. throughput: a client publishes a long run (Spider-sized frames of 10 samples) as fast as it can;
   from its first frame to the recorder's closed file, how many MCAP messages and input MB per second
   the recorder absorbed, with no frame dropped (its queue is made large enough to hold the burst);
2. the standard case (Spider, 5 s, 2 ms output, as fast as possible) through the whole service with the
   recorder off and on, in adjacent pairs; overhead = median over pairs of 1 - RTF on / RTF off; the
   recorder's own CPU time per simulated second; and, as a reference, the same with a subscriber that
   receives the frames and does nothing (on a 2-vCPU VM any work beside the simulator slows it);
3. replay: the recorded run replayed as a run of a session (proxy, simulator worker) as fast as possible
   and at 100x, speed measured from the frames.
Targets (issue 6): >= 20,000 msg/s, overhead <= 5 %, replay up to 100x real time.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.ext
from simecs.mesh.client import MeshClient
from simecs.mesh.process.config import MeshConfig, open_session
from simecs.mesh.process.seal import SealedPublisher
from simecs.mesh.protocol import codec, frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.local_mesh import LocalMesh, clean_env
from simecs.nodes.recording import mcapread

STOP = 5.0
OUTPUT = 0.002
ROWS_PER_FRAME = 10
BURST_FRAMES = 3000  # 30,000 samples = 60 simulated seconds of the standard output rate
PAIRS = 8  # adjacent runs with the recorder off and on
FINAL_WAIT_S = 0.5


def absorb(mesh: LocalMesh, rec_dir: Path) -> dict[str, Any]:
    """Publish a burst of Spider-sized frames and time the recorder until its file is closed."""
    from simecs import models

    desc = models.get_model("spider").describe()
    cols, units = desc.run_columns()
    sid = keys.new_session_id()
    user = "bench"
    z = mesh.new_client().z
    stop = BURST_FRAMES * ROWS_PER_FRAME * OUTPUT
    settings = m.RunSettings(stop_time=stop, output_interval=OUTPUT, pacing="fast")
    context = m.RunContext("bench", desc.default_values(), [0.0] * len(desc.links), None, settings)
    layout = m.RunLayout(sid, "r1", 1, desc.id, cols, units, cols[:1], 50.0, stop, OUTPUT, context)
    # Published as a worker would: sealed with the mesh's service key, or the recorder ignores it.
    layout_key, full_key = keys.layout(user, sid), keys.vars_full(user, sid)
    lay_pub = SealedPublisher(
        zenoh.ext.declare_advanced_publisher(
            z, layout_key, cache=zenoh.ext.CacheConfig(1), publisher_detection=True
        ),
        layout_key,
        mesh.seal,
    )
    full = SealedPublisher(
        z.declare_publisher(full_key, congestion_control=zenoh.CongestionControl.BLOCK), full_key, mesh.seal
    )
    n = BURST_FRAMES * ROWS_PER_FRAME
    t = np.arange(n) * OUTPUT
    rows = np.sin(np.outer(t, np.linspace(0.5, 3.0, len(cols))) + np.linspace(0, 1, len(cols)))
    rows[:, 0] = t
    payloads = [
        frames.encode(
            frames.Frame(
                1,
                k,
                0,
                rows[k * ROWS_PER_FRAME : (k + 1) * ROWS_PER_FRAME],
                frames.FLAG_FINAL if k == BURST_FRAMES - 1 else 0,
            )
        )
        for k in range(BURST_FRAMES)
    ]
    try:
        lay_pub.put(codec.dumps(layout))
        time.sleep(0.5)  # the recorder opens the file
        pid = mesh.procs["recorder"].pid
        c0 = _cpu_s(pid)
        t0 = time.perf_counter()
        for p in payloads:
            full.put(p)
        sent_s = time.perf_counter() - t0
        state_key = keys.state(user, sid)
        state = codec.dumps(m.SessionState(sid, "finished", run_id="r1", sim_time=float(t[-1])))
        z.put(state_key, state, attachment=mesh.seal.mac(state_key, state))
        path = rec_dir / user / f"{keys.recording_name(sid, 'r1')}.mcap"
        end = time.monotonic() + 300
        while not mcapread.has_footer(path):
            if time.monotonic() > end:
                raise TimeoutError(f"the recorder did not close {path} within 300 s")
            time.sleep(0.005)
        elapsed = time.perf_counter() - t0
        cpu = _cpu_s(pid) - c0
    finally:
        lay_pub.undeclare()
        full.undeclare()
    v = mcapread.validate(path)
    end_meta = v.metadata.get("simecs.end", {})
    in_bytes = sum(len(p) for p in payloads)
    return {
        "columns": len(cols),
        "samples": n,
        "messages": v.messages,
        "vars_messages": v.per_topic.get("/vars", 0),
        "seconds": elapsed,
        "publish_seconds": sent_s,
        "msgs_per_s": v.messages / elapsed,
        "samples_per_s": n / elapsed,
        "mb_per_s": in_bytes / elapsed / 1e6,
        "file_mb_per_s": path.stat().st_size / elapsed / 1e6,
        "file_mb": path.stat().st_size / 1e6,
        "dropped_frames": int(end_meta.get("dropped_frames", "-1")),
        "cpu_us_per_sample": cpu / n * 1e6,
        "path": path,
    }


def replay_speed(mesh: LocalMesh, path: Path, speed: float) -> float:
    """Simulated seconds per wall second achieved by a replay of `path` at `speed` (0 = max): a run of
    a session, produced by a simulator's worker from the recording in the library."""
    client = mesh.new_client()
    session = client.create_session("bench", "spider")
    got: list[tuple[int, float]] = []
    done = threading.Event()

    def on_full(fr: frames.Frame) -> None:
        if fr.rows.shape[0]:
            got.append((time.perf_counter_ns(), float(fr.rows[-1, 0])))
        if fr.final:
            done.set()

    with session.watch(on_full=on_full):
        run_id = session.replay(path.stem, speed, paused=True)
        session.wait_for(["paused"], 60, run_id)
        time.sleep(0.3)
        session.resume()
        if not done.wait(300):
            raise TimeoutError(f"replay at {speed}x did not finish")
    session.close()
    (w0, s0), (w1, s1) = got[0], got[-1]
    return (s1 - s0) / max((w1 - w0) / 1e9, 1e-9)


def standard_rtf(client: MeshClient, pid: int | None = None) -> tuple[float, float]:
    """RTF of one standard run, and the CPU seconds process `pid` spent from its start to its end."""
    from simecs.models import get_model

    STANDARD_TARGET = get_model("spider").spec.standard_target
    s = client.create_session("bench", "spider")
    s.set_settings(stop_time=STOP, output_interval=OUTPUT, pacing="fast")
    s.set_joint_path([(list(STANDARD_TARGET), 100.0, 100.0)])
    c0 = _cpu_s(pid) if pid else 0.0
    run = s.run()
    st = s.wait_for(["finished", "failed", "aborted"], 180, run)
    if pid:
        time.sleep(FINAL_WAIT_S)  # the recorder closes the file
    cpu = _cpu_s(pid) - c0 if pid else 0.0
    if st.phase != "finished":
        raise RuntimeError(f"standard run {st.phase}: {st.reason}")
    s.close()
    return st.rtf, cpu


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def sink_main(endpoint: str) -> None:
    """A subscriber of every full frame that does nothing with them: the floor of any recorder's cost
    (the hub forwards each frame once more, and a process receives it)."""
    z = open_session(MeshConfig(connect=[endpoint]))
    sub = z.declare_subscriber(keys.ALL_FULL, zenoh.handlers.RingChannel(8192))
    try:
        while True:
            if sub.try_recv() is None:
                time.sleep(0.005)
    finally:
        z.close()


def overhead(rec_dir: Path, pairs: int = PAIRS) -> dict[str, Any]:
    """Standard runs with the recorder off and on, in adjacent triples with a do-nothing subscriber
    (slow drifts of the machine's load cancel in each ratio); each `on` run gets a fresh recorder."""
    off: list[float] = []
    on: list[float] = []
    sink: list[float] = []
    cpu: list[float] = []
    with LocalMesh() as mesh:
        mesh.start_hub()
        mesh.start_service(max_running=4)
        client = mesh.client()
        time.sleep(3.0)  # the warm worker finishes compiling
        standard_rtf(client)  # warm-up run, not counted
        for i in range(pairs):
            off.append(standard_rtf(client)[0])
            proc = subprocess.Popen(
                [sys.executable, "-m", "simecs.benchmarks.recorder", "--sink", mesh.endpoint],
                env=clean_env(),
            )
            time.sleep(1.0)
            sink.append(standard_rtf(client)[0])
            proc.kill()
            proc.wait()
            name = f"recorder{i}"
            mesh.start("recorder", "--dir", str(rec_dir), name=name)
            time.sleep(1.0)  # past its start-up
            rtf, used = standard_rtf(client, mesh.procs[name].pid)
            on.append(rtf)
            cpu.append(used)
            mesh.stop(name)
    ratios = [1 - b / a for a, b in zip(off, on, strict=True)]
    return {
        "rtf_sink": sink,
        "receive_only_overhead": statistics.median([1 - b / a for a, b in zip(off, sink, strict=True)]),
        "rtf_off": off,
        "rtf_on": on,
        "rtf_off_median": statistics.median(off),
        "rtf_on_median": statistics.median(on),
        "overhead": statistics.median(ratios),
        "recorder_cpu_s_per_sim_s": statistics.median(cpu) / STOP,
    }


def run_recorder_bench(json_out: bool = False) -> dict[str, Any]:
    with LocalMesh() as mesh:
        mesh.start_hub()
        rec_dir = mesh.folder / "rec"
        mesh.start("recorder", "--dir", str(rec_dir), "--queue-frames", "100000", "--queue-mb", "4096")
        thr = absorb(mesh, rec_dir)
        mesh.start_service(max_running=4)
        max_speed = replay_speed(mesh, thr["path"], 0.0)
        at_100 = replay_speed(mesh, thr["path"], 100.0)
    ovh = overhead(mesh.folder / "rec-ovh")
    result: dict[str, Any] = {
        "msgs_per_s": round(thr["msgs_per_s"]),
        "samples_per_s": round(thr["samples_per_s"]),
        "mb_per_s": round(thr["mb_per_s"], 2),
        "file_mb_per_s": round(thr["file_mb_per_s"], 2),
        "messages": thr["messages"],
        "dropped_frames": thr["dropped_frames"],
        "recorder_cpu_us_per_sample": round(thr["cpu_us_per_sample"], 1),
        "columns": thr["columns"],
        "recording_overhead": round(ovh["overhead"], 4),
        "rtf_off_median": round(ovh["rtf_off_median"], 2),
        "rtf_on_median": round(ovh["rtf_on_median"], 2),
        "rtf_off": [round(x, 2) for x in ovh["rtf_off"]],
        "rtf_on": [round(x, 2) for x in ovh["rtf_on"]],
        "recorder_cpu_s_per_sim_s": round(ovh["recorder_cpu_s_per_sim_s"], 4),
        "receive_only_overhead": round(ovh["receive_only_overhead"], 4),
        "rtf_sink": [round(x, 2) for x in ovh["rtf_sink"]],
        "replay_max_speed": round(max_speed, 1),
        "replay_at_100x": round(at_100, 1),
        "targets": {"msgs_per_s": 20000, "recording_overhead": 0.05, "replay_speed": 100},
    }
    result["meets_targets"] = bool(
        result["msgs_per_s"] >= 20000
        and result["dropped_frames"] == 0
        and result["recording_overhead"] <= 0.05
        and at_100 >= 95.0
    )
    print("simecs bench recorder")
    print(
        f"  absorbed            {result['msgs_per_s']:>10,} msg/s   (target >= 20,000; "
        f"{thr['messages']:,} messages)"
    )
    print(f"                      {result['samples_per_s']:>10,} samples/s of {thr['columns']} columns")
    print(
        f"                      {result['mb_per_s']:>10.2f} MB/s in, "
        f"{result['file_mb_per_s']:.2f} MB/s to disk"
    )
    print(f"  dropped frames      {result['dropped_frames']:>10}")
    print(
        f"  recorder CPU        {result['recorder_cpu_us_per_sample']:>10.1f} us per sample (whole process)"
    )
    print(
        f"  standard case RTF   off {result['rtf_off_median']:.2f} / on "
        f"{result['rtf_on_median']:.2f} (median)"
    )
    print(f"  recording overhead  {result['recording_overhead'] * 100:>9.1f} %   (target <= 5 %)")
    print(f"  recorder CPU        {result['recorder_cpu_s_per_sim_s']:>9.3f} s per simulated second")
    print(
        f"  do-nothing sink     {result['receive_only_overhead'] * 100:>9.1f} %   (a subscriber of the "
        "frames that does nothing: the floor on this machine)"
    )
    print(f"  replay              {result['replay_max_speed']:>9.1f} x real time as fast as possible")
    print(f"                      {result['replay_at_100x']:>9.1f} x real time when asked for 100x")
    print(f"  meets targets       {result['meets_targets']}")
    if json_out:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description="helper process of simecs bench recorder")
    parser.add_argument("--sink", required=True, help="hub endpoint")
    sink_main(parser.parse_args().sink)
