"""The viewer node of `simecs bench viewer` and the pages it measures: started on a port of its own,
a page with a session of its own, which session a page shows."""

from __future__ import annotations

import socket
import time
import urllib.request
from typing import Any

from simecs.nodes.local_mesh import LocalMesh
from simecs.testing import browser

MODEL_BUTTON = "Load Spider arm (joint-independent control)"
USER = "bench"  # the viewer's user for browsers that have none (its --user)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def viewer_flags(port: int) -> tuple[str, ...]:
    return ("--host", "127.0.0.1", "--port", str(port), "--user", USER)


def start_viewer(mesh: LocalMesh, port: int, timeout: float = 60.0) -> float:
    """Start the viewer node on `port`; the wall-clock time its port first accepted a connection and
    answered (returns once the node is live too)."""
    mesh.spawn("viewer", "simecs.viewer.app", *viewer_flags(port), node_id="viewer-t")
    end = time.monotonic() + timeout
    while True:
        asked = time.time()  # a connection that is accepted is accepted at once
        try:  # what a browser asks first: the page (a bare connection makes the viewer log an error)
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2.0) as reply:
                reply.read()
            ready = asked
            break
        except OSError:
            if time.monotonic() > end or mesh.procs["viewer"].poll() is not None:
                raise RuntimeError(f"the viewer did not open port {port}:\n{mesh.log('viewer')}") from None
            time.sleep(0.02)
    mesh.wait_node("viewer", "viewer-t", timeout=timeout)
    return ready


def session_page(context: Any, url: str) -> Any:
    """A new page of `context` that loaded the Spider (a session of its own)."""
    page = context.new_page()
    page.add_init_script(browser.PROBE_JS)
    page.goto(url)
    page.get_by_role("button", name=MODEL_BUTTON).click(timeout=60_000)
    shown_session_of(page)
    return page


def sessions(mesh: LocalMesh) -> set[str]:
    return {s.session for s in mesh.client().list_sessions(USER) if s.phase != "closed"}


def shown_session_of(page: Any, timeout: float = 60.0) -> str:
    """The first 8 characters of the session the page's header names, once it names one."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        prefix = browser.shown_session(page)
        if prefix:
            return prefix
        time.sleep(0.1)
    raise TimeoutError(f"the page named no session within {timeout:.0f} s")
