"""The viewer node: a viser web server whose every browser tab is a user with their own session.

    python -m simecs.viewer.app --connect tcp/127.0.0.1:7447 --host 127.0.0.1 --port 8080

It is a mesh node like any other (liveliness, status, clean exit on SIGTERM) and, of simecs, it
imports only `simecs.mesh`: models reach it as messages, as they would reach a third party's client.
The web server binds to loopback unless a LAN address is asked for, and viser's Share button (which
would open a tunnel to an outside service) is hidden and disabled.
"""

from __future__ import annotations

import argparse
import threading
from typing import Any

import viser
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process.config import open_session
from simecs.mesh.process.runtime import Node, main_for, mesh_from_args
from simecs.mesh.protocol.model import ModelDescription

from .host import Claimant, Claims
from .tab import TICKS_PER_S, Tab

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080


class Viewer(Node):
    """The web client of simecs (paper §3.2): one viser server, one `Tab` per browser tab. It is the
    tabs' `Host` (host.py): the mesh client, cached model descriptions, one tab per session."""

    role = "viewer"
    live_path = True
    tick_s = 1.0 / TICKS_PER_S  # every tab ticks with the node

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        user: str = "",
    ) -> None:
        super().__init__(mesh, node_id)
        self.host = host
        self.port = port
        self.default_user = user
        self.server: viser.ViserServer | None = None
        self.mc: MeshClient = None  # type: ignore[assignment]  # set in start()
        self.tabs: dict[int, Tab] = {}
        self.claims = Claims(self._live)
        self._models: dict[str, ModelDescription] = {}
        self._meshes: dict[tuple[str, str], bytes] = {}
        self._models_lock = threading.Lock()

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--host",
            default=DEFAULT_HOST,
            help="address to serve the web page on (default loopback; a LAN "
            "address or 0.0.0.0 to let other machines in)",
        )
        parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="web port (default 8080)")
        parser.add_argument("--user", default="", help="user name for browsers that have none yet")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Viewer:
        return cls(mesh_from_args(args), args.node_id, args.host, args.port, args.user)

    def status_detail(self) -> dict[str, Any]:
        return {"url": self.url, "tabs": len(self.tabs)}

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{host}:{self.port}"

    # -- node lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        self.mc = MeshClient(self.z, timeout=10.0, seal=self.seal)  # shows only what the service said
        server = viser.ViserServer(host=self.host, port=self.port, label="simecs", verbose=False)
        # Never offer or open a public share tunnel (viser's share button reaches a public relay): hide
        # the button, disable the call.
        server.gui.configure_theme(show_share_button=False, show_logo=False, control_width="large")
        server.request_share_url = _no_share  # type: ignore[method-assign]
        server.disconnect_share_url = lambda: None  # type: ignore[method-assign]
        server.on_client_connect(self._connected)
        server.on_client_disconnect(self._disconnected)
        self.server = server
        self.log.info("viewer at %s", self.url)
        print(f"simecs viewer: {self.url}", flush=True)

    def stop(self) -> None:
        for tab in list(self.tabs.values()):
            tab.close()
        self.tabs.clear()
        if self.server is not None:
            self.server.stop()
            self.server = None

    def tick(self) -> None:
        """Each tab's tick, on its own loop; a tab still busy with its last one skips this one."""
        for tab in list(self.tabs.values()):
            tab.loop.post(tab.tick, key="tick")

    # -- tabs ------------------------------------------------------------------------------------
    def _connected(self, client: Any) -> None:
        tab = Tab(self, client)
        self.tabs[client.client_id] = tab
        try:
            tab.start()
        except Exception:
            self.log.exception("tab %s failed to start", client.client_id)

    def _disconnected(self, client: Any) -> None:
        tab = self.tabs.pop(client.client_id, None)
        if tab is not None:
            tab.close()

    @property
    def secured(self) -> bool:
        return self.mesh.secured

    def login(self, user: str, password: str) -> MeshClient:
        """A client joined as `user` (a secured mesh: the hub checks the password and applies that
        user's rules); ValueError when the hub refuses."""
        try:
            z = open_session(self.mesh.as_user(user, password), deadline_s=0.0)
        except RuntimeError:
            self.log.info("login of %s refused", user)
            raise ValueError(f"the hub did not let {user} in: wrong user name or password?") from None
        self.log.info("%s logged in", user)
        return MeshClient(z, timeout=10.0, owns_session=True, seal=self.seal)

    def describe(self, model_id: str) -> ModelDescription:
        """A model's description, asked once per viewer (it only changes with a server restart)."""
        with self._models_lock:
            desc = self._models.get(model_id)
        if desc is None:
            desc = self.mc.describe(model_id)
            with self._models_lock:
                self._models[model_id] = desc
        return desc

    def meshes(self, model: ModelDescription) -> dict[str, bytes]:
        """The GLB of every mesh shape of the model, asked once per viewer; missing ones left out."""
        out = {}
        for name in model.mesh_names():
            with self._models_lock:
                data = self._meshes.get((model.id, name))
            if data is None:
                try:
                    data = self.mc.model_mesh(model.id, name)
                except (RemoteError, NoReply) as exc:
                    self.log.warning("model %s: mesh %s not drawn: %s", model.id, name, exc)
                    continue
                with self._models_lock:
                    self._meshes[(model.id, name)] = data
            out[name] = data
        return out

    # -- one tab per session ------------------------------------------------------------------------
    def _live(self, claimant: Claimant) -> bool:
        """A holder of a session counts while its tab is open and its browser still connected."""
        connected = set(self.server.get_clients()) if self.server is not None else set()
        return not claimant.closed and claimant.tab_id in connected


def _no_share(*_args: Any, **_kwargs: Any) -> None:
    """viser's share tunnel is disabled in simecs: the viewer serves the LAN only."""
    return None


def main(argv: list[str] | None = None) -> int:
    return main_for(Viewer, argv)


if __name__ == "__main__":
    main()
