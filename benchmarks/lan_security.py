"""`simecs bench lan`, parts 1-3: what the seal and the access rules cost (TLS) and stop (forgeries,
fuzzing). lan.py says what each figure is.
"""

from __future__ import annotations

import importlib
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from simecs.mesh.client import MeshClient
from simecs.mesh.process.config import MeshConfig, TlsConfig
from simecs.mesh.protocol import frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.local_mesh import wait_until

from .lan_mesh import ENDED, OUTPUT, LanMesh, live_nodes, prepared, recording_matches, sim_time_above

TLS_STOP = 15.0  # simulated s of each as-fast-as-possible run (~1 s of wall time)
TLS_PAIRS = 5
QUIET_BUSY = 0.2  # between runs: until at most this share of the CPUs is busy (the next warm worker
QUIET_MAX_S = 8.0  # starts meanwhile), for at most this long
FORGERY_ROUNDS = 3
FORGED_VALUE = 7.0  # what testing/forgery.py puts in its forged frames
FUZZ_COUNT, FUZZ_DEADLINE_S = 3000, 45.0
FUZZ_BYSTANDER_STOP = 15.0


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
    from simecs.nodes.recording import mcapread

    return mcapread.has_footer(path)
