"""The simulation service end to end: proxy, simulator, hot-feedback as real processes on a real mesh,
driven by a client that uses only mesh/ types."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import zenoh
from simecs.mesh.client import NoReply, RemoteError, SessionClient
from simecs.mesh.process.config import MeshConfig
from simecs.mesh.protocol import codec, frames, keys
from simecs.mesh.protocol import messages as m

from .conftest import Mesh, Service, restart_every_node, start_service, wait_until

TARGET = [0.3, -0.2, 0.2, 0.1, -0.1, 0.1, 0.0]


def prepare(s: SessionClient, stop_time: float = 0.4, pacing: str = "fast", **settings: object) -> None:
    s.set_settings(stop_time=stop_time, output_interval=0.002, pacing=pacing, **settings)
    s.set_joint_path([(TARGET, 100, 100)])


class Recorder:
    """Collects what a session publishes, as any client would see it."""

    def __init__(self, s: SessionClient) -> None:
        self.full: list[frames.Frame] = []
        self.live: list[tuple[float, frames.Frame]] = []
        self.states: list[m.SessionState] = []
        self.layouts: list[m.RunLayout] = []
        self.watch = s.watch(
            on_full=self.full.append,
            on_live=lambda f: self.live.append((time.time(), f)),
            on_state=self.states.append,
            on_layout=self.layouts.append,
        )

    def close(self) -> None:
        self.watch.close()


@pytest.mark.shares_service
def test_whole_run(service: Service) -> None:
    c = service.client
    assert {s.id for s in c.list_models()} >= {"spider"}
    desc = c.describe("spider")
    s = c.create_session("ann", "spider")
    rec = Recorder(s)
    prepare(s, stop_time=0.4)
    run_id = s.run()
    state = s.wait_for(["finished", "failed", "aborted"], timeout=120, run_id=run_id)
    assert state.phase == "finished", state.reason
    assert state.progress == pytest.approx(1.0)
    wait_until(lambda: rec.full and rec.full[-1].final, what="final full frame")
    wait_until(lambda: rec.live and rec.live[-1][1].final, what="final live frame")
    # the state topic is its own stream: its last message may come after the last frames
    wait_until(lambda: rec.states and rec.states[-1].phase == "finished", what="finished state")
    rec.close()

    layout = rec.layouts[-1]
    assert layout.run_id == run_id and layout.columns[0] == "time"
    assert [v.name for v in desc.variables] == layout.columns[1 : 1 + len(desc.variables)]
    full = np.concatenate([f.rows for f in rec.full])
    assert full.shape == (201, len(layout.columns))  # t = 0, 0.002, ..., 0.4
    np.testing.assert_allclose(full[:, 0], np.linspace(0, 0.4, 201), atol=1e-9)

    # Full-resolution reload equals what the simulator computed and streamed.
    columns, rows = s.results(run_id)
    assert columns == layout.columns
    np.testing.assert_array_equal(rows, full)
    cols, some = s.results(run_id, ["joint1.q", "joint2.q"], t0=0.1, t1=0.2, every=5)
    assert cols == ["time", "joint1.q", "joint2.q"]
    picked = [0, layout.columns.index("joint1.q"), layout.columns.index("joint2.q")]
    np.testing.assert_array_equal(some, full[50:101:5][:, picked])
    assert [r.run_id for r in s.runs()] == [run_id]
    # The reply says what produced the run: the run's own context, as its layout announced it.
    att, _ = s.results_of(run_id, ["joint1.q"], t1=0.0)
    assert att.context == layout.context and att.run.run_id == run_id
    assert att.context is not None and att.context.settings.stop_time == pytest.approx(0.4)
    # a damaged description on disk costs the context, never the rows
    meta = service.data_dir / "results" / "ann" / s.id / f"{run_id}.json"
    stored = json.loads(meta.read_text())
    meta.write_text(json.dumps({**stored, "context": {"user": 5}}))
    att, again = s.results_of(run_id)
    assert att.context is None and again.shape == full.shape
    assert "stored context is unreadable" in service.mesh.log("simulator")

    # The last live frame is the last sample, restricted to the live columns.
    last_live = rec.live[-1][1].rows[-1]
    idx = [layout.columns.index(name) for name in layout.live_columns]
    np.testing.assert_array_equal(last_live, full[-1, idx])
    phases = [st.phase for st in rec.states]
    assert "running" in phases and phases[-1] == "finished"


@pytest.mark.shares_service
def test_two_sessions_are_isolated(service: Service) -> None:
    c = service.client
    a = c.create_session("ann", "spider")
    b = c.create_session("bob", "spider")
    a.set_settings(stop_time=0.3, output_interval=0.002, pacing="fast")
    b.set_settings(stop_time=0.5, output_interval=0.005, pacing="fast")
    a.set_joint_path([([0.3, 0, 0, 0, 0, 0, 0], 100, 100)])
    b.set_joint_path([([-0.3, 0, 0, 0, 0, 0, 0], 100, 100)])
    a.set_params({"joint1.ctrl.kp_pos": a.snapshot().values["joint1.ctrl.kp_pos"] * 0.5})
    rec_a, rec_b = Recorder(a), Recorder(b)
    ra, rb = a.run(), b.run()
    assert a.wait_for(["finished", "failed"], 120, ra).phase == "finished"
    assert b.wait_for(["finished", "failed"], 120, rb).phase == "finished"
    _, rows_a = a.results(ra, ["joint1.q_ref"])
    _, rows_b = b.results(rb, ["joint1.q_ref"])
    assert rows_a.shape[0] == 151 and rows_b.shape[0] == 101
    assert rows_a[-1, 1] > 0 > rows_b[-1, 1]
    assert a.snapshot().values != b.snapshot().values
    wait_until(lambda: rec_a.full and rec_a.full[-1].final and rec_b.full and rec_b.full[-1].final)
    rec_a.close()
    rec_b.close()
    assert sum(f.rows.shape[0] for f in rec_a.full) == 151
    assert sum(f.rows.shape[0] for f in rec_b.full) == 101
    # A foreign session id is unknown; so is ann's session under bob's keys (a session is reached
    # only under its own user's keys), and bob's list and results never show ann's.
    with pytest.raises(RemoteError) as err:
        c.session("ann", keys.new_session_id()).snapshot()
    assert err.value.code == "not_found"
    for request in (
        lambda s: s.snapshot(),
        lambda s: s.abort(),
        lambda s: s.set_params({}),
        lambda s: s.runs(),
    ):
        with pytest.raises(RemoteError) as err:
            request(c.session("bob", a.id))
        assert err.value.code == "not_found" and "bob has no session" in err.value.error.message
    assert [e.session for e in c.list_sessions("bob")] == [b.id]
    with pytest.raises((RemoteError, NoReply)):  # nobody holds results of bob's (unknown) session
        c.session("bob", a.id).results(ra)
    assert a.snapshot().state.phase == "finished"


@pytest.mark.shares_service
def test_pause_resume_abort_within_a_chunk(service: Service) -> None:
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=4.0, pacing="realtime")
    rec = Recorder(s)
    run_id = s.run()
    s.wait_for(["running"], 60, run_id)
    wait_until(lambda: rec.full and rec.full[-1].rows[-1, 0] > 0.3, timeout=30, what="0.3 s simulated")
    s.pause()
    paused = s.wait_for(["paused"], 10, run_id)
    n_at_pause = len(rec.full)
    time.sleep(0.6)
    # At most the chunk under way when the pause arrived follows.
    assert len(rec.full) - n_at_pause <= 1
    t_paused = rec.full[-1].rows[-1, 0]
    assert abs(t_paused - paused.sim_time) <= 0.026
    s.resume()
    s.wait_for(["running"], 10, run_id)
    wait_until(lambda: rec.full[-1].rows[-1, 0] > t_paused + 0.2, timeout=30, what="progress after resume")
    s.abort()
    state = s.wait_for(["aborted", "finished"], 10, run_id)
    assert state.phase == "aborted"
    wait_until(lambda: rec.full[-1].final, what="final frame after abort")
    assert rec.full[-1].rows.shape[0] == 0
    rec.close()
    # The aborted run's results are still there, up to where it stopped.
    _, rows = s.results(run_id, ["joint1.q"])
    assert 0.5 < rows[-1, 0] < 4.0
    with pytest.raises(RemoteError) as err:
        s.pause()
    assert err.value.code == "conflict"


@pytest.mark.parametrize("rate_hz", [20.0, 2.0])
@pytest.mark.shares_service
def test_decimated_rate_holds_from_the_first_frame_and_the_final_frame_goes(
    service: Service, rate_hz: float
) -> None:
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=3.0, pacing="realtime", live_rate_hz=rate_hz, live_vars=["joint1.q", "joint2.q"])
    rec = Recorder(s)
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    wait_until(lambda: rec.live and rec.live[-1][1].final, what="final live frame")
    # each key reaches the watch through its own queue: the final state may come after the frames
    wait_until(lambda: rec.states and rec.states[-1].phase == "finished", what="final state in the watch")
    rec.close()
    layout = rec.layouts[-1]
    assert layout.live_columns[:3] == ["time", "joint1.q", "joint2.q"]
    assert all(f.rows.shape[1] == len(layout.live_columns) for _, f in rec.live)
    times = np.array([t for t, f in rec.live if not f.final])
    # The hot-feedback node spaces live frames 1/R apart from a run's first frame on; here they are timed
    # on arrival, so the network's jitter (a few ms) is allowed for.
    first_second = np.count_nonzero(times < times[0] + 1.0 - 0.05)
    assert first_second <= rate_hz, f"{first_second} live frames in the run's first second at {rate_hz} Hz"
    # Any second of arrivals: R frames, and one late frame at either end of the window (a loaded CI
    # machine delivered 22 at 20 Hz once: two late frames bunched onto punctual ones).
    for start in times:
        assert np.count_nonzero((times >= start) & (times < start + 1.0)) <= rate_hz + 2
    # One frame late on the wire makes the next gap short (CI saw 17 ms at 20 Hz); a sender that bursts
    # puts three frames within one period, which no single late arrival can fake.
    spans = times[2:] - times[:-2]
    assert spans.min() >= 1.0 / rate_hz, (
        f"three live frames within {spans.min() * 1000:.1f} ms at {rate_hz} Hz"
    )
    if rate_hz >= 10:
        steady = times[(times > times[0] + 0.5) & (times < times[-1] - 0.5)]
        rate = (len(steady) - 1) / (steady[-1] - steady[0])
        assert 18.0 <= rate <= 22.0, f"live rate {rate:.1f} Hz, wanted 20 Hz +- 10 %"
    assert rec.live[-1][1].rows[-1, 0] == pytest.approx(3.0)


@pytest.mark.shares_service
def test_a_realtime_run_sends_a_frame_every_25_ms_each_at_its_time(service: Service) -> None:
    """A paced run simulates two frames per solver call (fewer wake-ups, cheaper runs) and still sends
    40 frames per second, each when it is due, not two at a time."""
    s = service.client.create_session("ann", "spider")
    prepare(s, stop_time=2.0, pacing="realtime")
    rec = Recorder(s)
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    wait_until(lambda: rec.full and rec.full[-1].final, what="final full frame")
    rec.close()
    # 2 s of samples every 2 ms, in 80 frames of at most 25 ms each
    assert len(rec.full) == 80 and rec.full[-1].rows[-1, 0] == pytest.approx(2.0)
    assert max(f.rows[-1, 0] - f.rows[0, 0] for f in rec.full) < 0.025 + 1e-9
    gaps = np.diff([f.wall_ns for f in rec.full]) / 1e6
    # sent in pairs, the gaps would be about 0 and 50 ms in turn
    assert np.count_nonzero(gaps < 5.0) < len(gaps) / 4, np.round(gaps, 1)
    assert 15.0 < float(np.median(gaps)) < 35.0, np.round(gaps, 1)


def test_a_first_run_starts_at_once_and_the_session_keeps_its_last_ten_runs(mesh: Mesh) -> None:
    """The simulator is ready only once a worker is warm: the first run of a new service finds one
    and does not wait for a worker to start (the simulator's log says which kind took it). A service
    of its own: on a shared one, the run before may have taken the warm worker."""
    # The host takes one run at a time, and a run handed to it would count against it for ten minutes
    # if nothing released it: only a run that frees its share as it ends lets the next one start.
    service = start_service(mesh, extra_simulator=("--max-runs", "1"), extra_proxy=("--reservation-s", "600"))
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=1.0, pacing="realtime")
    rec = Recorder(s)
    run_id = s.run()
    wait_until(lambda: rec.full, timeout=10, what="first frame")
    assert f"run {s.id}/{run_id} handed to warm worker" in service.mesh.log("simulator")
    s.wait_for(["finished"], 30, run_id)
    rec.close()
    prepare(s, stop_time=0.02, pacing="fast")
    for _ in range(11):
        # A bound against a hang only (a cold worker took 14 s on a loaded 2-core clone), far below
        # the reservation a run that ended and was not released would hold.
        s.wait_for(["finished"], 120, s.run())
    kept = [r.run_id for r in s.runs()]
    assert kept == [f"r{i}" for i in range(3, 13)]
    with pytest.raises(RemoteError) as err:
        s.results("r2")
    assert err.value.code == "not_found" and "r3" in err.value.error.message
    assert s.results("r3")[1].shape[0] > 0
    folder = service.data_dir / "results" / s.user / s.id
    assert sorted(p.name for p in folder.glob("*.npy")) == sorted(f"r{i}.npy" for i in range(3, 13))


@pytest.mark.shares_service
def test_results_selectors_are_strict(service: Service) -> None:
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=0.1)
    run_id = s.run()
    s.wait_for(["finished"], 30, run_id)
    for selector, field in (
        ("bogus=1", "bogus"),
        ("evry=10", "evry"),
        ("t0=nan", "t0"),
        ("t1=inf", "t1"),
        ("t0=abc", "t0"),
        ("every=0", "every"),
        ("vars=nope", "vars"),
    ):
        replies = list(c.z.get(f"{keys.results(s.user, s.id, run_id)}?{selector}", timeout=5))
        assert len(replies) == 1 and replies[0].err is not None, selector
        err = codec.loads(m.Error, replies[0].err.payload.to_bytes())
        assert (err.code, err.field) == ("bad_request", field), (selector, err)


def test_parameter_sets_and_sessions_survive_a_restart_of_every_node(mesh: Mesh) -> None:
    svc = start_service(mesh)
    c = svc.client
    s = c.create_session("ann", "spider")
    values = s.set_params({"joint2.ctrl.kp_pos": 33.0, "link2.length": 0.9})
    s.save_param_set("stiff")
    s.set_initial([0.1, 0, 0, 0, 0, 0, 0])
    restart_every_node(mesh)
    c = mesh.client()
    back = c.session(s.user, s.id).snapshot()
    assert back.values == values and back.initial[0] == 0.1
    other = c.create_session("ann", "spider")
    assert other.list_param_sets() == ["stiff"]
    assert other.load_param_set("stiff") == values
    assert c.create_session("bob", "spider").list_param_sets() == []


@pytest.mark.shares_service
def test_bad_values_are_refused_with_the_reason_and_nothing_applied(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    before = s.snapshot().values
    cases = [
        ({"joint1.ctrl.kp_pos": 1e9}, "values.joint1.ctrl.kp_pos", "outside"),
        ({"joint1.nope": 1.0}, "values.joint1.nope", "unknown parameter"),
        ({"joint2.ctrl.kp_pos": 10.0, "link1.length": -5.0}, "values.link1.length", "outside"),
    ]
    for values, field, words in cases:
        with pytest.raises(RemoteError) as err:
            s.set_params(values)
        assert (
            err.value.code == "bad_request" and err.value.field == field and words in err.value.error.message
        )
    assert s.snapshot().values == before
    with pytest.raises(RemoteError) as err:
        s.set_initial([0.0] * 6)
    assert err.value.field == "joints"
    with pytest.raises(RemoteError) as err:
        s.set_initial([100.0] + [0.0] * 6)
    assert err.value.field == "joints[0]"
    with pytest.raises(RemoteError) as err:
        s.run()
    assert "no command" in err.value.error.message
    with pytest.raises(RemoteError) as err:
        s.command(m.SetCommand(m.CartesianPath([m.CartesianNode([9, 0, 0], [0, 0, 0], "ptp")])))
    assert (err.value.code, err.value.field) == ("bad_request", "command.nodes[0]")
    assert "reach" in err.value.error.message
    with pytest.raises(RemoteError) as err:
        s.load_param_set("never-saved")
    assert err.value.code == "not_found"


HOSTILE = [
    (b"", ""),
    (b"\x00\xff", ""),
    (b"{}", "*"),
    (b'{"op":"run","v":2}', "*"),
    (b'{"op":"run"}', "*"),
    (b"[" * 5000, ""),
    (b'{"op":"get_session","v":1,"x":"\xed\xa0\x80"}', ""),
]


@pytest.mark.shares_service
def test_hostile_payloads_get_errors_naming_the_field_and_nodes_survive(service: Service) -> None:
    """One service takes them all in turn: each is answered, and none leaves a node the worse for it."""
    c = service.client
    run_key = keys.simulator_run("simulator-t")
    sessions = []
    for payload, field in HOSTILE:
        s = c.create_session("ann", "spider")
        sessions.append(s)
        seal = service.mesh.seal.mac(run_key, payload)  # a run request as the proxy would send it
        for key, attachment in (
            (keys.cmd(s.user, s.id), None),
            (keys.sessions("ann"), None),
            (run_key, seal),
        ):
            replies = list(c.z.get(key, payload=payload or None, attachment=attachment, timeout=5))
            assert len(replies) == 1 and replies[0].err is not None, (payload, key)
            err = codec.loads(m.Error, replies[0].err.payload.to_bytes())
            assert err.code == "bad_request" and err.message, (payload, key, err)
            assert err.field != "" if field == "*" else err.field == field, (payload, key, err)
        # The same request from anyone but the proxy is refused before it is read.
        replies = list(c.z.get(run_key, payload=payload or None, timeout=5))
        assert codec.loads(m.Error, replies[0].err.payload.to_bytes()).code == "forbidden", payload
        assert {r for r, _ in c.live_nodes()} >= {"proxy", "simulator", "hotfeedback"}, payload
    assert [s.snapshot().state.phase for s in sessions] == ["created"] * len(HOSTILE)
    # and the service still runs
    prepare(sessions[0], stop_time=0.1)
    assert sessions[0].wait_for(["finished", "failed"], 60, sessions[0].run()).phase == "finished"


@pytest.mark.shares_service
def test_numerical_failure_ends_the_run_with_the_reason(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    prepare(s, stop_time=1.0, step=0.01)  # far beyond the drives' stability limit
    run_id = s.run()
    state = s.wait_for(["finished", "failed"], 60, run_id)
    assert state.phase == "failed"
    assert "broke down" in state.reason and "t = " in state.reason and "smaller step" in state.reason
    assert s.runs()[-1].phase == "failed"
    # The session is usable again at once.
    prepare(s, stop_time=0.1)
    assert s.wait_for(["finished", "failed"], 60, s.run()).phase == "finished"


@pytest.mark.shares_service
def test_notices_about_a_run_reach_its_state(service: Service) -> None:
    c = service.client
    s = c.create_session("ann", "spider")
    prepare(s, stop_time=1.0, pacing="realtime")
    run_id = s.run()
    s.wait_for(["running"], 30, run_id)
    key = keys.notices(s.user, s.id)

    def as_recorder(payload: bytes) -> None:  # sealed as the service's recorder would
        c.z.put(key, payload, attachment=service.mesh.seal.mac(key, payload))

    notice = m.Notice(session=s.id, run_id=run_id, source="recorder", message="dropped samples")
    for _ in range(2):  # the same notice twice is listed once
        as_recorder(codec.dumps(notice))
    as_recorder(codec.dumps(m.Notice(s.id, "r99", "recorder", "another run")))
    as_recorder(b"not json")  # refused, logged, nothing else happens
    forged = m.Notice(s.id, run_id, "recorder", "re-login at http://evil.example")
    c.z.put(key, codec.dumps(forged))  # without the seal: not from the service, ignored
    wait_until(lambda: s.snapshot().state.warnings, what="warning in state")
    assert s.wait_for(["finished"], 30, run_id).warnings == ["recorder: dropped samples"]
    assert "without a valid service seal" in service.mesh.log("proxy")
    prepare(s, stop_time=0.1)
    second = s.run()
    assert s.wait_for(["finished"], 30, second).warnings == []


@pytest.mark.shares_service
def test_a_client_with_the_service_key_takes_no_forged_answer(service: Service) -> None:
    """A peer answering queries in place of the proxy (the library, a session's commands), quicker than
    it: a client holding the service's key ignores the unsealed answers and takes the proxy's (issue 33,
    2); one without the key would take the first to come."""
    c = service.client
    assert c.seal is not None
    s = c.create_session("ann", "spider")
    forger = zenoh.open(MeshConfig(connect=[service.mesh.endpoint]).to_zenoh())
    forged = codec.dumps(m.Ok(data={"models": [], "session": "forged"}))
    answered: list[str] = []

    def answer(query: zenoh.Query) -> None:
        answered.append(str(query.key_expr))
        query.reply(query.key_expr, forged)  # at once, unsealed

    try:
        queryables = [forger.declare_queryable(k, answer) for k in (keys.LIBRARY, keys.cmd("ann", s.id))]
        wait_until(lambda: c.list_models() is not None and bool(answered), 10, what="the forger asked")
        for _ in range(5):
            assert c.list_models(), "the forged empty library was taken"
            assert s.snapshot().session == s.id
        assert len(answered) >= 10
        for q in queryables:
            q.undeclare()
    finally:
        forger.close()
