"""The fork server (mesh/process/forks.py): a forked child is the process `python -m module args`
would be, with what the request gives it; what it cannot serve is refused and it serves on."""

from __future__ import annotations

import json
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from simecs.mesh.process.forks import FORK_SERVER_ENV, ForkedProcess, ForkServer, running

from .conftest import wait_until

PROBE = "simecs.testing.fork_probe"


@pytest.fixture
def forks() -> Iterator[ForkServer]:
    server = ForkServer.start("os:getpid", dict(os.environ), timeout=60)  # a warm-up of nothing
    assert server is not None
    try:
        yield server
    finally:
        server.close()


def started(server: ForkServer, args: list[str], **options: object) -> tuple[ForkedProcess, dict, str]:
    """Fork the probe, and read what it said (stdout) and its stderr until it ended or slept."""
    out_r, out_w = os.pipe()
    err_r, err_w = os.pipe()
    fds = {1: out_w, 2: err_w, **options.pop("fds", {})}  # type: ignore[dict-item]
    env = options.pop("env", dict(os.environ))
    proc = server.spawn(PROBE, args, env, fds=fds, **options)  # type: ignore[arg-type]
    os.close(out_w)
    os.close(err_w)
    assert proc is not None
    with os.fdopen(out_r) as out:
        seen = json.loads(out.readline())
    if args[:1] == ["sleep"]:
        os.close(err_r)
        return proc, seen, ""
    with os.fdopen(err_r) as err:
        return proc, seen, err.read()


def test_a_child_gets_its_arguments_environment_directory_and_descriptors(
    forks: ForkServer, tmp_path: Path
) -> None:
    extra = tmp_path / "extra.txt"
    with open(extra, "w") as f:
        env = {**os.environ, "PROBE_VALUE": "x y"}
        proc, seen, _ = started(forks, ["7", "--flag"], env=env, fds={5: f.fileno()}, cwd=str(tmp_path))
    assert seen["args"] == ["7", "--flag"] and seen["argv"][1:] == ["7", "--flag"]
    assert seen["env"]["PROBE_VALUE"] == "x y" and seen["env"][FORK_SERVER_ENV] == forks.path
    assert seen["cwd"] == str(tmp_path)
    assert seen["pgid"] == seen["pid"] == proc.pid  # a process group of its own
    assert seen["stdin"] == ""  # /dev/null when the request gives none
    assert seen["fd5"] == str(extra)
    assert proc.wait(10) == 7 and proc.returncode == 7


def test_how_a_child_ended_is_reported(forks: ForkServer) -> None:
    proc, _, err = started(forks, ["raise"])
    assert proc.wait(10) == 1 and "the probe was asked to fail" in err  # with its traceback
    proc, seen, _ = started(forks, ["sleep"])
    assert proc.poll() is None and running(seen["pid"])
    proc.kill()
    assert proc.wait(10) == -signal.SIGKILL


def test_a_child_joins_the_process_group_it_is_given(forks: ForkServer) -> None:
    leader, first, _ = started(forks, ["sleep"])
    member, second, _ = started(forks, ["sleep"], group=leader.pid)
    assert second["pgid"] == leader.pid != member.pid
    os.killpg(leader.pid, signal.SIGTERM)  # a node stopped with its group takes its helpers along
    assert leader.wait(10) == -signal.SIGTERM and member.wait(10) == -signal.SIGTERM


def test_what_it_cannot_serve_is_refused_and_it_serves_on(forks: ForkServer) -> None:
    # a variable read at import that differs: the child would not see it, so the caller starts it
    assert forks.spawn(PROBE, [], {**os.environ, "NUMBA_CACHE_DIR": "/elsewhere"}) is None
    for request in (
        b"not json\n",
        b'{"module": "x"}\n',
        b'{"module": "x", "args": [], "env": {}, "cwd": "/", "fds": [1], "group": "new"}\n',
    ):
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(10)
            sock.connect(forks.path)
            sock.sendall(request)
            answer = sock.recv(4096).decode()
        assert answer.startswith("refused "), (request, answer)
    # a module that is not there: forked, and the child says so and exits 1
    out_r, out_w = os.pipe()
    proc = forks.spawn("simecs.no_such_module", [], dict(os.environ), fds={2: out_w})
    os.close(out_w)
    assert proc is not None and proc.wait(10) == 1
    with os.fdopen(out_r) as err:
        assert "No module named 'simecs.no_such_module'" in err.read()
    proc, seen, _ = started(forks, ["0"])  # and it serves on
    assert proc.wait(10) == 0


def test_it_ends_with_its_owner_and_its_children_go_on() -> None:
    server = ForkServer.start("os:getpid", dict(os.environ), timeout=60)
    assert server is not None
    proc, seen, _ = started(server, ["sleep"])
    server.close()  # its owner closes it (or ends)
    assert server._proc is not None and server._proc.poll() is not None
    assert running(proc.pid) and proc.poll() is None
    os.kill(proc.pid, signal.SIGKILL)
    # its exit code is nobody's to report now: gone is gone (an orphan's reaper may be late)
    wait_until(lambda: proc.poll() is not None, 10, what="the orphan's end seen")
    assert proc.returncode == -signal.SIGKILL
    assert ForkServer(server.path).spawn(PROBE, [], dict(os.environ)) is None  # gone: callers start it


def test_a_warm_up_that_fails_leaves_no_server() -> None:
    t0 = time.monotonic()
    assert ForkServer.start("simecs.no_such_module:warm", dict(os.environ), timeout=60) is None
    assert time.monotonic() - t0 < 60  # said at once, not after the timeout


def test_spawns_from_many_threads_each_get_their_own_child_and_leave_no_descriptor(forks: ForkServer) -> None:
    def open_fds() -> int:
        return len(os.listdir("/proc/self/fd"))

    started(forks, ["0"])[0].wait(10)  # the first connection's one-off descriptors (logging, ...)
    before = open_fds()
    codes: dict[int, int] = {}

    def one(k: int) -> None:
        with open(os.devnull, "w") as quiet:
            proc = forks.spawn(PROBE, [str(k)], dict(os.environ), fds={1: quiet.fileno()})
        assert proc is not None
        codes[k] = proc.wait(30)

    threads = [threading.Thread(target=one, args=(k,)) for k in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert codes == {k: k for k in range(12)}
    assert open_fds() == before  # each process's connection closed once its exit was read
