"""The live path's placement: hub, hot-feedback (and viewer) share the mesh core, simulator workers
put only their zenoh threads there, everything else is left to the OS (`simecs.mesh.process.affinity`)."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
from simecs.mesh.process import affinity
from simecs.nodes.local_mesh import LocalMesh, clean_env

from .conftest import Mesh, Service, wait_until, worker_pids
from .test_robustness import watch_status

ALLOWED = os.sched_getaffinity(0)
multi_cpu = pytest.mark.skipif(len(ALLOWED) < 2, reason="placement only matters with two CPUs or more")
ZENOH_THREAD = re.compile(r"^(app|rx|tx|net|acc)-\d+$")


def threads(pid: int) -> dict[int, tuple[str, set[int]]]:
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                name = f.read().strip()
            out[int(tid)] = (name, os.sched_getaffinity(int(tid)))
        except (FileNotFoundError, ProcessLookupError):
            continue
    return out


def test_cpu_choices() -> None:
    assert affinity.mesh_core("none") is None
    assert affinity.mesh_core("auto") == (max(ALLOWED) if len(ALLOWED) >= 2 else None)
    assert affinity.mesh_core(str(min(ALLOWED))) == min(ALLOWED)
    with pytest.raises(ValueError, match="expected auto, none or a CPU number"):
        affinity.mesh_core("banana")
    with pytest.raises(ValueError, match="may run on CPUs"):
        affinity.mesh_core("4096")


@multi_cpu
def test_live_path_shares_the_mesh_core(service: Service) -> None:
    core = {max(ALLOWED)}
    procs = service.mesh.procs
    for name in ("hub", "hotfeedback"):
        placed = threads(procs[name].pid)
        assert all(cpus == core for _, cpus in placed.values()), (name, placed)
    # Nodes off the live path are left to the OS.
    assert all(cpus == ALLOWED for _, cpus in threads(procs["proxy"].pid).values())
    # A warm worker: simulation (main) thread free, zenoh's threads on the mesh core.
    workers = worker_pids(procs["simulator"].pid)
    assert workers
    worker = workers[0]

    def zenoh_threads_placed() -> bool:
        zt = [cpus for name, cpus in threads(worker).values() if ZENOH_THREAD.match(name)]
        return bool(zt) and all(cpus == core for cpus in zt)

    # (placed as soon as its session has opened)
    wait_until(zenoh_threads_placed, timeout=60, what=f"worker {worker}'s zenoh threads on {core}")
    assert threads(worker)[worker][1] == ALLOWED
    # The node says where it runs.
    seen, sub = watch_status(service, "hotfeedback")
    try:
        wait_until(lambda: seen, what="hot-feedback status")
        assert seen[-1].detail["cpu"] == max(ALLOWED)
    finally:
        sub.undeclare()


@multi_cpu
def test_cpu_none_leaves_placement_to_the_os(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SIMECS_CPU", "none")
    with LocalMesh() as mesh:
        mesh.start_hub()
        mesh.start("hotfeedback")
        for name in ("hub", "hotfeedback"):
            assert all(cpus == ALLOWED for _, cpus in threads(mesh.procs[name].pid).values())


def test_a_bad_cpu_choice_stops_the_node_with_the_reason(mesh: Mesh) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "simecs.nodes.hotfeedback", "--connect", mesh.endpoint, "--cpu", "banana"],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=60,
    )
    assert proc.returncode == 1
    assert "--cpu 'banana': expected auto, none or a CPU number" in proc.stdout + proc.stderr
