"""The session controller driven by injected messages and a fake mesh client (no server, no browser):
attaching sessions, logging in, phases and run buttons, edits and refusals, live frames, replays,
continuing a failed run, overlays and downloads, undo."""

from __future__ import annotations

import time

import msgspec
import numpy as np
import pytest
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import frames, keys, session_commands
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.kinematics import link_poses
from simecs.viewer import (
    compare,
    events,
    run,
    session,
)
from simecs.viewer.loop import TabLoop

from tests.viewer_fakes import (
    FakeHost,
    FakeMesh,
    Recorder,
    arm,
    attached,
    controller,
    layout,
    live_frame,
    state,
)


# -- the session controller, driven by injected messages ------------------------------------------------
def test_controller_starts_with_the_library_then_attaches_a_new_session() -> None:
    ctl, mesh, got = controller()
    ctl.start(remembered_session="", remembered_user="")
    ctl.drain()
    assert got.of(events.UserChanged)[0].user == "tester"  # the viewer's --user for a new browser
    listed = got.of(events.LibraryListed)[-1]
    assert [s.id for s in listed.models] == ["arm3"] and not listed.can_dismiss and listed.current == ""
    ctl.opening.load_model("arm3")
    ctl.drain()
    sc = mesh.sessions[ctl.session.id]
    assert got.of(events.SessionRemembered)[-1].session == sc.id
    assert got.of(events.ModelLoaded)[-1].model.id == "arm3" and got.of(events.LibraryClosed)
    assert set(sc.watched) == {"on_state", "on_params", "on_obstacles", "on_command", "on_layout", "on_live"}
    assert ctl.values == arm().default_values() and ctl.streamed == {v.name for v in arm().variables}
    assert got.of(events.ParamSetsChanged)[-1].names == ["light"]
    assert got.of(events.StateShown)[-1].state.phase == "created"


def test_on_a_secured_mesh_a_tab_logs_in_first_and_acts_as_its_user_only() -> None:
    mesh = FakeMesh(arm())
    host = FakeHost(mesh, passwords={"ann": "ann-password", "bob": "bob-password"})
    kept = mesh.create_session("ann", "arm3")  # from an earlier visit of this browser
    ctl = session.SessionController(host, tab_id=3, sync_delay_s=0.05, loop=TabLoop("t", driven=True))
    got = Recorder()
    ctl.subscribe(got)
    ctl.start(remembered_session=kept.id, remembered_user="ann")
    ctl.drain()
    listed = got.of(events.LibraryListed)[-1]
    assert listed.login and listed.sessions == [] and ctl.session is None  # nothing before the password
    ctl.opening.load_model("arm3")
    ctl.drain()
    assert "log in first" in got.of(events.Notice)[-1].body and ctl.session is None
    ctl.login("not-her-password")
    ctl.drain()
    assert "did not let ann in" in got.of(events.Notice)[-1].body and host.logins == []
    ctl.login("ann-password")
    ctl.drain()
    assert [c.user for c in host.logins] == ["ann"]
    assert ctl.session is not None and ctl.session.id == kept.id  # the remembered session, reopened
    ctl.opening.load_model("arm3")
    ctl.drain()
    assert mesh.sessions[ctl.session.id].snap.user == "ann"
    # Another name logs ann out: her client is closed, nothing is asked as her any more.
    ctl.opening.set_user("bob")
    ctl.drain()
    assert host.logins[0].closed and not ctl.identity.logged_in
    ctl.opening.open_library()
    ctl.drain()
    assert got.of(events.LibraryListed)[-1].login and got.of(events.LibraryListed)[-1].sessions == []
    ctl.close()


def test_controller_reopens_the_remembered_session_and_forgets_a_vanished_one() -> None:
    ctl, mesh, got = controller()
    sc = mesh.create_session("ada", "arm3")
    sc.snap.values["link2.length"] = 0.9
    ctl.start(remembered_session=sc.id, remembered_user="ada")
    ctl.drain()
    assert ctl.user == "ada" and not got.of(events.UserChanged)
    assert ctl.session is not None and ctl.session.id == sc.id and ctl.values["link2.length"] == 0.9
    other, mesh2, got2 = controller()
    other.start(remembered_session=keys.new_session_id(), remembered_user="ada")
    other.drain()
    assert got2.of(events.SessionRemembered)[-1].session == ""
    assert got2.of(events.Notice)[-1].title == "Previous session ended" and got2.of(events.LibraryListed)


def test_a_remembered_session_is_asked_again_when_the_server_does_not_answer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(session, "REOPEN_PAUSE_S", 0.0)
    ctl, mesh, got = controller()
    sc = mesh.create_session("ada", "arm3")
    sc.unanswered = session.REOPEN_TRIES - 1  # a viewer restarted before the mesh had its routes
    ctl.start(remembered_session=sc.id, remembered_user="ada")
    ctl.drain()
    assert ctl.session is not None and ctl.session.id == sc.id and not got.of(events.Notice)

    other, mesh2, got2 = controller()
    gone = mesh2.create_session("ada", "arm3")
    gone.unanswered = session.REOPEN_TRIES  # the server stays silent: the user is told, and
    other.start(remembered_session=gone.id, remembered_user="ada")
    other.drain()
    assert other.session is None and got2.of(events.Notice)[-1].title == "Cannot open the session"
    assert got2.of(events.LibraryListed)  # they can pick a model or a session,
    assert not got2.of(events.SessionRemembered)  # and the tab still remembers its session
    other.opening.open_session(gone.id)  # which opens once the server answers
    other.drain()
    assert other.session is not None and other.session.id == gone.id


def test_one_tab_per_session() -> None:
    ctl, sc, got = attached()
    second = session.SessionController(ctl.host, tab_id=4, loop=TabLoop("t2", driven=True))
    seen = Recorder()
    second.subscribe(seen)
    second.start()  # the same browser: the same user
    second.drain()
    second.opening.open_session(sc.id)
    second.drain()
    assert second.session is None and seen.of(events.Notice)[-1].title == "Session already open"
    ctl.close()  # the first tab went away: the session is free
    second.opening.open_session(sc.id)
    second.drain()
    assert second.session is not None and second.session.id == sc.id


def test_a_state_update_reaches_the_toolbar_listener() -> None:
    ctl, sc, got = attached()
    st = state(sc, "running", progress=0.5, sim_time=0.5, rtf=1.0)
    sc.watched["on_state"](st)
    shown = got.of(events.StateShown)[-1]
    assert shown.state is st and shown.replay == "" and ctl.phase == "running"
    sc.watched["on_state"](state(sc, "running", seq=3))  # an older publication arriving late
    assert ctl.state is st
    sc.watched["on_state"](m.SessionState(session=keys.new_session_id(), phase="failed"))  # not ours
    assert ctl.state is st


def test_a_finished_run_is_told_once_and_the_runs_are_listed_from_the_proxy() -> None:
    ctl, sc, got = attached()
    sc.run_list = [
        m.RunInfo("r1", "finished", 1.0, 1.0, samples=501),
        m.RunInfo("r2", "running", 1.0, 0.2, recording="rec_r1"),
    ]
    sc.watched["on_state"](state(sc, "finished", sim_time=1.0, rtf=2.0))
    sc.watched["on_state"](state(sc, "finished", seq=11, sim_time=1.0, rtf=2.0))
    ctl.drain()
    assert [n.title for n in got.of(events.Notice)].count("Run r1 finished") == 1
    listed = got.of(events.RunsChanged)[-1]
    assert [r.run_id for r in listed.runs] == ["r1", "r2"] and listed.newest == "r2"
    assert ctl.replay_of("r2") == "rec_r1" and ctl.replay_of("r1") == ""


@pytest.mark.parametrize(
    ("phase", "op"),
    [
        ("finished", "pause"),
        ("finished", "resume"),
        ("created", "abort"),
        ("running", "run"),
        ("paused", "pause"),
    ],
)
def test_run_buttons_are_refused_locally_with_the_phase_table(phase: str, op: str) -> None:
    ctl, sc, got = attached()
    sc.watched["on_state"](state(sc, phase))
    sent = len(sc.sent)
    ctl.control.run_action(op)
    ctl.drain()
    note = got.of(events.Notice)[-1]
    assert note.body == session_commands.refusal(op, phase) and note.kind == "warning"
    assert len(sc.sent) == sent


def test_run_sends_the_pending_path_first_and_pause_resume_abort_go_through() -> None:
    ctl, sc, got = attached()
    ctl.control.run_action("run")
    ctl.drain()
    assert "joint path is empty" in got.of(events.Notice)[-1].body and not sc.of(m.Run)
    ctl.path.teach([0.1, 0.2, 0.3])
    ctl.edits.command_changed()
    ctl.control.run_action("run")  # before the edit pause: the path goes first anyway
    ctl.drain()
    assert [type(c) for c in sc.sent[-2:]] == [m.SetCommand, m.Run]
    assert sc.of(m.SetCommand)[-1].command.nodes[0].q == [0.1, 0.2, 0.3]
    assert got.of(events.Notice)[-1].body == "Run **r1** assigned."
    # typed but not applied parameter values: the run would not take them, so it does not start
    ctl.pending_params = lambda: ["link2.mass"]
    sc.watched["on_state"](state(sc, "finished", seq=10))
    sent = len(sc.sent)
    ctl.control.run_action("run")
    ctl.drain()
    assert len(sc.sent) == sent and "not applied yet (link2.mass)" in got.of(events.Notice)[-1].body
    ctl.pending_params = lambda: []
    sc.watched["on_state"](state(sc, "running", seq=10))
    sc.watched["on_state"](state(sc, "running"))
    ctl.control.run_action("pause")
    sc.watched["on_state"](state(sc, "paused", seq=11))
    ctl.control.run_action("resume")
    sc.watched["on_state"](state(sc, "running", seq=12))
    ctl.control.run_action("abort")
    ctl.drain()
    assert [type(c) for c in sc.sent[-3:]] == [m.Pause, m.Resume, m.Abort]


def test_an_edit_burst_sends_one_request_after_the_pause() -> None:
    ctl, sc, got = attached()
    for k in range(20):  # a slider dragged: an event per move
        ctl.edits.set_initial([0.01 * k, 0.0, 0.0])
    assert len(got.of(events.PosePreview)) == 20 and ctl.shown_q == [0.19, 0.0, 0.0]
    ctl.tick()  # the user has not paused yet
    ctl.drain()
    assert not sc.of(m.SetInitial)
    ctl.tick(time.monotonic() + 1.0)
    ctl.tick(time.monotonic() + 2.0)
    ctl.drain()
    assert [c.joints for c in sc.of(m.SetInitial)] == [[0.19, 0.0, 0.0]]
    ctl.edits.set_streamed({"joint1.qd"}, plotted=set())
    ctl.tick(time.monotonic() + 1.0)
    ctl.drain()
    live = sc.of(m.SetSettings)[-1].settings.live_vars
    assert live == ["joint1.q", "joint1.qd", "joint2.q", "joint3.q"]  # joint positions always streamed


def test_a_refused_parameter_comes_back_to_the_server_value() -> None:
    ctl, sc, got = attached()
    sc.refuse[m.SetParams] = RemoteError(
        m.Error("bad_request", "values.link2.mass: 9999 kg is outside [0, 100] kg", "values.link2.mass")
    )
    ctl.edits.set_param("link2.mass", 9999.0)
    ctl.drain()
    assert got.of(events.ValuesChanged)[-1].values["link2.mass"] == 4.0
    note = got.of(events.Notice)[-1]
    assert note.title == "link2.mass not changed" and "outside [0, 100] kg (values.link2.mass)" in note.body
    # an appearance parameter reshapes the arm at once, and back when refused
    ctl.edits.set_param("link2.length", 2.5)
    ctl.drain()
    assert [e.values["link2.length"] for e in got.of(events.ShapesChanged)][-2:] == [2.5, 0.5]
    # accepted: the server's values are shown
    del sc.refuse[m.SetParams]
    ctl.edits.set_param("link2.length", 0.75)
    ctl.drain()
    assert (
        ctl.values["link2.length"] == 0.75 and got.of(events.ShapesChanged)[-1].values["link2.length"] == 0.75
    )
    # while a run is under way the edit is refused here, with the phase table's reason
    sc.watched["on_state"](state(sc, "running"))
    sent = len(sc.sent)
    ctl.edits.set_param("link2.mass", 5.0)
    ctl.drain()
    assert len(sc.sent) == sent and got.of(events.Notice)[-1].body == session_commands.refusal(
        "set_params", "running"
    )
    sc.watched["on_params"](m.ParamValues(sc.id, "arm3", {**ctl.values, "link2.mass": 7.0}))
    assert got.of(events.ValuesChanged)[-1].values["link2.mass"] == 7.0


def test_live_frames_pose_the_arm_and_teach_knows_the_pose() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    lay = layout(sc, model, "r1")
    sc.watched["on_layout"](lay)
    assert got.of(events.LayoutChanged)[-1].layout is lay
    sc.watched["on_live"](live_frame(lay, model, [0.3, -0.2, 0.1]))
    sample = got.of(events.LiveSamples)[-1]
    assert sample.poses is not None and sample.poses.shape == (3, 7)
    assert np.allclose(sample.poses, link_poses(model, model.default_values(), [0.3, -0.2, 0.1])[:3])
    assert ctl.shown_q == pytest.approx([0.3, -0.2, 0.1]) and ctl.stream.live.has("joint1.q")
    old = frames.Frame(7, 0, 0, live_frame(lay, model, [0.0] * 3).rows)  # another run: dropped
    sc.watched["on_live"](old)
    assert len(got.of(events.LiveSamples)) == 1
    ctl.path.teach(ctl.shown_q)
    assert ctl.path.nodes[0].q == pytest.approx([0.3, -0.2, 0.1])


def test_skipped_live_frames_are_counted_and_said_once_per_run() -> None:
    """The hub drops live frames for a tab that cannot keep up: the tab says so once, and counts them."""
    model = arm()
    ctl, sc, got = attached(model)
    lay = layout(sc, model, "r1")
    sc.watched["on_layout"](lay)
    rows = live_frame(lay, model, [0.1, 0.1, 0.1]).rows
    for seq in (0, 1, 4, 5, 9):  # 2, 3, 6, 7, 8 never came
        sc.watched["on_live"](frames.Frame(lay.run_index, seq, 0, rows))
    assert ctl.stream.missed == 5 and len(got.of(events.LiveSamples)) == 5
    said = [n for n in got.of(events.Notice) if n.title == "Live view behind"]
    assert len(said) == 1 and said[0].kind == "warning"
    sc.watched["on_layout"](layout(sc, model, "r2"))  # a new run counts afresh
    assert ctl.stream.missed == 0


def test_a_replay_is_a_run_of_the_session_shaped_by_the_recorded_values() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    sc.run_list = [m.RunInfo("r1", "finished", 1.0, 1.0, samples=501)]
    ctl.refresh_runs()
    ctl.control.replay_run("r1")
    ctl.drain()
    recording = keys.recording_name(sc.id, "r1")
    assert sc.of(m.Replay)[-1].recording == recording and ctl.session.id == sc.id  # no other session
    sc.watched["on_state"](state(sc, "queued", "r2"))
    lay = layout(sc, model, "r2", recording, **{"link2.length": 1.0})
    sc.watched["on_layout"](lay)
    assert ctl.replaying is lay
    assert got.of(events.ShapesChanged)[-1].values["link2.length"] == 1.0
    assert ctl.values["link2.length"] == 0.5  # the session's own values are untouched
    sc.watched["on_state"](state(sc, "running", "r2", seq=11))
    shown = got.of(events.StateShown)[-1]
    assert shown.replay == recording and f"replay r2 of `{recording}`" in run.status_text(
        shown.state, shown.replay
    )
    sc.watched["on_live"](live_frame(lay, model, [0.2, 0.2, 0.2]))
    assert np.allclose(  # the poses of the recorded arm
        got.of(events.LiveSamples)[-1].poses, link_poses(model, lay.context.values, [0.2] * 3)[:3]
    )
    ctl.control.run_action("pause")  # the buttons act on the replay as on any run
    ctl.drain()
    assert isinstance(sc.sent[-1], m.Pause)
    sc.watched["on_state"](state(sc, "finished", "r2", seq=12, sim_time=1.0))
    ctl.drain()
    assert got.of(events.Notice)[-1].title == f"Replay r2 of {recording} finished"
    # replaying a replay run replays its recording (replays are not recorded again)
    ctl.control.replay_run("r2")
    ctl.drain()
    assert sc.of(m.Replay)[-1].recording == recording
    # the user's own configuration again: the session's values shape the arm
    ctl.preview([0.0, 0.0, 0.0])
    assert ctl.replaying is None and got.of(events.ShapesChanged)[-1].values["link2.length"] == 0.5


def test_a_run_that_failed_part_way_is_offered_to_continue_and_the_server_says_why_not() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    sc.watched["on_state"](state(sc, "running", "r1", seq=11))
    crashed = "the simulator process of run r1 disappeared (crashed or killed)"
    sc.watched["on_state"](state(sc, "failed", "r1", seq=12, sim_time=0.4, reason=crashed))
    ctl.drain()
    said = got.of(events.Notice)[-1]
    assert said.title == "Run r1 failed" and crashed in said.body and "**Continue** (Results)" in said.body
    sc.counter = 1  # r1 is the server's last run
    ctl.control.continue_run("r1")
    ctl.drain()
    assert sc.of(m.Continue)[-1].run_id == "r1"
    assert "Run **r2** goes on from where **r1** ended" in got.of(events.Notice)[-1].body
    why = "run r1 cannot be continued: it was jogged for 0.20 s, and jogs are not run again"
    sc.refuse[m.Continue] = RemoteError(m.Error("conflict", why, "run_id"))
    ctl.control.continue_run("r1")
    ctl.drain()
    refused = got.of(events.Notice)[-1]
    assert refused.title == "Continue refused" and why in refused.body


def test_a_replay_already_over_when_the_tab_attaches_does_not_reshape_the_arm() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    sc.watched["on_state"](state(sc, "finished", "r2"))
    sc.watched["on_layout"](layout(sc, model, "r2", "rec_r1", **{"link2.length": 1.0}))
    assert ctl.replaying is None and got.of(events.StateShown)[-1].replay == "rec_r1"


def test_an_upload_replays_here_or_in_a_new_session_on_its_model() -> None:
    model = arm()
    other = msgspec.structs.replace(arm(), id="arm3b", name="Other arm")
    ctl, sc, got = attached(model, other)
    mesh = ctl.host.mc
    ctl.results.upload("/home/ada/kept run.mcap", b"MCAP")
    ctl.drain()
    assert mesh.uploaded == ["kept_run"] and sc.of(m.Replay)[-1].recording == "kept_run"
    mesh.upload_model = "arm3b"
    ctl.results.upload("other.mcap", b"MCAP")
    ctl.drain()
    assert ctl.session.id != sc.id and ctl.model.id == "arm3b"
    assert mesh.sessions[ctl.session.id].of(m.Replay)[-1].recording == "other"
    assert len(sc.of(m.Replay)) == 1


def test_full_resolution_overlay_and_downloads() -> None:
    ctl, sc, got = attached()
    sc.run_list = [m.RunInfo("r1", "finished", 1.0, 1.0, 11), m.RunInfo("r2", "finished", 1.0, 1.0, 11)]
    ctl.refresh_runs()
    ctx = m.RunContext("tester", {"joint1.ctrl.kp_pos": 20.0}, [0.0, 0.0, 0.0], None, m.RunSettings())
    sc.contexts["r1"] = ctx
    ctl.results.load_full(5, ["joint1.q"], None, None, run_id="", compare=["r1", "r2"])
    ctl.drain()
    loaded = got.of(events.TransientLoaded)[-1]
    assert loaded.plot == 5 and loaded.full.run_id == "r2" and [o.run_id for o in loaded.others] == ["r1"]
    assert loaded.others[0].context == ctx and loaded.full.context is None
    assert np.allclose(loaded.full.ys["joint1.q"], np.linspace(0, 1, 11))
    ctl.results.load_compared(5, ["joint1.q", "joint2.q"], ["r1"], 0.2, 0.4)
    ctl.drain()
    compared = got.of(events.ComparedLoaded)[-1]
    assert compared.plot == 5 and set(compared.others[0].ys) == {"joint1.q", "joint2.q"}
    assert compared.others[0].t0 == 0.2 and sc.asked[-1] == ("r1", ["joint1.q", "joint2.q"])
    ctl.results.load_compared(5, ["joint1.q"], ["r9"])
    ctl.drain()
    assert "r9 is no longer kept" in got.of(events.Notice)[-1].body
    ctl.results.load_track("r1")
    ctl.drain()
    track = got.of(events.TrackLoaded)[-1].track
    assert track.run_id == "r1" and track.context == ctx and track.poses.shape == (11, 3, 7)
    assert sc.asked[-1] == ("r1", compare.track_columns(ctl.model))
    sc.watched["on_state"](state(sc, "running", "r3"))
    sc.run_list.append(m.RunInfo("r3", "running", 1.0, 0.3))
    ctl.refresh_runs()
    ctl.results.load_full(5, ["joint1.q"])
    ctl.drain()
    assert "still going on" in got.of(events.Notice)[-1].body
    ctl.results.load_track("r3")
    ctl.drain()
    assert "r3 is still going on: compare it once it ends" in got.of(events.Notice)[-1].body
    ctl.results.download_csv("r1", ["joint1.q"])
    ctl.results.download_mcap("r1")
    ctl.drain()
    csv, mcap = got.of(events.Download)[-2:]
    assert csv.filename.endswith("_r1.csv") and b"# run: r1" in csv.data
    assert b"time,joint1.q\ns,rad\n" in csv.data
    assert mcap.filename == f"{keys.recording_name(sc.id, 'r1')}.mcap" and mcap.data.startswith(b"\x89MCAP")


def test_undo_puts_back_what_the_last_change_of_values_replaced() -> None:
    ctl, sc, got = attached()
    name, other = ctl.model.parameters[0].name, ctl.model.parameters[1].name
    old, old_other = ctl.values[name], ctl.values[other]
    assert ctl.edits.undo_what() == ""
    ctl.edits.set_params({name: old * 2})
    ctl.drain()
    assert got.of(events.UndoChanged)[-1].what == f"{name} back to {old:g}"
    ctl.edits.set_params({name: old * 3, other: old_other * 0.9})
    ctl.drain()
    assert ctl.edits.undo_what() == "2 parameters back to their values before the last change"
    ctl.edits.undo_params()
    ctl.drain()
    assert sc.of(m.SetParams)[-1].values == {name: old * 2, other: old_other}
    assert ctl.values[name] == old * 2 and got.of(events.Notice)[-1].title == "Undone"
    ctl.edits.undo_params()
    ctl.drain()
    assert ctl.values[name] == old and ctl.edits.undo_what() == ""
    assert got.of(events.UndoChanged)[-1].what == ""
    ctl.edits.undo_params()  # nothing left: said, nothing sent
    ctl.drain()
    assert "no change of parameter values to undo" in got.of(events.Notice)[-1].body
    assert len(sc.of(m.SetParams)) == 4
    ctl.edits.set_params({name: old * 2})
    ctl.drain()
    ctl.opening.load_model(ctl.model.id)  # another session: the last one's changes are not undone here
    ctl.drain()
    assert ctl.session.id != sc.id and ctl.edits.undo_what() == ""


def test_documentation_pages_not_carried_are_fetched_off_thread() -> None:
    ctl, sc, got = attached()
    ctl.fetch_doc("arm.motor")
    ctl.drain()
    page = got.of(events.DocFetched)[-1].page
    assert page.id == "arm.motor" and page.title == "Missing page"
    assert got.of(events.Notice)[-1].title == "Documentation"
