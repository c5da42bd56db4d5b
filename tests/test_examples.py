"""Every example in docs/examples runs against real nodes (as zenoh-python tests its examples)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from .conftest import Service, mesh_env

EXAMPLES = Path(__file__).resolve().parent.parent / "docs" / "examples"


def test_plain_client_from_the_protocol_document(service: Service) -> None:
    service.mesh.start("recorder", "--dir", str(service.mesh.folder / "rec"))
    source = (EXAMPLES / "plain_client.py").read_text()
    assert "simecs." not in source.replace("simecs/", "")  # no simecs code: the document alone
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / "plain_client.py"), service.mesh.endpoint],
        capture_output=True,
        text=True,
        timeout=120,
        env=mesh_env(),
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "run r1: finished" in out.stdout
    assert "101 samples of ['time', 'joint1.q', 'joint2.q']" in out.stdout
    assert "replay r2: finished" in out.stdout and "r2 finished (replay)" in out.stdout


def test_commands_client_runs_a_line_and_a_saved_task(service: Service) -> None:
    source = (EXAMPLES / "commands_client.py").read_text()
    assert "simecs." not in source.replace("simecs/", "")
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / "commands_client.py"), service.mesh.endpoint],
        capture_output=True,
        text=True,
        timeout=180,
        env=mesh_env(),
    )
    assert out.returncode == 0, out.stdout + out.stderr
    line = next(x for x in out.stdout.splitlines() if x.startswith("line r1:"))
    assert float(line.split("ends ")[1].split(" mm")[0]) < 2.0, line
    assert "saved: ['back']" in out.stdout
    assert "task r2: finished; steps seen: retreat, wait, settle" in out.stdout, out.stdout


def test_batch_client_runs_and_sweeps_with_the_python_api(service: Service) -> None:
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / "batch_client.py"), service.mesh.endpoint],
        capture_output=True,
        text=True,
        timeout=180,
        env=mesh_env(),
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "r1: finished, 1001 samples, joint2 ends at 0.3" in out.stdout, out.stdout
    assert sum(line.startswith("kp_pos") for line in out.stdout.splitlines()) == 3, out.stdout
