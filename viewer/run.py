"""The toolbar and the time presentation (paper §3.2, §5.2): windows to open, the run's progress
with simulated time and real-time factor, and run / pause / resume / abort; plus the simulation
settings window (paper §2.2 step 6).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from simecs.mesh.protocol import codec, phases, session_commands
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.protocol.model import CONTROL_SYSTEM_TITLES

from .camera import VIEWS
from .markup import escape_html, escape_text
from .path import step_words

PACING = {"real time": "realtime", "N x real time": "scaled", "as fast as possible": "fast"}
PACING_LABEL = {v: k for k, v in PACING.items()}
CONTROL_LABEL = dict(CONTROL_SYSTEM_TITLES)
CONTROL = {v: k for k, v in CONTROL_LABEL.items()}
#: RunSettings.collisions as the settings window words it.
COLLISIONS = {
    "refuse a run that would touch": "refuse",
    "simulate the contact": "simulate",
}
#: RunSettings.controller as the settings window words it.
CONTROLLERS = {
    "built in (the model's)": "builtin",
    "external (on hil/actuators)": "external",
}
TOOLBAR = ("Models", "Initialise", "Settings", "Documentation")
#: Run buttons and the session command each sends (the phase table says when it applies).
RUN_BUTTONS = {"Run": "run", "Pause": "pause", "Resume": "resume", "Abort": "abort"}


def status_text(st: m.SessionState | None, replay: str = "", until_stopped: bool = False) -> str:
    """One line a user can read at a glance: phase, which run (a replay names its recording), time,
    progress (a run until stopped has none: it says so), speed. The run bar shows it; what else the
    run says is `status_detail`'s."""
    if st is None:
        return "_No session: choose a model (Models)._"
    what = f"run {st.run_id}" if st.run_id else ""
    if replay:
        what = f"replay {st.run_id} of `{escape_html(replay)}`"
    if st.phase == "queued":
        return f"**queued** {what}: position {st.queue_position} (the server is busy with other runs)"
    if st.phase in (*phases.GOING, *phases.ENDED):
        done = "until stopped" if until_stopped else f"{st.progress * 100:.0f} %"
        progress = f"t = {st.sim_time:.3f} s · {done} · RTF {st.rtf:.2f}"
        return f"**{st.phase}** {what} · {progress}"
    return f"**{st.phase}**: ready to run"


def status_detail(st: m.SessionState | None) -> str:
    """What the run says besides its progress: the step that runs, why it ended early, warnings."""
    if st is None:
        return ""
    parts = []
    doing = " · ".join(x for x in (st.task, st.action) if x) or step_words(st.step)
    if doing and st.phase in phases.GOING:  # the step of a task or path that runs now
        parts.append(f"⏵ {escape_html(doing)}")
    if st.reason and st.phase in ("aborted", "failed"):
        parts.append(escape_text(st.reason))
    parts += [f"⚠ {escape_text(warning)}" for warning in st.warnings]
    return "\n\n".join(parts)


def applicable(phase: str) -> list[str]:
    """The run buttons that act in `phase` (the others say why not when clicked)."""
    return [label for label, op in RUN_BUTTONS.items() if not session_commands.refusal(op, phase)]


#: The run bar's hint: what its buttons do, and the keys that do the same.
RUN_BAR_HINT = (
    "Preview plays the planned move on the goal ghost (nothing runs); Run starts a run (the pending edits "
    "first); Pause holds it, Resume goes on, Abort ends it now (its results so far are kept). Keys: "
    "Space pauses or resumes, Esc aborts."
)
#: The page's run keys (browser.install_page_rules): the key (its KeyboardEvent.code) and the run buttons
#: it clicks, the first that acts in the phase; with what the run bar's second line calls it.
RUN_KEYS = {"Space": ("Space", ("Pause", "Resume")), "Escape": ("Esc", ("Abort",))}
KEY_VERBS = {"Pause": "pauses", "Resume": "resumes", "Abort": "aborts"}


def key_buttons(phase: str) -> dict[str, str]:
    """Which run button each key clicks in `phase` (the keys that do nothing there left out)."""
    ops = applicable(phase)
    return {
        code: next(b for b in buttons if b in ops)
        for code, (_name, buttons) in RUN_KEYS.items()
        if any(b in ops for b in buttons)
    }


def keys_text(phase: str) -> str:
    """The run bar's word on the keys that act now: " · keys: Space pauses, Esc aborts"."""
    acts = [f"{RUN_KEYS[code][0]} {KEY_VERBS[button]}" for code, button in key_buttons(phase).items()]
    if not acts:
        return ""
    return f" · {'keys' if len(acts) > 1 else 'key'}: " + ", ".join(acts)


PREVIEW = "Preview"  # the run bar's button that plays the plan on the ghost (MoveIt's Plan before Execute)


class RunBar:
    """The run's controls, which never hide (paper §3.2 Time Presentation): the status line, the
    progress bar and Run, Pause, Resume, Abort, in a window of their own floating at the foot of the
    3D view, sized to its content (so never scrolled away, whatever the docks around it do), and
    under them what the run says besides its progress (the step that runs, why it ended, warnings).
    A button that does not apply now says why when clicked; the line under the status says which
    apply."""

    def __init__(self, gui: Any, on_run: Callable[[str], None], on_preview: Callable[[], None]) -> None:
        self.panel = gui.add_panel()
        self.tab = self.panel.add_tab("Run")  # the page's timeline goes in it too (timeline.py)
        with self.tab:
            self.status = gui.add_markdown("_Choose a model to start._")
            self.progress = gui.add_progress_bar(0.0, animated=False)
            self.buttons = gui.add_button_group("Run", (PREVIEW, *RUN_BUTTONS), hint=RUN_BAR_HINT)
            self.buttons.on_click(
                lambda e: (
                    on_preview() if e.target.value == PREVIEW else on_run(RUN_BUTTONS[str(e.target.value)])
                )
            )
            self.readout = gui.add_markdown("")  # the arm's joints and tool, as shown (readout.py)
            self.detail = gui.add_markdown("")

    def show_readout(self, text: str) -> None:
        if self.readout.content != text:
            self.readout.content = text

    def show(self, st: m.SessionState | None, replay: str = "", until_stopped: bool = False) -> None:
        ops = applicable(st.phase) if st is not None else []
        line = status_text(st, replay, until_stopped)
        if st is not None:
            now = " or ".join(ops) if ops else "nothing to do"
            line += "  \n<small>now: " + now + keys_text(st.phase) + "</small>"
        if self.status.content != line:
            self.status.content = line
        detail = status_detail(st)
        if self.detail.content != detail:
            self.detail.content = detail
        progress = 0.0 if st is None else max(0.0, min(100.0, st.progress * 100.0))
        if until_stopped and st is not None and st.phase in phases.GOING:
            progress = 100.0  # a run until stopped: the bar says it goes, not how far
        if abs(self.progress.value - progress) > 1e-6:
            self.progress.value = progress
        running = st is not None and st.phase in phases.UNDER_WAY and st.phase != "paused"
        self.progress.animated = running
        color = None
        if st is not None:
            color = {"failed": "red", "aborted": "yellow", "finished": "green"}.get(st.phase)
        self.progress.color = color


class Toolbar:
    """The paper's toolbar (§5.2), at the top of the trees' column: the windows to open and the camera
    presets. `on_window` and `on_view` get the clicked label."""

    def __init__(self, gui: Any, on_window: Callable[[str], None], on_view: Callable[[str], None]) -> None:
        self.windows = gui.add_button_group("Windows", TOOLBAR)
        self.windows.on_click(lambda e: on_window(e.target.value))
        self.views = gui.add_button_group("View", VIEWS)
        self.views.on_click(lambda e: on_view(e.target.value))


def settings_from_form(
    stop_time: float,
    output_interval: float,
    step: float,
    pacing_label: str,
    factor: float,
    live_rate: float,
    live_vars: list[str],
    control_label: str = CONTROL_LABEL["joint_independent"],
    base: m.RunSettings | None = None,
    collisions_label: str | None = None,
    controller_label: str | None = None,
    external_joints: str | None = None,
    control_period: float | None = None,
    hil_timeout: float | None = None,
) -> m.RunSettings:
    """RunSettings from the form's fields over `base` (the settings the form does not show, e.g. an
    external controller's, are kept); DecodeError names the field when one is out of range."""
    pacing = PACING.get(pacing_label)
    if pacing is None:
        raise DecodeError("pacing", f"unknown pacing {pacing_label!r}")
    control = CONTROL.get(control_label)
    if control is None:
        raise DecodeError("control_system", f"unknown control system {control_label!r}")
    form = {
        "stop_time": float(stop_time),
        "output_interval": float(output_interval),
        "step": float(step),
        "pacing": pacing,
        "factor": float(factor),
        "live_rate_hz": float(live_rate),
        "live_vars": list(live_vars),
        "control_system": control,
    }
    if collisions_label is not None:
        if collisions_label not in COLLISIONS:
            raise DecodeError("collisions", f"unknown choice {collisions_label!r}")
        form["collisions"] = COLLISIONS[collisions_label]
    if controller_label is not None:
        if controller_label not in CONTROLLERS:
            raise DecodeError("controller", f"unknown controller {controller_label!r}")
        form["controller"] = CONTROLLERS[controller_label]
    if external_joints is not None:
        form["external_joints"] = [j for j in external_joints.replace(",", " ").split() if j]
    if control_period is not None:
        form["control_period"] = float(control_period)
    if hil_timeout is not None:
        form["hil_timeout"] = float(hil_timeout)
    kept = codec.to_obj(base) if base is not None else {}
    # the bounds of the protocol, checked as the server will
    return codec.from_obj(m.RunSettings, {**kept, **form})


class SettingsWindow:
    """A modal with the run settings; Apply sends them (the server checks them again)."""

    def __init__(
        self,
        gui: Any,
        settings: m.RunSettings,
        on_apply: Callable[[dict[str, Any]], None],
        control_systems: Sequence[str] = ("joint_independent",),
    ) -> None:
        self.modal = gui.add_modal("Simulation settings")
        with self.modal:
            self.stop = gui.add_number("Stop time [s]", settings.stop_time, step=0.1, hint="(0, 3600] s")
            self.out = gui.add_number(
                "Output interval [s]",
                settings.output_interval,
                step=0.0001,
                hint="time between samples of the results",
            )
            self.step = gui.add_number(
                "Solver step [s]",
                settings.step,
                step=0.0001,
                hint="0 = the model's default; otherwise [1e-5, 0.01] s",
            )
            self.pacing = gui.add_dropdown(
                "Pacing", tuple(PACING), initial_value=PACING_LABEL.get(settings.pacing, "real time")
            )
            self.factor = gui.add_number(
                "N (for N x real time)", settings.factor, step=0.1, hint="[0.01, 1000]"
            )
            self.rate = gui.add_number(
                "Live rate [Hz]", settings.live_rate_hz, step=1.0, hint="frames per second sent to this page"
            )
            self.control = gui.add_dropdown(
                "Control system",
                tuple(CONTROL_LABEL[c] for c in control_systems),
                initial_value=CONTROL_LABEL[settings.control_system],
                hint="what drives the joints: each joint's cascade, the tool tracked in task space, or "
                "that with force control where a Cartesian node sets a force (the model's documentation, "
                "Control systems)",
            )
            self.collisions = gui.add_dropdown(
                "Obstacles",
                tuple(COLLISIONS),
                initial_value=_label_of(COLLISIONS, settings.collisions),
                hint="refuse: a run whose planned path touches an obstacle is refused, naming the step; "
                "simulate: it runs, and the contact is simulated (forces drawn as arrows)",
            )
            with gui.add_folder("External controller (hardware in the loop)", expand_by_default=False):
                self.controller = gui.add_dropdown(
                    "Controller",
                    tuple(CONTROLLERS),
                    initial_value=_label_of(CONTROLLERS, settings.controller),
                    hint="external: a controller of yours drives the joints over the mesh, one exchange per "
                    "control period (PROTOCOL.md §6.3, examples/external_controller.py)",
                )
                self.external_joints = gui.add_text(
                    "Joints it drives",
                    " ".join(settings.external_joints),
                    hint="joint names separated by spaces; empty: every joint",
                )
                self.period = gui.add_number(
                    "Control period [s]", settings.control_period, step=0.0001, hint="[1e-4, 0.1] s"
                )
                self.hil_timeout = gui.add_number(
                    "Controller timeout [s]",
                    settings.hil_timeout,
                    step=0.1,
                    hint="wall time without an actuator frame before the run fails, [0.05, 60] s",
                )
            apply = gui.add_button("Apply settings", color="green")
            apply.on_click(lambda _e: on_apply(self.values()))
            cancel = gui.add_button("Cancel", color="gray")
            cancel.on_click(lambda _e: self.close())

    def values(self) -> dict[str, Any]:
        return {
            "stop_time": float(self.stop.value),
            "output_interval": float(self.out.value),
            "step": float(self.step.value),
            "pacing_label": str(self.pacing.value),
            "factor": float(self.factor.value),
            "live_rate": float(self.rate.value),
            "control_label": str(self.control.value),
            "collisions_label": str(self.collisions.value),
            "controller_label": str(self.controller.value),
            "external_joints": str(self.external_joints.value),
            "control_period": float(self.period.value),
            "hil_timeout": float(self.hil_timeout.value),
        }

    def close(self) -> None:
        if not self.modal.closed:
            self.modal.close()


def _label_of(labels: dict[str, str], value: str) -> str:
    return next((k for k, v in labels.items() if v == value), next(iter(labels)))
