"""Driving the viewer in a real browser (Debian chromium through Playwright): shared by the browser
tests and `simecs bench viewer`.

viser's websocket lives in a Web Worker, out of Playwright's sight, so `PROBE_JS`
wraps the page's `Worker` before viser creates it and timestamps every message batch that moves a
link of the 3D arm: those are the pose updates the tab actually received. It also notes every
binary glTF mesh (an imported model's links) the tab received, the batches that move the goal
ghost (`ghosts`: the translucent arm drawn where a node puts it), and keeps the worker and each
transform gizmo's owner so `drag_gizmo` can send what a drag of that gizmo sends. It notes when the
page's websocket connects and closes (wall-clock ms, `links`) and when the document was loaded (a
reload starts a new record).

Playwright makes every page count as focused (`document.hasFocus()`), which a real browser does for
one page per window only: `real_focus` turns that off for a page, so a page in the background of its
window behaves as a user's would.
"""

from __future__ import annotations

import glob
import os
import re
import shutil
from typing import Any, NamedTuple

CHROMIUM = os.environ.get("SIMECS_CHROMIUM", "/usr/bin/chromium")
# WebGL on Mesa's llvmpipe (through ANGLE's EGL backend), not chromium's own SwiftShader: the viewer's
# frames cost the browser a third less CPU there (measured: the layout walk 64 -> 51 s alone, its GPU
# process 41 -> 34 CPU s), and a test run is mostly browsers drawing on a machine without a GPU.
WEBGL_ARGS = ["--use-gl=angle", "--use-angle=gl-egl", "--ignore-gpu-blocklist"]
# The page composited in software (WebGL still drawn on llvmpipe): GL compositing through llvmpipe
# costs the browser more than it saves (measured: the camera tests' browsers 25.0 -> 21.0 CPU s, the
# direct-input and jog tests' 55.0 -> 48.8; rasterizing in software too cost more, 53.2).
SOFTWARE_COMPOSITING = ["--disable-gpu-compositing"]
CHROMIUM_ARGS = [
    "--no-sandbox",
    *WEBGL_ARGS,
    *SOFTWARE_COMPOSITING,
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWPORT = {"width": 1600, "height": 1000}

PROBE_JS = """
(() => {
  const rec = window.__simecs = {batches: [], ghosts: [], clicks: [], plots: [], glbs: [], sent: [],
                                 links: [], gizmos: {}, gizmoTurns: {}, worker: null, loaded: Date.now()};
  const Base = window.Worker;
  if (!Base) return;
  class Probed extends Base {
    postMessage(data, ...rest) {  // what the page sends: a widget's new value leaves here
      const m = data && data.type === 'send' ? data.message : null;
      if (m && m.type === 'GuiUpdateMessage') rec.sent.push([performance.now(), m.uuid]);
      return super.postMessage(data, ...rest);
    }
    constructor(...args) {
      super(...args);
      rec.worker = this;  // what sends the page's messages: a drag is replayed through it
      this.addEventListener('message', (e) => {
        const d = e.data;
        if (d && (d.type === 'connected' || d.type === 'closed')) rec.links.push([Date.now(), d.type]);
        if (!d || d.type !== 'message_batch' || !d.messages) return;
        let poses = 0, ghostPoses = 0;
        for (const m of d.messages) {
          if ((m.type === 'SetPositionMessage' || m.type === 'SetOrientationMessage')
              && typeof m.name === 'string' && m.name.startsWith('/arm/')) poses++;
          else if ((m.type === 'SetPositionMessage' || m.type === 'SetOrientationMessage')
              && typeof m.name === 'string' && m.name.startsWith('/ghost/')) ghostPoses++;
          else if (m.type === 'TransformControlsMessage') {
            rec.gizmos[m.name] = m.owner || '';
            if (m.wxyz) rec.gizmoTurns[m.name] = Array.from(m.wxyz);
          }
          else if (m.type === 'SetOrientationMessage' && m.name in rec.gizmos) {
            rec.gizmoTurns[m.name] = Array.from(m.wxyz);
          }
          else if (m.type === 'GlbMessage' && m.props && m.props.glb_data) {
            rec.glbs.push([m.name, m.props.glb_data.byteLength || m.props.glb_data.length || 0]);
          }
          else if (m.type === 'GuiUpdateMessage' && m.updates && Array.isArray(m.updates.data)) {
            const x = m.updates.data[0];
            rec.plots.push([performance.now(), x ? (x.length || x.byteLength / 8 || 0) : 0]);
          }
        }
        if (poses) rec.batches.push([performance.now(), poses]);
        if (ghostPoses) rec.ghosts.push([performance.now(), ghostPoses]);
      });
    }
  }
  window.Worker = Probed;
  document.addEventListener('click', (e) => {
    const b = e.target && e.target.closest ? e.target.closest('button') : null;
    if (b) rec.clicks.push([performance.now(), b.textContent.trim()]);
  }, true);
  // Where each press and release landed (the last 40): a click the page never saw shows here whether
  // the press and the release met different elements (something moved between them).
  rec.pointer = [];
  for (const type of ['pointerdown', 'pointerup']) {
    document.addEventListener(type, (e) => {
      const t = e.target instanceof Element ? e.target : null;
      const what = t ? t.tagName.toLowerCase() + ' "' + (t.textContent || '').trim().slice(0, 24) + '"' : '?';
      const at = [Math.round(e.clientX), Math.round(e.clientY)];
      rec.pointer.push([Math.round(performance.now()), type, ...at, what]);
      if (rec.pointer.length > 40) rec.pointer.shift();
    }, true);
  }
})();
"""


def browser_missing() -> str:
    """Why a real-browser run cannot happen here ('' when it can)."""
    if not (os.path.isfile(CHROMIUM) or shutil.which(CHROMIUM)):
        return f"no chromium at {CHROMIUM} (Debian: apt-get install chromium; .ci/run installs it)"
    if not glob.glob("/usr/lib/*/dri/swrast_dri.so") or not glob.glob("/usr/lib/*/libEGL_mesa.so.0"):
        return "no Mesa for chromium's WebGL (Debian: apt-get install libegl-mesa0 libgl1-mesa-dri)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright Python package is not installed (pip install -e '.[test]')"
    return ""


def launch(pw: Any) -> Any:
    """Headless Debian chromium with the flags that work on these machines (never `playwright install`)."""
    return pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)


def slider_input(page: Any, label: str) -> Any:
    """The number box of the viser slider labelled `label` (typing there moves the slider)."""
    return page.locator(
        f"xpath=//label[normalize-space(text())='{label}']/ancestor::div[contains(@class,'mantine-Flex-root')][1]"
        "//input[contains(@class,'NumberInput-input')]"
    )


def set_field(page: Any, locator: Any, value: str) -> None:
    """Type a value into a viser input as a user does: select what it holds, type the new text key by
    key, Enter. Playwright's `fill` puts the whole text in at once, and viser's number boxes
    (react-number-format) miss such a change once the server has set their value since they were
    last typed in: the box shows the server's value again and nothing is sent."""
    locator.focus()
    locator.press("Control+a")
    if value:
        locator.press_sequentially(value)  # the first key replaces the selected text
    else:
        locator.press("Backspace")
    locator.press("Enter")


def labelled_input(page: Any, label: str) -> Any:
    """The visible input of the viser field labelled `label` (text, number or dropdown): a text
    input's label is not tied to it, and viser breaks a label after each '_' with a <wbr>."""
    return (
        page.locator(
            f"xpath=//label[normalize-space(.)='{label}']/ancestor::div[contains(@class,'mantine-Flex-root')][1]"
            "//input"
        )
        .locator("visible=true")
        .first
    )


def type_then_click_at_once(page: Any, fields: list[tuple[str, str]], button: Any) -> None:
    """Type each (label, text) into its field, then click `button` (a locator), all in one go on
    the page (no wait between them: a script's or a fast hand's pace)."""
    handles = [labelled_input(page, label).element_handle() for label, _ in fields]
    page.evaluate(
        """([inputs, texts, button]) => {
  const setText = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
  inputs.forEach((input, k) => {
    setText.call(input, texts[k]);
    input.dispatchEvent(new Event('input', {bubbles: true}));
  });
  button.click();
}""",
        [handles, [text for _, text in fields], button.element_handle()],
    )


def type_into(page: Any, label: str, value: str) -> None:
    """Type `value` into the visible viser field labelled `label` and commit it (Enter)."""
    set_field(page, labelled_input(page, label), value)


def pick_option(page: Any, label: str, option: str) -> None:
    """Choose `option` in the visible viser dropdown labelled `label`, as a user does."""
    labelled_input(page, label).click()
    page.get_by_role("option", name=option, exact=True).click()


def vector_input(page: Any, label: str, index: int) -> Any:
    """Box `index` (0: x) of the viser vector input labelled `label`."""
    return page.locator(
        f"xpath=//label[normalize-space(text())='{label}']/ancestor::div[contains(@class,'mantine-Flex-root')][1]"
        "//input"
    ).nth(index)


def drag_gizmo(page: Any, name: str, position: Any, wxyz: Any = None) -> float:
    """Move the transform gizmo `name` as a user's drag does: the page sends the messages its gizmo
    sends while dragged (start, a pose, end), turned to `wxyz` or, by default, as it is (a drag along
    its arrows). Returns the page's time (ms) of the pose message."""
    return float(
        page.evaluate(
            """([name, position, wxyz]) => {
  const rec = window.__simecs;
  const owner = rec.gizmos[name];
  if (owner === undefined || !rec.worker) throw new Error('no gizmo ' + name + ' on the page');
  wxyz = wxyz || rec.gizmoTurns[name] || [1, 0, 0, 0];
  const send = (message) => rec.worker.postMessage({type: 'send', message});
  send({type: 'TransformControlsDragStartMessage', name, owner});
  const t = performance.now();
  send({type: 'TransformControlsUpdateMessage', name, wxyz, position, owner});
  send({type: 'TransformControlsDragEndMessage', name, owner});
  return t;
}""",
            [name, list(position), list(wxyz) if wxyz is not None else None],
        )
    )


def pose_batches(page: Any) -> list[tuple[float, int]]:
    """(time in ms, pose messages) of every batch that moved the arm so far."""
    return [
        (float(t), int(n)) for t, n in page.evaluate("() => window.__simecs ? window.__simecs.batches : []")
    ]


def ghost_batches(page: Any) -> list[tuple[float, int]]:
    """(time in ms, pose messages) of every batch that moved the goal ghost (the translucent arm
    drawn where a node puts it) so far."""
    return [
        (float(t), int(n)) for t, n in page.evaluate("() => window.__simecs ? window.__simecs.ghosts : []")
    ]


def sent_updates(page: Any) -> list[float]:
    """The page's time (ms) of every widget value it sent to the viewer."""
    return [float(t) for t, _uuid in page.evaluate("() => window.__simecs ? window.__simecs.sent : []")]


def glbs(page: Any) -> list[tuple[str, int]]:
    """(scene node name, bytes) of every binary glTF mesh the tab received."""
    return [(str(n), int(b)) for n, b in page.evaluate("() => (window.__simecs || {glbs: []}).glbs")]


def plot_points(page: Any) -> list[tuple[float, int]]:
    """(time in ms, points) of every plot redraw the page received."""
    return [
        (float(t), int(n)) for t, n in page.evaluate("() => window.__simecs ? window.__simecs.plots : []")
    ]


def clicks(page: Any) -> list[tuple[float, str]]:
    return [
        (float(t), str(s)) for t, s in page.evaluate("() => window.__simecs ? window.__simecs.clicks : []")
    ]


def status_text(page: Any) -> str:
    """The toolbar's one-line run status (phase, time, progress, RTF)."""
    loc = page.locator("p, div").filter(has_text="RTF").last
    return loc.inner_text() if loc.count() else ""


def real_focus(page: Any) -> None:
    """Let `page` have the focus only when it really has it (the front page of its window), as in a
    user's browser: Playwright otherwise tells every page it is focused."""
    page.context.new_cdp_session(page).send("Emulation.setFocusEmulationEnabled", {"enabled": False})


def has_focus(page: Any) -> bool:
    """Whether the page has the focus, as the browser says (not as a script in the page may say)."""
    return bool(page.evaluate("() => Document.prototype.hasFocus.call(document)"))


def links(page: Any) -> list[tuple[float, str]]:
    """(wall-clock ms, 'connected' | 'closed') of every change of the page's websocket so far."""
    rows = page.evaluate("() => window.__simecs ? window.__simecs.links : []")
    return [(float(t), str(k)) for t, k in rows]


def loaded_at(page: Any) -> float:
    """When the page's document was loaded (wall-clock ms): it changes only with a reload."""
    return float(page.evaluate("() => window.__simecs ? window.__simecs.loaded : 0"))


SHOWN_SESSION_JS = r"""() => {
  const code = Array.from(document.querySelectorAll('p code')).find((c) =>
    /^\S{8}…$/.test(c.textContent || '') &&
    (c.parentElement.textContent || '').includes('session ' + c.textContent));
  return code ? code.textContent.slice(0, 8) : '';
}"""


def shown_session(page: Any) -> str:
    """The first 8 characters of the session the page's header names ('' when no model page)."""
    return str(page.evaluate(SHOWN_SESSION_JS))


WATCH_SESSION_JS = r"""(prefix) => {
  const w = window.__simecsShown = window.__simecsShown ||
    {seen: [], ids: new WeakMap(), next: 0, last: -2, timer: null};
  w.prefix = prefix;
  if (w.timer) return;
  const look = () => {
    const code = Array.from(document.querySelectorAll('p code')).find((c) => c.isConnected &&
      (c.textContent || '').startsWith(w.prefix) &&
      (c.parentElement.textContent || '').includes('session ' + w.prefix));
    let id = -1;
    if (code) {
      if (!w.ids.has(code)) w.ids.set(code, w.next++);
      id = w.ids.get(code);
    }
    if (id !== w.last) { w.seen.push([Date.now(), id]); w.last = id; }
  };
  look();
  w.timer = setInterval(look, 50);
}"""


def watch_session(page: Any, prefix: str) -> None:
    """Note, every 50 ms in the page, which element shows the header "session <prefix>…": each new
    element (a page built anew, as after a reconnect) gets the next number, -1 when none shows it."""
    page.evaluate(WATCH_SESSION_JS, prefix)


def session_shown(page: Any) -> list[tuple[float, int]]:
    """(wall-clock ms, element number or -1) at each change `watch_session` saw."""
    return [
        (float(t), int(k))
        for t, k in page.evaluate("() => window.__simecsShown ? window.__simecsShown.seen : []")
    ]


def shown_anew_after(page: Any, element: int) -> float | None:
    """When (wall-clock ms) the page first showed its session in an element newer than `element`
    (see `watch_session`): the page was built anew and reopened that session; None: not yet."""
    return next((t for t, k in session_shown(page) if k > element), None)


AXIS_JS = """([variable, titlePattern, everyMs]) => {
  const a = window.__simecsAxis = {samples: [], timer: null};
  const title = new RegExp(titlePattern);
  a.timer = setInterval(() => {
    const charts = Object.values((window.__viserTestpoints || {}).uplots || {});
    const found = document.body.textContent.match(title);
    for (const tp of charts) {
      const u = tp.chart, xs = u.data && u.data[0];
      if (!(u.series || []).some((s) => (s.label || '').startsWith(variable))) continue;
      if (u.scales.x.min == null || u.scales.x.max == null || !xs || !xs.length) continue;
      a.samples.push([performance.now(), u.scales.x.min, u.scales.x.max, xs[0], xs[xs.length - 1],
                      window.__simecsPhase || '', found ? found[1] : '']);
    }
  }, everyMs);
}"""


def sample_time_axis(page: Any, variable: str, every_ms: float = 150.0) -> None:
    """Start noting, every `every_ms` in the page, the time axis shown by the chart of `variable`:
    (page ms, shown x min, x max, first and last time of its data, the session's phase, the run its
    title says it shows live, e.g. "run r3"). Read with `time_axis_samples`; a new call starts over."""
    page.evaluate("() => { if (window.__simecsAxis) clearInterval(window.__simecsAxis.timer); }")
    title = rf"Plot \d+: {re.escape(variable)}[^·]*· (\S+ r\d+) live"  # the chart's folder title
    page.evaluate(AXIS_JS, [variable, title, every_ms])


class AxisSample(NamedTuple):
    """The time axis a chart showed at one instant (`sample_time_axis`)."""

    t_ms: float  # the page's clock (performance.now(), as `clicks`)
    x_min: float  # the shown time axis
    x_max: float
    data_first: float  # the first and last time of the chart's data
    data_last: float
    phase: str  # the session's phase, as the page was told it
    run: str  # the run the chart's title says it shows live ("run r3"; '' when none)


def time_axis_samples(page: Any, stop: bool = True) -> list[AxisSample]:
    """What `sample_time_axis` noted so far (and stop noting, with `stop`)."""
    rows = page.evaluate(
        "(stop) => { const a = window.__simecsAxis; if (!a) return []; if (stop) clearInterval(a.timer);"
        " return a.samples; }",
        stop,
    )
    return [
        AxisSample(float(t), float(lo), float(hi), float(x0), float(x1), str(ph), str(run))
        for t, lo, hi, x0, x1, ph, run in rows
    ]


def open_components(page: Any) -> None:
    """Unfold the component tree of the visible tab (a pick folds it under the picked name)."""
    page.get_by_text(re.compile(r"^Components · ")).locator("visible=true").first.click()


def open_plot(page: Any, component: str, owner: str, variable: str) -> None:
    """Open a plot from the Variables tab as a user does: unfold Components, pick the tree node
    `component` (e.g. "joint1 (14)"), then `owner` (e.g. "joint1 (2 own)"), then "Plot <variable>"."""
    page.get_by_role("tab", name="Variables").click()
    open_components(page)
    page.get_by_text(component, exact=True).click()
    page.get_by_role("button", name=owner).click()
    page.get_by_role("button", name=f"Plot {variable}", exact=True).click()


def run_axis(
    samples: list[AxisSample], run: str, clicked_ms: float, slack_s: float = 0.5
) -> list[AxisSample]:
    """The samples that show `run` (e.g. "run r3") while it goes on: the chart's title names it, the
    session runs, and the chart's data are the run's. A paced run's newest sample is at most the
    time since Run was clicked (`clicked_ms`, the page's clock): data beyond that are the previous
    run's (or the empty window's ends), still drawn until the chart's next redraw."""
    return [
        a
        for a in samples
        if a.run == run
        and a.phase == "running"
        and a.t_ms >= clicked_ms
        and a.data_last <= (a.t_ms - clicked_ms) / 1000.0 + slack_s
    ]


def set_stop_time(page: Any, stop_time: float) -> None:
    """Type the run's stop time into the Settings window and apply it, as a user does; returns once
    the window has closed (it closes when the server stored the settings)."""
    page.get_by_role("button", name="Settings", exact=True).click()
    set_field(page, page.get_by_label("Stop time [s]"), f"{stop_time:g}")
    page.get_by_role("button", name="Apply settings").click()
    page.get_by_label("Stop time [s]").wait_for(state="hidden", timeout=20_000)
