"""`simecs bench lan [--json]`: the shared service on a LAN: isolation, robustness, security, and their cost.

The bench makes a LAN on this machine (testing/netns.py, as root): network namespaces `hub`
(10.231.0.1), `sim` (.2: proxy, simulator, hot-feedback, recorder), `client` (.3: the users, the
attacker and this bench's own measuring process) and `slow` (.4: a slow subscriber), joined by veth
pairs on a private bridge, so that every sample crosses a TCP (or TLS) connection between hosts. Where
namespaces cannot be made it falls back to loopback and says so (`network`). Nodes are real processes
started with the arguments LocalMesh and tests/conftest.py use. Measured, in this order:

1. `tls_run_rtf_ratio`: the standard case (Spider, 7 joints, 2 ms output) as fast as possible, with a
   subscriber of its full-rate frames, on the secured mesh (TLS hub, user/password, the generated
   access rules, as `simecs up --secure` and the `secured` fixture) against a plain TCP mesh, both up at
   once and used alternately; median RTF secured / median RTF plain (and the same for wall times);
2. `forged_puts_effective`: a client without the service key puts every forgery of testing/forgery.py
   (run status, frames, layout, state, params, notices, controls, node status) three times against
   another user's real-time run, sends a run request straight to the simulator and poses as a
   simulator; counted as effective: the puts of every key whose forgery shows anywhere (the run's
   states, results, recording, live frames and parameters, as a seal-checking client sees them), and
   apart (`forged_other_effective`) a direct request or a fake simulator that got a run;
   `default_mode_forgeries_effective`: the same against the secured mesh, which is what `simecs up`
   starts by default (private), sent by eve, a second user with her own password;
3. `fuzz_internal_replies`: testing/fuzz.py against the plain mesh's service (null while it is missing);
4. `slow_subscriber_other_session_rtf`: a subscriber of every session's `vars/full` and `vars/live`
   whose callback sleeps 200 ms per sample (on its own host), while its user's run goes as fast as
   possible and another user's real-time run goes on: that run's RTF (target 1.0), and runs that did not
   finish (`slow_subscriber_failed_runs`);
5. `recorder_crash_loss_s`: the recorder is killed (SIGKILL) in the middle of a real-time run and
   restarted; simulated seconds of the run's results found in none of its recording files afterwards
   (the torn file, repaired, and the continuation);
6. `worker_crash_results_kept`: a worker is killed (SIGKILL) in a real-time run: whether the results it
   computed are kept up to where it was killed, and `frames_after_failed`, live frames of the run after
   the session showed it failed;
7. `simulator_crash_runs_lost`: the simulator node alone is killed (SIGKILL) in two users' real-time
   runs and started again at once (as `make up` does): runs that did not finish in their first attempt
   (and `simulator_crash_results_whole`, runs whose results are whole);
8. `hub_restart_failed_runs`: the hub is killed (SIGKILL) and restarted 2 s later while two real-time
   runs go on (one ends while it is away): runs that did not finish, and recordings not equal to the
   results.
Targets (issue 14): 1.0 and 0 failed runs with a slow subscriber, 0 failed runs across a hub restart,
0 effective forgeries, 0 internal replies to fuzzing, TLS ratio >= 0.95; (issue 33) recorder crash loss
<= 0.1 s, no run lost to a simulator node crash, a crashed worker's results kept, no frame after failed.
Every wait is bounded; the whole bench takes about 3 minutes on 2 cores. Node logs are kept in the
folder printed last (`logs`).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from simecs.mesh import frames, keys
from simecs.mesh import messages as m
from simecs.mesh.client import MeshClient, SessionClient
from simecs.mesh.config import MeshConfig, TlsConfig, load, open_session
from simecs.nodes.local_mesh import LocalMesh, clean_env, wait_until
from simecs.testing import netns

HOSTS = ("hub", "sim", "client", "slow")
HUB = "simecs.nodes.hub"
PLAIN_PORT, TLS_PORT = 7447, 7448
OUTPUT = 0.002
TARGET = [0.3, -0.2, 0.2, 0.1, -0.1, 0.1, 0.0]
ENDED = ["finished", "failed", "aborted"]
TLS_STOP = 15.0  # simulated s of each as-fast-as-possible run (~1 s of wall time)
TLS_PAIRS = 5
QUIET_BUSY = 0.2  # between runs: until at most this share of the CPUs is busy (the next warm worker
QUIET_MAX_S = 8.0  # starts meanwhile), for at most this long
FORGERY_ROUNDS = 3
FORGED_VALUE = 7.0  # what testing/forgery.py puts in its forged frames
SLOW_SLEEP_S = 0.2
SLOW_STOP = 6.0
CRASH_STOP, CRASH_AT = 8.0, 3.0
INNER_TIMEOUT_S = 420.0
FUZZ_COUNT, FUZZ_DEADLINE_S = 3000, 45.0
FUZZ_BYSTANDER_STOP = 15.0


def log(text: str) -> None:
    print(f"bench lan: {text}", file=sys.stderr, flush=True)


# -- where things run --------------------------------------------------------------------------------
@dataclass
class Hosts:
    """How to start a command on each host (an argv prefix) and each host's address."""

    network: str  # "netns" | "loopback"
    prefixes: dict[str, list[str]]
    addresses: dict[str, str]

    @classmethod
    def loopback(cls) -> Hosts:
        return cls("loopback", {h: [] for h in HOSTS}, {h: "127.0.0.1" for h in HOSTS})

    @classmethod
    def of(cls, lan: netns.Lan) -> Hosts:
        return cls("netns", {h: lan.prefix(h) for h in HOSTS}, {h: lan.address(h) for h in HOSTS})

    def endpoint(self, proto: str, port: int) -> str:
        """The hub's endpoint: fixed ports in the hub's own namespace, free ones on loopback."""
        if self.network == "loopback":
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = int(s.getsockname()[1])
        return f"{proto}/{self.addresses['hub']}:{port}"


class LanMesh(LocalMesh):
    """A LocalMesh whose hub listens on the hub host's address and whose nodes start on the `sim` host."""

    def __init__(self, hosts: Hosts, endpoint: str, name: str) -> None:
        super().__init__(endpoint=endpoint)
        self.hosts = hosts
        self.name = name
        self.eve = ""  # secured: the second user's password
        self.ca_file = ""

    def argv_prefix(self, module: str) -> list[str]:
        return self.hosts.prefixes["hub" if module == HUB else "sim"]

    def keep_logs(self, logs: Path) -> None:
        target = logs / self.name
        target.mkdir(parents=True, exist_ok=True)
        for path in self.folder.glob("*.log"):
            shutil.copy(path, target / path.name)


def plain_mesh(hosts: Hosts) -> LanMesh:
    mesh = LanMesh(hosts, hosts.endpoint("tcp", PLAIN_PORT), "plain")
    mesh.start_hub()
    mesh.start_service(max_running=4, simulator_args=("--warm", "2"))  # two runs start at once
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    return mesh


def secured_mesh(hosts: Hosts) -> tuple[LanMesh, str]:
    """As `simecs up` (private, its default) and the `secured` fixture make it, with two users, ann and
    eve; returns the mesh and ann's password (eve's: `mesh.eve`)."""
    from simecs.nodes.secure import SecureFolder

    mesh = LanMesh(hosts, hosts.endpoint("tls", TLS_PORT), "secured")
    folder = SecureFolder(mesh.folder / "secure")
    password = folder.add_user("ann")
    mesh.eve = folder.add_user("eve")  # the attacker of the forgery trial, a user like any other
    mesh.ca_file = str(folder.ca_file)
    folder.ensure_certificates([hosts.addresses["hub"]])
    hub = folder.hub_config([mesh.endpoint])
    nodes = str(folder.node_config(mesh.endpoint, str(mesh.key_file)))
    mesh.client_config = load(nodes, env={})  # the harness joins as the service
    mesh.spawn("hub", HUB, "--mesh-config", str(hub), node_id="hub")
    mesh.client()
    data = mesh.folder / "data"
    mesh.start("proxy", "--data-dir", str(data), "--mesh-config", nodes)
    mesh.start("simulator", "--results-dir", str(data / "results"), "--mesh-config", nodes)
    mesh.start("hotfeedback", "--mesh-config", nodes)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"), "--mesh-config", nodes)
    return mesh, password


def prepared(
    client: MeshClient, user: str, stop: float, pacing: str, target: list[float] | None = None
) -> SessionClient:
    s = client.create_session(user, "spider")
    s.set_settings(stop_time=stop, output_interval=OUTPUT, pacing=pacing)
    s.set_joint_path([(target or TARGET, 100.0, 100.0)])
    return s


def recording_files(mesh: LocalMesh, s: SessionClient, run_id: str) -> list[Path]:
    """The run's recording and its continuations (a restarted recorder writes `<name>.2.mcap`)."""
    name = keys.recording_name(s.id, run_id)
    folder = mesh.folder / "rec" / s.user
    return sorted(p for p in folder.glob(f"{name}*.mcap") if p.stem == name or p.stem.startswith(name + "."))


def closed_recordings(
    mesh: LocalMesh, s: SessionClient, run_id: str, parts: int, timeout: float
) -> list[Path]:
    """The run's `parts` recording files once each is complete (has its footer)."""
    from simecs.nodes import mcapread

    def done() -> list[Path]:
        paths = recording_files(mesh, s, run_id)
        return paths if len(paths) >= parts and all(mcapread.has_footer(p) for p in paths) else []

    return list(wait_until(done, timeout, 0.1, f"{parts} closed recording(s) of {run_id}"))


def recording_matches(mesh: LocalMesh, s: SessionClient, run_id: str) -> bool:
    """The run's one recording holds exactly its results, with no gap left."""
    from simecs.nodes import mcapread

    try:
        (path,) = closed_recordings(mesh, s, run_id, 1, 40.0)
        rec = mcapread.load(path)
        _cols, rows = s.results(run_id)
    except Exception as exc:  # no file, a bad file, no results: all mean "not the results"
        log(f"recording of {s.user}/{run_id}: {exc}")
        return False
    same = rec.rows.shape == rows.shape and bool(np.array_equal(rec.rows, rows))
    return same and rec.metadata.get("simecs.end", {}).get("gaps") == "0"


# -- 1. TLS ---------------------------------------------------------------------------------------------
def timed_run(client: MeshClient, user: str) -> tuple[float, float]:
    """RTF and wall seconds (from the run command to its finished state) of one standard run as fast as
    possible, its full-rate frames received by this client."""
    s = prepared(client, user, TLS_STOP, "fast", standard_target())
    got = [0]

    def count(_sample: zenoh.Sample) -> None:
        got[0] += 1

    sub = client.z.declare_subscriber(keys.vars_full(user, s.id), count)
    try:
        time.sleep(0.2)
        t0 = time.perf_counter()
        run = s.run()
        st = s.wait_for(ENDED, 120, run)
        wall = time.perf_counter() - t0
    finally:
        sub.undeclare()
    s.close()
    if st.phase != "finished" or not got[0]:
        raise RuntimeError(f"standard run {st.phase} ({got[0]} frames): {st.reason}")
    return st.rtf, wall


def wait_quiet() -> None:
    """Until the machine is nearly idle (at least 1 s): on 2 cores the start of the simulator's next warm
    worker, or anything else, would land on one of the two meshes' runs only."""

    def busy_share(window: float) -> float:
        def sample() -> tuple[int, int]:
            values = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
            return sum(values), values[3] + values[4]  # all, idle + iowait

        all0, idle0 = sample()
        time.sleep(window)
        all1, idle1 = sample()
        return 1.0 - (idle1 - idle0) / max(all1 - all0, 1)

    time.sleep(0.5)
    end = time.monotonic() + QUIET_MAX_S
    while busy_share(0.5) > QUIET_BUSY and time.monotonic() < end:
        pass


def standard_target() -> list[float]:
    from simecs.models import get_model

    return list(get_model("spider").spec.standard_target)


def tls_ratio(plain: LanMesh, secured: LanMesh, password: str) -> dict[str, Any]:
    """Alternated standard runs on both meshes (ABBA order), each joined as a user would."""
    users = {  # neither checks seals: each is a user's client
        "plain": MeshClient.open(MeshConfig(connect=[plain.endpoint]), timeout=10.0),
        "secured": MeshClient.open(secured.config.as_user("ann", password, 3000), timeout=10.0),
    }
    plain.clients.append(users["plain"])
    secured.clients.append(users["secured"])
    rtf: dict[str, list[float]] = {"plain": [], "secured": []}
    wall: dict[str, list[float]] = {"plain": [], "secured": []}
    for which in ("plain", "secured"):  # warm-up: first runs compile and fill caches
        timed_run(users[which], "ann")
        wait_quiet()
    for i in range(TLS_PAIRS):
        for which in ("plain", "secured") if i % 2 == 0 else ("secured", "plain"):
            r, w = timed_run(users[which], "ann")
            rtf[which].append(r)
            wall[which].append(w)
            wait_quiet()
    return {
        "tls_run_rtf_ratio": statistics.median(rtf["secured"]) / statistics.median(rtf["plain"]),
        "tls_run_wall_ratio": statistics.median(wall["plain"]) / statistics.median(wall["secured"]),
        "tls_rtf_plain": [round(x, 2) for x in rtf["plain"]],
        "tls_rtf_secured": [round(x, 2) for x in rtf["secured"]],
    }


# -- 2. forgeries ----------------------------------------------------------------------------------------
def forgery_trial(mesh: LanMesh) -> dict[str, Any]:
    """testing/forgery.py against ann's real-time run; which forgeries show anywhere. On the secured
    mesh (the private default) the attacker is eve, a user with her own password."""
    from simecs.testing import forgery

    client = mesh.client()  # holds the seal: sees what the viewer would show
    stop = 2.0
    attacker_cfg = MeshConfig(connect=[mesh.endpoint])
    if mesh.eve:
        attacker_cfg = MeshConfig(
            connect=[mesh.endpoint],
            user="eve",
            password=mesh.eve,
            tls=TlsConfig(root_ca_certificate=mesh.ca_file),
        )
    with MeshClient.open(attacker_cfg) as attacker:
        fake = forgery.FakeSimulator(attacker.z)
        statuses: list[str] = []

        def on_status(sample: zenoh.Sample) -> None:
            if client.seal is not None and client.seal.sample_valid(sample):
                statuses.append(str(sample.key_expr))

        status_sub = client.z.declare_subscriber(keys.wildcard("node_status"), on_status)
        try:
            try:  # the hub of the private default refuses the fake simulator's token
                wait_until(
                    lambda: ("simulator", forgery.FAKE_SIMULATOR) in client.live_nodes(),
                    10 if not mesh.eve else 3,
                    what="fake simulator",
                )
            except TimeoutError:
                if not mesh.eve:
                    raise
            s = prepared(client, "ann", stop, "realtime")
            states: list[m.SessionState] = []
            live: list[tuple[float, frames.Frame]] = []  # (when it came, frame)
            params: list[m.ParamValues] = []
            with s.watch(
                on_state=states.append,
                on_live=lambda f: live.append((time.monotonic(), f)),
                on_params=params.append,
            ):
                run = s.run()
                wait_until(sim_time_above(s, 0.2), 30, what="run under way")
                width = len(client.describe("spider").variables) + 1
                sent: list[tuple[str, bytes]] = []
                for _ in range(FORGERY_ROUNDS):
                    sent += forgery.forged_messages("ann", s.id, run, 1, width)
                    forgery.forge(attacker.z, "ann", s.id, run, 1, width)
                    time.sleep(0.2)
                replies = forgery.direct_run_request(attacker.z, "simulator-t", "ann", s.id, "r9")
                end = s.wait_for(ENDED, 60, run)
                time.sleep(0.5)  # anything the forgeries could still cause
            # Hosts are offered runs in turn: the fake one's turn comes within two more runs.
            s.set_settings(stop_time=0.1, output_interval=OUTPUT, pacing="fast")
            later = []
            for _ in range(2):
                later.append(s.run())
                later_end = s.wait_for(ENDED, 60, later[-1])
                if later_end.phase != "finished":
                    break
        finally:
            status_sub.undeclare()
            fake.close()
    _cols, rows = s.results(run)
    symptoms: dict[str, set[str]] = {}  # what showed -> the forged keys that could have caused it

    def showed(symptom: str, *kinds: str) -> None:
        symptoms[symptom] = set(kinds)

    ours = [st for st in states if st.run_id == run]
    if end.phase != "finished" or abs(end.sim_time - stop) > 1e-9:
        showed(f"run ended {end.phase} at t = {end.sim_time}", "run_status", "control")
    if any(st.phase == "failed" for st in ours):
        showed("a failed state", "run_status")
    if any(st.phase == "finished" and st.sim_time < stop - 1e-9 for st in ours):
        showed("finished before its stop time", "run_status")
    if any(st.phase == "paused" for st in ours):
        showed("paused", "control")
    if any(st.phase == "aborted" for st in ours):
        showed("aborted", "control")
    if end.warnings:
        showed(f"warnings {end.warnings}", "notices")
    if any(p.values.get("joint1.ctrl.kp_pos") == 1.0 for p in params) or (
        s.snapshot().values.get("joint1.ctrl.kp_pos") == 1.0
    ):
        showed("parameter changed", "params")
    if rows.shape[0] != round(stop / OUTPUT) + 1 or FORGED_VALUE in rows[:5, 1:]:
        showed("forged or missing samples in the results", "vars_full")
    if not recording_matches(mesh, s, run):
        showed("recording differs from the results", "vars_full", "layout", "state")
    widths = {f.rows.shape[1] for _t, f in live if f.rows.shape[0]}
    live_width = max(widths) if widths else None
    if len(widths) > 1 or any(f.rows.shape[0] and np.all(f.rows[:, 1:] == FORGED_VALUE) for _t, f in live):
        showed("forged live frames", "vars_full", "vars_live", "layout")
    finals = [f for _t, f in live if f.final]
    if len(finals) != 1 or not finals[0].rows.shape[0] or abs(finals[0].rows[-1, 0] - stop) > 1e-9:
        showed("live stream ended early or twice", "vars_full", "vars_live", "layout")
    if any(forgery.FAKE_SIMULATOR in k for k in statuses):
        showed("fake node status", "node_status")
    kind_of = {
        keys.run_status("ann", s.id): "run_status",
        keys.vars_full("ann", s.id): "vars_full",
        keys.vars_live("ann", s.id): "vars_live",
        keys.layout("ann", s.id): "layout",
        keys.state("ann", s.id): "state",
        keys.params("ann", s.id): "params",
        keys.notices("ann", s.id): "notices",
        keys.control("ann", s.id): "control",
        keys.node_status("simulator", forgery.FAKE_SIMULATOR): "node_status",
    }
    implicated = set().union(*symptoms.values()) if symptoms else set()
    effective = sum(1 for key, _payload in sent if kind_of.get(key, key) in implicated)
    direct_ok = any(r.ok is not None for r in replies) or "r9" in {r.run_id for r in s.runs()}
    fake_took = fake.offered > 0 and later_end.phase != "finished"
    if direct_ok:
        showed("a run request straight to the simulator was taken", "direct")
    if fake_took:
        showed("the fake simulator took a run", "fake")
    return {
        "forged_puts_effective": effective,
        "forged_puts_sent": len(sent),
        # The other attempts: the direct run request, and each run offered to the fake simulator.
        "forged_other_effective": int(direct_ok) + int(fake_took),
        "forged_other_sent": 1 + fake.offered,
        "forged_effects": sorted(symptoms),
        "forged_direct_request_reply": [
            "ok" if r.ok is not None else r.err.payload.to_bytes().decode(errors="replace")[:80]
            for r in replies
        ],
        "fake_simulator_offered": fake.offered,
        "live_width": live_width,
    }


def default_mode_forgeries(secured: LanMesh) -> dict[str, Any]:
    """The forgery trial against the private default (what `simecs up` starts), by a second user."""
    r = forgery_trial(secured)
    return {
        "default_mode_forgeries_effective": r["forged_puts_effective"] + r["forged_other_effective"],
        "default_mode_forgeries_sent": r["forged_puts_sent"] + r["forged_other_sent"],
        "default_mode_forged_effects": r["forged_effects"],
    }


# -- 3. fuzzing -------------------------------------------------------------------------------------------
def fuzz_trial(mesh: LanMesh) -> dict[str, Any]:
    """testing/fuzz.py against the plain mesh, from a client without the service key, aimed at ann's
    session (a finished run) while bob's real-time run goes on. Null with a note while it is missing."""
    try:
        fuzzing: Any = importlib.import_module("simecs.testing.fuzz")
    except ImportError as exc:
        return {"fuzz_internal_replies": None, "fuzz_note": f"testing/fuzz.py not available: {exc}"}
    client = mesh.client()
    victim = prepared(client, "ann", 0.2, "fast")
    v_run = victim.run()
    victim.wait_for(ENDED, 60, v_run)
    bystander = prepared(client, "bob", FUZZ_BYSTANDER_STOP, "realtime")
    b_run = bystander.run()
    width = len(client.describe("spider").variables) + 1
    nodes = tuple(sorted(client.live_nodes()))
    done = [p for p in (mesh.folder / "rec" / "ann").glob("*.mcap") if mcapread_complete(p)]
    with MeshClient.open(MeshConfig(connect=[mesh.endpoint])) as attacker:
        own = tuple(attacker.create_session("mallory", "spider").id for _ in range(2))
        try:
            targets = fuzzing.FuzzTargets(
                attacker_user="mallory",
                attacker_sessions=own,
                victim_user="ann",
                victim_session=victim.id,
                victim_run_id=v_run,
                victim_run_index=int(v_run[1:]),
                width=width,
                simulators=("simulator-t",),
                nodes=nodes,
                bystanders=(fuzzing.Victim("bob", bystander.id, b_run, int(b_run[1:])),),
                mcap=done[0].read_bytes() if done else b"",
            )
        except TypeError as exc:
            return {"fuzz_internal_replies": None, "fuzz_note": f"testing/fuzz.py does not fit: {exc}"}
        report = fuzzing.fuzz(attacker.z, targets, seed=1, count=FUZZ_COUNT, deadline_s=FUZZ_DEADLINE_S)
    b_end = bystander.wait_for(ENDED, FUZZ_BYSTANDER_STOP * 3 + 30, b_run)
    gone = sorted(set(nodes) - set(live_nodes(client)))
    v_state = victim.snapshot().state
    return {
        "fuzz_internal_replies": int(report.internal_replies),
        "fuzz_sent": report.sent,
        "fuzz_replies": dict(sorted(report.replies_by_code.items())),
        "fuzz_seconds": round(report.elapsed_s, 1),
        "fuzz_out_of_time": report.out_of_time,
        "fuzz_internal_examples": [list(x) for x in report.internal[:3]],
        "fuzz_malformed_examples": [list(x) for x in report.malformed[:3]],
        "fuzz_timeouts": len(report.timeouts),
        "fuzz_timeout_examples": [list(x) for x in report.timeouts[:3]],
        "fuzz_nodes_gone": [f"{role}/{node}" for role, node in gone],
        "fuzz_bystander_run": b_end.phase,
        "fuzz_victim_phase": v_state.phase,
    }


def mcapread_complete(path: Path) -> bool:
    from simecs.nodes import mcapread

    return mcapread.has_footer(path)


# -- 4. a slow subscriber ---------------------------------------------------------------------------------
def slow_main(endpoint: str, status_file: str, seconds: float) -> None:
    """The slow subscriber's process: every session's sample streams, 200 ms per sample, until SIGTERM."""
    stop = threading.Event()
    seen = [0]

    def sleepy(_sample: zenoh.Sample) -> None:
        seen[0] += 1
        if not stop.is_set():
            time.sleep(SLOW_SLEEP_S)

    def terminate(*_: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, terminate)
    z = open_session(MeshConfig(connect=[endpoint]))
    subs = [z.declare_subscriber(keys.ALL_FULL, sleepy), z.declare_subscriber(keys.ALL_LIVE, sleepy)]
    Path(status_file).write_text(json.dumps({"ready": True}))
    try:
        stop.wait(seconds)
    finally:
        stop.set()
        for sub in subs:
            sub.undeclare()
        z.close()
        Path(status_file).write_text(json.dumps({"ready": True, "seen": seen[0]}))


def slow_trial(mesh: LanMesh) -> dict[str, Any]:
    status = mesh.folder / "slow.json"
    argv = [*mesh.hosts.prefixes["slow"], sys.executable, "-m", "simecs.benchmarks.lan"]
    argv += ["--slow-subscriber", mesh.endpoint, "--status-file", str(status), "--seconds", "120"]
    with open(mesh.folder / "slow.log", "ab") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=clean_env())
    try:
        wait_until(status.exists, 20, what="slow subscriber ready")
        time.sleep(0.3)
        client = mesh.client()
        mine = prepared(client, "slowpoke", SLOW_STOP, "fast")  # floods the slow subscriber's link
        other = prepared(client, "ann", SLOW_STOP, "realtime")
        states: list[m.SessionState] = []
        with other.watch(on_state=states.append):
            r_mine, r_other = mine.run(), other.run()
            st_other = other.wait_for(ENDED, SLOW_STOP * 5 + 30, r_other)
        st_mine = mine.wait_for(ENDED, 120, r_mine)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    running = [s.sim_time for s in states if s.phase == "running" and s.run_id == r_other]
    seen = json.loads(status.read_text()).get("seen", -1) if status.exists() else -1
    return {
        "slow_subscriber_other_session_rtf": st_other.rtf,
        "slow_subscriber_failed_runs": sum(st.phase != "finished" for st in (st_mine, st_other)),
        "slow_subscriber_fast_run_rtf": st_mine.rtf,
        "slow_subscriber_max_progress_step_s": float(np.max(np.diff([0.0, *running]))) if running else None,
        "slow_subscriber_samples_seen": seen,
    }


# -- 5. the recorder crashes ------------------------------------------------------------------------------
def recorder_crash_trial(mesh: LanMesh) -> dict[str, Any]:
    from simecs.nodes import mcapread

    client = mesh.client()
    s = prepared(client, "carol", CRASH_STOP, "realtime")
    run = s.run()
    wait_until(sim_time_above(s, CRASH_AT), 30, what="run under way")
    killed_at = s.snapshot().state.sim_time
    t0 = time.monotonic()
    mesh.stop("recorder", signal.SIGKILL)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"), name="recorder2")
    restart_s = time.monotonic() - t0
    end = s.wait_for(ENDED, 60, run)
    paths = closed_recordings(mesh, s, run, 2, 45.0)
    _cols, rows = s.results(run)
    got = np.concatenate([mcapread.load(p).rows[:, 0] for p in paths])
    missing = rows[~np.isin(rows[:, 0], got), 0]
    return {
        "recorder_crash_loss_s": float(missing.size * OUTPUT),
        "recorder_crash_missing": [round(float(missing.min()), 4), round(float(missing.max()), 4)]
        if missing.size
        else [],
        "recorder_killed_at_s": round(killed_at, 3),
        "recorder_restart_s": round(restart_s, 2),
        "recorder_crash_run": end.phase,
        "recorder_crash_files": [p.name.split("_", 1)[1] for p in paths],
    }


# -- 6, 7. a worker and the simulator node die -------------------------------------------------------------
SIM_CRASH_STOP, SIM_CRASH_AT = 4.0, 1.0


def worker_of(mesh: LocalMesh, s: SessionClient, run_id: str) -> int:
    line = re.compile(rf"run {re.escape(s.id)}/{re.escape(run_id)} handed to (?:warm|cold) worker pid (\d+)")
    hit = wait_until(lambda: line.search(mesh.log("simulator")), 30, what=f"the worker of {run_id}")
    return int(hit.group(1))


def frames_after_end(s: SessionClient, run_id: str, ended: list[float], count: list[int]) -> Any:
    """Watch `s`: the time its run `run_id` was shown failed, and the live frames of it after that."""

    def on_state(st: m.SessionState) -> None:
        if st.run_id == run_id and st.phase == "failed" and not ended:
            ended.append(time.monotonic())

    def on_live(_frame: frames.Frame) -> None:  # the session has this run only
        if ended:
            count[0] += 1

    return s.watch(on_state=on_state, on_live=on_live)


def simulator_crash_trial(mesh: LanMesh) -> dict[str, Any]:
    """Two users' real-time runs; their simulator node killed alone (SIGKILL: its workers live on) and
    started again at once under the same name, as `make up`'s supervisor does."""
    client = mesh.client()
    sessions = [prepared(client, user, SIM_CRASH_STOP, "realtime") for user in ("fay", "gus")]
    runs = {s.user: s.run() for s in sessions}
    for s in sessions:
        wait_until(sim_time_above(s, SIM_CRASH_AT), 30, what="runs under way")
    joined = mesh.log("proxy").count("simulator host simulator-t joined")
    os.kill(mesh.procs["simulator"].pid, signal.SIGKILL)
    mesh.start("simulator", "--results-dir", str(mesh.folder / "data" / "results"), "--warm", "2")
    ends = {s.user: s.wait_for(ENDED, 60, runs[s.user]) for s in sessions}

    # the next trial's runs need the host back: the proxy says when it has it again
    def back() -> bool:
        return mesh.log("proxy").count("simulator host simulator-t joined") > joined

    wait_until(back, 60, what="the restarted simulator taken by the proxy")
    whole = 0
    for s in sessions:
        _cols, rows = s.results(runs[s.user])
        whole += int(rows.shape[0] == round(SIM_CRASH_STOP / OUTPUT) + 1)
    return {
        "simulator_crash_runs_lost": sum(st.phase != "finished" or st.attempt != 1 for st in ends.values()),
        "simulator_crash_results_whole": whole,
        "simulator_crash_phases": {u: st.phase for u, st in ends.items()},
    }


def worker_crash_trial(mesh: LanMesh) -> dict[str, Any]:
    """A worker killed mid real-time run: the run fails at once, what it computed is kept, and no frame
    of it comes after it was shown failed."""
    client = mesh.client()
    s = prepared(client, "hal", CRASH_STOP, "realtime")
    run = s.run()
    worker = worker_of(mesh, s, run)
    wait_until(sim_time_above(s, CRASH_AT), 30, what="run under way")
    ended: list[float] = []
    after = [0]
    with frames_after_end(s, run, ended, after):
        reached = s.snapshot().state.sim_time
        t0 = time.monotonic()
        os.kill(worker, signal.SIGKILL)
        end = s.wait_for(ENDED, 30, run)
        failed_s = time.monotonic() - t0
        time.sleep(1.0)
    _cols, rows = wait_until(lambda: results_or_none(s, run), 10, what="the results it left")
    return {
        "worker_crash_results_kept": bool(rows.shape[0] > 0 and rows[-1, 0] >= reached - 0.3),
        "worker_crash_results_end_s": round(float(rows[-1, 0]), 3) if rows.shape[0] else None,
        "worker_crash_failed_after_s": round(failed_s, 2),
        "worker_crash_phase": end.phase,
        "frames_after_failed": after[0],
    }


def results_or_none(s: SessionClient, run_id: str) -> tuple[list[str], np.ndarray] | None:
    try:
        return s.results(run_id)
    except Exception:  # not stored yet
        return None


# -- 8. the hub restarts ----------------------------------------------------------------------------------
def live_nodes(client: MeshClient) -> list[tuple[str, str]]:
    try:
        return client.live_nodes(timeout=0.5)
    except Exception:  # while the session has no hub
        return []


def sim_time_above(s: SessionClient, t: float) -> Callable[[], bool]:
    return lambda: s.snapshot().state.sim_time > t


def hub_restart_trial(mesh: LanMesh) -> dict[str, Any]:
    client = mesh.client()
    through = prepared(client, "dave", 4.0, "realtime")  # goes on through the restart
    ended = prepared(client, "erin", 1.5, "realtime")  # ends while the hub is away
    runs = {through.user: through.run(), ended.user: ended.run()}
    for s in (through, ended):
        wait_until(sim_time_above(s, 0.3), 30, what="runs under way")
    mesh.stop("hub", signal.SIGKILL)
    time.sleep(2.0)
    mesh.start_hub()  # this client's session reconnects by itself
    wait_until(lambda: ("proxy", "proxy-t") in live_nodes(client), 20, what="proxy back")
    phases = {s.user: s.wait_for(ENDED, 60, runs[s.user]) for s in (through, ended)}
    bad = [s.user for s in (through, ended) if not recording_matches(mesh, s, runs[s.user])]
    return {
        "hub_restart_failed_runs": sum(st.phase != "finished" for st in phases.values()),
        "hub_restart_phases": {u: st.phase for u, st in phases.items()},
        "hub_restart_incomplete_recordings": len(bad),
    }


# -- the measuring process (on the client host) ------------------------------------------------------------
def inner_main(plan: dict[str, Any]) -> None:
    """All measurements; writes the figures as JSON to plan["out"]. SIGTERM ends it through `finally`."""

    def terminate(*_: object) -> None:
        raise SystemExit(143)

    signal.signal(signal.SIGTERM, terminate)
    hosts = Hosts(plan["network"], plan["prefixes"], plan["addresses"])
    logs = Path(plan["logs"])
    result: dict[str, Any] = {}
    errors: dict[str, str] = {}

    def part(name: str, fn: Callable[[], dict[str, Any]]) -> None:
        log(f"{name} ...")
        t0 = time.monotonic()
        try:
            result.update(fn())
        except Exception as exc:  # a part that fails is reported, the others still run
            errors[name] = f"{type(exc).__name__}: {exc}"[:500]
            log(f"{name} FAILED: {errors[name]}")
        result.setdefault("part_seconds", {})[name] = round(time.monotonic() - t0, 1)

    meshes: list[LanMesh] = []
    try:
        plain = plain_mesh(hosts)
        meshes.append(plain)
        secured, password = secured_mesh(hosts)
        meshes.append(secured)
        time.sleep(2.0)  # warm workers finish compiling
        part("tls", lambda: tls_ratio(plain, secured, password))
        part("default_mode_forgery", lambda: default_mode_forgeries(secured))
        secured.keep_logs(logs)
        secured.close()
        meshes.remove(secured)
        part("forgery", lambda: forgery_trial(plain))
        part("fuzz", lambda: fuzz_trial(plain))
        part("slow_subscriber", lambda: slow_trial(plain))
        part("recorder_crash", lambda: recorder_crash_trial(plain))
        part("worker_crash", lambda: worker_crash_trial(plain))
        part("simulator_crash", lambda: simulator_crash_trial(plain))
        part("hub_restart", lambda: hub_restart_trial(plain))
    finally:
        for mesh in meshes:
            mesh.keep_logs(logs)
            mesh.close()
        result["errors"] = errors
        Path(plan["out"]).write_text(json.dumps(result))


# -- the bench --------------------------------------------------------------------------------------------
TARGETS = {
    "slow_subscriber_other_session_rtf": 1.0,
    "slow_subscriber_failed_runs": 0,
    "hub_restart_failed_runs": 0,
    "forged_puts_effective": 0,
    "fuzz_internal_replies": 0,
    "tls_run_rtf_ratio": 0.95,
    "recorder_crash_loss_s": 0.1,
    "simulator_crash_runs_lost": 0,
    "worker_crash_results_kept": True,
    "frames_after_failed": 0,
    "default_mode_forgeries_effective": 0,
}


def meets(result: dict[str, Any]) -> bool:
    """Every figure measured and on target (a real-time RTF within 2 % of 1.0)."""
    r = result
    checks = [
        r.get("slow_subscriber_other_session_rtf") is not None
        and r["slow_subscriber_other_session_rtf"] >= 0.98,
        r.get("slow_subscriber_failed_runs") == 0,
        r.get("hub_restart_failed_runs") == 0,
        r.get("forged_puts_effective") == 0 and r.get("forged_other_effective") == 0,
        r.get("fuzz_internal_replies") == 0,
        r.get("tls_run_rtf_ratio") is not None and r["tls_run_rtf_ratio"] >= 0.95,
        r.get("recorder_crash_loss_s") is not None and r["recorder_crash_loss_s"] <= 0.1,
        r.get("simulator_crash_runs_lost") == 0,
        r.get("worker_crash_results_kept") is True,
        r.get("frames_after_failed") == 0,
        r.get("default_mode_forgeries_effective") == 0,
    ]
    return all(checks)


def run_lan_bench(as_json: bool) -> dict[str, Any] | None:
    t0 = time.monotonic()
    logs = Path(tempfile.mkdtemp(prefix="simecs-lan-"))
    lan: netns.Lan | None = None
    note = ""
    try:
        lan = netns.Lan(HOSTS).up()  # removes what it made if it fails
        hosts = Hosts.of(lan)
    except netns.NetnsUnavailable as exc:
        hosts = Hosts.loopback()
        note = f"network namespaces unavailable ({exc}): every host is this machine's loopback"
    out = logs / "result.json"
    plan = {**dataclasses.asdict(hosts), "out": str(out), "logs": str(logs)}
    proc: subprocess.Popen[bytes] | None = None
    try:
        argv = [*hosts.prefixes["client"], sys.executable, "-m", "simecs.benchmarks.lan"]
        proc = subprocess.Popen([*argv, "--inner", json.dumps(plan)], env=clean_env(), start_new_session=True)
        try:
            proc.wait(INNER_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            log(f"still running after {INNER_TIMEOUT_S:g} s: stopping it")
    finally:
        if proc is not None and proc.poll() is None:
            stop_inner(proc)
        if lan is not None:
            lan.down()  # kills whatever still runs on the hosts
    if not out.exists():
        code = proc.returncode if proc is not None else None
        print(f"simecs bench lan: no result (exit code {code}); node logs in {logs}", file=sys.stderr)
        return None
    inner = json.loads(out.read_text())
    result: dict[str, Any] = {"network": hosts.network}
    if note:
        result["network_note"] = note
    result["hosts"] = hosts.addresses
    for key in TARGETS:
        result[key] = inner.pop(key, None)
    result.update(inner)
    for key in ("slow_subscriber_other_session_rtf", "tls_run_rtf_ratio", "tls_run_wall_ratio"):
        if isinstance(result.get(key), float):
            result[key] = round(result[key], 3)
    result["targets"] = TARGETS
    result["meets_targets"] = meets(result)
    result["seconds"] = round(time.monotonic() - t0, 1)
    result["logs"] = str(logs)
    print_table(result)
    if as_json:
        print(json.dumps(result))
    return result


def stop_inner(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM lets the measuring process stop its nodes (its `finally`); SIGKILL if it hangs."""
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)


def _fmt(value: Any, spec: str = "") -> str:
    if value is None:
        return "null"
    return format(value, spec) if spec and isinstance(value, int | float) else str(value)


def print_table(r: dict[str, Any]) -> None:
    hosts = ", ".join(f"{h} {a}" for h, a in r["hosts"].items())
    print(f"simecs bench lan  (network: {r['network']}; hosts {hosts})")
    if r.get("network_note"):
        print(f"  NOTE {r['network_note']}")
    rows = [
        ("slow subscriber: other session RTF", _fmt(r["slow_subscriber_other_session_rtf"], ".3f"), "1.0"),
        ("slow subscriber: failed runs", _fmt(r["slow_subscriber_failed_runs"]), "0"),
        ("hub restart: failed runs", _fmt(r["hub_restart_failed_runs"]), "0"),
        (
            "forged puts effective",
            f"{_fmt(r['forged_puts_effective'])} of {_fmt(r.get('forged_puts_sent'))}"
            f" (+{_fmt(r.get('forged_other_effective'))} of {_fmt(r.get('forged_other_sent'))})",
            "0",
        ),
        (
            "fuzzing: internal replies",
            f"{_fmt(r['fuzz_internal_replies'])} of {_fmt(r.get('fuzz_sent'))}",
            "0",
        ),
        ("TLS run RTF ratio (secured/plain)", _fmt(r["tls_run_rtf_ratio"], ".3f"), ">= 0.95"),
        ("recorder crash: seconds lost", _fmt(r["recorder_crash_loss_s"], ".3f"), "<= 0.1"),
        ("simulator node crash: runs lost", _fmt(r["simulator_crash_runs_lost"]), "0"),
        ("worker crash: results kept", _fmt(r["worker_crash_results_kept"]), "True"),
        ("worker crash: frames after failed", _fmt(r["frames_after_failed"]), "0"),
        (
            "private default: forgeries effective",
            f"{_fmt(r['default_mode_forgeries_effective'])} of {_fmt(r.get('default_mode_forgeries_sent'))}",
            "0",
        ),
    ]
    for label, value, target in rows:
        print(f"  {label:38s} {value:>14s}   (target {target})")
    if "tls_rtf_plain" in r:
        print(
            f"    TLS: RTF plain {r['tls_rtf_plain']}, secured {r['tls_rtf_secured']}; "
            f"wall ratio {_fmt(r.get('tls_run_wall_ratio'), '.3f')}"
        )
    if r.get("forged_effects"):
        print(f"    forgeries that showed: {'; '.join(r['forged_effects'])}")
    if r.get("fuzz_note"):
        print(f"    fuzzing: {r['fuzz_note']}")
    if "fuzz_replies" in r:
        print(
            f"    fuzzing: replies {r['fuzz_replies']} in {r['fuzz_seconds']} s; nodes gone "
            f"{r['fuzz_nodes_gone']}; bystander run {r['fuzz_bystander_run']}"
        )
    if "recorder_restart_s" in r:
        print(
            f"    recorder killed at t = {r['recorder_killed_at_s']} s, back after "
            f"{r['recorder_restart_s']} s; missing t = {r['recorder_crash_missing']}; "
            f"files {r['recorder_crash_files']}"
        )
    if "hub_restart_incomplete_recordings" in r:
        print(
            f"    hub restart: recordings not equal to the results: {r['hub_restart_incomplete_recordings']}"
        )
    for name, error in r.get("errors", {}).items():
        print(f"  ERROR in {name}: {error}")
    print(f"  meets targets {r['meets_targets']}   ({r['seconds']} s; node logs in {r['logs']})")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="simecs bench lan and its helper processes")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--inner", help="(helper) run the measurements with this JSON plan")
    parser.add_argument("--slow-subscriber", metavar="ENDPOINT", help="(helper) be the slow subscriber")
    parser.add_argument("--status-file", default="")
    parser.add_argument("--seconds", type=float, default=120.0)
    args = parser.parse_args(argv)
    if args.inner:
        inner_main(json.loads(args.inner))
    elif args.slow_subscriber:
        slow_main(args.slow_subscriber, args.status_file, args.seconds)
    else:
        sys.exit(0 if run_lan_bench(args.json) is not None else 1)


if __name__ == "__main__":
    main()
