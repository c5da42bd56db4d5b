"""Runs compared in a real browser (Debian chromium + Playwright) on the real service (issue 12, runs
compared for real): two runs of one session that differ in one gain; the later one's transient in a
plot with the earlier one ticked beside it, what they differ in listed, and the time cursor posing
the arm as the picked run was at that instant; an aborted run ticked too is drawn to where its data
end, and the chart still draws (uPlot fits no axis over a gap); a recording of another session's
longer run, ticked, is drawn to its own end without being replayed.

A screenshot goes to `artifacts/viewer/compare_*.png`.
"""

from __future__ import annotations

import math
from typing import Any

from simecs.mesh.protocol import keys
from simecs.testing import browser as chromium
from simecs.viewer import compare

from .conftest import Mesh, wait_until
from .test_recorder_support import wait_file_closed
from .test_viewer_browser import (
    SHOTS,
    dismiss_notifications,
    logs_on_failure,
    now_ms,
    plot_joint1_q,
    poses_since,
    spider_tab,
    text_appears,
)

GAIN = "joint1.ctrl.kp_pos"


def charts(page: Any) -> list[dict[str, Any]]:
    """Each chart as the page's uPlot holds it: its series' labels, the time of each series' last
    drawn value, and its y range (null: uPlot could not fit one and draws nothing)."""
    return list(
        page.evaluate("""() => Object.values((window.__viserTestpoints || {}).uplots || {}).map((tp) => {
  const u = tp.chart, xs = u.data[0];
  const ends = u.data.slice(1).map((ys) => {
    for (let i = ys.length - 1; i >= 0; i--) if (Number.isFinite(ys[i])) return xs[i];
    return null;
  });
  return {labels: u.series.slice(1).map((s) => s.label), ends, y: [u.scales.y.min, u.scales.y.max]};
})""")
    )


def test_two_runs_compared_with_a_time_cursor(mesh: Mesh, browser: Any) -> None:
    with logs_on_failure(mesh, "viewer", "proxy"):
        compare_walk(mesh, browser)


def compare_walk(mesh: Mesh, browser: Any) -> None:
    SHOTS.mkdir(parents=True, exist_ok=True)
    page, _context, session = spider_tab(mesh, browser, {"width": 1600, "height": 900})
    # A recording of another session's run (2 s, stiffer), kept by the recorder: compared, not replayed
    mesh.start("recorder", "--dir", str(mesh.folder / "rec"))
    elsewhere = mesh.client().create_session(session.user, "spider")
    elsewhere.set_settings(stop_time=2.0, output_interval=0.002, pacing="fast")
    elsewhere.set_joint_path([([0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2], 100.0, 100.0)])
    other_run = elsewhere.run()
    elsewhere.wait_for(["finished"], 120, other_run)
    recorded = keys.recording_name(elsewhere.id, other_run)
    wait_file_closed(mesh.folder / "rec" / session.user / f"{recorded}.mcap")
    # Two short runs of the same path; the second with a softer joint1 gain (the user's other client)
    session.set_settings(stop_time=1.0, output_interval=0.002, pacing="fast")
    session.set_joint_path([([0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2], 100.0, 100.0)])
    kp = session.snapshot().values[GAIN]
    # r1 is aborted early (5 s at real time, aborted past 0.3 s: the abort comes long before its end
    # even on a loaded machine): compared, it ends where its data end
    session.set_settings(stop_time=5.0, output_interval=0.002, pacing="realtime")
    assert session.run() == "r1"
    wait_until(lambda: session.snapshot().state.sim_time > 0.3, timeout=60, what="r1 under way")
    session.abort()
    aborted = session.wait_for(["aborted"], 30, "r1").sim_time
    session.set_settings(stop_time=1.0, output_interval=0.002, pacing="fast")
    for run_id in ("r2", "r3"):
        if run_id == "r3":
            session.set_params({GAIN: kp / 4})
        assert session.run() == run_id
        session.wait_for(["finished"], 120, run_id)
    text_appears(page, "finished run r3", timeout=30)
    dismiss_notifications(page)

    # the later run's transient in a plot, with the earlier one ticked beside it
    plot_joint1_q(page)
    page.get_by_role("tab", name="Results").click()
    page.get_by_role("button", name="Full resolution").first.click()
    text_appears(page, "r3 full res")
    page.get_by_label("r2 · finished", exact=False).check()
    text_appears(page, "joint1.q (r2)")  # its legend entry: drawn beside r3
    text_appears(page, GAIN)  # what the runs differ in
    text_appears(page, f"{kp / 4:.6g}")
    page.get_by_label("r1 · aborted", exact=False).check()
    text_appears(page, "joint1.q (r1)")
    chart = wait_until(lambda: next((c for c in charts(page) if len(c["labels"]) == 3), None), what="3 runs")
    assert chart["y"][0] is not None and chart["y"][1] > chart["y"][0], chart  # drawn, not blank
    ends = dict(zip(chart["labels"], chart["ends"], strict=True))
    assert ends["joint1.q (r2)"] == ends["joint1.q [deg]"] == 1.0  # angles in degrees, as the pendants
    assert abs(ends["joint1.q (r1)"] - aborted) < 0.01, (ends, aborted)  # not held flat to 1 s
    page.get_by_text("Recordings to compare", exact=True).locator("visible=true").first.click()
    mark = compare.recording_key(recorded)
    # listed by when it was made and which run it holds, not by its opaque name (issue 32, 9)
    info = next(r for r in mesh.client().recordings(session.user) if r.name == recorded)
    assert info.created and info.run_id in compare.recording_label(info)
    box = page.get_by_label(compare.recording_label(info), exact=True)
    box.check()
    label = f"joint1.q ({mark})"
    chart = wait_until(lambda: next((c for c in charts(page) if label in c["labels"]), None), what=label)
    assert dict(zip(chart["labels"], chart["ends"], strict=True))[label] == 2.0  # to its own end
    page.screenshot(path=str(SHOTS / "compare_recording_1600x900.png"))
    box.uncheck()
    wait_until(lambda: not [c for c in charts(page) if label in c["labels"]], what="the recording taken off")

    # the time cursor: the arm is posed as r2 was at 0.5 s, and the values there are read
    page.get_by_text("Timeline", exact=True).locator("visible=true").first.click()  # in the run bar
    page.get_by_label("Time cursor").check()
    box = chromium.slider_input(page, "Cursor [s]")
    wait_until(lambda: not box.is_disabled(), timeout=20, what="the cursor enabled (the run's poses in)")
    t = now_ms(page)
    chromium.set_field(page, box, "0.5")
    wait_until(lambda: poses_since(page, t) > 0, timeout=10, what="the arm posed at the cursor")
    text_appears(page, "at 0.500 s")
    _, rows = session.results("r3", ["joint1.q"], t0=0.5, t1=0.5)
    assert rows.shape[0] == 1
    text_appears(page, f"{math.degrees(rows[0, 1]):.6g}")  # r3's joint1.q at the cursor, in degrees
    chart = wait_until(
        lambda: next((c for c in charts(page) if "cursor" in c["labels"]), None), what="cursor"
    )
    assert chart["y"][0] is not None, chart
    assert abs(rows[0, 1]) > math.radians(1)  # the arm had moved: the pose shown is not the start
    # angles in radians, chosen once in the plots dock: the plot and the values at the cursor follow
    page.get_by_label("Angles in").click()
    page.get_by_role("option", name="rad", exact=True).click()
    text_appears(page, "joint1.q [rad]")
    text_appears(page, f"{rows[0, 1]:.6g}")
    page.wait_for_timeout(1500)  # the chart redrawn in its new range
    page.screenshot(path=str(SHOTS / "compare_1600x900.png"))
    # one variable against another: each run's curve, and a dot at the cursor
    page.get_by_label("X axis").click()
    page.get_by_role("option", name="joint2.q", exact=True).click()
    text_appears(page, "joint1.q vs joint2.q")
    wait_until(lambda: page.locator("polyline").count() == 3, timeout=20, what="3 runs against joint2.q")
    assert page.locator("svg circle").count() >= 1
    page.screenshot(path=str(SHOTS / "compare_xy_1600x900.png"))
