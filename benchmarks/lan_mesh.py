"""The LAN of `simecs bench lan` (lan.py): its hosts, the plain and the secured mesh started on them,
and what every trial uses (a prepared session, a run's recording files).
"""

from __future__ import annotations

import shutil
import socket
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from simecs.mesh.client import MeshClient, SessionClient
from simecs.mesh.protocol import keys
from simecs.nodes.local_mesh import LocalMesh, wait_until
from simecs.testing import netns

HOSTS = ("hub", "sim", "client", "slow")
HUB = "simecs.nodes.hub"
PLAIN_PORT, TLS_PORT = 7447, 7448
OUTPUT = 0.002
TARGET = [0.3, -0.2, 0.2, 0.1, -0.1, 0.1, 0.0]
ENDED = ["finished", "failed", "aborted"]


def log(text: str) -> None:
    print(f"bench lan: {text}", file=sys.stderr, flush=True)


# -- where things run --------------------------------------------------------------------------------
@dataclass
class Hosts:
    """How to start a command on each host (an argv prefix) and each host's address."""

    network: str  # "netns" | "loopback"
    prefixes: dict[str, list[str]]
    addresses: dict[str, str]

    @classmethod
    def loopback(cls) -> Hosts:
        return cls("loopback", {h: [] for h in HOSTS}, {h: "127.0.0.1" for h in HOSTS})

    @classmethod
    def of(cls, lan: netns.Lan) -> Hosts:
        return cls("netns", {h: lan.prefix(h) for h in HOSTS}, {h: lan.address(h) for h in HOSTS})

    def endpoint(self, proto: str, port: int) -> str:
        """The hub's endpoint: fixed ports in the hub's own namespace, free ones on loopback."""
        if self.network == "loopback":
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = int(s.getsockname()[1])
        return f"{proto}/{self.addresses['hub']}:{port}"


class LanMesh(LocalMesh):
    """A LocalMesh whose hub listens on the hub host's address and whose nodes start on the `sim` host."""

    def __init__(self, hosts: Hosts, endpoint: str, name: str) -> None:
        super().__init__(endpoint=endpoint)
        self.hosts = hosts
        self.name = name
        self.eve = ""  # secured: the second user's password
        self.ca_file = ""

    def argv_prefix(self, module: str) -> list[str]:
        return self.hosts.prefixes["hub" if module == HUB else "sim"]

    def keep_logs(self, logs: Path) -> None:
        target = logs / self.name
        target.mkdir(parents=True, exist_ok=True)
        for path in self.folder.glob("*.log"):
            shutil.copy(path, target / path.name)


def plain_mesh(hosts: Hosts) -> LanMesh:
    mesh = LanMesh(hosts, hosts.endpoint("tcp", PLAIN_PORT), "plain")
    mesh.start_hub()
    mesh.start_service(max_running=4, simulator_args=("--warm", "2"))  # two runs start at once
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    return mesh


def secured_mesh(hosts: Hosts) -> tuple[LanMesh, str]:
    """As `simecs up` (private, its default) and the `secured` fixture make it, with two users, ann and
    eve; returns the mesh and ann's password (eve's: `mesh.eve`)."""
    mesh = LanMesh(hosts, hosts.endpoint("tls", TLS_PORT), "secured")
    service = mesh.start_secured({"ann": "user", "eve": "user"}, [hosts.addresses["hub"]])
    mesh.eve = service.passwords["eve"]  # the attacker of the forgery trial, a user like any other
    mesh.ca_file = str(service.folder.ca_file)
    password = service.passwords["ann"]
    return mesh, password


def prepared(
    client: MeshClient, user: str, stop: float, pacing: str, target: list[float] | None = None
) -> SessionClient:
    s = client.create_session(user, "spider")
    s.set_settings(stop_time=stop, output_interval=OUTPUT, pacing=pacing)
    s.set_joint_path([(target or TARGET, 100.0, 100.0)])
    return s


def recording_files(mesh: LocalMesh, s: SessionClient, run_id: str) -> list[Path]:
    """The run's recording and its continuations (a restarted recorder writes `<name>.2.mcap`)."""
    name = keys.recording_name(s.id, run_id)
    folder = mesh.folder / "rec" / s.user
    return sorted(p for p in folder.glob(f"{name}*.mcap") if p.stem == name or p.stem.startswith(name + "."))


def closed_recordings(
    mesh: LocalMesh, s: SessionClient, run_id: str, parts: int, timeout: float
) -> list[Path]:
    """The run's `parts` recording files once each is complete (has its footer)."""
    from simecs.nodes.recording import mcapread

    def done() -> list[Path]:
        paths = recording_files(mesh, s, run_id)
        return paths if len(paths) >= parts and all(mcapread.has_footer(p) for p in paths) else []

    return list(wait_until(done, timeout, 0.1, f"{parts} closed recording(s) of {run_id}"))


def recording_matches(mesh: LocalMesh, s: SessionClient, run_id: str) -> bool:
    """The run's one recording holds exactly its results, with no gap left."""
    from simecs.nodes.recording import mcapread

    try:
        (path,) = closed_recordings(mesh, s, run_id, 1, 40.0)
        rec = mcapread.load(path)
        _cols, rows = s.results(run_id)
    except Exception as exc:  # no file, a bad file, no results: all mean "not the results"
        log(f"recording of {s.user}/{run_id}: {exc}")
        return False
    same = rec.rows.shape == rows.shape and bool(np.array_equal(rec.rows, rows))
    return same and rec.metadata.get("simecs.end", {}).get("gaps") == "0"


def live_nodes(client: MeshClient) -> list[tuple[str, str]]:
    try:
        return client.live_nodes(timeout=0.5)
    except Exception:  # while the session has no hub
        return []


def sim_time_above(s: SessionClient, t: float) -> Callable[[], bool]:
    return lambda: s.snapshot().state.sim_time > t
