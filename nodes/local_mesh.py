"""Start a private mesh of node processes: for `simecs run --embedded`, the tests and the benchmarks.

Each `LocalMesh` has its own hub on a unix socket in a fresh temporary folder (no ports, no races,
no cross-talk with anything else on the machine or the LAN; multicast scouting and shared memory stay
off). Nodes are started by module name, so nothing here imports a node: forked from one fork server
per process that imported and warmed up every node once (mesh/process/forks.py, nodes/node_forks.py;
SIMECS_FORK_NODES=0 starts each as `python -m` instead), or as `python -m` when it cannot be.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simecs.mesh.client import MeshClient
from simecs.mesh.process import seal as seals
from simecs.mesh.process.config import MeshConfig, load
from simecs.mesh.process.forks import ForkedProcess, ForkServer

from .secure import SecureFolder


def wait_until(
    predicate: Callable[[], Any], timeout: float = 10.0, interval: float = 0.02, what: str = "condition"
) -> Any:
    """`predicate()`'s first true value, asked every `interval` s; TimeoutError after `timeout` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise TimeoutError(f"{what} not met within {timeout} s")


def clean_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("SIMECS_MESH_CONFIG", None)
    env["SIMECS_CLIENT_CONFIG"] = ""  # never this machine's user's file (`simecs up`): each test its own mesh
    env["PYTHONUNBUFFERED"] = "1"
    return env


#: s the fork server of nodes may take to warm up (loading the kernels: a few s; compiling them, on a
#: fresh install without `make warm`: minutes, which each node would otherwise spend itself).
WARM_TIMEOUT_S = 900.0
_forks_lock = threading.Lock()
_forks: list[ForkServer | None] = []  # this process's fork server of nodes, once asked for (None: none)


def node_forks() -> ForkServer | None:
    """This process's fork server of nodes, started on first use (a few CPU s, once); None when
    SIMECS_FORK_NODES=0 or it could not start."""
    with _forks_lock:
        if not _forks:
            server = None
            if os.environ.get("SIMECS_FORK_NODES", "1") != "0":
                from .node_forks import WARM  # names modules only: importing it imports no node

                # A cold numba cache compiles for minutes here, once, instead of in every node
                server = ForkServer.start(WARM, clean_env(), timeout=WARM_TIMEOUT_S)
            _forks.append(server)
        return _forks[0]


@dataclass
class SecuredService:
    """What `LocalMesh.start_secured` made: the secure folder, each user's password and the service
    nodes' configuration file."""

    folder: SecureFolder
    passwords: dict[str, str]
    node_config: str


class LocalMesh:
    """A hub and the nodes started on it; `close()` stops them all (SIGTERM, then SIGKILL)."""

    def __init__(self, folder: str | os.PathLike[str] | None = None, endpoint: str = "") -> None:
        # Short path: unix socket paths are limited to 108 bytes.
        self.folder = Path(folder) if folder else Path(tempfile.mkdtemp(prefix="smx"))
        self._owns_folder = folder is None
        self.endpoint = endpoint or f"unixsock-stream/{self.folder}/hub.sock"
        #: How this harness joins the hub (a secured hub: as the service); default a plain client.
        self.client_config: MeshConfig | None = None
        self.key_file = self.folder / "service.key"  # this mesh's service secret (mesh/process/seal.py)
        self.seal = seals.load(self.key_file, create=True)
        self.procs: dict[str, subprocess.Popen[bytes] | ForkedProcess] = {}
        self.clients: list[MeshClient] = []

    @property
    def config(self) -> MeshConfig:
        """A client of this mesh that checks the service's seals, as the viewer does."""
        if self.client_config is not None:
            return self.client_config
        return MeshConfig(mode="client", connect=[self.endpoint], service_key_file=str(self.key_file))

    def spawn(
        self, name: str, module: str, *args: str, node_id: str | None = None
    ) -> subprocess.Popen[bytes] | ForkedProcess:
        """Start `python -m module args` (forked warm when it can be), logging to `<folder>/<name>.log`,
        in a process group of its own."""
        flags = list(args)
        if module != "simecs.nodes.hub":
            flags += ["--connect", self.connect_to(name)]
        if node_id:
            flags += ["--node-id", node_id]
        env = clean_env()
        env["SIMECS_SERVICE_KEY_FILE"] = str(self.key_file)
        prefix = self.argv_prefix(module)
        with open(self.folder / f"{name}.log", "ab") as log:
            forks = node_forks() if not prefix else None
            fd = log.fileno()
            forked = forks.spawn(module, flags, env, fds={1: fd, 2: fd}) if forks is not None else None
            proc: subprocess.Popen[bytes] | ForkedProcess
            if forked is not None:
                proc = forked
            else:
                proc = subprocess.Popen(
                    [*prefix, sys.executable, "-m", module, *flags],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=env,
                    start_new_session=True,
                )
        self.procs[name] = proc
        return proc

    def connect_to(self, name: str) -> str:
        """The endpoint node `name` joins the hub on (a LAN of namespaces overrides it)."""
        return self.endpoint

    def argv_prefix(self, module: str) -> list[str]:
        """What runs a node's command on its host (a LAN of namespaces overrides it; here: nothing)."""
        return []

    def start_hub(self) -> None:
        self.spawn("hub", "simecs.nodes.hub", "--listen", self.endpoint, node_id="hub")
        self.client()  # returns once the hub accepts clients

    def start(
        self, role: str, *args: str, name: str | None = None, module: str | None = None, timeout: float = 60.0
    ) -> str:
        """Start node `role` and wait until its liveliness token (= ready) is up; returns its node id."""
        name = name or role
        node_id = f"{name}-t"
        self.spawn(name, module or f"simecs.nodes.{role}", *args, node_id=node_id)
        self.wait_node(role, node_id, timeout, name)
        return node_id

    def start_together(self, nodes: dict[str, tuple[str, ...]], timeout: float = 60.0) -> None:
        """Start several nodes (role -> arguments) at once, then wait until each is ready: their
        start-ups overlap (each finds the others on the mesh, as after any node's restart)."""
        for role, args in nodes.items():
            self.spawn(role, f"simecs.nodes.{role}", *args, node_id=f"{role}-t")
        for role in nodes:
            self.wait_node(role, f"{role}-t", timeout, role)

    def wait_node(self, role: str, node_id: str, timeout: float = 60.0, name: str | None = None) -> None:
        client = self.client()
        proc = self.procs.get(name or role)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if (role, node_id) in client.live_nodes(timeout=0.5):
                return
            if proc is not None and proc.poll() is not None:
                raise RuntimeError(f"{name or role} exited with {proc.returncode}:\n{self.log(name or role)}")
            time.sleep(0.05)
        raise TimeoutError(f"node {role}/{node_id} not live within {timeout} s:\n{self.log(name or role)}")

    def start_service(
        self, max_running: int = 4, simulator_args: tuple[str, ...] = (), proxy_args: tuple[str, ...] = ()
    ) -> Path:
        """Proxy, simulator and hot-feedback; returns the data folder."""
        data = self.folder / "data"
        self.start_together(
            {
                "simulator": ("--results-dir", str(data / "results"), *simulator_args),  # the slowest
                "proxy": ("--data-dir", str(data), "--max-running", str(max_running), *proxy_args),
                "hotfeedback": (),
            }
        )
        return data

    def start_secured(self, users: Mapping[str, str], addresses: Sequence[str] = ()) -> SecuredService:
        """A private mesh as `simecs up` makes it by default, on this mesh's (TLS) endpoint: a hub with
        the generated access rules, `users` (name -> role) with passwords of their own, the service's
        nodes (simulator, proxy, hot-feedback, recorder) joined as the service, and this harness
        joined as the service too. The hub's certificate names `addresses` besides loopback."""
        folder = SecureFolder(self.folder / "secure")
        passwords = {name: folder.add_user(name, role) for name, role in users.items()}
        folder.ensure_certificates(list(addresses))
        hub = folder.hub_config([self.endpoint])
        nodes = str(folder.node_config(self.endpoint, str(self.key_file)))
        self.client_config = load(nodes, env={})
        self.spawn("hub", "simecs.nodes.hub", "--mesh-config", str(hub), node_id="hub")
        self.client()  # returns once the hub accepts clients
        data = self.folder / "data"
        self.start_together(  # their start-ups overlap, as `simecs up` starts them
            {
                "simulator": ("--results-dir", str(data / "results"), "--mesh-config", nodes),
                "proxy": ("--data-dir", str(data), "--mesh-config", nodes),
                "hotfeedback": ("--mesh-config", nodes),
                "recorder": ("--dir", str(self.folder / "rec"), "--mesh-config", nodes),
            }
        )
        return SecuredService(folder, passwords, nodes)

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
        try:  # whatever is left in the node's group (e.g. simulator workers)
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        return proc.returncode

    def close(self) -> None:
        for c in self.clients:
            try:
                c.close()
            except Exception:
                pass
        self.clients.clear()
        for name in reversed(list(self.procs)):
            if name != "hub":
                self.stop(name)
        if "hub" in self.procs:
            self.stop("hub")
        if self._owns_folder:
            shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> LocalMesh:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
