"""Every example in docs/examples runs against real nodes (as zenoh-python tests its examples)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from .conftest import Service, mesh_env

EXAMPLES = Path(__file__).resolve().parent.parent / "docs" / "examples"


def run_example(name: str, service: Service, timeout: float = 180.0, protocol_only: bool = True) -> str:
    """Run docs/examples/<name> against the service's hub; its stdout (the run must succeed).
    `protocol_only`: the example uses no simecs code, only the document and the schema."""
    if protocol_only:
        assert "simecs." not in (EXAMPLES / name).read_text().replace("simecs/", "")
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / name), service.mesh.endpoint],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=mesh_env(),
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def test_plain_client_from_the_protocol_document(service: Service) -> None:
    service.mesh.start("recorder", "--dir", str(service.mesh.folder / "rec"))
    stdout = run_example("plain_client.py", service, timeout=120)
    assert "run r1: finished" in stdout
    assert "101 samples of ['time', 'joint1.q', 'joint2.q']" in stdout
    assert "replay r2: finished" in stdout and "r2 finished (replay)" in stdout


def test_commands_client_runs_a_line_and_a_saved_task(service: Service) -> None:
    stdout = run_example("commands_client.py", service)
    line = next(x for x in stdout.splitlines() if x.startswith("line r1:"))
    assert float(line.split("ends ")[1].split(" mm")[0]) < 2.0, line
    assert "saved: ['back']" in stdout
    assert "task r2: finished; steps seen: retreat, wait, settle" in stdout, stdout


def test_batch_client_runs_and_sweeps_with_the_python_api(service: Service) -> None:
    stdout = run_example("batch_client.py", service, protocol_only=False)
    assert "r1: finished, 1001 samples, joint2 ends at 0.3" in stdout, stdout
    assert sum(line.startswith("kp_pos") for line in stdout.splitlines()) == 3, stdout


def test_external_controller_closes_the_loop_and_matches_the_builtin_controller(service: Service) -> None:
    stdout = run_example("external_controller.py", service)
    line = next(x for x in stdout.splitlines() if x.startswith("built-in vs external controller:"))
    assert float(line.split(": ")[1].split(" mrad")[0]) < 0.5, stdout
    assert "control periods in" in stdout
