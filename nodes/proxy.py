"""The proxy node: the paper's Simulation Server + Low Level Proxy.

It owns sessions (who they belong to, their parameter values, initial pose, command and settings),
validates every request against the model description and applies nothing partially, keeps named
parameter sets on disk, admits at most N simultaneous runs and queues the rest, and translates
simulator-independent requests into `RunRequest`s for simulator nodes, which it reaches only over the
mesh. Sessions are persisted on every change, so a restart of any node loses nothing a user did.
"""

from __future__ import annotations

import argparse
import collections
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh
from simecs.mesh import codec, files, keys
from simecs.mesh import messages as m
from simecs.mesh.model import ModelDescription, check_values
from simecs.mesh.runtime import Node, Request, RequestError, main_for, mesh_from_args

ACTIVE = ("running", "paused")
MAX_WARNINGS = 20
ENDED = ("finished", "aborted", "failed")


@dataclass
class SessionRecord:
    id: str
    user: str
    model_id: str
    values: dict[str, float]
    initial: list[float]
    command: Any
    settings: m.RunSettings
    state: m.SessionState
    runs: list[m.RunInfo] = field(default_factory=list)
    run_counter: int = 0
    pubs: dict[str, Any] = field(default_factory=dict)
    #: A RunRequest is on its way to a simulator; the proxy's lock is not held meanwhile.
    starting: bool = False
    #: The run the user aborted: asked again on each of its status reports until it ends (a worker
    #: that was just starting may not have been listening yet).
    abort_run: str = ""

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
        )


def load_library() -> dict[str, Any]:
    """The models installed with this server. The proxy uses their descriptions and value checks
    only; simulations run in simulator nodes, reached over the mesh."""
    from simecs import models

    return {s.id: models.get_model(s.id) for s in models.list_models()}


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
        self.data_dir = Path(data_dir)
        self.max_running = max_running or os.cpu_count() or 1
        self.max_queue = max_queue
        self.max_sessions = max_sessions
        self.lock = threading.RLock()
        self.sessions: dict[str, SessionRecord] = {}
        self.queue: collections.deque[str] = collections.deque()
        self.library: dict[str, ModelDescription] = {}
        self.packages: dict[str, Any] = {}
        self._rr = 0
        #: Runs of closed sessions that were told to abort: session id -> run id.
        self._orphan_runs: dict[str, str] = {}

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
            running = sum(1 for s in self.sessions.values() if s.state.phase in ACTIVE)
            return {"sessions": len(self.sessions), "running": running, "queued": len(self.queue)}

    # -- startup ---------------------------------------------------------------------------------
    def start(self) -> None:
        self.packages = load_library()
        self.library = {model_id: pkg.describe() for model_id, pkg in self.packages.items()}
        self._load_sessions()
        self.serve(keys.LIBRARY, self._on_library)
        self.serve(keys.ALL_MODELS, self._on_model)
        self.serve(keys.ALL_DOCS, self._on_doc)
        self.serve(keys.SESSIONS, self._on_sessions, threaded=True)
        self.serve(keys.ALL_CMD, self._on_cmd, threaded=True)
        self.subscribe_messages(keys.ALL_RUN_STATUS, m.RunStatus, self._on_run_status, maxlen=4096)
        self.subscribe_messages(keys.ALL_NOTICES, m.Notice, self._on_notice, maxlen=256)
        self.subscribe(keys.RUN_TOKENS, self._on_run_token, maxlen=4096, liveliness=True)
        self._recover_runs()

    def _session_path(self, sid: str) -> Path:
        return self.data_dir / "sessions" / f"{sid}.json"

    def _persist(self, rec: SessionRecord) -> None:
        data = codec.to_obj(rec.snapshot())
        data["run_counter"] = rec.run_counter
        files.write_json(self._session_path(rec.id), data)

    def _load_sessions(self) -> None:
        folder = self.data_dir / "sessions"
        if not folder.is_dir():
            return
        for path in sorted(folder.glob("*.json")):
            try:
                data = files.read_json(path)
                counter = int(data.pop("run_counter", 0))
                snap = codec.from_obj(m.SessionSnapshot, data)
                if snap.model_id not in self.library:
                    raise ValueError(f"model {snap.model_id} is no longer in the library")
            except Exception as exc:
                self.log.error("cannot restore session file %s: %s (left in place)", path, exc)
                continue
            rec = SessionRecord(
                id=snap.session,
                user=snap.user,
                model_id=snap.model_id,
                values=snap.values,
                initial=snap.initial,
                command=snap.command,
                settings=snap.settings,
                state=snap.state,
                runs=snap.runs,
                run_counter=counter,
            )
            if rec.state.phase == "closed":
                continue
            self.sessions[rec.id] = rec
            self._declare_pubs(rec)
        self.log.info("restored %d sessions from %s", len(self.sessions), folder)

    def _recover_runs(self) -> None:
        """After a restart: runs whose worker still lives go on; the others failed; queued runs re-queue."""
        alive = set()
        for reply in self.z.liveliness().get(keys.RUN_TOKENS, timeout=1.0):
            if reply.ok is not None:
                parts = str(reply.ok.key_expr).split("/")
                alive.add((parts[2], parts[3]))
        with self.lock:
            for rec in self.sessions.values():
                if rec.state.phase in ACTIVE and (rec.id, rec.state.run_id) not in alive:
                    self._settle_ended_run(rec)
                elif rec.state.phase == "queued" and (rec.id, rec.state.run_id) in alive:
                    # The proxy stopped while handing it over, after a simulator took it.
                    self._set_phase(rec, "running", queue_position=0)
                    self._run_info(rec, rec.state.run_id, phase="running")
                elif rec.state.phase == "queued":
                    self.queue.append(rec.id)
                else:
                    self._publish_state(rec)
                    self._publish_params(rec, [])
            self._update_queue()

    def _settle_ended_run(self, rec: SessionRecord) -> None:
        """A run that ended while the proxy was down: its stored results tell how it ended."""
        run_id = rec.state.run_id
        try:
            replies = list(self.z.get(keys.results(rec.id), timeout=3.0))
            infos = [
                i
                for r in replies
                if r.ok is not None
                for i in codec.loads(m.Ok, r.ok.payload.to_bytes()).data
            ]
            info = next(codec.from_obj(m.RunInfo, i) for i in infos if i.get("run_id") == run_id)
        except (StopIteration, codec.DecodeError, zenoh.ZError, TypeError, AttributeError):
            self._end_run(rec, "failed", "the run was lost while the proxy was down")
            return
        rec.state.sim_time = info.sim_time
        rec.state.progress = min(1.0, info.sim_time / info.stop_time) if info.stop_time else 0.0
        self._end_run(rec, info.phase, info.reason)

    # -- publishing --------------------------------------------------------------------------------
    def _declare_pubs(self, rec: SessionRecord) -> None:
        rec.pubs["state"] = self.publisher(keys.state(rec.id), latched=True)
        rec.pubs["params"] = self.publisher(keys.params(rec.id), latched=True)

    def _publish_state(self, rec: SessionRecord, persist: bool = True) -> None:
        rec.state.seq += 1
        rec.pubs["state"].put(codec.dumps(rec.state))
        if persist:
            self._persist(rec)

    def _publish_params(self, rec: SessionRecord, changed: list[str]) -> None:
        msg = m.ParamValues(session=rec.id, model_id=rec.model_id, values=rec.values, changed=changed)
        rec.pubs["params"].put(codec.dumps(msg))

    def _set_phase(self, rec: SessionRecord, phase: str, **fields: Any) -> None:
        rec.state.phase = phase  # type: ignore[assignment]
        for name, value in fields.items():
            setattr(rec.state, name, value)
        self._publish_state(rec)

    # -- library -----------------------------------------------------------------------------------
    def _on_library(self, req: Request) -> m.ModelList:
        return m.ModelList(models=[d.summary_entry() for d in self.library.values()])

    def _model(self, model_id: str) -> ModelDescription:
        desc = self.library.get(model_id)
        if desc is None:
            raise RequestError(
                "not_found", f"no model {model_id!r} (models: {', '.join(self.library)})", "model_id"
            )
        return desc

    def _on_model(self, req: Request) -> ModelDescription:
        return self._model(keys.last_chunk(req.key))

    def _on_doc(self, req: Request) -> Any:
        parts = req.key.split("/")
        desc = self._model(parts[2])
        for page in desc.docs:
            if page.id == parts[4]:
                return page
        raise RequestError("not_found", f"model {desc.id} has no documentation page {parts[4]!r}", "page")

    # -- sessions ----------------------------------------------------------------------------------
    def _on_sessions(self, req: Request) -> Any:
        msg = req.json(m.SessionRequest)
        if isinstance(msg, m.CreateSession):
            return self._create(msg)
        self._check_user(msg.user)
        with self.lock:
            return [
                {"session": r.id, "model_id": r.model_id, "phase": r.state.phase}
                for r in self.sessions.values()
                if r.user == msg.user
            ]

    @staticmethod
    def _check_user(user: str) -> None:
        try:
            keys.check_name(user, "user name")
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "user") from None

    def _create(self, msg: m.CreateSession) -> m.SessionSnapshot:
        self._check_user(msg.user)
        desc = self._model(msg.model_id)
        with self.lock:
            if len(self.sessions) >= self.max_sessions:
                raise RequestError("busy", f"the server holds its maximum of {self.max_sessions} sessions")
            sid = keys.new_session_id()
            rec = SessionRecord(
                id=sid,
                user=msg.user,
                model_id=desc.id,
                values=desc.default_values(),
                initial=[0.0] * len(desc.links),
                command=None,
                settings=m.RunSettings(),
                state=m.SessionState(session=sid, phase="created"),
            )
            self.sessions[sid] = rec
            self._declare_pubs(rec)
            self._publish_state(rec)
            self._publish_params(rec, [])
            self.log.info("session %s created for %s on model %s", sid, msg.user, desc.id)
            return rec.snapshot()

    def _session(self, key: str) -> SessionRecord:
        try:
            sid = keys.session_of(key)
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "session") from None
        rec = self.sessions.get(sid)
        if rec is None:
            raise RequestError("not_found", f"no session {sid} (closed, or never created)", "session")
        return rec

    # -- commands ------------------------------------------------------------------------------
    def _on_cmd(self, req: Request) -> Any:
        cmd = req.json(m.Command)
        with self.lock:
            rec = self._session(req.key)
            handler = getattr(self, f"_cmd_{cmd.op}")
            return handler(rec, cmd)

    def _editable(self, rec: SessionRecord, what: str) -> None:
        if rec.state.phase in ACTIVE or rec.state.phase == "queued":
            raise RequestError("conflict", f"cannot change {what} while the run is {rec.state.phase}")

    def _configured(self, rec: SessionRecord) -> None:
        if rec.state.phase == "created":
            self._set_phase(rec, "configured")
        else:
            self._persist(rec)

    def _checked(self, rec: SessionRecord, changes: dict[str, Any]) -> dict[str, float]:
        """The session's values with `changes` applied, if the model accepts them all."""
        values = check_values(self.library[rec.model_id], changes, rec.values)
        try:
            return dict(self.packages[rec.model_id].check_values(values))
        except ValueError as exc:  # the model's cross-checks (models.ParameterError)
            name = getattr(exc, "name", "")
            raise RequestError("bad_request", str(exc), f"values.{name}" if name else "values") from None

    def _cmd_set_params(self, rec: SessionRecord, cmd: m.SetParams) -> dict[str, float]:
        self._editable(rec, "parameters")
        rec.values = self._checked(rec, dict(cmd.values))
        self._publish_params(rec, sorted(cmd.values))
        self._configured(rec)
        return rec.values

    def _cmd_reset_params(self, rec: SessionRecord, cmd: m.ResetParams) -> dict[str, float]:
        self._editable(rec, "parameters")
        desc = self.library[rec.model_id]
        defaults = desc.default_values()
        unknown = [n for n in cmd.names if n not in defaults]
        if unknown:
            raise RequestError("bad_request", f"unknown parameter {unknown[0]!r}", f"names.{unknown[0]}")
        names = cmd.names or list(defaults)
        rec.values = self._checked(rec, {n: defaults[n] for n in names})
        self._publish_params(rec, sorted(names))
        self._configured(rec)
        return rec.values

    def _check_joints(self, rec: SessionRecord, q: list[float], where: str) -> None:
        desc = self.library[rec.model_id]
        if len(q) != len(desc.links):
            raise RequestError(
                "bad_request", f"{len(q)} joint positions for a {len(desc.links)}-joint arm", where
            )
        for i, (qi, link) in enumerate(zip(q, desc.links, strict=True)):
            if not link.joint_min <= qi <= link.joint_max:
                raise RequestError(
                    "bad_request",
                    f"{link.joint} = {qi:.4g} rad is outside its range "
                    f"[{link.joint_min:.4g}, {link.joint_max:.4g}] rad",
                    f"{where}[{i}]",
                )

    def _cmd_set_initial(self, rec: SessionRecord, cmd: m.SetInitial) -> list[float]:
        self._editable(rec, "the initial pose")
        self._check_joints(rec, cmd.joints, "joints")
        rec.initial = list(cmd.joints)
        self._configured(rec)
        return rec.initial

    def _cmd_set_command(self, rec: SessionRecord, cmd: m.SetCommand) -> str:
        self._editable(rec, "the command")
        desc = self.library[rec.model_id]
        level = cmd.command.kind
        if level not in desc.command_levels:
            raise RequestError(
                "unsupported",
                f"model {desc.id} accepts {', '.join(desc.command_levels)} commands, not {level}",
                "command.kind",
            )
        if isinstance(cmd.command, m.JointPath):
            for i, node in enumerate(cmd.command.nodes):
                self._check_joints(rec, node.q, f"command.nodes[{i}].q")
        rec.command = cmd.command
        self._configured(rec)
        return level

    def _cmd_set_settings(self, rec: SessionRecord, cmd: m.SetSettings) -> m.RunSettings:
        self._editable(rec, "the simulation settings")
        desc = self.library[rec.model_id]
        names = {v.name for v in desc.variables}
        for i, name in enumerate(cmd.settings.live_vars):
            if name not in names:
                raise RequestError(
                    "bad_request", f"model {desc.id} has no variable {name!r}", f"settings.live_vars[{i}]"
                )
        rec.settings = cmd.settings
        self._configured(rec)
        return rec.settings

    def _cmd_get_session(self, rec: SessionRecord, cmd: m.GetSession) -> m.SessionSnapshot:
        return rec.snapshot()

    def _cmd_close_session(self, rec: SessionRecord, cmd: m.CloseSession) -> str:
        if rec.state.phase in ACTIVE:
            self._orphan_runs[rec.id] = rec.state.run_id
            self._control(rec, "abort")
        if rec.id in self.queue:
            self.queue.remove(rec.id)
        self._set_phase(rec, "closed")
        for pub in rec.pubs.values():
            try:
                pub.undeclare()
                self._declared.remove(pub)
            except Exception:
                pass
        del self.sessions[rec.id]
        # Closing is the user's explicit end of the session; parameter sets and results stay.
        self._session_path(rec.id).unlink(missing_ok=True)
        self._update_queue()
        return rec.id

    # -- parameter sets (per user and model, on disk) ----------------------------------------------
    def _set_path(self, rec: SessionRecord, name: str) -> Path:
        try:
            keys.check_name(name, "parameter set name")
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "name") from None
        return self.data_dir / "paramsets" / rec.user / rec.model_id / f"{name}.json"

    def _cmd_save_param_set(self, rec: SessionRecord, cmd: m.SaveParamSet) -> str:
        path = self._set_path(rec, cmd.name)
        files.write_json(path, {"model_id": rec.model_id, "values": rec.values, "saved": time.time()})
        return cmd.name

    def _cmd_load_param_set(self, rec: SessionRecord, cmd: m.LoadParamSet) -> dict[str, float]:
        self._editable(rec, "parameters")
        path = self._set_path(rec, cmd.name)
        if not path.is_file():
            raise RequestError(
                "not_found", f"no parameter set {cmd.name!r} for {rec.user} on {rec.model_id}", "name"
            )
        try:
            stored = files.read_json(path)["values"]
            desc = self.library[rec.model_id]
            # Parameters added to the model since the set was saved keep their current values.
            known = {k: v for k, v in stored.items() if any(p.name == k for p in desc.parameters)}
            new_values = self._checked(rec, known)
        except (OSError, ValueError, KeyError, TypeError, codec.DecodeError, RequestError) as exc:
            raise RequestError(
                "bad_request", f"parameter set {cmd.name!r} is unusable: {exc}", "name"
            ) from None
        rec.values = new_values
        self._publish_params(rec, sorted(known))
        self._configured(rec)
        return rec.values

    def _cmd_delete_param_set(self, rec: SessionRecord, cmd: m.DeleteParamSet) -> str:
        path = self._set_path(rec, cmd.name)
        if not path.is_file():
            raise RequestError("not_found", f"no parameter set {cmd.name!r}", "name")
        path.unlink()
        return cmd.name

    def _cmd_list_param_sets(self, rec: SessionRecord, cmd: m.ListParamSets) -> list[str]:
        folder = self.data_dir / "paramsets" / rec.user / rec.model_id
        return sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []

    # -- runs ----------------------------------------------------------------------------------------
    def _cmd_run(self, rec: SessionRecord, cmd: m.Run) -> dict[str, Any]:
        if rec.state.phase in ACTIVE or rec.state.phase == "queued":
            raise RequestError("conflict", f"a run is already {rec.state.phase} in this session")
        if rec.starting:
            raise RequestError("conflict", "the previous run is still being handed to a simulator")
        if rec.command is None:
            raise RequestError("bad_request", "no command assigned: set a joint path first", "command")
        active = self._occupied()
        if active >= self.max_running and len(self.queue) >= self.max_queue:
            raise RequestError(
                "busy",
                f"server full: {active} runs going and {len(self.queue)} waiting (limit {self.max_queue})",
            )
        rec.run_counter += 1
        run_id = f"r{rec.run_counter}"
        rec.runs.append(
            m.RunInfo(run_id=run_id, phase="queued", stop_time=rec.settings.stop_time, sim_time=0.0)
        )
        rec.runs = rec.runs[-20:]
        rec.state = m.SessionState(session=rec.id, phase="queued", seq=rec.state.seq, run_id=run_id)
        self.queue.append(rec.id)
        self._update_queue()
        return {"run_id": run_id, "phase": rec.state.phase, "queue_position": rec.state.queue_position}

    def _occupied(self) -> int:
        """Simulation slots in use: runs going, and runs being handed to a simulator."""
        return sum(1 for s in self.sessions.values() if s.state.phase in ACTIVE or s.starting)

    def _update_queue(self) -> None:
        """Start queued runs while there is capacity; tell the others their position."""
        while self.queue:
            if self._occupied() >= self.max_running:
                break
            rec = self.sessions.get(self.queue.popleft())
            if rec is not None and rec.state.phase == "queued":
                self._start(rec)
        for pos, sid in enumerate(self.queue, start=1):
            rec = self.sessions[sid]
            if rec.state.queue_position != pos or rec.state.phase != "queued":
                self._set_phase(rec, "queued", queue_position=pos)

    def _simulators(self) -> list[str]:
        hosts = []
        for reply in self.z.liveliness().get(f"{keys.ROOT}/@node/simulator/*", timeout=1.0):
            if reply.ok is not None:
                hosts.append(keys.last_chunk(str(reply.ok.key_expr)))
        return sorted(hosts)

    def _start(self, rec: SessionRecord) -> None:
        """Hand the session's queued run to a simulator, in a thread of its own: a simulator that is
        slow to answer (up to the 10 s query timeout) must not hold up every other session's
        commands. Called with the lock held; the run counts as occupying a slot meanwhile."""
        request = m.RunRequest(
            session=rec.id,
            run_id=rec.state.run_id,
            run_index=rec.run_counter,
            model_id=rec.model_id,
            values=dict(rec.values),
            initial=list(rec.initial),
            command=rec.command,
            settings=rec.settings,
        )
        rec.starting, rec.abort_run = True, ""
        self._set_phase(rec, "queued", queue_position=0)
        self._rr += 1
        threading.Thread(
            target=self._dispatch, args=(request, self._rr), name=f"dispatch:{rec.id[:8]}", daemon=True
        ).start()

    def _dispatch(self, request: m.RunRequest, rr: int) -> None:
        """Offer the run to the simulators in turn (without the lock), then record the outcome."""
        hosts: list[str] = []
        errors: list[str] = []
        accepted = ""
        try:
            hosts = self._simulators()
            payload = codec.dumps(request)
            for i in range(len(hosts)):
                host = hosts[(rr + i) % len(hosts)]
                try:
                    replies = list(self.z.get(keys.simulator_run(host), payload=payload, timeout=10.0))
                except zenoh.ZError as exc:
                    errors.append(f"{host}: {exc}")
                    continue
                for reply in replies:
                    if reply.ok is not None:
                        accepted = host
                        break
                    errors.append(f"{host}: {reply.err.payload.to_bytes().decode('utf-8', 'replace')[:300]}")
                if accepted:
                    break
                if not replies:
                    errors.append(f"{host}: no answer")
        except Exception as exc:  # the session closing under us, say: never leave the slot taken
            errors.append(f"{type(exc).__name__}: {exc}")
        with self.lock:
            self._started(request, accepted, hosts, errors)
            self._update_queue()

    def _started(self, request: m.RunRequest, host: str, hosts: list[str], errors: list[str]) -> None:
        sid, run_id = request.session, request.run_id
        rec = self.sessions.get(sid)
        if rec is not None:
            rec.starting = False
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
            if rec.state.phase == "queued":  # its first status report may have come first
                self._set_phase(
                    rec, "running", queue_position=0, progress=0.0, sim_time=0.0, rtf=0.0, reason=""
                )
                self._run_info(rec, run_id, phase="running")
        elif rec.state.phase == "queued":
            reason = (
                "no simulator accepted the run: " + "; ".join(errors)
                if hosts
                else "no simulator node is on the mesh"
            )
            self._end_run(rec, "failed", reason)

    def _run_info(self, rec: SessionRecord, run_id: str, **fields: Any) -> None:
        for info in rec.runs:
            if info.run_id == run_id:
                for k, v in fields.items():
                    setattr(info, k, v)

    def _end_run(self, rec: SessionRecord, phase: str, reason: str = "") -> None:
        self._run_info(rec, rec.state.run_id, phase=phase, reason=reason, sim_time=rec.state.sim_time)
        self._set_phase(rec, phase, reason=reason, queue_position=0)
        if phase == "failed":
            self.log.warning("session %s run %s failed: %s", rec.id, rec.state.run_id, reason)

    def _control(self, rec: SessionRecord, op: str) -> None:
        if op == "abort":
            rec.abort_run = rec.state.run_id
        self._send_control(rec.id, rec.state.run_id, op)

    def _send_control(self, sid: str, run_id: str, op: str) -> None:
        self.z.put(keys.control(sid), codec.dumps(m.RunControl(op=op, run_id=run_id)))  # type: ignore[arg-type]

    def _cmd_pause(self, rec: SessionRecord, cmd: m.Pause) -> str:
        if rec.state.phase != "running":
            raise RequestError("conflict", f"nothing to pause: the session is {rec.state.phase}")
        self._control(rec, "pause")
        return rec.state.run_id

    def _cmd_resume(self, rec: SessionRecord, cmd: m.Resume) -> str:
        if rec.state.phase != "paused":
            raise RequestError("conflict", f"nothing to resume: the session is {rec.state.phase}")
        self._control(rec, "resume")
        return rec.state.run_id

    def _cmd_abort(self, rec: SessionRecord, cmd: m.Abort) -> str:
        if rec.state.phase == "queued" and rec.starting:
            rec.abort_run = rec.state.run_id  # _started() stops it if a simulator took it
            self._end_run(rec, "aborted", "aborted while being handed to a simulator")
        elif rec.state.phase == "queued":
            self.queue.remove(rec.id)
            self._end_run(rec, "aborted", "aborted while queued")
            self._update_queue()
        elif rec.state.phase in ACTIVE:
            self._control(rec, "abort")
        else:
            raise RequestError("conflict", f"nothing to abort: the session is {rec.state.phase}")
        return rec.state.run_id

    # -- reports from workers --------------------------------------------------------------------
    def _on_run_status(self, st: m.RunStatus) -> None:
        with self.lock:
            rec = self.sessions.get(st.session)
            if st.phase not in ENDED and (
                (rec is not None and rec.abort_run == st.run_id)
                or (rec is None and self._orphan_runs.get(st.session) == st.run_id)
            ):
                self._send_control(st.session, st.run_id, "abort")  # in case the first was missed
            if st.phase in ENDED and self._orphan_runs.get(st.session) == st.run_id:
                del self._orphan_runs[st.session]
            if rec is None or rec.state.run_id != st.run_id or rec.state.phase in ENDED:
                return
            progress = min(1.0, st.sim_time / st.stop_time) if st.stop_time > 0 else 0.0
            self._run_info(rec, st.run_id, sim_time=st.sim_time, samples=st.samples)
            if st.phase in ENDED:
                rec.state.sim_time, rec.state.progress, rec.state.rtf = st.sim_time, progress, st.rtf
                self._end_run(rec, st.phase, st.reason)
                self._update_queue()
            else:
                phase = "paused" if st.phase == "paused" else "running"
                changed = phase != rec.state.phase
                rec.state.phase = phase  # type: ignore[assignment]
                rec.state.sim_time, rec.state.progress, rec.state.rtf = st.sim_time, progress, st.rtf
                if changed:
                    self._run_info(rec, st.run_id, phase=phase)
                self._publish_state(rec, persist=changed)

    def _on_notice(self, notice: m.Notice) -> None:
        with self.lock:
            rec = self.sessions.get(notice.session)
            if rec is None or rec.state.run_id != notice.run_id:
                return
            text = f"{notice.source}: {notice.message}"
            if text not in rec.state.warnings and len(rec.state.warnings) < MAX_WARNINGS:
                rec.state.warnings.append(text)
                self._publish_state(rec)

    def _on_run_token(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        parts = str(sample.key_expr).split("/")
        if len(parts) != 4:
            return
        sid, run_id = parts[2], parts[3]
        # The worker's last RunStatus may still be on its way (another channel than liveliness):
        # give it a moment before calling the run lost. Still well within the 1 s promise.
        time.sleep(0.3)
        with self.lock:
            rec = self.sessions.get(sid)
            if rec is None or rec.state.run_id != run_id or rec.state.phase not in ACTIVE:
                return
            self._end_run(
                rec, "failed", f"the simulator process of run {run_id} disappeared (crashed or killed)"
            )
            self._update_queue()

    def stop(self) -> None:
        with self.lock:
            for rec in self.sessions.values():
                try:
                    self._persist(rec)
                except Exception as exc:
                    self.log.error("could not persist session %s: %s", rec.id, exc)


def main(argv: list[str] | None = None) -> int:
    return main_for(Proxy, argv)


if __name__ == "__main__":
    main()
