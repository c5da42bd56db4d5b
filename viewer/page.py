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

from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.rules import shapes

from . import browser, camera
from . import events as ev
from .command_panel import INIT_TAB, CommandPanel
from .compare_panel import ComparePanel
from .docs import DocsWindow
from .ghost import GoalGhost
from .layout import Layout
from .markup import escape_html
from .params import ParamPanel, VariablePanel
from .plot_dock import PlotDock
from .plots import Plot, PlotActions
from .readout import readout_text
from .results import ResultsPanel
from .run import SettingsWindow, settings_from_form
from .scene import ArmScene
from .session import SessionController
from .trace import ToolTrace

MAX_RESTORED_PLOTS = 8  # plots a reloaded tab opens again at most


class ModelPage:
    """Everything drawn for the controller's model."""

    def __init__(
        self, client: Any, controller: SessionController, layout: Layout, timeline_place: Any = None
    ) -> None:
        """`timeline_place`: where the timeline of finished runs goes (the run bar's tab)."""
        c = controller
        model = c.model
        assert model is not None and c.stream is not None and c.path is not None and c.session is not None
        self.client = client
        self.gui = gui = client.gui
        self.c = c
        self.layout = layout
        self.handles: list[Any] = []
        self.docs: DocsWindow | None = None
        self._show_plots = True  # a plot opening brings the plots' tab to the front (not on a reload)
        self.settings: SettingsWindow | None = None

        self.header = gui.add_markdown(
            f"**{escape_html(model.name)}**  \nuser `{c.user}` · session `{c.session.id[:8]}…`  \n"
            f"<small>{escape_html(model.summary)}</small>"
        )
        self.tabs = tabs = gui.add_tab_group()
        self.handles += [self.header, tabs]
        with tabs.add_tab("Parameters"):
            self.params = ParamPanel(
                gui,
                model,
                c.values,
                c.edits.set_params,
                c.edits.reset_params,
                c.edits.param_set,
                c.edits.undo_params,
                after=c.loop.after,
            )
            self.params.show_undo(c.edits.undo_what())
        with tabs.add_tab("Variables"):
            self.variables = VariablePanel(gui, model, c.streamed, self._set_streamed, self.open_plot)
        results_tab = tabs.add_tab("Results")
        with results_tab:
            self.results = ResultsPanel(gui, self._results_action, c.results.upload)
            self.results.show_runs(c.runs)

        c.pending_params = lambda: sorted(self.params.drafts)
        self.scene = ArmScene(client.scene, model, c.values, meshes=c.meshes)
        self.scene.q = list(c.initial)
        self.scene.build()
        self.scene.show_obstacles(c.obstacles)
        self.trace = ToolTrace(client.scene)
        bounds = {name: shapes.glb_bounds(data) for name, data in c.meshes.items()}
        self.ghost = GoalGhost(client.scene, model, c.values, bounds)
        self.look("Fit arm")

        self.commands = CommandPanel(client, c, self.scene, layout, self._warn)
        self.handles.append(self.commands)

        actions = PlotActions(
            load_full=self._load_full,
            close=lambda p: self.plots.close(p),
            error=self._warn("Plot"),
            added=lambda _p, name: c.edits.ensure_streamed(name),
            variable_names=lambda: sorted(c.streamed),
            batch=client.atomic,
        )
        self.plots = PlotDock(gui, c.stream.units, actions, self._place_plots)
        with results_tab:
            self.compare = ComparePanel(gui, c, self.plots, self.scene, self.results.selected, timeline_place)
            self.compare.show_runs(c.runs)
        self.results.runs.on_update(lambda _e: self.compare.refresh())
        self.plots.on_angles = lambda _a: self.compare.show_cursor()
        self._apply: dict[type, Callable[[Any], None]] = {
            ev.ValuesChanged: lambda e: self.params.show_values(e.values),
            ev.ParamsRefused: lambda e: self.params.refused(e.field, e.reason),
            ev.ShapesChanged: self._show_shapes,
            ev.StreamedChanged: self._show_streamed,
            ev.RunsChanged: self._show_runs,
            ev.RunsDescribed: lambda _e: self._show_runs(ev.RunsChanged(list(self.c.runs))),
            ev.ParamSetsChanged: lambda e: self.params.set_names(e.names),
            ev.UndoChanged: lambda e: self.params.show_undo(e.what),
            ev.LayoutChanged: self._new_run,
            ev.ObstaclesChanged: self._show_obstacles,
            ev.LiveSamples: self._show_live,
            ev.PosePreview: self._show_preview,
            ev.GoalShown: lambda e: self.ghost.show(e.q),
            ev.TransientLoaded: self._show_transient,
            ev.ComparedLoaded: self.compare.apply,
            ev.TrackLoaded: self.compare.apply,
            ev.RecordingsListed: self.compare.show_recordings,
            ev.DocFetched: self._show_doc,
            ev.SettingsChanged: self._settings_applied,
            ev.PlanChanged: self.commands.show_plan,
            ev.CommandRefused: self.commands.show_refusal,
            ev.CommandReplaced: self.commands.show_replaced,
            ev.StateShown: self._state_shown,
        }
        self.show_editable()

    def readout(self) -> str:
        """The digital readout of the arm as shown (the pose Teach records), in the tab's angle unit."""
        c, model = self.c, self.c.model
        assert model is not None
        q = list(c.shown_q)
        try:
            pose = c.tool_pose(q)
            tool: list[float] | None = [*pose.position, *pose.rpy]
        except Exception:  # a pose the description cannot place (a model without a tool frame)
            tool = None
        return readout_text([link.joint for link in model.links], q, tool, self.plots.angles)

    def _place_plots(self) -> tuple[Any, Any]:
        """Where the plots go (`Layout.plots_where`): a column of their own beside the arm on a wide
        screen, above the pendant on a middling one, else a tab beside the trees, shown at once."""
        where = self.layout.plots_where
        if where != "tab":
            panel = self.gui.add_panel()
            tab = panel.add_tab("Plots")
            if where == "column":
                self.layout.place_plots(panel)
            else:
                self.layout.place_beside_pendant(panel, self.commands.panel)
            return panel, tab
        tab = self.tabs.add_tab("Plots")
        if self._show_plots:
            browser.show_tab(self.client, "Plots")
        return tab, tab

    def look(self, view: str) -> None:
        """A camera preset of the toolbar's View buttons: the arm as it stands now, framed."""
        fov, aspect = camera.lens(self.client.camera)
        camera.apply(self.client.camera, camera.preset(view, self.scene.corners(), fov, aspect))

    def _warn(self, title: str) -> Callable[[str], None]:
        return lambda message: self.c.notify(title, message, "warning")

    def apply(self, event: ev.Event) -> None:
        """Show a controller event on these panels (events about no panel here are ignored)."""
        handler = self._apply.get(type(event))
        if handler is not None:
            handler(event)

    def show_editable(self) -> None:
        """The command and the initial pose cannot change while a run is under way."""
        self.commands.show_editable()

    def _state_shown(self, event: ev.StateShown) -> None:
        self.show_editable()
        self.commands.show_state(event.state)
        self.compare.show_phase()
        self.trace.draw()  # a run that ended: its trace to its last sample

    def _show_shapes(self, event: ev.ShapesChanged) -> None:
        self.scene.set_values(event.values)
        self.ghost.set_values(event.values)

    def preview_motion(self) -> None:
        """Play the session's planned move on the goal ghost, at its own pace (MoveIt's Plan before
        Execute): the server's set points (`CommandPlan.motion`), nothing recomputed here."""
        plan = self.c.edits.plan
        motion = plan.motion if plan is not None else None
        if plan is None or motion is None or len(motion.t) < 2:
            why = "the command has no plan yet: teach or edit it first"
            if plan is not None:
                why = "its joint positions are not known before the run (speeds or motor currents)"
            self.c.notify("Preview", f"Nothing to preview: {why}.", "warning")
            return
        end = list(motion.q[-1])
        self.ghost.play(motion.t, motion.q, self.c.loop.after, done=lambda: self.ghost.show(end))

    def _show_live(self, event: ev.LiveSamples) -> None:
        if event.poses is not None:
            self.scene.apply_poses(event.poses)
        self.scene.move_obstacles(event.moved)
        self.scene.show_contacts(event.arrows)
        self.trace.add(event.tool)
        self.plots.mark_all()

    def _show_preview(self, event: ev.PosePreview) -> None:
        self.scene.settle_world()
        self.scene.show_q(event.q)

    def _new_run(self, event: ev.LayoutChanged) -> None:
        layout = event.layout
        kind = "replay" if layout.source == "replay" else "run"
        self.plots.new_run(f"{kind} {layout.run_id}", layout.stop_time)
        self.compare.new_run()
        self.trace.clear()
        self._draw_obstacles()

    def _show_obstacles(self, event: ev.ObstaclesChanged) -> None:
        self.commands.obstacles.show(event.obstacles)
        self._draw_obstacles()

    def _draw_obstacles(self) -> None:
        """The session's obstacles where they are listed; a replay's run's while it plays."""
        replay = self.c.replaying
        self.scene.show_obstacles(replay.context.obstacles if replay is not None else self.c.obstacles)

    # -- what a reload gets back -------------------------------------------------------------------
    def view_state(self) -> dict[str, Any]:
        """What this page shows of its session, kept in the tab for a reload (tab.py)."""
        pose = camera.current(self.client.camera)
        return {
            "session": self.c.session.id if self.c.session is not None else "",
            "camera": pose.to_obj() if pose is not None else None,
            "plots": [list(p.variables) for p in self.plots.plots.values()],
            "x_axes": [p.x_var for p in self.plots.plots.values()],  # each plot's, in the same order
            "component": self.params.tree.picked,
            "angles": self.plots.angles,
        }

    def restore(self, view: dict[str, Any]) -> None:
        """Show what a reloaded tab showed: its camera, plots and component. The memory is the
        browser's, so only names the model has are taken."""
        pose = camera.CameraPose.from_obj(view.get("camera"))
        if pose is not None:
            camera.apply(self.client.camera, pose)
        known = {v.name for v in self.c.model.variables} if self.c.model is not None else set()
        plots, x_axes = view.get("plots"), view.get("x_axes")
        x_axes = x_axes if isinstance(x_axes, list) else []
        for k, names in enumerate(plots[:MAX_RESTORED_PLOTS] if isinstance(plots, list) else []):
            names = [n for n in names if isinstance(n, str) and n in known] if isinstance(names, list) else []
            if names:
                plot = self.open_plot(names[0], show=False)  # the tab shown before the reload stays
                for name in names[1:]:
                    plot.add(name)
                x = x_axes[k] if k < len(x_axes) else None
                if isinstance(x, str) and x in known and x not in names:
                    plot.set_x(x)
        if isinstance(view.get("angles"), str):
            self.plots.set_angles(view["angles"])  # checked against units.ANGLES there
        if isinstance(view.get("component"), str):
            self.params.show_path(view["component"])

    # -- variables and plots ------------------------------------------------------------------------
    def _set_streamed(self, wanted: set[str]) -> None:
        self.c.edits.set_streamed(wanted, self.plots.plotted())

    def _show_streamed(self, event: ev.StreamedChanged) -> None:
        self.variables.show_streamed(event.streamed)
        self.plots.set_choices(sorted(event.streamed))

    def open_plot(self, name: str, show: bool = True) -> Plot:
        """A new plot of `name` (paper §5.2: plots open from the variable tree)."""
        self._show_plots = show
        plot = self.plots.open(name, sorted(self.c.streamed | {name}))
        self.c.edits.ensure_streamed(name)
        if self.c.results.wants_full(name):
            self.c.results.load_full(
                plot.number, [name], run_id=self.results.selected(), compare=self.compare.compared()
            )
        else:
            self.compare.refresh()
        return plot

    def _load_full(self, plot: Plot, t0: float | None, t1: float | None) -> None:
        run_id = self.results.selected()
        self.c.results.load_full(plot.number, plot.names(), t0, t1, run_id, self.compare.compared())

    def _show_transient(self, event: ev.TransientLoaded) -> None:
        plot = self.plots.get(event.plot)
        if plot is None:
            return
        plot.full = event.full
        plot.others = event.others
        plot.folder.label = plot.title()
        plot.reset_zoom()  # the window asked for, not a drag-zoom of the data shown before
        self.compare.show_cursor()

    def _show_runs(self, event: ev.RunsChanged) -> None:
        self.results.show_runs(event.runs, event.newest, self.c.contexts)
        self.compare.show_runs(event.runs)

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
        elif action == "Continue":
            c.control.continue_run(run_id)

    def _show_doc(self, event: ev.DocFetched) -> None:
        if self.docs is not None:
            self.docs.receive(event.page)

    def _settings_applied(self, _event: ev.SettingsChanged) -> None:
        if self.settings is not None:
            self.settings.close()
        self.commands.show_plan()

    # -- windows -----------------------------------------------------------------------------------
    def show_init(self) -> None:
        """The initial pose's sliders (a tab of the pendant's column) to the front, the arm at that
        pose (paper §5.2: the initialisation panel)."""
        browser.show_tab(self.client, INIT_TAB)
        self.c.preview(list(self.c.initial))

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
            self.docs = DocsWindow(
                self.gui,
                model.docs,
                model.doc_root,
                self.c.fetch_doc,
                lambda p: self.layout.place_beside_pendant(p, self.commands.panel),
            )
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
        for h in self.handles:
            if h is None:
                continue
            try:
                h.remove()
            except Exception:
                pass
        self.trace.remove()
        self.ghost.remove()
        self.scene.remove()
