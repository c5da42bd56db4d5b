"""A well-formed message from the wrong peer changes nothing: another client, without the service key,
forges every service key of a user's running session, sends a run request straight to the simulator and
poses as a simulator, and the run, its state, results and recording are as if it had not."""

from __future__ import annotations

import time

import numpy as np
import pytest
from simecs.mesh.client import MeshClient, RemoteError
from simecs.mesh.process.config import MeshConfig
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.testing import forgery

from .conftest import Mesh, start_service, wait_until
from .test_resilience import assert_recording_is_the_results, prepared


def test_forged_messages_change_nothing(mesh: Mesh) -> None:
    start_service(mesh)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    client = mesh.client()
    # A plain client of the same hub: no service key (MeshConfig without service_key_file).
    with MeshClient.open(MeshConfig(connect=[mesh.endpoint])) as attacker:
        fake = forgery.FakeSimulator(attacker.z)
        try:
            wait_until(lambda: ("simulator", forgery.FAKE_SIMULATOR) in client.live_nodes(), what="fake")
            s = prepared(client, "ann", 2.0, "realtime")
            states: list[m.SessionState] = []
            with s.watch(on_state=states.append):
                runs = [s.run()]
                wait_until(lambda: s.snapshot().state.sim_time > 0.2, timeout=30, what="run under way")
                width = len(client.describe("spider").variables) + 1
                sent = 0
                for _ in range(3):
                    sent += forgery.forge(attacker.z, "ann", s.id, runs[0], 1, width)
                    time.sleep(0.2)
                replies = forgery.direct_run_request(attacker.z, "simulator-t", "ann", s.id, "r9")
                assert [codec.loads(m.Error, r.err.payload.to_bytes()).code for r in replies] == ["forbidden"]
                end = s.wait_for(["finished", "failed", "aborted"], 60, runs[0])
                time.sleep(0.5)  # anything the forgeries could still cause
            # Runs are placed by the hosts' sealed statuses (their load): the fake host's status carries
            # no seal, so it is never offered a run, and every run goes to the real host.
            s.set_settings(stop_time=0.1, output_interval=0.002, pacing="fast")
            for _ in range(2):
                runs.append(s.run())
                assert s.wait_for(["finished", "failed", "aborted"], 60, runs[-1]).phase == "finished"
            assert fake.offered == 0
        finally:
            fake.close()
    assert sent > 30
    assert end.phase == "finished" and end.sim_time == 2.0 and end.warnings == [], end
    assert {st.phase for st in states} <= {"configured", "queued", "running", "finished"}  # no pause
    info = {r.run_id: r for r in s.runs()}[runs[0]]
    assert info.phase == "finished" and info.recording == ""
    _columns, rows = s.results(runs[0])
    assert rows.shape[0] == 1001 and np.all(np.diff(rows[:, 0]) > 0)
    assert 7.0 not in rows[:5, 1:]  # none of the forged samples
    assert_recording_is_the_results(mesh, s, runs[0])
    assert s.snapshot().values["joint1.ctrl.kp_pos"] != 1.0
    assert [r.run_id for r in s.runs()] == runs  # the direct request started nothing
    assert "without a valid service seal" in mesh.log("proxy")


def test_a_peers_run_token_does_not_fail_another_users_run(mesh: Mesh) -> None:
    """Liveliness tokens carry no seal: a peer that declares and drops a run's token (before its worker
    is up, and while it runs) changes nothing; the run finishes."""
    start_service(mesh)
    client = mesh.client()
    with MeshClient.open(MeshConfig(connect=[mesh.endpoint])) as attacker:
        s = prepared(client, "ann", 1.5, "realtime")
        for run_id in ("r1", "r2", "r3"):  # predictable names, dropped before their run starts
            attacker.z.liveliness().declare_token(keys.run_token("ann", s.id, run_id)).undeclare()
        run = s.run()
        attacker.z.liveliness().declare_token(keys.run_token("ann", s.id, run)).undeclare()
        wait_until(lambda: s.snapshot().state.sim_time > 0.3, timeout=30, what="run under way")
        attacker.z.liveliness().declare_token(keys.run_token("ann", s.id, run)).undeclare()
        end = s.wait_for(["finished", "failed", "aborted"], 60, run)
    assert end.phase == "finished", end


def test_answers_from_the_wrong_peer_are_not_taken(mesh: Mesh) -> None:
    """A peer without the service key answers queries in place of the simulator and the recorder (for a
    run and a recording that do not exist, so that only the service's refusal competes with it): a
    client holding the seal, the proxy (a replay's recording) and the simulator take none of it."""
    start_service(mesh)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    client = mesh.client()
    s = prepared(client, "ann", 0.2, "fast")
    run = s.run()
    assert s.wait_for(["finished", "failed", "aborted"], 60, run).phase == "finished"
    real = keys.recording_name(s.id, run)
    wait_until(lambda: real in [r.name for r in client.recordings("ann")], timeout=30, what="the recording")
    with MeshClient.open(MeshConfig(connect=[mesh.endpoint])) as plain:  # no service key: takes any answer
        _, described = plain.request_binary(keys.results("ann", s.id, run), m.ResultsAttachment)
        fake = forgery.FakeAnswers(plain.z, "ann", s.id, "r9", "ghost", described)
        try:
            # the forger is heard: a client without the seal cannot tell its answers from the service's
            wait_until(lambda: plain.session("ann", s.id).results("r9")[1][0, 1] == 7.0, what="forger heard")
            assert plain.download_recording("ann", "ghost") == b"not an mcap"
            for ask in (lambda: s.results("r9"), lambda: client.download_recording("ann", "ghost")):
                with pytest.raises(RemoteError) as refused:
                    ask()
                assert refused.value.code == "not_found"
            with pytest.raises(RemoteError) as refused:  # the proxy asks the recorder, sealed, for it
                s.replay("ghost")
            assert refused.value.code == "not_found", refused.value
            for _ in range(5):  # the real answers still come, sealed, whoever else answers
                assert s.results(run)[1][0, 1] != 7.0
                assert client.download_recording("ann", real)[:8] == b"\x89MCAP0\r\n"
            assert fake.asked >= 2 + 2 + 1
        finally:
            fake.close()
    assert [r.run_id for r in s.runs()] == [run]  # the replay of a forged recording started nothing
