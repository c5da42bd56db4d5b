"""Warm workers forked from one process that warmed up once, instead of each warming up itself.

A worker's warm-up (importing the models, loading the drives' machine code, measuring each model's
cost) takes 2-3 CPU s; every run used to pay it again for the worker that replaced its own, on a
2-core host as much CPU as a run of several seconds. The simulator starts one *fork server*
(`python -m simecs.nodes.worker_forks`, the worker's flags; or, when the simulator itself was forked
from a node fork server, mesh/process/forks.py, forked from that one, already warm but for measuring
the models' costs) that warms up once, and asks it for each
worker over a Unix socket: it passes the two pipe ends the worker is to use as its stdin and stdout
(SCM_RIGHTS), the fork server forks a child that becomes a worker (nodes/worker.py, `serve`) and
answers its pid, and later its exit code (the fork server is the worker's parent). A worker forked
so is the same process a fresh one would be after its warm-up: it opens its own zenoh session.

Forking is safe only from a single-threaded process: the fork server checks it has one thread (BLAS
on one thread, no zenoh session) and otherwise says so and exits; the simulator then starts each
worker as a process of its own, as it does whenever the fork server is gone.

Lines on the socket, fork server to simulator: `ready`, `pid <pid>` (one per request, in order),
`exit <pid> <code>` (a negative code: killed by that signal).
"""

from __future__ import annotations

import contextlib
import faulthandler
import logging
import os
import queue
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import IO, Any, Protocol

from simecs.mesh.process.forks import (
    ForkedProcess,
    ForkServer,
    reap_exits,
    reset_signals_in_child,
    running,
    single_threaded,
)
from simecs.mesh.process.logs import setup_logging

from . import worker

log = logging.getLogger("simecs.worker")

READY = "ready"
FORK_REQUEST = b"fork"
CONTROL_FD = 3  # the socket to the simulator, in a fork server forked from the node fork server
EXITS_KEPT = 4096  # exit codes kept for the simulator to read (it reads each within a tick)


# -- the fork server --------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> None:
    parser = worker.worker_arguments("simecs-worker-forks", __doc__)
    parser.add_argument("--control-fd", type=int, required=True, help="the socket to the simulator")
    args = parser.parse_args(argv)
    setup_logging("worker", args.log_level)
    # Ctrl-C in a terminal, or a SIGTERM to the node's process group, reaches the fork server too: it
    # ends with its simulator (the socket closes), after reporting how the workers it forked ended.
    # Gone first, it would leave them to init, which may never reap them (a container's init), and
    # the simulator waiting for their exit codes until its timeout.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    control = socket.socket(fileno=args.control_fd)
    try:
        cost = worker.warm_up()
    except Exception as exc:
        log.error("the worker fork server failed to warm up: %s", exc)
        os._exit(1)
    if not single_threaded():
        log.error(
            "the worker fork server has more than one thread: forking is unsafe, workers start on their own"
        )
        os._exit(1)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # a child's exit wakes the select below
    try:
        control.sendall(f"{READY}\n".encode())
    except OSError:  # the simulator ended while this warmed up
        os._exit(0)
    while True:
        ready, _, _ = select.select([control.fileno(), wake_r], [], [], 1.0)
        if wake_r in ready:
            os.read(wake_r, 4096)
        _report_exits(control)
        if control.fileno() in ready:
            message, fds, _flags, _addr = socket.recv_fds(control, 64, 2)
            if not message:  # the simulator is gone: its workers see their stdin close
                break
            if message != FORK_REQUEST or len(fds) != 2:
                for fd in fds:
                    os.close(fd)
                continue
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _become_worker(args, cost, control, fds, (wake_r, wake_w))
            for fd in fds:
                os.close(fd)
            control.sendall(f"pid {pid}\n".encode())
    os._exit(0)


def _report_exits(control: socket.socket) -> None:
    for pid, code in reap_exits():
        with contextlib.suppress(OSError):
            control.sendall(f"exit {pid} {code}\n".encode())


def _become_worker(
    args: Any, cost: str, control: socket.socket, fds: list[int], wake: tuple[int, int]
) -> None:
    """The forked child: the pipes as its stdin and stdout, nothing else of the fork server's kept."""
    try:
        faulthandler.enable()  # a crash in a native library leaves every thread's stack in the log
        reset_signals_in_child()  # as in a worker started on its own
        control.close()
        for fd in wake:
            os.close(fd)
        os.dup2(fds[0], 0)
        os.dup2(fds[1], 1)
        for fd in fds:
            os.close(fd)
        sys.stdin = open(0, closefd=False)  # noqa: SIM115 - the process's own stdin, for its life
    except Exception as exc:
        log.error("a forked worker could not take its pipes: %s", exc)
        os._exit(1)
    worker.serve(args, cost)
    os._exit(1)  # serve exits itself


# -- the simulator's side ---------------------------------------------------------------------------
class WorkerProcess(Protocol):
    """What the simulator uses of a worker process: a `subprocess.Popen` or a `ForkedWorker`."""

    @property
    def pid(self) -> int: ...
    @property
    def stdin(self) -> IO[str] | None: ...
    @property
    def stdout(self) -> IO[Any] | None: ...
    def poll(self) -> int | None: ...
    def wait(self, timeout: float | None = None) -> int: ...
    def terminate(self) -> None: ...
    def kill(self) -> None: ...


class ForkedWorker(ForkedProcess):
    """A worker forked by the fork server, with the pipes the simulator talks to it on."""

    def __init__(self, pid: int, stdin: IO[str], stdout: IO[bytes], forks: WorkerForks) -> None:
        super().__init__(pid, lambda: forks.exit_code(pid))
        self.stdin: IO[str] | None = stdin
        self.stdout: IO[bytes] | None = stdout


class WorkerForks:
    """The simulator's fork server: started at once, it warms up while the node starts; `fork` makes a
    warm worker in milliseconds, or returns None when the fork server is not there (not warm within
    `ready_timeout`, or gone): the caller then starts a worker of its own."""

    def __init__(self, argv: list[str], env: dict[str, str], ready_timeout: float) -> None:
        self._sock, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        # Forked from the node fork server this node came from, if any: already warm but for the models'
        # costs; in this node's process group, as a process of its own would be.
        node_forks = ForkServer.from_env()
        proc: ForkedProcess | subprocess.Popen[bytes] | None = None
        if node_forks is not None:
            out = {1: sys.stdout.fileno(), 2: sys.stderr.fileno(), CONTROL_FD: theirs.fileno()}
            flags = [*argv, "--control-fd", str(CONTROL_FD)]
            proc = node_forks.spawn(__name__, flags, env, fds=out, group=os.getpgid(0))
        if proc is None:
            cmd = [sys.executable, "-m", __name__, *argv, "--control-fd", str(theirs.fileno())]
            proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, pass_fds=[theirs.fileno()])
        self._proc = proc
        theirs.close()
        self._ready = threading.Event()
        self._gone = threading.Event()
        self._pids: queue.Queue[int] = queue.Queue()
        self._codes: dict[int, int] = {}  # the last EXITS_KEPT workers' exit codes, by pid
        self._lock = threading.Lock()  # one request and its answer at a time
        self._ready_timeout = ready_timeout
        self._started = time.monotonic()
        self._closing = False
        threading.Thread(target=self._read, name="worker-forks", daemon=True).start()

    def _read(self) -> None:
        buffer = b""
        try:
            while chunk := self._sock.recv(4096):
                buffer += chunk
                *lines, buffer = buffer.split(b"\n")
                for line in lines:
                    self._take(line.decode(errors="replace").split())
        except OSError:
            pass
        self._gone.set()
        self._ready.set()  # nobody waits for a fork server that is gone
        if not self._closing:
            code = self._proc.wait()
            log.warning("the worker fork server is gone (exit code %s): workers start on their own", code)

    def _take(self, words: list[str]) -> None:
        if words == [READY]:
            self._ready.set()
        elif len(words) == 2 and words[0] == "pid":
            self._pids.put(int(words[1]))
        elif len(words) == 3 and words[0] == "exit":
            self._codes[int(words[1])] = int(words[2])
            while len(self._codes) > EXITS_KEPT:  # a long-lived host forks many thousands
                del self._codes[next(iter(self._codes))]

    def exit_code(self, pid: int) -> int | None:
        code = self._codes.get(pid)
        if code is None and self._gone.is_set() and not running(pid):
            # the fork server is gone: its orphans are init's, which may reap them late or never
            return self._codes.setdefault(pid, -signal.SIGKILL)
        return code

    def wait_ready(self) -> bool:
        """Wait until the fork server is warm (at most the timeout from its start): True if it is."""
        wait = max(0.0, self._started + self._ready_timeout - time.monotonic())
        return self._ready.wait(wait) and not self._gone.is_set()

    def fork(self) -> ForkedWorker | None:
        """A warm worker, or None at once if the fork server is not warm yet, or gone."""
        if not self._ready.is_set() or self._gone.is_set():
            return None
        child_in, my_in = os.pipe()
        my_out, child_out = os.pipe()
        try:
            with self._lock:
                socket.send_fds(self._sock, [FORK_REQUEST], [child_in, child_out])
                pid = self._pids.get(timeout=10.0)
        except (OSError, queue.Empty) as exc:
            log.warning("the worker fork server did not fork (%s): a worker starts on its own", exc)
            for fd in (my_in, my_out):
                os.close(fd)
            return None
        finally:
            os.close(child_in)
            os.close(child_out)
        return ForkedWorker(pid, open(my_in, "w", buffering=1), open(my_out, "rb", buffering=0), self)

    def close(self) -> None:
        self._closing = True
        with contextlib.suppress(OSError):  # shutdown, not only close: the reading thread holds the socket
            self._sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self._sock.close()
        try:
            self._proc.wait(timeout=3)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


if __name__ == "__main__":
    main()
