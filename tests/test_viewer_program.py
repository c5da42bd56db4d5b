"""The task pendant (issue 12, build item 2: actions, tasks and missions composed from the user's
library, reordered, saved, with the running step shown).

The composition as data (the protocol's primitives and arguments, step paths as the server names
them), then the pendant in a real browser on the real service, at 1024×768 and 1600×900: a task of
two actions taught and typed is stored and planned, saved in the library, a second task makes a
mission, an argument out of bounds is refused beside the arguments naming the task and action, and
at 1600×900 the mission runs with its running step marked.

Screenshots go to `artifacts/viewer/tasks_*.png`.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.robot_commands import ACTION_ARGS
from simecs.testing import browser as chromium
from simecs.viewer import program
from simecs.viewer.path import PathError
from simecs.viewer.program_pendant import refusal_text

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


def test_the_composition_is_what_the_protocol_takes_and_steps_are_named_as_the_server_names_them() -> None:
    ed = program.ProgramEditor(JOINTS)
    assert ed.empty and ed.kind == "task"
    # typed as on the other pendants (degrees, mm), stored in the protocol's units (rad, m)
    ed.insert(ed.build("move_joints", {"q": "90, 45 -30", "speed_pct": "50"}, "reach"))
    ed.insert(ed.build("wait", {"duration": "0.5"}))
    ed.insert(ed.build("move_linear", {"position": "400, 0, 300"}))  # rpy left out: optional
    assert ed.current.actions[-1].args["position"] == pytest.approx([0.4, 0.0, 0.3])
    ed.move(-1)
    ed.remove()  # the line, now second
    cmd = ed.to_command()
    assert cmd == m.Task(
        "task1",
        [
            m.Action(
                "move_joints", {"q": [math.pi / 2, math.pi / 4, -math.pi / 6], "speed_pct": 50.0}, "reach"
            ),
            m.Action("wait", {"duration": 0.5}),
        ],
    )
    assert codec.loads(m.Task, codec.dumps(cmd)) == cmd
    assert ed.step_path(0, 1) == "actions[1]"
    ed.add_task("place")
    with pytest.raises(PathError, match="task place has no action"):
        ed.to_command()
    ed.insert(ed.build("home", {}))
    mission = ed.to_command()
    assert isinstance(mission, m.Mission) and [t.name for t in mission.tasks] == ["task1", "place"]
    assert ed.kind == "mission" and ed.step_path(1, 0) == "tasks[1].actions[0]"
    table = ed.table_markdown({"tasks[0].actions[1]": (1.25, 1.75)}, running="tasks[1].actions[0]")
    assert "| 2 | wait (duration 0.5 s) | 1.25–1.75 |" in table and "| ⏵ **▶1** | home | — |" in table
    assert "reach: move_joints (joint positions 90, 45, -30 deg; speed 50 %)" in table  # the user's words
    assert program.arg_text("q", ACTION_ARGS["move_joints"]["q"], [-2.68254e-05, 0.5]) == "-0.002, 28.648"

    # what the editor cannot take is named, and nothing changes
    for primitive, texts, label, match in [
        ("move_joints", {"q": "1, 2"}, "", "Joint positions: 3 numbers, got 2"),
        ("move_joints", {}, "", "Joint positions is required"),
        ("wait", {"duration": "soon"}, "", "Duration: 'soon' is not a number"),
        ("wait", {"duration": "1"}, "no spaces", "wait: name"),
        ("fly", {}, "", "no primitive 'fly'"),
    ]:
        with pytest.raises(PathError, match=match):
            ed.build(primitive, texts, label)
    with pytest.raises(PathError, match="task name"):
        ed.add_task("two words")
    ed.move_task(-1)
    assert [t.name for t in ed.tasks] == ["place", "task1"] and ed.task == 0

    # saved programs come in where the user is; a stored mission comes back whole
    other = program.ProgramEditor(JOINTS)
    other.take(mission.tasks[0])  # a task into an empty composition takes its place
    other.take(m.Action("release"))
    assert [t.name for t in other.tasks] == ["task1"] and other.current.actions[-1].primitive == "release"
    other.load(mission)
    assert other.to_command() == mission and (other.task, other.action) == (0, 1)
    assert refusal_text(other, "command.tasks[1].actions[0].args.speed_pct", "250 % is outside") == (
        "**✗ The server refused place, action 1 (Speed):** 250 % is outside"
    )


def press(page: Any, button: str, nth: int = 0) -> None:
    page.get_by_role("button", name=button, exact=True).locator("visible=true").nth(nth).click()


@BOTH_SIZES
def test_the_task_pendant_composes_saves_refuses_and_runs(
    mesh: Mesh, browser: Any, size: tuple[int, int]
) -> None:
    with logs_on_failure(mesh, "viewer", "proxy"):
        tasks_walk(mesh, browser, size)


def tasks_walk(mesh: Mesh, browser: Any, size: tuple[int, int]) -> None:
    page, session, tag = sized_spider_tab(mesh, browser, size)
    width, height = size
    q0 = session.snapshot().initial
    page.get_by_role("tab", name="Tasks").click()

    # move_joints taught at the arm's pose, then edited; a wait after it: a task, stored and planned
    press(page, "Teach")
    q_field = chromium.labelled_input(page, "Joint positions [deg]")
    wait_until(lambda: q_field.input_value() != "", what="Teach fills q")
    taught = [math.radians(float(x)) for x in q_field.input_value().split(",")]
    assert taught == pytest.approx(q0, abs=2e-5)  # in degrees, to 0.001 deg
    target = [math.radians(20.0), *q0[1:]]
    # typed and added at once: two fields and a click inside viser's 50 ms send window, none lost
    chromium.type_then_click_at_once(
        page,
        [("Joint positions [deg]", ", ".join(f"{math.degrees(x):.3f}" for x in target)), ("Label", "turn")],
        page.get_by_role("button", name="Add", exact=True).locator("visible=true").first,
    )
    text_appears(page, "turn: move_joints")
    chromium.pick_option(page, "Primitive", "wait")
    chromium.type_into(page, "Duration [s]", "0.3")
    press(page, "Add")
    task = wait_until(
        lambda: c if isinstance(c := session.snapshot().command, m.Task) and len(c.actions) == 2 else None,
        what="the task stored",
    )
    assert task.actions[0] == m.Action("move_joints", {"q": pytest.approx(target, abs=2e-5)}, "turn")
    text_appears(page, "Task duration")
    view_is_clear(page, 300 if width < 1400 else 500)

    # kept in the library, under a name the user typed
    page.get_by_text("Library", exact=True).locator("visible=true").first.click()
    chromium.type_into(page, "Save as", "turn_wait")
    press(page, "task")
    wait_until(lambda: m.ProgramEntry("task", "turn_wait") in session.command(m.ListPrograms()), what="saved")
    wait_until(
        lambda: chromium.labelled_input(page, "Saved").input_value() == "task · turn_wait",
        what="the saved one picked",
    )

    # a second task: the composition becomes a mission
    chromium.type_into(page, "Task name", "back")
    press(page, "New")
    chromium.pick_option(page, "Primitive", "home")
    chromium.type_into(page, "Speed [%]", "250")
    press(page, "Add")
    text_appears(page, "The server refused back, action 1 (Speed)")
    reason = page.get_by_text("is outside").locator("visible=true").first.bounding_box()
    assert reason is not None and 0 <= reason["y"] < height - 10, f"the reason is out of sight: {reason}"
    assert session.snapshot().command == task
    page.screenshot(path=str(SHOTS / f"tasks_refused_{tag}.png"))
    chromium.type_into(page, "Speed [%]", "80")
    press(page, "Update")
    mission = wait_until(
        lambda: c if isinstance(c := session.snapshot().command, m.Mission) else None, what="a mission"
    )
    assert [t.name for t in mission.tasks] == ["task1", "back"]
    page.get_by_text("The server refused").wait_for(state="hidden")
    page.screenshot(path=str(SHOTS / f"tasks_{tag}.png"))
    if width < 1400:
        return
    # it runs, each step marked while it runs
    session.set_settings(stop_time=8.0, output_interval=0.01, pacing="realtime")
    page.get_by_role("button", name="Run", exact=True).click()
    marked = page.locator("td", has_text="⏵")
    wait_until(lambda: marked.count() == 1, timeout=30, interval=0.05, what="a step marked as running")
    page.screenshot(path=str(SHOTS / f"tasks_running_{tag}.png"))
    text_appears(page, "finished run", timeout=60)
    wait_until(lambda: marked.count() == 0, what="no step marked once the run is done")
