"""Key builders refuse what could escape a session; mesh configuration is safe by default."""

from __future__ import annotations

import pytest
from simecs.mesh.process import config
from simecs.mesh.protocol import keys


def test_session_ids_are_unguessable_and_valid() -> None:
    ids = {keys.new_session_id() for _ in range(1000)}
    assert len(ids) == 1000
    assert all(keys.is_session_id(i) for i in ids)
    # every one names a recording too (<session>_<run> must be a name: no leading - or _)
    assert all(keys.check_name(keys.recording_name(i, "r1"), "recording name") for i in ids)
    assert not keys.is_session_id("_" + "a" * 21) and not keys.is_session_id("-" + "a" * 21)


@pytest.mark.parametrize("bad", ["", "*", "**", "a/b", "$*", "@node", "x" * 22 + "/", "short"])
def test_session_keys_refuse_bad_ids(bad: str) -> None:
    with pytest.raises(ValueError):
        keys.cmd("ann", bad)


@pytest.mark.parametrize("bad", ["", "*", "**", "a/b", "$*", "@run", "ann bob", "x" * 65])
def test_user_keys_refuse_bad_user_names(bad: str) -> None:
    sid = keys.new_session_id()
    for build in (lambda: keys.cmd(bad, sid), lambda: keys.sessions(bad), lambda: keys.user_space(bad)):
        with pytest.raises(ValueError):
            build()


@pytest.mark.parametrize("bad", ["", "*", "a/b", "../x", "-x", "x" * 65, "a b"])
def test_names_refuse_wildcards_and_paths(bad: str) -> None:
    with pytest.raises(ValueError):
        keys.model(bad)


def test_every_chunk_of_every_key_refuses_a_bad_value_by_name() -> None:
    """A query on any key with a chunk no name can have is a KeyProblem naming that chunk (answered
    `bad_request`), never an error of our own (a chunk the checks did not know answered `internal`)."""
    for spec in keys.KEYS.values():
        for chunk in spec.chunks:
            values = {c: "ok" for c in spec.chunks}
            if "session" in values:
                values["session"] = keys.new_session_id()
            values[chunk] = "a b"
            key = spec.pattern
            for c, v in values.items():
                key = key.replace(f"<{c}>", v)
            with pytest.raises(keys.KeyProblem) as problem:
                keys.parse(spec.name, key)
            assert problem.value.chunk == chunk, (spec.name, chunk)


def test_owner_of_parses_back() -> None:
    sid = keys.new_session_id()
    built = (keys.cmd, keys.state, keys.vars_full, lambda u, s: keys.results(u, s, "r3"))
    for key in (build("ann", sid) for build in built):
        assert keys.owner_of(key) == ("ann", sid)
        assert key.startswith(keys.user_space("ann")[:-2])
    others = (keys.LIBRARY, keys.sessions("ann"), keys.recording("ann", "x"), "simecs/u/*/sessions/x")
    for not_per_session in others:
        with pytest.raises(ValueError):
            keys.owner_of(not_per_session)


def test_liveliness_tokens_are_under_at_chunks() -> None:
    assert "/@node/" in keys.node_token("proxy", "p1")
    assert "/@run/" in keys.run_token("ann", keys.new_session_id(), "r1")


def test_defaults_are_safe() -> None:
    entries = config.MeshConfig().zenoh_entries()
    assert entries["scouting/multicast/enabled"] is False
    assert entries["transport/shared_memory/enabled"] is False
    assert entries["listen/endpoints"] == []
    assert entries["connect/endpoints"] == [config.DEFAULT_HUB]
    assert config.DEFAULT_HUB.startswith("tcp/127.0.0.1:")


def test_file_then_environment(tmp_path) -> None:  # noqa: ANN001
    path = tmp_path / "mesh.json5"
    path.write_text("{ // comments allowed\n mode: 'peer', listen: ['tcp/127.0.0.1:0'], lease_ms: 500 }")
    cfg = config.load(path, env={"SIMECS_CONNECT": "tcp/127.0.0.1:1,tcp/127.0.0.1:2", "SIMECS_USER": "ann"})
    assert cfg.mode == "peer" and cfg.lease_ms == 500
    assert cfg.connect == ["tcp/127.0.0.1:1", "tcp/127.0.0.1:2"]
    assert cfg.zenoh_entries()["transport/auth/usrpwd/user"] == "ann"
    cfg.to_zenoh()  # zenoh accepts every entry


def test_bad_config_file_is_named(tmp_path) -> None:  # noqa: ANN001
    path = tmp_path / "bad.json5"
    path.write_text("{ mdoe: 'peer' }")
    with pytest.raises(ValueError, match="unknown key 'mdoe'"):
        config.load(path, env={})
    path.write_text("{ not json")
    with pytest.raises(ValueError, match="bad.json5"):
        config.load(path, env={})


def test_tls_entries() -> None:
    cfg = config.MeshConfig(tls=config.TlsConfig(root_ca_certificate="/ca.pem", enable_mtls=True))
    entries = cfg.zenoh_entries()
    assert entries["transport/link/tls/root_ca_certificate"] == "/ca.pem"
    assert entries["transport/link/tls/enable_mtls"] is True
