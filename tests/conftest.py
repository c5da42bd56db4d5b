"""Fixtures that start real node processes on a mesh of their own.

Every test gets its own hub on a unix socket in a fresh temporary folder (no ports, no races, no
cross-talk with other tests or machines), with multicast scouting and shared memory off. Every wait
is bounded; every process is stopped (SIGTERM, then SIGKILL) when the test ends.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from simecs.mesh import keys
from simecs.mesh.client import MeshClient
from simecs.mesh.config import MeshConfig

ARTIFACTS = Path(__file__).resolve().parent.parent / "artifacts"


def mesh_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("SIMECS_MESH_CONFIG", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@dataclass
class Mesh:
    """One isolated mesh: a hub and the nodes a test starts on it."""

    folder: Path
    endpoint: str
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    clients: list[MeshClient] = field(default_factory=list)

    @property
    def config(self) -> MeshConfig:
        return MeshConfig(mode="client", connect=[self.endpoint])

    def spawn(
        self, name: str, module: str, *args: str, node_id: str | None = None
    ) -> subprocess.Popen[bytes]:
        argv = [sys.executable, "-m", module, *args]
        if module != "simecs.nodes.hub":
            argv += ["--connect", self.endpoint]
        if node_id:
            argv += ["--node-id", node_id]
        log = open(self.folder / f"{name}.log", "ab")  # noqa: SIM115 - closed with the folder
        proc = subprocess.Popen(
            argv, stdout=log, stderr=subprocess.STDOUT, env=mesh_env(), start_new_session=True
        )
        self.procs[name] = proc
        return proc

    def start_hub(self) -> None:
        self.spawn("hub", "simecs.nodes.hub", "--listen", self.endpoint, node_id="hub")
        self.client()  # returns once the hub accepts clients

    def start(self, role: str, *args: str, name: str | None = None, timeout: float = 60.0) -> str:
        """Start node `role` (module simecs.nodes.<role>) and wait for its liveliness token."""
        name = name or role
        node_id = f"{name}-t"
        self.spawn(name, f"simecs.nodes.{role}", *args, node_id=node_id)
        self.wait_node(role, node_id, timeout)
        return node_id

    def wait_node(self, role: str, node_id: str, timeout: float = 60.0) -> None:
        client = self.client()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if (role, node_id) in client.live_nodes(timeout=0.5):
                return
            for name, proc in self.procs.items():
                if proc.poll() is not None and name.startswith(role):
                    raise RuntimeError(f"{name} exited with {proc.returncode}:\n{self.log(name)}")
            time.sleep(0.05)
        raise TimeoutError(f"node {role}/{node_id} not live within {timeout} s:\n{self.log(role)}")

    def log(self, name: str) -> str:
        path = self.folder / f"{name}.log"
        return path.read_text(errors="replace")[-4000:] if path.exists() else ""

    def client(self) -> MeshClient:
        if not self.clients:
            self.clients.append(MeshClient.open(self.config, timeout=10.0))
        return self.clients[0]

    def new_client(self) -> MeshClient:
        c = MeshClient.open(self.config, timeout=10.0)
        self.clients.append(c)
        return c

    def stop(self, name: str, sig: int = signal.SIGTERM, timeout: float = 5.0) -> int | None:
        proc = self.procs[name]
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(2)
        return proc.returncode

    def close(self) -> None:
        for c in self.clients:
            try:
                c.close()
            except Exception:
                pass
        for name in reversed(list(self.procs)):
            if name != "hub":
                self.stop(name)
        if "hub" in self.procs:
            self.stop("hub")


@pytest.fixture
def mesh() -> Iterator[Mesh]:
    folder = Path(tempfile.mkdtemp(prefix="smx"))  # short: unix socket paths are limited to 108 bytes
    m = Mesh(folder=folder, endpoint=f"unixsock-stream/{folder}/hub.sock")
    try:
        m.start_hub()
        yield m
    finally:
        m.close()
        shutil.rmtree(folder, ignore_errors=True)


@dataclass
class Service:
    mesh: Mesh
    data_dir: Path

    @property
    def client(self) -> MeshClient:
        return self.mesh.client()


def start_service(mesh: Mesh, max_running: int = 4, extra_simulator: tuple[str, ...] = ()) -> Service:
    data = mesh.folder / "data"
    mesh.start("proxy", "--data-dir", str(data), "--max-running", str(max_running))
    mesh.start("simulator", "--results-dir", str(data / "results"), *extra_simulator)
    mesh.start("hotfeedback")
    return Service(mesh, data)


@pytest.fixture
def service(mesh: Mesh) -> Service:
    """Hub, proxy, simulator and hot-feedback on an isolated mesh."""
    return start_service(mesh)


def wait_until(predicate, timeout: float = 10.0, interval: float = 0.02, what: str = "condition"):  # noqa: ANN001
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise TimeoutError(f"{what} not met within {timeout} s")


__all__ = ["Mesh", "Service", "start_service", "wait_until", "keys", "ARTIFACTS"]
