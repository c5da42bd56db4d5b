"""The viewer's layout in a real browser (Debian chromium + Playwright), at 1024×768, 1600×900 and 1920×1080:
no region covers the 3D view, the documentation's in-text links work and a new page opens at its
top, a reload gets back the plots and the shown component, pages survive a viewer restart (they
say the server is gone, then each reopens its own session by itself, a page in the background of
its window too), and Run, Pause, Resume, Abort stay in sight (a live plot's time axis is checked in
test_viewer_browser.py's use case).

Screenshots of each state go to `artifacts/viewer/`.
"""

from __future__ import annotations

from typing import Any

import pytest
from simecs.mesh.client import MeshClient
from simecs.testing import browser as chromium
from simecs.viewer import browser as viewer_browser

from .conftest import Mesh, free_port, start_service, wait_until
from .test_viewer_browser import (
    SHOTS,
    SIZES,
    SPIDER,
    dismiss_notifications,
    logs_on_failure,
    model_shown,
    new_page,
    open_components,
    plot_joint1_q,
    service_and_viewer,
    sessions_of,
    start_viewer,
    text_appears,
)

#: What covers the 3D view's centre, and how wide the view is (the three.js canvas is the largest).
VIEW_JS = """
() => {
  // three.js draws on the page's large canvases; uPlot's are small ones inside panels
  const area = (c) => { const r = c.getBoundingClientRect(); return r.width * r.height; };
  const canvases = Array.from(document.querySelectorAll('canvas'));
  const biggest = Math.max(0, ...canvases.map(area));
  const isView = (el) => !!el && el.tagName === 'CANVAS' && area(el) >= 0.5 * biggest;
  if (!biggest) return null;
  // the part of the view no region sits on, along a row across the window's middle
  const y = window.innerHeight / 2;
  let left = null, right = null;
  for (let x = 1; x < window.innerWidth; x += 4) {
    if (isView(document.elementFromPoint(x, y))) { if (left === null) left = x; right = x; }
  }
  if (left === null) return {free: 0, centre: 'nothing'};
  const hit = document.elementFromPoint((left + right) / 2, y);
  return {free: right - left, centre: isView(hit) ? 'view' : (hit ? hit.tagName + '.' + hit.className : '')};
}
"""


def view_is_clear(page: Any, min_free_px: int) -> None:
    """Nothing on the 3D view's centre, and the view wide enough (once the page has settled: a
    closing modal or a panel's opening animation passes within a few seconds)."""
    found: Any = None
    for _ in range(40):
        found = page.evaluate(VIEW_JS)
        if found is not None and found["centre"] == "view" and found["free"] >= min_free_px:
            return
        page.wait_for_timeout(250)
    assert found is not None, "no 3D canvas on the page"
    assert found["centre"] == "view", f"the 3D view's centre is covered by {found['centre']}"
    assert found["free"] >= min_free_px, f"the 3D view is {found['free']} px wide"


#: Where each run control is and what hides it: off the window, under something else, or clipped by
#: a box that scrolls (an E-stop is never in a scroll box).
RUN_CONTROLS_JS = """
() => ['Run', 'Pause', 'Resume', 'Abort'].map((label) => {
  const button = Array.from(document.querySelectorAll('button')).find((b) =>
    b.textContent.trim() === label && b.parentElement &&
    Array.from(b.parentElement.children).some((c) => c.textContent.trim() === 'Abort'));
  if (!button) return label + ': not on the page';
  const r = button.getBoundingClientRect();
  if (r.width < 4 || r.height < 4) return label + ': not drawn';
  if (r.left < 0 || r.top < 0 || r.right > window.innerWidth || r.bottom > window.innerHeight)
    return label + ': off the window';
  const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
  if (!hit || !(hit === button || button.contains(hit)))
    return label + ': covered by ' + (hit ? hit.tagName : '?');
  for (let e = button.parentElement; e; e = e.parentElement) {
    const style = getComputedStyle(e);
    if (/(auto|scroll)/.test(style.overflowY) && e.scrollHeight > e.clientHeight + 1)
      return label + ': in a scroll box';
  }
  return '';
}).filter((x) => x)
"""


def run_controls_in_sight(page: Any) -> None:
    """Run, Pause, Resume, Abort and the status line are in sight: in the window, on top, in no box
    that scrolls (issue 32, 2)."""
    problems: list[str] = []
    for _ in range(20):  # a panel's opening animation passes within a few seconds
        problems = page.evaluate(RUN_CONTROLS_JS)
        if not problems:
            break
        page.wait_for_timeout(250)
    assert not problems, problems
    page.get_by_text("now: ").locator("visible=true").first.wait_for(timeout=5000)  # the status line


@pytest.mark.timeout(480)  # three walks of about 25 s each, slower on a loaded machine
def test_no_region_covers_the_arm_and_a_reload_keeps_the_view(mesh: Mesh, browser: Any) -> None:
    """At each supported size and full HD, a tab of its own (one service and viewer for the three)."""
    _service, url = service_and_viewer(mesh)
    for size in [*SIZES, (1920, 1080)]:
        with logs_on_failure(mesh, "viewer", "proxy"):
            try:
                layout_walk(browser, url, size)
            except AssertionError as exc:
                raise AssertionError(f"at {size[0]}x{size[1]}: {exc}") from exc


def layout_walk(browser: Any, url: str, size: tuple[int, int]) -> None:
    width, height = size
    tag = f"{width}x{height}"
    SHOTS.mkdir(parents=True, exist_ok=True)
    context = browser.new_context(viewport={"width": width, "height": height})
    page = new_page(context, url)
    page.get_by_role("button", name=SPIDER).click()
    model_shown(page)
    dismiss_notifications(page)
    min_free = 300 if width < 1400 else 500
    view_is_clear(page, min_free)
    run_controls_in_sight(page)

    # the initial pose sliders open beside the arm, not on it
    page.get_by_role("button", name="Initialise").click()
    text_appears(page, "All joints to zero")
    view_is_clear(page, min_free)
    run_controls_in_sight(page)

    # a component's parameters come into view when it is picked (the tree folds up under its name)
    open_components(page)
    page.get_by_role("button", name="link2 (3)").click()
    length = page.get_by_label("length [m]")
    length.wait_for()
    box = length.bounding_box()
    assert box is not None and 0 <= box["y"] < height - 20, f"the picked parameters are out of sight: {box}"

    # documentation docked beside the trees; an in-text link opens its page, shown from its top
    page.get_by_role("button", name="Documentation").click()
    text_appears(page, "Links on this page")
    view_is_clear(page, min_free)
    page.get_by_role("link", name="Joint drive").first.click()
    text_appears(page, "Sub-components")
    back = page.get_by_role("button", name="◀ Back")
    back.wait_for()
    box = back.bounding_box()
    assert box is not None and 0 <= box["y"] < height, "a new page did not open at its top"

    # a plot, docked: still nothing on the arm
    plot_joint1_q(page)
    view_is_clear(page, 250 if width < 1400 else 400)
    run_controls_in_sight(page)  # with the documentation, the initial pose and a plot open
    page.screenshot(path=str(SHOTS / f"layout_{tag}.png"))

    # a reload gets back the session, its plot and the component shown (once the tab has kept them)
    page.get_by_role("tab", name="Parameters").click()
    view_kept = f"(sessionStorage.getItem('{viewer_browser.VIEW_KEY}') || '').match(/joint1[.]q.*link2/)"
    page.wait_for_function(view_kept, timeout=10_000)
    page.reload()
    model_shown(page)
    if width < 1400:  # the plots are a tab beside the trees: the tab shown before the reload stays
        page.get_by_role("tab", name="Plots").click()
    text_appears(page, "Plot 1: joint1.q")
    if width < 1400:
        page.get_by_role("tab", name="Parameters").click()
    page.get_by_text("Components · link2").locator("visible=true").first.wait_for()
    page.get_by_label("length [m]").wait_for()
    page.screenshot(path=str(SHOTS / f"reloaded_{tag}.png"))
    context.close()


def test_a_page_survives_a_viewer_restart(mesh: Mesh, browser: Any) -> None:
    with logs_on_failure(mesh, "viewer"):
        restart_walk(mesh, browser)


def session_page(context: Any, url: str, client: MeshClient, known: set[str]) -> tuple[Any, str]:
    """A new page of `context` that loaded the Spider: (the page, its session, not one of `known`)."""
    page = new_page(context, url)
    page.get_by_role("button", name=SPIDER).click()
    model_shown(page)
    sid = wait_until(lambda: next(iter(sessions_of(client) - known), None), timeout=20, what="a session")
    # the page shows it (the models window's button says "Spider arm" too): the tab remembers it now
    text_appears(page, f"session {sid[:8]}")
    return page, sid


def restart_walk(mesh: Mesh, browser: Any) -> None:
    """Two pages of one browser window, each with its session: the front one has the focus, the
    other none (Playwright's focus emulation off, as for a user's background tab). The viewer stops:
    the page says so; it starts again on the same port: both pages, the one in the background too,
    show their own session again by themselves (no reload), and the server has no other session.
    (`simecs bench viewer` does it six times with a third page in a window of its own.)"""
    service = start_service(mesh)
    port = free_port()
    url = start_viewer(mesh, port=port)
    one = browser.new_context(viewport=chromium.VIEWPORT)
    pages: list[Any] = []
    sids: list[str] = []
    for context in (one, one):
        page, sid = session_page(context, url, service.client, set(sids))
        chromium.real_focus(page)
        pages.append(page)
        sids.append(sid)
    pages[1].bring_to_front()
    wait_until(lambda: not chromium.has_focus(pages[0]), timeout=10, what="the first page in the background")
    assert chromium.has_focus(pages[1])
    for page, sid in zip(pages, sids, strict=True):
        chromium.watch_session(page, sid[:8])
    shown = [chromium.session_shown(page)[-1][1] for page in pages]  # the header's element, now
    assert min(shown) >= 0, "a page does not show its session"
    loaded = [chromium.loaded_at(page) for page in pages]
    banner = pages[0].locator("#simecs-lost")
    assert not banner.is_visible()

    mesh.stop("viewer")
    banner.wait_for(state="visible", timeout=15_000)  # the page says the server is gone
    # ... because its link went, not because the beats stopped: the last beat is younger than the
    # silence that would have shown the banner
    beat_age_ms = pages[0].evaluate("() => Date.now() - window.__simecsBeat")
    assert beat_age_ms < viewer_browser.SILENT_S * 1000, beat_age_ms
    assert "reconnects by itself" in banner.inner_text()
    SHOTS.mkdir(parents=True, exist_ok=True)
    pages[0].screenshot(path=str(SHOTS / "server_gone.png"))

    start_viewer(mesh, port=port)
    for n, (page, element) in enumerate(zip(pages, shown, strict=True), start=1):
        # the page built anew (a new header element) with its own session: reconnected and reopened
        wait_until(
            lambda page=page, element=element: chromium.shown_anew_after(page, element),
            timeout=90,
            interval=0.2,
            what=f"page {n} showing its session again",
        )
    assert [chromium.loaded_at(page) for page in pages] == loaded, "a page was reloaded"
    assert not chromium.has_focus(pages[0]), "the page in the background was brought to the front"
    for page, sid in zip(pages, sids, strict=True):
        text_appears(page, f"session {sid[:8]}")
    assert sessions_of(service.client) == set(sids), "a restarted page opened another session"
    banner.wait_for(state="hidden", timeout=30_000)
    pages[0].get_by_role("button", name="Run", exact=True).wait_for()
    pages[0].screenshot(path=str(SHOTS / "server_back.png"))
