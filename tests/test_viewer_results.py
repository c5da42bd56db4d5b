"""Results, runs and the library in the viewer, without a page: CSV, recording names, the results
panel, text shown never run, the status line and run buttons, the settings form, error sentences."""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np
import pytest
from simecs.benchmarks.viewer import viewer_latency
from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.protocol.model import InitEquation
from simecs.mesh.rules import shapes, table_csv
from simecs.viewer import (
    export,
    identity,
    joints,
    library,
    path,
    results,
    run,
)
from simecs.viewer.errors import describe_error

from tests.viewer_fakes import arm


# -- results, run, library --------------------------------------------------------------------------
def test_csv_has_units_and_full_precision() -> None:
    rows = np.array([[0.0, 1 / 3], [0.002, 2.0]])
    data = table_csv.table_bytes(["time", "joint1.q"], rows, ["s", "rad"], {"run": "r1"}).decode()
    lines = data.splitlines()
    assert lines[:3] == ["# run: r1", "time,joint1.q", "s,rad"]
    assert float(lines[3].split(",")[1]) == 1 / 3
    back = np.loadtxt(data.splitlines()[3:], delimiter=",")
    assert np.array_equal(back, rows)
    assert export.csv_name("spider", "abcdefghijkl", "r3") == "simecs_spider_abcdefgh_r3.csv"


def test_uploaded_files_get_key_safe_recording_names() -> None:
    assert export.upload_name("C:\\\\runs\\\\my run (2).MCAP") == "my_run__2_"
    assert export.upload_name("/tmp/..hidden.mcap") == "hidden"
    assert export.upload_name("été.mcap") == "t_"
    assert export.upload_name(".mcap") == "upload"
    assert keys.check_name(export.upload_name("x" * 200 + ".mcap"), "recording name")
    # A run's name stays the run's: its downloaded file comes back as a copy.
    sid = keys.new_session_id()
    assert export.upload_name(f"{sid}_r12.mcap") == f"{sid}_r12-copy"
    assert export.upload_name(f"{sid}_r12.2.mcap") == f"{sid}_r12.2-copy"
    assert not keys.is_run_recording_name(export.upload_name(f"{sid}_r12.mcap"))


def test_results_panel_lists_runs_and_replays(server: Any) -> None:
    got: list[tuple[str, str]] = []
    panel = results.ResultsPanel(server.gui, lambda a, r: got.append((a, r)), lambda n, d: None)
    runs = [m.RunInfo("r1", "finished", 1.0, 1.0), m.RunInfo("r2", "running", 1.0, 0.4, recording="s_r1")]
    panel.show_runs(runs, "r2")
    assert panel.runs.options[0].startswith("r2") and "replay of s_r1" in panel.runs.options[0]
    assert panel.selected() == "r2"
    panel.runs.value = panel.runs.options[1]
    assert panel.selected() == "r1"


def test_text_from_a_model_or_the_server_is_shown_never_run() -> None:
    """viser renders raw HTML in markdown, scripts included: a model's names, summaries and equations
    and a server's reasons are escaped wherever they reach markdown (markup.py)."""
    evil = "<img src=x onerror=alert(1)>"
    model = arm()
    summary = library.model_markdown(msgspec.structs.replace(model.summary_entry(), name=evil, summary=evil))
    eqs = joints.init_equations_markdown([InitEquation("x", "q", evil)])
    failed = m.SessionState("s" * 22, "failed", run_id="r2", reason=evil, warnings=[evil])
    for shown in (summary, eqs, run.status_detail(failed)):
        assert "<img" not in shown and "&lt;img" in shown, shown


def test_status_line_and_run_buttons() -> None:
    st = m.SessionState("s" * 22, "running", run_id="r2", progress=0.5, sim_time=1.0, rtf=0.98)
    assert run.status_text(st) == "**running** run r2 · t = 1.000 s · 50 % · RTF 0.98"
    assert "**running** replay r2 of `s_r1`" in run.status_text(st, replay="s_r1")
    doing = msgspec.structs.replace(st, step="tasks[1].actions[0]", task="back", action="home")
    assert run.status_detail(doing) == "⏵ back · home"  # the step that runs, beside the run bar
    unnamed = msgspec.structs.replace(doing, task="", action="")
    assert run.status_detail(unnamed) == "⏵ task 2, action 1"  # counted as the tables count (issue 32, 9)
    assert path.step_words("nodes[0]") == "node 1" and path.step_words("signals") == "signals"
    failed = m.SessionState("s" * 22, "failed", run_id="r2", reason="diverged: 2*pi*f")
    assert "diverged" not in run.status_text(failed)  # the reason is in the session panel, as written:
    assert r"diverged: 2\*pi\*f" in run.status_detail(failed)  # stars, not emphasis (issue 32, 9)
    queued = m.SessionState("s" * 22, "queued", run_id="r3", queue_position=2)
    assert "position 2" in run.status_text(queued)
    assert run.applicable("finished") == ["Run"] and run.applicable("paused") == ["Resume", "Abort"]
    assert run.applicable("running") == ["Pause", "Abort"] and run.applicable("queued") == ["Abort"]
    assert set(run.RUN_BUTTONS.values()) == {"run", "pause", "resume", "abort"}


def test_settings_form_is_checked_before_sending() -> None:
    s = run.settings_from_form(2.0, 0.002, 0.0, "N x real time", 4.0, 50.0, ["joint1.q"])
    assert s.pacing == "scaled" and s.factor == 4.0 and s.live_vars == ["joint1.q"]
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(-1.0, 0.002, 0.0, "real time", 1.0, 50.0, [])
    assert err.value.field == "stop_time"
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(1.0, 2.0, 0.0, "real time", 1.0, 50.0, [])
    assert err.value.field == "output_interval"
    with pytest.raises(DecodeError):
        run.settings_from_form(1.0, 0.002, 0.0, "warp", 1.0, 50.0, [])
    # The control system by its title; the settings the form does not show are kept from `base`.
    base = m.RunSettings(controller="external", control_period=0.002, hil_timeout=5.0)
    s = run.settings_from_form(2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], base=base)
    assert (s.controller, s.control_period, s.hil_timeout, s.stop_time) == ("external", 0.002, 5.0, 2.0)
    s = run.settings_from_form(
        2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], "operational-space motion control"
    )
    assert s.control_system == "opspace_motion"
    with pytest.raises(DecodeError) as err:  # opspace_motion is built in: not with an external controller
        run.settings_from_form(
            2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], run.CONTROL_LABEL["opspace_motion"], base
        )
    assert err.value.field == "control_system"
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], "fuzzy control")
    assert err.value.field == "control_system"
    # what the service had and the page did not offer (issue 32): collisions, the external controller
    form = dict(stop_time=2.0, output_interval=0.002, step=0.0, pacing_label="real time", factor=1.0)
    s = run.settings_from_form(
        **form,
        live_rate=50.0,
        live_vars=[],
        collisions_label="simulate the contact",
        controller_label="external (on hil/actuators)",
        external_joints="joint1, joint3",
        control_period=0.002,
        hil_timeout=3.0,
    )
    assert (s.collisions, s.controller, s.external_joints) == ("simulate", "external", ["joint1", "joint3"])
    assert (s.control_period, s.hil_timeout) == (0.002, 3.0)
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(**form, live_rate=50.0, live_vars=[], control_period=1.0)
    assert err.value.field == "control_period"


def test_errors_read_as_sentences() -> None:
    e = RemoteError(
        m.Error("bad_request", "values.link2.mass: 9999 kg is outside [0, 500] kg", "values.link2.mass")
    )
    assert describe_error(e) == "9999 kg is outside [0, 500] kg (values.link2.mass)"
    assert describe_error(RemoteError(m.Error("conflict", "a run is running"))) == "a run is running"
    text = describe_error(NoReply("no node answered simecs/library within 10.0 s"))
    assert text == "no simecs node answered: is the service running? (simecs/library)"
    assert describe_error(path.PathError("the path is empty")) == "the path is empty"


def test_user_names_and_model_summaries() -> None:
    assert identity.valid_user(" ada ") == "ada"
    with pytest.raises(ValueError):
        identity.valid_user("no spaces")
    assert identity.valid_user(identity.new_user_name())
    text = library.model_markdown(arm().summary_entry())
    assert "3 joints" in text and "joint path" in text
    entry = m.SessionEntry("abcdefghijklmnopqrstuv", "arm3", "finished")
    assert library.session_label(entry) == "arm3 · finished · abcdefgh"


def test_bench_reads_the_viewer_latency_from_its_log() -> None:
    log = "x\n2026 INFO viewer tab 0: first live frame of r1 drawn 129 ms after the click\n"
    assert viewer_latency(log) == pytest.approx(0.129)
    assert viewer_latency("nothing") is None


def test_spider_appearance_parameters_reshape_its_shapes() -> None:
    """Every appearance parameter of the real Spider description reshapes what the viewer draws."""
    from simecs.models import get_model  # the description as the proxy sends it; the viewer gets it as data

    desc = get_model("spider").describe()
    defaults = desc.default_values()
    changed = dict(defaults)
    changed.update(
        {"payload.size": 2 * defaults["payload.size"], "link7.radius": 1.5 * defaults["link7.radius"]}
    )
    changed["link7.length"] = defaults["link7.length"] + 0.1
    before = [shapes.effective_shape(s, desc, defaults, defaults) for s in desc.shapes]
    after = [shapes.effective_shape(s, desc, changed, defaults) for s in desc.shapes]
    payload = next(i for i, s in enumerate(desc.shapes) if s.kind == "box" and s.link == 6)
    assert after[payload].width == pytest.approx(2 * before[payload].width)
    assert after[payload].origin[0] == pytest.approx(before[payload].origin[0] + 0.1)
    tube = next(i for i, s in enumerate(desc.shapes) if s.resizable and s.link == 6)
    assert after[tube].radius == pytest.approx(1.5 * before[tube].radius)
    assert after[tube].length == pytest.approx(before[tube].length + 0.1)
    appearance = {p.name for p in desc.parameters if p.appearance}
    tied = {v for s in desc.shapes for v in s.scales_with.values()} | {lk.length_param for lk in desc.links}
    assert appearance == tied
    assert shapes.appearance_parameters(desc) == appearance | {lk.length_param for lk in desc.links}


def test_status_line_shows_warnings() -> None:
    st = m.SessionState(session="s", phase="finished", run_id="r1", warnings=["recorder: gaps"])
    assert "⚠ recorder: gaps" in run.status_detail(st)
