"""The session of one browser tab, without the browser: what the tab shows and every request it makes.

`SessionController` owns the tab's session on the server (attach, create, close): its data is a
`TabState` (the model description, the parameter values, the initial pose, the pendants' commands,
the settings, the streamed variables, the state, the shown run and its live samples, the runs), kept
on the tab's loop (loop.py). It makes every request on its two worker threads (commands in order on
one, data fetches on the other), so viser's and zenoh's callbacks never wait on the server; a worker
hands what it got back to the loop. It sends slider-rate edits once they pause, and it tells its
listeners what changed with the events of `events.py`. It imports nothing of viser: the tests drive
it with a fake client and injected messages on a driven loop.

Its parts each hold one idea and see the tab only through `TabState` and the `Dispatcher`: `edits`
sends the user's edits, `control` starts and steers runs, `results` fetches and saves them, `opening`
lists the models and the user's sessions and opens one, `jog` jogs the arm.

A replay is a run of the session whose source is a recording of the same model: it is started,
paused, aborted and listed like any run; while its layout is the one shown, the 3D arm takes the
recorded parameter values.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from functools import partial

import numpy as np
from simecs.mesh.client import MeshClient, NoReply, RemoteError, SessionClient, Watch
from simecs.mesh.protocol import frames, keys, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import DocPage, ModelDescription

from . import events as ev
from .cartesian import CartesianPathEditor
from .direct import DirectInputEditor
from .edits import SYNC_DELAY_S, Edits
from .errors import describe_error
from .host import Host
from .identity import Identity, new_user_name
from .jog import JogControl
from .loop import TabLoop
from .opening import Opening
from .path import JointPathEditor, clamp_to_limits
from .program import ProgramEditor, pendant_level
from .results_io import ResultsIO
from .runs import RunControl
from .stream import LIVE_BEHIND, RunStream, Sample
from .tab_state import TabState
from .workers import Dispatcher

log = logging.getLogger("simecs.viewer")
REOPEN_TRIES = 3  # asks for a remembered session when the server does not answer
REOPEN_PAUSE_S = 1.0
#: Live frames waiting for the loop at most: a tab that falls further behind skips the oldest (the
#: run and its full results are not affected, and the tab says so once per run).
LIVE_QUEUE = 256


class SessionController(TabState, Dispatcher):
    """One tab's session and what the tab shows of it; see the module docstring."""

    def __init__(
        self,
        host: Host,
        tab_id: int = 0,
        sync_delay_s: float = SYNC_DELAY_S,
        loop: TabLoop | None = None,
    ) -> None:
        TabState.__init__(self)
        Dispatcher.__init__(self, tab_id, loop)
        self.host = host
        self.identity = Identity(host)
        self._remembered = ""  # the session the tab had, reopened once its user logged in
        self.edits = Edits(self, self, self.preview, sync_delay_s)
        self.control = RunControl(self, self, self.edits, self.refresh_runs)
        self.jog = JogControl(self, lambda: self.closed, self.control.open_run, self.control.finish_run)
        self.opening = Opening(self, self, host, self.identity, self.attach, self)
        self.results = ResultsIO(self, self, self.identity, self.control.replay, self._replay_in_new_session)
        self.live_frames = 0  # frames shown (diagnostics)
        self._notified_end: set[str] = set()
        self._watch: Watch | None = None
        self._watch_lock = threading.Lock()
        self._live: deque[tuple[str, frames.Frame]] = deque(maxlen=LIVE_QUEUE)

    @property
    def user(self) -> str:
        return self.identity.user

    @property
    def mc(self) -> MeshClient:
        """The client this tab acts for its user with (identity.py)."""
        return self.identity.mc

    # == lifecycle ================================================================================
    def start(self, remembered_session: str = "", remembered_user: str = "") -> None:
        """Find out who this is and reopen the session the tab had, or offer the models window (on a
        secured mesh: once the user has logged in there)."""
        try:
            self.identity.choose(remembered_user or self.host.default_user or new_user_name())
        except ValueError:
            self.identity.choose(new_user_name())
        if self.user != remembered_user:
            self.emit(ev.UserChanged(self.user))
        self._remembered = remembered_session
        self.submit("Open your session", self._reopen)

    def _reopen(self) -> None:
        sid, self._remembered = self._remembered, ""
        if not self.identity.logged_in:
            self._remembered = sid
            self.opening.list_library(can_dismiss=False)
            return
        if sid and keys.is_session_id(sid):
            log.info("tab %s reopens its session %s", self.tab_id, sid)
            if self.attach(sid, quiet_missing=True, tries=REOPEN_TRIES):
                return
        self.opening.list_library(can_dismiss=False)

    def login(self, password: str) -> None:
        """Log the tab's user in (secured mesh), then reopen the tab's session or list theirs."""

        def job() -> None:
            self.identity.login(password)
            self.notify("Logged in", f"You are **{self.user}** on this server.", "ok")
            self._reopen()

        self.submit("Log in", job)

    def close(self) -> None:
        """The tab went away (closed or reloading): keep the session, drop the subscriptions."""
        self.jog.stop()
        self.closed = True
        session = self.session
        if session is not None:
            self.host.claims.release(session.id, self)
        self._stop_watch()
        self.shutdown()
        self.identity.logout()

    def _replay_in_new_session(self, model_id: str, recording: str) -> None:
        """A recording of another model (an upload): replayed in a new session on its model."""

        def job() -> None:
            if self.opening.open_new_now(model_id):
                self.control.replay_now(recording)

        self.submit("Replay refused", job)

    def _stop_watch(self) -> None:
        with self._watch_lock:
            watch, self._watch = self._watch, None
        if watch is not None:
            try:
                watch.close()
            except Exception as exc:
                log.debug("watch close: %s", exc)

    def attach(
        self,
        sid: str,
        snapshot: m.SessionSnapshot | None = None,
        quiet_missing: bool = False,
        tries: int = 1,
    ) -> bool:
        """Make `sid` this tab's session (on a worker): restore its values, pose, command, settings
        and runs. `tries` > 1 asks again when the server did not answer (a viewer that has just
        restarted may ask before the mesh has its routes)."""
        claims = self.host.claims
        if not claims.claim(sid, self):
            log.info("tab %s: session %s is open in another tab", self.tab_id, sid)
            self.notify(
                "Session already open",
                "That session is shown in another tab; each tab works on its own session. "
                "Choose a model to start a new one, or close the other tab.",
                "warning",
            )
            return False
        sc = self.mc.session(self.user, sid)
        try:
            for attempt in range(1, tries + 1):
                try:
                    snap = snapshot or sc.snapshot()
                    break
                except NoReply as exc:
                    if attempt == tries or self.closed:
                        raise
                    log.info("tab %s: session %s: %s; asking again", self.tab_id, sid, exc)
                    time.sleep(REOPEN_PAUSE_S)
            model = self.host.describe(snap.model_id)
            meshes = self.host.meshes(model)
            if missing := len(set(model.mesh_names()) - set(meshes)):
                self.notify(
                    "Some parts are not drawn", f"{missing} of the model's meshes did not come.", "warning"
                )
        except (RemoteError, NoReply) as exc:
            log.info("tab %s: session %s not opened: %s", self.tab_id, sid, describe_error(exc))
            claims.release(sid, self)
            if quiet_missing and isinstance(exc, RemoteError) and exc.code == "not_found":
                self.notify("Previous session ended", "Your previous session is no longer on the server.")
                self.emit(ev.SessionRemembered(""))
            else:
                self.fail("Cannot open the session", exc)
            return False
        self._stop_watch()
        if not self.on_loop(partial(self._show_session, sc, model, meshes, snap)):
            claims.release(sid, self)
            return False
        log.info("tab %s shows session %s (%s, user %s)", self.tab_id, sid, model.id, self.user)
        watch = sc.watch(
            on_state=self.loop.wrap(self.on_state),
            on_params=self.loop.wrap(self.on_params),
            on_obstacles=self.loop.wrap(self.edits.on_obstacles),
            on_command=self.loop.wrap(self.edits.on_command),
            on_layout=self.loop.wrap(self.on_layout),
            on_live=partial(self._on_live_of, sid),
        )
        with self._watch_lock:
            self._watch = watch
        if self.on_loop(
            lambda: self.editor(self.command_kind) is not None and not self.refusal("set_command")
        ):
            # the plan of the session's path (its duration, tool path, node poses) is the server's
            self.submit("Command not planned", self.edits.send_command)
        self.submit("Results", self.refresh_runs, "io")
        self.submit("Parameter sets", self.edits.refresh_sets, "io")
        return True

    def _show_session(
        self, sc: SessionClient, model: ModelDescription, meshes: dict[str, bytes], snap: m.SessionSnapshot
    ) -> bool:
        """On the loop: the attached session becomes the tab's, and its page is built."""
        if self.closed:
            return False
        if self.session is not None and self.session.id != sc.id:
            self.host.claims.release(self.session.id, self)
        self.session = sc
        self.meshes = meshes
        self._take(model, snap)
        self.emit(ev.SessionRemembered(sc.id))
        self.emit(ev.ModelLoaded(model, sc.id))
        self.show_state()
        return True

    def _take(self, model: ModelDescription, snap: m.SessionSnapshot) -> None:
        self.model = model
        self.values = dict(snap.values)
        self.settings = snap.settings
        self.obstacles = list(snap.obstacles)
        self.state = snap.state
        self.runs = list(snap.runs)
        self.recordings = {r.run_id: r.recording for r in snap.runs if r.recording}
        self.contexts = {}
        self._notified_end = {r.run_id for r in snap.runs if r.phase in phases.ENDED}
        if snap.state.phase in phases.ENDED:
            self._notified_end.add(snap.state.run_id)
        self.initial = clamp_to_limits(snap.initial or [0.0] * len(model.links), model.links)
        self.shown_q = list(self.initial)
        every = {v.name for v in model.variables}
        self.streamed = set(snap.settings.live_vars) & every if snap.settings.live_vars else set(every)
        self.path = JointPathEditor(model.links)
        self.cart = CartesianPathEditor() if "cartesian_path" in model.command_levels else None
        joints = [link.joint for link in model.links]
        direct = "direct_input" in model.command_levels
        self.direct = DirectInputEditor(joints, lambda: self.initial) if direct else None
        self.program = ProgramEditor(joints) if "task" in model.command_levels else None
        if isinstance(snap.command, m.JointPath):
            self.path.load(snap.command)
        elif isinstance(snap.command, m.CartesianPath) and self.cart is not None:
            self.cart.load(snap.command)
        elif isinstance(snap.command, m.DirectInput) and self.direct is not None:
            self.direct.load(snap.command)
        elif isinstance(snap.command, m.Action | m.Task | m.Mission) and self.program is not None:
            self.program.load(snap.command)
        self.command_kind = pendant_level(snap.command.kind) if snap.command is not None else "joint_path"
        self.stream = RunStream(model)
        self.replaying = None
        self.edits.forget()

    # == what the arm shows ========================================================================
    def preview(self, q: list[float]) -> None:
        """Show the arm at `q` (the user's own configuration: a replay's shapes give way)."""
        self.shown_q = list(q)
        if self.replaying is not None:
            self.replaying = None
            self.emit(ev.ShapesChanged(dict(self.values)))
        self.emit(ev.PosePreview(list(q)))

    def show_pose(self, q: list[float]) -> None:
        """The arm is drawn at `q` by someone else (the time cursor, from a run's own link poses):
        what the readout shows and Teach records, without posing the arm again."""
        self.shown_q = list(q)

    def show_goal(self, q: list[float] | None) -> None:
        """The goal ghost at `q` (a pendant's picked node or action; None hides it): the arm itself
        stays where it is, which is what Teach records."""
        self.emit(ev.GoalShown(list(q) if q is not None else None))

    def tick(self, now: float | None = None) -> None:
        """Send the edits whose pause has come (called about 10 times a second)."""
        self.edits.tick(now)

    def fetch_doc(self, page: str) -> None:
        """A documentation page the description does not carry, asked from the server."""
        model = self.model
        if model is None:
            return

        def job() -> None:
            try:
                found = self.host.mc.doc(model.id, page)
            except (RemoteError, NoReply, ValueError) as exc:
                self.fail("Documentation", exc)
                found = DocPage(page, "Missing page", f"No page `{page}`: {describe_error(exc)}")
            self.emit(ev.DocFetched(found))

        self.submit("Documentation", job, "io")

    # == runs =====================================================================================
    def refresh_runs(self) -> None:
        """The session's runs, asked from the server (on a worker)."""
        sc = self.session
        if sc is None:
            return
        try:
            runs = sc.runs()
        except (RemoteError, NoReply):
            runs = list(sc.snapshot().runs)

        def take() -> None:
            if sc is not self.session:
                return
            self.runs = list(runs)
            self.recordings.update({r.run_id: r.recording for r in runs if r.recording})
            self.emit(ev.RunsChanged(list(runs), runs[-1].run_id if runs else ""))
            unknown = [r.run_id for r in runs if r.phase in phases.ENDED and r.run_id not in self.contexts]
            self.results.load_contexts(unknown)

        self.on_loop(take)

    # == streams from the server (run on the loop: `attach` wraps them) ==========================
    def _mine(self, session: str) -> bool:
        return not self.closed and self.session is not None and session == self.session.id

    def on_state(self, st: m.SessionState) -> None:
        if not self._mine(st.session):
            return
        prev = self.state
        if prev is not None and prev.run_id == st.run_id and prev.seq > st.seq:
            return  # an older publication arriving late
        self.state = st
        moved = prev is None or (prev.phase, prev.run_id) != (st.phase, st.run_id)
        ended = st.phase in phases.ENDED and st.run_id and st.run_id not in self._notified_end
        if ended:
            self._notified_end.add(st.run_id)
        self.show_state()
        if ended:
            self.control.ended(st)
        if moved:
            self.submit("Results", self.refresh_runs, "io")

    def show_state(self) -> None:
        st = self.state
        replay = self.replay_of(st.run_id) if st is not None else ""
        self.emit(ev.StateShown(st, replay, self.until_stopped()))

    def on_params(self, pv: m.ParamValues) -> None:
        if self._mine(pv.session) and pv.values != self.values:
            self.edits.show_values(pv.values)

    def on_layout(self, layout: m.RunLayout) -> None:
        """A run announced its columns: it is the run shown from now on (a replay's shapes with it)."""
        stream, st = self.stream, self.state
        if not self._mine(layout.session) or stream is None:
            return
        stream.take_layout(layout)
        replay = layout.source == "replay"
        if replay and layout.context.recording:
            self.recordings[layout.run_id] = layout.context.recording
        # A replay that already ended (a latched layout seen on attach) is not shown again.
        over = st is not None and st.run_id == layout.run_id and st.phase in phases.ENDED
        was = self.replaying
        self.replaying = layout if replay and not over else None
        self.emit(ev.LayoutChanged(layout))
        if self.replaying is not None or was is not None:
            self.emit(ev.ShapesChanged(self.shape_values()))
        self.show_state()

    def _on_live_of(self, session: str, frame: frames.Frame) -> None:
        """A live frame (on zenoh's thread): queued for the loop, which takes every waiting frame at
        once, so a tab that falls behind draws the newest pose instead of a backlog."""
        self._live.append((session, frame))
        if self.loop.owns():
            self._take_live()
        else:
            self.loop.post(self._take_live, key="live")

    def _take_live(self) -> None:
        samples: list[Sample] = []
        while self._live:
            session, frame = self._live.popleft()
            if self._mine(session):
                sample = self._sample(frame)
                if sample is not None:
                    samples.append(sample)
        if samples:
            self._show_live(samples)

    def on_live(self, frame: frames.Frame) -> None:
        """A decimated sample of the shown run: pose the arm, feed the plots (on the loop)."""
        sample = self._sample(frame)
        if sample is not None:
            self._show_live([sample])

    def _sample(self, frame: frames.Frame) -> Sample | None:
        stream = self.stream
        if self.closed or stream is None:
            return None
        sample = stream.take_frame(frame)
        if sample is not None and sample.first_gap:  # said once per run
            self.notify(*LIVE_BEHIND)
        return sample

    def _show_live(self, samples: list[Sample]) -> None:
        """What the frames taken at once show: the newest pose, every row for the plots and trace."""
        last = samples[-1]
        q = next((s.q for s in reversed(samples) if s.q is not None), None)
        if q is not None:
            self.shown_q = q
        poses = next((s.poses for s in reversed(samples) if s.poses is not None), None)
        rows = np.concatenate([s.rows for s in samples]) if len(samples) > 1 else last.rows
        tool = np.concatenate([s.tool for s in samples]) if len(samples) > 1 else last.tool
        self.emit(ev.LiveSamples(rows, poses, last.moved, last.arrows, tool))
        self.live_frames += len(samples)
        stream = self.stream
        if stream is not None and stream.layout is not None:
            self.control.shown(stream.layout.run_id)
