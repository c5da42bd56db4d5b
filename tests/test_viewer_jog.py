"""Jogging as on a teach pendant, in a real browser on the real service (issue 32): an idle arm is
jogged by holding a button (viser reports a held button as repeated hold messages and its release as
a click), in a run until stopped that the pendant starts; letting go stops the arm, Stop jogging ends
the run as finished, and Teach then records where the jog left the arm. The run bar and its keys
(Space, Esc) act on the run too.

A screenshot goes to `artifacts/viewer/jog_*.png`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from simecs.mesh.protocol import messages as m

from .conftest import Mesh, wait_until
from .test_viewer_browser import SHOTS, dismiss_notifications, logs_on_failure, sized_spider_tab, text_appears
from .test_viewer_layout import run_controls_in_sight


def test_an_idle_arm_is_jogged_by_holding_a_button_and_taught_where_it_was_left(
    mesh: Mesh, browser: Any
) -> None:
    with logs_on_failure(mesh, "viewer", "proxy", "simulator"):
        jog_walk(mesh, browser)


def hold(page: Any, label: str, seconds: float) -> None:
    """Press the button labelled `label`, hold it `seconds`, let go (as a user's mouse does)."""
    box = page.get_by_role("button", name=label, exact=True).bounding_box()
    assert box is not None, f"no button {label}"
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_timeout(seconds * 1000)
    page.mouse.up()


def shown(page: Any, text: str) -> None:
    """`text` visible on the page (the run bar's status line)."""
    page.get_by_text(text).locator("visible=true").first.wait_for(timeout=30_000)


def unfocus(page: Any) -> None:
    page.evaluate("() => document.activeElement && document.activeElement.blur()")


def jog_walk(mesh: Mesh, browser: Any) -> None:
    page, session, tag = sized_spider_tab(mesh, browser, (1600, 900))
    q0 = session.snapshot().initial
    # a number field typed blank (letters are not taken): the value in force comes back, said so
    speed = page.get_by_label("Speed [%]").locator("visible=true").first
    speed.fill("")
    speed.press("Tab")
    page.get_by_text("Not a number: the value stays 100").wait_for()
    assert speed.input_value() == "100"
    page.get_by_role("tab", name="Jog").click()
    page.get_by_label("Axis").click()
    page.get_by_role("option", name="joint2", exact=True).click()

    # the idle arm: a hold starts a run until stopped and moves joint2 while the button is held
    hold(page, "Jog +", 3.0)
    wait_until(lambda: session.snapshot().state.phase == "running", timeout=30, what="a run until stopped")
    run_id = session.snapshot().state.run_id
    assert session.runs()[-1].until_stopped
    text_appears(page, "until stopped")  # the run bar says it has no end of its own
    run_controls_in_sight(page)  # while a run goes on too
    hold(page, "Jog +", 2.0)  # held while the run runs: the arm moves
    page.wait_for_timeout(1500)  # let go: the arm stands still from the release on
    dismiss_notifications(page)
    page.screenshot(path=str(SHOTS / f"jog_{tag}.png"))

    # Space pauses, Space resumes (the run bar's keys), Stop jogging ends the run as finished
    unfocus(page)  # the keys act on the page, not on a field being typed in
    page.keyboard.press("Space")
    wait_until(lambda: session.snapshot().state.phase == "paused", timeout=15, what="Space paused")
    shown(page, f"paused run {run_id}")  # the page knows it too: Space now resumes
    page.keyboard.press("Space")
    wait_until(lambda: session.snapshot().state.phase == "running", timeout=15, what="Space resumed")
    shown(page, f"running run {run_id}")
    page.get_by_role("button", name="Stop jogging").click()
    st = session.wait_for(["finished"], 30, run_id)
    assert "stopped by the user" in st.reason
    _, rows = session.results(run_id, ["joint2.qd_ref", "joint2.q"])
    t, qd_ref, q = rows[:, 0], rows[:, 1], rows[:, 2]
    jogged = float(q[-1])
    assert jogged - q0[1] > math.radians(1), "joint2 did not move while the button was held"
    moving = t[np.abs(qd_ref) > 1e-6]
    assert len(moving) and t[-1] - moving[-1] > 1.0, "joint2 was still commanded after the release"

    # Teach records where the jog left the arm (the last live pose), not the initial pose
    page.get_by_role("tab", name="Joint path").click()
    page.get_by_role("button", name="Teach").click()
    cmd = wait_until(
        lambda: c if isinstance(c := session.snapshot().command, m.JointPath) else None, what="a taught node"
    )
    assert abs(cmd.nodes[0].q[1] - jogged) < math.radians(0.2), (cmd.nodes[0].q, jogged)

    # Esc aborts a run going (the run bar's Abort): a timed run started with Run
    session.set_settings(stop_time=30.0, pacing="realtime")
    page.get_by_role("button", name="Run", exact=True).click()
    wait_until(lambda: session.snapshot().state.phase == "running", timeout=30, what="the run running")
    shown(page, "running run")
    unfocus(page)
    page.keyboard.press("Escape")
    session.wait_for(["aborted"], 30)
