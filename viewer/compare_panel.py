"""The "Compare runs" folder of the Results tab (issue 12, runs compared for real): tick any kept runs
of the session (replays of recordings are runs too), and any of the user's recordings of the model
(read on the server, not replayed), to draw them in every plot, each to its own end; move one time
cursor across every plot while the arm shows the chosen run at that instant; read the values at the
cursor and what the runs differ in.

The run compared against is the one the Results tab has picked (what "Full resolution" loads).
Requests go through the session controller (`results_io.py`); their answers come back as
`ComparedLoaded` and `TrackLoaded` events.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol import phases

from . import events as ev
from .compare import RunTrack, differences, recording_key, recording_label, values_table
from .plot_dock import PlotDock
from .results import run_label
from .scene import ArmScene
from .session import SessionController
from .timeline import Timeline

MAX_COMPARED = 5  # runs drawn beside the shown one (each a dash pattern of its own)
RECORDINGS_LISTED = 20  # the newest recordings offered (and any ticked one): a box each
NO_RUN = "—"


class ComparePanel:
    """Which runs are compared, the shared time cursor, and what it reads."""

    def __init__(
        self,
        gui: Any,
        controller: SessionController,
        plots: PlotDock,
        scene: ArmScene,
        shown: Callable[[], str],
        timeline_place: Any = None,
    ) -> None:
        """`timeline_place`: the container the timeline goes in (the run bar's: beside the arm it
        drives); the panel's own folder when None."""
        self.gui = gui
        self.c = controller
        self.plots = plots
        self.scene = scene
        self.shown = shown  # the run the Results tab picked ('' before any run)
        self.tracks: dict[str, RunTrack] = {}
        self.asked: set[str] = set()  # tracks asked for (once each: a few MB)
        self.boxes: dict[str, Any] = {}  # run id -> its box
        self.recording_boxes: dict[str, Any] = {}  # recording_key(name) -> its box
        self._ended: set[str] | None = None  # the ended runs last shown (a change lists the recordings)
        self.folder = gui.add_folder("Compare runs")
        with self.folder:
            gui.add_markdown(
                "Tick runs to draw them in every plot beside the picked run, each to its own end. "
                "The **time cursor** moves across every plot and poses the arm as the chosen run was then."
            )
            self.box_folder = gui.add_folder("Runs to compare")
            self.recording_folder = gui.add_folder("Recordings to compare", expand_by_default=False)
            with self.recording_folder:
                self.recordings_note = gui.add_markdown("_Listing your recordings…_")
                self.relist = gui.add_button(
                    "List recordings again", hint="recordings of this model, other sessions' runs included"
                )
            self.relist.on_click(lambda _e: self.c.results.list_recordings())
            self.follow = gui.add_dropdown(
                "Arm shows", (NO_RUN,), hint="whose pose the arm takes at the cursor"
            )
            self.follow.on_update(self._follow_changed)
            self.values = gui.add_markdown("")
            self.diff = gui.add_markdown("")
        with timeline_place if timeline_place is not None else self.folder:
            self.timeline = Timeline(
                gui,
                on_toggle=self._cursor_toggled,
                on_move=self.show_cursor,
                after=controller.loop.after,
                warn=lambda text: controller.notify("Timeline", text, "warning"),
            )
        self._show_cursor_widgets()

    # -- which runs ----------------------------------------------------------------------------------
    def compared(self) -> list[str]:
        """The ticked runs other than the shown one, oldest first, then the ticked recordings."""
        shown = self.shown()
        return [r for r, box in self._all_boxes().items() if box.value and r != shown][:MAX_COMPARED]

    def _all_boxes(self) -> dict[str, Any]:
        return {**self.boxes, **self.recording_boxes}

    def show_runs(self, runs: Sequence[m.RunInfo]) -> None:
        """Boxes for the ended runs the server keeps (a run going on is compared once it ends), each
        once what produced it is known: its label is then final, so no box below it moves later
        (a box that moved under the pointer takes no click)."""
        ended = {r.run_id: r for r in runs if r.phase in phases.ENDED}
        described = {r: info for r, info in ended.items() if r in self.c.contexts}
        for run_id in [r for r in self.boxes if r not in ended]:
            self.boxes.pop(run_id).remove()
            self.tracks.pop(run_id, None)
            self.asked.discard(run_id)
        for run_id, info in described.items():
            label = run_label(info, self.c.contexts.get(run_id))
            if run_id in self.boxes:
                if self.boxes[run_id].label != label:
                    self.boxes[run_id].label = label
                continue
            with self.box_folder:
                box = self.gui.add_checkbox(label, False)
            box.on_update(self._ticked)
            self.boxes[run_id] = box
        if not ended:
            self.values.content = "_No finished run yet: runs are compared once they end._"
        if set(ended) != self._ended:  # a run ended, or one left the kept ten: its recording may show
            self._ended = set(ended)
            self.c.results.list_recordings()
        self.refresh()

    def show_recordings(self, event: ev.RecordingsListed) -> None:
        """Boxes for the user's recordings of this model, but those of runs the session still keeps
        (ticked as runs already)."""
        if not event.available:  # no recorder answered: the boxes shown (ticked ones too) stay
            note = (
                "_No recorder answered: there is none on the server, or it is busy. Runs are not listed "
                "as recordings until one answers (List recordings again)._"
            )
            if self.recordings_note.content != note:
                self.recordings_note.content = note
            return
        sc = self.c.session
        kept = {r.run_id for r in self.c.runs}
        shown = [r for r in event.recordings if sc is None or r.session != sc.id or r.run_id not in kept]
        ticked = {key for key, box in self.recording_boxes.items() if box.value}
        wanted = {
            recording_key(r.name): r
            for k, r in enumerate(shown)  # newest first
            if k < RECORDINGS_LISTED or recording_key(r.name) in ticked
        }
        gone = [k for k in self.recording_boxes if k not in wanted]
        for key in gone:
            self.recording_boxes.pop(key).remove()
            self.tracks.pop(key, None)
            self.asked.discard(key)
        new = [key for key in wanted if key not in self.recording_boxes]
        for key in new:
            info = wanted[key]
            size = f"{info.bytes / 1e6:.1f} MB"
            hint = f"recording {info.name}: run {info.run_id} of session {info.session}, {size}"
            with self.recording_folder:
                box = self.gui.add_checkbox(recording_label(info), False, hint=hint)
            box.on_update(self._ticked)
            self.recording_boxes[key] = box
        if not wanted:
            note = "_None yet besides the runs above: the recordings of this model's runs show here._"
        else:
            note = "Tick one to draw it beside the picked run: it is read on the server, not replayed."
            if len(shown) > RECORDINGS_LISTED:
                note += f" The {RECORDINGS_LISTED} newest of your {len(shown)} are listed."
        if self.recordings_note.content != note:
            self.recordings_note.content = note
        if gone or new:  # a listing that changed nothing leaves the page as it is
            self.refresh()

    def _ticked(self, event: Any) -> None:
        if event.client is None:
            return
        if len([b for b in self._all_boxes().values() if b.value]) > MAX_COMPARED + 1:
            event.target.value = False
            self.c.notify("Compare", f"At most {MAX_COMPARED} runs beside the picked one.", "warning")
            return
        self.refresh()

    def refresh(self) -> None:
        """Load what the plots and the cursor need of the runs now compared (the shown one too)."""
        compare = self.compared()
        for plot in self.plots.plots.values():
            have = [o.run_id for o in plot.others]
            if have == compare and all(v in o.ys for o in plot.others for v in plot.names()):
                continue
            if not compare:
                plot.others = []
                plot.mark()
            elif plot.full is not None:
                self.c.results.load_compared(plot.number, plot.names(), compare, plot.full.t0, plot.full.t1)
            else:
                self.c.results.load_compared(plot.number, plot.names(), compare)
        if compare or self.timeline.on:  # a track is a few MB: fetched when it is used
            for run_id in [self.shown(), *compare]:
                if run_id and run_id in self._all_boxes() and run_id not in {*self.tracks, *self.asked}:
                    self.asked.add(run_id)
                    self.c.results.load_track(run_id)
        self._show_cursor_widgets()

    # -- events --------------------------------------------------------------------------------------
    def apply(self, event: ev.Event) -> None:
        if isinstance(event, ev.ComparedLoaded):
            plot = self.plots.get(event.plot)
            if plot is not None and [o.run_id for o in event.others] == self.compared():  # not a stale answer
                plot.others = event.others
                plot.mark()
            self.show_cursor()
        elif isinstance(event, ev.TrackLoaded):
            self.tracks[event.track.run_id] = event.track
            self._show_cursor_widgets()

    def new_run(self) -> None:
        """A run starts: the arm is the live one's again, the cursor goes."""
        self.timeline.turn_off()
        self.plots.set_cursor(None)
        self._show_cursor_widgets()

    def show_phase(self) -> None:
        """The cursor poses the arm: not while a run moves it."""
        busy = self.c.phase in phases.UNDER_WAY
        if busy and self.timeline.on:
            self.plots.set_cursor(None)
        self._show_cursor_widgets()

    # -- the cursor ----------------------------------------------------------------------------------
    def _runs_in_view(self) -> list[str]:
        shown = self.shown()
        return [r for r in [shown, *self.compared()] if r]

    def _show_cursor_widgets(self) -> None:
        runs = [r for r in self._runs_in_view() if r in self.tracks]
        options = tuple(runs) or (NO_RUN,)
        if tuple(self.follow.options) != options:
            keep = self.follow.value
            self.follow.options = options
            self.follow.value = keep if keep in options else options[0]
        self.timeline.set_end(max((self.tracks[r].end for r in runs), default=0.0))
        self.timeline.enable(bool(runs), self.c.phase in phases.UNDER_WAY)
        self.follow.disabled = not self.timeline.on or not runs
        contexts = {r: self.tracks[r].context for r in runs}
        jogged = {r: info.jogged_s for r in runs if (info := self.tracks[r].info) is not None}
        diff = differences(contexts, self.c.model, jogged) if self.c.model is not None else ""
        if self.diff.content != diff:
            self.diff.content = diff

    def _cursor_toggled(self) -> None:
        if self.timeline.on and not [r for r in self._runs_in_view() if r in self._all_boxes()]:
            self.c.notify("Time cursor", "No finished run to scrub yet: run a simulation first.", "warning")
        self.asked &= set(self.tracks)  # a track that never came (a failed request) is asked again
        self.refresh()
        self.show_cursor()

    def _follow_changed(self, event: Any) -> None:
        if event.client is not None:
            self.show_cursor()

    def show_cursor(self) -> None:
        """Cursor on: every plot marks it, the arm takes the followed run's pose, values are read."""
        if not self.timeline.on:
            self.plots.set_cursor(None)
            if self.values.content:  # no cursor, nothing read at it (issue 32, 8)
                self.values.content = ""
            return
        at = self.timeline.at
        self.plots.set_cursor(at)
        track = self.tracks.get(str(self.follow.value))
        poses = track.at(at) if track is not None else None
        if poses is not None:
            self.scene.apply_poses(poses)
        q = track.q_at(at) if track is not None else None
        if q is not None:
            self.c.show_pose(q)  # the readout (and Teach) follow the instant shown
        names = self._variables()
        shown = {v: self.plots.unit_of(v)[0] for v in names}
        self.values.content = values_table(at, self._series(), names, shown)

    def _variables(self) -> list[str]:
        seen: list[str] = []
        for plot in self.plots.plots.values():
            seen += [v for v in plot.variables if v not in seen]
        return seen

    def _series(self) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
        """Each run's data as the plots hold it, in the units they show: run → variable → (t, y)."""
        out: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
        for plot in self.plots.plots.values():
            loaded = ([plot.full] if plot.full is not None else []) + plot.others
            for tr in loaded:
                for name, y in tr.ys.items():
                    factor = self.plots.unit_of(name)[1]
                    out.setdefault(tr.run_id, {})[name] = (tr.t, y * factor)
        order = self._runs_in_view()
        return {r: out[r] for r in [*order, *[r for r in out if r not in order]] if r in out}

    def remove(self) -> None:
        self.timeline.remove()
        self.folder.remove()
