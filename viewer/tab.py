"""One browser tab = one user with their own session (paper §3.2: the Simulation Interface, which
instantiates every visual sub-component and gives it its place on screen).

A `Tab` owns the tab's session on the server and wires the panels to it: every request goes
through `simecs.mesh.client` on a worker thread of the tab (viser's callbacks and zenoh's never
wait on the server), every refusal comes back as a readable notification, and every published
state, parameter change and live frame is drawn as it arrives.

Layout (figure 9): the parameter / variable / results tabs docked left, the 3D prototype in the
centre, the toolbar with the time presentation on top, the joint command panel at the bottom, plots
docked right; the models, initialisation, settings and documentation windows open from the toolbar.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from simecs.mesh import frames, keys
from simecs.mesh import messages as m
from simecs.mesh.client import NoReply, RemoteError, SessionClient, Watch
from simecs.mesh.codec import DecodeError
from simecs.mesh.model import ModelDescription

from . import browser
from .docs import DocsWindow
from .joints import InitPanel, clamp_to_limits
from .library import LibraryWindow, new_user_name, valid_user
from .params import ParamPanel, VariablePanel
from .pendant import JointPathEditor, PathError, PendantPanel
from .plots import LiveBuffer, Plot, PlotActions, Transient, every_for
from .results import ResultsPanel, csv_name, to_csv
from .run import ACTIVE, SettingsWindow, Toolbar, run_action_refusal, settings_from_form
from .scene import ArmScene, pose_indices

if TYPE_CHECKING:
    from .app import Viewer

log = logging.getLogger("simecs.viewer")

SYNC_DELAY_S = 0.25  # an edit is sent once the user paused this long (sliders fire on every move)
ENDED = ("finished", "aborted", "failed")


def required_streams(model: ModelDescription) -> list[str]:
    """Variables always streamed: each joint's position, so Teach knows the pose after a run."""
    names = {v.name for v in model.variables}
    return [f"{link.joint}.q" for link in model.links if f"{link.joint}.q" in names]


class ModelUI:
    """Everything drawn for one loaded model; removed as a whole when the tab changes model."""

    def __init__(self) -> None:
        self.handles: list[Any] = []  # root GUI elements and panels
        self.scene: ArmScene | None = None
        self.params: ParamPanel | None = None
        self.variables: VariablePanel | None = None
        self.results: ResultsPanel | None = None
        self.pendant: PendantPanel | None = None
        self.init_panel: Any = None
        self.init_widget: InitPanel | None = None
        self.docs: DocsWindow | None = None
        self.plots_panel: Any = None
        self.plots_tab: Any = None
        self.header: Any = None

    def remove(self) -> None:
        if self.docs is not None:
            self.docs.close()
        for h in [self.init_panel, self.plots_panel, *self.handles]:
            if h is None:
                continue
            try:
                h.remove()
            except Exception:
                pass
        if self.scene is not None:
            self.scene.remove()


class Tab:
    """The session and the panels of one browser tab."""

    def __init__(self, viewer: Viewer, client: Any) -> None:
        self.viewer = viewer
        self.client = client
        self.gui = client.gui
        self.mc = viewer.mc
        self.lock = threading.RLock()
        self.cmd_pool = ThreadPoolExecutor(1, thread_name_prefix=f"tab{client.client_id}-cmd")
        self.io_pool = ThreadPoolExecutor(1, thread_name_prefix=f"tab{client.client_id}-io")
        self.closed = False
        self.user = ""
        self.session: SessionClient | None = None
        self.model: ModelDescription | None = None
        self.values: dict[str, float] = {}
        self.settings = m.RunSettings()
        self.streamed: set[str] = set()
        self.initial: list[float] = []
        self.shown_q: list[float] = []
        self.state: m.SessionState | None = None
        self.layout: m.RunLayout | None = None
        self.runs: list[m.RunInfo] = []
        self.watch: Watch | None = None
        self.replay_id = ""
        self.replay_state: m.SessionState | None = None
        self.replay_watch: Watch | None = None
        self.ui: ModelUI | None = None
        self.path: JointPathEditor | None = None
        self.plots: list[Plot] = []
        self.plot_counter = 0
        self.live = LiveBuffer()
        self.pose_idx: np.ndarray | None = None
        self.q_idx: list[int] | None = None
        self.units: dict[str, str] = {}
        self._due: dict[str, float] = {}
        self._notified_end: set[str] = set()
        self._library: LibraryWindow | None = None
        self._settings_window: SettingsWindow | None = None
        self.live_frames = 0  # frames drawn (diagnostics)
        self._clicked_at = 0.0
        self._first_live = False
        self.toolbar: Toolbar | None = None

    # ================================================================================================
    # lifecycle
    def start(self) -> None:
        """Build the page, find out who this is and which session the tab had, and restore it."""
        gui = self.gui
        gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        gui.main_panel.dock_left()
        gui.main_panel.set_width(400)
        gui.set_panel_label("simecs")
        self.client.scene.set_up_direction("+z")
        self.toolbar = Toolbar(gui, self._on_window, self._on_run_button)
        memory = browser.recall(self.client)
        if self.closed:
            return
        user = memory.user or self.viewer.default_user or new_user_name()
        try:
            self.user = valid_user(user)
        except ValueError:
            self.user = new_user_name()
        if self.user != memory.user:
            browser.remember_user(self.client, self.user)
        if (
            memory.session
            and keys.is_session_id(memory.session)
            and self._attach(memory.session, quiet_missing=True)
        ):
            return
        self.open_library(can_dismiss=False)

    def close(self) -> None:
        """The tab went away (closed or reloading): keep the session, drop the subscriptions."""
        with self.lock:
            self.closed = True
            if self.session is not None:
                self.viewer.release(self.session.id, self)
        self._stop_watches()
        self.cmd_pool.shutdown(wait=False, cancel_futures=True)
        self.io_pool.shutdown(wait=False, cancel_futures=True)

    def _stop_watches(self) -> None:
        """Drop this tab's subscriptions (and its replay, if one is shown); never under `self.lock`,
        since a watch worker may be waiting for that lock while its watch is being closed."""
        with self.lock:
            watches = [w for w in (self.watch, self.replay_watch) if w is not None]
            replay = self.replay_id
            self.watch, self.replay_watch, self.replay_id = None, None, ""
        if replay:
            try:
                self.mc.session(replay).close()
            except Exception:
                pass
        for w in watches:
            try:
                w.close()
            except Exception:
                pass

    # ================================================================================================
    # talking to the server and to the user
    def notify(self, title: str, body: str, kind: str = "info") -> None:
        browser.notify(self.client, title, body, kind)

    def error(self, what: str, exc: BaseException) -> None:
        """A failed request as the user should read it; unexpected failures are logged too."""
        if not isinstance(exc, RemoteError | NoReply | TimeoutError | PathError | DecodeError | ValueError):
            log.exception("tab %s: %s failed", self.client.client_id, what, exc_info=exc)
        kind = "warning" if isinstance(exc, RemoteError) and exc.code == "conflict" else "error"
        self.notify(what, browser.describe_error(exc) if not isinstance(exc, PathError) else str(exc), kind)

    def submit(self, what: str, job: Callable[[], Any], pool: str = "cmd") -> None:
        """Run `job` on the tab's worker (commands in order; data fetches on their own)."""
        if self.closed:
            return

        def run() -> None:
            try:
                job()
            except Exception as exc:
                if not self.closed:
                    self.error(what, exc)

        try:
            (self.cmd_pool if pool == "cmd" else self.io_pool).submit(run)
        except RuntimeError:  # pool shut down: the tab is closing
            pass

    # ================================================================================================
    # sessions
    def open_library(self, can_dismiss: bool = True) -> None:
        def job() -> None:
            try:
                models = self.mc.list_models()
            except (RemoteError, NoReply) as exc:
                self.error("Cannot list the models", exc)
                models = []
            try:
                sessions = self.mc.list_sessions(self.user)
            except (RemoteError, NoReply):
                sessions = []
            with self.lock:
                if self._library is not None:
                    self._library.close()
                self._library = LibraryWindow(
                    self.gui,
                    self.user,
                    models,
                    sessions,
                    self.session.id if self.session else "",
                    on_load=self._load_model,
                    on_open=lambda sid: self.submit("Open session", lambda: self._switch(sid)),
                    on_close_session=self._close_other,
                    on_user=self._set_user,
                    can_dismiss=can_dismiss and self.session is not None,
                )

        self.submit("Models", job)

    def _set_user(self, name: str) -> None:
        try:
            self.user = valid_user(name)
        except ValueError as exc:
            self.notify("User name refused", str(exc), "error")
            return
        browser.remember_user(self.client, self.user)
        self.notify("User", f"You are now **{self.user}**; reopen Models to see this user's sessions.", "ok")

    def _load_model(self, model_id: str) -> None:
        def job() -> None:
            sc = self.mc.create_session(self.user, model_id)
            self._switch(sc.id, sc.created)

        self.submit(f"Load {model_id}", job)

    def _switch(self, sid: str, snapshot: m.SessionSnapshot | None = None) -> None:
        if self.session is not None and self.session.id == sid:
            self._close_library()
            return
        if self._attach(sid, snapshot=snapshot):
            self._close_library()

    def _close_library(self) -> None:
        if self._library is not None:
            self._library.close()
            self._library = None

    def _close_other(self, sid: str) -> None:
        def job() -> None:
            if self.viewer.claimed_by_other(sid, self):
                raise ValueError("that session is open in another tab: close it there")
            self.mc.session(sid).close()
            self.notify("Session closed", f"Session {sid[:8]}… is closed.", "ok")
            self.open_library(can_dismiss=True)

        self.submit("Close session", job)

    def _attach(
        self, sid: str, snapshot: m.SessionSnapshot | None = None, quiet_missing: bool = False
    ) -> bool:
        """Make `sid` this tab's session: restore its values, pose, command, settings and runs."""
        if not self.viewer.claim(sid, self):
            self.notify(
                "Session already open",
                "That session is shown in another tab; each tab works on its own session. "
                "Choose a model to start a new one, or close the other tab.",
                "warning",
            )
            return False
        sc = self.mc.session(sid)
        try:
            snap = snapshot or sc.snapshot()
            model = self.viewer.describe(snap.model_id)
        except (RemoteError, NoReply) as exc:
            self.viewer.release(sid, self)
            if quiet_missing and isinstance(exc, RemoteError) and exc.code == "not_found":
                self.notify(
                    "Previous session ended", "Your previous session is no longer on the server.", "info"
                )
                browser.remember_session(self.client, "")
            else:
                self.error("Cannot open the session", exc)
            return False
        self._stop_watches()
        with self.lock:
            if self.closed:
                self.viewer.release(sid, self)
                return False
            old = self.session
            if old is not None and old.id != sid:
                self.viewer.release(old.id, self)
            self.session = sc
            self._build(model, snap)
        browser.remember_session(self.client, sid)
        browser.set_title(self.client, f"simecs · {model.name}")
        self.watch = sc.watch(
            on_state=self._on_state,
            on_params=self._on_params,
            on_layout=self._on_layout,
            on_live=lambda f: self._on_live(f, sid),
        )
        self.submit("Results", self._refresh_runs, pool="io")
        self.submit("Parameter sets", self._refresh_sets, pool="io")
        return True

    # ================================================================================================
    # building the page for a model
    def _build(self, model: ModelDescription, snap: m.SessionSnapshot) -> None:
        gui, client = self.gui, self.client
        if self.ui is not None:
            self.ui.remove()
        for plot in self.plots:
            plot.remove()
        self.plots.clear()
        self.model = model
        self.values = dict(snap.values)
        self.settings = snap.settings
        self.state = snap.state
        self.runs = list(snap.runs)
        self.layout = None
        self._notified_end = {r.run_id for r in snap.runs if r.phase in ENDED}
        self.units = {v.name: v.unit for v in model.variables}
        self.initial = clamp_to_limits(snap.initial or [0.0] * len(model.links), model.links)
        self.shown_q = list(self.initial)
        every = {v.name for v in model.variables}
        self.streamed = set(snap.settings.live_vars) & every if snap.settings.live_vars else set(every)
        self.path = JointPathEditor(model.links)
        if isinstance(snap.command, m.JointPath):
            self.path.load(snap.command)
        ui = self.ui = ModelUI()

        with client.atomic():
            ui.header = gui.add_markdown(self._header_text())
            ui.handles.append(ui.header)
            tabs = gui.add_tab_group()
            ui.handles.append(tabs)
            with tabs.add_tab("Parameters"):
                ui.params = ParamPanel(
                    gui, model, self.values, self._set_param, self._reset_params, self._set_op
                )
            with tabs.add_tab("Variables"):
                ui.variables = VariablePanel(gui, model, self.streamed, self._set_streamed, self.open_plot)
            with tabs.add_tab("Results"):
                ui.results = ResultsPanel(
                    gui,
                    self._on_results_action,
                    lambda name, data: self.submit("Upload", lambda: self._upload(name, data), "io"),
                )
                ui.results.show_runs(self.runs)

            ui.scene = ArmScene(client.scene, model, self.values)
            ui.scene.q = list(self.initial)
            ui.scene.build()
            reach = ui.scene.extent()
            client.camera.position = (1.3 * reach, -1.4 * reach, 1.0 * reach)
            client.camera.look_at = (0.0, 0.0, 0.25 * reach)

            command = gui.add_panel()
            ui.handles.append(command)
            with command.add_tab("Joint path"):
                if "joint_path" in model.command_levels:
                    ui.pendant = PendantPanel(
                        gui,
                        self.path,
                        current_q=lambda: list(self.shown_q),
                        on_changed=lambda: self._later("command"),
                        on_preview=self._preview,
                        on_error=lambda msg: self.notify("Joint path", msg, "warning"),
                    )
                else:
                    levels = ", ".join(model.command_levels) or "none"
                    gui.add_markdown(
                        f"_This model accepts {levels} commands; this viewer edits joint paths._"
                    )
            command.float(x=12, y=-12, width=620, height=360)
        self._show_state()

    def _header_text(self) -> str:
        if self.model is None or self.session is None:
            return ""
        return (
            f"**{self.model.name}**  \nuser `{self.user}` · session `{self.session.id[:8]}…`  \n"
            f"<small>{self.model.summary}</small>"
        )

    # ================================================================================================
    # toolbar
    def _on_window(self, name: str) -> None:
        if name == "Models":
            self.open_library(can_dismiss=True)
            return
        if self.model is None or self.ui is None:
            self.notify(name, "Load a model first (Models).", "warning")
            return
        if name == "Initialise":
            self.toggle_init()
        elif name == "Settings":
            self.open_settings()
        elif name == "Documentation":
            self.toggle_docs()

    def toggle_init(self) -> None:
        ui, model = self.ui, self.model
        assert ui is not None and model is not None
        with self.lock:
            if ui.init_panel is not None:
                ui.init_panel.remove()
                ui.init_panel, ui.init_widget = None, None
                return
            ui.init_panel = self.gui.add_panel()
            with ui.init_panel.add_tab("Initialisation"):
                ui.init_widget = InitPanel(
                    self.gui,
                    model.links,
                    model.init_equations,
                    self.initial,
                    self._set_initial,
                    self._zero_initial,
                )
                close = self.gui.add_button("Close initialisation", color="gray")
                close.on_click(lambda _e: self.toggle_init())
            ui.init_panel.float(x=-12, y=190, width=380)
            if self.state is not None and self.state.phase in ACTIVE:
                ui.init_widget.sliders.set_disabled(True)
        self._preview(self.initial)

    def _set_initial(self, q: list[float]) -> None:
        self.initial = list(q)
        self._preview(q)
        self._later("initial")

    def _zero_initial(self) -> None:
        if self.model is None or self.ui is None or self.ui.init_widget is None:
            return
        q = [0.0] * len(self.model.links)
        self.ui.init_widget.sliders.set_q(q)
        self._set_initial(clamp_to_limits(q, self.model.links))

    def _preview(self, q: list[float]) -> None:
        """Kinematic simulation: show the arm at `q` at once."""
        if self.ui is None or self.ui.scene is None:
            return
        self.shown_q = list(q)
        with self.client.atomic():
            self.ui.scene.show_q(q)

    def open_settings(self) -> None:
        if self._settings_window is not None:
            self._settings_window.close()
        self._settings_window = SettingsWindow(self.gui, self.settings, self._apply_settings)

    def _apply_settings(self, form: dict[str, Any]) -> None:
        try:
            settings = settings_from_form(live_vars=sorted(self.streamed), **form)
        except DecodeError as exc:
            self.notify("Settings refused", f"{exc.field}: {exc.problem}", "error")
            return

        def job() -> None:
            assert self.session is not None
            self.session.command(m.SetSettings(settings))
            self.settings = settings
            if self._settings_window is not None:
                self._settings_window.close()
            self.notify("Settings", f"Stop time {settings.stop_time:g} s, pacing {settings.pacing}.", "ok")

        self.submit("Settings refused", job)

    def toggle_docs(self) -> None:
        ui, model = self.ui, self.model
        assert ui is not None and model is not None
        if ui.docs is None:
            ui.docs = DocsWindow(self.gui, model.docs, model.doc_root, self._fetch_doc)
        if ui.docs.is_open:
            ui.docs.close()
        else:
            ui.docs.open()

    def _fetch_doc(self, page: str) -> Any:
        if self.model is None:
            return None
        try:
            return self.mc.doc(self.model.id, page)
        except (RemoteError, NoReply, ValueError) as exc:
            self.error("Documentation", exc)
            return None

    # ================================================================================================
    # parameters and variables
    def _set_param(self, name: str, value: float) -> None:
        model, ui = self.model, self.ui
        if model is None or ui is None or self.session is None:
            return
        p = model.parameter(name)
        if p.appearance and ui.scene is not None:  # the 3D arm reshapes at once; undone if refused
            with self.client.atomic():
                ui.scene.set_values({**self.values, name: value})

        def job() -> None:
            assert self.session is not None
            try:
                values = self.session.set_params({name: value})
            except (RemoteError, NoReply) as exc:
                self._show_values(self.values)
                self.error(f"{name} not changed", exc)
                return
            self._show_values(values)

        self.submit(f"{name} not changed", job)

    def _reset_params(self, names: list[str]) -> None:
        def job() -> None:
            assert self.session is not None
            values = self.session.reset_params(names)
            self._show_values(values)
            self.notify("Parameters", f"{len(names) or 'All'} parameter(s) back to their defaults.", "ok")

        self.submit("Reset refused", job)

    def _set_op(self, op: str, name: str) -> None:
        def job() -> None:
            assert self.session is not None
            if op in ("load", "delete") and name in ("", "(none)"):
                raise ValueError("no saved set chosen")
            if op == "save":
                self.session.save_param_set(name)
                self.notify("Parameter set saved", f"Saved **{name}**.", "ok")
            elif op == "load":
                self._show_values(self.session.load_param_set(name))
                self.notify("Parameter set loaded", f"Loaded **{name}**.", "ok")
            elif op == "delete":
                self.session.delete_param_set(name)
                self.notify("Parameter set deleted", f"Deleted **{name}**.", "ok")
            self._refresh_sets()

        self.submit(f"Parameter set {op}", job)

    def _refresh_sets(self) -> None:
        if self.session is None or self.ui is None or self.ui.params is None:
            return
        self.ui.params.set_names(self.session.list_param_sets())

    def _show_values(self, values: dict[str, float]) -> None:
        with self.lock:
            self.values = dict(values)
            ui = self.ui
            if ui is None:
                return
            with self.client.atomic():
                if ui.params is not None:
                    ui.params.show_values(self.values)
                if ui.scene is not None:
                    ui.scene.set_values(self.values)

    def _set_streamed(self, wanted: set[str]) -> None:
        if self.model is None:
            return
        plotted = {v for p in self.plots for v in p.variables}
        self.streamed = set(wanted) | set(required_streams(self.model)) | (plotted if not wanted else set())
        if self.ui is not None and self.ui.variables is not None:
            self.ui.variables.show_streamed(self.streamed)
        self._later("settings")

    # ================================================================================================
    # the joint path and the run
    def _later(self, what: str) -> None:
        """Send `what` (initial / command / settings) once edits pause (see tick)."""
        self._due[what] = time.monotonic() + SYNC_DELAY_S

    def _sync(self, what: str) -> None:
        """Send one pending edit to the server (on the command worker)."""
        sc, model = self.session, self.model
        if sc is None or model is None:
            return
        if what == "initial":
            sc.set_initial(self.initial)
        elif what == "command":
            if self.path is not None and self.path.nodes:
                sc.command(m.SetCommand(self.path.to_command()))
        elif what == "settings":
            every = {v.name for v in model.variables}
            live = [] if self.streamed >= every else sorted(self.streamed)
            settings = replace(self.settings, live_vars=live)
            sc.command(m.SetSettings(settings))
            self.settings = settings

    def _flush(self) -> None:
        for what in ("initial", "command", "settings"):
            if self._due.pop(what, None) is not None:
                self._sync(what)

    def _on_run_button(self, action: str) -> None:
        self._clicked_at = time.monotonic()
        if self.session is None:
            self.notify(action, "Load a model first (Models).", "warning")
            return
        if self.replay_id:
            self._replay_control(action)
            return
        phase = self.state.phase if self.state else "created"
        why = run_action_refusal(action, phase)
        if why:
            self.notify(action, why, "warning")
            return

        def job() -> None:
            sc = self.session
            assert sc is not None
            if action == "Run":
                if self.path is None or not self.path.nodes:
                    raise PathError("the joint path is empty: Teach at least one node in the command panel")
                self._due["command"] = 0.0
                self._flush()
                t0 = time.monotonic()
                run_id = sc.run()
                self._first_live = True
                log.info(
                    "tab %s: run %s assigned %.0f ms after the click (request %.0f ms)",
                    self.client.client_id,
                    run_id,
                    (time.monotonic() - self._clicked_at) * 1000,
                    (time.monotonic() - t0) * 1000,
                )
                self.notify("Run", f"Run **{run_id}** assigned.", "info")
            elif action == "Pause":
                sc.pause()
            elif action == "Resume":
                sc.resume()
            elif action == "Abort":
                sc.abort()

        self.submit(f"{action} refused", job)

    # ================================================================================================
    # streams from the server (called on zenoh worker threads)
    def _mine(self, session: str) -> bool:
        return (self.session is not None and session == self.session.id) or (
            bool(self.replay_id) and session == self.replay_id
        )

    def _on_state(self, st: m.SessionState) -> None:
        if self.closed or not self._mine(st.session):
            return
        replay = bool(self.replay_id) and st.session == self.replay_id
        with self.lock:
            if replay:
                self.replay_state = st
            else:
                prev = self.state
                if prev is not None and prev.seq > st.seq and prev.run_id == st.run_id:
                    return  # an older publication arriving late
                self.state = st
            if replay or not self.replay_id:
                self._show_state(st, replay)
        if st.phase in ENDED and st.run_id and not replay and st.run_id not in self._notified_end:
            self._notified_end.add(st.run_id)
            self._run_ended(st)
        if replay and st.phase in ENDED:
            self.notify("Replay", f"Replay {st.phase}.", "info")

    def _show_state(self, st: m.SessionState | None = None, replay: bool = False) -> None:
        st = st or self.state
        if self.toolbar is not None:
            self.toolbar.show(st, replay)
        active = st is not None and st.phase in ACTIVE and not replay
        if self.ui is not None:
            if self.ui.pendant is not None:
                self.ui.pendant.set_disabled(active)
            if self.ui.init_widget is not None:
                self.ui.init_widget.sliders.set_disabled(active)

    def _run_ended(self, st: m.SessionState) -> None:
        if st.phase == "finished":
            self.notify(
                f"Run {st.run_id} finished",
                f"{st.sim_time:.3f} s simulated (RTF {st.rtf:.2f}). Results: full resolution, CSV, MCAP.",
                "ok",
            )
        elif st.phase == "aborted":
            self.notify(f"Run {st.run_id} aborted", st.reason or "aborted", "warning")
        else:
            self.notify(f"Run {st.run_id} failed", st.reason or "the simulation failed", "error")
        self.submit("Results", self._refresh_runs, pool="io")

    def _refresh_runs(self) -> None:
        sc = self.session
        if sc is None:
            return
        try:
            runs = sc.runs()
        except (RemoteError, NoReply):
            runs = [r for r in sc.snapshot().runs if r.phase in ENDED]
        with self.lock:
            self.runs = runs
            if self.ui is not None and self.ui.results is not None:
                newest = runs[-1].run_id if runs else ""
                self.ui.results.show_runs(runs, newest)

    def _on_params(self, pv: m.ParamValues) -> None:
        if self.closed or self.session is None or pv.session != self.session.id:
            return
        if pv.values != self.values:
            self._show_values(pv.values)

    def _shown_session(self) -> str:
        """The session whose stream the 3D arm and the plots show: a replay while one is on."""
        return self.replay_id or (self.session.id if self.session is not None else "")

    def _on_layout(self, layout: m.RunLayout) -> None:
        if self.closed or self.model is None or layout.session != self._shown_session():
            return
        with self.lock:
            self.layout = layout
            self.live.reset(layout.live_columns)
            self.pose_idx = pose_indices(layout.live_columns, self.model)
            where = {c: i for i, c in enumerate(layout.live_columns)}
            names = [f"{link.joint}.q" for link in self.model.links]
            self.q_idx = [where[n] for n in names] if all(n in where for n in names) else None
            for name, unit in zip(layout.columns, layout.units, strict=False):
                self.units.setdefault(name, unit)
            for plot in self.plots:
                plot.full = None
                plot.folder.label = plot.title()
                plot.mark()

    def _on_live(self, frame: frames.Frame, session: str) -> None:
        """A decimated sample: pose the arm, feed the plots (drawn on the next tick)."""
        layout, ui = self.layout, self.ui
        if self.closed or layout is None or ui is None:
            return
        if session != layout.session or frame.run_index != layout.run_index:
            return
        rows = frame.rows
        if rows.ndim != 2 or rows.shape[0] == 0 or rows.shape[1] != len(layout.live_columns):
            return
        self.live.append(rows)
        last = rows[-1]
        if self.pose_idx is not None and ui.scene is not None:
            with self.client.atomic():
                ui.scene.apply_poses(last[self.pose_idx])
        if self.q_idx is not None:
            self.shown_q = [float(last[i]) for i in self.q_idx]
        self.live_frames += 1
        if self._first_live:
            self._first_live = False
            log.info(
                "tab %s: first live frame of %s drawn %.0f ms after the click",
                self.client.client_id,
                layout.run_id,
                (time.monotonic() - self._clicked_at) * 1000,
            )
        for plot in self.plots:
            plot.dirty = True

    # ================================================================================================
    # plots
    def _plots_container(self) -> Any:
        ui = self.ui
        assert ui is not None
        if ui.plots_panel is None:
            ui.plots_panel = self.gui.add_panel()
            ui.plots_tab = ui.plots_panel.add_tab("Plots")
            ui.plots_panel.dock_right()
            ui.plots_panel.set_width(440)
        return ui.plots_tab

    def plot_actions(self) -> PlotActions:
        return PlotActions(
            load_full=lambda p, t0, t1: self.submit(
                "Full resolution", lambda: self._load_full(p, t0, t1), "io"
            ),
            overlay=lambda p, on: self.submit("Overlay", lambda: self._overlay(p, on), "io"),
            close=self.close_plot,
            error=lambda msg: self.notify("Plot", msg, "warning"),
            added=lambda p, name: self._ensure_streamed(name),
            variable_names=lambda: sorted(self.streamed),
            batch=self.client.atomic,
        )

    def open_plot(self, name: str) -> Plot | None:
        """A new plot of `name` (paper §5.2: plots open from the variable tree)."""
        if self.model is None:
            return None
        with self.lock:
            self.plot_counter += 1
            with self._plots_container():
                plot = Plot(self.gui, self.plot_counter, [name], self.units, self.plot_actions())
            self.plots.append(plot)
            for p in self.plots:
                p.set_choices(sorted(self.streamed | {name}))
        self._ensure_streamed(name)
        idle = self.state is None or self.state.phase not in ACTIVE
        if idle and self.runs and not self.live.has(name):
            plot.full = None
            self.submit("Full resolution", lambda: self._load_full(plot, None, None), "io")
        return plot

    def _ensure_streamed(self, name: str) -> None:
        if name not in self.streamed:
            self.streamed.add(name)
            if self.ui is not None and self.ui.variables is not None:
                self.ui.variables.show_streamed(self.streamed)
            self._later("settings")

    def close_plot(self, plot: Plot) -> None:
        with self.lock:
            plot.remove()
            if plot in self.plots:
                self.plots.remove(plot)
            if not self.plots and self.ui is not None and self.ui.plots_panel is not None:
                self.ui.plots_panel.remove()
                self.ui.plots_panel, self.ui.plots_tab = None, None

    def _results_source(self) -> tuple[SessionClient, list[m.RunInfo]]:
        """Whose results the plots and downloads use: the replay while one is shown, else this session."""
        if self.replay_id:
            rc = self.mc.session(self.replay_id)
            return rc, list(rc.snapshot().runs)
        assert self.session is not None
        return self.session, list(self.runs)

    def _run_for_results(self, runs: list[m.RunInfo]) -> m.RunInfo | None:
        chosen = self.ui.results.selected() if self.ui and self.ui.results and not self.replay_id else ""
        return next((r for r in runs if r.run_id == chosen), runs[-1] if runs else None)

    def _fetch(
        self, sc: SessionClient, run: m.RunInfo, names: list[str], t0: float | None, t1: float | None
    ) -> Transient:
        every = every_for(run.samples, t0, t1, run.stop_time)
        cols, rows = sc.results(run.run_id, names, t0, t1, every)
        if every > 1:
            self.notify(
                "Long run",
                f"Showing every {every}th sample of {run.run_id}; zoom in for full resolution.",
                "info",
            )
        ys = {c: rows[:, k].copy() for k, c in enumerate(cols) if k}
        return Transient(run.run_id, rows[:, 0].copy(), ys, t0, t1)

    def _load_full(self, plot: Plot, t0: float | None, t1: float | None) -> None:
        if not self.replay_id and self.state is not None and self.state.phase in ACTIVE:
            raise ValueError("the run is still going on: full resolution is available once it ends")
        sc, runs = self._results_source()
        run = self._run_for_results(runs)
        if run is None:
            raise ValueError("no finished run yet")
        plot.full = self._fetch(sc, run, plot.variables, t0, t1)
        plot.folder.label = plot.title()
        if plot.compare.value:
            self._overlay(plot, True)
        plot.mark()

    def _overlay(self, plot: Plot, on: bool) -> None:
        if not on:
            plot.prev = None
            plot.mark()
            return
        if self.session is None:
            return
        current = plot.full.run_id if plot.full else (self.layout.run_id if self.layout else "")
        ids = [r.run_id for r in self.runs]
        before = self.runs[: ids.index(current)] if current in ids else self.runs[:-1]
        if not before:
            plot.compare.value = False
            raise ValueError("there is no previous run to compare with")
        t0, t1 = (plot.full.t0, plot.full.t1) if plot.full else (None, None)  # the same window as shown
        plot.prev = self._fetch(self.session, before[-1], plot.variables, t0, t1)
        plot.mark()

    # ================================================================================================
    # results
    def _on_results_action(self, action: str, run_id: str) -> None:
        if self.session is None or self.model is None:
            return
        if action == "Full resolution":
            if not self.plots:
                self.notify(action, "Open a plot first (Variables tab, Plot).", "warning")
            for plot in self.plots:
                self.submit(action, lambda p=plot: self._load_full(p, None, None), "io")
            return
        if not run_id:
            self.notify(action, "No run yet: run a simulation first.", "warning")
            return
        if action == "CSV":
            self.submit("CSV download", lambda: self._download_csv(run_id), "io")
        elif action == "MCAP":
            self.submit("Recording download", lambda: self._download_mcap(run_id), "io")
        elif action == "Replay":
            self.submit("Replay", lambda: self._replay(self._recording(run_id)), "io")

    def _download_csv(self, run_id: str) -> None:
        sc, model, ui = self.session, self.model, self.ui
        assert sc is not None and model is not None and ui is not None and ui.results is not None
        if ui.results.csv_scope.value == "every variable":
            names: list[str] | None = None
        else:
            plotted = [v for p in self.plots for v in p.variables]
            names = sorted(set(self.streamed) | set(plotted))
        cols, rows = sc.results(run_id, names)
        units = [self.units.get(c, "s" if c == "time" else "") for c in cols]
        meta = {"model": model.id, "session": sc.id, "run": run_id, "samples": str(rows.shape[0])}
        data = to_csv(cols, units, rows, meta)
        self.client.send_file_download(csv_name(model.id, sc.id, run_id), data, save_immediately=True)
        self.notify("CSV", f"{rows.shape[0]} samples × {len(cols)} columns of {run_id}.", "ok")

    def _recording(self, run_id: str) -> str:
        assert self.session is not None
        return keys.recording_name(self.session.id, run_id)

    def _download_mcap(self, run_id: str) -> None:
        name = self._recording(run_id)
        try:
            payload = self.mc.download_recording(name)
        except NoReply:
            self.notify(
                "No recording",
                "No recorder answered: the server runs without the recorder node, so this run was not "
                "recorded. CSV is available.",
                "warning",
            )
            return
        self.client.send_file_download(f"{name}.mcap", payload, save_immediately=True)
        self.notify("Recording", f"{name}.mcap ({len(payload) / 1e6:.2f} MB): opens in Foxglove.", "ok")

    def _upload(self, filename: str, content: bytes) -> None:
        """Put a recording the user kept back on the server, then replay it."""
        stem = filename.rsplit("/", 1)[-1]
        stem = stem[: -len(".mcap")] if stem.lower().endswith(".mcap") else stem
        name = "".join(c if c.isalnum() or c in "_-." else "_" for c in stem).lstrip("._-")[:64] or "upload"
        try:
            self.mc.upload_recording(name, content)
        except NoReply:
            self.notify(
                "Upload unavailable", "No recorder answered: the server cannot take recordings.", "warning"
            )
            return
        self.notify("Recording uploaded", f"Stored as **{name}**; replaying it.", "ok")
        self._replay(name)

    def _replay(self, name: str) -> None:
        try:
            sid = self.mc.replay(name, speed=1.0).id
        except NoReply:
            self.notify("Replay unavailable", "No recorder answered: nothing to replay from.", "warning")
            return
        self._end_replay()
        with self.lock:
            self.replay_id = sid
            self.replay_state = None
            self.replay_watch = self.mc.session(sid).watch(
                on_state=self._on_state, on_layout=self._on_layout, on_live=lambda f: self._on_live(f, sid)
            )
        self.notify("Replay", f"Replaying **{name}** as a live run; **Run** returns to your session.", "info")

    def _end_replay(self) -> None:
        """Stop showing the replay and let its process go (close_session ends it)."""
        with self.lock:
            sid, watch = self.replay_id, self.replay_watch
            self.replay_watch, self.replay_id = None, ""
        if watch is not None:
            watch.close()
        if sid:
            try:
                self.mc.session(sid).close()
            except (RemoteError, NoReply) as exc:
                log.info("replay %s already gone: %s", sid, exc)
        self._show_state()

    def _replay_control(self, action: str) -> None:
        """Run leaves the replay for the user's own session; the other buttons act on the replay."""
        if action == "Run":
            self.submit("Replay", self._end_replay, "io")
            self.notify("Replay", "Back to your session: press Run again to start your own run.", "info")
            return
        phase = self.replay_state.phase if self.replay_state is not None else "running"
        why = run_action_refusal(action, phase) if action != "Abort" else ""
        if why:
            self.notify(action, why.replace("the session", "the replay"), "warning")
            return
        rc = self.mc.session(self.replay_id)

        def job() -> None:
            if action == "Pause":
                rc.pause()
            elif action == "Resume":
                rc.resume()
            elif action == "Abort":  # closing a replay session aborts it and ends its process
                self._end_replay()
                self.notify("Replay", "Replay ended.", "info")

        self.submit(f"{action} refused", job)

    # ================================================================================================
    def tick(self) -> None:
        """About 10 times a second: send edits whose pause has come, redraw plots that have new data."""
        if self.closed:
            return
        now = time.monotonic()
        for what, due in list(self._due.items()):
            if due <= now and self._due.get(what) == due:
                del self._due[what]
                self.submit(f"{what.capitalize()} not sent", lambda w=what: self._sync(w))
        for plot in list(self.plots):
            if plot.dirty:
                try:
                    plot.redraw(self.live)
                except Exception as exc:  # a removed plot, a closed tab
                    log.debug("plot redraw skipped: %s", exc)
