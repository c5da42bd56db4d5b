"""A worker thread fed by a bounded queue: what every zenoh callback hands its work to.

A zenoh callback must return at once (a slow one stalls every other sample on the same link), so handlers run
here; when the queue is full the oldest item is dropped and counted, so a slow handler costs only its
own stream.
"""

from __future__ import annotations

import collections
import logging
import threading
import traceback
from collections.abc import Callable
from typing import Any

log = logging.getLogger("simecs")


class BoundedWorker:
    """A worker thread fed by a bounded queue; when full the oldest item is dropped and counted."""

    def __init__(self, name: str, handle: Callable[[Any], None], maxlen: int = 1024) -> None:
        self._q: collections.deque[Any] = collections.deque(maxlen=maxlen)
        self._cv = threading.Condition()
        self._handle = handle
        self._stopped = False
        self.dropped = 0
        self.name = name
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def push(self, item: Any) -> None:
        with self._cv:
            if len(self._q) == self._q.maxlen:
                self.dropped += 1
            self._q.append(item)
            self._cv.notify()

    def _loop(self) -> None:
        while True:
            with self._cv:
                while not self._q and not self._stopped:
                    self._cv.wait()
                if self._stopped and not self._q:
                    return
                item = self._q.popleft()
            try:
                self._handle(item)
            except Exception:  # a bad sample must not kill the worker
                log.error("handler %s failed:\n%s", self.name, traceback.format_exc())

    def stop(self, timeout: float = 2.0) -> None:
        with self._cv:
            self._stopped = True
            self._cv.notify()
        self._thread.join(timeout)
