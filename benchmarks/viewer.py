"""`simecs bench viewer`: what a browser tab receives during a standard run.

A private mesh (hub on a unix socket, proxy, simulator, hot-feedback, viewer: real processes) and a
headless Debian chromium. In the page, the Spider is loaded, a one-node joint path to the standard
target is taught through the command panel, and Run is clicked. Measured in the browser itself:

- `updates_per_s`: message batches that moved the 3D arm, per second, while it moved (target >= 30);
- `first_frame_s`: from the click on Run to the first such batch (target <= 1 s);
- `pendant_to_3d_ms`: before the run, a Cartesian node is taught and its gizmo dragged 15 times (the
  page sends what a drag sends); from each drag to the first batch that moves the arm, i.e. the
  path sent, planned by the server (inverse kinematics) and the arm drawn at the node (p50, target
  <= 300 ms: the arm follows the hand);
- `scrub_frame_ms`: after the run, the Results tab's time cursor is turned on and set 15 times (typed
  into its box); from the page sending each new cursor value to the first batch that moves the arm
  to the run's pose at that instant (p50, target <= 100 ms: scrubbing feels direct).

The simulator is warmed first by one short run through the typed client (its first worker compiles
the drive kernels once). The standard run: Spider, 5 s at real-time pacing, 50 Hz live rate (the
default settings), all joints from 0 to (0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2) rad at 100 % / 100 %
(the models' standard case).
"""

from __future__ import annotations

import json
import math
import re
import socket
import statistics
import time
from typing import Any

from simecs.testing import browser
from simecs.testing.launch import LocalMesh
from simecs.viewer.cartesian_pendant import GIZMO

STANDARD_TARGET = (0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2)  # rad: standard_target of models/library/spider
MODEL_BUTTON = "Load Spider arm (joint-independent control)"
TARGET_UPDATES_PER_S = 30.0
TARGET_FIRST_FRAME_S = 1.0
TARGET_PENDANT_MS = 300.0
TARGET_SCRUB_MS = 100.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


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
        if page.get_by_text("finished run", exact=False).count():
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
    sends it) and time each drag until the page receives the arm drawn at the node's planned pose."""
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
            drawn = next((b for b, _n in browser.pose_batches(page) if b > t), None)
            time.sleep(0.005)
        if drawn is None:
            raise TimeoutError(f"drag {k + 1}: the arm was not redrawn within 10 s")
        waits.append(drawn - t)
        time.sleep(0.15)
    return {"pendant_to_3d_ms": float(statistics.median(waits)), "pendant_drags": len(waits)}


def measure_scrub(page: Any, moves: int = 15) -> dict[str, Any]:
    """Turn the time cursor on for the finished run and set it `moves` times across the run; time
    each setting until the page receives the arm posed at that instant."""
    page.get_by_role("tab", name="Results").click()
    page.get_by_label("Time cursor").check()
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


def _ms(seconds: float | None) -> str:
    return "?" if seconds is None else f"{seconds * 1000:.0f} ms"


def run_viewer_bench(json_out: bool) -> dict[str, Any] | None:
    """Run the benchmark; print a table (and with `json_out` one JSON object on the last line)."""
    missing = browser.browser_missing()
    if missing:
        print(f"simecs bench viewer: cannot run: {missing}")
        return None
    from playwright.sync_api import sync_playwright

    t0 = time.monotonic()
    port = free_port()
    with LocalMesh() as mesh:
        mesh.start_hub()
        mesh.start_service()
        mesh.start(
            "viewer",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--user",
            "bench",
            module="simecs.viewer.app",
        )
        warm_s = warm_up(mesh)
        setup_s = time.monotonic() - t0
        with sync_playwright() as pw:
            chrome = browser.launch(pw)
            try:
                page = chrome.new_page(viewport=browser.VIEWPORT)
                page.add_init_script(browser.PROBE_JS)
                page.goto(f"http://127.0.0.1:{port}")
                page.get_by_role("button", name=MODEL_BUTTON).click(timeout=60_000)
                pendant = measure_pendant(page)  # from the initial pose, where the path starts
                result = measure(page)
                result.update(pendant)
                result.update(measure_scrub(page))
            finally:
                chrome.close()
        result["viewer_click_to_frame_s"] = viewer_latency(mesh.log("viewer"))
    result.update(
        {
            "target_updates_per_s": TARGET_UPDATES_PER_S,
            "target_first_frame_s": TARGET_FIRST_FRAME_S,
            "target_pendant_to_3d_ms": TARGET_PENDANT_MS,
            "target_scrub_frame_ms": TARGET_SCRUB_MS,
            "ok": result["updates_per_s"] >= TARGET_UPDATES_PER_S
            and result["first_frame_s"] <= TARGET_FIRST_FRAME_S
            and result["pendant_to_3d_ms"] <= TARGET_PENDANT_MS
            and result["scrub_frame_ms"] <= TARGET_SCRUB_MS,
            "setup_s": setup_s,
            "warm_up_s": warm_s,
            "total_s": time.monotonic() - t0,
        }
    )
    rows = [
        (
            "3D pose updates received by the tab",
            f"{result['updates_per_s']:.1f} /s",
            f">= {TARGET_UPDATES_PER_S:g} /s",
        ),
        (
            "Run click -> first live frame in the tab",
            f"{result['first_frame_s'] * 1000:.0f} ms",
            f"<= {TARGET_FIRST_FRAME_S * 1000:.0f} ms",
        ),
        (
            "gizmo dragged -> arm at the node (p50)",
            f"{result['pendant_to_3d_ms']:.0f} ms",
            f"<= {TARGET_PENDANT_MS:.0f} ms",
        ),
        (
            "time cursor set -> arm at that instant (p50)",
            f"{result['scrub_frame_ms']:.0f} ms",
            f"<= {TARGET_SCRUB_MS:.0f} ms",
        ),
        ("pose updates while the arm moved", f"{result['pose_updates']} in {result['moving_s']:.2f} s", ""),
        ("  of which in the viewer (click in -> frame out)", _ms(result["viewer_click_to_frame_s"]), ""),
        ("mesh + viewer start, simulator warm-up", f"{setup_s:.1f} s ({warm_s:.1f} s)", ""),
    ]
    print("simecs bench viewer (headless chromium, standard run: Spider, 5 s real time, 50 Hz live)")
    print(f"{'measure':44} {'value':>18}  target")
    for name, value, target in rows:
        print(f"{name:44} {value:>18}  {target}")
    print(f"final status: {result['status']}")
    print("PASS" if result["ok"] else "FAIL: below target")
    if json_out:
        print(json.dumps(result))
    return result
