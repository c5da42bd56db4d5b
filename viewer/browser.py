"""What the viewer needs from the browser tab itself: which session it had before a reload, the user
name kept on this browser, notifications, and the page title.

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
from dataclasses import dataclass
from typing import Any

from viser import _messages as viser_messages

log = logging.getLogger("simecs.viewer")

SESSION_KEY = "simecs.session"  # sessionStorage: this tab's session id
USER_KEY = "simecs.user"  # localStorage (via viser): the user name on this browser


@dataclass
class TabMemory:
    """What a tab remembered: its session id (may be empty) and the browser's user name."""

    session: str = ""
    user: str = ""
    answered: bool = False  # False: the browser did not answer (script blocked, storage disabled)


def run_js(client: Any, source: str) -> None:
    """Run a script in one tab (viser's own mechanism for shipping scripts to the page)."""
    client._websock_connection.queue_message(viser_messages.RunJavascriptMessage(source=source))


def recall(client: Any, timeout: float = 5.0) -> TabMemory:
    """Read this tab's session id and this browser's user name (blocks up to `timeout`)."""
    key = f"simecs.tab.{client.client_id}"
    nonce = secrets.token_hex(8)
    try:
        client.local_storage.set_item(key, nonce)
        # Find viser's key prefix from the probe just written, then put the tab's memory in its place.
        run_js(
            client,
            f"""(() => {{
  const key = {json.dumps(key)}, nonce = {json.dumps(nonce)};
  const probe = Object.keys(localStorage).find(k => k.endsWith(key) && localStorage.getItem(k) === nonce);
  if (!probe) return;
  let session = "";
  try {{ session = sessionStorage.getItem({json.dumps(SESSION_KEY)}) || ""; }} catch (e) {{}}
  localStorage.setItem(probe, JSON.stringify({{session: session}}));
}})();""",
        )
        end = time.monotonic() + timeout
        raw = None
        while time.monotonic() < end:
            raw = client.local_storage.get_item(key, timeout=max(0.1, end - time.monotonic()))
            if raw is not None and raw != nonce:
                break
            time.sleep(0.05)
        user = client.local_storage.get_item(USER_KEY, timeout=max(0.5, end - time.monotonic())) or ""
        client.local_storage.remove_item(key)
    except (RuntimeError, TimeoutError) as exc:
        log.warning("tab %s did not tell its memory: %s", client.client_id, exc)
        return TabMemory()
    if raw is None or raw == nonce:
        return TabMemory(user=user, answered=False)
    try:
        session = str(json.loads(raw).get("session", ""))
    except (ValueError, AttributeError):
        session = ""
    return TabMemory(session=session, user=user, answered=True)


def remember_session(client: Any, session: str) -> None:
    """Keep `session` in this tab across reloads ('' forgets it)."""
    if session:
        value = json.dumps(session)
        js = f"try {{ sessionStorage.setItem({json.dumps(SESSION_KEY)}, {value}); }} catch (e) {{}}"
    else:
        js = f"try {{ sessionStorage.removeItem({json.dumps(SESSION_KEY)}); }} catch (e) {{}}"
    run_js(client, js)


def remember_user(client: Any, user: str) -> None:
    client.local_storage.set_item(USER_KEY, user)


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
