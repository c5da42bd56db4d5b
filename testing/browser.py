"""Driving the viewer in a real browser (Debian chromium through Playwright): shared by the browser
tests and `simecs bench viewer`.

viser's websocket lives in a Web Worker, out of Playwright's sight (STACK-NOTES), so `PROBE_JS`
wraps the page's `Worker` before viser creates it and timestamps every message batch that moves a
link of the 3D arm: those are the pose updates the tab actually received. It also notes every
binary glTF mesh (an imported model's links) the tab received, and keeps the worker and each
transform gizmo's owner so `drag_gizmo` can send what a drag of that gizmo sends.
"""

from __future__ import annotations

import os
import shutil
from typing import Any

CHROMIUM = os.environ.get("SIMECS_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWPORT = {"width": 1600, "height": 1000}

PROBE_JS = """
(() => {
  const rec = window.__simecs = {batches: [], clicks: [], plots: [], glbs: [], sent: [],
                                 gizmos: {}, gizmoTurns: {}, worker: null};
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
        if (!d || d.type !== 'message_batch' || !d.messages) return;
        let poses = 0;
        for (const m of d.messages) {
          if ((m.type === 'SetPositionMessage' || m.type === 'SetOrientationMessage')
              && typeof m.name === 'string' && m.name.startsWith('/arm/')) poses++;
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
      });
    }
  }
  window.Worker = Probed;
  document.addEventListener('click', (e) => {
    const b = e.target && e.target.closest ? e.target.closest('button') : null;
    if (b) rec.clicks.push([performance.now(), b.textContent.trim()]);
  }, true);
})();
"""


def browser_missing() -> str:
    """Why a real-browser run cannot happen here ('' when it can)."""
    if not (os.path.isfile(CHROMIUM) or shutil.which(CHROMIUM)):
        return f"no chromium at {CHROMIUM} (Debian: apt-get install chromium; .ci/run installs it)"
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
    """Type a value into a viser input and commit it as a user would (Enter)."""
    locator.fill(value)
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
