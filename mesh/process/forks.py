"""Processes forked from one process that imported and warmed up once, instead of each doing it again.

A node's start costs 0.3-2.2 CPU s before it does anything (imports; the proxy's and the simulator's
kernels loaded from numba's cache; the simulator's worker fork server measuring the models): a host,
or a test suite, that starts nodes often pays it again every time. A *fork server* pays it once: it
imports what its `warm` hook names, then forks a child per request that runs a module's `main(args)`
as `python -m module args` would, with the environment, working directory and file descriptors the
request gives.

One Unix socket (its path in `FORK_SERVER_ENV` for the processes started from it, so that a node can
start its own helpers from it too), one connection per process. The client sends one request, a JSON
line (`module`, `args`, `env`, `cwd`, `fds`: the descriptor numbers the child gets the passed ones as,
`group`: "new" or a process group to join) with the descriptors attached (SCM_RIGHTS); the server
answers `pid <pid>`, then `exit <code>` when the child ends (a negative code: killed by that signal),
or `refused <reason>`. A fork server that is not there, or refuses, leaves the caller to start the
process itself (`ForkServer.spawn` returns None): forking is an optimisation, never a requirement.

Forking is safe only from a single-threaded process: the server checks it has one thread after its
warm-up (no zenoh session, BLAS on one thread), otherwise it says so and exits. A child is the process
a fresh start would be once its imports are done: it opens its own zenoh session.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import importlib
import json
import logging
import os
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, NoReturn

log = logging.getLogger("simecs.forks")

#: The environment variable that names a fork server's socket to the processes it started.
FORK_SERVER_ENV = "SIMECS_FORK_SERVER"
READY = b"ready\n"
MAX_REQUEST = 1 << 20  # a request line (its environment included) is far shorter
MAX_FDS = 8
FIRST_FREE_FD = 64  # a request's descriptor numbers are below it
#: Variables read when a module is imported (numba's cache, BLAS threads, the interpreter's own): a
#: request whose value of one differs from the server's is refused, since the child would not see it.
IMPORT_TIME_ENV = (
    "NUMBA_CACHE_DIR",
    "SIMECS_NUMBA_CACHE",
    "OPENBLAS_NUM_THREADS",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "PYTHONPATH",
    "PYTHONHASHSEED",
    "PYTHONDONTWRITEBYTECODE",
    "PYTHONUNBUFFERED",
    "PYTHONWARNINGS",
)


# -- what every fork server's child and parent do -----------------------------------------------------
def reset_signals_in_child() -> None:
    """A forked child takes the signal dispositions a fresh process has (the server's are its own)."""
    signal.set_wakeup_fd(-1)
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def reap_exits() -> Iterator[tuple[int, int]]:
    """(pid, exit code) of every child that ended since the last call (negative: killed by a signal)."""
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        yield pid, os.waitstatus_to_exitcode(status)


def running(pid: int) -> bool:
    """Whether process `pid` is there and not a zombie (an orphan init has not reaped yet)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as stat:
            return stat.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return False


def single_threaded() -> bool:
    return len(os.listdir("/proc/self/task")) == 1


class ForkedProcess:
    """A process a fork server forked, with what callers use of a `subprocess.Popen`; its exit code
    comes from `exit_code()` (the fork server, its parent, reports it)."""

    stdin: Any = None
    stdout: Any = None
    stderr: Any = None

    def __init__(self, pid: int, exit_code: Callable[[], int | None]) -> None:
        self.pid = pid
        self._exit_code = exit_code
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self._exit_code()
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        end = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            if end is not None and time.monotonic() >= end:
                raise subprocess.TimeoutExpired(f"process {self.pid}", timeout or 0.0)
            time.sleep(0.01)
        return code

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


# -- the client side ------------------------------------------------------------------------------------
class _Answer:
    """The server's answers on one process's connection: its pid, then its exit code."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.buffer = b""
        self.code: int | None = None
        self.pid = 0
        self._lock = threading.Lock()  # a node's threads may poll one process at once

    def line(self, timeout: float) -> str | None:
        """The next line, waiting at most `timeout` s; None if the connection closed first."""
        end = time.monotonic() + timeout
        while b"\n" not in self.buffer:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError("no answer from the fork server")
            self.sock.settimeout(left)
            chunk = self.sock.recv(4096)
            if not chunk:
                return None
            self.buffer += chunk
        line, self.buffer = self.buffer.split(b"\n", 1)
        return line.decode(errors="replace")

    def exit_code(self) -> int | None:
        with self._lock:
            return self._exit_code()

    def _exit_code(self) -> int | None:
        if self.code is not None:
            return self.code
        try:
            self.sock.setblocking(False)
            chunk = self.sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:
            chunk = b""
        if chunk:
            self.buffer += chunk
            words = self.buffer.split()
            if len(words) >= 2 and words[0] == b"exit":
                self.code = int(words[1])
        elif not running(self.pid):  # the fork server went first: its orphans are init's
            self.code = -signal.SIGKILL
        if self.code is not None:
            self.sock.close()
        return self.code


class ForkServer:
    """A fork server's client: `spawn` forks a process from it, or returns None (the caller then
    starts the process itself)."""

    def __init__(self, path: str, env: Mapping[str, str] | None = None) -> None:
        self.path = path
        self.env = dict(os.environ if env is None else env)  # the server's, for IMPORT_TIME_ENV
        self._proc: subprocess.Popen[bytes] | None = None
        self._control: socket.socket | None = None
        self._folder: str | None = None

    @classmethod
    def start(cls, warm: str, env: Mapping[str, str], timeout: float = 120.0) -> ForkServer | None:
        """Start a fork server that runs `warm` ("module:function") first; None if it did not
        become ready within `timeout` s (it is stopped then). It ends when this process closes it or
        ends."""
        folder = tempfile.mkdtemp(prefix="smxf")  # private (0700): whoever connects runs code here
        path = os.path.join(folder, "forks.sock")
        control, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        argv = [
            sys.executable,
            "-m",
            __name__,
            "--listen",
            path,
            "--warm",
            warm,
            "--control-fd",
            str(theirs.fileno()),
        ]
        proc = subprocess.Popen(
            argv, env=dict(env), stdin=subprocess.DEVNULL, pass_fds=[theirs.fileno()], start_new_session=True
        )
        theirs.close()
        server = cls(path, env)
        server._proc, server._control, server._folder = proc, control, folder
        control.settimeout(timeout)
        try:
            ready = control.recv(len(READY)) == READY
        except OSError:
            ready = False
        if not ready:
            log.warning(
                "the fork server did not become ready within %.0f s: processes start on their own", timeout
            )
            server.close()
            return None
        return server

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> ForkServer | None:
        """The fork server this process was started from (`FORK_SERVER_ENV`), if any."""
        path = (os.environ if env is None else env).get(FORK_SERVER_ENV, "")
        return cls(path) if path else None

    def spawn(
        self,
        module: str,
        args: list[str],
        env: Mapping[str, str],
        fds: Mapping[int, int] | None = None,
        group: int | None = None,
        cwd: str | None = None,
    ) -> ForkedProcess | None:
        """Fork `python -m module args` from the server: `fds` maps the child's descriptor numbers to
        ours (stdin is /dev/null unless given), `group` the process group it joins (None: one of its
        own). None when the server is gone, refuses or does not answer within 10 s."""
        differs = [k for k in IMPORT_TIME_ENV if env.get(k) != self.env.get(k)]
        if differs:
            log.info(
                "not forked (%s read at import differs): %s starts on its own", ", ".join(differs), module
            )
            return None
        fds = dict(fds or {})
        request = {
            "module": module,
            "args": list(args),
            "env": {**env, FORK_SERVER_ENV: self.path},  # its own helpers may be forked here too
            "cwd": cwd or os.getcwd(),
            "fds": list(fds),
            "group": "new" if group is None else group,
        }
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        answer = _Answer(sock)
        try:
            sock.settimeout(10.0)
            sock.connect(self.path)
            socket.send_fds(sock, [json.dumps(request).encode() + b"\n"], list(fds.values()))
            line = answer.line(10.0) or "refused the fork server closed the connection"
        except (OSError, TimeoutError) as exc:
            line = f"refused {exc}"
        words = line.split(maxsplit=1)
        if len(words) == 2 and words[0] == "pid" and words[1].isdigit():
            answer.pid = int(words[1])
            return ForkedProcess(answer.pid, answer.exit_code)
        sock.close()
        log.warning("the fork server did not fork %s (%s): it starts on its own", module, line)
        return None

    def close(self) -> None:
        """Stop the fork server this process started (the processes it forked go on)."""
        if self._control is not None:
            with contextlib.suppress(OSError):
                self._control.close()
        if self._proc is not None:
            try:
                self._proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        if self._folder is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            with contextlib.suppress(OSError):
                os.rmdir(self._folder)


# -- the server side ------------------------------------------------------------------------------------
def _read_request(conn: socket.socket) -> tuple[dict[str, Any], list[int]]:
    """One request line and the descriptors sent with it (ValueError naming what is wrong)."""
    data, fds = b"", []
    while not data.endswith(b"\n"):
        chunk, got, _flags, _addr = socket.recv_fds(conn, 65536, MAX_FDS)
        fds += got
        if not chunk:
            break
        data += chunk
        if len(data) > MAX_REQUEST:
            break
    try:
        request = json.loads(data)
    except ValueError:
        for fd in fds:
            os.close(fd)
        raise ValueError("the request is not one JSON line") from None
    ok = (
        isinstance(request, dict)
        and isinstance(request.get("module"), str)
        and isinstance(request.get("args"), list)
        and all(isinstance(a, str) for a in request["args"])
        and isinstance(request.get("env"), dict)
        and isinstance(request.get("cwd"), str)
        and isinstance(request.get("fds"), list)
        and len(request["fds"]) == len(fds)
        and all(isinstance(t, int) and 0 <= t < FIRST_FREE_FD for t in request["fds"])
        and (request.get("group") == "new" or isinstance(request.get("group"), int))
    )
    if not ok:
        for fd in fds:
            os.close(fd)
        raise ValueError("the request lacks module, args, env, cwd, fds (one per descriptor sent) or group")
    return request, fds


def _become(request: dict[str, Any], fds: list[int], keep_closed: list[socket.socket]) -> NoReturn:
    """The forked child: the request's descriptors, group, environment and directory, then the
    module's `main(args)`; never returns."""
    code = 1
    try:
        reset_signals_in_child()
        for s in keep_closed:
            s.close()
        if request["group"] == "new":
            os.setpgid(0, 0)
        else:
            try:
                os.setpgid(0, int(request["group"]))
            except OSError as exc:  # another session's group: its owner stops this one by other means
                print(f"fork server: could not join process group {request['group']}: {exc}", file=sys.stderr)
        targets = [int(t) for t in request["fds"]]
        moved = [fcntl.fcntl(fd, fcntl.F_DUPFD, FIRST_FREE_FD) for fd in fds]  # above every target
        for fd in fds:
            os.close(fd)
        if 0 not in targets:
            null = os.open(os.devnull, os.O_RDONLY)
            os.dup2(null, 0)
            os.close(null)
        for target, fd in zip(targets, moved, strict=True):
            os.dup2(fd, target)
        for fd in moved:
            os.close(fd)
        os.environ.clear()
        os.environ.update({str(k): str(v) for k, v in request["env"].items()})
        os.chdir(request["cwd"])
        module = importlib.import_module(request["module"])
        sys.argv = [module.__file__ or request["module"], *request["args"]]
        result = module.main(request["args"])
        code = result if isinstance(result, int) else 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        traceback.print_exc()
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


def serve(listen: str, control: socket.socket) -> NoReturn:
    """Fork a child per request on `listen` until `control` closes (the owner is gone)."""
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(listen)
    server.listen(64)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # a child's exit wakes the selector
    connections: dict[int, socket.socket] = {}  # pid -> the connection its exit goes to
    selector = selectors.DefaultSelector()
    selector.register(server, selectors.EVENT_READ, "accept")
    selector.register(control, selectors.EVENT_READ, "control")
    selector.register(wake_r, selectors.EVENT_READ, "wake")
    control.sendall(READY)
    while True:
        for key, _ in selector.select(timeout=1.0):
            if key.data == "control":
                if not control.recv(64):
                    os._exit(0)  # the owner is gone; the children go on (init reaps them)
            elif key.data == "wake":
                os.read(wake_r, 4096)
            elif key.data == "accept":
                conn, _addr = server.accept()
                _answer(conn, server, control, selector, connections)
        for pid, code in reap_exits():
            if pid in connections:
                conn = connections.pop(pid)
                with contextlib.suppress(OSError):
                    conn.sendall(f"exit {code}\n".encode())
                conn.close()


def _answer(
    conn: socket.socket,
    server: socket.socket,
    control: socket.socket,
    selector: selectors.BaseSelector,
    connections: dict[int, socket.socket],
) -> None:
    try:
        conn.settimeout(5.0)
        request, fds = _read_request(conn)
    except (OSError, ValueError) as exc:
        with contextlib.suppress(OSError):
            conn.sendall(f"refused {exc}\n".encode())
        conn.close()
        return
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        selector.close()
        _become(request, fds, [conn, server, control, *connections.values()])
    for fd in fds:
        os.close(fd)
    try:
        conn.sendall(f"pid {pid}\n".encode())
        connections[pid] = conn
    except OSError:  # the client went away: the child runs on, nobody is told its exit
        conn.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="simecs-forks", description=__doc__)
    parser.add_argument("--listen", required=True, help="the Unix socket path to serve on")
    parser.add_argument("--warm", required=True, help="module:function to run once before forking")
    parser.add_argument("--control-fd", type=int, required=True, help="the owner's socket: its end ends this")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s fork server %(levelname)s %(message)s")
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # ends with its owner, whose children it reports
    control = socket.socket(fileno=args.control_fd)
    module, _, function = args.warm.partition(":")
    try:
        getattr(importlib.import_module(module), function)()
    except Exception as exc:
        log.error("the fork server failed to warm up (%s): %s", args.warm, exc)
        os._exit(1)
    if not single_threaded():
        log.error(
            "the fork server has %d threads after its warm-up: forking is unsafe",
            len(os.listdir("/proc/self/task")),
        )
        os._exit(1)
    Path(args.listen).unlink(missing_ok=True)
    serve(args.listen, control)


if __name__ == "__main__":
    main()
