"""The user's edits of their session, on their way to the server (paper §2.2 steps 2-6): parameter
values (each checked by the server, undone when refused), named parameter sets, the streamed
variables, the initial pose, the joint path and the settings.

Sliders and the pendant fire on every move, so the pose, the path and the settings are sent once
the user paused for `sync_delay_s` (`tick`), and all at once before a run starts (`flush`). An edit
the session's phase forbids is refused here with the phase table's reason. Part of the session
controller: the values themselves live in the tab's state (tab_state.py), where the panels read them;
what a request brings back is handed to the tab's loop.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from functools import partial
from typing import Any

import msgspec
from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.shapes import appearance_parameters

from . import events as ev
from .program import pendant_level
from .tab_state import TabState
from .workers import Dispatcher

SYNC_DELAY_S = 0.25  # an edit is sent once the user paused this long (sliders fire on every move)
DEBOUNCED = ("initial", "command", "settings")


UNDO_DEPTH = 20  # changes of parameter values that can be undone, one after the other


def undo_label(before: dict[str, float]) -> str:
    """What undoing a change puts back, as the button's hint and the notice say it."""
    if len(before) == 1:
        name, value = next(iter(before.items()))
        return f"{name} back to {value:g}"
    return f"{len(before)} parameters back to their values before the last change"


class Edits:
    """Sending one tab's edits: `view` is the tab's state, `tasks` its loop and workers, `preview(q)`
    shows the arm at a pose."""

    def __init__(
        self,
        view: TabState,
        tasks: Dispatcher,
        preview: Callable[[list[float]], None],
        sync_delay_s: float = SYNC_DELAY_S,
    ) -> None:
        self.c = view
        self.t = tasks
        self.preview = preview
        self.sync_delay_s = sync_delay_s
        self._due: dict[str, float] = {}
        self._lock = threading.Lock()
        self.plan: m.CommandPlan | None = None  # the server's plan of the command last sent
        self.refused = ""  # why the server refused the path last sent ('' when it took it)
        #: The commands this tab sent lately (encoded): their publication is not another client's.
        self._sent: deque[bytes] = deque(maxlen=32)
        self._in_flight = False  # a dragged command is being sent
        self._again = False  # and it moved since: send once more
        #: What the user's last changes of parameter values replaced (newest last): Undo puts it back.
        self.undo_stack: list[dict[str, float]] = []

    def command(self, cmd: Any) -> Any:
        """Send a session command after the local phase check (the server checks again)."""
        sc = self.c.session
        if sc is None:
            raise ValueError("load a model first (Models)")
        why = self.c.refusal(cmd.op)
        if why:
            raise ValueError(why)
        return sc.command(cmd)

    # -- parameters --------------------------------------------------------------------------------
    def set_param(self, name: str, value: float) -> None:
        """One value (see `set_params`)."""
        self.set_params({name: value})

    def set_params(self, changes: dict[str, float]) -> None:
        """Values the user applied, all at once: the 3D arm reshapes at once, the server checks them
        (all or none; a refusal names the culprit, and the arm comes back)."""
        c, t = self.c, self.t
        sc, model = c.session, c.model
        if sc is None or model is None or not changes:
            return
        what = next(iter(changes)) if len(changes) == 1 else f"{len(changes)} parameters"
        why = c.refusal("set_params")
        if why:
            t.notify(f"{what} not changed", why, "warning")
            t.emit(ev.ParamsRefused("", why))
            t.emit(ev.ValuesChanged(dict(c.values)))
            return
        if set(changes) & appearance_parameters(model):
            c.replaying = None
            t.emit(ev.ShapesChanged({**c.values, **{k: float(v) for k, v in changes.items()}}))
        before = dict(c.values)

        def job() -> None:
            try:
                values = sc.command(m.SetParams({k: float(v) for k, v in changes.items()}))
            except (RemoteError, NoReply) as exc:
                t.on_loop(partial(self._params_refused, exc))
                t.fail(f"{what} not changed", exc)
                return
            t.on_loop(lambda: self._took(before, values))

        t.submit(f"{what} not changed", job)

    def _params_refused(self, exc: RemoteError | NoReply) -> None:
        """The server did not take a change of values: the stored ones shown again, and its reason."""
        self.show_values(self.c.values)
        if isinstance(exc, RemoteError):
            self.t.emit(ev.ParamsRefused(exc.field.removeprefix("values."), exc.error.message))

    def _took(self, before: dict[str, float], values: dict[str, float]) -> None:
        """The server took a change of values (`before`: the values when it was sent): shown, and
        what it replaced kept for Undo (on the loop)."""
        self._replaced(before, values)
        self.show_values(values)

    def undo_params(self) -> None:
        """Put back the values the user's last change (applied edits, a reset, a loaded set) replaced."""
        t = self.t
        if not self.undo_stack:
            t.notify("Undo refused", "no change of parameter values to undo", "warning")
            return
        before = self.undo_stack[-1]

        def job() -> None:
            values = self.command(m.SetParams(dict(before)))

            def undone() -> None:
                if self.undo_stack and self.undo_stack[-1] is before:
                    self.undo_stack.pop()
                self.show_values(values)
                self._undo_shown()

            t.on_loop(undone)
            t.notify("Undone", undo_label(before), "ok")

        t.submit("Undo refused", job)

    def _replaced(self, before: dict[str, float], values: dict[str, float]) -> None:
        """The server took a change of the user's (`before` the values when it was sent): keep what
        it replaced for Undo."""
        replaced = {k: v for k, v in before.items() if k in values and values[k] != v}
        if replaced:
            self.undo_stack = [*self.undo_stack, replaced][-UNDO_DEPTH:]
            self._undo_shown()

    def undo_what(self) -> str:
        """What Undo would put back now ('' when there is nothing to undo)."""
        return undo_label(self.undo_stack[-1]) if self.undo_stack else ""

    def _undo_shown(self) -> None:
        self.t.emit(ev.UndoChanged(self.undo_what()))

    def reset_params(self, names: list[str]) -> None:
        before = dict(self.c.values)

        def job() -> None:
            values = self.command(m.ResetParams(list(names)))
            self.t.on_loop(lambda: self._took(before, values))
            self.t.notify("Parameters", f"{len(names) or 'All'} parameter(s) back to their defaults.", "ok")

        self.t.submit("Reset refused", job)

    def param_set(self, op: str, name: str) -> None:
        """save / load / delete a named parameter set (kept by the server per user and model)."""
        t = self.t
        before = dict(self.c.values)

        def job() -> None:
            if op in ("load", "delete") and name in ("", "(none)"):
                raise ValueError("no saved set chosen")
            if op == "save":
                self.command(m.SaveParamSet(name))
                t.notify("Parameter set saved", f"Saved **{name}**.", "ok")
            elif op == "load":
                values = self.command(m.LoadParamSet(name))
                t.on_loop(lambda: self._took(before, values))
                t.notify("Parameter set loaded", f"Loaded **{name}**.", "ok")
            elif op == "delete":
                self.command(m.DeleteParamSet(name))
                t.notify("Parameter set deleted", f"Deleted **{name}**.", "ok")
            self.refresh_sets()

        t.submit(f"Parameter set {op}", job)

    def refresh_sets(self) -> None:
        if self.c.session is not None:
            self.t.emit(ev.ParamSetsChanged(list(self.command(m.ListParamSets()))))

    def show_values(self, values: dict[str, float]) -> None:
        """The server's values: to the parameter panel, and to the arm unless a replay shapes it."""
        c = self.c
        c.values = dict(values)
        self.t.emit(ev.ValuesChanged(dict(c.values)))
        if c.replaying is None:
            self.t.emit(ev.ShapesChanged(dict(c.values)))

    # -- obstacles ---------------------------------------------------------------------------------
    def set_obstacles(self, obstacles: list[m.Obstacle]) -> None:
        """The session's whole obstacle list as the user edited it: drawn at once, then stored by the
        server (a refusal names the field, and the list drawn comes back to the stored one)."""
        before = list(self.c.obstacles)
        self.show_obstacles(obstacles)

        def job() -> None:
            try:
                self.command(m.SetObstacles(list(obstacles)))
            except (RemoteError, NoReply, ValueError):
                self.t.on_loop(lambda: self.show_obstacles(before))
                raise
            self.t.notify("Obstacles", f"{len(obstacles)} obstacle(s) stored for the next runs.", "ok")

        self.t.submit("Obstacles refused", job)

    def show_obstacles(self, obstacles: list[m.Obstacle]) -> None:
        self.c.obstacles = list(obstacles)
        self.t.emit(ev.ObstaclesChanged(list(obstacles)))

    def on_obstacles(self, published: m.ObstacleValues) -> None:
        """The server's list (after any client's set_obstacles): drawn when it is not the one shown."""
        session = self.c.session
        if (
            session is not None
            and published.session == session.id
            and published.obstacles != self.c.obstacles
        ):
            self.show_obstacles(published.obstacles)

    # -- variables, pose, path, settings -------------------------------------------------------------
    def set_streamed(self, wanted: set[str], plotted: set[str]) -> None:
        """Variables streamed live: the chosen ones (the plotted ones when none), and the joint
        positions always (Teach needs the pose after a run)."""
        c = self.c
        if c.model is None:
            return
        required = set(c.model.joint_position_columns())
        c.streamed = set(wanted) | required | (set(plotted) if not wanted else set())
        self.t.emit(ev.StreamedChanged(set(c.streamed)))
        self.later("settings")

    def ensure_streamed(self, name: str) -> None:
        c = self.c
        if name not in c.streamed:
            c.streamed.add(name)
            self.t.emit(ev.StreamedChanged(set(c.streamed)))
            self.later("settings")

    def set_initial(self, q: list[float]) -> None:
        self.c.initial = list(q)
        self.preview(q)
        self.later("initial")

    def command_changed(self, kind: str = "joint_path") -> None:
        """A path (the controller's `path` or `cart`) was edited in place: it becomes the session's
        command, sent once the edits pause. A path emptied (its last node removed) has no plan: the
        pendant and the 3D view forget the last one (a run is refused until a node is taught)."""
        self.c.command_kind = kind
        editor = self.c.editor(kind)
        if editor is not None and editor.empty:
            with self._lock:
                self._due.pop("command", None)
            self.plan, self.refused = None, ""
            self.t.emit(ev.PlanChanged(None, kind))
            return
        self.later("command")

    def command_dragged(self, kind: str) -> None:
        """A path is being dragged in 3D: sent as soon as the worker is free, the latest pose each
        time (no pause to wait for), so the arm follows the gizmo at the server's planning rate."""
        self.c.command_kind = kind
        with self._lock:
            self._due.pop("command", None)
            if self._in_flight:
                self._again = True
                return
            self._in_flight = True
        self.t.submit("Command not sent", self._send_latest_command)

    def _send_latest_command(self) -> None:
        try:
            while True:
                self.send("command")
                with self._lock:
                    if not self._again:
                        return
                    self._again = False
        finally:
            with self._lock:
                self._in_flight = self._again = False

    def apply_settings(self, settings: m.RunSettings) -> None:
        """Settings from the settings window (the streamed variables go with them)."""
        settings = msgspec.structs.replace(settings, live_vars=self.live_vars())

        def job() -> None:
            self.command(m.SetSettings(settings))
            self.t.on_loop(lambda: self._settings_taken(settings))
            self.t.notify("Settings", f"Stop time {settings.stop_time:g} s, pacing {settings.pacing}.", "ok")

        self.t.submit("Settings refused", job)

    def _settings_taken(self, settings: m.RunSettings) -> None:
        self.c.settings = settings
        self.t.emit(ev.SettingsChanged(settings))

    def live_vars(self) -> list[str]:
        """`RunSettings.live_vars` for the streamed variables ([] = every variable)."""
        model = self.c.model
        every = {v.name for v in model.variables} if model is not None else set()
        return [] if self.c.streamed >= every else sorted(self.c.streamed)

    # -- sending once the edits pause ------------------------------------------------------------------
    def later(self, what: str) -> None:
        with self._lock:
            self._due[what] = time.monotonic() + self.sync_delay_s

    def forget(self) -> None:
        """Another session is shown: nothing of the last one is sent, planned or undone."""
        with self._lock:
            self._due.clear()
        self.plan, self.refused = None, ""
        self.undo_stack = []

    def tick(self, now: float | None = None) -> None:
        """Send the edits whose pause has come."""
        now = time.monotonic() if now is None else now
        with self._lock:
            due = [what for what, at in self._due.items() if at <= now]
            for what in due:
                del self._due[what]
        for what in due:
            self.t.submit(f"{what.capitalize()} not sent", partial(self.send, what))

    def flush(self, also: tuple[str, ...] = ()) -> None:
        """Send every pending edit now (and `also`, pending or not), on the calling worker."""
        with self._lock:
            pending = [w for w in DEBOUNCED if self._due.pop(w, None) is not None or w in also]
        for what in pending:
            self.send(what)

    def send(self, what: str) -> None:
        """Send one edit (on the command worker), as the loop holds it when it goes."""
        c, t = self.c, self.t
        if c.session is None or c.model is None:
            return
        if what == "initial":
            self.command(m.SetInitial(t.on_loop(lambda: list(c.initial))))
        elif what == "command":
            self.send_command()
        elif what == "settings":
            settings = t.on_loop(lambda: msgspec.structs.replace(c.settings, live_vars=self.live_vars()))
            self.command(m.SetSettings(settings))
            t.on_loop(lambda: setattr(c, "settings", settings))

    def _command_now(self) -> tuple[str, Any]:
        """(level, command) of the pendant whose path is the session's command, as it stands (on the
        loop); (level, None) when that pendant's path is empty or not this viewer's."""
        kind = self.c.command_kind
        editor = self.c.editor(kind)
        if editor is None or editor.empty:
            return kind, None
        return kind, editor.to_command()

    def send_command(self) -> None:
        """The path being edited as the session's command; the server's plan, or its refusal of the
        path (shown beside the path, naming the node: `CommandRefused`)."""
        t = self.t
        kind, command = t.on_loop(self._command_now)
        if command is None:
            return
        with self._lock:
            self._sent.append(codec.dumps(command))
        try:
            plan = self.command(m.SetCommand(command))
        except RemoteError as exc:
            if not exc.field.startswith("command"):
                raise
            t.on_loop(partial(self._command_refused, kind, exc.field, exc.error.message))
            return

        def planned() -> None:
            self.plan, self.refused = plan, ""
            t.emit(ev.PlanChanged(plan, kind))

        t.on_loop(planned)

    def _command_refused(self, kind: str, field: str, reason: str) -> None:
        self.refused = reason
        self.t.emit(ev.CommandRefused(kind, field, reason))

    def on_command(self, published: m.CommandValue) -> None:
        """The session's command as the proxy published it: one another client set (not one this
        tab sent, nor the one its pendant holds) goes into its pendant, with its plan."""
        c = self.c
        session, command = c.session, published.command
        if session is None or published.session != session.id or command is None:
            return
        encoded = codec.dumps(command)
        kind = pendant_level(command.kind)
        editor = c.editor(kind)
        with self._lock:
            if encoded in self._sent or editor is None:
                return
        try:
            if not editor.empty and codec.dumps(editor.to_command()) == encoded:
                return
        except ValueError:
            pass  # a composition that cannot be sent differs from any published command
        editor.load(command)  # type: ignore[arg-type]
        c.command_kind = kind
        self.plan, self.refused = published.plan, ""
        self.t.emit(ev.CommandReplaced(kind))
