"""Comparing runs in the viewer (a viser server with no page): recordings compared without replaying
them, runs on every plot with a time cursor that poses the arm, what runs differ in and the values at
the cursor."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace
from typing import Any

import msgspec
import numpy as np
import pytest
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.viewer import (
    compare,
    compare_panel,
    events,
    results,
    series,
)

from tests.viewer_fakes import (
    Event,
    arm,
    attached,
    loaded_tab,
    settle,
    state,
)


def test_recordings_are_listed_and_compared_without_replaying_them() -> None:
    ctl, sc, got = attached()
    mesh = ctl.host.mc
    sc.run_list = [m.RunInfo("r1", "finished", 1.0, 1.0, 11)]
    ctl.refresh_runs()
    ctx = m.RunContext("tester", {"joint1.ctrl.kp_pos": 7.0}, [0.0, 0.0, 0.0], None, m.RunSettings())
    mesh.recorded_context = ctx
    mesh.kept = [
        m.RecordingInfo("old_r4", "sOld", "r4", "arm3", 2000, stop_time=2.0),
        m.RecordingInfo("puma_r1", "sP", "r1", "puma560", 3000, stop_time=1.0),
    ]
    ctl.results.list_recordings()
    ctl.drain()
    assert [r.name for r in got.of(events.RecordingsListed)[-1].recordings] == ["old_r4"]  # this model's
    old = compare.recording_key("old_r4")
    assert compare.recording_of_key(old) == "old_r4" and compare.recording_of_key("r1") == ""
    # compared beside a run: read on the server (not replayed), each to its own end, with its context
    ctl.results.load_full(5, ["joint1.q"], None, None, run_id="r1", compare=[old])
    ctl.drain()
    loaded = got.of(events.TransientLoaded)[-1]
    (other,) = loaded.others
    assert other.run_id == old and other.context == ctx and other.t[-1] == 2.0
    assert mesh.read[-1] == ("old_r4", ["joint1.q"]) and not sc.of(m.Replay)
    ctl.results.load_track(old)
    ctl.drain()
    track = got.of(events.TrackLoaded)[-1].track
    assert track.run_id == old and track.end == 2.0 and track.poses.shape == (21, 3, 7)
    # a recording deleted meanwhile, or no recorder: said, not silent
    ctl.results.load_compared(5, ["joint1.q"], [compare.recording_key("gone")])
    ctl.drain()
    assert "no recording 'gone'" in got.of(events.Notice)[-1].body
    mesh.no_recorder = True
    ctl.results.list_recordings()
    ctl.drain()
    assert got.of(events.RecordingsListed)[-1].available is False


def test_runs_compared_on_every_plot_with_a_time_cursor_that_poses_the_arm(server: Any) -> None:
    model = arm()
    tab, client, page, sc = loaded_tab(server, model)
    ctl = tab.controller
    try:
        ctl.drain()  # a fresh session has no run yet: its recordings are listed all the same
        assert "None yet" in page.compare.recordings_note.content
        base = m.RunContext("tester", model.default_values(), [0.0, 0.0, 0.0], None, m.RunSettings())
        kp = model.parameters[0].name
        sc.contexts = {
            "r1": base,
            "r2": msgspec.structs.replace(base, values={**base.values, kp: 1.5}),
            "r3": base,
        }
        sc.run_list = [m.RunInfo(r, "finished", 1.0, 1.0, 11) for r in ("r1", "r2")]
        sc.run_list.append(m.RunInfo("r3", "running", 1.0, 0.2))
        ctl.refresh_runs()
        ctl.drain()
        cmp = page.compare
        assert list(cmp.boxes) == ["r1", "r2"] and page.results.selected() == "r3"  # a run going on: no box
        sc.run_list[-1] = m.RunInfo("r3", "aborted", 1.0, 0.4, 5)
        ctl.refresh_runs()
        ctl.drain()
        page.results.runs.value = next(o for o in page.results.runs.options if o.startswith("r2"))
        settle(tab)
        plot = page.open_plot("joint1.q")
        plot._transient(Event(SimpleNamespace(value="Full resolution")))
        ctl.drain()
        assert plot.full is not None and plot.full.run_id == "r2" and plot.others == []
        # tick r1 and r3: both drawn on the plot beside r2, and listed in how the runs differ
        for run_id in ("r1", "r3"):
            cmp.boxes[run_id].value = True
            cmp._ticked(Event(cmp.boxes[run_id]))
        ctl.drain()
        assert [o.run_id for o in plot.others] == ["r1", "r3"]
        stale = series.Transient("r1", np.linspace(0, 1, 3), {"joint1.q": np.zeros(3)})
        cmp.apply(events.ComparedLoaded(plot.number, [stale]))  # an answer to an older tick
        assert [o.run_id for o in plot.others] == ["r1", "r3"] and plot.others[0] is not stale
        plot.redraw(ctl.stream.live)
        labels = [s["label"] for s in plot.chart.series]
        assert labels[2:] == ["joint1.q (r1)", "joint1.q (r3)"]
        assert f"| {kp} |" in cmp.diff.content and "1.5" in cmp.diff.content
        # a recording of another session's run: listed, ticked, drawn beside them to its own end; the
        # recording of a run the session still keeps is not listed twice
        ctl.host.mc.kept = [
            m.RecordingInfo(keys.recording_name(sc.id, "r1"), sc.id, "r1", model.id, 100, stop_time=1.0),
            m.RecordingInfo("old_r4", "sOld", "r4", model.id, 2000, stop_time=2.0),
        ]
        ctl.results.list_recordings()
        ctl.drain()
        old = compare.recording_key("old_r4")
        assert list(cmp.recording_boxes) == [old] and "not replayed" in cmp.recordings_note.content
        cmp.recording_boxes[old].value = True
        cmp._ticked(Event(cmp.recording_boxes[old]))
        ctl.drain()
        assert [o.run_id for o in plot.others] == ["r1", "r3", old] and plot.others[-1].t[-1] == 2.0
        # a listing no recorder answered (a busy one) takes no box away, the ticked one least of all
        box = cmp.recording_boxes[old]
        ctl.host.mc.no_recorder = True
        ctl.results.list_recordings()
        ctl.drain()
        assert (
            cmp.recording_boxes == {old: box}
            and box.value
            and "No recorder answered" in cmp.recordings_note.content
        )
        ctl.host.mc.no_recorder = False
        # many recordings: the newest are offered, and a ticked one stays even when it is no longer
        many = [
            m.RecordingInfo(f"new_r{k}", "sNew", f"r{k}", model.id, 100, stop_time=1.0) for k in range(25)
        ]
        ctl.host.mc.kept = [*many, *ctl.host.mc.kept]
        ctl.results.list_recordings()
        ctl.drain()
        assert len(cmp.recording_boxes) == compare_panel.RECORDINGS_LISTED + 1 and old in cmp.recording_boxes
        assert (
            f"The {compare_panel.RECORDINGS_LISTED} newest of your 26 are listed"
            in cmp.recordings_note.content
        )
        cmp.recording_boxes[old].value = False
        cmp._ticked(Event(cmp.recording_boxes[old]))
        ctl.drain()
        assert [o.run_id for o in plot.others] == ["r1", "r3"]
        # the cursor: every plot marks it, the arm takes r2's pose there, values are read per run
        line = cmp.timeline  # one timeline, in the run bar (timeline.py)
        assert line.cursor.disabled
        line.cursor_on.value = True
        line._toggled(Event(line.cursor_on))
        assert not line.cursor.disabled and cmp.follow.options == ("r2", "r1", "r3")
        line.cursor.value = 0.5
        settle(tab)
        assert plot.cursor == 0.5
        assert np.allclose(page.scene.frames[0].position, [0.5, 1.0, 1.5])  # the fake's pose.link1.x/y/z
        assert "| joint1.q [deg] | 28.6479 | 28.6479 | 28.6479 |" in cmp.values.content  # degrees first
        plot.redraw(ctl.stream.live)
        assert plot.chart.series[-1]["label"] == "cursor"
        page.plots.angle_choice.value = "rad"
        settle(tab)
        assert plot.angles == "rad" and "| joint1.q [rad] | 0.5 | 0.5 | 0.5 |" in cmp.values.content
        # angles in degrees, chosen once: every plot and the values read at the cursor; remembered
        page.plots.angle_choice.value = "deg"
        settle(tab)
        assert (
            plot.angles == "deg" and "| joint1.q [deg] | 28.6479 | 28.6479 | 28.6479 |" in cmp.values.content
        )
        plot.redraw(ctl.stream.live)
        assert plot.chart.series[1]["label"] == "joint1.q [deg]" and plot.chart.axes[1]["label"] == "deg"
        assert max(plot.chart.data[1]) == pytest.approx(math.degrees(1.0))
        assert page.view_state()["angles"] == "deg"
        page.plots.set_angles("grad")  # a reload's memory is the browser's: only known choices are taken
        assert page.plots.angles == "deg"
        # the timeline plays: the cursor, and with it the arm, every plot and the values, on to the end
        line.speed.value = "4×"
        settle(tab)
        line._transport("▶ Play")
        seen = set()
        end = time.monotonic() + 10.0
        while time.monotonic() < end and line.playing:
            time.sleep(0.01)
            tab.loop.run_pending()
            seen.add(round(plot.cursor or 0.0, 3))
        settle(tab)  # the last step's cursor callback runs after the step that set it
        assert line.at == pytest.approx(float(line.cursor.max)) and plot.cursor == pytest.approx(line.at)
        assert len(seen) >= 3  # it moved on step by step, not in one jump
        line._transport("To start")
        assert line.at == 0.0
        # a variable on the X axis: remembered over a reload, drawn against it again
        other = next(v.name for v in ctl.model.variables if v.name != "joint1.q")
        plot.x_axis.value = other
        plot._x_axis_changed(Event(plot.x_axis))
        view = page.view_state()
        assert view["plots"] == [["joint1.q"]] and view["x_axes"] == [other]
        page.plots.close(plot)
        page.restore({**view, "x_axes": [other, "joint1.q"]})  # a second entry for no plot: ignored
        (again,) = page.plots.plots.values()
        assert again.x_var == other and again.x_axis.value == other and again.xy.visible
        page.plots.close(again)
        page.restore({**view, "x_axes": ["no.such"]})  # a name the model lacks: over time
        (plot,) = page.plots.plots.values()
        assert plot.x_var == "time" and plot.chart.visible
        # a new run takes the arm back: the cursor goes
        sc.watched["on_state"](state(sc, "running", "r4", seq=20))
        assert line.cursor_on.disabled and not line.on and plot.cursor is None
    finally:
        tab.close()
        page.remove()


def test_what_runs_differ_in_is_listed_and_values_at_the_cursor_read() -> None:
    model = arm()
    base = m.RunContext("u", model.default_values(), [0.0, 0.1, 0.0], None, m.RunSettings())
    same = compare.differences({"r1": base, "r2": base}, model)
    assert same == "_r1, r2 ran with the same parameters, initial pose, command and settings, none jogged._"
    name = model.parameters[0].name
    other = msgspec.structs.replace(
        base,
        values={**base.values, name: base.values[name] * 2},
        initial=[0.0, 0.2, 0.0],
        settings=m.RunSettings(stop_time=2.0),
        command=m.JointPath([m.PathNode([0.1, 0.0, 0.0])]),
    )
    table = compare.differences({"r1": base, "r2": other}, model)
    assert f"| {name} |" in table and "| initial pose [deg] | 0.0 5.7 0.0 | 0.0 11.5 0.0 |" in table
    assert "| stop time [s] |" in table and "| command | none | joint path, 1 node |" in table
    jogged = compare.differences({"r1": base, "r2": base}, model, {"r1": 0.0, "r2": 1.25})
    assert "| jogged [s] | no | 1.25 |" in jogged  # a jogged run is not said to have run the same
    info = m.RunInfo("r3", "finished", 5.0, 5.0, jogged_s=2.0, until_stopped=True)
    assert (
        results.run_label(info, other)
        == "r3 · finished · 5.00 s · joint path, 1 node · until stopped · jogged 2.0 s"
    )
    assert "older server" in compare.differences({"r1": base, "r2": None}, model)
    t = np.linspace(0.0, 1.0, 11)
    runs = {"r1": {"joint1.q": (t, t)}, "r2": {"joint1.q": (t[:6], -t[:6])}}
    text = compare.values_table(0.75, runs, ["joint1.q"], {"joint1.q": "rad"})
    assert "| joint1.q [rad] | 0.75 | — |" in text  # r2 ended at 0.5 s
    track = compare.RunTrack("r1", t, np.arange(11 * 2 * 7, dtype=float).reshape(11, 2, 7))
    assert track.at(0.24)[0, 0] == 28.0 and track.at(0.26)[0, 0] == 42.0 and track.at(9.0)[0, 0] == 140.0
