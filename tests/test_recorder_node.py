"""The recorder node in its own process: runs published on the mesh become valid MCAP files; a SIGKILL
loses at most the last second; the files are listed, downloaded and uploaded over the mesh."""

from __future__ import annotations

import base64
import datetime
import json
import signal
import struct
import time

import numpy as np
import pytest
import zenoh
import zenoh.ext
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.recording import mcapfmt as fmt
from simecs.nodes.recording import mcapread
from simecs.testing.fuzz_recordings import McapTemplate

from .conftest import Mesh, start_service, wait_until
from .test_recorder_support import (
    USER,
    FakeProxy,
    FakeRun,
    arm_model,
    check_file,
    make_rows,
    wait_file_closed,
)

SID = "Rec0rderTestSess10n-Ab"


def test_published_run_is_recorded_listed_downloaded_uploaded(mesh: Mesh) -> None:
    rec_dir = mesh.folder / "rec"
    mesh.start("recorder", "--dir", str(rec_dir))
    client = mesh.new_client()
    proxy = FakeProxy(client.z, mesh.seal)
    run = FakeRun(client.z, mesh.seal, SID)
    try:
        run.announce()
        time.sleep(0.3)
        run.state("running")
        rows = make_rows(arm_model(), 300)
        for k in range(30):
            run.frame(rows[k * 10 : (k + 1) * 10], final=k == 29)
        run.state("finished", float(rows[-1, 0]))
        path = rec_dir / USER / f"{keys.recording_name(SID, 'r1')}.mcap"
        wait_file_closed(path)
    finally:
        run.close()
        proxy.close()
    v, rec = check_file(path)
    assert v.per_topic[fmt.TOPIC_VARS] == 300 and np.array_equal(rec.rows, rows)
    assert [g[0] for g in rec.frames()] == list(range(30))
    assert v.per_topic[fmt.TOPIC_SCENE] == 1 and "model.json" in v.attachments
    assert rec.metadata[fmt.META_SESSION]["user"] == "tester"
    assert '"joint_path"' in rec.metadata[fmt.META_SESSION]["command"]
    assert rec.metadata[fmt.META_END]["phase"] == "finished"
    assert rec.metadata[fmt.META_END]["dropped_frames"] == "0"
    texts = [log["message"] for log in rec.logs]
    assert any("recording started" in t for t in texts) and any("finished" in t for t in texts)

    name = path.stem
    listed = {r.name: r for r in client.recordings(USER)}
    assert listed[name].session == SID and listed[name].run_id == "r1" and not listed[name].recovered
    data, att = client.request_binary(keys.recording(USER, name), m.RecordingInfo)
    assert data == path.read_bytes() and att.name == name
    assert client.recording_info(USER, name) == att

    info = client.upload_recording(USER, "uploaded-copy", data)
    assert info.name == "uploaded-copy" and (rec_dir / USER / "uploaded-copy.mcap").read_bytes() == data
    with pytest.raises(RemoteError, match="already exists") as err:
        client.request(keys.recording(USER, "uploaded-copy"), data)
    assert err.value.code == "conflict"
    future = keys.recording_name(SID, "r2")  # the name the session's next run will be recorded under
    with pytest.raises(RemoteError, match="kept for the recordings of runs") as err:
        client.upload_recording(USER, future, data)
    assert err.value.code == "bad_request" and not (rec_dir / USER / f"{future}.mcap").exists()
    with pytest.raises(RemoteError, match="not an MCAP file") as err:
        client.request(keys.recording(USER, "junk"), b"PK\x03\x04 a zip file, not a recording")
    assert err.value.code == "bad_request"
    with pytest.raises(RemoteError, match="incomplete MCAP"):
        client.request(keys.recording(USER, "torn"), data[: len(data) // 2])
    # Well-formed files whose samples cannot be replayed (the fuzzer made these) are refused too.
    template = McapTemplate(data)
    unplayable = (
        (float("nan"), "time is not a finite number"),
        (1e9, r"outside \[0, 3600\] s"),
        (0.0, "sample 2: time 0 s goes back from"),  # not re-sorted: refused, naming the sample
    )
    for how, words in unplayable:

        def edit(i: int, payload: bytes, value: float = how) -> bytes:
            values = list(struct.unpack(f"<{(len(payload) - 4) // 8}d", payload[4:]))
            if i == 2:
                values[0] = value
            return payload[:4] + struct.pack(f"<{len(values)}d", *values)

        with pytest.raises(RemoteError, match=words) as err:
            client.upload_recording(USER, "lying", template.write(template.metadata, edits={"/vars": edit}))
        assert err.value.code == "bad_request" and not (rec_dir / USER / "lying.mcap").exists()
    with pytest.raises(RemoteError) as err:
        client.request_binary(keys.recording(USER, "nosuch"), m.RecordingInfo)
    assert err.value.code == "not_found"
    with pytest.raises(RemoteError) as err:
        client.recording_info(USER, "nosuch")
    assert err.value.code == "not_found" and err.value.field == "name"
    assert not (rec_dir / USER / "junk.mcap").exists() and not (rec_dir / USER / "torn.mcap").exists()


def test_sigkill_mid_run_keeps_everything_up_to_the_last_flush(mesh: Mesh) -> None:
    rec_dir = mesh.folder / "rec"
    mesh.start("recorder", "--dir", str(rec_dir))
    client = mesh.new_client()
    run = FakeRun(client.z, mesh.seal, SID)
    rows = make_rows(arm_model(), 1500)
    sent_at: list[tuple[float, int]] = []
    try:
        run.announce()
        time.sleep(0.3)
        for k in range(120):  # 10 rows per 20 ms frame: real-time pacing, 2.4 s
            run.frame(rows[k * 10 : (k + 1) * 10])
            sent_at.append((time.monotonic(), (k + 1) * 10))
            time.sleep(0.02)
        mesh.stop("recorder", signal.SIGKILL)
        killed = time.monotonic()
        path = rec_dir / USER / f"{keys.recording_name(SID, 'r1')}.mcap"
        assert path.exists() and not mcapread.has_footer(path)
        mesh.start("recorder", "--dir", str(rec_dir), name="recorder2")
        wait_until(lambda: mcapread.has_footer(path), 15, what="recovery at start")
        # The run goes on: the restarted recorder continues it in a second file.
        for k in range(120, 150):
            run.frame(rows[k * 10 : (k + 1) * 10], final=k == 149)
        cont = path.parent / f"{path.stem}.2.mcap"
        wait_file_closed(cont)
    finally:
        run.close()
    v, rec = check_file(path)
    assert rec.recovered and fmt.META_RECOVERY in v.metadata
    flushed_by = max(n for t, n in sent_at if t <= killed - 1.5)  # flush period 1 s, plus transport slack
    assert len(rec.rows) >= flushed_by, (len(rec.rows), flushed_by)
    assert np.array_equal(rec.rows, rows[: len(rec.rows)])
    assert any("recovered" in log["message"] for log in rec.logs)
    assert client.recordings(USER)[0].name in (path.stem, cont.stem)
    assert {r.name: r.recovered for r in client.recordings(USER)}[path.stem] is True
    _v2, rec2 = check_file(cont)
    assert rec2.metadata[fmt.META_RUN]["continues"] == path.stem
    assert np.array_equal(rec2.rows[-300:], rows[1200:1500])


@pytest.mark.timeout(120)
@pytest.mark.parametrize("model_id", ["spider", "ur5"])
def test_real_run_leaves_a_valid_recording(mesh: Mesh, model_id: str) -> None:
    """A run through the whole service: the recording equals the simulator's own results, and its
    /scene draws the arm (the UR5 with its URDF meshes embedded, as the proxy serves them)."""
    from simecs.models import get_model

    service = start_service(mesh)
    rec_dir = mesh.folder / "rec"
    mesh.start("recorder", "--dir", str(rec_dir))
    client = service.client
    s = client.create_session(USER, model_id)
    s.set_settings(stop_time=0.5, output_interval=0.002, pacing="fast")
    pkg = get_model(model_id)
    s.set_initial(list(pkg.home()))
    s.set_joint_path([(list(pkg.spec.standard_target), 100.0, 100.0)])
    run_id = s.run()
    s.wait_for(["finished", "failed", "aborted"], 90, run_id)
    path = rec_dir / USER / f"{keys.recording_name(s.id, run_id)}.mcap"
    wait_file_closed(path)
    v, rec = check_file(path)
    columns, results = s.results(run_id)
    assert rec.columns == columns
    assert np.array_equal(rec.rows, results)
    assert v.per_topic[fmt.TOPIC_VARS] == len(results) == 251
    # /tf and /joint_states at the documented default of 50 per simulated second: 0.5 s -> 26 samples
    assert v.per_topic[fmt.TOPIC_TF] == v.per_topic[fmt.TOPIC_JOINTS] == 26
    assert rec.metadata[fmt.META_END]["phase"] == "finished"
    assert rec.metadata[fmt.META_RUN]["model_id"] == model_id
    assert json.loads(rec.metadata[fmt.META_SESSION]["command"])["kind"] == "joint_path"
    desc = client.describe(model_id)
    assert len(rec.params()) == len(desc.parameters)
    sc = mcapread.scan(path)
    scene = next((msg for msg in sc.messages if sc.channels[msg.channel_id].topic == fmt.TOPIC_SCENE), None)
    assert scene is not None, mesh.log("recorder")
    entities = {e["id"]: e for e in json.loads(scene.data)["entities"]}
    assert {link.name for link in desc.links} <= set(entities)
    embedded = [base64.b64decode(p["data"]) for e in entities.values() for p in e["models"]]
    served = [client.model_mesh(model_id, name) for name in desc.mesh_names()]
    assert sorted(embedded) == sorted(served) and (model_id == "spider" or len(embedded) >= len(desc.links))
    name = path.stem
    assert name in {r.name for r in client.recordings(USER)}
    data = client.download_recording(USER, name)
    assert mcapread.validate(data).messages == v.messages


def test_aborted_run_and_dropped_frames_are_marked_in_the_file(mesh: Mesh) -> None:
    """A recorder that must drop says so: in the file's /log, in simecs.end, and in its node status."""
    rec_dir = mesh.folder / "rec"
    node_id = mesh.start("recorder", "--dir", str(rec_dir), "--queue-frames", "4")
    client = mesh.new_client()
    statuses: list[dict] = []
    status_sub = zenoh.ext.declare_advanced_subscriber(
        client.z,
        keys.node_status("recorder", node_id),
        lambda s: statuses.append(json.loads(s.payload.to_bytes())),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
    )
    run = FakeRun(client.z, mesh.seal, SID)
    rows = make_rows(arm_model(), 1000)
    try:
        run.announce()
        time.sleep(0.3)
        for k in range(100):  # a burst far beyond a 4-frame queue
            run.frame(rows[k * 10 : (k + 1) * 10])
        run.frame(np.empty((0, rows.shape[1])), final=True)  # how a worker ends an aborted run
        run.state("aborted", float(rows[-1, 0]), "aborted by the user")
        path = rec_dir / USER / f"{keys.recording_name(SID, 'r1')}.mcap"
        wait_file_closed(path)
        wait_until(lambda: statuses and statuses[-1]["detail"]["dropped_frames"] > 0, 10, what="status")
    finally:
        status_sub.undeclare()
        run.close()
    _v, rec = check_file(path)
    end = rec.metadata[fmt.META_END]
    assert end["phase"] == "aborted" and end["reason"] == "aborted by the user"
    dropped = int(end["dropped_frames"])
    kept_frames = len(list(rec.frames()))
    assert dropped > 0 and len(rec.rows) == 10 * kept_frames
    assert 100 <= dropped + kept_frames <= 101  # 100 data frames + the empty final one (kept or dropped)
    kept = {tuple(r) for r in rec.rows.tolist()}
    assert kept <= {tuple(r) for r in rows.tolist()}  # every stored sample is a real one, unchanged
    said = {
        lv: [log["message"] for log in rec.logs if log["level"] == lv]
        for lv in (fmt.LOG_WARNING, fmt.LOG_ERROR)
    }
    assert any("queue full" in t for t in said[fmt.LOG_WARNING])  # when and how many, as it happened
    # No simulator holds this run's results, so the gaps could not be filled: the summary says so.
    assert any("gaps not filled: no node holds the run's results" in t for t in said[fmt.LOG_ERROR])
    assert any(f"gaps LEFT (at least {dropped} frames)" in t for t in said[fmt.LOG_ERROR])
    assert int(end["gaps"]) > 0 and end["filled_rows"] == "0"


def test_frames_lost_on_the_way_show_as_a_gap(mesh: Mesh) -> None:
    rec_dir = mesh.folder / "rec"
    mesh.start("recorder", "--dir", str(rec_dir))
    client = mesh.new_client()
    run = FakeRun(client.z, mesh.seal, SID)
    rows = make_rows(arm_model(), 70)
    notices: list[m.Notice] = []
    sub = client.z.declare_subscriber(
        keys.notices(USER, SID), lambda s: notices.append(codec.loads(m.Notice, s.payload.to_bytes()))
    )
    try:
        run.announce()
        time.sleep(0.3)
        for k in range(7):
            if k in (3, 4):
                run.seq += 1  # lost between the simulator and the recorder
                continue
            run.frame(rows[k * 10 : (k + 1) * 10], final=k == 6)
        path = rec_dir / USER / f"{keys.recording_name(SID, 'r1')}.mcap"
        wait_file_closed(path)
    finally:
        run.close()
    _v, rec = check_file(path)
    assert rec.metadata[fmt.META_END]["dropped_frames"] == "2"
    assert np.array_equal(rec.rows, np.concatenate([rows[:30], rows[50:]]))
    assert any("MISSING frames 3..4" in log["message"] for log in rec.logs)
    sub.undeclare()
    assert [(n.run_id, n.source) for n in notices] == [("r1", "recorder")]  # once per run, for state
    assert "gaps" in notices[0].message


@pytest.mark.timeout(120)
def test_a_recording_says_when_it_was_made_and_how_long_its_run_was_jogged(mesh: Mesh) -> None:
    """A real-time run jogged through the whole service: its recording's listing says when it was made
    (UTC ISO 8601, within the test), and its results, and its replay, say the jogged time the
    session's list says."""
    from .test_jog import jog_for, running, sim_time_past

    service = start_service(mesh)
    rec_dir = mesh.folder / "rec"
    mesh.start("recorder", "--dir", str(rec_dir))
    began = datetime.datetime.now(datetime.UTC).replace(microsecond=0)
    s = service.client.create_session(USER, "spider")
    run_id = running(s, 1.5)
    sim_time_past(s, 0.2, "the run under way")
    jog_for(s, run_id, 0.3, qd=[0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert s.wait_for(["finished", "failed", "aborted"], 30, run_id).phase == "finished"
    info = next(r for r in s.runs() if r.run_id == run_id)
    assert 0.2 <= info.jogged_s <= 1.0, info
    name = keys.recording_name(s.id, run_id)

    def closed() -> tuple[m.ResultsAttachment, np.ndarray] | None:
        try:  # answered once the file is closed (a conflict while it is being written)
            return service.client.recording_results(USER, name, ["joint2.q_ref"])
        except RemoteError as exc:
            assert exc.code == "conflict", exc
            return None

    att, rows = wait_until(closed, timeout=30, what="the recording closed")
    assert att.run.recording == name and att.run.jogged_s == info.jogged_s, (att.run, info)
    _, results = s.results(run_id, ["joint2.q_ref"])
    assert np.array_equal(rows, results)
    listed = {r.name: r for r in service.client.recordings(USER)}[name]
    made = datetime.datetime.fromisoformat(listed.created)
    ended = datetime.datetime.now(datetime.UTC)
    assert listed.created.endswith("Z") and made.tzinfo is not None, listed
    assert began <= made <= ended, (began, listed.created, ended)
    assert service.client.recording_info(USER, name).created == listed.created
    path = rec_dir / USER / f"{name}.mcap"
    assert float(mcapread.load(path).metadata[fmt.META_END]["jogged_s"]) == info.jogged_s
    # Its replay plays the jogged rows: it says the recorded figure too.
    replay_run = s.replay(name, speed=0.0)
    assert s.wait_for(["finished", "failed", "aborted"], 30, replay_run).phase == "finished"
    replayed = next(r for r in s.runs() if r.run_id == replay_run)
    assert replayed.recording == name and replayed.jogged_s == info.jogged_s, replayed
    assert s.results_of(replay_run, ["joint2.q_ref"])[0].run.jogged_s == info.jogged_s
