"""What the viewer needs from the browser tab itself: which session it had before a reload, the user
name kept on this browser, the size of its viewport, notifications, and the page title.

viser keeps no per-tab state across a reload (a reloaded page is a new client), so the tab keeps it:
the session id goes into the tab's `sessionStorage` (one value per tab, kept by a reload, not shared
with other tabs), the user name into `localStorage` (shared by the tabs of one browser). viser only
exposes `localStorage` to Python, so a small script copies the sessionStorage value into a
localStorage key private to this connection, which Python then reads.
"""

from __future__ import annotations

import json
import logging
import re
import secrets
import time
from dataclasses import dataclass, field
from typing import Any

from viser import _messages as viser_messages

log = logging.getLogger("simecs.viewer")

SESSION_KEY = "simecs.session"  # sessionStorage: this tab's session id
VIEW_KEY = "simecs.view"  # sessionStorage: what the tab showed of it (camera, plots; `remember_view`)
USER_KEY = "simecs.user"  # localStorage (via viser): the user name on this browser


@dataclass
class TabMemory:
    """What a tab remembered: its session id (may be empty) and the browser's user name."""

    session: str = ""
    user: str = ""
    answered: bool = False  # False: the browser did not answer (script blocked, storage disabled)
    width: int = 0  # the page's viewport in CSS pixels (0: not told)
    height: int = 0
    view: dict[str, Any] = field(default_factory=dict)  # what remember_view kept (checked by its reader)


def run_js(client: Any, source: str) -> None:
    """Run a script in one tab (viser's own mechanism for shipping scripts to the page)."""
    client._websock_connection.queue_message(viser_messages.RunJavascriptMessage(source=source))


ASK_AGAIN_S = 1.0


def recall(client: Any, timeout: float = 8.0) -> TabMemory:
    """Read this tab's session id and this browser's user name (blocks up to `timeout`), in one round
    trip to the page: a page in the background of its window (a reconnect) may answer slowly."""
    key = f"simecs.tab.{client.client_id}"
    nonce = secrets.token_hex(8)
    script = f"""(() => {{
  const key = {json.dumps(key)}, nonce = {json.dumps(nonce)};
  const probe = Object.keys(localStorage).find(k => k.endsWith(key) && localStorage.getItem(k) === nonce);
  if (!probe) return;
  let session = "", view = null, user = "";
  try {{ session = sessionStorage.getItem({json.dumps(SESSION_KEY)}) || ""; }} catch (e) {{}}
  try {{ view = JSON.parse(sessionStorage.getItem({json.dumps(VIEW_KEY)}) || "null"); }} catch (e) {{}}
  // the user name viser keeps for us under the same prefix as the probe: one round trip for both
  try {{ user = localStorage.getItem(probe.slice(0, -key.length) + {json.dumps(USER_KEY)}) || ""; }}
  catch (e) {{}}
  localStorage.setItem(probe, JSON.stringify({{session: session, view: view, user: user,
                                               width: window.innerWidth, height: window.innerHeight}}));
}})();"""
    try:
        end = time.monotonic() + timeout
        raw = None
        # Asked again every ASK_AGAIN_S: a page that has just reconnected may drop the first script.
        while time.monotonic() < end and (raw is None or raw == nonce):
            client.local_storage.set_item(key, nonce)
            # Find viser's key prefix from the probe just written, then put the tab's memory there.
            run_js(client, script)
            again = min(end, time.monotonic() + ASK_AGAIN_S)
            while time.monotonic() < again:
                try:
                    raw = client.local_storage.get_item(key, timeout=max(0.1, again - time.monotonic()))
                except TimeoutError:  # a busy page answers late: asked again until `timeout`
                    continue
                if raw is not None and raw != nonce:
                    break
                time.sleep(0.05)
        client.local_storage.remove_item(key)
    except (RuntimeError, TimeoutError) as exc:
        log.warning("tab %s did not tell its memory: %s", client.client_id, exc)
        return TabMemory()
    if raw is None or raw == nonce:
        log.info("tab %s did not tell its memory within %.0f s", client.client_id, timeout)
        return TabMemory(answered=False)
    try:
        told = json.loads(raw)
        session, user = str(told.get("session", "")), str(told.get("user", ""))
        width, height = int(told.get("width", 0)), int(told.get("height", 0))
        view = told.get("view")
    except (ValueError, TypeError, AttributeError):
        session, user, width, height, view = "", "", 0, 0, None
    view = view if isinstance(view, dict) else {}
    return TabMemory(session=session, user=user, answered=True, width=width, height=height, view=view)


def remember_session(client: Any, session: str) -> None:
    """Keep `session` in this tab across reloads ('' forgets it)."""
    if session:
        value = json.dumps(session)
        js = f"try {{ sessionStorage.setItem({json.dumps(SESSION_KEY)}, {value}); }} catch (e) {{}}"
    else:
        js = f"try {{ sessionStorage.removeItem({json.dumps(SESSION_KEY)}); }} catch (e) {{}}"
    run_js(client, js)


def remember_view(client: Any, view: dict[str, Any]) -> None:
    """Keep what the tab shows of its session (camera, open plots, shown component) across reloads."""
    value = json.dumps(json.dumps(view))
    run_js(client, f"try {{ sessionStorage.setItem({json.dumps(VIEW_KEY)}, {value}); }} catch (e) {{}}")


def remember_user(client: Any, user: str) -> None:
    client.local_storage.set_item(USER_KEY, user)


def install_doc_links(client: Any, prefix: str) -> None:
    """Make the documentation's in-text links work: a click on a link to `prefix<label>` clicks the
    button labelled `<label>` (docs.py); viser calls Python only from its widgets."""
    run_js(
        client,
        f"""(() => {{
  if (window.__simecsDocLinks) return;
  window.__simecsDocLinks = true;
  const prefix = {json.dumps(prefix)};
  document.addEventListener('click', (e) => {{
    const a = e.target && e.target.closest ? e.target.closest('a[href]') : null;
    const href = a ? a.getAttribute('href') || '' : '';
    if (!href.startsWith(prefix)) return;
    e.preventDefault();
    e.stopPropagation();
    const label = decodeURIComponent(href.slice(prefix.length));
    const found = Array.from(document.querySelectorAll('button')).filter(
      (b) => b.textContent.trim() === label);
    if (found.length) found[found.length - 1].click();
  }}, true);
}})();""",
    )


#: s between the viewer's beats. Every message makes the page draw the 3D view for a quarter of a
#: second (viser's on-demand rendering): a beat every second kept a browser without a GPU drawing
#: 40 % of the time, and the goal ghost came 100 ms late behind those frames.
BEAT_S = 5.0
#: The banner a tab shows once the server has been silent this long: a viewer that still holds the
#: page's link but no longer serves the tab. A lost link shows it at once.
SILENT_S = 12.0
LOST_TEXT = (
    "The simecs server is not answering. Your session is kept on the server; this page reconnects "
    "by itself when the server is back."
)


def install_watchdog(client: Any) -> None:
    """Say, on the page itself, when the server is gone. viser only dims the panels (and swaps its
    "connected" cloud icon in the panel's header for dots); the banner at the page's top edge says what
    happened and that nothing is lost. It shows as soon as that icon goes (the link is lost), or after
    `SILENT_S` without a beat from the viewer (`beat`, every `BEAT_S`), and goes when both are back
    (viser reconnects by itself, and the new tab reopens the session).

    viser's page retries a lost connection every second, but only while the page has the focus
    (`document.hasFocus()`): a page in a background tab or window, or beside another one, would
    never come back until clicked. The page here always counts as focused for that, so every page
    reconnects within a second or two of the server's return."""
    run_js(
        client,
        f"""(() => {{
  window.__simecsBeat = Date.now();
  if (window.__simecsWatchdog) return;
  window.__simecsWatchdog = true;
  document.hasFocus = () => true;
  const banner = document.createElement('div');
  banner.id = 'simecs-lost';
  banner.setAttribute('role', 'alert');
  banner.textContent = {json.dumps(LOST_TEXT)};
  banner.style.cssText = 'position:fixed;top:0;left:50%;transform:translateX(-50%);z-index:100000;' +
    'max-width:560px;padding:8px 14px;background:#c92a2a;color:#fff;font:14px sans-serif;' +
    'border-radius:0 0 6px 6px;box-shadow:0 2px 8px rgba(0,0,0,.3);display:none';
  document.body.appendChild(banner);
  let sawLink = false;  // the icon is only trusted once seen (a viser without it: the beats alone)
  setInterval(() => {{
    const linked = document.querySelector('svg.tabler-icon-cloud-check') !== null;
    sawLink = sawLink || linked;
    const silent = Date.now() - (window.__simecsBeat || 0) > {SILENT_S * 1000:.0f};
    banner.style.display = silent || (sawLink && !linked) ? 'block' : 'none';
  }}, 500);
}})();""",
    )


def install_page_rules(client: Any, key_buttons: dict[str, dict[str, str]]) -> None:
    """What the page does besides viser's own: viser's developer controls (server URL, Save Canvas,
    dev settings, the scene tree, behind the panel's "Configuration & diagnostics" icon) are hidden
    from users; the browser's Back button does not leave the app; a number field left blank or with
    what is not a number gets the value in force back, and says so (viser would leave it blank);
    the run keys click the run bar's buttons, so the same checks apply (`key_buttons`: phase -> key code ->
    button label, run.key_buttons), except while the user types in a field or answers a dialog."""
    run_js(
        client,
        "window.__simecsKeys = "
        + json.dumps(key_buttons)
        + """;
(() => {
  if (window.__simecsRules) return;
  window.__simecsRules = true;
  const style = document.createElement('style');
  style.textContent = 'button:has(svg.tabler-icon-adjustments){display:none !important}';
  document.head.appendChild(style);
  history.pushState({simecs: true}, '', location.href);
  window.addEventListener('popstate', () => history.pushState({simecs: true}, '', location.href));
  const runButton = (label) => Array.from(document.querySelectorAll('button')).find((b) =>
    b.textContent.trim() === label && b.parentElement &&
    Array.from(b.parentElement.children).some((c) => c.textContent.trim() === 'Abort') &&
    Array.from(b.parentElement.children).some((c) => c.textContent.trim() === 'Run'));
  // A number field left empty or with what is not a number (viser ignores it, the field would stay
  // blank over the value still in force): the value in force comes back, and the page says so.
  const typedBefore = new WeakMap();
  const nativeSet = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
  const isNumberField = (t) =>
    t && t.tagName === 'INPUT' && t.classList.contains('mantine-NumberInput-input');
  document.addEventListener('focusin', (e) => {
    if (isNumberField(e.target)) typedBefore.set(e.target, e.target.value);
  }, true);
  document.addEventListener('focusout', (e) => {
    const t = e.target;
    if (!isNumberField(t) || !typedBefore.has(t)) return;
    const text = t.value.trim(), before = typedBefore.get(t);
    if (text !== '' && Number.isFinite(Number(text.replace(/,/g, '')))) return;
    nativeSet.call(t, before);
    t.dispatchEvent(new Event('input', {bubbles: true}));
    const note = document.createElement('div');
    note.className = 'simecs-not-a-number';
    note.setAttribute('role', 'status');
    note.textContent = 'Not a number: the value stays ' + before;
    const box = t.getBoundingClientRect();
    note.style.cssText = 'position:fixed;z-index:100001;padding:2px 6px;font:12px sans-serif;' +
      'background:#c92a2a;color:#fff;border-radius:4px;' +
      'left:' + box.left + 'px;top:' + (box.bottom + 2) + 'px';
    document.body.appendChild(note);
    setTimeout(() => note.remove(), 4000);
  }, true);
  document.addEventListener('keydown', (e) => {
    if (e.ctrlKey || e.metaKey || e.altKey || e.repeat) return;
    const t = e.target;
    const typing = t && (t.isContentEditable || ['INPUT', 'TEXTAREA', 'SELECT'].includes(t.tagName));
    if (typing || document.querySelector('.mantine-Modal-content')) return;
    const label = (window.__simecsKeys[window.__simecsPhase || ''] || {})[e.code];
    if (!label) return;
    const button = runButton(label);
    if (!button) return;
    e.preventDefault();
    e.stopPropagation();
    button.click();
  }, true);
})();""",
    )


def show_tab(client: Any, label: str) -> None:
    """Bring the tab labelled `label` to the front (viser lets Python add tabs, not pick one)."""
    run_js(
        client,
        f"""(() => {{
  let tries = 0;
  const pick = () => {{  // the tab may be on its way (added in the same batch): looked for a while
    const tab = Array.from(document.querySelectorAll('[role="tab"]')).find(
      (t) => t.textContent.trim() === {json.dumps(label)});
    if (tab) {{  // a dock's tab activates on Enter (a press starts a drag), the trees' on a click
      tab.dispatchEvent(new KeyboardEvent('keydown', {{key: 'Enter', bubbles: true}}));
      if (tab.getAttribute('aria-selected') !== 'true') tab.click();
    }} else if (++tries < 40) setTimeout(pick, 50);
  }};
  pick();
}})();""",
    )


def tell_phase(client: Any, phase: str) -> None:
    """The session's phase, for the page's keys (Space, Esc: `install_page_rules`)."""
    run_js(client, f"window.__simecsPhase = {json.dumps(phase)};")


def beat(client: Any) -> None:
    """The server is here (see `install_watchdog`)."""
    run_js(client, "window.__simecsBeat = Date.now();")


def set_title(client: Any, title: str) -> None:
    run_js(client, f"document.title = {json.dumps(title)};")


def plain(text: str) -> str:
    """Markdown emphasis and code marks taken out: viser shows a notification's text as it is."""
    return re.sub(r"\*\*(.+?)\*\*|`([^`]+)`", lambda mt: mt.group(1) or mt.group(2), text)


def notify(client: Any, title: str, body: str, kind: str = "info", seconds: float | None = None) -> None:
    """A notification in one tab; errors stay until closed, the rest close by themselves."""
    color = {"error": "red", "warning": "yellow", "ok": "green", "info": "blue"}.get(kind, "blue")
    if seconds is None:
        seconds = None if kind == "error" else (8.0 if kind == "warning" else 4.0)
    try:
        client.add_notification(
            plain(title), plain(body), auto_close_seconds=seconds, color=color, with_close_button=True
        )
    except Exception as exc:  # the tab may be gone
        log.debug("notification to a closed tab dropped: %s", exc)
