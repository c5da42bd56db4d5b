"""Quick edits and clicks on a page all reach the server, in order (viewer/send_order.py).

viser's page keeps one message waiting per 50 ms window and a third replaces it. The page script
that holds such a message back is tried here on a plain viser server in a real browser, with and
without it: two fields typed and a button clicked in one go, three boxes ticked in one go. Without
the script the middle edit is lost (the day viser's page stops dropping it, the unguarded case
fails here and the script can go); with it nothing is lost, the click comes after the fields it
reads, and the ticked boxes show their tick at once.
"""

from __future__ import annotations

from typing import Any

import pytest
import viser
from simecs.testing import browser as chromium
from simecs.viewer.send_order import install_send_order

from .conftest import free_port, wait_until


@pytest.mark.parametrize("guarded", [True, False], ids=["guarded", "viser-alone"])
def test_quick_edits_and_clicks_all_reach_the_server_in_order(browser: Any, guarded: bool) -> None:
    srv = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    heard: list[tuple[str, Any]] = []  # what the server was told, in the order it heard it
    try:
        first, second = srv.gui.add_text("First", ""), srv.gui.add_text("Second", "")
        boxes = [srv.gui.add_checkbox(f"Box {k}", False) for k in range(3)]
        numbers = [srv.gui.add_number(f"Number {k}", 0.0, step=0.1) for k in range(3)]
        position = srv.gui.add_vector3("Position", (0.0, 0.0, 0.0), step=0.1)
        add = srv.gui.add_button("Add")
        for handle in (first, second, *boxes, *numbers, position):
            handle.on_update(lambda _e, h=handle: heard.append((h.label, h.value)))
        add.on_click(lambda _e: heard.append(("Add", (first.value, second.value))))
        if guarded:
            srv.on_client_connect(install_send_order)
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{srv.get_port()}")
        chromium.labelled_input(page, "Second").wait_for()
        if guarded:
            page.wait_for_function("window.__simecsSendOrder === true")

        chromium.type_then_click_at_once(
            page, [("First", "x"), ("Second", "y")], page.get_by_role("button", name="Add")
        )
        wait_until(lambda: any(what == "Add" for what, _ in heard), what="the click heard")
        page.wait_for_timeout(300)  # anything still on its way
        if not guarded:
            assert ("Second", "y") not in heard and ("Add", ("x", "")) in heard, heard
            return
        assert heard == [("First", "x"), ("Second", "y"), ("Add", ("x", "y"))]

        heard.clear()
        ticked = page.evaluate(
            """(boxes) => { boxes.forEach((b) => b.click()); return boxes.map((b) => b.checked); }""",
            [page.get_by_label(f"Box {k}").element_handle() for k in range(3)],
        )
        assert ticked == [True, True, True]  # shown at once, held or not
        wait_until(lambda: all(b.value for b in boxes), what="the three boxes ticked on the server")
        page.wait_for_timeout(300)
        assert heard == [(f"Box {k}", True) for k in range(3)]
        assert [page.get_by_label(f"Box {k}").is_checked() for k in range(3)] == [True] * 3

        # number fields typed one after the other, each left with Enter and by going to the next (a
        # number field writes back on Enter and on leaving what it knows), then a vector's three boxes
        heard.clear()
        fields = [chromium.labelled_input(page, f"Number {k}").element_handle() for k in range(3)]
        fields += [chromium.vector_input(page, "Position", k).element_handle() for k in range(3)]
        page.evaluate(
            """(fields) => {
  const setText = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
  fields.forEach((field, k) => {
    field.focus();
    setText.call(field, String(k + 1.5));
    field.dispatchEvent(new Event('input', {bubbles: true}));
    field.dispatchEvent(new KeyboardEvent('keydown', {key: 'Enter', code: 'Enter', bubbles: true}));
  });
  fields[0].focus();
}""",
            fields,
        )
        wait_until(
            lambda: [n.value for n in numbers] == [1.5, 2.5, 3.5] and position.value == (4.5, 5.5, 6.5),
            what=f"every typed number on the server (heard {heard})",
        )
        page.wait_for_timeout(300)
        assert [n.value for n in numbers] == [1.5, 2.5, 3.5] and position.value == (4.5, 5.5, 6.5)
        shown = [f.input_value() for f in fields]
        assert [float(x) for x in shown] == [1.5, 2.5, 3.5, 4.5, 5.5, 6.5], shown  # none written back
        page.close()
    finally:
        srv.stop()
