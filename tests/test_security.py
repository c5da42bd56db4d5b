"""LAN deployment features from plain zenoh configuration: user/password at the hub, access roles."""

from __future__ import annotations

import json
import threading

import pytest
from simecs.mesh import messages as m
from simecs.mesh.client import MeshClient, NoReply
from simecs.mesh.config import MeshConfig, open_session
from simecs.testing.launch import LocalMesh

VIEWER_ACL = {
    "enabled": True,
    "default_permission": "allow",
    "rules": [
        {
            "id": "no_commands",
            "messages": ["query", "put"],
            "flows": ["ingress", "egress"],
            "permission": "deny",
            "key_exprs": [f"simecs/u/*/sessions/*/{k}" for k in ("cmd", "control", "jog")],
        }
    ],
    "subjects": [{"id": "viewers", "usernames": ["watcher"]}],
    "policies": [{"rules": ["no_commands"], "subjects": ["viewers"]}],
}


@pytest.fixture
def secured() -> LocalMesh:
    mesh = LocalMesh()
    users = mesh.folder / "users.txt"
    users.write_text("server:s3rver\nann:ann-pw\nwatcher:look\n")
    (mesh.folder / "hub.json5").write_text(
        json.dumps({"users_file": str(users), "access_control": VIEWER_ACL})
    )
    (mesh.folder / "server.json5").write_text(json.dumps({"user": "server", "password": "s3rver"}))
    mesh.spawn(
        "hub", "simecs.nodes.hub", "--listen", mesh.endpoint, "--mesh-config", str(mesh.folder / "hub.json5")
    )
    mesh.clients.append(MeshClient.open(user_config(mesh, "server", "s3rver")))
    mesh.start(
        "proxy", "--data-dir", str(mesh.folder / "d"), "--mesh-config", str(mesh.folder / "server.json5")
    )
    try:
        yield mesh
    finally:
        mesh.close()


def user_config(mesh: LocalMesh, user: str, password: str) -> MeshConfig:
    # A refused login retries until connect/timeout_ms: keep it short in tests.
    return MeshConfig(
        connect=[mesh.endpoint], user=user, password=password, extra={"connect/timeout_ms": {"client": 800}}
    )


@pytest.mark.parametrize(("user", "password"), [("ann", "wrong"), ("eve", "ann-pw"), ("", "")])
def test_unknown_users_cannot_join(secured: LocalMesh, user: str, password: str) -> None:
    with pytest.raises(RuntimeError, match="cannot join the mesh"):
        open_session(user_config(secured, user, password), deadline_s=1.0)


def test_a_viewer_watches_but_cannot_command(secured: LocalMesh) -> None:
    with MeshClient.open(user_config(secured, "ann", "ann-pw")) as ann:
        session = ann.create_session("ann", "spider")
        session.set_params({"joint1.ctrl.kp_pos": 42.0})
        with MeshClient.open(user_config(secured, "watcher", "look"), timeout=2.0) as watcher:
            assert [s.id for s in watcher.list_models()]  # reading the library is allowed
            seen = threading.Event()
            states: list[m.SessionState] = []

            def on_state(st: m.SessionState) -> None:
                states.append(st)
                seen.set()

            with watcher.session("ann", session.id).watch(on_state=on_state):
                assert seen.wait(5.0), "the viewer role may subscribe to state"
                with pytest.raises(NoReply):
                    watcher.session("ann", session.id).set_params({"joint1.ctrl.kp_pos": 1.0})
                with pytest.raises(NoReply):
                    watcher.session("ann", session.id).snapshot()
            assert states[-1].session == session.id
        assert session.snapshot().values["joint1.ctrl.kp_pos"] == 42.0
