"""The direct-input pendant (issue 12, build item 2: a signal editor per joint with a preview plot).

The editor as data (the protocol's shapes and bounds, a typed table, a refusal naming the number),
then the pendant in a real browser on the real service, at 1024×768 and 1600×900: a position sine
applied to joint2 is stored as the session's command and previewed as the server expanded it; a
current beyond i_max is refused beside the signals with the server's reason; the 3D view stays
clear. At 1600×900 the signals run, and the run's current set point is the one previewed.

Screenshots go to `artifacts/viewer/direct_*.png`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.testing import browser as chromium
from simecs.viewer import direct
from simecs.viewer.direct_pendant import refusal_text
from simecs.viewer.path import PathError

from .conftest import Mesh, wait_until
from .test_viewer_browser import (
    BOTH_SIZES,
    SHOTS,
    logs_on_failure,
    sized_spider_tab,
    text_appears,
)
from .test_viewer_layout import view_is_clear

JOINTS = ["joint1", "joint2", "joint3"]


def test_the_editor_builds_what_the_protocol_takes_and_names_what_it_refuses() -> None:
    ed = direct.DirectInputEditor(JOINTS)
    assert ed.empty and ed.unit == "A"
    with pytest.raises(PathError, match="no joint has a signal"):
        ed.to_command()
    ed.set_mode("Position set point (closed loop)")
    assert (ed.mode, ed.reference, ed.unit) == ("closed_loop", "position", "rad")
    ed.set_signal("joint3", "sine", {"amplitude": 0.1, "frequency_hz": 0.5, "offset": 0.2, "slope": 7.0})
    ed.set_signal("joint1", "table", {}, "# t, q\n0, 0\n1; 0.3\n\n2 0.3\n")
    cmd = ed.to_command()
    assert list(cmd.signals) == ["joint1", "joint3"]  # the arm's order, whatever the order applied
    assert cmd.signals["joint1"] == m.TableSignal([[0.0, 0.0], [1.0, 0.3], [2.0, 0.3]])
    assert cmd.signals["joint3"] == m.SineSignal(amplitude=0.1, frequency_hz=0.5, offset=0.2)  # no slope
    assert codec.loads(m.DirectInput, codec.dumps(cmd)) == cmd  # valid on the wire
    assert "| joint3 | sine 0.1 rad at 0.5 Hz from 0 s |" in ed.table_markdown("joint2")
    assert "| **▶joint2** | holds its initial position |" in ed.table_markdown("joint2")

    # what the protocol refuses is named, and nothing changes
    for kind, numbers, table, match in [
        ("sine", {"amplitude": 1.0, "frequency_hz": 900.0}, "", "joint2 sine: frequency_hz: .*<= 500"),
        ("chirp", {"amplitude": 1.0, "f0_hz": 1.0, "f1_hz": 2.0, "duration": 0.0}, "", "duration: .*> 0"),
        ("table", {}, "0, 1\n1, x", "table line 2: '1, x' is not two numbers"),
        ("table", {}, "1, 1\n0.5, 2", r"points\[1\]: times must not decrease"),
        ("table", {}, "\n# nothing\n", "the table is empty"),
        ("noise", {}, "", "no signal type 'noise'"),
    ]:
        with pytest.raises(PathError, match=match):
            ed.set_signal("joint2", kind, numbers, table)
    with pytest.raises(PathError, match="no joint 'joint9'"):
        ed.set_signal("joint9", "step", {"amplitude": 1.0})
    assert list(ed.signals) == ["joint3", "joint1"]

    # what the pendant shows of a joint: its own numbers, the first values elsewhere
    kind, numbers, _ = ed.shown("joint3")
    assert kind == "sine" and numbers["sine"]["frequency_hz"] == 0.5 and numbers["chirp"]["duration"] == 2.0
    kind, _, table = ed.shown("joint1")
    assert kind == "table" and direct.parse_points(table) == [[0.0, 0.0], [1.0, 0.3], [2.0, 0.3]]
    assert ed.shown("joint2")[0] == direct.NO_SIGNAL
    ed.remove("joint1")
    with pytest.raises(PathError, match="joint1 has no signal"):
        ed.remove("joint1")

    # a session's stored direct input comes back as it was
    other = direct.DirectInputEditor(JOINTS)
    other.load(
        m.DirectInput("closed_loop", {"joint2": m.StepSignal(0.3), "joint7": m.StepSignal(1.0)}, "speed")
    )
    assert other.mode_label == "Speed set point (closed loop)" and list(other.signals) == ["joint2"]
    assert refusal_text("command.signals.joint2.amplitude", "too big") == (
        "**✗ The server refused joint2's amplitude:** too big"
    )


def previews(page: Any) -> list[dict[str, Any]]:
    """Each chart's series labels and their lowest and highest values, as the page's uPlot holds them."""
    return list(
        page.evaluate("""() => Object.values((window.__viserTestpoints || {}).uplots || {}).map((tp) => {
  const u = tp.chart;
  return {labels: u.series.slice(1).map((s) => s.label),
          lows: u.data.slice(1).map((ys) => Math.min(...ys.filter(Number.isFinite))),
          highs: u.data.slice(1).map((ys) => Math.max(...ys.filter(Number.isFinite)))};
})""")
    )


def preview_of(page: Any, label: str) -> tuple[float, float]:
    chart = wait_until(
        lambda: next((c for c in previews(page) if label in c["labels"]), None), what=f"{label} previewed"
    )
    k = chart["labels"].index(label)
    return chart["lows"][k], chart["highs"][k]


@BOTH_SIZES
def test_the_signal_editor_previews_refuses_and_runs(mesh: Mesh, browser: Any, size: tuple[int, int]) -> None:
    with logs_on_failure(mesh, "viewer", "proxy"):
        direct_walk(mesh, browser, size)


def direct_walk(mesh: Mesh, browser: Any, size: tuple[int, int]) -> None:
    page, session, tag = sized_spider_tab(mesh, browser, size)
    width, height = size
    q2 = session.snapshot().initial[1]
    page.get_by_role("tab", name="Direct input").click()

    # a slow position sine about joint2's initial position: stored, and previewed as expanded
    chromium.pick_option(page, "Mode", "Position set point (closed loop)")
    chromium.pick_option(page, "Joint", "joint2")
    chromium.pick_option(page, "Signal", "sine")
    chromium.type_into(page, "Amplitude [rad]", "0.05")
    chromium.type_into(page, "Frequency [Hz]", "0.5")
    chromium.type_into(page, "Offset [rad]", f"{q2:.6g}")
    page.get_by_role("button", name="Apply signal").click()
    command = wait_until(
        lambda: c if isinstance(c := session.snapshot().command, m.DirectInput) else None,
        what="the direct input stored",
    )
    assert command.mode == "closed_loop" and command.reference == "position"
    assert command.signals == {
        "joint2": m.SineSignal(amplitude=0.05, frequency_hz=0.5, offset=float(f"{q2:.6g}"))
    }
    low, high = preview_of(page, "joint2 [rad]")
    assert low == pytest.approx(q2 - 0.05, abs=1e-4) and high == pytest.approx(q2 + 0.05, abs=1e-4)
    text_appears(page, "The signals run for the whole run")
    view_is_clear(page, 300 if width < 1400 else 500)
    page.screenshot(path=str(SHOTS / f"direct_{tag}.png"))

    # the mode is a choice, not a draft: the same sine at once as a current (0.05 A about 0 A)
    chromium.pick_option(page, "Mode", "Motor current (open loop)")
    command = wait_until(
        lambda: c if (c := session.snapshot().command).mode == "open_loop" else None,
        what="the signals stored as currents",
    )
    preview_of(page, "joint2 [A]")
    # 9 A is beyond joint2's i_max: refused beside the signals, nothing stored
    chromium.type_into(page, "Amplitude [A]", "9")
    chromium.type_into(page, "Offset [A]", "0")
    page.get_by_role("button", name="Apply signal").click()
    text_appears(page, "The server refused joint2")
    text_appears(page, "motor.i_max")
    reason = page.get_by_text("motor.i_max").locator("visible=true").first.bounding_box()
    assert reason is not None and 0 <= reason["y"] < height - 10, f"the reason is out of sight: {reason}"
    assert session.snapshot().command == command
    page.screenshot(path=str(SHOTS / f"direct_refused_{tag}.png"))

    # 0.5 A: taken, the refusal gone and the preview in amperes
    chromium.type_into(page, "Amplitude [A]", "0.5")
    chromium.type_into(page, "Frequency [Hz]", "2")
    page.get_by_role("button", name="Apply signal").click()
    page.get_by_text("The server refused").wait_for(state="hidden")
    low, high = preview_of(page, "joint2 [A]")
    assert low == pytest.approx(-0.5, abs=1e-3) and high == pytest.approx(0.5, abs=1e-3)
    if width < 1400:
        return
    # the signals run: the current set point follows the sine the preview showed
    session.set_settings(stop_time=1.0, output_interval=0.002, pacing="fast")
    page.get_by_role("button", name="Run", exact=True).click()
    text_appears(page, "finished run", timeout=60)
    run = session.runs()[-1]
    _cols, rows = session.results(run.run_id, ["joint2.i_ref"])
    assert np.max(rows[:, 1]) == pytest.approx(0.5, abs=1e-3) and np.min(rows[:, 1]) == pytest.approx(
        -0.5, abs=1e-3
    )
    page.screenshot(path=str(SHOTS / f"direct_run_{tag}.png"))
