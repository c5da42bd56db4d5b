"""Fixtures that start real node processes on a mesh of their own.

Every test gets its own hub on a unix socket in a fresh temporary folder (no ports, no races, no
cross-talk with other tests or machines), with multicast scouting and shared memory off. Every wait
is bounded; every process is stopped (SIGTERM, then SIGKILL) when the test ends.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from simecs.mesh.client import MeshClient
from simecs.testing.launch import LocalMesh, clean_env

ARTIFACTS = Path(__file__).resolve().parent.parent / "artifacts"

Mesh = LocalMesh
mesh_env = clean_env


@pytest.fixture
def mesh() -> Iterator[LocalMesh]:
    m = LocalMesh()
    try:
        m.start_hub()
        yield m
    finally:
        m.close()


@dataclass
class Service:
    mesh: LocalMesh
    data_dir: Path

    @property
    def client(self) -> MeshClient:
        return self.mesh.client()


def start_service(mesh: LocalMesh, max_running: int = 4, extra_simulator: tuple[str, ...] = ()) -> Service:
    return Service(mesh, mesh.start_service(max_running, extra_simulator))


@pytest.fixture
def service(mesh: LocalMesh) -> Service:
    """Hub, proxy, simulator and hot-feedback on an isolated mesh."""
    return start_service(mesh)


def wait_until(
    predicate: Callable[[], Any], timeout: float = 10.0, interval: float = 0.02, what: str = "condition"
) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise TimeoutError(f"{what} not met within {timeout} s")
