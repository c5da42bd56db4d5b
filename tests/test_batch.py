"""Headless runs for integrators: `simecs run` and `simecs sweep` as a CI job would call them, against
real nodes (and a private mesh with --embedded); the Python API behind them in mesh/batch.py."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from simecs.mesh import batch
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.recording import mcapread

from tests.conftest import Service, mesh_env
from tests.test_recorder_support import wait_file_closed

Q0 = [0.0, 0.2, 0.0, 0.3, 0.0, 0.0, 0.0]
PATH = m.JointPath([m.PathNode([0.3, 0.4, 0.0, 0.3, 0.0, 0.2, 0.0], 100.0, 100.0)])


def simecs(*args: str, timeout: float = 180.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "simecs.nodes.tools.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=mesh_env(),
    )


def write(folder: Path, name: str, obj: object) -> str:
    path = folder / name
    path.write_text(json.dumps(obj))
    return str(path)


def test_simecs_run_writes_the_recording_a_client_run_leaves(service: Service, tmp_path: Path) -> None:
    mesh = service.mesh
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    c = service.client
    settings = m.RunSettings(stop_time=1.0, output_interval=0.002, pacing="fast")
    values = {"joint2.ctrl.kp_pos": 30.0}
    by_client = batch.run_simulation(c, "ci", "spider", PATH, values, Q0, settings, close=False)
    assert by_client.ok and by_client.rows.shape[0] == 501
    path = mesh.folder / "rec" / "ci" / f"{keys.recording_name(by_client.session, by_client.run_id)}.mcap"
    wait_file_closed(path, timeout=40.0)
    reference = mcapread.load(path)

    command = write(tmp_path, "cmd.json", {"kind": "joint_path", "nodes": [{"q": PATH.nodes[0].q}]})
    params = write(tmp_path, "set.json", {"values": values})
    common = [
        "--model",
        "spider",
        "--command",
        command,
        "--params",
        params,
        "--initial",
        ",".join(map(str, Q0)),
    ]
    common += ["--stop-time", "1.0", "--output-interval", "0.002", "--connect", mesh.endpoint, "--user", "ci"]
    out = simecs("run", *common, "--out", str(tmp_path / "run.mcap"))
    assert out.returncode == 0, out.stderr
    assert "run r1: finished at t = 1.000 s" in out.stderr
    mine = mcapread.load(tmp_path / "run.mcap")
    assert mine.layout.columns == reference.layout.columns
    assert np.array_equal(mine.rows, reference.rows)  # the simulation is deterministic
    assert mine.context("").command == reference.context("").command == PATH

    out = simecs("run", *common, "--out", str(tmp_path / "run.csv"), "--vars", "joint2.q,joint2.i_ref")
    assert out.returncode == 0, out.stderr
    with (tmp_path / "run.csv").open() as fh:
        table = list(csv.reader(fh))
    assert table[0] == ["time", "joint2.q", "joint2.i_ref"] and len(table) == 502
    assert np.allclose(
        [float(r[1]) for r in table[1:]], reference.rows[:, reference.layout.columns.index("joint2.q")]
    )
    assert c.list_sessions("ci") == [m.SessionEntry(by_client.session, "spider", "finished")]


def test_simecs_run_says_what_is_wrong_with_a_clear_exit_code(service: Service, tmp_path: Path) -> None:
    endpoint = ["--connect", service.mesh.endpoint, "--model", "spider", "--out", str(tmp_path / "x.csv")]
    far = write(tmp_path, "far.json", {"kind": "joint_path", "nodes": [{"q": [9.0] * 7}]})
    out = simecs("run", *endpoint, "--command", far)
    assert out.returncode == 2 and "command.nodes[0].q[0]" in out.stderr, out.stderr
    broken = write(tmp_path, "broken.json", {"kind": "joint_path", "nodes": "all"})
    out = simecs("run", *endpoint, "--command", broken)
    assert out.returncode == 2 and "nodes" in out.stderr, out.stderr
    ok = write(tmp_path, "ok.json", {"kind": "action", "primitive": "wait", "args": {"duration": 0.1}})
    out = simecs("run", *endpoint, "--command", ok, "--stop-time", "0")
    assert out.returncode == 2 and "stop_time" in out.stderr, out.stderr
    out = simecs(
        "run",
        "--connect",
        "tcp/127.0.0.1:9",
        "--model",
        "spider",
        "--command",
        ok,
        "--out",
        "x.csv",
        timeout=60,
    )
    assert out.returncode == 3, out.stderr
    assert not (tmp_path / "x.csv").exists()


def test_simecs_sweep_tabulates_one_row_per_variation(service: Service, tmp_path: Path) -> None:
    command = write(tmp_path, "cmd.json", {"kind": "joint_path", "nodes": [{"q": PATH.nodes[0].q}]})
    table = tmp_path / "sweep.csv"
    out = simecs(
        "sweep", "--connect", service.mesh.endpoint, "--model", "spider", "--command", command,
        "--initial", ",".join(map(str, Q0)), "--stop-time", "2.0",
        "--grid", "joint2.ctrl.kp_pos=5,40", "--grid", "joint2.ctrl.kp_vel=0.5,2",
        "--measure", "overshoot:joint2.q", "--measure", "max_abs:joint2.i_ref", "--measure", "final:joint2.q",
        "--parallel", "2", "--out", str(table),
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    rows = list(csv.DictReader(table.open()))
    assert len(rows) == 4 and [r["case"] for r in rows] == ["1", "2", "3", "4"]
    assert {(r["joint2.ctrl.kp_pos"], r["joint2.ctrl.kp_vel"]) for r in rows} == {
        ("5.0", "0.5"), ("5.0", "2.0"), ("40.0", "0.5"), ("40.0", "2.0")
    }  # fmt: skip
    assert all(r["phase"] == "finished" and not r["error"] for r in rows)
    finals = [float(r["final:joint2.q"]) for r in rows]
    assert all(abs(f - 0.4) < 0.01 for f in finals)
    assert len({r["max_abs:joint2.i_ref"] for r in rows}) == 4  # the gains change the currents


def test_outcome_measures_on_known_curves() -> None:
    t = np.linspace(0.0, 2.0, 201)
    x = 1.0 - np.exp(-5 * t) * np.cos(10 * t)  # a damped step to 1
    out = batch.RunOutcome("s", "r1", "finished", "", 2.0, 1.0, m.CommandPlan("joint_path", 1.0, [], [0.0]))
    out.columns, out.rows = ["time", "x"], np.column_stack([t, x])
    peak = x.max()
    assert batch.measure("overshoot:x", out) == np.float64((peak - x[-1]) / (x[-1] - x[0]) * 100)
    assert batch.measure("final:x", out) == x[-1] and batch.measure("max_abs:x", out) == peak
    settle = batch.measure("settling_time:x", out)
    late = t >= settle
    assert np.all(np.abs(x[late] - x[-1]) <= 0.02 * (x[-1] - x[0])) and not np.all(np.abs(x - x[-1]) <= 0.02)
    for bad in ("overshoot", "peak:x", "final:nope"):
        try:
            batch.measure(bad, out)
        except ValueError as exc:
            assert bad in str(exc)
        else:
            raise AssertionError(f"{bad} accepted")


def test_simecs_run_embedded_starts_and_stops_a_private_mesh(tmp_path: Path) -> None:
    command = write(
        tmp_path, "cmd.json", {"kind": "action", "primitive": "move_joints", "args": {"q": [0.1] * 7}}
    )
    out = simecs(
        "run",
        "--embedded",
        "--model",
        "spider",
        "--command",
        command,
        "--stop-time",
        "0.5",
        "--out",
        str(tmp_path / "e.mcap"),
    )
    assert out.returncode == 0, out.stderr
    recording = mcapread.load(tmp_path / "e.mcap")
    said = [entry.get("message") for entry in recording.logs]  # what the recorder wrote, if it went wrong
    assert recording.rows.shape[0] == 251, (recording.rows.shape, said, out.stderr)
    assert recording.context("").command.kind == "action"
