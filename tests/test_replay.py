"""Replays: a recording republished onto the mesh as a session, frames equal to the recorded ones."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from simecs.mesh import codec, frames, keys
from simecs.mesh import messages as m
from simecs.mesh.client import MeshClient, RemoteError
from simecs.nodes import mcapfmt as fmt
from simecs.nodes import mcapread

from .conftest import Mesh, wait_until
from .test_recorder_support import arm_model, layout_for, make_rows

SID = "Rep1ayS0urceSessi0n-Ab"


def write_recording(folder: Path, n_frames: int = 50) -> tuple[Path, list[frames.Frame]]:
    folder.mkdir(parents=True, exist_ok=True)
    lay = layout_for(SID, stop_time=1.0)
    path = folder / f"{keys.recording_name(SID, 'r1')}.mcap"
    w = fmt.RunWriter(path, lay)
    w.write_metadata(fmt.META_PARAMS, {k: repr(v) for k, v in arm_model().default_values().items()})
    rows = make_rows(arm_model(), n_frames * 10)
    sent = []
    for k in range(n_frames):
        n = 10 if k % 7 else 7  # uneven frames: their boundaries must survive the replay
        a = sum(f.rows.shape[0] for f in sent)
        flags = frames.FLAG_FINAL if k == n_frames - 1 else 0
        fr = frames.Frame(1, k, time.time_ns(), rows[a : a + n], flags)
        w.write_frame(fr)
        sent.append(fr)
    w.close({"phase": "finished"})
    return path, sent


class Collector:
    def __init__(self, client: MeshClient, session: str) -> None:
        self.frames: list[frames.Frame] = []
        self.states: list[m.SessionState] = []
        self.final = threading.Event()
        self.watch = client.session(session).watch(on_full=self._on_full, on_state=self.states.append)

    def _on_full(self, fr: frames.Frame) -> None:
        self.frames.append(fr)
        if fr.final:
            self.final.set()

    def phase(self) -> str:
        return self.states[-1].phase if self.states else ""


def test_replay_republishes_the_recorded_frames_with_pause_and_seek(mesh: Mesh) -> None:
    rec_dir = mesh.folder / "rec"
    path, sent = write_recording(rec_dir)
    mesh.start("recorder", "--dir", str(rec_dir))
    client = mesh.new_client()
    reply = client.request(keys.recording_replay(path.stem), m.ReplayRequest(speed=4.0, paused=True))
    sid = reply["session"]
    assert keys.is_session_id(sid) and sid != SID
    col = Collector(client, sid)
    try:
        wait_until(lambda: col.phase() == "paused", 10, what="paused replay state")
        snap = client.session(sid).snapshot()  # answered by the replay node itself
        assert snap.model_id == "testarm" and snap.state.phase == "paused"
        assert snap.runs[0].samples == sum(f.rows.shape[0] for f in sent)
        time.sleep(0.3)
        assert col.frames == []  # paused: nothing published
        client.session(sid).resume()
        assert col.final.wait(20), "no final frame"
        got = list(col.frames)
        assert [f.rows.shape[0] for f in got] == [f.rows.shape[0] for f in sent]
        assert np.array_equal(np.concatenate([f.rows for f in got]), np.concatenate([f.rows for f in sent]))
        assert all(f.run_index == 1 for f in got) and got[-1].final and not any(f.final for f in got[:-1])
        wall = (got[-1].wall_ns - got[0].wall_ns) / 1e9
        recorded = sent[-1].rows[-1, 0] - sent[0].rows[-1, 0]
        assert wall >= 0.8 * recorded / 4.0, (wall, recorded)  # paced at 4x, not as fast as possible
        wait_until(lambda: col.phase() == "finished", 10, what="finished")
        assert col.states[-1].progress > 0.6

        # Seek back (the replay lingers after its end): it plays again from 0.5 s.
        col.frames.clear()
        col.final.clear()
        control = client.z.declare_publisher(keys.control(sid))
        control.put(codec.dumps(m.RunControl(op="seek", run_id="r1", time=0.5)))
        assert col.final.wait(20)
        first = col.frames[0].rows[:, 0]
        assert first[0] <= 0.5 + 1e-9 <= first[-1] + 0.02
        assert col.frames[-1].rows[-1, 0] == sent[-1].rows[-1, 0]
        control.undeclare()

        # Only replay commands are accepted on its cmd key.
        try:
            client.session(sid).set_params({"link1.length": 0.5})
            raise AssertionError("set_params accepted by a replay")
        except RemoteError as exc:
            assert exc.code in ("unsupported", "not_found")
        client.session(sid).abort()
        wait_until(lambda: col.phase() == "aborted", 10, what="aborted")
        wait_until(lambda: ("replay", f"replay-{sid}") not in client.live_nodes(), 10, what="replay exit")
    finally:
        col.watch.close()
    # The recorder did not record the replay as a new run.
    assert sorted(p.name for p in rec_dir.glob("*.mcap")) == [path.name]


def test_replay_cli_as_fast_as_possible(mesh: Mesh, tmp_path: Path) -> None:
    path, sent = write_recording(tmp_path / "rec", n_frames=100)
    mesh.start("hotfeedback")
    other_dir = tmp_path / "other"
    mesh.start("recorder", "--dir", str(other_dir))  # it did not start this replay
    client = mesh.new_client()
    sid = keys.new_session_id()
    live: list[frames.Frame] = []
    layouts: list[m.RunLayout] = []
    col = Collector(client, sid)
    watch_live = client.session(sid).watch(on_live=live.append, on_layout=layouts.append)
    try:
        mesh.start("replay", str(path), "--speed", "0", f"--session={sid}", "--linger", "0.5")
        assert col.final.wait(20)
        rows = np.concatenate([f.rows for f in col.frames])
        assert np.array_equal(rows, mcapread.load(path).rows)
        wait_until(lambda: live and live[-1].final, 10, what="final live frame from hot-feedback")
        assert live[-1].rows[-1, 0] == sent[-1].rows[-1, 0]
        wait_until(lambda: mesh.procs["replay"].poll() is not None, 15, what="replay exit after linger")
        assert mesh.procs["replay"].returncode == 0
        assert layouts and all(lay.source == "replay" for lay in layouts)
    finally:
        col.watch.close()
        watch_live.close()
    # The layout says it is a replay: the recorder leaves it alone.
    assert list(other_dir.glob("*.mcap")) == []
    assert "is a replay: not recorded" in mesh.log("recorder")


def test_replay_cli_refuses_bad_files(tmp_path: Path) -> None:
    import subprocess
    import sys

    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"nope")
    proc = subprocess.run(
        [sys.executable, "-m", "simecs.nodes.replay", str(bad)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode != 0 and "bad.mcap: not an MCAP file" in proc.stderr
