"""How the session controller works off its callers' threads and reports back: the tab's loop, which
owns the controller's state and runs its listeners (loop.py); two worker threads for what waits on the
server (commands in order on one, data fetches on the other), whose failures become notices; and the
listeners that receive its events.

viser's and zenoh's callbacks must return at once (a slow zenoh callback stalls the whole link), and
the loop never waits on the server, so everything that does is submitted to a worker; a worker hands
what it got back to the loop (`on_loop`) rather than changing the controller's state itself.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from . import events as ev
from .errors import EXPECTED, describe_error, error_kind
from .loop import LoopClosed, TabLoop

log = logging.getLogger("simecs.viewer")
T = TypeVar("T")


class Dispatcher:
    """The loop, listeners and workers of one tab (`tab_id` names its threads and log lines).
    `loop`: the tab's loop (a test passes a driven one); by default a thread of its own."""

    def __init__(self, tab_id: int, loop: TabLoop | None = None) -> None:
        self.tab_id = tab_id
        self.closed = False
        self.loop = loop if loop is not None else TabLoop(f"tab{tab_id}")
        self._listeners: list[ev.Listener] = []
        self._cmd = ThreadPoolExecutor(1, thread_name_prefix=f"tab{tab_id}-cmd")
        self._io = ThreadPoolExecutor(1, thread_name_prefix=f"tab{tab_id}-io")
        self._in_flight = 0  # jobs submitted to the workers and not done yet
        self._count_lock = threading.Lock()

    def subscribe(self, listener: ev.Listener) -> None:
        self._listeners.append(listener)

    def emit(self, event: ev.Event) -> None:
        """Tell the listeners, on the loop (at once when called there, in order otherwise)."""
        self.loop.soon(lambda: self._deliver(event))

    def _deliver(self, event: ev.Event) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # a panel removed meanwhile, a closed tab: never the controller's end
                log.exception("tab %s: listener failed on %s", self.tab_id, type(event).__name__)

    def on_loop(self, fn: Callable[[], T]) -> T:
        """`fn()` run on the loop (how a worker changes the controller's state), its result back."""
        return self.loop.call(fn)

    def notify(self, title: str, body: str, kind: str = "info") -> None:
        self.emit(ev.Notice(title, body, kind))

    def fail(self, what: str, exc: BaseException) -> None:
        """A failed request as the user should read it; unexpected failures are logged too."""
        if not isinstance(exc, EXPECTED):
            log.exception("tab %s: %s failed", self.tab_id, what, exc_info=exc)
        self.notify(what, describe_error(exc), error_kind(exc))

    def submit(self, what: str, job: Callable[[], Any], pool: str = "cmd") -> None:
        """Run `job` on a worker (`cmd`: commands, in order; `io`: data fetches); a failure becomes a
        notice titled `what`."""
        if self.closed:
            return

        def run() -> None:
            try:
                job()
            except LoopClosed:
                pass  # the tab went away while the job ran
            except Exception as exc:
                if not self.closed:
                    self.fail(what, exc)
            finally:
                with self._count_lock:
                    self._in_flight -= 1

        with self._count_lock:
            self._in_flight += 1
        try:
            (self._cmd if pool == "cmd" else self._io).submit(run)
        except RuntimeError:  # workers shut down: the tab is closing
            with self._count_lock:
                self._in_flight -= 1

    def drain(self, timeout: float = 10.0) -> None:
        """Wait until the workers ran what was submitted and the loop what was handed to it (and what
        that submitted in turn): for tests and benchmarks. A driven loop runs its jobs here."""
        end = time.monotonic() + timeout
        quiet = 0
        while quiet < 3:  # three looks in a row at nothing to do: workers and loop hand over no more
            if time.monotonic() > end:
                raise TimeoutError(f"tab {self.tab_id}: work still pending after {timeout:.0f} s")
            if self.loop.driven:
                self.loop.run_pending()
            with self._count_lock:
                busy = self._in_flight > 0
            if busy or not self.loop.idle():
                quiet = 0
                time.sleep(0.002)
            else:
                quiet += 1
                time.sleep(0.001)

    def shutdown(self) -> None:
        self.closed = True
        self._cmd.shutdown(wait=False, cancel_futures=True)
        self._io.shutdown(wait=False, cancel_futures=True)
        self.loop.close()
