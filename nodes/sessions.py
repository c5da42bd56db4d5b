"""The proxy's sessions: who they belong to, their values, pose, command, settings, runs and state;
kept in memory, written to disk on every change (one JSON file each, atomically), and published on
the session's latched `state` and `params` keys. Phases move only as `mesh.protocol.phases` allows.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simecs.mesh.process import files
from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import codec, keys, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.limits import RUNS_KEPT
from simecs.mesh.protocol.model import ModelDescription

log = logging.getLogger("simecs.proxy")


@dataclass
class SessionRecord:
    id: str
    user: str
    model_id: str
    values: dict[str, float]
    initial: list[float]
    command: m.RobotCommand | None
    settings: m.RunSettings
    state: m.SessionState
    runs: list[m.RunInfo] = field(default_factory=list)
    run_counter: int = 0
    obstacles: list[Obstacle] = field(default_factory=list)
    pubs: dict[str, Any] = field(default_factory=dict)
    #: A RunRequest is on its way to a simulator; the proxy's lock is not held meanwhile.
    starting: bool = False
    #: The run the user aborted: asked again on each of its status reports until it ends (a worker
    #: that was just starting may not have been listening yet).
    abort_run: str = ""
    #: The run whose worker has reported (a sealed status): only then may the loss of its token fail it.
    reported: str = ""
    #: When (monotonic) that worker's last status report came: a worker that reports after its token
    #: vanished is alive, whatever the mesh's token tables say under load.
    reported_at: float = 0.0
    #: Wall time of the user's last command or the last run's end: idle sessions expire from it.
    active_at: float = field(default_factory=time.time)

    def snapshot(self) -> m.SessionSnapshot:
        return m.SessionSnapshot(
            session=self.id,
            user=self.user,
            model_id=self.model_id,
            values=dict(self.values),
            initial=list(self.initial),
            command=self.command,
            settings=self.settings,
            state=self.state,
            runs=list(self.runs),
            obstacles=list(self.obstacles),
        )

    def run_info(self, run_id: str) -> m.RunInfo | None:
        return next((r for r in self.runs if r.run_id == run_id), None)

    def add_run(self, info: m.RunInfo) -> None:
        """A new run; the session keeps (and its simulator stores) the last RUNS_KEPT."""
        self.runs = [*self.runs, info][-RUNS_KEPT:]

    @property
    def phase(self) -> str:
        return self.state.phase


class SessionStore:
    """Every open session, on disk and on the mesh."""

    def __init__(
        self,
        folder: str | os.PathLike[str],
        latched_publisher: Callable[[str], Any],
        release: Callable[[Any], None],
    ) -> None:
        self.folder = Path(folder)
        self._publisher = latched_publisher
        self._release = release
        self.records: dict[str, SessionRecord] = {}

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self) -> Iterator[SessionRecord]:
        return iter(list(self.records.values()))

    def _path(self, sid: str) -> Path:
        return self.folder / f"{sid}.json"

    # -- on disk -------------------------------------------------------------------------------------
    def persist(self, rec: SessionRecord) -> None:
        data = codec.to_obj(rec.snapshot())
        data["run_counter"] = rec.run_counter
        data["active_at"] = rec.active_at
        files.write_json(self._path(rec.id), data)

    def load(self, library: dict[str, ModelDescription]) -> None:
        """Restore every session file; one that cannot be read is logged and left in place."""
        if not self.folder.is_dir():
            return
        for path in sorted(self.folder.glob("*.json")):
            try:
                data = files.read_json(path)
                counter = int(data.pop("run_counter", 0))
                active_at = float(data.pop("active_at", time.time()))
                snap = codec.from_obj(m.SessionSnapshot, data)
                if snap.model_id not in library:
                    raise ValueError(f"model {snap.model_id} is no longer in the library")
                if "obstacles" not in data:  # a session of a simecs before obstacles: the model's
                    snap.obstacles = list(library[snap.model_id].obstacles)
            except Exception as exc:
                log.error("cannot restore session file %s: %s (left in place)", path, exc)
                continue
            if snap.state.phase == "closed":
                continue
            rec = SessionRecord(
                snap.session,
                snap.user,
                snap.model_id,
                snap.values,
                snap.initial,
                snap.command,
                snap.settings,
                snap.state,
                snap.runs,
                counter,
                obstacles=snap.obstacles,
                active_at=active_at,
            )
            self._add(rec)
            self.publish_command(rec, None)  # what every client's pendants show (plans are not kept)
        log.info("restored %d sessions from %s", len(self.records), self.folder)

    # -- lifecycle -----------------------------------------------------------------------------------
    def _add(self, rec: SessionRecord) -> None:
        self.records[rec.id] = rec
        rec.pubs["state"] = self._publisher(keys.state(rec.user, rec.id))
        rec.pubs["params"] = self._publisher(keys.params(rec.user, rec.id))
        rec.pubs["obstacles"] = self._publisher(keys.obstacles(rec.user, rec.id))
        rec.pubs["command"] = self._publisher(keys.command(rec.user, rec.id))

    def create(self, user: str, desc: ModelDescription) -> SessionRecord:
        sid = keys.new_session_id()
        rec = SessionRecord(
            id=sid,
            user=user,
            model_id=desc.id,
            values=desc.default_values(),
            initial=list(desc.home) if desc.home else [0.0] * len(desc.links),  # within every range
            command=None,
            settings=m.RunSettings(),
            state=m.SessionState(session=sid, phase="created"),
            obstacles=list(desc.obstacles),
        )
        self._add(rec)
        self.publish_state(rec)
        self.publish_params(rec, [])
        self.publish_obstacles(rec)
        self.publish_command(rec, None)
        return rec

    def get(self, key: str) -> SessionRecord:
        """The session a per-session key names; its user must be the one in the key (a session of
        another user is as unknown as one that never existed)."""
        user, sid = keys.owner_of(key)
        rec = self.owned(user, sid)
        if rec is None:
            raise RequestError(
                "not_found", f"{user} has no session {sid} (closed, or never created)", "session"
            )
        return rec

    def owned(self, user: str, sid: str) -> SessionRecord | None:
        rec = self.records.get(sid)
        return rec if rec is not None and rec.user == user else None

    def idle(self, older_than_s: float, now: float | None = None) -> list[SessionRecord]:
        """Sessions with no run under way and nothing done for `older_than_s`."""
        now = time.time() if now is None else now
        return [
            r
            for r in self
            if r.phase not in phases.UNDER_WAY and not r.starting and now - r.active_at > older_than_s
        ]

    def close(self, rec: SessionRecord) -> None:
        """The end of a session (the user's, or its idle expiry): its file goes, and the `closed` state
        tells the simulators to remove its results (parameter sets and recordings stay)."""
        self.move(rec, "closed", persist=False)
        for pub in rec.pubs.values():
            self._release(pub)
        del self.records[rec.id]
        self._path(rec.id).unlink(missing_ok=True)

    def of_user(self, user: str) -> list[m.SessionEntry]:
        return [m.SessionEntry(r.id, r.model_id, r.phase) for r in self.records.values() if r.user == user]  # type: ignore[arg-type]

    # -- publishing ----------------------------------------------------------------------------------
    def publish_state(self, rec: SessionRecord, persist: bool = True) -> None:
        rec.state.seq += 1
        rec.pubs["state"].put(codec.dumps(rec.state))
        if persist:
            self.persist(rec)

    def publish_params(self, rec: SessionRecord, changed: list[str]) -> None:
        msg = m.ParamValues(session=rec.id, model_id=rec.model_id, values=rec.values, changed=changed)
        rec.pubs["params"].put(codec.dumps(msg))

    def publish_obstacles(self, rec: SessionRecord) -> None:
        rec.pubs["obstacles"].put(codec.dumps(m.ObstacleValues(session=rec.id, obstacles=rec.obstacles)))

    def publish_command(self, rec: SessionRecord, plan: m.CommandPlan | None) -> None:
        msg = m.CommandValue(session=rec.id, command=rec.command, plan=plan)
        rec.pubs["command"].put(codec.dumps(msg))

    def move(self, rec: SessionRecord, event: str, persist: bool = True, **fields: Any) -> None:
        """Apply a lifecycle event (mesh.protocol.phases) and publish the new state."""
        rec.state.phase = phases.after(rec.phase, event)  # type: ignore[assignment]
        for name, value in fields.items():
            setattr(rec.state, name, value)
        self.publish_state(rec, persist)

    def edited(self, rec: SessionRecord) -> None:
        """Values, pose, command, settings or obstacles changed: stored; `created` becomes `configured`."""
        if rec.phase == "created":
            self.move(rec, "edited")
        else:
            self.persist(rec)

    def persist_all(self) -> None:
        for rec in self:
            try:
                self.persist(rec)
            except Exception as exc:
                log.error("could not persist session %s: %s", rec.id, exc)
