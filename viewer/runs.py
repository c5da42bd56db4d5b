"""Starting and steering the runs of a tab's session (paper §2.2 steps 7-8, 11): run, pause, resume,
abort, and replay, which plays a recording of the session's model back as a new run of the same
session. A button that does not apply in the session's phase is refused here with the reason of the
phase table (`simecs.mesh.protocol.phases`), before any request.

It also times the click on Run to the first live frame shown: the viewer's share of the latency
`simecs bench viewer` reports, read from the log line written here. Part of the session controller:
it sees the tab through its state and dispatcher only.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from functools import partial

from simecs.mesh.protocol import messages as m

from . import events as ev
from .edits import Edits
from .path import PathError, ended_early
from .tab_state import TabState
from .workers import Dispatcher

log = logging.getLogger("simecs.viewer")

STEER = {"pause": m.Pause, "resume": m.Resume, "abort": m.Abort}


class RunControl:
    """Run commands of one tab's session: `view` its state, `tasks` its loop and workers, `edits` sent
    before a run, `refresh_runs` asks the server for the session's runs (on a worker)."""

    def __init__(
        self, view: TabState, tasks: Dispatcher, edits: Edits, refresh_runs: Callable[[], None]
    ) -> None:
        self.c = view
        self.t = tasks
        self.edits = edits
        self.refresh_runs = refresh_runs
        self._clicked_at = 0.0
        self._timing = ""  # the run whose first live frame is timed from the click

    def run_action(self, op: str) -> None:
        """run / pause / resume / abort (a toolbar button)."""
        self._clicked_at = time.monotonic()
        c, t, title = self.c, self.t, op.capitalize()
        if c.session is None:
            t.notify(title, "Load a model first (Models).", "warning")
            return
        why = c.refusal(op)
        if why:
            t.notify(title, why, "warning")
            return
        drafts = c.pending_params() if op == "run" else []
        if drafts:  # the run would take the stored values, not the ones on the screen
            shown = ", ".join(drafts[:3]) + (f" and {len(drafts) - 3} more" if len(drafts) > 3 else "")
            t.notify(
                title,
                f"Typed values not applied yet ({shown}): Apply edits or Discard edits first.",
                "warning",
            )
            return
        editor = c.editor(c.command_kind)  # None: a command this viewer does not edit (the server's)
        if op == "run" and editor is not None and editor.empty:
            try:
                editor.to_command()  # raises PathError: what the empty command lacks
            except PathError as exc:
                t.notify(f"{title} refused", str(exc), "warning")
                return
        t.submit(f"{title} refused", partial(self._send, op, editor is not None))

    def _send(self, op: str, edited: bool) -> None:
        """Send run/pause/resume/abort (on the command worker); a run sends the pending edits first.
        `edited`: the session's command is a pendant's (its refusal stops the run here)."""
        c, t = self.c, self.t
        sc = c.session
        assert sc is not None
        if op != "run":
            sc.command(STEER[op]())
            return
        self.edits.flush(also=("command",))  # the run takes what the user sees, paused or not
        if edited and self.edits.refused:
            raise PathError(f"the server refused the command ({self.edits.refused}): change it, then Run")
        t0 = time.monotonic()
        started: m.RunStarted = sc.command(m.Run())
        self._timing = started.run_id
        log.info(
            "tab %s: run %s assigned %.0f ms after the click (request %.0f ms)",
            t.tab_id,
            started.run_id,
            (time.monotonic() - self._clicked_at) * 1000,
            (time.monotonic() - t0) * 1000,
        )
        t.notify("Run", f"Run **{started.run_id}** assigned.")
        t.submit("Results", self.refresh_runs, "io")

    def open_run(self) -> None:
        """A run until stopped, for jogging the idle arm (real time, holding the initial pose or
        following the command): the pending edits go first, as for Run."""
        t = self.t

        def job() -> None:
            sc = self.c.session
            if sc is None:
                return
            self.edits.flush()
            started: m.RunStarted = self.edits.command(m.Run(until_stopped=True))
            t.notify("Jog", f"Run **{started.run_id}** holds the arm until you press Stop jogging.")
            t.submit("Results", self.refresh_runs, "io")

        t.submit("Jog refused", job)

    def finish_run(self) -> None:
        """End the run going now as finished (stop: its results kept, not aborted)."""
        self.t.submit("Stop refused", lambda: self.edits.command(m.Stop()))

    def shown(self, run_id: str) -> None:
        """A live frame of `run_id` was shown: log the first one of a run started here."""
        if run_id and run_id == self._timing:
            self._timing = ""
            log.info(
                "tab %s: first live frame of %s drawn %.0f ms after the click",
                self.t.tab_id,
                run_id,
                (time.monotonic() - self._clicked_at) * 1000,
            )

    def _start(self, title: str, op: str, job: Callable[[], None]) -> None:
        """Hand `job`, a command that starts a run, to a worker, unless the page can say at once why not."""
        c, t = self.c, self.t
        if c.session is None:
            t.notify(title, "Load a model first (Models).", "warning")
            return
        why = c.refusal(op)
        if why:
            t.notify(title, why, "warning")
            return
        t.submit(f"{title} refused", job)

    def replay(self, recording: str) -> None:
        """Replay `recording` (of this session's model) as a run of this session."""
        self._start("Replay", "replay", partial(self.replay_now, recording))

    def replay_now(self, recording: str) -> None:
        """Start the replay (on a worker: it waits for the server)."""
        c, t = self.c, self.t
        started: m.RunStarted = self.edits.command(m.Replay(recording, 1.0, False))

        def replaying() -> None:
            c.recordings[started.run_id] = recording
            st = c.state
            t.emit(ev.StateShown(st, c.replay_of(st.run_id) if st is not None else "", c.until_stopped()))

        t.on_loop(replaying)
        t.notify("Replay", f"Replaying **{recording}** as run **{started.run_id}** of this session.")
        t.submit("Results", self.refresh_runs, "io")

    def replay_run(self, run_id: str) -> None:
        """Replay the recording of a run of this session (of a replay run: the recording it replayed)."""
        if self.c.session is not None:
            self.replay(self.c.recording_of(run_id))

    def continue_run(self, run_id: str) -> None:
        """Go on with `run_id`, a run that failed part way, as a new run (the server says whether it can)."""
        self._start("Continue", "continue", partial(self.continue_now, run_id))

    def continue_now(self, run_id: str) -> None:
        """Start the continued run (on a worker: it waits for the server)."""
        started: m.RunStarted = self.edits.command(m.Continue(run_id))
        self.t.notify(
            "Continue",
            f"Run **{started.run_id}** goes on from where **{run_id}** ended: the same inputs, as fast as "
            "possible up to there, then at its pacing.",
        )
        self.t.submit("Results", self.refresh_runs, "io")

    def ended(self, st: m.SessionState) -> None:
        """Say how a run ended; a run whose stop time came before its command was done says so."""
        t = self.t
        recording = self.c.replay_of(st.run_id)
        what = f"Replay {st.run_id} of {recording}" if recording else f"Run {st.run_id}"
        if st.phase == "finished":
            early = "" if recording else ended_early(self.edits.plan, st.sim_time)
            done = (
                f"{st.sim_time:.3f} s replayed."
                if recording
                else f"{st.sim_time:.3f} s simulated (RTF {st.rtf:.2f}). Results: full resolution, CSV, MCAP."
            )
            t.notify(f"{what} finished", f"{early} {done}" if early else done, "warning" if early else "ok")
        elif st.phase == "aborted":
            t.notify(f"{what} aborted", st.reason or "aborted", "warning")
        else:
            offer = "" if recording else " **Continue** (Results) goes on from where its kept results end."
            t.notify(f"{what} failed", (st.reason or "the run failed") + offer, "error")
