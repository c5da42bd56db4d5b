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
