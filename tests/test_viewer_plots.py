"""The viewer's plots and documentation without a page: live windows, full-resolution requests,
overlays and the time cursor, the live time axis, x-y curves, the plot dock; documentation links and
history."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from simecs.mesh.protocol.model import DocPage
from simecs.viewer import (
    docs,
    plot_dock,
    plots,
    series,
    xy_plot,
)

from tests.viewer_fakes import Event, arm


# -- plots ---------------------------------------------------------------------------------------------
def test_live_buffer_is_a_bounded_window() -> None:
    buf = series.LiveBuffer(capacity=100)
    buf.reset(["time", "a", "b"])
    for k in range(25):
        t = np.arange(k * 10, k * 10 + 10) * 0.01
        buf.append(np.column_stack([t, t * 2, -t]))
    assert len(buf) == 100
    t, (a, b) = buf.window(["a", "b"])
    assert len(t) == 100 and t[0] == pytest.approx(1.5) and t[-1] == pytest.approx(2.49)
    assert np.allclose(a, 2 * t) and np.all(np.diff(t) > 0)
    t, (a,) = buf.window(["a"], seconds=0.2)
    assert t[0] >= 2.29 - 1e-9
    _, (missing,) = buf.window(["nope"])
    assert np.all(missing == 0)
    buf.append(np.zeros((3, 2)))  # wrong width: ignored
    assert len(buf) == 100


def test_full_resolution_requests_stay_bounded() -> None:
    assert series.every_for(2501, None, None, 5.0) == 1
    assert series.every_for(2_000_001, None, None, 3600.0) == math.ceil(2_000_001 / series.MAX_POINTS)
    assert series.every_for(2_000_001, 0.0, 36.0, 3600.0) == 2  # a 1 % zoom is (nearly) full resolution


def test_overlay_puts_two_runs_on_one_time_axis() -> None:
    t = np.linspace(0, 1, 11)
    t_prev = np.linspace(0, 2, 5)
    x, cur, (prev,) = series.overlay(t, [t * 2], [(t_prev, [t_prev * 3])])
    assert x[0] == 0 and x[-1] == 2 and np.all(np.diff(x) > 0)
    assert np.allclose(np.interp(0.5, x, cur[0]), 1.0) and np.allclose(np.interp(1.5, x, prev[0]), 4.5)
    # a shorter run is drawn to its own end, never held flat beyond it (uPlot draws no NaN)
    beyond = x > 1.0
    assert beyond.any() and np.isnan(cur[0][beyond]).all() and not np.isnan(cur[0][~beyond]).any()
    assert not np.isnan(prev[0]).any()
    x, cur, (prev,) = series.overlay(np.empty(0), [np.empty(0)], [(t_prev, [t_prev])])
    assert np.array_equal(x, t_prev) and np.isnan(cur[0]).all()
    # several compared runs: each interpolated onto the union of all times, each to its own end
    t3 = np.linspace(0, 0.5, 6)
    x, cur, (_, (b,)) = series.overlay(t, [t], [(t_prev, [t_prev]), (t3, [-t3])])
    assert set(t3) <= set(x) and np.isnan(b[x > 0.5]).all() and np.allclose(np.interp(0.25, x, b), -0.25)


def test_the_time_cursor_is_a_vertical_line_that_breaks_no_other_line() -> None:
    x = np.linspace(0, 1, 11)
    y = 2 * x
    y_short = np.where(x <= 0.5, -x, np.nan)  # a compared run that ended at 0.5 s
    x2, (y2, s2), line = series.with_cursor(x, [y, y_short], 0.25)
    k = int(np.flatnonzero(np.isfinite(line))[0])
    assert x2[k] == 0.25 and 0.25 < x2[k + 1] < 0.25 + 1e-5 and np.all(np.diff(x2) > 0) and len(x2) == 13
    assert (line[k], line[k + 1]) == (-0.5, 2.0)  # spans every run's values
    assert np.isfinite(line).sum() == 2 and y2[k] == 0.5 and s2[k] == -0.25
    _, (_, s3), _ = series.with_cursor(x, [y, y_short], 0.75)
    assert np.isnan(s3[np.searchsorted(x, 0.75) :][:2]).all()  # past the short run's end: no value
    x5, (y5,), line5 = series.with_cursor(x, [y], 0.5)  # on a sample: one point added after it
    assert len(x5) == 12 and np.all(np.diff(x5) > 0) and line5[5] == 0.0 and line5[6] == 2.0
    x4, _, none = series.with_cursor(x, [y], 2.0)  # outside the data: no line
    assert np.array_equal(x4, x) and np.isnan(none).all()


def test_plot_redraws_live_then_full_resolution(server: Any) -> None:
    actions = plots.PlotActions(
        load_full=lambda *a: None,
        close=lambda p: None,
        error=lambda msg: None,
        added=lambda p, n: None,
        variable_names=lambda: ["joint1.q", "joint2.q"],
        batch=server.atomic,
    )
    plot = plots.Plot(server.gui, 1, ["joint1.q"], {"joint1.q": "rad"}, actions)
    buf = series.LiveBuffer()
    buf.reset(["time", "joint1.q"])
    plot.redraw(buf)  # no sample yet: the live window's span, nothing drawn in it, a y axis all the same
    assert list(plot.chart.data[0]) == [0.0, 10.0] and np.isnan(plot.chart.data[1]).all()
    assert plot.chart.scales["y"]["range"] == [-0.5, 0.5] and plot.chart.scales["x"]["range"] == [0, 10]
    plot.stop_time = 2.0  # a run shorter than the window: its own span, from its start
    plot.redraw(buf)
    assert plot.chart.scales["x"]["range"] == [0, 2]
    buf.append(np.column_stack([np.linspace(0, 1, 50), np.linspace(0, 2, 50)]))
    plot.redraw(buf)
    assert len(plot.chart.data) == 2 and len(plot.chart.data[0]) == 50
    assert plot.chart.series[1]["label"] == "joint1.q [rad]"
    plot.full = series.Transient("r2", np.linspace(0, 1, 500), {"joint1.q": np.ones(500)})
    plot.others = [series.Transient("r1", np.linspace(0, 1, 300), {"joint1.q": np.zeros(300)})]
    plot.redraw(buf)
    assert len(plot.chart.data) == 3 and len(plot.chart.data[0]) >= 500
    assert plot.chart.series[2]["dash"] == [6, 4] and "r2 full res" in plot.title()
    assert (
        plot.chart.series[2]["label"] == "joint1.q (r1)" and plot.chart.series[2]["stroke"] == plots.COLORS[1]
    )
    plot.cursor = 0.5
    plot.redraw(buf)
    assert len(plot.chart.data) == 4 and plot.chart.series[-1]["label"] == "cursor"
    plot.cursor = None
    plot.add_var.value = "joint2.q"
    plot._add_variable(Event(plot.add_var))
    assert plot.variables == ["joint1.q", "joint2.q"] and plot.add_var.value == "—"
    # Reset zoom: a drag-zoom lives in the browser's chart; new scales make it draw the chart anew
    # (the same chart: nothing is removed under the user's pointer)
    old, scaled = plot.chart, dict(plot.chart.scales)
    plot.reset_zoom()
    assert plot.dirty
    plot.redraw(buf)
    assert plot.chart is old and plot.chart.scales != scaled
    assert plot.chart.scales["x"]["range"] == [0, 1]  # the full resolution's span
    assert len(plot.chart.data) == 5 and plot.chart.series[2]["label"] == "joint2.q"  # 2 + 2 overlaid
    plot._transient(Event(SimpleNamespace(value="Live")))  # back to live: no drag-zoom left over
    plot.redraw(buf)
    assert plot.full is None and plot.chart is old and plot.chart.scales["x"]["range"] == [0, 2]
    plot.remove()


def test_the_live_time_axis_shows_the_runs_span_or_sweeps_the_window() -> None:
    """Issue 32, 1: the live time axis is never wider than the live window or the run, whichever is
    shorter; past the window it moves on a quarter at a time, keeping its span."""
    assert plots.live_axis(0.3, 10.0, 2.0, None) == (0.0, 2.0)
    assert plots.live_axis(1.9, 10.0, 2.0, (0.0, 2.0)) == (0.0, 2.0)
    assert plots.live_axis(4.0, 10.0, 60.0, None) == (0.0, 10.0)
    lo, hi = plots.live_axis(10.5, 10.0, 60.0, (0.0, 10.0))
    assert (lo, hi) == pytest.approx((3.0, 13.0))
    assert plots.live_axis(12.9, 10.0, 60.0, (lo, hi)) == (lo, hi)  # kept while the trace is inside
    assert plots.live_axis(5.0, 4.0, 0.0, None)[1] - plots.live_axis(5.0, 4.0, 0.0, None)[0] == 4.0


def test_a_variable_against_another_is_drawn_as_a_curve(server: Any) -> None:
    loaded: list[Any] = []
    actions = plots.PlotActions(
        load_full=lambda p, t0, t1: loaded.append((p.names(), t0, t1)),
        close=lambda p: None,
        error=lambda msg: None,
        added=lambda p, n: loaded.append(n),
        variable_names=lambda: ["joint1.q", "joint2.q"],
        batch=server.atomic,
    )
    units = {"joint1.q": "rad", "joint2.q": "rad"}
    plot = plots.Plot(server.gui, 1, ["joint1.q"], units, actions)
    plot.set_choices(["joint1.q", "joint2.q"])
    assert plot.x_axis.options == ("time", "joint2.q")
    plot.x_axis.value = "joint2.q"
    plot._x_axis_changed(Event(plot.x_axis))
    assert plot.names() == ["joint1.q", "joint2.q"] and loaded == ["joint2.q"]  # streamed from now on
    assert not plot.chart.visible and plot.xy.visible and "vs joint2.q" in plot.title()
    buf = series.LiveBuffer()
    buf.reset(["time", "joint1.q", "joint2.q"])
    t = np.linspace(0, 2 * np.pi, 200)
    buf.append(np.column_stack([t, np.cos(t), np.sin(t)]))  # a circle: x turns back on itself
    plot.cursor = np.pi / 2
    plot.redraw(buf)
    content = plot.xy.content
    assert content.count("<polyline") == 1 and "joint2.q [rad]" in content and "<circle" in content
    plot.others = [series.Transient("r1", t, {"joint1.q": 0.5 * np.cos(t), "joint2.q": 0.5 * np.sin(t)})]
    plot.redraw(buf)
    assert plot.xy.content.count("<polyline") == 2 and "stroke-dasharray" in plot.xy.content
    assert xy_plot.nice_ticks(-1.05, 1.05) == [-1.0, 0.0, 1.0]
    assert xy_plot.nice_ticks(0.0, 1.0) == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert "no data yet" in xy_plot.svg([], "x", "y")
    assert "&lt;b&gt;" in xy_plot.svg([xy_plot.XYLine("<b>", "#000", t, t)], "x", "y")  # labels escaped
    plot.full = series.Transient("r2", t, {"joint1.q": t})
    plot.x_axis.value = "time"
    plot._x_axis_changed(Event(plot.x_axis))
    assert plot.chart.visible and not plot.xy.visible and plot.names() == ["joint1.q"]
    plot.remove()


def test_plot_dock_opens_and_closes_with_its_plots(server: Any) -> None:
    closed: list[Any] = []
    actions = plots.PlotActions(
        load_full=lambda *a: None,
        close=closed.append,
        error=lambda msg: None,
        added=lambda p, n: None,
        variable_names=lambda: ["joint1.q"],
        batch=server.atomic,
    )
    placed: list[Any] = []

    def place() -> tuple[Any, Any]:  # what the page does on a wide screen: a column of their own
        panel = server.gui.add_panel()
        placed.append(panel)
        return panel, panel.add_tab("Plots")

    dock = plot_dock.PlotDock(server.gui, {}, actions, place)
    a = dock.open("joint1.q", ["joint1.q", "joint2.q"])
    b = dock.open("joint2.q", ["joint1.q", "joint2.q"])
    assert (a.number, b.number) == (1, 2) and dock.get(2) is b and dock.plotted() == {"joint1.q", "joint2.q"}
    assert placed == [dock.panel]  # the panel is placed once, by the layout
    a.full = series.Transient("r1", np.zeros(2))
    dock.new_run()
    assert a.full is None and a.dirty
    dock.close(a)
    assert dock.panel is not None and dock.get(1) is None
    dock.close(b)
    assert dock.panel is None and not dock.plots


# -- documentation ---------------------------------------------------------------------------------
def test_doc_links_become_buttons_and_history_goes_back(server: Any) -> None:
    model = arm()
    titles = {p.id: p.title for p in model.docs}
    r = docs.render(model.docs[1], titles)
    assert r.links == [("arm", "the arm")]  # doc:arm.motor does not exist: plain text, no button
    # an in-text link names the button that follows it (the tab's script clicks that button)
    assert f"[the arm]({docs.LINK_PREFIX}%E2%86%92%20Arm)" in r.markdown
    assert docs.button_label("Arm") == "→ Arm" and "doc:" not in r.markdown.replace("arm.motor", "")
    # a page's raw HTML is shown as text, its code as typed
    shown = docs.render(DocPage("x", "X", "a <script>alert(1)</script> `<link>`"), titles).markdown
    assert "<script>" not in shown and "&lt;script>" in shown and "`<link>`" in shown
    r0 = docs.render(model.docs[0], titles)
    assert r0.links == [("arm.joint", "joint drive"), ("arm.chain", "Chain")]
    h = docs.DocHistory("arm")
    h.go("arm.joint")
    h.go("arm.chain")
    assert h.back() and h.current == "arm.joint" and h.back() and h.current == "arm" and not h.back()

    asked: list[str] = []
    window = docs.DocsWindow(server.gui, model.docs, "arm", asked.append, lambda panel: None)
    window.open()
    window.follow("arm.joint")
    assert window.history.current == "arm.joint"
    window.back()
    assert window.history.current == "arm"
    window.follow("arm.motor")  # not carried in the description: asked from the server, off-thread
    assert asked == ["arm.motor"] and "Loading" in window.widgets[1].content
    window.receive(DocPage("arm.motor", "Motor", "The motor."))
    assert "The motor." in window.widgets[1].content and asked == ["arm.motor"]
    window.close()
    assert not window.is_open
