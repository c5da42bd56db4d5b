"""`simecs up` headless: ready, restarts a killed node, stops everything on Ctrl-C; the CLI's help."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
from simecs.mesh.client import MeshClient, NoReply
from simecs.mesh.process.config import MeshConfig, load, open_session

from .conftest import mesh_env, wait_until

SIMECS = [sys.executable, "-m", "simecs.nodes.tools.cli"]


def descendants(pid: int) -> set[int]:
    """Every living process whose ancestry leads to `pid`."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
                parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    out, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier} - out
        out |= frontier
    return out


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


class Up:
    """`simecs up` with its defaults (private), headless, on a unix socket; a second user, bob, added
    before it starts."""

    def __init__(self, folder: Path) -> None:
        from simecs.nodes.secure import SecureFolder

        self.hub = f"unixsock-stream/{folder}/hub.sock"
        self.client_file = folder / "data" / "client.json5"  # this machine's user's, written by up
        self.bob_password = SecureFolder(folder / "data" / "secure").add_user("bob")
        argv = [
            *SIMECS,
            "up",
            "--hub",
            self.hub,
            "--no-viewer",
            "--data-dir",
            str(folder / "data"),
            "--recordings",
            str(folder / "rec"),
        ]
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=mesh_env(), text=True
        )
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def text(self) -> str:
        return "\n".join(self.lines)


@pytest.fixture
def up() -> Up:
    folder = Path(tempfile.mkdtemp(prefix="smu"))
    u = Up(folder)
    try:
        yield u
    finally:
        if u.proc.poll() is None:
            for pid in descendants(u.proc.pid):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            u.proc.kill()
        u.proc.wait(5)
        shutil.rmtree(folder, ignore_errors=True)


def test_up_ready_restart_and_clean_stop(up: Up) -> None:
    wait_until(lambda: "simecs is up" in up.text(), timeout=90, what="banner")
    client = MeshClient.open(load(str(up.client_file)))
    try:
        roles = {r for r, _ in client.live_nodes()}
        assert roles >= {"hub", "proxy", "simulator", "hotfeedback"}
        assert client.list_models()
        # SIGKILL a node: the supervisor reports it and starts it again.
        node = next(n for r, n in client.live_nodes() if r == "hotfeedback")
        pid = int(node.rsplit("-", 1)[1])
        os.kill(pid, signal.SIGKILL)
        wait_until(lambda: "hotfeedback exited" in up.text(), timeout=10, what="crash report")
        wait_until(
            lambda: any(r == "hotfeedback" and n != node for r, n in client.live_nodes()),
            timeout=60,
            what="hotfeedback restarted",
        )
        assert "restarted hotfeedback" in up.text()
    finally:
        client.close()
    family = descendants(up.proc.pid)
    assert len(family) >= 5  # hub, proxy, simulator (+ warm worker), hotfeedback
    t0 = time.monotonic()
    up.proc.send_signal(signal.SIGINT)
    up.proc.wait(10)
    assert time.monotonic() - t0 < 5.0
    assert up.proc.returncode == 0
    wait_until(lambda: not any(alive(p) for p in family), timeout=2, what="no process left")
    assert "simecs: stopped" in up.text()


def test_up_is_private_and_its_clients_need_no_flags(up: Up) -> None:
    """The default is private: this machine's user is made, with a client file only they can read,
    which `simecs ls` finds alone; a client without a password is not let in; another user (bob) with
    his own password does not reach this user's sessions (issue 33, 2)."""
    wait_until(lambda: "simecs is up" in up.text(), timeout=90, what="banner")
    assert "private" in up.text() and "OPEN" not in up.text()
    assert up.client_file.stat().st_mode & 0o077 == 0  # the owner's only
    mine = load(str(up.client_file))
    assert mine.user and mine.password and f"you are {mine.user} (password {mine.password})" in up.text()
    with MeshClient.open(mine) as client:
        s = client.create_session(mine.user, "spider")
        env = {**mesh_env(), "SIMECS_CLIENT_CONFIG": str(up.client_file)}
        out = subprocess.run([*SIMECS, "ls"], capture_output=True, text=True, timeout=30, env=env)
        assert out.returncode == 0, out.stderr
        for role in ("hub/", "proxy/", "simulator/", "hotfeedback/"):
            assert role in out.stdout
        assert s.id in out.stdout and "created" in out.stdout

        stranger = MeshConfig(connect=[up.hub], extra={"connect/timeout_ms": {"client": 2000}})
        with pytest.raises(RuntimeError, match="cannot join"):
            open_session(stranger, deadline_s=0.0)

        bob = MeshConfig(connect=[up.hub], user="bob", password=up.bob_password)
        with MeshClient.open(bob, timeout=2.0) as other:
            other.create_session("bob", "spider")  # his own space
            with pytest.raises(NoReply):
                other.create_session(mine.user, "spider")
            with pytest.raises(NoReply):
                other.session(mine.user, s.id).snapshot()
        assert s.snapshot().state.phase == "created"


@pytest.mark.parametrize(
    "args",
    [
        ["--help"],
        ["up", "--help"],
        ["ls", "--help"],
        ["bench", "--help"],
        ["node", "proxy", "--help"],
        ["node", "simulator", "--help"],
        ["node", "hotfeedback", "--help"],
        ["node", "hub", "--help"],
    ],
)
def test_help_everywhere(args: list[str]) -> None:
    out = subprocess.run([*SIMECS, *args], capture_output=True, text=True, timeout=60, env=mesh_env())
    assert out.returncode == 0, out.stderr
    assert "usage" in out.stdout.lower()


def test_up_listens_with_tls_on_the_port_hub_names(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`simecs up --hub tcp/127.0.0.1:7500` (private, the default) listens with TLS on 7500, not on 7447,
    and this machine's user's client file says so."""
    from simecs.nodes.tools import cli

    monkeypatch.setenv("SIMECS_SERVICE_KEY_FILE", str(tmp_path / "service.key"))
    args = cli.build_parser().parse_args(["up", "--hub", "tcp/127.0.0.1:7500", "--data-dir", str(tmp_path)])
    hub, hub_flags, node_flags, note = cli.secure_setup(args)
    assert hub == "tls/127.0.0.1:7500" and "private" in note
    hub_config = (tmp_path / "secure" / "hub.json5").read_text()
    assert "tls/127.0.0.1:7500" in hub_config and "7447" not in hub_config
    mine = load(str(tmp_path / "client.json5"))
    assert mine.connect == ["tls/127.0.0.1:7500"] and mine.tls is not None and mine.password
    args.hub = "tcp/127.0.0.1"
    with pytest.raises(SystemExit, match="has no port"):
        cli.secure_setup(args)


def test_a_node_that_had_started_is_back_at_once_and_one_that_cannot_start_waits() -> None:
    """A proxy killed again and again must not sit out a growing back-off (it was ~11 s per crash):
    only a node that dies as it starts waits, longer each time."""
    from simecs.nodes import supervisor as sv

    def exited(started_ago: float) -> sv.Child:
        child = sv.Child("proxy", [sys.executable, "-c", "pass"])
        child.proc = subprocess.Popen(child.argv)
        child.proc.wait(10)
        child.started = time.monotonic() - started_ago
        return child

    sup = sv.Supervisor([], MeshConfig())
    ran = exited(started_ago=sv.STARTED_S + 1)
    ran.backoff = sv.MAX_BACKOFF_S  # after earlier start failures
    sup.children = [ran]
    before = time.monotonic()
    sup.check()
    assert ran.proc is None and ran.next_start <= before + 0.05 and ran.backoff == sv.FIRST_BACKOFF_S
    waits = []
    for _ in range(6):
        failing = exited(started_ago=0.1)
        failing.backoff = ran.backoff
        sup.children = [failing]
        now = time.monotonic()
        sup.check()
        waits.append(round(failing.next_start - now, 1))
        ran = failing
    assert waits == [0.5, 1.0, 2.0, 4.0, 8.0, 10.0], waits


def test_the_workers_a_killed_node_left_are_stopped_with_the_service() -> None:
    """A simulator node's workers outlive it (their runs go on, nodes/runs.py): the node killed and
    started again, its first process group's worker runs on, and is stopped with the service."""
    from simecs.nodes import supervisor as sv

    sleeper = [sys.executable, "-c", "import time; time.sleep(60)"]
    leader = f"import subprocess, time; subprocess.Popen({sleeper!r}); time.sleep(60)"
    child = sv.Child("simulator", [sys.executable, "-c", leader])
    sup = sv.Supervisor([child], MeshConfig())
    sup.start_all()
    first = child.proc
    assert first is not None
    (worker,) = wait_until(lambda: descendants(first.pid) or None, timeout=10, what="its worker")
    try:
        first.kill()
        first.wait(5)
        sup.check()  # it exited
        wait_until(lambda: sup.check() or child.proc is not None, timeout=5, what="the node started again")
        assert alive(worker) and len(child.groups) == 2
    finally:
        sup.stop_all()
    wait_until(lambda: not alive(worker), timeout=5, what="the first node's worker stopped")
