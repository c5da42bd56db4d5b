"""One owner of each tab's state (issue 32): the tab's loop runs every widget callback, controller
event and tick one at a time, on one thread; workers hand their answers to it. Checked on the loop
itself (real threads), and on a tab built on a real viser server: every callback its panels register
runs on its loop, whichever thread viser calls it from.
"""

from __future__ import annotations

import asyncio
import inspect
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest
from simecs.viewer.loop import LoopClosed, TabLoop

from .viewer_fakes import FakeClient, arm, loaded_tab


def test_the_loop_runs_jobs_in_order_on_one_thread_whoever_posts_them() -> None:
    loop = TabLoop("t")
    try:
        ran: list[tuple[int, int]] = []

        def job(k: int) -> None:
            ran.append((k, threading.get_ident()))

        with ThreadPoolExecutor(8) as pool:  # eight threads post at once, each its own numbers in order
            for p in range(8):
                pool.submit(lambda p=p: [loop.post(lambda k=100 * p + i: job(k)) for i in range(100)])
        assert loop.wait_idle(10)
        assert len(ran) == 800 and len({t for _, t in ran}) == 1  # one thread ran them all
        assert ran[0][1] == loop._owner and ran[0][1] != threading.get_ident()
        for p in range(8):  # each poster's jobs ran in the order it posted them
            mine = [k for k, _ in ran if k // 100 == p]
            assert mine == sorted(mine)
    finally:
        loop.close()


def test_a_worker_changes_state_through_the_loop_and_gets_the_answer() -> None:
    loop = TabLoop("t")
    try:
        state = {"n": 0}

        def bump() -> int:
            assert loop.owns()
            state["n"] += 1
            return state["n"]

        with ThreadPoolExecutor(4) as pool:
            answers = list(pool.map(lambda _: loop.call(bump), range(40)))
        assert sorted(answers) == list(range(1, 41)) and state["n"] == 40
        with pytest.raises(ZeroDivisionError):  # the job's error reaches the worker that asked
            loop.call(lambda: 1 / 0)
        assert loop.call(lambda: "still running") == "still running"  # a failed job ends nothing
    finally:
        loop.close()
    with pytest.raises(LoopClosed):
        loop.call(lambda: 1, timeout=1.0)


def test_coalesced_jobs_and_timers() -> None:
    """A tick (a redraw) still waiting makes the next one redundant; a timer runs when due, not
    before; a closed loop drops what waits."""
    loop = TabLoop("t", driven=True)
    ran: list[str] = []
    loop.post(lambda: ran.append("tick"), key="tick")
    loop.post(lambda: ran.append("tick"), key="tick")
    loop.after(0.15, lambda: ran.append("later"))
    loop.post(lambda: ran.append("event"))
    loop.run_pending()
    assert ran == ["tick", "event"]
    time.sleep(0.2)
    loop.run_pending()
    assert ran == ["tick", "event", "later"]
    loop.post(lambda: ran.append("tick"), key="tick")  # the key is free again once its job ran
    loop.close()
    loop.run_pending()
    assert ran == ["tick", "event", "later"]


def registered_callbacks(server: Any) -> list[tuple[str, Any]]:
    """(what, callback) of every callback registered on the server's widgets and scene nodes."""
    out: list[tuple[str, Any]] = []
    for handle in list(server.gui._gui_input_handle_from_uuid.values()):
        impl = handle._impl
        label = f"{type(handle).__name__} {getattr(impl, 'label', '')!r}"
        out += [(label, cb) for cb in impl.update_cb]
        for cbs in getattr(impl, "hold_cbs_from_freq", {}).values():
            out += [(f"{label} hold", cb) for cb in cbs]
    for name, handle in list(server.scene._handle_from_node_name.items()):
        aux = getattr(handle, "_impl_aux", None)
        out += [(f"scene {name}", cb) for cb in getattr(aux, "update_cb", [])]
        out += [(f"scene {name} click", e.callback) for e in getattr(handle._impl, "click_cb", None) or []]
    return out


def test_every_callback_of_a_loaded_page_runs_on_the_tabs_loop(server: Any) -> None:
    """Every window a page opens included: a callback registered past the tab's loop-bound client
    would run on viser's thread pool, beside the tab's events (the race this issue removes)."""
    tab, _client, page, _sc = loaded_tab(server, arm())
    try:
        page.show_init()
        page.open_settings()
        page.toggle_docs()
        page.open_plot("joint1.q")
        page.params.confirm_reset_all()
        tab.controller.drain()
        found = registered_callbacks(server)
        assert len(found) > 60, len(found)
        stray = [what for what, cb in found if getattr(cb, "on_tab_loop", None) is not tab.loop]
        assert not stray, stray
        # each is a coroutine: viser awaits it on its event loop, message after message (a plain
        # one it would run on its thread pool, several at once, and two clicks could swap)
        pooled = [what for what, cb in found if not inspect.iscoroutinefunction(cb)]
        assert not pooled, pooled
        # a page's messages in the order they came (viser awaits each message's callbacks before
        # the next message's): the panels' code runs on the loop, in that order
        ran: list[tuple[str, bool]] = []
        number = tab.client.gui.add_number("probe number", 0.5)
        number.on_update(lambda e: ran.append(("number", tab.loop.owns())))
        button = tab.client.gui.add_button("probe button")
        button.on_click(lambda e: ran.append(("button", tab.loop.owns())))

        async def page_messages() -> None:
            for handle in (button, number, button, number):
                for cb in handle._impl.update_cb:
                    await cb(FakeEvent(handle))

        viser_thread = threading.Thread(target=lambda: asyncio.run(page_messages()))
        viser_thread.start()
        viser_thread.join(10)
        tab.controller.drain()
        assert ran == [("button", True), ("number", True), ("button", True), ("number", True)]
    finally:
        tab.close()
        page.remove()


class FakeEvent:
    """What viser hands a callback: the handle, and no client (as for an assignment from code)."""

    def __init__(self, target: Any) -> None:
        self.target = target
        self.client = None
        self.client_id = None


def test_a_tab_on_its_own_thread_applies_events_from_many_threads_without_a_lock(server: Any) -> None:
    """The tab's events come from workers and zenoh's threads at once; each is applied on the loop,
    so the panels see them one at a time (the tab holds no lock any more)."""
    from simecs.viewer.tab import Tab

    from .viewer_fakes import FakeHost, FakeMesh

    model = arm()
    client = FakeClient(server)
    tab = Tab(FakeHost(FakeMesh(model)), client)  # a loop of its own, as in the viewer node
    try:
        tab.loop.call(tab.build_frame)
        applied: list[bool] = []
        tab.controller.subscribe(lambda _e: applied.append(tab.loop.owns()))
        with ThreadPoolExecutor(6) as pool:
            for k in range(300):
                pool.submit(tab.controller.notify, "n", str(k))
        tab.controller.drain()
        assert len(applied) == 300 and all(applied)
        assert not hasattr(tab, "lock")
    finally:
        tab.close()


def test_preview_plays_the_planned_motion_on_the_ghost_and_the_arm_stays(server: Any) -> None:
    """Issue 32 (MoveIt's Plan before Execute): Preview poses the goal ghost along the server's
    planned set points at their own pace, on the tab's loop; the arm itself does not move."""
    from simecs.mesh.protocol import messages as m

    tab, client, page, _sc = loaded_tab(server, arm())
    try:
        page.preview_motion()  # no plan yet: said, nothing plays
        assert "Nothing to preview" in client.notes[-1][1]
        t = [0.0, 0.1, 0.2]
        q = [[0.0, 0.0, 0.0], [0.1, 0.2, 0.0], [0.2, 0.4, 0.0]]
        plan = m.CommandPlan("joint_path", 0.2, [], q[-1], motion=m.PlannedMotion(t, q))
        tab.controller.edits.plan = plan
        page.preview_motion()
        seen: list[list[float]] = []
        end = time.monotonic() + 5.0
        while time.monotonic() < end and page.ghost.q != q[-1]:
            time.sleep(0.01)
            tab.loop.run_pending()
            if page.ghost.q is not None and (not seen or seen[-1] != page.ghost.q):
                seen.append(list(page.ghost.q))
        assert page.ghost.q == pytest.approx(q[-1]) and len(seen) >= 4  # several poses, in order
        assert all(a[0] <= b[0] for a, b in zip(seen, seen[1:], strict=False))
        assert tab.controller.shown_q == [0.0, 0.0, 0.0]  # the arm stayed where the run starts
    finally:
        tab.close()
        page.remove()
