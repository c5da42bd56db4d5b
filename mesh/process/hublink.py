"""Whether this process's link to its hub is up, and since when.

When the hub restarts, every liveliness token of the mesh disappears for every node at once, exactly as
one worker's token does when that worker dies. The difference is only visible here: our own link to
the hub dropped around the same moment. Nodes ask `lost_since(t)` before calling a token's loss a death,
and act again once `wait_back()` says the hub has been back long enough for every node to reconnect.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import zenoh

#: After the hub comes back, how long every node gets to reconnect and declare its tokens again
#: (clients retry every 0.1 s, backing off to 1 s: mesh/process/config.py HUB_RETRY).
REGRACE_S = 2.5

log = logging.getLogger("simecs.hublink")


class HubLink:
    """The state of this session's link to its router (the hub), from zenoh's transport events."""

    def __init__(self, z: zenoh.Session) -> None:
        self._z = z
        self._cv = threading.Condition()
        self._up = bool(z.info.routers_zid())
        self._lost_at = float("-inf")  # monotonic time the link last dropped
        self._back_at = time.monotonic()  # ... and last came back
        self.losses = 0
        self._listener: Any = z.info.declare_transport_events_listener(self._on_event, history=False)

    def _on_event(self, event: Any) -> None:  # zenoh's thread: record and return
        if event.transport.whatami != zenoh.WhatAmI.ROUTER:
            return
        up = event.kind == zenoh.SampleKind.PUT
        with self._cv:
            now = time.monotonic()
            if up:
                self._back_at = now
            else:
                self._lost_at = now
                self.losses += 1
            self._up = up
            self._cv.notify_all()
        if not up:
            log.warning("lost the link to the hub; waiting for it to come back")
        else:
            log.info("the link to the hub is back")

    def is_up(self) -> bool:
        with self._cv:
            up = self._up
        return up and bool(self._z.info.routers_zid())

    def lost_since(self, t: float) -> bool:
        """True if the link dropped at or after monotonic time `t`, or is down now: then a token that
        disappeared after `t` may only be hidden by the hub, not gone."""
        with self._cv:
            dropped = self._lost_at >= t
        return dropped or not self.is_up()

    def wait_back(self, timeout: float, regrace_s: float = REGRACE_S) -> bool:
        """Wait until the link is up and has been for `regrace_s` (every node has had time to come
        back); False after `timeout`."""
        end = time.monotonic() + timeout
        with self._cv:
            while True:
                now = time.monotonic()
                if self._up and now - self._back_at >= regrace_s:
                    return True
                if now >= end:
                    return False
                wait = regrace_s - (now - self._back_at) if self._up else 0.5
                self._cv.wait(min(max(wait, 0.01), end - now))

    def close(self) -> None:
        try:
            self._listener.undeclare()
        except Exception:
            pass
