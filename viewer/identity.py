"""Who a tab acts for, and the mesh client it acts with.

On an open mesh (the embedded default: one machine) a user is a name chosen in the tab, and the viewer's
own client serves every tab. On a secured mesh (`simecs up --secure`, docs/LAN.md) the tab logs in with
a name and a password, and the viewer joins the hub as that user for this tab: the hub's rules for that
user then apply to everything the tab does, so the viewer can show a user nothing the user could not
reach with a client of their own.
"""

from __future__ import annotations

import secrets
import threading

from simecs.mesh.client import MeshClient
from simecs.mesh.protocol import keys

from .host import Host


class NotLoggedIn(ValueError):
    """The tab asked for something of its user before logging in (secured mesh)."""


def new_user_name() -> str:
    return f"user-{secrets.token_hex(3)}"


def valid_user(name: str) -> str:
    """The name if it can be a user name on the mesh; ValueError with the rule otherwise."""
    return keys.check_name(name.strip(), "user name")


class Identity:
    """The tab's user name and, on a secured mesh, the client logged in as that user."""

    def __init__(self, host: Host) -> None:
        self.host = host
        self.user = ""
        self._client: MeshClient | None = None
        self._lock = threading.Lock()

    @property
    def secured(self) -> bool:
        return self.host.secured

    @property
    def logged_in(self) -> bool:
        return not self.secured or self._client is not None

    @property
    def mc(self) -> MeshClient:
        """The client to act for the user with."""
        if not self.secured:
            return self.host.mc
        with self._lock:
            client = self._client
        if client is None:
            raise NotLoggedIn("log in first: enter your user name and password in the Models window")
        return client

    def choose(self, name: str) -> bool:
        """Take user name `name` (ValueError naming the rule if it cannot be one); whether it changed.
        On a secured mesh a new name logs the old one out."""
        name = valid_user(name)
        if name == self.user:
            return False
        self.logout()
        self.user = name
        return True

    def login(self, password: str) -> None:
        """Join the hub as the tab's user (blocks: a refusal takes the hub's connect timeout)."""
        if not self.secured:
            return
        if not password:
            raise ValueError("enter your password")
        client = self.host.login(self.user, password)  # ValueError when refused
        with self._lock:
            old, self._client = self._client, client
        if old is not None:
            old.close()

    def logout(self) -> None:
        with self._lock:
            client, self._client = self._client, None
        if client is not None:
            client.close()
