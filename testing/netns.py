"""Hosts of a LAN on one machine: Linux network namespaces joined by veth pairs on a private bridge.

`simecs bench lan` runs the hub, the service and the clients on different "hosts" so that everything
between them crosses a real (virtual) Ethernet link and TCP/TLS stack, as on a LAN, instead of the
loopback interface. Needs root (`ip netns`); `Lan.up()` raises `NetnsUnavailable` otherwise.

Nothing of the machine's own network is touched: the bridge lives in a namespace of its own (the
"switch"), each host namespace gets one veth leg with a private address (`10.231.0.<n>/24`, valid only
inside these namespaces), and `down()` removes every namespace made here, and with them every link.
Processes still running in them (ours: they were started there) are killed first, by id.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from collections.abc import Sequence
from typing import Any

SUBNET = "10.231.0"
PREFIX = "smx"  # names: smx<pid>-<host>, so a crashed bench's leftovers can be recognised
_OURS = re.compile(rf"^{PREFIX}(\d+)-\w+$")


class NetnsUnavailable(RuntimeError):
    """Network namespaces cannot be made here (not root, no `ip`, a kernel without veth/bridge)."""


def _ip(*args: str, timeout: float = 10.0) -> str:
    proc = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise NetnsUnavailable(f"ip {' '.join(args)}: {proc.stderr.strip() or proc.returncode}")
    return proc.stdout


def _namespaces() -> list[str]:
    try:
        out = _ip("netns", "list")
    except (NetnsUnavailable, OSError, subprocess.TimeoutExpired):
        return []
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def _kill_and_delete(ns: str) -> None:
    """Kill what runs in namespace `ns` (by id) and delete it; its veth legs go with it."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            pids = [int(p) for p in _ip("netns", "pids", ns).split()]
        except (NetnsUnavailable, OSError, ValueError, subprocess.TimeoutExpired):
            pids = []
        if not pids:
            break
        for pid in pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        end = time.monotonic() + 3.0
        while time.monotonic() < end and any(_alive(p) for p in pids):
            time.sleep(0.05)
    try:
        _ip("netns", "delete", ns)
    except (NetnsUnavailable, OSError, subprocess.TimeoutExpired):
        pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_leftovers() -> list[str]:
    """Delete namespaces an earlier bench made and could not remove (its process is gone)."""
    removed = []
    for ns in _namespaces():
        match = _OURS.match(ns)
        if match and int(match.group(1)) != os.getpid() and not _alive(int(match.group(1))):
            _kill_and_delete(ns)
            removed.append(ns)
    return removed


class Lan:
    """Hosts `names` (namespaces) on one bridge: host i has address 10.231.0.<i+1>."""

    def __init__(self, names: Sequence[str]) -> None:
        if len(set(names)) != len(names) or not all(re.fullmatch(r"\w{1,8}", n) for n in names):
            raise ValueError(f"host names must be distinct words of at most 8 characters: {names}")
        self.hosts = list(names)
        self.tag = f"{PREFIX}{os.getpid()}"
        self.switch = f"{self.tag}-sw"
        self.made: list[str] = []

    def namespace(self, host: str) -> str:
        return f"{self.tag}-{host}"

    def address(self, host: str) -> str:
        return f"{SUBNET}.{self.hosts.index(host) + 1}"

    def prefix(self, host: str) -> list[str]:
        """The argv prefix that runs a command on `host`."""
        return ["ip", "netns", "exec", self.namespace(host)]

    def up(self) -> Lan:
        """Make the switch and the hosts; on any failure, remove what was made and raise."""
        if os.geteuid() != 0:
            raise NetnsUnavailable("network namespaces need root")
        remove_leftovers()
        try:
            self._add(self.switch)
            _ip("-n", self.switch, "link", "add", "br0", "type", "bridge")
            _ip("-n", self.switch, "link", "set", "br0", "up")
            for i, host in enumerate(self.hosts):
                ns = self.namespace(host)
                self._add(ns)
                leg = f"p{i}"
                _ip(
                    "-n", ns, "link", "add", "eth0", "type", "veth", "peer", "name", leg, "netns", self.switch
                )
                _ip("-n", self.switch, "link", "set", leg, "master", "br0")
                _ip("-n", self.switch, "link", "set", leg, "up")
                _ip("-n", ns, "addr", "add", f"{self.address(host)}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "eth0", "up")
                _ip("-n", ns, "link", "set", "lo", "up")
            self._wait_links()
        except (NetnsUnavailable, OSError, subprocess.TimeoutExpired) as exc:
            self.down()
            raise NetnsUnavailable(str(exc)) from None
        return self

    def _add(self, ns: str) -> None:
        _ip("netns", "add", ns)
        self.made.append(ns)

    def _wait_links(self, timeout: float = 5.0) -> None:
        """Until every host's address is usable (IPv4 has no duplicate detection, but the bridge
        ports start in a learning state for a moment)."""
        end = time.monotonic() + timeout
        for host in self.hosts:
            while "UP" not in _ip("-n", self.namespace(host), "-br", "link", "show", "eth0"):
                if time.monotonic() > end:
                    raise NetnsUnavailable(f"link of {host} not up within {timeout} s")
                time.sleep(0.05)

    def down(self) -> None:
        """Kill what runs on the hosts and remove every namespace made here (links go with them)."""
        for ns in reversed(self.made):
            _kill_and_delete(ns)
        self.made.clear()

    def __enter__(self) -> Lan:
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.down()


def lan_mesh(
    lan: Lan, placement: dict[str, str], hub_host: str = "hub", cpus: dict[str, int] | None = None
) -> Any:
    """A `LocalMesh` whose hub listens on `hub_host`'s LAN address too, and whose nodes named in
    `placement` (node name -> host) run on their host and join the hub over the LAN. The harness
    itself (and nodes not placed) stays on the machine and joins through the hub's unix socket.
    `cpus` pins nodes (by name) to one CPU each, as a host of that size."""
    from simecs.nodes.local_mesh import LocalMesh

    lan_endpoint = f"tcp/{lan.address(hub_host)}:7447"

    class LanMesh(LocalMesh):
        _placing = ""  # the node being spawned

        def spawn(self, name: str, module: str, *args: str, node_id: str | None = None) -> Any:
            if module == "simecs.nodes.hub":
                args = (*args, "--listen", lan_endpoint)
            self._placing = name
            return super().spawn(name, module, *args, node_id=node_id)

        def argv_prefix(self, module: str) -> list[str]:
            if module == "simecs.nodes.hub":
                return lan.prefix(hub_host)
            host = placement.get(self._placing)
            pin = (cpus or {}).get(self._placing)
            return [
                *(lan.prefix(host) if host else []),
                *(["taskset", "-c", str(pin)] if pin is not None else []),
            ]

        def connect_to(self, name: str) -> str:
            return lan_endpoint if name in placement else self.endpoint

    return LanMesh()
