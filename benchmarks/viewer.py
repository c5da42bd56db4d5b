"""`simecs bench viewer`: what a browser tab receives during a standard run.

A private mesh (hub on a unix socket, proxy, simulator, hot-feedback, viewer: real processes) and a
headless Debian chromium. In the page, the Spider is loaded, a one-node joint path to the standard
target is taught through the command panel, and Run is clicked. Measured in the browser itself:

- `updates_per_s`: message batches that moved the 3D arm, per second, while it moved (target >= 30);
- `first_frame_s`: from the click on Run to the first such batch (target <= 1 s);
- `pendant_to_3d_ms`: before the run, a Cartesian node is taught and its gizmo dragged 15 times (the
  page sends what a drag sends); from each drag to the first batch that moves the goal ghost (the
  translucent arm drawn where the node puts it; the arm itself before there was a ghost), i.e. the
  path sent, planned by the server (inverse kinematics) and drawn at the node (p50, target
  <= 100 ms: the arm follows the hand);
- `scrub_frame_ms`: after the run, the time cursor (the run bar's Timeline) is turned on and set 15
  times (typed into its box); from the page sending each new cursor value to the first batch that
  moves the arm to the run's pose at that instant (p50, target <= 100 ms: scrubbing feels direct);
- `live_axis_span_ratio_max`: then a plot of joint1.q is opened and runs of 2, 5 and 10 s (real time,
  stop time set in the Settings window) go on under it; every 150 ms the page notes the time span its
  chart shows, over min(live window, the run's span): the largest such ratio (target <= 1.2: the live
  window shows the run's real span), the smallest, each run's largest, and the smallest time shown
  (never negative: a run starts at 0);
- `reconnect_pages`, `reconnect_pages_back`, `reconnect_s_max`: then three pages, each with a session
  of its own (two in one browser window, one in another: one of the two is in the background, so it
  has no focus, as in a user's browser), see the viewer node stopped and started again on the same
  port 6 times; a page is back when it shows its own session again, built anew, without a reload, at
  most 30 s after the restarted viewer's port accepts connections. The figures: page/restart events,
  how many came back by themselves, and the worst time from the viewer's port accepting connections
  to the page showing its session (target <= 5 s; every event must come back, and no new session
  may appear on the server).

The simulator is warmed first by one short run through the typed client (its first worker compiles
the drive kernels once). The standard run: Spider, 5 s at real-time pacing, 50 Hz live rate (the
default settings), all joints from 0 to (0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2) rad at 100 % / 100 %
(the models' standard case).
"""

from __future__ import annotations

import json
import math
import os
import re
import statistics
import time
from collections.abc import Callable
from typing import Any

from simecs.nodes.local_mesh import LocalMesh
from simecs.testing import browser
from simecs.viewer.cartesian_pendant import GIZMO

from .viewer_page import MODEL_BUTTON, USER, free_port, shown_session_of, start_viewer
from .viewer_reconnect import RESTARTS, measure_reconnect

STANDARD_TARGET = (0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2)  # rad: standard_target of models/library/spider
FINISHED = re.compile(r"finished run r\d+")  # the status line of a run that ended
TARGET_UPDATES_PER_S = 30.0
TARGET_FIRST_FRAME_S = 1.0
TARGET_PENDANT_MS = 100.0
TARGET_SCRUB_MS = 100.0
LIVE_RUNS_S = (2.0, 5.0, 10.0)  # stop times of the runs under a live plot, real time
TARGET_AXIS_RATIO = 1.2  # shown time span / min(live window, run's span)
AXIS_EVERY_MS = 150.0
TARGET_RECONNECT_S = 5.0


def warm_up(mesh: LocalMesh) -> float:
    """One short run through the typed client, so the measured run finds the simulator's worker warm.

    A fresh simulator compiles (or loads from numba's cache) the drive kernels in its first worker;
    that one-time cost belongs to the simulator's start, not to the viewer measured here.
    """
    t0 = time.monotonic()
    s = mesh.client().create_session("bench-warmup", "spider")
    try:
        s.set_settings(stop_time=0.2, output_interval=0.002, pacing="fast")
        s.set_joint_path([(list(STANDARD_TARGET), 100.0, 100.0)])
        s.run()
        s.wait_for(["finished", "failed", "aborted"], timeout=180.0)
    finally:
        s.close()
    return time.monotonic() - t0


def viewer_latency(log: str) -> float | None:
    """Click received -> first live frame drawn, as the viewer logged it (the server-side share)."""
    for line in reversed(log.splitlines()):
        if "first live frame" in line and "ms after the click" in line:
            try:
                return float(line.split(" drawn ", 1)[1].split(" ms", 1)[0]) / 1000.0
            except (IndexError, ValueError):
                return None
    return None


def measure(page: Any, run_timeout_s: float = 60.0) -> dict[str, Any]:
    """Teach the standard path, click Run, and time the pose updates the page receives."""
    page.get_by_role("tab", name="Joint path").click()
    page.get_by_role("button", name="Teach").click(timeout=30_000)
    for k, q in enumerate(STANDARD_TARGET, start=1):
        browser.set_field(
            page, browser.slider_input(page, f"joint{k} target [deg]"), f"{math.degrees(q):.1f}"
        )
    time.sleep(0.6)  # the path reaches the server after the edits pause (the Run click sends it anyway)
    before = len(browser.pose_batches(page))
    page.get_by_role("button", name="Run", exact=True).click()
    end = time.monotonic() + run_timeout_s
    while time.monotonic() < end:
        if page.get_by_text(FINISHED).count():  # the status line ("finished runs" is said elsewhere)
            break
        time.sleep(0.25)
    else:
        raise TimeoutError(f"the run did not finish within {run_timeout_s} s: {browser.status_text(page)!r}")
    run_clicks = [t for t, label in browser.clicks(page) if label == "Run"]
    batches = browser.pose_batches(page)[before:]
    if not run_clicks or not batches:
        raise RuntimeError("no pose update reached the page after Run")
    clicked = run_clicks[-1]
    after = [(t, n) for t, n in batches if t >= clicked]
    first = after[0][0]
    span = (after[-1][0] - first) / 1000.0
    return {
        "updates_per_s": (len(after) - 1) / span if span > 0 else 0.0,
        "first_frame_s": (first - clicked) / 1000.0,
        "pose_updates": len(after),
        "moving_s": span,
        "status": browser.status_text(page),
    }


def measure_pendant(page: Any, drags: int = 15) -> dict[str, Any]:
    """Teach a Cartesian node, then drag its gizmo `drags` times (a few cm each, as a user's drag
    sends it) and time each drag until the page receives the goal ghost (the translucent arm; before
    there was one, the arm itself) drawn at the node's planned pose."""
    page.get_by_role("tab", name="Cartesian").click()
    page.get_by_role("button", name="Teach").click()
    page.get_by_text(re.compile(r"Path duration \d")).locator("visible=true").first.wait_for(timeout=30_000)
    base = [float(browser.vector_input(page, "Position [mm]", k).input_value()) / 1000.0 for k in range(3)]
    waits = []
    for k in range(drags):
        offset = 0.02 * ((k % 4) - 1)  # within the Spider's reach by LIN at 100 % from the start pose
        target = [base[0] - 0.1 + offset, base[1], base[2] - 0.1 - offset]
        t = browser.drag_gizmo(page, GIZMO, target)
        end = time.monotonic() + 10.0
        drawn = None
        while drawn is None and time.monotonic() < end:
            drawn = next(
                (b for b, _n in browser.ghost_batches(page) + browser.pose_batches(page) if b > t), None
            )
            time.sleep(0.005)
        if drawn is None:
            raise TimeoutError(f"drag {k + 1}: neither the arm nor its goal ghost was redrawn within 10 s")
        waits.append(drawn - t)
        time.sleep(0.15)
    return {"pendant_to_3d_ms": float(statistics.median(waits)), "pendant_drags": len(waits)}


def measure_scrub(page: Any, moves: int = 15) -> dict[str, Any]:
    """Turn the time cursor on for the finished run and set it `moves` times across the run; time
    each setting until the page receives the arm posed at that instant."""
    toggle = page.get_by_label("Time cursor").locator("visible=true")
    if not toggle.count():  # in the run bar's Timeline folder, folded at first
        page.get_by_text("Timeline", exact=True).locator("visible=true").first.click()
    toggle.first.check()
    box = browser.slider_input(page, "Cursor [s]")
    end = time.monotonic() + 30.0
    while box.is_disabled() and time.monotonic() < end:  # enabled once the run's poses arrived
        time.sleep(0.05)
    waits = []
    for k in range(moves):
        at = 0.2 + 4.5 * ((k * 7) % moves) / moves  # spread over the 5 s run, not in order
        typed = float(page.evaluate("() => performance.now()"))
        browser.set_field(page, box, f"{at:.3f}")
        stop = time.monotonic() + 10.0
        t = drawn = None
        while drawn is None and time.monotonic() < stop:
            # from the page sending the cursor's value (not from the test's typing) to the arm drawn
            t = next((s for s in browser.sent_updates(page) if s > typed), None)
            drawn = next((b for b, _n in browser.pose_batches(page) if b > t), None) if t else None
            time.sleep(0.005)
        if drawn is None or t is None:
            raise TimeoutError(f"cursor setting {k + 1}: the arm was not redrawn within 10 s")
        waits.append(drawn - t)
        time.sleep(0.1)
    return {"scrub_frame_ms": float(statistics.median(waits)), "scrub_moves": len(waits)}


def session_of(mesh: LocalMesh, page: Any) -> Any:
    """The page's session, as the typed client sees it (found from the page's header)."""
    prefix = shown_session_of(page)
    found = [s.session for s in mesh.client().list_sessions(USER) if s.session.startswith(prefix)]
    if len(found) != 1:
        raise RuntimeError(f"the page's session {prefix}… is not one session on the server: {found}")
    return mesh.client().session(USER, found[0])


def measure_live_axis(page: Any, session: Any, run_timeout_s: float = 60.0) -> dict[str, Any]:
    """Open a plot of joint1.q, then for each stop time of LIVE_RUNS_S set it, click Run and note
    the chart's shown time axis while the run goes on."""
    browser.open_plot(page, "joint1 (14)", "joint1 (2 own)", "q")
    page.get_by_text("Plot 1: joint1.q").first.wait_for(timeout=30_000)
    window = float(browser.labelled_input(page, "Live window [s]").input_value())  # as the plot opens
    by_run: dict[str, Any] = {}
    ratios: list[float] = []
    lowest = math.inf
    for stop_time in LIVE_RUNS_S:
        browser.set_stop_time(page, stop_time)
        if session.snapshot().settings.stop_time != stop_time:
            raise RuntimeError(f"the stop time {stop_time:g} s did not reach the server")
        before = {r.run_id for r in session.runs()}
        browser.sample_time_axis(page, "joint1.q", AXIS_EVERY_MS)
        page.get_by_role("button", name="Run", exact=True).click()
        end = time.monotonic() + run_timeout_s
        new: list[str] = []
        while not new and time.monotonic() < end:
            new = [r.run_id for r in session.runs() if r.run_id not in before]
            time.sleep(0.1)
        if not new:
            raise TimeoutError(f"the {stop_time:g} s run did not start")
        run_id = new[0]
        session.wait_for(["finished", "failed", "aborted"], timeout=run_timeout_s, run_id=run_id)
        page.get_by_text(re.compile(rf"finished run {run_id}\b")).first.wait_for(timeout=30_000)
        samples = browser.time_axis_samples(page)
        clicked = max(t for t, label in browser.clicks(page) if label == "Run")
        shown = browser.run_axis(samples, f"run {run_id}", clicked)
        span = min(window, stop_time)
        run_ratios = [(a.x_max - a.x_min) / span for a in shown]
        titled = [a for a in samples if a.run == f"run {run_id}" and a.t_ms >= clicked]
        lowest = min([lowest, *[a.x_min for a in titled]])
        by_run[f"{stop_time:g}"] = {
            "ratio_max": max(run_ratios, default=math.nan),
            "ratio_min": min(run_ratios, default=math.nan),
            "samples": len(run_ratios),
            # the axis shown while the run went on (the smallest time shown is over every sample)
            "x_min": min((a.x_min for a in shown), default=math.nan),
            "x_max": max((a.x_max for a in shown), default=math.nan),
            # under the run's title, but still the previous run's data until the chart's next redraw
            "left_out": sum(1 for a in titled if a.phase == "running" and a not in shown),
        }
        ratios += run_ratios
    counted = [r["samples"] for r in by_run.values()]
    return {
        "live_axis_span_ratio_max": max(ratios, default=math.inf),
        "live_axis_span_ratio_min": min(ratios, default=0.0),
        "live_axis_runs": by_run,
        "live_axis_samples": sum(counted),
        "live_axis_sampled_every_run": min(counted) >= 3,
        "live_axis_lowest_s": lowest,
        "live_axis_negative": lowest < -1e-9,
        "live_window_s": window,
    }


def _ms(seconds: float | None) -> str:
    return "?" if seconds is None else f"{seconds * 1000:.0f} ms"


def _finite(value: Any) -> Any:
    """A figure for JSON: None when there is none (no sample, no page back)."""
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _num(value: float | None, fmt: str, unit: str = "", scale: float = 1.0) -> str:
    return "?" if value is None else f"{value * scale:{fmt}}{unit}"


def _at_most(value: float | None, target: float) -> bool:
    return value is not None and value <= target


def judge(result: dict[str, Any]) -> bool:
    """Every figure measured and on target (a part that failed has no figures: not ok)."""
    axis_ok = (
        _at_most(result.get("live_axis_span_ratio_max"), TARGET_AXIS_RATIO)
        and bool(result.get("live_axis_sampled_every_run"))
        and result.get("live_axis_negative") is False
    )
    pages = result.get("reconnect_pages", 0)
    reconnect_ok = (
        pages > 0
        and result.get("reconnect_pages_back") == pages
        and _at_most(result.get("reconnect_s_max"), TARGET_RECONNECT_S)
        and result.get("reconnect_sessions_kept") is True
        and not result.get("reconnect_viewer_crashes")
    )
    updates = result.get("updates_per_s")
    return (
        not result["errors"]
        and updates is not None
        and updates >= TARGET_UPDATES_PER_S
        and _at_most(result.get("first_frame_s"), TARGET_FIRST_FRAME_S)
        and _at_most(result.get("pendant_to_3d_ms"), TARGET_PENDANT_MS)
        and _at_most(result.get("scrub_frame_ms"), TARGET_SCRUB_MS)
        and axis_ok
        and reconnect_ok
    )


def run_viewer_bench(json_out: bool) -> dict[str, Any] | None:
    """Run the benchmark; print a table (and with `json_out` one JSON object on the last line).

    Each part is measured even when one before it failed (its error is kept in `errors`, and the
    bench is not ok): a figure that cannot be measured says so instead of hiding the others."""
    missing = browser.browser_missing()
    if missing:
        print(f"simecs bench viewer: cannot run: {missing}")
        return None
    from playwright.sync_api import sync_playwright

    t0 = time.monotonic()
    port = free_port()
    os.environ.setdefault("PYTHONFAULTHANDLER", "1")  # a node that crashes leaves its stacks in its log
    result: dict[str, Any] = {"errors": {}}

    def part(name: str, measure_part: Callable[[], dict[str, Any]]) -> None:
        started = time.monotonic()
        try:
            result.update(measure_part())
        except Exception as exc:  # said in the table and the JSON; the next part still runs
            result["errors"][name] = f"{type(exc).__name__}: {exc}"[:600]
        result[f"{name}_took_s"] = round(time.monotonic() - started, 1)

    with LocalMesh() as mesh:
        mesh.start_hub()
        mesh.start_service()
        start_viewer(mesh, port)
        warm_s = warm_up(mesh)
        setup_s = time.monotonic() - t0
        with sync_playwright() as pw:
            chrome = browser.launch(pw)
            try:
                page = chrome.new_context(viewport=browser.VIEWPORT).new_page()
                page.add_init_script(browser.PROBE_JS)
                page.goto(f"http://127.0.0.1:{port}")
                page.get_by_role("button", name=MODEL_BUTTON).click(timeout=60_000)
                part("pendant", lambda: measure_pendant(page))  # from the initial pose, where the path starts
                part("run", lambda: measure(page))
                part("scrub", lambda: measure_scrub(page))
                result["viewer_click_to_frame_s"] = viewer_latency(mesh.log("viewer"))
                part("live_axis", lambda: measure_live_axis(page, session_of(mesh, page)))
                part("reconnect", lambda: measure_reconnect(mesh, chrome, port, page))
            finally:
                chrome.close()
    result = {name: _finite(value) for name, value in result.items()}
    for run in result.get("live_axis_runs", {}).values():
        run.update({name: _finite(value) for name, value in run.items()})
    result.update(
        {
            "target_updates_per_s": TARGET_UPDATES_PER_S,
            "target_first_frame_s": TARGET_FIRST_FRAME_S,
            "target_pendant_to_3d_ms": TARGET_PENDANT_MS,
            "target_scrub_frame_ms": TARGET_SCRUB_MS,
            "target_live_axis_span_ratio": TARGET_AXIS_RATIO,
            "target_reconnect_s": TARGET_RECONNECT_S,
            "setup_s": setup_s,
            "warm_up_s": warm_s,
            "total_s": time.monotonic() - t0,
        }
    )
    result["ok"] = judge(result)
    print_table(result)
    if json_out:
        print(json.dumps(result))
    return result


def print_table(result: dict[str, Any]) -> None:
    r = result.get
    runs = r("live_axis_runs") or {}
    spread = ", ".join(f"{stop} s: {_num(run['ratio_max'], '.2f')}" for stop, run in runs.items())
    crashes = r("reconnect_viewer_crashes")
    rows = [
        (
            "3D pose updates received by the tab",
            _num(r("updates_per_s"), ".1f", " /s"),
            f">= {TARGET_UPDATES_PER_S:g} /s",
        ),
        (
            "Run click -> first live frame in the tab",
            _num(r("first_frame_s"), ".0f", " ms", 1000.0),
            f"<= {TARGET_FIRST_FRAME_S * 1000:.0f} ms",
        ),
        (
            "gizmo dragged -> goal ghost at the node (p50)",
            _num(r("pendant_to_3d_ms"), ".0f", " ms"),
            f"<= {TARGET_PENDANT_MS:.0f} ms",
        ),
        (
            "time cursor set -> arm at that instant (p50)",
            _num(r("scrub_frame_ms"), ".0f", " ms"),
            f"<= {TARGET_SCRUB_MS:.0f} ms",
        ),
        (
            "live plot: shown span / run's span (max)",
            _num(r("live_axis_span_ratio_max"), ".2f"),
            f"<= {TARGET_AXIS_RATIO:g}",
        ),
        ("  smallest ratio; largest per run", _num(r("live_axis_span_ratio_min"), ".2f"), spread),
        ("  smallest time shown", _num(r("live_axis_lowest_s"), ".3f", " s"), ">= 0 s"),
        (
            "pages back by themselves after a restart",
            f"{r('reconnect_pages_back', '?')}/{r('reconnect_pages', '?')}",
            "all",
        ),
        (
            "  of which in the background (no focus)",
            f"{r('reconnect_background_back', '?')}/{r('reconnect_background', '?')}",
            "all",
        ),
        (
            "viewer back -> page shows its session (max)",
            _num(r("reconnect_s_max"), ".2f", " s"),
            f"<= {TARGET_RECONNECT_S:g} s",
        ),
        ("  median", _num(r("reconnect_s_p50"), ".2f", " s"), ""),
        (
            "  worst of pages with focus / in the background",
            _num(r("reconnect_s_max_focused"), ".2f")
            + " / "
            + _num(r("reconnect_s_max_background"), ".2f", " s"),
            "",
        ),
        (
            "  the server's sessions unchanged",
            {"True": "yes", "False": "NO"}.get(str(r("reconnect_sessions_kept")), "?"),
            "yes",
        ),
        ("  viewer processes that died", "?" if crashes is None else str(len(crashes)), "0"),
        (
            "pose updates while the arm moved",
            f"{r('pose_updates', '?')} in {_num(r('moving_s'), '.2f', ' s')}",
            "",
        ),
        ("  of which in the viewer (click in -> frame out)", _ms(r("viewer_click_to_frame_s")), ""),
        (
            "mesh + viewer start, simulator warm-up",
            f"{result['setup_s']:.1f} s ({result['warm_up_s']:.1f} s)",
            "",
        ),
        (
            "live plots, restarts, whole bench",
            f"{r('live_axis_took_s', 0):.0f} s, {r('reconnect_took_s', 0):.0f} s, {result['total_s']:.0f} s",
            "",
        ),
    ]
    print(
        "simecs bench viewer (headless chromium, standard run: Spider, 5 s real time, 50 Hz live; "
        f"live plot over runs of {', '.join(f'{s:g}' for s in LIVE_RUNS_S)} s; "
        f"{RESTARTS} viewer restarts under 3 pages)"
    )
    print(f"{'measure':44} {'value':>18}  target")
    for name, value, target in rows:
        print(f"{name:44} {value:>18}  {target}")
    print(f"final status: {r('status', '?')}")
    for crash in crashes or []:
        print(f"the viewer died after restart {crash['restart']} (exit {crash['exit']}); its log ended:")
        print(crash["log"])
    for name, error in result["errors"].items():
        print(f"{name}: not measured: {error}")
    print("PASS" if result["ok"] else "FAIL: below target")
