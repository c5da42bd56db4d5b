"""Starting and steering the runs of a tab's session (paper §2.2 steps 7-8, 11): run, pause, resume,
abort, and replay, which plays a recording of the session's model back as a new run of the same
session. A button that does not apply in the session's phase is refused here with the reason of the
phase table (`simecs.mesh.phases`), before any request.

It also times the click on Run to the first live frame shown: the viewer's share of the latency
`simecs bench viewer` reports, read from the log line written here. Part of the session controller.
"""

from __future__ import annotations

import logging
import time
from functools import partial
from typing import TYPE_CHECKING

from simecs.mesh import messages as m

from .path import PathError, ended_early

if TYPE_CHECKING:
    from .session import SessionController

log = logging.getLogger("simecs.viewer")

STEER = {"pause": m.Pause, "resume": m.Resume, "abort": m.Abort}


class RunControl:
    """Run commands of one controller's session."""

    def __init__(self, controller: SessionController) -> None:
        self.c = controller
        self._clicked_at = 0.0
        self._timing = ""  # the run whose first live frame is timed from the click

    def run_action(self, op: str) -> None:
        """run / pause / resume / abort (a toolbar button)."""
        self._clicked_at = time.monotonic()
        c, title = self.c, op.capitalize()
        if c.session is None:
            c.notify(title, "Load a model first (Models).", "warning")
            return
        why = c.refusal(op)
        if why:
            c.notify(title, why, "warning")
            return
        drafts = c.pending_params() if op == "run" else []
        if drafts:  # the run would take the stored values, not the ones on the screen
            shown = ", ".join(drafts[:3]) + (f" and {len(drafts) - 3} more" if len(drafts) > 3 else "")
            c.notify(
                title,
                f"Typed values not applied yet ({shown}): Apply edits or Discard edits first.",
                "warning",
            )
            return
        c.submit(f"{title} refused", partial(self._send, op))

    def _send(self, op: str) -> None:
        c = self.c
        sc = c.session
        assert sc is not None
        if op != "run":
            sc.command(STEER[op]())
            return
        editor = c.editor(c.command_kind)  # None: a command this viewer does not edit (the server's)
        if editor is not None and editor.empty:
            editor.to_command()  # raises PathError: what the empty command lacks
        c.edits.flush(also=("command",))  # the run takes what the user sees, paused or not
        if editor is not None and c.edits.refused:
            raise PathError(f"the server refused the command ({c.edits.refused}): change it, then Run")
        t0 = time.monotonic()
        started: m.RunStarted = sc.command(m.Run())
        self._timing = started.run_id
        log.info(
            "tab %s: run %s assigned %.0f ms after the click (request %.0f ms)",
            c.tab_id,
            started.run_id,
            (time.monotonic() - self._clicked_at) * 1000,
            (time.monotonic() - t0) * 1000,
        )
        c.notify("Run", f"Run **{started.run_id}** assigned.")
        c.submit("Results", c.refresh_runs, "io")

    def shown(self, run_id: str) -> None:
        """A live frame of `run_id` was shown: log the first one of a run started here."""
        if run_id and run_id == self._timing:
            self._timing = ""
            log.info(
                "tab %s: first live frame of %s drawn %.0f ms after the click",
                self.c.tab_id,
                run_id,
                (time.monotonic() - self._clicked_at) * 1000,
            )

    def replay(self, recording: str) -> None:
        """Replay `recording` (of this session's model) as a run of this session."""
        c = self.c
        if c.session is None:
            c.notify("Replay", "Load a model first (Models).", "warning")
            return
        why = c.refusal("replay")
        if why:
            c.notify("Replay", why, "warning")
            return
        c.submit("Replay refused", partial(self.replay_now, recording))

    def replay_now(self, recording: str) -> None:
        """Start the replay (on a worker: it waits for the server)."""
        c = self.c
        started: m.RunStarted = c.edits.command(m.Replay(recording, 1.0, False))
        c.replays(started.run_id, recording)
        c.notify("Replay", f"Replaying **{recording}** as run **{started.run_id}** of this session.")
        c.show_state()
        c.submit("Results", c.refresh_runs, "io")

    def replay_run(self, run_id: str) -> None:
        """Replay the recording of a run of this session (of a replay run: the recording it replayed)."""
        if self.c.session is not None:
            self.replay(self.c.results.recording_of(run_id))

    def ended(self, st: m.SessionState) -> None:
        """Say how a run ended; a run whose stop time came before its command was done says so."""
        c = self.c
        recording = c.replay_of(st.run_id)
        what = f"Replay {st.run_id} of {recording}" if recording else f"Run {st.run_id}"
        if st.phase == "finished":
            early = "" if recording else ended_early(c.edits.plan, st.sim_time)
            done = (
                f"{st.sim_time:.3f} s replayed."
                if recording
                else f"{st.sim_time:.3f} s simulated (RTF {st.rtf:.2f}). Results: full resolution, CSV, MCAP."
            )
            c.notify(f"{what} finished", f"{early} {done}" if early else done, "warning" if early else "ok")
        elif st.phase == "aborted":
            c.notify(f"{what} aborted", st.reason or "aborted", "warning")
        else:
            c.notify(f"{what} failed", st.reason or "the run failed", "error")
