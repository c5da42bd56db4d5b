"""`simecs up`: the hub and every node as separate processes, watched and restarted.

Each node runs in its own process group (so a terminal's Ctrl-C reaches the supervisor alone, which
then stops the nodes in order and kills whatever is left after a grace period: no orphans, also of the
simulator's worker processes). A node that exits on its own is reported and started again at once; one
that dies as it starts (it cannot start) waits before each new try, longer each time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from simecs.mesh.process.config import MeshConfig, open_session
from simecs.mesh.protocol import keys

GRACE_S = 3.0
READY_TIMEOUT_S = 600.0  # the banner waits this long for every node (a cold compile included)


#: A node that ran this long had started: when it dies it is started again at once. Only a node that
#: dies sooner (it cannot start) waits, from FIRST_BACKOFF_S doubling up to MAX_BACKOFF_S.
STARTED_S = 3.0
FIRST_BACKOFF_S = 0.5
MAX_BACKOFF_S = 10.0


@dataclass
class Child:
    name: str
    argv: list[str]
    proc: subprocess.Popen[bytes] | None = None
    started: float = 0.0
    restarts: int = 0
    backoff: float = FIRST_BACKOFF_S
    next_start: float = 0.0
    # Every process group it ever led: a simulator's workers outlive it (their runs go on, nodes/runs.py)
    # and are stopped with the service, not with their first node.
    groups: list[int] = field(default_factory=list)


def group_alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def node_argv(module: str, args: list[str]) -> list[str]:
    return [sys.executable, "-m", module, *args]


class Supervisor:
    def __init__(self, children: list[Child], hub: MeshConfig) -> None:
        self.children = children
        self.hub = hub  # how to join the hub to see which nodes are ready
        self.stopping = threading.Event()

    @staticmethod
    def say(text: str) -> None:
        print(text, flush=True)

    def _start(self, child: Child) -> subprocess.Popen[bytes]:
        child.proc = subprocess.Popen(child.argv, start_new_session=True)
        child.groups.append(child.proc.pid)
        child.started = time.monotonic()
        return child.proc

    def start_all(self) -> None:
        for child in self.children:
            self._start(child)

    def check(self) -> None:
        """Restart children that exited while we were not stopping."""
        now = time.monotonic()
        for child in self.children:
            child.groups = [g for g in child.groups if group_alive(g)]  # an id reused is never signalled
            proc = child.proc
            if proc is None:
                if now >= child.next_start:
                    started = self._start(child)
                    child.restarts += 1
                    self.say(f"simecs: restarted {child.name} (pid {started.pid}, restart {child.restarts})")
                continue
            code = proc.poll()
            if code is None:
                continue
            if now - child.started >= STARTED_S:  # it had started: back at once, however often
                child.backoff = FIRST_BACKOFF_S
            delay = child.backoff if now - child.started < STARTED_S else 0.0
            self.say(f"simecs: {child.name} exited with code {code}; restarting in {delay:.1f} s")
            child.proc = None
            child.next_start = now + delay
            if delay:  # it dies as it starts (a bad flag, a busy port): waits grow, up to a cap
                child.backoff = min(child.backoff * 2, MAX_BACKOFF_S)

    def wait_ready(self, roles: list[str], timeout: float = 60.0) -> bool:
        """Wait until every role has a liveliness token on the hub."""
        cfg = self.hub
        end = time.monotonic() + timeout
        z = None
        try:
            while time.monotonic() < end and not self.stopping.is_set():
                self.check()
                try:
                    if z is None:
                        z = open_session(cfg, deadline_s=1.0)
                    live = set()
                    for reply in z.liveliness().get(keys.NODE_TOKENS, timeout=1.0):
                        if reply.ok is not None:
                            live.add(keys.parse("node_token", reply.ok.key_expr)["role"])
                    if all(r in live for r in roles):
                        return True
                except RuntimeError:
                    pass
                time.sleep(0.2)
            return False
        finally:
            if z is not None:
                z.close()

    def stop_all(self) -> None:
        """SIGTERM every process group, then SIGKILL what is left after the grace period."""
        self.stopping.set()
        for child in reversed(self.children):
            for group in child.groups:
                try:
                    os.killpg(group, signal.SIGTERM)
                except (ProcessLookupError, PermissionError):
                    pass
        end = time.monotonic() + GRACE_S
        for child in self.children:
            if child.proc is None:
                continue
            try:
                child.proc.wait(timeout=max(0.05, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for child in self.children:
            for group in child.groups:
                try:  # the group may hold grandchildren (simulator workers) even if the leader is gone
                    os.killpg(group, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
            if child.proc is None:
                continue
            try:
                child.proc.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                pass

    def run_forever(self, roles: list[str], banner: str) -> int:
        def on_signal(signum: int, _frame: Any) -> None:
            self.stopping.set()

        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        self.start_all()
        try:
            ready = self.wait_ready(roles)
            if not ready and not self.stopping.is_set():
                self.say(
                    "simecs: some nodes are not ready after 60 s (a first start compiles the simulator's "
                    "drives); still waiting"
                )
                ready = self.wait_ready(roles, timeout=READY_TIMEOUT_S)
            if ready:
                self.say(banner)
            elif not self.stopping.is_set():
                self.say(f"simecs: some nodes did not come up within {READY_TIMEOUT_S:.0f} s: see their logs")
            while not self.stopping.wait(0.2):
                self.check()
        finally:
            self.say("simecs: stopping")
            self.stop_all()
            self.say("simecs: stopped")
        return 0
