"""The viewer in a real browser (Debian chromium + Playwright): the paper's use case step by step
(§2.2 steps 1-11) through the UI, a replay as a run of the same session, and one session per browser
tab.

Skips with its reason when chromium or Playwright is missing (.ci/run installs chromium).
"""

from __future__ import annotations

import importlib.util
import math
import re
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from simecs.mesh.client import MeshClient, SessionClient
from simecs.mesh.protocol import keys
from simecs.testing import browser as chromium

from .conftest import ARTIFACTS, Mesh, Secured, Service, free_port, start_service, wait_until

SPIDER = "Load Spider arm (joint-independent control)"
USER = "tester"
SHOTS = ARTIFACTS / "viewer"  # screenshots of what the browser tests saw


def start_viewer(mesh: Mesh, *flags: str, port: int = 0) -> str:
    """The viewer node on `port` (a free one if 0), its URL once it is ready."""
    url = spawn_viewer(mesh, *flags, port=port)
    mesh.wait_node("viewer", "viewer-t", timeout=60)
    return url


def spawn_viewer(mesh: Mesh, *flags: str, port: int = 0) -> str:
    """Start the viewer node on `port` (a free one if 0) without waiting for it; its URL."""
    port = port or free_port()
    mesh.spawn(
        "viewer",
        "simecs.viewer.app",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--user",
        USER,
        *flags,
        node_id="viewer-t",
    )
    return f"http://127.0.0.1:{port}"


def service_and_viewer(mesh: Mesh) -> tuple[Service, str]:
    """The service and a viewer, their start-ups overlapping: (the service, the viewer's URL)."""
    url = spawn_viewer(mesh)
    service = start_service(mesh)
    mesh.wait_node("viewer", "viewer-t", timeout=60)
    return service, url


def new_page(context: Any, url: str) -> Any:
    page = context.new_page()
    page.set_default_timeout(30_000)
    page.add_init_script(chromium.PROBE_JS)
    page.goto(url)
    return page


def plot_joint1_q(page: Any) -> None:
    """Open the first plot, of joint1.q, from the Variables tab as a user does."""
    chromium.open_plot(page, "joint1 (14)", "joint1 (2 own)", "q")
    text_appears(page, "Plot 1: joint1.q")


def spider_tab(
    mesh: Mesh, browser: Any, viewport: dict[str, int] | None = None
) -> tuple[Any, Any, SessionClient]:
    """The service and a viewer on `mesh`, and a tab that loaded the Spider: (page, its browser
    context, the tab's session as its user's client sees it)."""
    service, url = service_and_viewer(mesh)
    context = browser.new_context(viewport=viewport or chromium.VIEWPORT)
    page = new_page(context, url)
    page.get_by_role("button", name=SPIDER).click()
    model_shown(page)
    client = service.client
    sid = wait_until(lambda: next(iter(sessions_of(client)), None), timeout=20, what="a session")
    return page, context, client.session(USER, sid)


#: The viewports every pendant and layout walk runs at: the smallest supported, and a common laptop's.
SIZES = [(1024, 768), (1600, 900)]
BOTH_SIZES = pytest.mark.parametrize("size", SIZES, ids=lambda size: f"{size[0]}x{size[1]}")


def sized_spider_tab(mesh: Mesh, browser: Any, size: tuple[int, int]) -> tuple[Any, SessionClient, str]:
    """`spider_tab` at viewport `size`, its notices closed: (page, session, the size as a tag for
    screenshot names, which go to SHOTS)."""
    width, height = size
    SHOTS.mkdir(parents=True, exist_ok=True)
    page, _context, session = spider_tab(mesh, browser, {"width": width, "height": height})
    dismiss_notifications(page)
    return page, session, f"{width}x{height}"


def sessions_of(client: MeshClient) -> set[str]:
    return {s.session for s in client.list_sessions(USER) if s.phase != "closed"}


def text_appears(page: Any, text: str, timeout: float = 30.0) -> None:
    """Wait for `text`; when it does not come, say what the page showed instead (its notices and a
    screenshot in artifacts/viewer/), so a failure on a CI machine can be read."""
    try:
        page.get_by_text(text, exact=False).first.wait_for(timeout=timeout * 1000)
    except Exception as exc:
        SHOTS.mkdir(parents=True, exist_ok=True)
        shot = SHOTS / f"missing_{abs(hash(text)) % 10**8}.png"
        notices: list[str] = []
        try:
            page.screenshot(path=str(shot))
            shot.with_suffix(".html").write_text(page.content())  # what a screenshot cannot tell
            notices = [n.inner_text(timeout=2000) for n in page.locator(".mantine-Notification-root").all()]
        except Exception:
            pass
        raise AssertionError(f"{text!r} did not appear; notices shown: {notices}; screenshot {shot}") from exc


def chart_spans(page: Any) -> list[float]:
    """For each chart in sight (not the Direct input pendant's preview, in a tab behind), the part of
    its data's time range its x axis shows (1: all)."""
    return page.evaluate("""() => Object.values((window.__viserTestpoints || {}).uplots || {})
    .filter((tp) => tp.chart.root.getClientRects().length > 0).map((tp) => {
  const u = tp.chart, xs = u.data[0];
  const range = xs[xs.length - 1] - xs[0];
  return range > 0 ? (u.scales.x.max - u.scales.x.min) / range : 0;
})""") or [0.0]


#: The plotting area of the chart in sight that draws at least 1000 samples (None: none yet).
FULL_CHART_JS = """() => {
  for (const tp of Object.values((window.__viserTestpoints || {}).uplots || {})) {
    const u = tp.chart;
    if (u.root.getClientRects().length > 0 && u.data && u.data[0] && u.data[0].length >= 1000) {
      const r = u.over.getBoundingClientRect();
      return {x: r.x, y: r.y, width: r.width, height: r.height};
    }
  }
  return null;
}"""


def model_shown(page: Any, timeout: float = 30.0) -> None:
    """The model's page is up: its header names the session (the models window's buttons carry the
    model's name too, so a name alone does not say the page changed)."""
    text_appears(page, "· session", timeout)


def poses_since(page: Any, t_ms: float, link: str | None = None) -> int:
    return sum(1 for t, _n in chromium.pose_batches(page) if t > t_ms)


def dismiss_notifications(page: Any) -> None:
    """Close the notifications stacked top left (they cover what is under them, as for a user), and
    wait until they are gone: a closing one slides out to the left over the panel's top buttons for a
    moment, and a click meanwhile lands on it (the Documentation button's click once did)."""
    notices = page.locator(".mantine-Notification-root")
    end = time.monotonic() + 15.0
    while notices.count() and time.monotonic() < end:
        for button in page.locator(".mantine-Notification-closeButton").all():
            try:
                button.click(timeout=2000)
            except Exception:
                pass  # gone meanwhile
        try:
            notices.first.wait_for(state="detached", timeout=3000)
        except Exception:
            pass  # still there: closed again above
    assert not notices.count(), f"notifications not closed: {notices.all_inner_texts()}"


open_components = chromium.open_components


def now_ms(page: Any) -> float:
    return float(page.evaluate("() => performance.now()"))


@contextmanager
def logs_on_failure(mesh: Mesh, *names: str) -> Iterator[None]:
    """Print the nodes' logs when the test fails (pytest shows them with the failure)."""
    try:
        yield
    except BaseException:
        for name in names:
            print(f"----- {name} log -----\n{mesh.log(name)}")
        raise


def test_use_case_in_the_browser(mesh: Mesh, browser: Any) -> None:
    """Steps 1-11 of §2.2 through the UI, with the 3D arm and the plots checked as the page got them."""
    with logs_on_failure(mesh, "viewer", "proxy", "simulator", "recorder"):
        use_case(mesh, browser)


def use_case(mesh: Mesh, browser: Any) -> None:
    service = start_service(mesh)
    recorder = importlib.util.find_spec("simecs.nodes.recorder") is not None
    if recorder:
        mesh.start("recorder", "--dir", str(mesh.folder / "recordings"))
    url = start_viewer(mesh)
    client = service.client
    context = browser.new_context(viewport=chromium.VIEWPORT, accept_downloads=True)
    page = new_page(context, url)

    # 1. the models window: the library with summaries; load the Spider
    text_appears(page, "7 joints")
    page.get_by_role("button", name=SPIDER).click()
    model_shown(page)
    sid = wait_until(lambda: next(iter(sessions_of(client)), None), timeout=20, what="a session")
    session = client.session(USER, sid)
    assert session.snapshot().model_id == "spider"

    # 2. parameters in place: a valid length, applied, reshapes the arm; an invalid mass is refused
    #    beside the field before anything is sent, and discarded
    open_components(page)
    page.get_by_role("button", name="link2 (3)").click()
    t = now_ms(page)
    chromium.set_field(page, page.get_by_label("length [m]"), "0.5")
    page.get_by_role("button", name="Apply edits").click()
    wait_until(lambda: session.snapshot().values["link2.length"] == 0.5, timeout=10, what="length stored")
    wait_until(lambda: poses_since(page, t) > 0, timeout=10, what="the 3D arm reshaped")
    chromium.set_field(page, page.get_by_label("mass [kg]"), "9999")
    text_appears(page, "outside [0, 500] kg")
    assert page.get_by_role("button", name="Apply edits").is_disabled()
    page.get_by_role("button", name="Discard edits").click()
    wait_until(lambda: page.get_by_label("mass [kg]").input_value() == "6", timeout=10, what="mass back")
    assert session.snapshot().values["link2.mass"] == 6.0

    # 2. documentation: hypertext, follow a link and come back
    dismiss_notifications(page)
    page.get_by_role("button", name="Documentation").click()
    page.get_by_role("button", name="→ Joint drive").click()
    text_appears(page, "Sub-components")
    page.get_by_role("button", name="◀ Back").click()
    page.get_by_role("button", name="Close", exact=True).click()

    # 3. variables: choose what to stream and open a plot
    plot_joint1_q(page)

    # 4. initial pose with the sliders: the 3D arm follows at once; the server gets it
    page.get_by_role("button", name="Initialise").click()
    t = now_ms(page)
    chromium.set_field(page, chromium.slider_input(page, "joint2 [deg]"), "20")
    wait_until(lambda: poses_since(page, t) > 0, timeout=10, what="the 3D arm following the slider")
    wait_until(
        lambda: abs(session.snapshot().initial[1] - math.radians(20)) < 1e-3, timeout=10, what="initial pose"
    )
    page.get_by_role("tab", name="Joint path").click()  # the pendant's tab beside the initial pose

    # 5. a 2-node joint path in the teach pendant
    page.get_by_role("button", name="Teach").click()
    text_appears(page, "▶1")  # the table grows under the buttons: click again once it has
    page.get_by_role("button", name="Teach").click()
    chromium.set_field(page, chromium.slider_input(page, "joint1 target [deg]"), "30")
    text_appears(page, "▶2")

    # 6. simulation settings: a 2 s run
    page.get_by_role("button", name="Settings").click()
    chromium.set_field(page, page.get_by_label("Stop time [s]"), "2")
    page.get_by_role("button", name="Apply settings").click()
    wait_until(lambda: session.snapshot().settings.stop_time == 2.0, timeout=10, what="settings stored")

    # 7-8. run: live plot data and the animated arm reach the page; progress reaches 100 %
    window = float(chromium.labelled_input(page, "Live window [s]").input_value())
    chromium.sample_time_axis(page, "joint1.q", every_ms=100)
    t = now_ms(page)
    page.get_by_role("button", name="Run", exact=True).click()
    text_appears(page, "finished run r1", timeout=120)
    text_appears(page, "100 %")
    # the live plot's time axis showed the run's own span (2 s), never -10..189 s (issue 32, 1)
    samples = chromium.time_axis_samples(page)
    clicked = max(tt for tt, label in chromium.clicks(page) if label == "Run")
    shown = chromium.run_axis(samples, "run r1", clicked)
    # sampled every 100 ms in the page; a page busy drawing (software WebGL) samples less often
    assert shown, f"the chart was never seen while the run went on: {samples}"
    wide = [
        (round(a.x_min, 3), round(a.x_max, 3)) for a in shown if a.x_max - a.x_min > 1.2 * min(window, 2.0)
    ]
    assert not wide, f"the live time axis spans more than the run: {wide}"
    assert min(a.x_min for a in samples if a.run == "run r1" and a.t_ms >= clicked) >= 0.0
    cmd = session.snapshot().command
    assert cmd is not None and len(cmd.nodes) == 2
    assert (
        abs(cmd.nodes[1].q[0] - math.radians(30)) < 1e-3 and abs(cmd.nodes[0].q[1] - math.radians(20)) < 1e-3
    )
    assert poses_since(page, t) >= 10, "the 3D arm did not animate from the live stream"
    live_points = [n for tt, n in chromium.plot_points(page) if tt > t]
    assert live_points and max(live_points) >= 10, f"the live plot got no data: {live_points[-5:]}"

    # 9-10. full-resolution transient on request
    page.get_by_role("tab", name="Results").click()
    page.get_by_role("button", name="Full resolution").first.click()
    text_appears(page, "r1 full res")
    # The chart in sight once the browser drew the full-resolution data (the message comes first; the
    # chart drawn anew for its new scales after): where to drag on it.
    box = wait_until(lambda: page.evaluate(FULL_CHART_JS), timeout=20, what="the full-resolution chart drawn")
    # a drag across the chart zooms in the browser; Reset zoom shows the whole transient again
    y = box["y"] + box["height"] / 2
    page.mouse.move(box["x"] + 0.3 * box["width"], y)
    page.mouse.down()
    page.mouse.move(box["x"] + 0.6 * box["width"], y, steps=8)
    page.mouse.up()
    zoomed = wait_until(lambda: chart_spans(page)[0] < 0.5, what="a drag-zoom")
    page.get_by_role("button", name="Reset zoom").first.click()
    wait_until(lambda: chart_spans(page)[0] > 0.99, what=f"the zoom reset (was {zoomed})")

    # 11. save the results: CSV of the chosen variables, and the MCAP recording when a recorder runs
    with page.expect_download(timeout=30_000) as dl:
        page.get_by_role("button", name="CSV", exact=True).click()
    csv_path = ARTIFACTS / "viewer_use_case.csv"
    ARTIFACTS.mkdir(exist_ok=True)
    dl.value.save_as(csv_path)
    lines = [ln for ln in csv_path.read_text().splitlines() if not ln.startswith("#")]
    names, units = lines[0].split(","), lines[1].split(",")
    assert names[0] == "time" and units[0] == "s" and units[names.index("joint1.q")] == "rad"
    assert len(lines) - 2 == 1001  # 2 s at 2 ms, both ends
    if recorder:
        with page.expect_download(timeout=60_000) as dl:
            page.get_by_role("button", name="MCAP", exact=True).click()
        mcap = ARTIFACTS / "viewer_use_case.mcap"
        dl.value.save_as(mcap)
        assert mcap.read_bytes()[:8] == b"\x89MCAP0\r\n"
    page.screenshot(path=str(ARTIFACTS / "viewer_use_case.png"))

    # 11. replay: the run's recording played back as a new run of the same session (no other session)
    if recorder:
        dismiss_notifications(page)
        t = now_ms(page)
        page.get_by_role("button", name="Replay", exact=True).click()
        text_appears(page, "finished replay r2 of", timeout=120)
        assert poses_since(page, t) >= 10, "the 3D arm did not follow the replay"
        runs = session.runs()
        assert [r.run_id for r in runs] == ["r1", "r2"]
        assert runs[1].recording == keys.recording_name(sid, "r1") and runs[1].phase == "finished"
        assert sessions_of(client) == {sid}
        # upload: a recording kept earlier goes back to the server and replays as run r3
        dismiss_notifications(page)
        page.locator("input[type=file]").first.set_input_files(str(mcap))
        text_appears(page, "finished replay r3 of", timeout=120)
        assert session.runs()[-1].recording == "viewer_use_case"
        page.screenshot(path=str(ARTIFACTS / "viewer_replay.png"))

    # the session and its values come back after a reload
    page.reload()
    text_appears(page, f"session {sid[:8]}")
    open_components(page)
    page.get_by_role("button", name="link2 (3)").click()
    assert page.get_by_label("length [m] •").input_value() == "0.5"
    text_appears(page, "▶1")
    assert sessions_of(client) == {sid}
    context.close()


def test_a_value_typed_key_by_key_is_stored_exactly_when_applied(mesh: Mesh, browser: Any) -> None:
    """Issue 12, 0: typing `0.00008` into J_rotor one key at a time sends nothing half-typed (no "0",
    no clobbered field); Apply stores exactly the typed value, and the field shows the stored one."""
    with logs_on_failure(mesh, "viewer", "proxy"):
        page, context, session = spider_tab(mesh, browser)
        search = text_field(page, "Find parameter")
        # the results of a search come from many components: each is labelled with its own (issue 32, 5)
        search.fill("kp_pos")
        text_appears(page, "8 parameters match")  # the 7 joints' and the task-space controller's
        labels = [f"joint{k}.ctrl.kp_pos [1/s]" for k in range(1, 8)]
        wait_until(lambda: all(page.get_by_label(lb, exact=True).count() == 1 for lb in labels), what="the 7")
        search.fill("joint3 J_rotor")
        # the label gains a mark as the value is typed (✎) and applied (•): found by its start
        field = page.get_by_label(re.compile(r"^joint3\.motor\.J_rotor \[kg\*m\^2\]"))
        field.wait_for(timeout=20_000)
        field.click()
        field.press("Control+a")
        field.press("Delete")
        field.press_sequentially("0.00008", delay=200)
        time.sleep(1.0)
        assert session.snapshot().values["joint3.motor.J_rotor"] == 6e-5  # nothing sent while typing
        assert field.input_value() == "0.00008"  # and nothing overwrote what was typed
        page.get_by_role("button", name="Apply edits").click()
        wait_until(
            lambda: session.snapshot().values["joint3.motor.J_rotor"] == 8e-5, timeout=10, what="8e-5 stored"
        )
        applied = "joint3.motor.J_rotor [kg*m^2] •"
        wait_until(lambda: page.get_by_label(applied, exact=True).count() == 1, what="applied")
        assert field.input_value() == "0.00008"
        page.screenshot(path=str(ARTIFACTS / "viewer_param_applied.png"))
        # Undo puts back what the change replaced, on the server and in the field
        page.get_by_role("button", name="Undo last change").click()
        wait_until(
            lambda: session.snapshot().values["joint3.motor.J_rotor"] == 6e-5, timeout=10, what="6e-5 back"
        )
        wait_until(lambda: float(field.input_value()) == 6e-5, timeout=10, what="the field back to 6e-5")
        context.close()


PANDA = "Load Franka Emika Panda (joint-independent control)"


def test_an_imported_model_is_drawn_with_its_meshes(mesh: Mesh, browser: Any) -> None:
    """The Panda's links reach the browser as its URDF meshes: every mesh shape of its description,
    byte for byte what the proxy serves, and the page draws them without an error."""
    with logs_on_failure(mesh, "viewer", "proxy"):
        service, url = service_and_viewer(mesh)
        client = service.client
        desc = client.describe("panda")
        names = desc.mesh_names()
        sizes = sorted(len(client.model_mesh("panda", name)) for name in names)
        assert len(names) >= 8
        context = browser.new_context(viewport=chromium.VIEWPORT)
        page = new_page(context, url)
        errors: list[str] = []
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.get_by_role("button", name=PANDA).click()
        text_appears(page, "Franka Emika Panda (joint-independent control)")

        def all_meshes() -> list[tuple[str, int]] | None:
            got = chromium.glbs(page)
            return got if len(got) >= len(names) else None

        got = wait_until(all_meshes, timeout=60, what="the Panda's meshes in the browser")
        assert sorted(size for _name, size in got) == sizes
        assert all(name.startswith(("/arm/", "/env/")) for name, _size in got)
        time.sleep(1.0)  # let the page parse and draw them
        page.screenshot(path=str(ARTIFACTS / "viewer_panda_meshes.png"))
        assert not [e for e in errors if "gltf" in e.lower() or "glb" in e.lower()], errors
        context.close()


def test_two_tabs_get_independent_sessions(mesh: Mesh, browser: Any) -> None:
    with logs_on_failure(mesh, "viewer", "proxy"):
        two_tabs(mesh, browser)


def two_tabs(mesh: Mesh, browser: Any) -> None:
    service, url = service_and_viewer(mesh)
    client = service.client
    context = browser.new_context(viewport=chromium.VIEWPORT)  # one browser, one user, two tabs
    a = new_page(context, url)
    a.get_by_role("button", name=SPIDER).click()
    model_shown(a)
    sid_a = wait_until(lambda: next(iter(sessions_of(client)), None), timeout=20, what="session A")
    b = new_page(context, url)
    b.get_by_role("button", name=SPIDER).click()
    sid_b = wait_until(lambda: next(iter(sessions_of(client) - {sid_a}), None), timeout=20, what="session B")
    assert sid_a != sid_b

    open_components(a)
    a.get_by_role("button", name="link3 (3)").click()
    chromium.set_field(a, a.get_by_label("length [m]"), "0.9")
    a.get_by_role("button", name="Apply edits").click()
    length_a = lambda: client.session(USER, sid_a).snapshot().values["link3.length"]  # noqa: E731
    wait_until(lambda: length_a() == 0.9, timeout=10, what="A")
    assert client.session(USER, sid_b).snapshot().values["link3.length"] == 0.7

    # each tab keeps its own session over a reload (the other tab is still open)
    b.reload()
    text_appears(b, f"session {sid_b[:8]}")
    open_components(b)
    b.get_by_role("button", name="link3 (3)").click()
    assert b.get_by_label("length [m]", exact=True).input_value() == "0.7"
    a.reload()
    text_appears(a, f"session {sid_a[:8]}")
    assert sessions_of(client) == {sid_a, sid_b}
    b.screenshot(path=str(ARTIFACTS / "viewer_two_tabs.png"))
    context.close()
    time.sleep(0.2)


def text_field(page: Any, label: str) -> Any:
    """A viser text input by its label (viser's label is not tied to its text input)."""
    return page.locator(f"div:has(> div > p > label:text-is('{label}')) input").first


def test_a_secured_viewer_asks_for_the_password_and_acts_as_that_user(secured: Secured, browser: Any) -> None:
    """On a secured mesh the page does nothing before the password; then everything the tab does is
    done as that user (the hub's rules apply), and the password is masked on screen."""
    mesh = secured.mesh
    with logs_on_failure(mesh, "viewer", "proxy"):
        url = start_viewer(mesh, "--mesh-config", secured.node_config)
        page = new_page(browser.new_context(viewport=chromium.VIEWPORT), url)
        text_appears(page, "log in with your password")
        user = text_field(page, "User")
        chromium.set_field(page, user, "ann")
        password = text_field(page, "Password")
        assert password.evaluate("e => getComputedStyle(e).webkitTextSecurity") == "disc"
        assert user.evaluate("e => getComputedStyle(e).webkitTextSecurity") == "none"
        password.fill("not-her-password")
        page.get_by_role("button", name="Log in").click()
        text_appears(page, "did not let ann in")
        password.fill(secured.passwords["ann"])
        page.get_by_role("button", name="Log in").click()
        text_appears(page, "Logged in")
        page.get_by_role("button", name=SPIDER).click()
        model_shown(page)
        ann = secured.login("ann")
        sessions = wait_until(lambda: ann.list_sessions("ann"), timeout=20, what="ann's session")
        assert len(sessions) == 1 and secured.login("bob").list_sessions("bob") == []
