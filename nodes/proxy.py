"""The proxy node: the paper's Simulation Server + Low Level Proxy, and the one owner of sessions.

It answers every session command (a table from message type to handler, each command allowed only in
the phases `mesh.phases` lists), validates it against the model and applies nothing partially, keeps
named parameter sets, admits runs (`admission.py`) and turns simulator-independent requests into
`RunRequest`s for simulator hosts, reached only over the mesh. A replay is a run like any other,
whose source is a recording. Sessions are persisted on every change (`sessions.py`), so a restart of
any node loses nothing a user did.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import zenoh
from simecs.mesh import codec, keys, phases
from simecs.mesh import messages as m
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.model import DocPage, ModelDescription, check_joints
from simecs.mesh.runtime import Node, NotMine, Request, RequestError, main_for, mesh_from_args

from .admission import Admission
from .library import ModelLibrary
from .paramsets import ParamSetStore
from .sessions import SessionRecord, SessionStore

MAX_WARNINGS = 20
#: How long a lost run token waits for the worker's own last report (it travels another way).
LAST_REPORT_GRACE_S = 0.3


class Proxy(Node):
    """Sessions, validation, parameter sets, model library and documentation, admission."""

    role = "proxy"

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        data_dir: str = ".simecs",
        max_running: int | None = None,
        max_queue: int = 16,
        max_sessions: int = 256,
    ) -> None:
        super().__init__(mesh, node_id)
        data = Path(data_dir)
        self.max_sessions = max_sessions
        self.lock = threading.RLock()
        self.library: ModelLibrary | None = None
        self.store = SessionStore(
            data / "sessions", lambda key: self.publisher(key, latched=True), self._release
        )
        self.paramsets = ParamSetStore(data / "paramsets")
        self.admission = Admission(
            self.store, lambda: self.z, self.lock, self._handed_over, max_running, max_queue
        )
        #: Runs of closed sessions that were told to abort: session id -> run id.
        self._orphan_runs: dict[str, str] = {}
        self.commands: dict[type, Callable[[SessionRecord, Any], Any]] = {
            m.SetParams: self._set_params,
            m.ResetParams: self._reset_params,
            m.SetInitial: self._set_initial,
            m.SetCommand: self._set_command,
            m.SetSettings: self._set_settings,
            m.Run: self._run,
            m.Pause: self._pause,
            m.Resume: self._resume,
            m.Abort: self._abort,
            m.Seek: self._seek,
            m.SaveParamSet: self._save_param_set,
            m.LoadParamSet: self._load_param_set,
            m.DeleteParamSet: self._delete_param_set,
            m.ListParamSets: self._list_param_sets,
            m.GetSession: lambda rec, _cmd: rec.snapshot(),
            m.CloseSession: self._close_session,
        }

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--data-dir", default=os.environ.get("SIMECS_DATA", ".simecs"), help="sessions and parameter sets"
        )
        parser.add_argument(
            "--max-running", type=int, default=None, help="simultaneous runs (default: cores)"
        )
        parser.add_argument("--max-queue", type=int, default=16, help="runs waiting beyond max-running")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Proxy:
        return cls(mesh_from_args(args), args.node_id, args.data_dir, args.max_running, args.max_queue)

    def status_detail(self) -> dict[str, Any]:
        with self.lock:
            running = sum(1 for s in self.store if s.phase in phases.GOING)
            return {"sessions": len(self.store), "running": running, "queued": len(self.admission.queue)}

    def _release(self, entity: Any) -> None:
        try:
            entity.undeclare()
            self._declared.remove(entity)
        except Exception:
            pass

    # -- startup ---------------------------------------------------------------------------------
    def start(self) -> None:
        self.library = ModelLibrary()
        self.store.load(self.library.descriptions)
        self.serve(keys.LIBRARY, lambda _req: self.models.summaries())
        self.serve(keys.ALL_MODELS, self._on_model)
        self.serve(keys.ALL_DOCS, self._on_doc)
        self.serve(keys.SESSIONS, self._on_sessions, threaded=True)
        self.serve(keys.ALL_CMD, self._on_cmd, threaded=True)
        self.serve(keys.ALL_RESULTS_LIST, self._on_results_list, threaded=True)
        self.serve(keys.ALL_RESULTS, self._on_results, threaded=True)
        self.subscribe_messages(keys.ALL_RUN_STATUS, m.RunStatus, self._on_run_status, maxlen=4096)
        self.subscribe_messages(keys.ALL_NOTICES, m.Notice, self._on_notice, maxlen=256)
        self.subscribe(keys.RUN_TOKENS, self._on_run_token, maxlen=4096, liveliness=True)
        self._recover_runs()

    @property
    def models(self) -> ModelLibrary:
        assert self.library is not None, "proxy not started"
        return self.library

    def _model(self, rec: SessionRecord) -> ModelDescription:
        return self.models.describe(rec.model_id)

    def _recover_runs(self) -> None:
        """After a restart: runs whose worker still lives go on; the others are settled from their
        stored results; queued runs take their place in the queue again."""
        alive = set()
        for reply in self.z.liveliness().get(keys.RUN_TOKENS, timeout=1.0):
            if reply.ok is not None:
                token = keys.parse("run_token", reply.ok.key_expr)
                alive.add((token["session"], token["run"]))
        with self.lock:
            for rec in self.store:
                mine = (rec.id, rec.state.run_id) in alive
                if rec.phase in phases.GOING and not mine:
                    self._settle_ended_run(rec)
                elif rec.phase == "queued" and mine:  # it was being handed over when the proxy stopped
                    self._started(rec)
                elif rec.phase == "queued":
                    self.admission.requeue(rec, self._request(rec, rec.state.run_id))
                else:
                    self.store.publish_state(rec)
                    self.store.publish_params(rec, [])
            self.admission.update()

    def _settle_ended_run(self, rec: SessionRecord) -> None:
        """A run that ended while the proxy was down: its stored results tell how it ended."""
        run_id = rec.state.run_id
        try:
            selector = keys.results(rec.id, run_id) + "?t0=-1;t1=-1"  # no rows: the description only
            _, att = MeshClient(self.z, timeout=3.0).request_binary(selector, m.ResultsAttachment)
            info: m.RunInfo = att.run
        except (RemoteError, NoReply, codec.DecodeError, zenoh.ZError, AttributeError):
            self._end_run(rec, "failed", "the run was lost while the proxy was down")
            return
        rec.state.sim_time = info.sim_time
        rec.state.progress = min(1.0, info.sim_time / info.stop_time) if info.stop_time else 0.0
        self._end_run(rec, info.phase if info.phase in phases.ENDED else "failed", info.reason)

    # -- library -----------------------------------------------------------------------------------
    def _on_model(self, req: Request) -> ModelDescription:
        return self.models.describe(keys.parse("model", req.key)["model"])

    def _on_doc(self, req: Request) -> DocPage:
        where = keys.parse("doc", req.key)
        return self.models.doc(where["model"], where["page"])

    # -- sessions ----------------------------------------------------------------------------------
    def _on_sessions(self, req: Request) -> Any:
        msg = req.json(m.SessionRequest)
        if isinstance(msg, m.ListSessions):
            with self.lock:
                return self.store.of_user(msg.user)
        desc = self.models.describe(msg.model_id)
        with self.lock:
            if len(self.store) >= self.max_sessions:
                raise RequestError("busy", f"the server holds its maximum of {self.max_sessions} sessions")
            rec = self.store.create(msg.user, desc)
            self.log.info("session %s created for %s on model %s", rec.id, msg.user, desc.id)
            return rec.snapshot()

    # -- commands ------------------------------------------------------------------------------
    def _on_cmd(self, req: Request) -> Any:
        cmd = req.json(m.SessionCommand)
        # Asking the recorder what a recording holds may take a while: not under the lock.
        recording = self._recording(cmd.recording) if isinstance(cmd, m.Replay) else None
        with self.lock:
            rec = self.store.get(req.key)
            why = phases.refusal(cmd.op, rec.phase)
            if why:
                raise RequestError("conflict", why)
            if isinstance(cmd, m.Replay):
                return self._replay(rec, cmd, recording)
            return self.commands[type(cmd)](rec, cmd)

    def _set_params(self, rec: SessionRecord, cmd: m.SetParams) -> dict[str, float]:
        rec.values = self.models.check(rec.model_id, cmd.values, rec.values)
        self.store.publish_params(rec, sorted(cmd.values))
        self.store.edited(rec)
        return rec.values

    def _reset_params(self, rec: SessionRecord, cmd: m.ResetParams) -> dict[str, float]:
        defaults = self._model(rec).default_values()
        for i, name in enumerate(cmd.names):
            if name not in defaults:
                raise RequestError("bad_request", f"unknown parameter {name!r}", f"names[{i}]")
        names = cmd.names or list(defaults)
        rec.values = self.models.check(rec.model_id, {n: defaults[n] for n in names}, rec.values)
        self.store.publish_params(rec, sorted(names))
        self.store.edited(rec)
        return rec.values

    def _set_initial(self, rec: SessionRecord, cmd: m.SetInitial) -> list[float]:
        check_joints(self._model(rec), cmd.joints, "joints")
        rec.initial = list(cmd.joints)
        self.store.edited(rec)
        return rec.initial

    def _set_command(self, rec: SessionRecord, cmd: m.SetCommand) -> str:
        desc = self._model(rec)
        level = cmd.command.kind
        if level not in desc.command_levels:
            raise RequestError(
                "unsupported",
                f"model {desc.id} accepts {', '.join(desc.command_levels)} commands, not {level}",
                "command.kind",
            )
        if isinstance(cmd.command, m.JointPath):
            for i, node in enumerate(cmd.command.nodes):
                check_joints(desc, node.q, f"command.nodes[{i}].q")
        rec.command = cmd.command
        self.store.edited(rec)
        return level

    def _set_settings(self, rec: SessionRecord, cmd: m.SetSettings) -> m.RunSettings:
        desc = self._model(rec)
        names = {v.name for v in desc.variables}
        for i, name in enumerate(cmd.settings.live_vars):
            if name not in names:
                raise RequestError(
                    "bad_request", f"model {desc.id} has no variable {name!r}", f"settings.live_vars[{i}]"
                )
        rec.settings = cmd.settings
        self.store.edited(rec)
        return rec.settings

    # -- parameter sets ----------------------------------------------------------------------------
    def _save_param_set(self, rec: SessionRecord, cmd: m.SaveParamSet) -> str:
        self.paramsets.save(rec.user, rec.model_id, cmd.name, rec.values)
        return cmd.name

    def _load_param_set(self, rec: SessionRecord, cmd: m.LoadParamSet) -> dict[str, float]:
        stored = self.paramsets.load(rec.user, rec.model_id, cmd.name)
        known = self._model(rec).default_values()
        # Parameters added to the model since the set was saved keep their current values.
        kept = {k: v for k, v in stored.items() if k in known}
        try:
            rec.values = self.models.check(rec.model_id, kept, rec.values)
        except (RequestError, codec.DecodeError) as exc:
            raise RequestError(
                "bad_request", f"parameter set {cmd.name!r} is unusable: {exc}", "name"
            ) from None
        self.store.publish_params(rec, sorted(kept))
        self.store.edited(rec)
        return rec.values

    def _delete_param_set(self, rec: SessionRecord, cmd: m.DeleteParamSet) -> str:
        self.paramsets.delete(rec.user, rec.model_id, cmd.name)
        return cmd.name

    def _list_param_sets(self, rec: SessionRecord, cmd: m.ListParamSets) -> list[str]:
        return self.paramsets.names(rec.user, rec.model_id)

    def _close_session(self, rec: SessionRecord, cmd: m.CloseSession) -> str:
        if rec.phase in phases.GOING:
            self._orphan_runs[rec.id] = rec.state.run_id
            self._control(rec, "abort")
        self.admission.withdraw(rec)
        self.store.close(rec)
        self.admission.update()
        return rec.id

    # -- runs ----------------------------------------------------------------------------------------
    def _run(self, rec: SessionRecord, cmd: m.Run) -> m.RunStarted:
        if rec.command is None:
            raise RequestError("bad_request", "no command assigned: set a joint path first", "command")
        return self._begin(rec, self._request(rec, f"r{rec.run_counter + 1}"), rec.settings.stop_time, "")

    def _recording(self, name: str) -> m.RecordingInfo:
        try:
            return MeshClient(self.z, timeout=5.0).recording_info(name)
        except RemoteError as exc:
            raise RequestError(exc.code, exc.error.message, "recording") from None
        except NoReply:
            raise RequestError(
                "not_found", "no recorder on the mesh serves recordings", "recording"
            ) from None

    def _replay(self, rec: SessionRecord, cmd: m.Replay, info: m.RecordingInfo | None) -> m.RunStarted:
        assert info is not None
        if info.model_id != rec.model_id:
            raise RequestError(
                "conflict",
                f"recording {info.name} is of model {info.model_id}; this session is on {rec.model_id}",
                "recording",
            )
        pacing = {"pacing": "fast"} if cmd.speed == 0 else {"pacing": "scaled", "factor": cmd.speed}
        settings = msgspec.structs.replace(rec.settings, **pacing)
        request = self._request(rec, f"r{rec.run_counter + 1}", settings, cmd.recording, cmd.paused)
        return self._begin(rec, request, info.stop_time, cmd.recording)

    def _request(
        self,
        rec: SessionRecord,
        run_id: str,
        settings: m.RunSettings | None = None,
        recording: str = "",
        paused: bool = False,
    ) -> m.RunRequest:
        info = rec.run_info(run_id)
        return m.RunRequest(
            session=rec.id,
            run_id=run_id,
            run_index=int(run_id[1:]),
            user=rec.user,
            model_id=rec.model_id,
            values=dict(rec.values),
            initial=list(rec.initial),
            command=rec.command,
            settings=settings or rec.settings,
            recording=recording or (info.recording if info else ""),
            paused=paused,
        )

    def _begin(
        self, rec: SessionRecord, request: m.RunRequest, stop_time: float, recording: str
    ) -> m.RunStarted:
        """A new run of `rec`: queued now, started when admission finds it a slot."""
        if rec.starting:
            raise RequestError("conflict", "the previous run is still being handed to a simulator")
        self.admission.enqueue(rec, request)  # refuses with busy when the server is full
        rec.run_counter += 1
        rec.add_run(m.RunInfo(request.run_id, "queued", stop_time, 0.0, recording=recording))
        queued = phases.after(rec.phase, "queued")
        rec.state = m.SessionState(session=rec.id, phase=queued, seq=rec.state.seq, run_id=request.run_id)  # type: ignore[arg-type]
        self.store.publish_state(rec)
        self.admission.update()
        return m.RunStarted(request.run_id, rec.phase, rec.state.queue_position)  # type: ignore[arg-type]

    def _handed_over(self, request: m.RunRequest, host: str, hosts: list[str], errors: list[str]) -> None:
        """Admission's outcome of handing a run to a simulator host (called with the lock held)."""
        sid, run_id = request.session, request.run_id
        rec = self.store.records.get(sid)
        if rec is None or rec.abort_run == run_id:
            if host:  # aborted or closed while it was being handed over: stop it at once
                self.log.info(
                    "session %s run %s started on %s after its abort: aborting it", sid, run_id, host
                )
                if rec is None:
                    self._orphan_runs[sid] = run_id
                self._send_control(sid, run_id, "abort")
            return
        if rec.state.run_id != run_id:
            return
        if host:
            self.log.info("session %s run %s started on simulator %s", sid, run_id, host)
            if rec.phase == "queued":  # its first status report may have come first
                self._started(rec)
        elif rec.phase == "queued":
            why = (
                "no simulator accepted the run: " + "; ".join(errors)
                if hosts
                else "no simulator node is on the mesh"
            )
            self._end_run(rec, "failed", why)

    def _started(self, rec: SessionRecord) -> None:
        self.store.move(rec, "started", queue_position=0, progress=0.0, sim_time=0.0, rtf=0.0, reason="")
        self._run_info(rec, rec.state.run_id, phase="running")

    def _run_info(self, rec: SessionRecord, run_id: str, **fields: Any) -> None:
        info = rec.run_info(run_id)
        if info is not None:
            for k, v in fields.items():
                setattr(info, k, v)

    def _end_run(self, rec: SessionRecord, phase: str, reason: str = "") -> None:
        self._run_info(rec, rec.state.run_id, phase=phase, reason=reason, sim_time=rec.state.sim_time)
        self.store.move(rec, phase, reason=reason, queue_position=0)
        if phase == "failed":
            self.log.warning("session %s run %s failed: %s", rec.id, rec.state.run_id, reason)

    def _control(self, rec: SessionRecord, op: str, at: float = 0.0) -> None:
        if op == "abort":
            rec.abort_run = rec.state.run_id
        self._send_control(rec.id, rec.state.run_id, op, at)

    def _send_control(self, sid: str, run_id: str, op: str, at: float = 0.0) -> None:
        self.z.put(keys.control(sid), codec.dumps(m.RunControl(op=op, run_id=run_id, time=at)))  # type: ignore[arg-type]

    def _pause(self, rec: SessionRecord, cmd: m.Pause) -> str:
        self._control(rec, "pause")
        return rec.state.run_id

    def _resume(self, rec: SessionRecord, cmd: m.Resume) -> str:
        self._control(rec, "resume")
        return rec.state.run_id

    def _seek(self, rec: SessionRecord, cmd: m.Seek) -> str:
        info = rec.run_info(rec.state.run_id)
        if info is None or not info.recording:
            raise RequestError("unsupported", "only replay runs can seek; a simulation runs forward", "op")
        self._control(rec, "seek", cmd.time)
        return rec.state.run_id

    def _abort(self, rec: SessionRecord, cmd: m.Abort) -> str:
        if rec.phase == "queued" and rec.starting:
            rec.abort_run = rec.state.run_id  # _handed_over() stops it if a simulator took it
            self._end_run(rec, "aborted", "aborted while being handed to a simulator")
        elif rec.phase == "queued":
            self.admission.withdraw(rec)
            self._end_run(rec, "aborted", "aborted while queued")
            self.admission.update()
        else:
            self._control(rec, "abort")
        return rec.state.run_id

    # -- results -------------------------------------------------------------------------------------
    def _on_results_list(self, req: Request) -> list[m.RunInfo]:
        with self.lock:
            return list(self.store.get(req.key).runs)

    def _on_results(self, req: Request) -> Any:
        """The simulator holding a run's results answers; the proxy says only what does not exist."""
        where = keys.parse("results", req.key)
        with self.lock:
            rec = self.store.records.get(where["session"])
            if rec is None or rec.run_info(where["run"]) is not None:
                raise NotMine()
            kept = ", ".join(r.run_id for r in rec.runs) or "none yet"
            raise RequestError(
                "not_found", f"session {rec.id} has no run {where['run']} (runs kept: {kept})", "run_id"
            )

    # -- reports from workers --------------------------------------------------------------------
    def _on_run_status(self, st: m.RunStatus) -> None:
        with self.lock:
            rec = self.store.records.get(st.session)
            if st.phase not in phases.ENDED and (
                (rec is not None and rec.abort_run == st.run_id)
                or (rec is None and self._orphan_runs.get(st.session) == st.run_id)
            ):
                self._send_control(st.session, st.run_id, "abort")  # in case the first was missed
            if st.phase in phases.ENDED and self._orphan_runs.get(st.session) == st.run_id:
                del self._orphan_runs[st.session]
            if rec is None or rec.state.run_id != st.run_id or rec.phase not in phases.UNDER_WAY:
                return
            progress = min(1.0, st.sim_time / st.stop_time) if st.stop_time > 0 else 0.0
            self._run_info(rec, st.run_id, sim_time=st.sim_time, samples=st.samples)
            if st.stop_time > 0:
                self._run_info(rec, st.run_id, stop_time=st.stop_time)
            rec.state.sim_time, rec.state.progress, rec.state.rtf = st.sim_time, progress, st.rtf
            if st.phase in phases.ENDED:
                self._end_run(rec, st.phase, st.reason)
                self.admission.update()
                return
            changed = False
            if rec.phase == "queued":
                self._started(rec)
                changed = True
            wanted = phases.of_worker(st.phase)
            if wanted != rec.phase:
                self.store.move(rec, "paused" if wanted == "paused" else "resumed")
                self._run_info(rec, st.run_id, phase=wanted)
                changed = True
            if not changed:
                self.store.publish_state(rec, persist=False)

    def _on_notice(self, notice: m.Notice) -> None:
        with self.lock:
            rec = self.store.records.get(notice.session)
            if rec is None or rec.state.run_id != notice.run_id:
                return
            text = f"{notice.source}: {notice.message}"
            if text not in rec.state.warnings and len(rec.state.warnings) < MAX_WARNINGS:
                rec.state.warnings.append(text)
                self.store.publish_state(rec)

    def _on_run_token(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        try:
            token = keys.parse("run_token", sample.key_expr)
        except ValueError:
            return
        sid, run_id = token["session"], token["run"]
        # The worker's last RunStatus may still be on its way (another channel than liveliness):
        # give it a moment before calling the run lost. Still well within the 1 s promise.
        time.sleep(LAST_REPORT_GRACE_S)
        with self.lock:
            rec = self.store.records.get(sid)
            if rec is None or rec.state.run_id != run_id or rec.phase not in phases.GOING:
                return
            self._end_run(
                rec, "failed", f"the simulator process of run {run_id} disappeared (crashed or killed)"
            )
            self.admission.update()

    def stop(self) -> None:
        with self.lock:
            self.store.persist_all()


def main(argv: list[str] | None = None) -> int:
    return main_for(Proxy, argv)


if __name__ == "__main__":
    main()
