"""How the session controller works off its callers' threads and reports back: two worker threads
(commands in order on one, data fetches on the other) whose failures become notices, and the
listeners that receive its events.

viser's and zenoh's callbacks must return at once (a slow zenoh callback stalls the whole link), so
everything that waits on the server is submitted here.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from . import events as ev
from .errors import EXPECTED, describe_error, error_kind

log = logging.getLogger("simecs.viewer")


class Dispatcher:
    """Listeners and workers of one tab (`tab_id` names its threads and log lines)."""

    def __init__(self, tab_id: int) -> None:
        self.tab_id = tab_id
        self.closed = False
        self._listeners: list[ev.Listener] = []
        self._cmd = ThreadPoolExecutor(1, thread_name_prefix=f"tab{tab_id}-cmd")
        self._io = ThreadPoolExecutor(1, thread_name_prefix=f"tab{tab_id}-io")

    def subscribe(self, listener: ev.Listener) -> None:
        self._listeners.append(listener)

    def emit(self, event: ev.Event) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # a panel removed meanwhile, a closed tab: never the controller's end
                log.exception("tab %s: listener failed on %s", self.tab_id, type(event).__name__)

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
            except Exception as exc:
                if not self.closed:
                    self.fail(what, exc)

        try:
            (self._cmd if pool == "cmd" else self._io).submit(run)
        except RuntimeError:  # workers shut down: the tab is closing
            pass

    def drain(self, timeout: float = 10.0, rounds: int = 3) -> None:
        """Wait until the workers ran what was submitted (and what that submitted): for tests."""
        for _ in range(rounds):
            for pool in (self._cmd, self._io):
                pool.submit(lambda: None).result(timeout)

    def shutdown(self) -> None:
        self.closed = True
        self._cmd.shutdown(wait=False, cancel_futures=True)
        self._io.shutdown(wait=False, cancel_futures=True)
