"""A secured mesh (`simecs up --secure`): TLS, users with passwords, and access rules generated from the
key table, with real nodes behind a real hub. Each user reaches only their own sessions and recordings,
a watcher reads but commands nothing, nobody can pose as the service, an unknown user cannot join."""

from __future__ import annotations

import json
import threading
import time

import pytest
import zenoh
from simecs.mesh.client import NoReply
from simecs.mesh.process.config import MeshConfig, open_session
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.secure import SERVICE_USER

from .conftest import Secured, wait_until

TARGET = [0.3, -0.2, 0.2, 0.1, -0.1, 0.1, 0.0]


def test_the_generated_hub_configuration_is_private_and_complete(secured: Secured) -> None:
    folder = secured.folder.dir
    for name in (
        "users.json",
        "service.json",
        "hub-users.txt",
        "hub.json5",
        "node.json5",
        "ca.key",
        "hub.key",
    ):
        assert (folder / name).stat().st_mode & 0o077 == 0, name  # its owner's only
    hub = json.loads((folder / "hub.json5").read_text())
    assert hub["access_control"]["default_permission"] == "deny"
    users = (folder / "hub-users.txt").read_text().split()
    assert sorted(u.split(":")[0] for u in users) == sorted(["ann", "bob", "eve", SERVICE_USER])


def test_unknown_users_and_wrong_passwords_cannot_join(secured: Secured) -> None:
    for user, password in [("ann", "wrong-password"), ("mallory", "ann-pw-12"), ("", "")]:
        cfg = secured.mesh.config.as_user(user, password, 800)
        with pytest.raises(RuntimeError, match="cannot join the mesh"):
            open_session(cfg, deadline_s=1.0)
    plain = MeshConfig(connect=[secured.mesh.endpoint], extra={"connect/timeout_ms": {"client": 800}})
    with pytest.raises(RuntimeError, match="cannot join the mesh"):  # no TLS, no name: not at all
        open_session(plain, deadline_s=1.0)
    assert secured.login("ann").list_models()  # the right name and password still join


def test_a_user_works_on_their_own_sessions_through_tls_and_the_rules(secured: Secured) -> None:
    ann = secured.login("ann")
    assert [d.id for d in ann.list_models()]  # the library is public
    s = ann.create_session("ann", "spider")
    s.set_settings(stop_time=0.3, output_interval=0.002, pacing="fast")
    s.set_joint_path([(TARGET, 100, 100)])
    states: list[m.SessionState] = []
    with s.watch(on_state=states.append):
        run_id = s.run()
        assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    assert any(st.phase == "running" for st in states)  # her own state reaches her
    _cols, rows = s.results(run_id)
    assert rows.shape[0] == 151
    name = keys.recording_name(s.id, run_id)
    wait_until(lambda: name in {r.name for r in ann.recordings("ann")}, timeout=20, what="recording")
    assert len(ann.download_recording("ann", name)) > 0
    assert [e.session for e in ann.list_sessions("ann")] == [s.id]


def test_other_users_reach_nothing_of_a_session_and_cannot_pose_as_the_service(secured: Secured) -> None:
    ann, bob = secured.login("ann"), secured.login("bob")
    bob_elsewhere = secured.login("bob")  # his listeners (in his querying session they would hear him)
    s = ann.create_session("ann", "spider")
    s.set_params({"joint1.ctrl.kp_pos": 42.0})
    seen: list[str] = []
    posed = threading.Event()

    def pose(query: zenoh.Query) -> None:  # bob's fake proxy: the hub never brings him a query
        posed.set()
        query.reply(query.key_expr, codec.dumps(m.Ok(data=None)))

    z = bob_elsewhere.z
    entities = [
        z.declare_subscriber(f"{keys.USERS}/**", lambda smp: seen.append(str(smp.key_expr))),
        z.declare_subscriber(keys.state("ann", s.id), lambda smp: seen.append(str(smp.key_expr))),
        z.declare_queryable(keys.wildcard("cmd"), pose),
        z.declare_queryable(keys.cmd("ann", s.id), pose),
    ]
    try:
        time.sleep(0.5)
        for request in (lambda c: c.snapshot(), lambda c: c.set_params({"joint1.ctrl.kp_pos": 1.0})):
            with pytest.raises(NoReply):  # not even refused: the hub does not let it through
                request(bob.session("ann", s.id))
        with pytest.raises(NoReply):
            bob.list_sessions("ann")
        with pytest.raises(NoReply):
            bob.recordings("ann")
        bob.z.put(keys.jog("ann", s.id), b"{}")
        bob.z.put(keys.state("ann", s.id), codec.dumps(m.SessionState(s.id, "failed", 99)))
        # ann's own requests are answered by the proxy alone, her state by the service alone
        replies = list(ann.z.get(keys.cmd("ann", s.id), payload=codec.dumps(m.GetSession()), timeout=3))
        assert len(replies) == 1 and replies[0].ok is not None
        s.set_params({"joint1.ctrl.kp_pos": 43.0})
        time.sleep(0.5)
    finally:
        for e in entities:
            e.undeclare()
    assert seen == [] and not posed.is_set()
    snap = s.snapshot()
    assert snap.values["joint1.ctrl.kp_pos"] == 43.0 and snap.state.phase == "configured"
    # bob's own space works as usual
    assert bob.create_session("bob", "spider").snapshot().user == "bob"


def test_a_watcher_reads_every_session_and_commands_nothing(secured: Secured) -> None:
    ann, eve = secured.login("ann"), secured.login("eve")
    s = ann.create_session("ann", "spider")
    s.set_settings(stop_time=0.2, output_interval=0.002, pacing="fast")
    s.set_joint_path([(TARGET, 100, 100)])
    run_id = s.run()
    assert s.wait_for(["finished", "failed"], 60, run_id).phase == "finished"
    watched = eve.session("ann", s.id)
    states: list[m.SessionState] = []
    with watched.watch(on_state=states.append):
        wait_until(lambda: states, timeout=5, what="ann's state seen by the watcher")
    assert states[-1].phase == "finished"
    assert [r.run_id for r in watched.runs()] == [run_id]  # reading runs and results is allowed
    assert watched.results(run_id)[1].shape[0] == 101
    for request in (
        lambda: watched.snapshot(),
        lambda: watched.abort(),
        lambda: eve.create_session("eve", "spider"),
        lambda: eve.download_recording("ann", keys.recording_name(s.id, run_id)),
    ):
        with pytest.raises(NoReply):
            request()
    assert s.snapshot().state.phase == "finished"
