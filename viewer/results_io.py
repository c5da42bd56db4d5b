"""A session's results as the tab fetches and saves them (paper §2.2 steps 9-11): full-resolution
transients for the plots (zoom windows, the runs compared with it), the poses a time cursor scrubs
through, CSV and MCAP downloads, and uploading a recording to replay it.

Part of the session controller: every method returns at once and does its requests on the
controller's data worker; what it gets reaches the listeners as events. It sees the tab through its
state, its dispatcher and its identity only.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import numpy as np
from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol import phases
from simecs.mesh.protocol.limits import RUNS_KEPT
from simecs.mesh.rules import table_csv

from . import events as ev
from .compare import recording_of_key, track_columns, track_every, track_of
from .export import csv_name, upload_name
from .identity import Identity
from .series import Transient, every_for, transient
from .tab_state import TabState
from .workers import Dispatcher

#: Asks for a run's (or a recording's) samples: (variables, t0, t1, every) -> the results reply.
Fetch = Callable[..., tuple[m.ResultsAttachment, np.ndarray]]


class ResultsIO:
    """Fetches and transfers of one tab's session: `view` its state, `tasks` its loop and workers,
    `identity` who asks; an uploaded recording is replayed with `replay(name)` when it is of the
    session's model, else with `replay_elsewhere(model_id, name)` in a new session on its model."""

    def __init__(
        self,
        view: TabState,
        tasks: Dispatcher,
        identity: Identity,
        replay: Callable[[str], None],
        replay_elsewhere: Callable[[str, str], None],
    ) -> None:
        self.c = view
        self.t = tasks
        self.identity = identity
        self.replay = replay
        self.replay_elsewhere = replay_elsewhere
        #: What each recording compared holds (its RunInfo), asked once per listing: a closed file
        #: does not change, and each plot and zoom would otherwise ask again before its samples.
        self._recorded: dict[str, m.RunInfo] = {}

    def run(self, run_id: str = "") -> m.RunInfo | None:
        """Run `run_id` of the session, or the newest when it names none."""
        runs = self.c.runs
        return next((r for r in runs if r.run_id == run_id), runs[-1] if runs else None)

    def wants_full(self, name: str) -> bool:
        """A plot opened on `name` shows the last run at full resolution (nothing live to show)."""
        stream = self.c.stream
        live = stream is not None and stream.live.has(name)
        return bool(self.c.runs) and self.c.phase not in phases.UNDER_WAY and not live

    # -- transients ---------------------------------------------------------------------------------
    def load_full(
        self,
        plot: int,
        names: list[str],
        t0: float | None = None,
        t1: float | None = None,
        run_id: str = "",
        compare: Sequence[str] = (),
    ) -> None:
        """Load `names` of run `run_id` (the newest if '') over [t0, t1] for plot `plot`, and of the
        runs in `compare` over the same window."""

        def job() -> None:
            run = self.run(run_id)
            if run is None:
                raise ValueError("no run yet: run a simulation first")
            st = self.c.state
            if st is not None and st.run_id == run.run_id and st.phase in phases.UNDER_WAY:
                raise ValueError("the run is still going on: full resolution is available once it ends")
            sc = self.c.session
            assert sc is not None
            full = self._fetch(run.run_id, run, functools.partial(sc.results_of, run.run_id), names, t0, t1)
            others = self._compared([r for r in compare if r != run.run_id], names, t0, t1)
            self.t.emit(ev.TransientLoaded(plot, full, others))

        self.t.submit("Full resolution", job, "io")

    def load_compared(
        self,
        plot: int,
        names: list[str],
        compare: Sequence[str],
        t0: float | None = None,
        t1: float | None = None,
    ) -> None:
        """The runs in `compare` (their `names` over [t0, t1]) for plot `plot`'s overlay."""

        def job() -> None:
            self.t.emit(ev.ComparedLoaded(plot, self._compared(compare, names, t0, t1)))

        self.t.submit("Compare", job, "io")

    def load_track(self, key: str) -> None:
        """What the time cursor needs of a run (or a recording: `compare.recording_key`): its link
        poses and its context."""

        def job() -> None:
            run, fetch = self._source(key)
            model = self.c.model
            assert model is not None
            att, rows = fetch(track_columns(model), every=track_every(run.samples))
            self.t.emit(ev.TrackLoaded(track_of(key, list(att.columns), rows, att.context, att.run)))

        self.t.submit("Time cursor", job, "io")

    def _ended(self, run_id: str) -> m.RunInfo:
        run = next((r for r in self.c.runs if r.run_id == run_id), None)
        if run is None:
            raise ValueError(f"run {run_id} is no longer kept by the server (it keeps the last {RUNS_KEPT})")
        if run.phase not in phases.ENDED:
            raise ValueError(f"run {run_id} is still going on: compare it once it ends")
        return run

    def _compared(
        self, compare: Sequence[str], names: list[str], t0: float | None, t1: float | None
    ) -> list[Transient]:
        return [self._fetch(key, *self._source(key), names, t0, t1) for key in compare]

    def _source(self, key: str) -> tuple[m.RunInfo, Fetch]:
        """What a compared key holds (an ended run of the session, or one of the user's recordings)
        and how to ask for its samples: the run's results, or the recorder's answer for the file."""
        name = recording_of_key(key)
        if name:
            mc, user = self.identity.mc, self.identity.user
            held = self._recorded.get(name)
            if held is None:
                try:
                    about, _ = mc.recording_results(user, name, t0=-1.0, t1=-1.0)  # no rows: what it holds
                except NoReply:
                    raise ValueError(
                        f"no recorder answered: recording {name} cannot be compared now"
                    ) from None
                held = self._recorded[name] = about.run
            return held, functools.partial(mc.recording_results, user, name)
        sc = self.c.session
        assert sc is not None
        run = self._ended(key)
        return run, functools.partial(sc.results_of, run.run_id)

    def load_contexts(self, run_ids: Sequence[str]) -> None:
        """What produced each of the session's ended runs `run_ids` (its context), asked once each:
        the run lists say what each run did. A results query for no row brings it."""
        sc = self.c.session
        if sc is None or not run_ids:
            return

        def job() -> None:
            got: dict[str, m.RunContext | None] = {}
            for run_id in run_ids:
                try:
                    att, _ = sc.results_of(run_id, ["time"], t0=-1.0, t1=-1.0)
                except (RemoteError, NoReply):
                    got[run_id] = None  # listed all the same, without saying what it did
                    continue
                got[run_id] = att.context

            def take() -> None:
                if sc is self.c.session and got:
                    self.c.contexts.update(got)
                    self.t.emit(ev.RunsDescribed())

            self.t.on_loop(take)

        self.t.submit("Results", job, "io")

    def list_recordings(self) -> None:
        """The user's recordings of the session's model, as `RecordingsListed`."""

        def job() -> None:
            model = self.c.model
            self._recorded.clear()  # a recording may have been deleted and uploaded again since
            try:
                listed = self.identity.mc.recordings(self.identity.user)
            except NoReply:
                self.t.emit(ev.RecordingsListed([], available=False))
                return
            kept = [r for r in listed if model is not None and r.model_id == model.id]
            self.t.emit(ev.RecordingsListed(kept))

        self.t.submit("Recordings", job, "io")

    def _fetch(
        self, key: str, run: m.RunInfo, fetch: Fetch, names: list[str], t0: float | None, t1: float | None
    ) -> Transient:
        every = every_for(run.samples, t0, t1, run.stop_time)
        att, rows = fetch(names, t0, t1, every)
        if every > 1:
            self.t.notify(
                "Long run", f"Showing every {every}th sample of {key}; zoom in for full resolution."
            )
        return transient(key, list(att.columns), rows, t0, t1, every, att.context)

    # -- files -------------------------------------------------------------------------------------
    def download_csv(self, run_id: str, names: list[str] | None) -> None:
        """The run's `names` (every variable when None) at full resolution, as a CSV download."""

        def job() -> None:
            sc, model, stream = self.c.session, self.c.model, self.c.stream
            assert sc is not None and model is not None and stream is not None
            cols, rows = sc.results(run_id, names)
            units = [stream.units.get(c, "") for c in cols]
            meta = {"model": model.id, "session": sc.id, "run": run_id, "samples": str(rows.shape[0])}
            recording = self.c.replay_of(run_id)
            if recording:
                meta["replay of"] = recording
            data = table_csv.table_bytes(cols, rows, units, meta)
            self.t.emit(ev.Download(csv_name(model.id, sc.id, run_id), data))
            self.t.notify("CSV", f"{rows.shape[0]} samples × {len(cols)} columns of {run_id}.", "ok")

        self.t.submit("CSV download", job, "io")

    def download_mcap(self, run_id: str) -> None:
        """The run's recording (from the recorder node; it opens in Foxglove)."""

        def job() -> None:
            name = self.c.recording_of(run_id)
            try:
                payload = self.identity.mc.download_recording(self.identity.user, name)
            except NoReply:
                self.t.notify(
                    "No recording",
                    "No recorder answered: the server runs without the recorder node, so this run was not "
                    "recorded. CSV is available.",
                    "warning",
                )
                return
            self.t.emit(ev.Download(f"{name}.mcap", payload))
            self.t.notify("Recording", f"{name}.mcap ({len(payload) / 1e6:.2f} MB): opens in Foxglove.", "ok")

        self.t.submit("Recording download", job, "io")

    def upload(self, filename: str, content: bytes) -> None:
        """Store a recording the user kept, then replay it: in this session when it is of this
        session's model, else in a new session on its model (as loading that model would)."""

        def job() -> None:
            name = upload_name(filename)
            try:
                info = self.identity.mc.upload_recording(self.identity.user, name, content)
            except NoReply:
                self.t.notify(
                    "Upload unavailable",
                    "No recorder answered: the server cannot take recordings.",
                    "warning",
                )
                return
            model = self.c.model
            if model is not None and info.model_id == model.id:
                self.t.notify("Recording uploaded", f"Stored as **{name}**; replaying it.", "ok")
                self.replay(name)
                return
            self.t.notify(
                "Recording uploaded",
                f"Stored as **{name}**, a recording of model **{info.model_id}**: a new session on that "
                "model replays it.",
                "ok",
            )
            self.replay_elsewhere(info.model_id, name)

        self.t.submit("Upload", job, "io")
