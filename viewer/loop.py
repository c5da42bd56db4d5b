"""The one thread that owns a browser tab's state (issue: one owner of each tab's state).

Everything that reads or changes what a tab shows runs here, one thing at a time and in the order it
came: viser's widget callbacks (which viser would otherwise run on its thread pool, several at once),
the session controller's events (sent from its worker threads and zenoh's), the 10 Hz tick, and the
controller's own state changes. So no panel is changed by two threads at once and no lock is needed
around panels; a worker that did a request hands what it got to the loop (`call`) instead of changing
state itself. Nothing here ever waits on the server: requests stay on the controller's workers.

A tab's loop is its own: a tab whose loop is slow (a big redraw) slows only itself.

Tests drive a loop from their own thread (`TabLoop(driven=True)`): the test's thread is then the
loop's, so what a test calls runs at once, and `drain` runs what the workers handed back.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

log = logging.getLogger("simecs.viewer")
T = TypeVar("T")
#: How long a worker waits for the loop to run what it handed over (the loop never waits on a worker,
#: so only a closed or wedged tab makes this run out).
CALL_TIMEOUT_S = 30.0
#: Jobs waiting at most; beyond it the oldest coalescable ones (`post(..., key=...)`) are the first
#: to go, and a tab that cannot keep up says so in its log.
MAX_PENDING = 10_000
#: s a job may hold the loop before the log says so (nothing on the loop should wait on anything).
SLOW_JOB_S = 1.0


class LoopClosed(RuntimeError):
    """The tab went away: what was handed to its loop will not run."""


class TabLoop:
    """A queue of jobs run one at a time on one thread (see the module docstring)."""

    def __init__(self, name: str = "tab", driven: bool = False) -> None:
        self.name = name
        self.driven = driven
        self._jobs: deque[tuple[Callable[[], Any], str | None]] = deque()
        self._keys: set[str] = set()  # coalesced jobs waiting (at most one per key)
        self._timers: list[tuple[float, int, Callable[[], Any]]] = []
        self._order = itertools.count()
        self._cond = threading.Condition()
        self._busy = False
        self._closed = False
        self._owner: int | None = threading.get_ident() if driven else None
        self._thread: threading.Thread | None = None
        if not driven:
            self._thread = threading.Thread(target=self._run, name=f"{name}-loop", daemon=True)
            self._thread.start()
            self._owner = self._thread.ident

    # -- handing work to the loop ----------------------------------------------------------------
    def owns(self) -> bool:
        """Whether the calling thread is this loop's (its state may be touched here)."""
        return threading.get_ident() == self._owner

    @property
    def closed(self) -> bool:
        return self._closed

    def post(self, job: Callable[[], Any], key: str | None = None) -> None:
        """Run `job` on the loop after what is already queued. With `key`, a job of that key still
        waiting makes this one redundant (ticks, redraws: the later one does the same)."""
        with self._cond:
            if self._closed:
                return
            if key is not None:
                if key in self._keys:
                    return
                self._keys.add(key)
            if len(self._jobs) >= MAX_PENDING:
                log.warning("%s: %d jobs waiting, the oldest dropped", self.name, len(self._jobs))
                dropped, dropped_key = self._jobs.popleft()
                if dropped_key is not None:
                    self._keys.discard(dropped_key)
            self._jobs.append((job, key))
            self._cond.notify_all()

    def soon(self, job: Callable[[], Any]) -> None:
        """Run `job` now when on the loop, else post it."""
        if self.owns():
            job()
        else:
            self.post(job)

    def after(self, delay_s: float, job: Callable[[], Any]) -> None:
        """Run `job` on the loop once `delay_s` has passed (never earlier; later when the loop is busy)."""
        with self._cond:
            if self._closed:
                return
            heapq.heappush(self._timers, (time.monotonic() + delay_s, next(self._order), job))
            self._cond.notify_all()

    def call(self, fn: Callable[[], T], timeout: float = CALL_TIMEOUT_S) -> T:
        """`fn()` run on the loop, its result (or exception) given back: how a worker changes the
        tab's state. Runs at once when called on the loop."""
        if self.owns():
            return fn()
        done: Future[T] = Future()

        def job() -> None:
            try:
                done.set_result(fn())
            except BaseException as exc:
                done.set_exception(exc)

        self.post(job)
        end = time.monotonic() + timeout
        while True:
            try:
                return done.result(0.2)
            except TimeoutError:
                if self._closed:
                    raise LoopClosed(f"{self.name} is closed") from None
                if time.monotonic() > end:
                    raise LoopClosed(f"{self.name} did not run the call within {timeout:.0f} s") from None

    def wrap(self, fn: Callable[..., Any]) -> Callable[..., None]:
        """`fn` as a callback that runs on the loop, whatever thread calls it (viser's, zenoh's):
        at once when the caller is the loop, posted otherwise."""

        def on_loop(*args: Any, **kwargs: Any) -> None:
            if self.owns():
                fn(*args, **kwargs)
            else:
                self.post(lambda: fn(*args, **kwargs))

        return self._tagged(on_loop, fn)

    def wrap_widget(self, fn: Callable[..., Any]) -> Callable[..., Any]:
        """`fn` as a viser widget or scene callback that runs on the loop, in the order the page's
        messages came. viser runs a plain callback on its thread pool, several at once, so two of a
        page's messages could reach the loop in the other order (a pick after a click applied before
        it: seen with three test workers on two cores); a coroutine callback it awaits on its event
        loop, one message after the other: this one only posts, and returns at once. A value the
        tab's own code assigns sets its callbacks off after the job that assigned it, not inside it."""

        async def on_loop(*args: Any, **kwargs: Any) -> None:
            self.post(lambda: fn(*args, **kwargs))

        return self._tagged(on_loop, fn)

    def _tagged(self, on_loop: Callable[..., Any], fn: Callable[..., Any]) -> Callable[..., Any]:
        """`on_loop` marked as `fn` run on this loop: what tests check callbacks by."""
        on_loop.__wrapped__ = fn  # type: ignore[attr-defined]
        on_loop.on_tab_loop = self  # type: ignore[attr-defined]
        return on_loop

    # -- running ---------------------------------------------------------------------------------
    def _next(self, wait: bool) -> Callable[[], Any] | None:
        """The next job due (a timer's or the queue's), waiting for one when `wait`."""
        with self._cond:
            while True:
                now = time.monotonic()
                if self._timers and self._timers[0][0] <= now:
                    return heapq.heappop(self._timers)[2]
                if self._jobs:
                    job, key = self._jobs.popleft()
                    if key is not None:
                        self._keys.discard(key)
                    return job
                if self._closed or not wait:
                    return None
                timeout = self._timers[0][0] - now if self._timers else None
                self._cond.wait(timeout)

    def _do(self, job: Callable[[], Any]) -> None:
        self._busy = True
        started = time.monotonic()
        try:
            job()
        except Exception:
            log.exception("%s: a job failed", self.name)
        finally:
            self._busy = False
            took = time.monotonic() - started
            if took > SLOW_JOB_S:  # the tab's page waited this long for everything else: said
                log.warning("%s: a job took %.1f s: %s", self.name, took, getattr(job, "__qualname__", job))

    def _run(self) -> None:
        while True:
            job = self._next(wait=True)
            if job is None:
                return
            self._do(job)

    def run_pending(self) -> int:
        """Run every job due now on the calling thread (a driven loop's owner); how many ran."""
        if not self.owns():
            raise RuntimeError(f"{self.name}: run_pending from a thread that is not the loop's")
        ran = 0
        while (job := self._next(wait=False)) is not None:
            self._do(job)
            ran += 1
        return ran

    def idle(self) -> bool:
        with self._cond:
            return not self._jobs and not self._busy

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Until nothing waits or runs (timers not due yet do not count): for tests and benchmarks."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.driven:
                self.run_pending()
            if self.idle():
                return True
            time.sleep(0.005)
        return False

    def close(self) -> None:
        """No more jobs: what waits is dropped, the thread ends after the job it runs."""
        with self._cond:
            self._closed = True
            self._jobs.clear()
            self._keys.clear()
            self._timers.clear()
            self._cond.notify_all()
