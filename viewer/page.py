"""The panels of one loaded model, wired to the tab's session controller (figure 9): the parameter,
variable and results tabs docked left, the 3D prototype in the centre, the joint command panel at
the bottom, plots docked right, and the initialisation, settings and documentation windows.

A user's action goes to a controller method (which returns at once); the controller's events come
back through `apply`, which the tab calls inside `client.atomic()`. Removed as a whole when the tab
changes model.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from simecs.mesh.codec import DecodeError

from . import events as ev
from .docs import DocsWindow
from .jog_panel import JogPanel
from .joints import InitPanel
from .obstacles import ObstaclePanel
from .params import ParamPanel, VariablePanel
from .path import clamp_to_limits
from .pendant import PendantPanel
from .plots import Plot, PlotActions, PlotDock
from .results import ResultsPanel
from .run import SettingsWindow, settings_from_form
from .scene import ArmScene
from .session import SessionController


class ModelPage:
    """Everything drawn for the controller's model."""

    def __init__(self, client: Any, controller: SessionController) -> None:
        c = controller
        model = c.model
        assert model is not None and c.stream is not None and c.path is not None and c.session is not None
        self.client = client
        self.gui = gui = client.gui
        self.c = c
        self.handles: list[Any] = []
        self.init_panel: Any = None
        self.init_widget: InitPanel | None = None
        self.docs: DocsWindow | None = None
        self.settings: SettingsWindow | None = None
        self.pendant: PendantPanel | None = None

        self.header = gui.add_markdown(
            f"**{model.name}**  \nuser `{c.user}` · session `{c.session.id[:8]}…`  \n"
            f"<small>{model.summary}</small>"
        )
        tabs = gui.add_tab_group()
        self.handles += [self.header, tabs]
        with tabs.add_tab("Parameters"):
            self.params = ParamPanel(
                gui, model, c.values, c.edits.set_params, c.edits.reset_params, c.edits.param_set
            )
        with tabs.add_tab("Variables"):
            self.variables = VariablePanel(gui, model, c.streamed, self._set_streamed, self.open_plot)
        with tabs.add_tab("Results"):
            self.results = ResultsPanel(gui, self._results_action, c.results.upload)
            self.results.show_runs(c.runs)

        c.pending_params = lambda: sorted(self.params.drafts)
        self.scene = ArmScene(client.scene, model, c.values, meshes=c.meshes)
        self.scene.q = list(c.initial)
        self.scene.build()
        self.scene.show_obstacles(c.obstacles)
        reach = self.scene.extent()
        client.camera.position = (1.3 * reach, -1.4 * reach, 1.0 * reach)
        client.camera.look_at = (0.0, 0.0, 0.25 * reach)

        command = gui.add_panel()
        self.handles.append(command)
        with command.add_tab("Joint path"):
            if "joint_path" in model.command_levels:
                self.pendant = PendantPanel(
                    gui,
                    c.path,
                    current_q=lambda: list(c.shown_q),
                    on_changed=c.edits.command_changed,
                    on_preview=c.preview,
                    on_error=self._warn("Joint path"),
                )
            else:
                levels = ", ".join(model.command_levels) or "none"
                gui.add_markdown(f"_This model accepts {levels} commands; this viewer edits joint paths._")
        with command.add_tab("Jog"):
            self.jog = JogPanel(gui, c.jog, self._warn("Jog"))
        with command.add_tab("Obstacles"):
            self.obstacles = ObstaclePanel(
                gui, c.obstacles, model.obstacles, c.edits.set_obstacles, self._warn("Obstacles")
            )
        command.float(x=12, y=-12, width=620, height=360)

        actions = PlotActions(
            load_full=self._load_full,
            overlay=self._overlay,
            close=lambda p: self.plots.close(p),
            error=self._warn("Plot"),
            added=lambda _p, name: c.edits.ensure_streamed(name),
            variable_names=lambda: sorted(c.streamed),
            batch=client.atomic,
        )
        self.plots = PlotDock(gui, c.stream.units, actions)
        self._apply: dict[type, Callable[[Any], None]] = {
            ev.ValuesChanged: lambda e: self.params.show_values(e.values),
            ev.ParamsRefused: lambda e: self.params.refused(e.field, e.reason),
            ev.ShapesChanged: self._show_shapes,
            ev.StreamedChanged: self._show_streamed,
            ev.RunsChanged: lambda e: self.results.show_runs(e.runs, e.newest),
            ev.ParamSetsChanged: lambda e: self.params.set_names(e.names),
            ev.LayoutChanged: self._new_run,
            ev.ObstaclesChanged: self._show_obstacles,
            ev.LiveSamples: self._show_live,
            ev.PosePreview: self._show_preview,
            ev.TransientLoaded: self._show_transient,
            ev.PreviousLoaded: self._show_previous,
            ev.DocFetched: self._show_doc,
            ev.SettingsChanged: self._settings_applied,
            ev.PlanChanged: lambda e: self._show_plan(),
            ev.StateShown: lambda _e: self.show_editable(),
        }
        self.show_editable()

    def _warn(self, title: str) -> Callable[[str], None]:
        return lambda message: self.c.notify(title, message, "warning")

    def apply(self, event: ev.Event) -> None:
        """Show a controller event on these panels (events about no panel here are ignored)."""
        handler = self._apply.get(type(event))
        if handler is not None:
            handler(event)

    def show_editable(self) -> None:
        """The command and the initial pose cannot change while a run is under way."""
        if self.pendant is not None:
            self.pendant.set_disabled(bool(self.c.refusal("set_command")))
        if self.init_widget is not None:
            self.init_widget.sliders.set_disabled(bool(self.c.refusal("set_initial")))

    def _show_shapes(self, event: ev.ShapesChanged) -> None:
        self.scene.set_values(event.values)

    def _show_live(self, event: ev.LiveSamples) -> None:
        if event.poses is not None:
            self.scene.apply_poses(event.poses)
        self.scene.move_obstacles(event.moved)
        self.scene.show_contacts(event.arrows)
        self.plots.mark_all()

    def _show_preview(self, event: ev.PosePreview) -> None:
        self.scene.settle_world()
        self.scene.show_q(event.q)

    def _new_run(self, _event: ev.LayoutChanged) -> None:
        self.plots.new_run()
        self._draw_obstacles()

    def _show_obstacles(self, event: ev.ObstaclesChanged) -> None:
        self.obstacles.show(event.obstacles)
        self._draw_obstacles()

    def _draw_obstacles(self) -> None:
        """The session's obstacles where they are listed; a replay's run's while it plays."""
        replay = self.c.replaying
        self.scene.show_obstacles(replay.context.obstacles if replay is not None else self.c.obstacles)

    # -- variables and plots ------------------------------------------------------------------------
    def _set_streamed(self, wanted: set[str]) -> None:
        self.c.edits.set_streamed(wanted, self.plots.plotted())

    def _show_streamed(self, event: ev.StreamedChanged) -> None:
        self.variables.show_streamed(event.streamed)
        self.plots.set_choices(sorted(event.streamed))

    def open_plot(self, name: str) -> None:
        """A new plot of `name` (paper §5.2: plots open from the variable tree)."""
        plot = self.plots.open(name, sorted(self.c.streamed | {name}))
        self.c.edits.ensure_streamed(name)
        if self.c.results.wants_full(name):
            self.c.results.load_full(plot.number, [name], run_id=self.results.selected())

    def _load_full(self, plot: Plot, t0: float | None, t1: float | None) -> None:
        run_id = self.results.selected()
        with_prev = bool(plot.compare.value)
        self.c.results.load_full(plot.number, list(plot.variables), t0, t1, run_id, with_prev)

    def _overlay(self, plot: Plot, on: bool) -> None:
        if not on:
            plot.prev = None
            plot.mark()
            return
        full = plot.full
        current, t0, t1 = (full.run_id, full.t0, full.t1) if full else ("", None, None)  # the same window
        self.c.results.load_previous(plot.number, list(plot.variables), current, t0, t1)

    def _show_transient(self, event: ev.TransientLoaded) -> None:
        plot = self.plots.get(event.plot)
        if plot is None:
            return
        plot.full = event.full
        if event.with_prev:
            plot.prev = event.prev
        plot.folder.label = plot.title()
        plot.mark()

    def _show_previous(self, event: ev.PreviousLoaded) -> None:
        plot = self.plots.get(event.plot)
        if plot is None:
            return
        plot.prev = event.prev
        if event.prev is None and plot.compare.value:
            plot.compare.value = False
        plot.mark()

    # -- results -----------------------------------------------------------------------------------
    def _results_action(self, action: str, run_id: str) -> None:
        c = self.c
        if action == "Full resolution":
            if not self.plots.plots:
                c.notify(action, "Open a plot first (Variables tab, Plot).", "warning")
            for plot in list(self.plots.plots.values()):
                self._load_full(plot, None, None)
            return
        if not run_id:
            c.notify(action, "No run yet: run a simulation first.", "warning")
            return
        if action == "CSV":
            every = self.results.csv_scope.value == "every variable"
            c.results.download_csv(run_id, None if every else sorted(c.streamed | self.plots.plotted()))
        elif action == "MCAP":
            c.results.download_mcap(run_id)
        elif action == "Replay":
            c.control.replay_run(run_id)

    def _show_doc(self, event: ev.DocFetched) -> None:
        if self.docs is not None:
            self.docs.receive(event.page)

    def _settings_applied(self, _event: ev.SettingsChanged) -> None:
        if self.settings is not None:
            self.settings.close()
        self._show_plan()

    def _show_plan(self) -> None:
        if self.pendant is not None:
            self.pendant.show_plan(self.c.edits.plan, self.c.settings.stop_time)

    # -- windows -----------------------------------------------------------------------------------
    def toggle_init(self) -> None:
        c, model = self.c, self.c.model
        assert model is not None
        if self.init_panel is not None:
            self.init_panel.remove()
            self.init_panel, self.init_widget = None, None
            return
        self.init_panel = self.gui.add_panel()
        with self.init_panel.add_tab("Initialisation"):
            self.init_widget = InitPanel(
                self.gui,
                model.links,
                model.init_equations,
                c.initial,
                c.edits.set_initial,
                self._zero_initial,
            )
            close = self.gui.add_button("Close initialisation", color="gray")
            close.on_click(lambda _e: self.toggle_init())
        self.init_panel.float(x=-12, y=190, width=380)
        self.show_editable()
        c.preview(list(c.initial))

    def _zero_initial(self) -> None:
        model = self.c.model
        if model is None or self.init_widget is None:
            return
        q = clamp_to_limits([0.0] * len(model.links), model.links)
        self.init_widget.sliders.set_q(q)
        self.c.edits.set_initial(q)

    def open_settings(self) -> None:
        if self.settings is not None:
            self.settings.close()
        model = self.c.model
        systems = list(model.control_systems) if model is not None else ["joint_independent"]
        if self.c.settings.control_system not in systems:
            systems.append(self.c.settings.control_system)
        self.settings = SettingsWindow(self.gui, self.c.settings, self._apply_settings, systems)

    def _apply_settings(self, form: dict[str, Any]) -> None:
        try:
            settings = settings_from_form(live_vars=sorted(self.c.streamed), base=self.c.settings, **form)
        except DecodeError as exc:
            self.c.notify("Settings refused", f"{exc.field}: {exc.problem}", "error")
            return
        self.c.edits.apply_settings(settings)

    def toggle_docs(self) -> None:
        model = self.c.model
        assert model is not None
        if self.docs is None:
            self.docs = DocsWindow(self.gui, model.docs, model.doc_root, self.c.fetch_doc)
        if self.docs.is_open:
            self.docs.close()
        else:
            self.docs.open()

    def remove(self) -> None:
        if self.docs is not None:
            self.docs.close()
        if self.settings is not None:
            self.settings.close()
        self.plots.remove()
        for h in [self.init_panel, *self.handles]:
            if h is None:
                continue
            try:
                h.remove()
            except Exception:
                pass
        self.scene.remove()
