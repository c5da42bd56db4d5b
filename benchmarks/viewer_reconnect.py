"""`simecs bench viewer`, its last part: pages open across restarts of the viewer node, and whether and
when each shows its session again by itself (viewer.py says what each figure is)."""

from __future__ import annotations

import math
import statistics
import time
from typing import Any

from simecs.nodes.local_mesh import LocalMesh
from simecs.testing import browser

from .viewer_page import session_page, sessions, shown_session_of, start_viewer

RESTARTS = 6
DOWN_S = (0.5, 2.0, 0.0, 5.0, 1.0, 3.0)  # how long the viewer stays stopped, restart by restart
BACK_WITHIN_S = 30.0  # a page not back this long after the viewer's return did not come back


def worst(events: list[dict[str, Any]]) -> float:
    """The longest time to come back of `events` (inf when one did not come back)."""
    return max((math.inf if e["back_s"] is None else e["back_s"] for e in events), default=0.0)


def measure_reconnect(mesh: LocalMesh, chrome: Any, port: int, first: Any) -> dict[str, Any]:
    """Three pages with a session each (`first` and one more in its window, one in a window of its
    own), the viewer stopped and started again RESTARTS times; each time, whether and when each page
    showed its own session again without a reload. The front page of the first window alternates,
    so each of its pages spends restarts in the background (without focus)."""
    url = f"http://127.0.0.1:{port}"
    pages = [first, session_page(first.context, url)]
    pages.append(session_page(chrome.new_context(viewport=browser.VIEWPORT), url))
    prefixes = [shown_session_of(p) for p in pages]
    if len(set(prefixes)) != len(pages):
        raise RuntimeError(f"the pages do not have a session each: {prefixes}")
    expected = sessions(mesh)
    for page, prefix in zip(pages, prefixes, strict=True):
        browser.real_focus(page)
        browser.watch_session(page, prefix)
    events: list[dict[str, Any]] = []
    crashes: list[dict[str, Any]] = []
    kept = True
    for k in range(RESTARTS):
        pages[k % 2].bring_to_front()
        time.sleep(0.3)
        focus = [browser.has_focus(p) for p in pages]
        shown = [browser.session_shown(p) for p in pages]
        if not all(seen and seen[-1][1] >= 0 for seen in shown):
            raise RuntimeError(f"restart {k + 1}: a page does not show its session before the stop")
        element = [seen[-1][1] for seen in shown]
        loaded = [browser.loaded_at(p) for p in pages]
        stopped = time.time() * 1000.0  # wall-clock ms, as the page notes its links
        mesh.stop("viewer")
        time.sleep(DOWN_S[k % len(DOWN_S)])
        ready = start_viewer(mesh, port)
        back: list[float | None] = [None] * len(pages)
        while time.time() < ready + BACK_WITHIN_S and None in back:
            for i, page in enumerate(pages):
                if back[i] is None:
                    at = browser.shown_anew_after(page, element[i])
                    back[i] = None if at is None else at / 1000.0 - ready
            if mesh.procs["viewer"].poll() is not None:
                break
            time.sleep(0.1)
        exit_code = mesh.procs["viewer"].poll()
        if exit_code is not None:  # the viewer died: said, and started again for the next restart
            crashes.append({"restart": k + 1, "exit": exit_code, "log": mesh.log("viewer")[-1500:]})
            start_viewer(mesh, port)
        for i, page in enumerate(pages):
            took = back[i] if browser.loaded_at(page) == loaded[i] else None  # a reload is not "back"
            up = [t for t, kind in browser.links(page) if kind == "connected" and t > stopped]
            events.append(
                {
                    "restart": k + 1,
                    "page": i + 1,
                    "focus": focus[i],
                    "down_s": round(ready - stopped / 1000.0, 3),  # the viewer's stop to its port open
                    "connected_s": round(up[0] / 1000.0 - ready, 3) if up else None,  # websocket up again
                    "back_s": None if took is None else round(took, 3),  # its session shown again
                }
            )
            if took is None:  # brought back by hand, for the next restart
                page.reload()
                shown_session_of(page)
                browser.watch_session(page, prefixes[i])
        if sessions(mesh) != expected:
            kept = False
        time.sleep(1.0)  # the pages settle (the tabs keep their view about once a second)
    times = [e["back_s"] for e in events if e["back_s"] is not None]
    background = [e for e in events if not e["focus"]]
    return {
        "reconnect_pages": len(events),
        "reconnect_pages_back": len(times),
        "reconnect_s_max": max(times, default=math.inf),
        "reconnect_s_p50": statistics.median(times) if times else math.inf,
        # the worst of the pages that had the focus, and of those in the background of their window
        "reconnect_s_max_focused": worst([e for e in events if e["focus"]]),
        "reconnect_s_max_background": worst(background),
        "reconnect_background": len(background),
        "reconnect_background_back": sum(1 for e in background if e["back_s"] is not None),
        "reconnect_sessions_kept": kept,
        "reconnect_viewer_crashes": crashes,
        "reconnect_events": events,
    }
