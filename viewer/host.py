"""What a tab needs from the viewer node, as an interface: the mesh client, the model descriptions
(asked once per viewer), the user name for browsers without one, and the rule that one tab shows a
session at a time.

The tab and its session controller see the viewer only through `Host`, so neither imports
`app.py` and a test can hand them a fake host with a fake client.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

from simecs.mesh.client import MeshClient
from simecs.mesh.protocol.model import ModelDescription


class Claimant(Protocol):
    """Who may hold a session: a tab's controller, known by its tab id."""

    @property
    def tab_id(self) -> int: ...

    @property
    def closed(self) -> bool: ...


class Claims:
    """One tab per session: a session is given to a tab unless another live tab holds it.

    `live(claimant)` says whether a holder still counts (its tab is open and connected); a reloading
    tab's old connection may close a moment after the new one asks, so a live holder is waited for.
    """

    def __init__(self, live: Callable[[Claimant], bool]) -> None:
        self._live = live
        self._held: dict[str, Claimant] = {}
        self._lock = threading.Lock()

    def claim(self, session: str, claimant: Claimant, wait_s: float = 2.0) -> bool:
        end = time.monotonic() + wait_s
        while True:
            with self._lock:
                owner = self._held.get(session)
                if owner is None or owner is claimant or not self._live(owner):
                    self._held[session] = claimant
                    return True
            if time.monotonic() > end:
                return False
            time.sleep(0.1)

    def held_by_other(self, session: str, claimant: Claimant) -> bool:
        with self._lock:
            owner = self._held.get(session)
            return owner is not None and owner is not claimant and not owner.closed

    def release(self, session: str, claimant: Claimant) -> None:
        with self._lock:
            if self._held.get(session) is claimant:
                del self._held[session]


class Host(Protocol):
    """The viewer node as its tabs see it."""

    @property
    def mc(self) -> MeshClient:
        """The viewer's own client: the library, and every tab's requests on an open mesh."""
        ...

    @property
    def secured(self) -> bool:
        """Users log in (name and password) and each tab acts as its user (identity.py)."""
        ...

    def login(self, user: str, password: str) -> MeshClient:
        """A client joined as `user`; ValueError saying so when the hub refuses."""
        ...

    @property
    def default_user(self) -> str: ...

    @property
    def claims(self) -> Claims: ...

    def describe(self, model_id: str) -> ModelDescription:
        """A model's description (cached by the viewer: it only changes with a server restart)."""
        ...

    def meshes(self, model: ModelDescription) -> dict[str, bytes]:
        """The binary glTF of every mesh shape of the model that could be had (cached like the
        descriptions); a mesh the server could not give is left out (and logged)."""
        ...
