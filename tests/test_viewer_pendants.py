"""The command pendants in a real browser (Debian chromium + Playwright), at 1024×768 and 1600×900, on
the real service (issue 12, build item 2): the Cartesian pendant teaches the tool's pose, a typed
pose out of reach is refused with the server's reason beside the path, a reachable one is planned
and drawn, a gizmo drag moves the arm to the node's planned pose, and the 3D view stays clear.

Screenshots of each pendant go to `artifacts/viewer/`.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
from simecs.testing import browser as chromium
from simecs.viewer.cartesian_pendant import GIZMO

from .conftest import Mesh, wait_until
from .test_viewer_browser import (
    BOTH_SIZES,
    SHOTS,
    SPIDER,
    dismiss_notifications,
    logs_on_failure,
    model_shown,
    new_page,
    service_and_viewer,
    text_appears,
)
from .test_viewer_layout import view_is_clear

PLANNED = re.compile(r"Path duration \d")  # the server's plan shown (not "known once the path is sent")


def typed_position(page: Any) -> list[float]:
    return [float(chromium.vector_input(page, "Position [mm]", k).input_value()) for k in range(3)]


def set_position(page: Any, mm: list[float]) -> None:
    for k, v in enumerate(mm):
        chromium.set_field(page, chromium.vector_input(page, "Position [mm]", k), f"{v:.1f}")
    page.get_by_role("button", name="Set pose").click()


@BOTH_SIZES
def test_the_cartesian_pendant_plans_refuses_and_follows_the_gizmo(
    mesh: Mesh, browser: Any, size: tuple[int, int]
) -> None:
    with logs_on_failure(mesh, "viewer", "proxy"):
        cartesian_walk(mesh, browser, size)


def cartesian_walk(mesh: Mesh, browser: Any, size: tuple[int, int]) -> None:
    service, url = service_and_viewer(mesh)
    width, height = size
    tag = f"{width}x{height}"
    SHOTS.mkdir(parents=True, exist_ok=True)
    page = new_page(browser.new_context(viewport={"width": width, "height": height}), url)
    page.get_by_role("button", name=SPIDER).click()
    model_shown(page)
    dismiss_notifications(page)
    page.get_by_role("tab", name="Cartesian").click()

    # Teach: the tool's pose at the initial pose becomes node 1, planned by the server
    page.get_by_role("button", name="Teach").click()
    page.get_by_text(PLANNED).locator("visible=true").first.wait_for()  # not the joint path's
    taught = typed_position(page)
    sid = wait_until(lambda: next(iter(service.client.list_sessions("tester")), None), what="a session")
    session = service.client.session("tester", sid.session)
    command = wait_until(lambda: session.snapshot().command, what="the command stored")
    assert command.kind == "cartesian_path"
    assert [round(x * 1000, 1) for x in command.nodes[0].position] == pytest.approx(taught, abs=0.1)
    view_is_clear(page, 300 if width < 1400 else 500)

    # a pose far out of reach: refused, with the server's reason beside the path; nothing stored
    set_position(page, [taught[0] + 5000.0, taught[1], taught[2]])
    text_appears(page, "The server refused node 1")
    text_appears(page, "leaves the workspace")  # the server's reason, under the pose just set
    reason = page.get_by_text("leaves the workspace").locator("visible=true").first.bounding_box()
    assert reason is not None and 0 <= reason["y"] < height - 10, f"the reason is out of sight: {reason}"
    assert session.snapshot().command == command
    page.screenshot(path=str(SHOTS / f"cartesian_refused_{tag}.png"))

    # a reachable pose: planned (the refusal goes), stored, and the goal ghost drawn at the node (the
    # arm itself stays where the run starts)
    before = len(chromium.ghost_batches(page))
    # the Spider reaches it by LIN at 100 %; a tenth of a millimetre typed is a tenth stored
    goal = [taught[0] - 100.5, taught[1], taught[2] - 100.0]
    set_position(page, goal)
    page.get_by_text("The server refused").wait_for(state="hidden")
    wait_until(
        lambda: [round(x * 1000, 1) for x in session.snapshot().command.nodes[0].position] == goal,
        what="the typed pose stored",
    )
    wait_until(lambda: len(chromium.ghost_batches(page)) > before, what="the ghost drawn at the node")

    # the gizmo dragged: the arm follows to where the server plans the node
    dragged_to = [(goal[0] + 50.0) / 1000, goal[1] / 1000, goal[2] / 1000]
    t_drag = chromium.drag_gizmo(page, GIZMO, dragged_to)  # along its arrows: the orientation kept
    wait_until(
        lambda: any(t > t_drag for t, _n in chromium.ghost_batches(page)),
        what="the ghost redrawn after a drag",
    )
    wait_until(
        lambda: abs(session.snapshot().command.nodes[0].position[0] - dragged_to[0]) < 1e-6,
        interval=0.2,
        what="the dragged pose stored",
    )
    wait_until(
        lambda: typed_position(page)[0] == pytest.approx(goal[0] + 50.0, abs=0.1), what="fields follow"
    )
    view_is_clear(page, 300 if width < 1400 else 500)
    page.screenshot(path=str(SHOTS / f"cartesian_{tag}.png"))
    if width < 1400:
        return
    # Run: the arm goes there (the tool ends on the dragged position, the trace drawn on the way)
    page.get_by_role("button", name="Run", exact=True).click()
    text_appears(page, "finished run", timeout=60)
    run = session.runs()[-1]
    cols, rows = session.results(run.run_id, [f"pose.tool.{f}" for f in ("x", "y", "z")])
    assert np.linalg.norm(rows[-1, 1:4] - np.array(dragged_to)) < 2e-3, (rows[-1], dragged_to)
    page.screenshot(path=str(SHOTS / f"cartesian_run_{tag}.png"))
