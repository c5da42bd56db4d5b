"""Replays: a recording played back as a run of a session, owned by the proxy like any run, frames and
results equal to the recorded ones, with pause, seek, abort and the recorded end. And a recording's
samples served as a run's results without replaying it (to compare runs with it)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from simecs.mesh.client import MeshClient, RemoteError, SessionClient
from simecs.mesh.protocol import frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.recording import mcapread

from .conftest import Mesh, mesh_env, start_service, wait_until
from .test_recorder_support import wait_file_closed

TARGET = [0.3, -0.2, 0.2, 0.1, -0.1, 0.1, 0.0]


class Collector:
    """What a client watching the session sees."""

    def __init__(self, s: SessionClient) -> None:
        self.full: list[frames.Frame] = []
        self.live: list[frames.Frame] = []
        self.states: list[m.SessionState] = []
        self.layouts: list[m.RunLayout] = []
        self.final = threading.Event()
        self.watch = s.watch(
            on_full=self._on_full,
            on_live=self.live.append,
            on_state=self.states.append,
            on_layout=self.layouts.append,
        )

    def _on_full(self, fr: frames.Frame) -> None:
        self.full.append(fr)
        if fr.final:
            self.final.set()

    def rows(self) -> np.ndarray:
        return np.concatenate([f.rows for f in self.full if f.rows.shape[0]])

    def close(self) -> None:
        self.watch.close()


def record_a_run(
    mesh: Mesh, client: MeshClient, stop_time: float = 1.0, abort_at: float = 0.0
) -> tuple[SessionClient, Path]:
    s = client.create_session("ann", "spider")
    s.set_settings(stop_time=stop_time, output_interval=0.005, pacing="realtime" if abort_at else "fast")
    s.set_joint_path([(TARGET, 100, 100)])
    run_id = s.run()
    if abort_at:
        wait_until(lambda: s.snapshot().state.sim_time > abort_at, timeout=30, what="run under way")
        s.abort()
    s.wait_for(list(("finished", "aborted", "failed")), 60, run_id)
    path = mesh.folder / "rec" / s.user / f"{keys.recording_name(s.id, run_id)}.mcap"
    wait_file_closed(path)
    return s, path


@pytest.fixture
def recording_service(mesh: Mesh) -> Mesh:
    start_service(mesh)
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    return mesh


def test_a_replay_is_a_run_of_the_session_paced_paused_and_sought(recording_service: Mesh) -> None:
    mesh = recording_service
    client = mesh.client()
    s, path = record_a_run(mesh, client)
    recorded = mcapread.load(path)
    col = Collector(s)
    try:
        run_id = s.replay(path.stem, speed=4.0, paused=True)
        assert s.wait_for(["paused"], 20, run_id).run_id == run_id == "r2"
        time.sleep(0.3)
        assert col.full == []  # paused from the start: nothing published
        s.resume()
        assert col.final.wait(20), "no final frame"
        assert np.array_equal(col.rows(), recorded.rows)  # every recorded sample, exactly
        wall = (col.full[-1].wall_ns - col.full[0].wall_ns) / 1e9
        assert wall >= 0.8 * recorded.duration / 4.0  # paced at 4x, not as fast as possible
        end = s.wait_for(["finished", "aborted", "failed"], 20, run_id)
        assert end.phase == "finished" and end.progress == pytest.approx(1.0)
        layout = col.layouts[-1]
        assert layout.source == "replay" and layout.context.recording == path.stem
        assert layout.context.command == recorded.layout.context.command
        # Results, runs list: like any run.
        cols, rows = s.results(run_id)
        assert cols == recorded.columns and np.array_equal(rows, recorded.rows)
        runs = {r.run_id: r for r in s.runs()}
        assert runs[run_id].recording == path.stem and runs[run_id].phase == "finished"

        # Seek while paused: it goes on from there once resumed.
        col.full.clear()
        col.final.clear()
        again = s.replay(path.stem, speed=2.0, paused=True)
        s.wait_for(["paused"], 20, again)
        s.seek(0.7)
        s.resume()
        assert col.final.wait(20)
        starts = [f.rows[0, 0] for f in col.full if f.rows.shape[0]]
        assert starts[0] == pytest.approx(0.7, abs=1e-6) and starts == sorted(starts)
        assert s.wait_for(["finished"], 20, again).phase == "finished"
        # Seek while it runs: it jumps there and plays on.
        col.full.clear()
        col.final.clear()
        third = s.replay(path.stem, speed=0.5)
        s.wait_for(["running"], 20, third)
        s.seek(0.9)
        assert col.final.wait(30)
        starts = [f.rows[0, 0] for f in col.full if f.rows.shape[0]]
        jump = starts.index(next(t for t in starts if abs(t - 0.9) < 1e-6))
        assert all(t < 0.9 for t in starts[:jump]) and starts[jump:] == sorted(starts[jump:])
        assert s.wait_for(["finished"], 20, third).phase == "finished"
        with pytest.raises(RemoteError) as err:
            s.seek(0.1)
        assert err.value.code == "conflict"
    finally:
        col.close()
    # The recorder did not record the replays as new runs.
    assert sorted(p.name for p in (mesh.folder / "rec").glob("*/*.mcap")) == [path.name]


def test_a_replay_ends_as_its_recording_did_and_can_be_aborted(recording_service: Mesh) -> None:
    mesh = recording_service
    client = mesh.client()
    s, path = record_a_run(mesh, client, stop_time=4.0, abort_at=0.3)
    assert mcapread.load(path).metadata["simecs.end"]["phase"] == "aborted"
    att, rows = client.recording_results(s.user, path.stem, t0=0.0, t1=0.1)
    assert att.run.phase == "aborted" and "aborted by the user" in att.run.reason and rows[-1, 0] <= 0.1
    run_id = s.replay(path.stem, speed=0)
    end = s.wait_for(["finished", "aborted", "failed"], 30, run_id)
    assert (
        end.phase == "aborted"
        and end.reason.startswith("as recorded")
        and "aborted by the user" in end.reason
    )
    live = Collector(s)
    try:
        second = s.replay(path.stem, speed=0.2)
        s.wait_for(["running"], 20, second)
        s.abort()
        end = s.wait_for(["aborted"], 20, second)
        assert end.reason == "aborted by the user" and end.sim_time < 0.3
        wait_until(lambda: live.live and live.live[-1].final, what="final live frame")
        assert live.live[-1].rows.shape[0] == 0  # an aborted run ends with no sample
    finally:
        live.close()


def test_a_recordings_samples_are_served_as_its_runs_results(recording_service: Mesh) -> None:
    mesh = recording_service
    client = mesh.client()
    s, path = record_a_run(mesh, client)
    run_id, name = s.snapshot().state.run_id, path.stem
    ran, ran_rows = s.results_of(run_id)
    att, rows = client.recording_results(s.user, name)
    # Every sample, bit for bit, with the run's columns, units and context, and what the file holds.
    assert np.array_equal(rows, ran_rows) and att.columns == ran.columns and att.units == ran.units
    assert att.context == ran.context and att.context is not None
    assert (att.run.run_id, att.run.phase, att.run.recording) == (run_id, "finished", name)
    assert att.run.samples == rows.shape[0] and att.run.sim_time == rows[-1, 0] == ran.run.sim_time
    # The same selector as a run's results, with the same answers.
    pick = [ran.columns[3], ran.columns[1]]
    sel_att, sel_rows = client.recording_results(s.user, name, pick, t0=0.2, t1=0.5, every=3)
    assert sel_att.columns == ["time", *pick]
    assert np.array_equal(sel_rows, s.results_of(run_id, pick, t0=0.2, t1=0.5, every=3)[1])
    # Refusals name what was wrong; the file is untouched by them.
    for key, code, field in (
        (keys.recording_results(s.user, name) + "?evry=2", "bad_request", "evry"),
        (keys.recording_results(s.user, name) + "?vars=nope", "bad_request", "vars"),
        (keys.recording_results(s.user, "nosuch"), "not_found", "name"),
        (keys.recording_results("bob", name), "not_found", "name"),
    ):
        with pytest.raises(RemoteError) as err:
            client.request_binary(key, m.ResultsAttachment)
        assert (err.value.code, err.value.error.field) == (code, field), key
    assert np.array_equal(client.recording_results(s.user, name)[1], ran_rows)


def test_replays_are_refused_before_they_start(recording_service: Mesh) -> None:
    client = recording_service.client()
    s, path = record_a_run(recording_service, client)
    puma = client.create_session("ann", "puma560")
    for session, name, code in ((puma, path.stem, "conflict"), (s, "no-such-recording", "not_found")):
        with pytest.raises(RemoteError) as err:
            session.replay(name)
        assert err.value.code == code and err.value.field == "recording"
    s.set_settings(stop_time=2.0, output_interval=0.01, pacing="realtime")
    run_id = s.run()
    s.wait_for(["running"], 20, run_id)
    with pytest.raises(RemoteError) as err:
        s.seek(0.5)
    assert err.value.code == "unsupported"
    with pytest.raises(RemoteError) as err:
        s.replay(path.stem)
    assert err.value.code == "conflict"
    s.abort()
    assert puma.snapshot().state.phase == "created"


def test_replay_cli_uploads_and_plays_as_fast_as_possible(recording_service: Mesh, tmp_path: Path) -> None:
    mesh = recording_service
    client = mesh.client()
    _s, path = record_a_run(mesh, client)
    copy = tmp_path / "kept run.mcap"
    copy.write_bytes(path.read_bytes())
    out = subprocess.run(
        [sys.executable, "-m", "simecs.nodes.replay", str(copy), "--speed", "0", "--connect", mesh.endpoint],
        capture_output=True,
        text=True,
        timeout=120,
        env=mesh_env(),
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "(recording kept_run)" in out.stdout and "run r1 finished" in out.stdout
    sid = out.stdout.split(" as session ", 1)[1].split()[0]
    replayed = client.session("replay", sid)
    _cols, rows = replayed.results("r1")
    assert np.array_equal(rows, mcapread.load(path).rows)
    assert client.recording_info("replay", "kept_run").bytes == path.stat().st_size
    # The user's own file in the library is not uploaded again.
    again = subprocess.run(
        [
            sys.executable,
            "-m",
            "simecs.nodes.replay",
            str(path),
            "--speed",
            "0",
            "--detach",
            "--user",
            "ann",
            "--connect",
            mesh.endpoint,
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env=mesh_env(),
    )
    assert again.returncode == 0 and f"(recording {path.stem})" in again.stdout, again.stdout + again.stderr


def test_replay_cli_refuses_bad_files(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"nope")
    proc = subprocess.run(
        [sys.executable, "-m", "simecs.nodes.replay", str(bad)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode != 0 and "bad.mcap: not an MCAP file" in proc.stderr
