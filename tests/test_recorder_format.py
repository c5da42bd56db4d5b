"""The MCAP format on its own: written, read back with CRC validation, schemas, torn files, export."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.writer import Writer
from simecs.mesh.protocol import columns, frames
from simecs.mesh.protocol import messages as m
from simecs.nodes.recording import mcapfmt as fmt
from simecs.nodes.recording import mcapread, mcaprepair, mcapscene
from simecs.nodes.recording.mcapwriter import RunWriter
from simecs.nodes.tools import export

from .test_recorder_support import arm_model, check_file, layout_for, make_rows

SID = "AbCdEfGhIjKlMnOpQrStUv"


def write_run(
    path: Path, n_frames: int = 40, rows_per_frame: int = 10, chunk_size: int = fmt.CHUNK_SIZE
) -> list[frames.Frame]:
    lay = layout_for(SID)
    model = arm_model()
    w = RunWriter(path, lay, chunk_size=chunk_size)
    w.write_log(fmt.LOG_INFO, "started", 0.0)
    w.write_scene(model, model.default_values())
    sent = []
    rows = make_rows(model, n_frames * rows_per_frame)
    for s in range(n_frames):
        fr = frames.Frame(1, s, time.time_ns(), rows[s * rows_per_frame : (s + 1) * rows_per_frame])
        fr.flags = frames.FLAG_FINAL if s == n_frames - 1 else 0
        w.write_frame(fr)
        sent.append(fr)
    w.close({"phase": "finished"})
    return sent


def test_written_run_reads_back_exactly_with_valid_schemas(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    sent = write_run(path)
    v, rec = check_file(path)
    n_rows = sum(f.rows.shape[0] for f in sent)
    assert v.per_topic[fmt.TOPIC_VARS] == n_rows
    assert v.per_topic[fmt.TOPIC_SCENE] == 1
    # /tf and /joint_states at 50 samples per simulated second: 0.8 s of data -> 40 (+ the final sample)
    assert 39 <= v.per_topic[fmt.TOPIC_TF] <= 42
    assert v.per_topic[fmt.TOPIC_JOINTS] == v.per_topic[fmt.TOPIC_TF]
    assert np.array_equal(rec.rows, np.concatenate([f.rows for f in sent]))  # bit-exact
    grouped = list(rec.frames())
    assert [g[0] for g in grouped] == [f.seq for f in sent]
    assert [g[2] - g[1] for g in grouped] == [f.rows.shape[0] for f in sent]
    assert rec.complete and not rec.recovered
    assert rec.layout.columns == layout_for(SID).columns
    assert rec.params() == arm_model().default_values()
    assert set(v.metadata) >= {fmt.META_RUN, fmt.META_PARAMS, fmt.META_SESSION, fmt.META_END}
    assert rec.context() == layout_for(SID).context  # the run's context travels in the file
    assert json.loads(v.metadata[fmt.META_SESSION]["command"])["kind"] == "joint_path"
    info = mcapread.info(path)
    assert (info.session, info.run_id, info.model_id, info.recovered) == (SID, "r1", "testarm", False)


def test_scene_uses_link_frames_and_resized_lengths() -> None:
    model = arm_model()
    values = dict(model.default_values(), **{"link1.length": 0.7})
    scene = mcapscene.scene_update(model, values, 1_000_000_123)
    jsonschema.Draft202012Validator(json.loads(fmt.foxglove_schema("foxglove.SceneUpdate"))).validate(scene)
    ents = {e["id"]: e for e in scene["entities"]}
    assert set(ents) == {"link1", "link2", "environment"}
    assert ents["link1"]["frame_locked"] and ents["link1"]["frame_id"] == "link1"
    pipe = ents["link1"]["cylinders"][1]
    assert pipe["size"]["z"] == pytest.approx(0.7) and pipe["pose"]["position"]["x"] == pytest.approx(0.35)
    assert len(ents["link2"]["spheres"]) == 1 and len(ents["link2"]["cubes"]) == 1
    assert ents["environment"]["frame_id"] == fmt.WORLD_FRAME


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"link2.length": 0.9, "link4.length": 0.2},
        {"link3.radius": 0.09, "link1.radius": 0.02},
        {"payload.size": 0.5, "link7.length": 0.4},
    ],
    ids=["defaults", "lengths", "radii", "payload"],
)
def test_foxglove_scene_draws_the_shape_geometry_the_viewer_draws(changes: dict[str, float]) -> None:
    """One rule (mesh.rules.shapes) for both: every Foxglove primitive sits and measures as its solid."""
    from simecs import models
    from simecs.mesh.rules import shapes

    model = models.get_model("spider").describe()
    values = {**model.default_values(), **changes}
    scene = mcapscene.scene_update(model, values, 1)
    prims: dict[str, list[dict]] = {}
    for entity in scene["entities"]:
        for kind in ("cylinders", "cubes", "spheres"):
            prims.setdefault(entity["id"], []).extend((kind, p) for p in entity[kind])
    kind_of = {"cylinder": "cylinders", "pipe": "cylinders", "box": "cubes", "sphere": "spheres"}
    order = ["cylinders", "cubes", "spheres"]  # how an entity lists its primitives
    drawn: dict[str, list] = {}
    for solid in shapes.solids(model, values):
        if solid.geometry.visible:
            drawn.setdefault("environment" if solid.frame == shapes.WORLD else solid.frame, []).append(solid)
    for solids in drawn.values():
        solids.sort(key=lambda sol: order.index(kind_of[sol.geometry.kind]))
    assert set(drawn) == set(prims)
    for frame, solids in drawn.items():
        assert len(solids) == len(prims[frame])
        for solid, (kind, prim) in zip(solids, prims[frame], strict=True):
            g = solid.geometry
            assert kind == kind_of[g.kind]
            pos, rot = prim["pose"]["position"], prim["pose"]["orientation"]
            assert [pos["x"], pos["y"], pos["z"]] == pytest.approx(list(g.position))
            assert [rot["w"], rot["x"], rot["y"], rot["z"]] == pytest.approx(list(g.wxyz))
            size = [prim["size"]["x"], prim["size"]["y"], prim["size"]["z"]]
            if kind == "cylinders":
                assert size == pytest.approx([2 * g.radius, 2 * g.radius, g.length])
            elif kind == "cubes":
                assert size == pytest.approx(list(g.dimensions))
            else:
                assert size == pytest.approx([2 * g.radius] * 3)
    # and the parameters really reshape: the payload cube, a link tube, a housing
    payload = [p["size"]["x"] for k, p in prims["link7"] if k == "cubes"]
    assert payload == pytest.approx([values["payload.size"]])
    tubes = [p for k, p in prims["link2"] if k == "cylinders"]
    assert any(p["size"]["z"] == pytest.approx(values["link2.length"]) for p in tubes)
    if "link3.radius" in changes:
        scale = changes["link3.radius"] / model.default_values()["link3.radius"]
        housing = [p for k, p in prims["link3"] if k == "cylinders"][0]
        default = mcapscene.scene_update(model, model.default_values(), 1)
        base = next(e for e in default["entities"] if e["id"] == "link3")["cylinders"][0]
        assert housing["size"]["x"] == pytest.approx(base["size"]["x"] * scale)


def _grasp_rows() -> tuple[list[str], np.ndarray]:
    """Ten rows of a box carried from x = 0.5 to x = 0.6: taken at row 2, let go at row 6."""
    names = ["t", columns.GRASP_OBJECT, columns.GRASP_HELD]
    names += [columns.pose_column(columns.GRASPED_FRAME, f) for f in columns.POSE_FIELDS]
    rows = np.zeros((10, len(names)))
    rows[:, 0] = np.arange(10) * 0.01
    rows[2:, 1] = 1.0
    rows[2:6, 2] = 1.0
    rows[:, 3] = np.clip(0.5 + (np.arange(10) - 2) * 0.025, 0.5, 0.6)  # the grasped frame's x
    rows[:, 5] = 0.2
    rows[:, 6] = 1.0  # qw
    return names, rows


def _box_x(update: dict) -> float | None:
    """Where the world draws the box in a /scene update (None: it is not in the world, it is held)."""
    world = [e for e in update["entities"] if e["id"] == mcapscene.OBSTACLES_ENTITY][0]
    return world["cubes"][0]["pose"]["position"]["x"] if world["cubes"] else None


@pytest.mark.parametrize("gap", [(0, 4), (3, 8), (5, 10)])
def test_a_gap_filled_late_draws_the_grasp_as_it_was_at_its_time(gap: tuple[int, int]) -> None:
    # The recorder writes the rows of a lost stretch after the run: their /scene updates must start
    # from what the tool held then, not from the run's end, and leave the later updates the last word.
    names, rows = _grasp_rows()
    box = m.Obstacle("box1", "box", [0.5, 0.0, 0.2], size=[0.05] * 3, mass=2.0)
    ns = [int(t * 1e9) + 1_000 for t in rows[:, 0]]
    a, b = gap
    whole = mcapscene.WorldScene(names, [box], "arm").grasp_updates(rows, ns)
    scene = mcapscene.WorldScene(names, [box], "arm")
    late = scene.grasp_updates(rows[:a], ns[:a]) + scene.grasp_updates(rows[b:], ns[b:])
    late += scene.grasp_updates(rows[a:b], ns[a:b], backfill=True)
    timeline = sorted(late, key=lambda u: u[0])
    # Every update in time order says what the rows said at its time; the last one puts the box down.
    held = {t: bool(rows[k, 2]) for k, t in enumerate(ns)}
    for t, update in timeline:
        carried = any(e["id"] == mcapscene.HELD_ENTITY for e in update["entities"])
        assert carried == held[t], (t, update)
        x = _box_x(update)
        assert carried or x == pytest.approx(rows[ns.index(t), 3] if rows[ns.index(t), 1] else 0.5)
    assert [t for t, _ in whole] == [ns[2], ns[6]]
    assert timeline[-1][1]["deletions"] and _box_x(timeline[-1][1]) == pytest.approx(0.6)


def test_contact_arrows_of_a_filled_gap_end_with_it() -> None:
    # A touch inside a lost stretch is drawn when the stretch is filled, and cleared where it ends:
    # the live updates after the gap had no arrows, so nothing else would take it down.
    names = ["t"] + [columns.contact_column(1, f) for f in (*columns.CONTACT_VECTOR, *columns.CONTACT_POINT)]
    rows = np.zeros((8, len(names)))
    rows[:, 0] = np.arange(8) * 0.02
    rows[3:5, 3] = 20.0  # 20 N up at rows 3 and 4
    ns = [int(t * 1e9) for t in rows[:, 0]]
    scene = mcapscene.WorldScene(names, [], "arm")
    live = scene.contacts_updates(rows[:2], ns[:2]) + scene.contacts_updates(rows[6:], ns[6:])
    assert live == []  # nothing touched on either side of the gap
    filled = scene.contacts_updates(rows[2:6], ns[2:6], backfill=True)
    arrows = [(t, len(u["entities"][0]["arrows"])) for t, u in filled]
    assert arrows == [(ns[3], 1), (ns[4], 1), (ns[5], 0)]
    assert scene.contacts_updates(rows[6:7], ns[6:7]) == []  # the live side's state is its own


def test_vars_schema_is_ros2_and_fields_map_to_columns() -> None:
    lay = layout_for(SID)
    codec_ = fmt.build_vars_codec(lay.columns + ["odd name!", "a", "a.b"], lay.units + ["", "", ""])
    assert sorted(codec_.order.tolist()) == list(range(len(lay.columns) + 3))
    paths = fmt.ros2_field_paths(codec_)
    assert paths["joint1.q"] == "/vars.joint1.q" and paths["pose.link2.qw"] == "/vars.pose.link2.qw"
    for line in codec_.schema.splitlines():
        if line and not line.startswith(("=", "MSG: ")):
            typ, name = line.split(" ")
            assert typ == "float64" or typ.startswith("simecs/"), line
            assert name.replace("_", "").isalnum() and name[0].isalpha() and name == name.lower(), line
    row = np.arange(len(codec_.columns), dtype=float)[None, :]
    out = np.empty(len(codec_.columns))
    codec_.decode_into(codec_.encode(row)[0], out)
    assert np.array_equal(out, row[0])


def test_torn_file_is_recovered_up_to_the_last_flush(tmp_path: Path) -> None:
    """A writer process SIGKILLed right after a flush: every flushed row comes back, marked recovered."""
    path = tmp_path / "torn.mcap"
    script = f"""
import os, signal, time, sys
sys.path.insert(0, {str(Path(__file__).parent.parent)!r})
from tests.test_recorder_support import layout_for, make_rows, arm_model
from simecs.mesh.protocol import frames
from simecs.nodes.recording import mcapfmt as fmt
from simecs.nodes.recording.mcapwriter import RunWriter
w = RunWriter({str(path)!r}, layout_for({SID!r}))
rows = make_rows(arm_model(), 400)
for s in range(40):
    w.write_frame(frames.Frame(1, s, time.time_ns(), rows[s * 10:(s + 1) * 10]))
    if s == 24:
        w.flush()
os.kill(os.getpid(), signal.SIGKILL)
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    assert proc.returncode == -9, proc.stderr.decode()
    assert not mcapread.has_footer(path)
    torn = tmp_path / "copy.mcap"
    shutil.copy(path, torn)
    result = mcaprepair.recover(path)
    assert result is not None and result.original_bytes == torn.stat().st_size
    v, rec = check_file(path)
    expected = make_rows(arm_model(), 400)
    assert rec.recovered and fmt.META_RECOVERY in v.metadata
    assert len(rec.rows) >= 250 and np.array_equal(rec.rows, expected[: len(rec.rows)])
    assert "recovered" in rec.logs[-1]["message"]
    assert mcaprepair.recover(path) is None  # already complete: nothing to do


@pytest.mark.parametrize("cut", [0.35, 0.6, 0.97])
def test_truncated_anywhere_keeps_every_complete_chunk(tmp_path: Path, cut: float) -> None:
    full = tmp_path / "full.mcap"
    sent = write_run(full, n_frames=200, chunk_size=32 * 1024)
    data = full.read_bytes()
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: int(len(data) * cut)])
    assert mcaprepair.recover(path) is not None
    _v, rec = check_file(path)
    allrows = np.concatenate([f.rows for f in sent])
    assert np.array_equal(rec.rows, allrows[: len(rec.rows)])
    assert len(rec.rows) > 0


def test_bad_files_are_refused_with_their_name(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"hello, not a recording" * 10)
    with pytest.raises(mcapread.RecordingError, match=r"junk\.mcap: not an MCAP file"):
        mcapread.load(junk)
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as fh:
        w = Writer(fh)
        w.start()
        w.finish()
    with pytest.raises(mcapread.RecordingError, match=r"foreign\.mcap: not a simecs recording"):
        mcapread.load(foreign)
    good = tmp_path / "good.mcap"
    write_run(good, n_frames=5)
    data = bytearray(good.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped bit inside a chunk
    with pytest.raises(mcapread.RecordingError, match="uploaded file"):
        mcapread.validate(bytes(data))


def test_export_csv_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    sent = write_run(path, n_frames=12)
    out = tmp_path / "run.csv"
    assert export.main([str(path), "--csv", "-o", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert header == layout_for(SID).columns
    assert np.array_equal(table, np.concatenate([f.rows for f in sent]))
    buf = io.StringIO()
    n = export.write_csv(mcapread.load(path), buf, ["joint2.*"], units=True, t0=0.1)
    lines = buf.getvalue().splitlines()
    assert lines[0] == "time,joint2.q,joint2.qd,joint2.tau_gear,joint2.i_a" and lines[1].startswith("s,rad,")
    assert n == len(lines) - 2 and float(lines[2].split(",")[0]) >= 0.1
    assert export.main([str(path), "--csv", "--vars", "nosuch.*", "-o", os.devnull]) == 2


def test_the_mcap_records_read_back_with_the_mcap_packages_reader() -> None:
    """The writer of mcaprecords.py against the mcap package's own reader (an independent reading of
    the format), every CRC checked: several chunks of single and bulk messages, metadata and an
    attachment between them, the statistics, every index and the summary; and the data section's CRC,
    which that reader does not check, recomputed here."""
    import io
    import struct
    import zlib

    from mcap.reader import make_reader
    from mcap.records import DataEnd
    from mcap.stream_reader import StreamReader
    from simecs.nodes.recording.mcaprecords import zstd_file

    out = io.BytesIO()
    w = zstd_file(out, 4096)
    w.start("", "simecs test")
    text = w.register_channel("/text", "json", w.register_schema("s", "jsonschema", b"{}"), {"k": "v"})
    raw = w.register_channel("/raw", "cdr", 0)
    record = np.dtype([("head", "V31"), ("value", "<f8")])
    sent: list[tuple[int, int, bytes]] = []
    for k in range(300):
        data = json.dumps({"k": k}).encode()
        w.add_message(text, 1000 + 10 * k, data, 7, k)
        sent.append((text, 1000 + 10 * k, data))
        if k % 50 == 0:
            times = np.arange(5, dtype=np.int64) + 1000 + 10 * k
            rows = np.zeros(5, dtype=record)
            for i, t in enumerate(times):
                payload = struct.pack("<d", float(k + i))
                head = struct.pack("<BQHIQQ", 0x05, 22 + 8, raw, 0, int(t), 9)
                rows[i] = (head, float(k + i))
                sent.append((raw, int(t), payload))
            w.add_records(raw, times, rows)
            w.add_metadata(f"m{k}", {"k": str(k)})
        if k == 120:
            w.flush()
            w.add_attachment(5, 6, "note.txt", "text/plain", b"hello")
    w.finish()
    data = out.getvalue()
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    stats = summary.statistics
    assert (stats.message_count, stats.schema_count, stats.channel_count) == (len(sent), 1, 2)
    assert (stats.attachment_count, stats.metadata_count) == (1, 6) and stats.chunk_count > 3
    assert dict(stats.channel_message_counts) == {text: 300, raw: 30}
    assert (stats.message_start_time, stats.message_end_time) == (1000, 1000 + 10 * 299)
    assert summary.channels[text].metadata == {"k": "v"} and summary.channels[raw].schema_id == 0
    got = [(ch.id, msg.log_time, msg.data) for _s, ch, msg in reader.iter_messages(log_time_order=True)]
    assert got == sorted(sent, key=lambda m: m[1])
    late = [msg.log_time for _s, _c, msg in reader.iter_messages(starting_at=3000, topics=["/text"])]
    assert late == [1000 + 10 * k for k in range(200, 300)]  # through the chunk and message indexes
    assert [a.data for a in reader.iter_attachments()] == [b"hello"]
    assert [md.name for md in reader.iter_metadata()] == [f"m{k}" for k in range(0, 300, 50)]
    records = list(StreamReader(io.BytesIO(data), validate_crcs=True).records)
    end = next(r for r in records if isinstance(r, DataEnd))
    data_end_at = data.index(struct.pack("<BQI", 0x0F, 4, end.data_section_crc))
    assert end.data_section_crc == zlib.crc32(data[:data_end_at])
