"""The recorder's bookkeeping of the runs it writes (nodes/recording/recording_files.py), driven by injected
messages in the order a mesh may deliver them, without a mesh: what a recording says of its run's end
when the stream lost it. (The recorder node on a real mesh is tested in test_recorder_node and
test_resilience.)"""

from __future__ import annotations

import logging
import math
import time
from datetime import datetime
from pathlib import Path

import msgspec
import numpy as np
from simecs.mesh.protocol import codec, frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.recording import mcapread
from simecs.nodes.recording.recording_files import ENDED_GRACE_S, MODEL_WAIT_S, Fill, Gap, Owner, RunFiles
from simecs.nodes.recording.recordings_library import RecordingsLibrary

from .test_recorder_support import USER, arm_model, layout_for, make_rows

SID = "AbCdEfGhIjKlMnOpQrStUv"


class ResultsOnRequest:
    """The mesh as the run files see it: the fills they ask for are kept for the test to answer."""

    def __init__(self) -> None:
        self.fills: list[tuple[Owner, str, list[Gap]]] = []
        self.asked: list[Owner] = []  # the sessions whose state was asked

    def lookup(self, owner: Owner, run_id: str, model_id: str) -> None:
        pass

    def fill(self, owner: Owner, run_id: str, gaps: list[Gap], columns: list[str]) -> None:
        self.fills.append((owner, run_id, list(gaps)))

    def ask_state(self, owner: Owner) -> None:
        self.asked.append(owner)

    def notify(self, user: str, notice: m.Notice) -> None:
        pass

    def worker_alive(self, user: str, session: str, run_id: str) -> bool:
        return True

    def take_drops(self) -> dict[Owner, list[int]]:
        return {}

    def status_changed(self) -> None:
        pass


def run_files(folder: Path) -> tuple[RecordingsLibrary, ResultsOnRequest, RunFiles]:
    """The run files of a recorder writing into `folder`, on a mesh the test answers for."""
    library, mesh = RecordingsLibrary(folder), ResultsOnRequest()
    return (
        library,
        mesh,
        RunFiles(library, "recorder-t", logging.getLogger("test"), mesh, idle_timeout_s=30.0),
    )


def send_frame(files: RunFiles, run_index: int, rows: np.ndarray, flags: int = 0) -> None:
    """One frame (number 0) of run `run_index`, as the hub hands it over."""
    frame = frames.Frame(run_index, 0, time.time_ns(), rows, flags)
    files.on_full(keys.vars_full(USER, SID), frames.encode(frame))


def test_a_run_whose_end_was_lost_ends_as_its_results_say(tmp_path: Path) -> None:
    # Back-to-back runs: the next run's layout can reach the recorder before the last frame and the
    # end state of the one before. That recording is closed then, and its results tell how it ended:
    # it is not marked incomplete when it holds every sample.
    library, mesh, files = run_files(tmp_path)
    first = layout_for(SID)
    rows = make_rows(arm_model(), 20)
    files.on_layout(keys.layout(USER, SID), codec.dumps(first))
    send_frame(files, 1, rows)
    second = msgspec.structs.replace(first, run_id="r2", run_index=2)
    files.on_layout(keys.layout(USER, SID), codec.dumps(second))
    ((owner, run_id, gaps),) = mesh.fills
    assert run_id == "r1" and len(gaps) == 1 and math.isinf(gaps[0].before)  # after its last sample
    ended = m.RunInfo("r1", "finished", 1.0, float(rows[-1, 0]), rows.shape[0])
    files.on_fill("", Fill(owner, "r1", [(gaps[0], rows[:0])], "", ended))
    rec = mcapread.load(library.path_of(USER, keys.recording_name(SID, "r1")))
    end = rec.metadata["simecs.end"]
    assert (end["phase"], end["gaps"]) == ("finished", "0") and np.array_equal(rec.rows, rows)
    # Without the results' word (no node holds them), the recording says it is incomplete.
    third = msgspec.structs.replace(first, run_id="r3", run_index=3)
    send_frame(files, 2, rows)
    files.on_layout(keys.layout(USER, SID), codec.dumps(third))
    owner, run_id, gaps = mesh.fills[-1]
    files.on_fill("", Fill(owner, run_id, [], "no node holds the run's results"))
    end = mcapread.load(library.path_of(USER, keys.recording_name(SID, "r2"))).metadata["simecs.end"]
    assert (end["phase"], end["gaps"]) == ("incomplete", "1")


def test_a_recording_keeps_how_long_its_run_was_jogged_and_when_it_was_made(tmp_path: Path) -> None:
    """The run's newest report (RunStatus.jogged_s) goes into simecs.end, and the recording's results
    say it; reports of another run or attempt change nothing; a run whose last report was lost takes
    its stored results' word. The listing says when each file was begun."""
    library, mesh, files = run_files(tmp_path)
    status_key, state_key = keys.run_status(USER, SID), keys.state(USER, SID)

    def report(run_id: str, jogged_s: float, phase: str = "running", attempt: int = 1) -> None:
        st = m.RunStatus(SID, run_id, phase, jogged_s=jogged_s, attempt=attempt)  # type: ignore[arg-type]
        files.on_run_status(status_key, codec.dumps(st))

    before = time.time_ns()
    first = layout_for(SID)
    rows = make_rows(arm_model(), 20)
    files.on_layout(keys.layout(USER, SID), codec.dumps(first))
    name = keys.recording_name(SID, "r1")
    writing = library.info(USER, name)  # listed while it is being written
    report("r1", 0.25)
    report("r1", 0.1)  # the figure only grows (the report of a lost worker says 0)
    report("r1", 9.0, attempt=2)  # an attempt the recording is not of
    report("r2", 8.0)  # another run of the session
    send_frame(files, 1, rows, frames.FLAG_FINAL)
    report("r1", 0.45, "finished")
    files.on_state(state_key, codec.dumps(m.SessionState(SID, "finished", run_id="r1")))
    files.close(files.active[(USER, SID)], "final frame")
    rec = mcapread.load(library.path_of(USER, name))
    assert rec.metadata["simecs.end"]["jogged_s"] == "0.45" and rec.jogged_s == 0.45
    att = library.results(USER, name, {}).attachment
    assert isinstance(att, m.ResultsAttachment) and att.run.jogged_s == 0.45 and att.run.recording == name
    listed = library.info(USER, name)
    made = mcapread.iso_utc(int(rec.metadata["simecs.run"]["created_ns"]))
    assert listed.created == writing.created == made and made.endswith("Z")
    assert before // 10**9 <= datetime.fromisoformat(made).timestamp() <= time.time()

    # r2's end is lost (r3 comes first): the results fetched for its gap have the final figure.
    second = msgspec.structs.replace(first, run_id="r2", run_index=2)
    files.on_layout(keys.layout(USER, SID), codec.dumps(second))
    send_frame(files, 2, rows)
    report("r2", 0.2)
    files.on_layout(keys.layout(USER, SID), codec.dumps(msgspec.structs.replace(first, run_id="r3")))
    owner, run_id, gaps = mesh.fills[-1]
    ended = m.RunInfo("r2", "finished", 1.0, float(rows[-1, 0]), rows.shape[0], jogged_s=0.3)
    files.on_fill("", Fill(owner, run_id, [(gaps[0], rows[:0])], "", ended))
    assert mcapread.load(library.path_of(USER, keys.recording_name(SID, "r2"))).jogged_s == 0.3
    # A file that does not say (its end not written yet, or written before it was kept): 0.
    assert mcapread.load(library.path_of(USER, keys.recording_name(SID, "r3"))).jogged_s == 0.0


def test_a_run_whose_final_frame_and_end_were_both_lost_is_asked_for_and_closed(tmp_path: Path) -> None:
    """A slow link dropped both the final frame and the ended state (each put once): the stream goes
    quiet, the run files ask the session's state (at 1 s of quiet, then every 5 s, not at every
    housekeeping), the answer ends the run, and its file is closed and filled from the results, long
    before the idle timeout. A run still going (a paused one: its state says so) stays open."""
    library, mesh, files = run_files(tmp_path)
    layout = layout_for(SID)
    rows = make_rows(arm_model(), 20)
    files.on_layout(keys.layout(USER, SID), codec.dumps(layout))
    send_frame(files, 1, rows)
    (rec,) = files.active.values()
    t = rec.last_data
    for dt in (0.2, 0.5, 0.9):
        files.housekeeping(t + dt)
    assert mesh.asked == []  # frames came less than a second ago
    files.housekeeping(t + 1.0)
    files.housekeeping(t + 1.5)
    assert mesh.asked == [(USER, SID)]  # asked once
    paused = m.SessionState(session=SID, phase="paused", run_id="r1", sim_time=float(rows[-1, 0]))
    files.on_state(keys.state(USER, SID), codec.dumps(paused))
    files.housekeeping(t + 5.9)
    assert mesh.asked == [(USER, SID)] and rec.close_at is None and mesh.fills == []
    files.housekeeping(t + 6.1)
    assert mesh.asked == [(USER, SID)] * 2  # still quiet: asked again after 5 s
    ended = m.SessionState(session=SID, phase="finished", run_id="r1", sim_time=1.0)
    files.on_state(keys.state(USER, SID), codec.dumps(ended))
    # past the grace for frames still on their way (and for its model, which this harness never brings)
    files.housekeeping(time.monotonic() + ENDED_GRACE_S + MODEL_WAIT_S + 1.0)
    ((owner, run_id, gaps),) = mesh.fills  # closed: its tail asked of the results
    assert run_id == "r1" and len(gaps) == 1 and math.isinf(gaps[0].before)


def test_a_frame_of_an_earlier_attempt_is_not_recorded(tmp_path: Path) -> None:
    """A run started again after its host was lost (layout context.attempt 2): frames of attempt 1, from
    a host that was only cut off, are strays; those of attempt 2 (and those that do not say) are kept."""
    _library, _mesh, files = run_files(tmp_path)
    layout = layout_for(SID)
    layout.context.attempt = 2
    rows = make_rows(arm_model(), 20)
    files.on_layout(keys.layout(USER, SID), codec.dumps(layout))
    for attempt in (1, 2):
        frame = frames.Frame(1, 0, time.time_ns(), rows[:10] + attempt, 0, attempt)
        files.on_full(keys.vars_full(USER, SID), frames.encode(frame))
    rec = files.active[(USER, SID)]
    assert rec.stray_frames == 1 and rec.writer.rows == 10
