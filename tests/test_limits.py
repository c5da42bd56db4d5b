"""Bounded resources (mesh/protocol/limits.py, PROTOCOL.md §4.1): one user's sessions, runs, results,
parameter sets and recordings are bounded and refused `busy` naming the bound; idle sessions expire and
take their results along; uploads are read in full, bombs and trailing bytes included, before anything
is stored."""

from __future__ import annotations

import dataclasses
import io
import time
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import keys, limits
from simecs.nodes.recording import mcapread

from .conftest import Mesh, wait_until
from .test_service import prepare


def start_bounded_service(mesh: Mesh, *proxy_flags: str) -> None:
    data = mesh.folder / "data"
    mesh.start("proxy", "--data-dir", str(data), "--max-running", "2", *proxy_flags)
    mesh.start("simulator", "--results-dir", str(data / "results"))
    mesh.start("hotfeedback")


def test_a_user_holds_at_most_their_quota_and_idle_sessions_expire_with_their_results(mesh: Mesh) -> None:
    start_bounded_service(
        mesh,
        *("--max-sessions", "4", "--max-sessions-per-user", "2", "--max-runs-per-user", "1"),
        *("--session-idle-s", "3"),
    )
    client = mesh.client()
    a1, a2 = client.create_session("ann", "spider"), client.create_session("ann", "spider")
    with pytest.raises(RemoteError, match="sessions_per_user = 2") as err:
        client.create_session("ann", "spider")
    assert err.value.code == "busy"
    b1 = client.create_session("bob", "spider")  # another user's quota is their own
    client.create_session("carol", "spider")
    with pytest.raises(RemoteError, match="sessions = 4") as err:  # the server's own bound
        client.create_session("dave", "spider")
    assert err.value.code == "busy" and "close a session you no longer need" in err.value.error.message

    prepare(a1, stop_time=1.0, pacing="realtime")
    prepare(a2, stop_time=0.2)
    run = a1.run()
    with pytest.raises(RemoteError, match="runs_per_user = 1") as err:
        a2.run()
    assert err.value.code == "busy" and a2.snapshot().state.phase == "configured"
    assert a1.wait_for(["finished", "failed", "aborted"], 60, run).phase == "finished"

    a2.set_settings(stop_time=3000.0, output_interval=0.002)
    with pytest.raises(RemoteError, match="results_bytes_per_run") as err:
        a2.run()
    assert err.value.code == "bad_request" and err.value.field == "settings.output_interval"

    results = mesh.folder / "data" / "results" / "ann" / a1.id
    assert (results / f"{run}.npy").is_file()
    # a1 ran last but nobody touches it any more: it expires (3 s), and its results go with it.
    wait_until(lambda: a1.id not in {e.session for e in client.list_sessions("ann")}, 20, what="expiry")
    wait_until(lambda: not results.exists(), 10, what="results removed")
    with pytest.raises(RemoteError) as err:
        a1.snapshot()
    assert err.value.code == "not_found"
    assert b1.id not in {e.session for e in client.list_sessions("ann")}


def test_a_run_until_stopped_ends_at_its_bound(mesh: Mesh) -> None:
    """An operator's --open-run-s bounds a run until stopped: it ends there as finished, saying why."""
    start_bounded_service(mesh, "--open-run-s", "1")
    s = mesh.client().create_session("ann", "spider")  # no command: the arm holds its pose
    run = s.run(until_stopped=True)
    end = s.wait_for(["finished", "failed", "aborted"], 60, run)
    assert end.phase == "finished" and "a run until stopped lasts at most 1 s here" in end.reason, end
    assert "open_run_s" in end.reason
    info = next(r for r in s.runs() if r.run_id == run)
    assert info.until_stopped and info.stop_time == 1.0 and abs(info.sim_time - 1.0) < 1e-6


def mcap_bytes(payload: bytes, compression: CompressionType = CompressionType.ZSTD) -> bytes:
    buf = io.BytesIO()
    w = Writer(buf, compression=compression, chunk_size=len(payload) + 1024)
    w.start()
    sid = w.register_schema("x", "jsonschema", b"{}")
    cid = w.register_channel("/x", "json", sid)
    w.add_message(cid, 0, payload, 0)
    w.finish()
    return buf.getvalue()


def rss_mb(pid: int) -> int:
    return memory_mb(pid)["VmRSS"]


def memory_mb(pid: int) -> dict[str, int]:
    """The process's resident memory and its parts (anonymous, file-backed, shared), in MB."""
    fields = ("VmRSS", "RssAnon", "RssFile", "RssShmem")
    lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    return {k: int(line.split()[1]) // 1024 for line in lines for k in fields if line.startswith(k + ":")}


def test_a_refused_large_upload_leaves_the_recorders_memory_as_it_was(mesh: Mesh) -> None:
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    pid, client = mesh.procs["recorder"].pid, mesh.client()
    client.recordings("ann")  # every path of a request taken once
    before = rss_mb(pid)
    too_large = mcapread.MAGIC + bytes((256 << 20) + 1)
    for _ in range(2):
        with pytest.raises(RemoteError, match="upload_bytes") as err:
            client.request(keys.recording("ann", "big"), too_large, timeout=60)
        assert err.value.code == "bad_request"
    # given back once answered (the reply goes out first)
    seen: list[tuple[float, dict[str, int]]] = []
    t0 = time.monotonic()

    def given_back() -> bool:
        seen.append((round(time.monotonic() - t0, 2), memory_mb(pid)))
        return seen[-1][1]["VmRSS"] - before < 64

    try:
        wait_until(given_back, 10, 0.5, what="the recorder's memory given back")
    except TimeoutError:
        pytest.fail(f"the recorder's memory not back to {before} MB within 10 s: seen (s, MB) {seen[::2]}")


def test_uploads_are_read_in_full_within_bounds_and_count_against_the_quota(mesh: Mesh) -> None:
    rec_dir = mesh.folder / "rec"
    bomb = mcap_bytes(b"\0" * (80 << 20))  # 80 MiB of zeros: a few KB of zstd
    assert len(bomb) < 100_000
    with pytest.raises(mcapread.RecordingError, match="more than upload_chunk_bytes = 64 MiB") as bound:
        mcapread.validate(bomb)
    assert "damaged" not in str(bound.value) and ".py" not in str(bound.value)  # a bound, said as one
    small = mcap_bytes(b"{}")
    mcapread.validate(small)
    # records MCAP has no opcode for (zeros after the magic: 9-byte records of opcode 0, which the
    # library skips one by one for minutes) end the reading at the first
    with pytest.raises(mcapread.RecordingError, match="unknown opcode 0x00"):
        mcapread.validate(mcapread.MAGIC + bytes(64 << 20))
    with pytest.raises(mcapread.RecordingError, match="after the footer"):
        mcapread.validate(small + b"trailing garbage")

    mesh.start("recorder", "--dir", str(rec_dir), "--max-mb-per-user", "0.5")
    client = mesh.client()
    for data, what in ((bomb, "upload_chunk_bytes"), (small + b"junk", "after the footer")):
        with pytest.raises(RemoteError, match=what) as err:
            client.request(keys.recording("ann", "x"), data)
        assert err.value.code == "bad_request"
    assert not (rec_dir / "ann" / "x.mcap").exists()

    # A real recording would be refused as not a simecs recording: fill the quota with bytes on disk.
    (rec_dir / "ann").mkdir(parents=True)
    (rec_dir / "ann" / "big.mcap").write_bytes(b"\0" * 600_000)
    with pytest.raises(RemoteError, match="recordings_bytes_per_user") as err:
        client.request(keys.recording("ann", "y"), small)
    assert err.value.code == "busy"
    listing = client.request(keys.recordings("ann"))
    assert listing["used_bytes"] == 600_000 and listing["quota_bytes"] == 512 * 1024
    assert client.delete_recording("ann", "big").name == "big"  # an unreadable file deletes too
    assert not (rec_dir / "ann" / "big.mcap").exists()
    with pytest.raises(RemoteError) as err:
        client.delete_recording("ann", "big")
    assert err.value.code == "not_found"


def test_a_flood_of_small_records_is_refused_before_it_is_decoded(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each record read costs microseconds and a few hundred bytes, however small: 256 MiB of empty
    messages would hold the recorder for minutes and take gigabytes. The bound is lowered here to
    make the flood small; the count is the same code at any size."""
    bound = limits.LIMITS["upload_records"]
    monkeypatch.setitem(limits.LIMITS, "upload_records", dataclasses.replace(bound, value=1000))
    for compression in (CompressionType.ZSTD, CompressionType.NONE):
        buf = io.BytesIO()
        w = Writer(buf, compression=compression, chunk_size=1 << 20)
        w.start()
        cid = w.register_channel("/x", "json", w.register_schema("x", "jsonschema", b"{}"))
        for k in range(1000):
            w.add_message(cid, k, b"", k)
        w.finish()
        with pytest.raises(
            mcapread.RecordingError, match="more than upload_records = 1,000 MCAP records"
        ) as err:
            mcapread.validate(buf.getvalue())
        assert "damaged" not in str(err.value)
    assert mcapread.validate(mcap_bytes(b"{}")).messages == 1  # a few records: read


def test_a_closed_sessions_run_keeps_its_slot_until_its_worker_ends(mesh: Mesh) -> None:
    """Closing a session whose run goes on must not let admission hand a simulator more runs than it
    takes: the next user's run waits in the queue and then runs."""
    data = mesh.folder / "data"
    mesh.start("proxy", "--data-dir", str(data), "--max-running", "1")
    mesh.start("simulator", "--results-dir", str(data / "results"), "--max-runs", "1")
    client = mesh.client()
    a, b = client.create_session("ann", "spider"), client.create_session("bob", "spider")
    prepare(a, stop_time=5.0, pacing="realtime")
    prepare(b, stop_time=0.2)
    a.run()
    wait_until(lambda: a.snapshot().state.sim_time > 0.1, 30, what="ann's run under way")
    a.close()
    run = b.run()
    end = b.wait_for(["finished", "failed", "aborted"], 60, run)
    assert end.phase == "finished", end
