"""The proxy node: the paper's Simulation Server + Low Level Proxy, and the one owner of sessions.

It answers every session command (a table from message type to handler, each command allowed only in
the phases `mesh.protocol.phases` lists), validates it against the model and applies nothing partially, keeps
named parameter sets (`paramsets.py`), admits runs (`admission.py`) and follows them to their end
(`runs.py`), turning simulator-independent requests into `RunRequest`s for simulator hosts, reached
only over the mesh. A replay is a run like any other, whose source is a recording. Sessions are
persisted on every change (`sessions.py`), so a restart of any node loses nothing a user did.
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
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process import files
from simecs.mesh.process.config import lossless_put
from simecs.mesh.process.hublink import HubLink
from simecs.mesh.process.runtime import Binary, Node, NotMine, Request, RequestError, main_for, mesh_from_args
from simecs.mesh.protocol import keys, limits, phases, session_commands
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import DocPage, ModelDescription, check_joints

from .admission import QUEUE_WAITS_FOR_HOST_S
from .library import ModelLibrary
from .placement import RESERVATION_S, Hosts
from .quotas import FLOAT_BYTES, QuotaCheck, Quotas
from .runs import LAST_REPORT_GRACE_S, RunTracker, open_settings
from .sessions import SessionRecord, SessionStore
from .user_library import UserLibrary

#: How long before a host's model that could not be fetched (or was refused) is asked for again.
MODEL_RETRY_S = 60.0
#: ... and when nobody answered: a host's status may name its models a moment before it serves them.
MODEL_UNANSWERED_RETRY_S = 1.0
#: The longest stop_time a run may have (RunSettings.stop_time): a run until stopped's bound too.
MAX_STOP_TIME_S = 3600.0


def _open_run_s(text: str) -> float:
    """--open-run-s: a time in (0, 3600] s (a run's stop_time cannot be longer)."""
    value = float(text)
    if not 0.0 < value <= MAX_STOP_TIME_S:
        raise argparse.ArgumentTypeError(f"{text} s is outside (0, {MAX_STOP_TIME_S:g}] s")
    return value


def _seconds(text: str) -> float:
    """--reservation-s, --host-wait-s: a time in (0, 3600] s (at 0 or below, runs on their way would
    not count, and a node's restart would fail the runs queued meanwhile)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a time in s") from None
    if not 0.0 < value <= 3600.0:
        raise argparse.ArgumentTypeError(f"{text} s is outside (0, 3600] s")
    return value


class Proxy(Node):
    """Sessions, validation, parameter sets, model library and documentation, admission."""

    role = "proxy"

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        data_dir: str = ".simecs",
        max_running: int | None = None,
        max_queue: int = limits.limit("run_queue"),
        quotas: Quotas | None = None,
        session_idle_s: float = limits.limit("session_idle_s"),
        open_run_s: float = limits.limit("open_run_s"),
        reservation_s: float = RESERVATION_S,
        host_wait_s: float = QUEUE_WAITS_FOR_HOST_S,
    ) -> None:
        super().__init__(mesh, node_id)
        data = Path(data_dir)
        self.session_idle_s = session_idle_s
        self.open_run_s = min(open_run_s, MAX_STOP_TIME_S)
        self._expiry_checked = 0.0
        self.lock = threading.RLock()
        self.library: ModelLibrary | None = None
        self.hosted_models = data / "models"  # models simulator hosts brought (kept over restarts)
        self._ask_after: dict[str, float] = {}  # model id -> when it may be asked of a host again
        self.store = SessionStore(
            data / "sessions",
            lambda key: self.publisher(key, latched=True, congestion_control=lossless_put()),  # LOSSLESS_KEYS
            self._release,
        )
        self.runs = RunTracker(
            self.store,
            lambda: self.z,
            lambda: self.seal,
            self.lock,
            max_running,
            max_queue,
            Hosts(reservation_s),
            host_wait_s,
        )
        self.admission = self.runs.admission
        self.quota = QuotaCheck(quotas or Quotas(), self.store, self._columns)
        self.user_library = UserLibrary(data, lambda: self.models, self.store, self.quota)
        # what a kill mid-write left in the folders only this node writes (not results: the workers')
        left = sum(files.remove_leftovers(data / d) for d in ("sessions", "paramsets", "programs", "models"))
        if left:
            self.log.info("removed %d temporary files a crash left behind", left)
        self.commands: dict[type, Callable[[SessionRecord, Any], Any]] = {
            m.SetParams: self._set_params,
            m.ResetParams: self._reset_params,
            m.SetInitial: self._set_initial,
            m.SetSettings: self._set_settings,
            m.SetObstacles: self._set_obstacles,
            m.Run: self._run,
            m.Pause: self.runs.pause,
            m.Resume: self.runs.resume,
            m.Stop: self.runs.stop,
            m.Abort: self.runs.abort,
            m.Seek: self.runs.seek,
            **self.user_library.handlers(),
            m.GetSession: lambda rec, _cmd: rec.snapshot(),
            m.CloseSession: self._close_session,
        }

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--data-dir", default=os.environ.get("SIMECS_DATA", ".simecs"), help="sessions and parameter sets"
        )
        parser.add_argument(
            "--max-running",
            type=int,
            default=None,
            help="a ceiling of runs at once, all hosts (default: what the simulator hosts can carry)",
        )
        parser.add_argument(
            "--max-queue", type=int, default=limits.limit("run_queue"), help="runs waiting for a host"
        )
        q = Quotas()
        parser.add_argument("--max-sessions", type=int, default=q.sessions, help="open sessions, all users")
        parser.add_argument("--max-sessions-per-user", type=int, default=q.sessions_per_user)
        parser.add_argument("--max-runs-per-user", type=int, default=q.runs_per_user, help="runs going")
        parser.add_argument(
            "--max-results-mb-per-user", type=float, default=q.results_bytes_per_user / limits.MiB
        )
        parser.add_argument(
            "--session-idle-s",
            type=float,
            default=float(limits.limit("session_idle_s")),
            help="close a session idle this long (its results go with it)",
        )
        parser.add_argument(
            "--open-run-s",
            type=_open_run_s,
            default=float(limits.limit("open_run_s")),
            help="the longest a run until stopped lasts, in s (at most 3600)",
        )
        parser.add_argument(
            "--reservation-s",
            type=_seconds,
            default=RESERVATION_S,
            help="how long a run handed to a simulator host counts against it before the host lists it",
        )
        parser.add_argument(
            "--host-wait-s",
            type=_seconds,
            default=QUEUE_WAITS_FOR_HOST_S,
            help="how long a queued run waits for a simulator host to come back when none is on the mesh",
        )

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Proxy:
        quotas = Quotas(
            sessions=args.max_sessions,
            sessions_per_user=args.max_sessions_per_user,
            runs_per_user=args.max_runs_per_user,
            results_bytes_per_user=int(args.max_results_mb_per_user * limits.MiB),
        )
        return cls(
            mesh_from_args(args),
            args.node_id,
            args.data_dir,
            args.max_running,
            args.max_queue,
            quotas,
            args.session_idle_s,
            args.open_run_s,
            args.reservation_s,
            args.host_wait_s,
        )

    def status_detail(self) -> dict[str, Any]:
        with self.lock:
            running = sum(1 for s in self.store if s.phase in phases.GOING)
            hosts = len(self.admission.hosts.live)
            queued = len(self.admission.queue)
            return {"sessions": len(self.store), "running": running, "queued": queued, "simulators": hosts}

    def _release(self, entity: Any) -> None:
        try:
            entity.undeclare()
            self._declared.remove(entity)
        except Exception:
            pass

    # -- startup ---------------------------------------------------------------------------------
    def start(self) -> None:
        self.library = ModelLibrary(self.hosted_models)
        self.store.load(self.library.descriptions)
        # Tells a hub restart (every run token disappears, the workers run on) from a lost worker.
        self.hub = HubLink(self.z)
        self.runs.hub = self.admission.hub = self.hub
        self.serve(keys.LIBRARY, lambda _req: self.models.summaries())
        self.serve(keys.ALL_MODELS, self._on_model)
        self.serve(keys.ALL_DOCS, self._on_doc)
        self.serve(keys.ALL_MESHES, self._on_mesh, threaded=True)  # the first ask makes the mesh
        self.serve(keys.ALL_SESSION_REQUESTS, self._on_sessions, threaded=True)
        self.serve(keys.ALL_CMD, self._on_cmd, threaded=True)
        self.serve(keys.ALL_RESULTS_LIST, self._on_results_list, threaded=True)
        self.serve(keys.ALL_RESULTS, self._on_results, threaded=True)
        self.subscribe_messages(
            keys.ALL_RUN_STATUS, m.RunStatus, self.runs.on_run_status, maxlen=4096, sealed=True
        )
        self.subscribe_messages(keys.ALL_NOTICES, m.Notice, self.runs.on_notice, maxlen=256, sealed=True)
        self.subscribe(keys.RUN_TOKENS, self.runs.on_run_token, maxlen=4096, liveliness=True)
        # The simulator hosts: which are up, and what each can carry (admission and placement).
        self.subscribe(keys.SIMULATOR_TOKENS, self._on_simulator_token, liveliness=True, history=True)
        self.subscribe_messages(
            keys.SIMULATOR_STATUS, m.NodeStatus, self._on_simulator_status, sealed=True, latched=True
        )
        self.runs.recover()

    def _on_simulator_token(self, sample: zenoh.Sample) -> None:
        try:
            host = keys.parse("node_token", sample.key_expr)["node"]
        except ValueError:
            return
        gone_at = time.monotonic()
        if sample.kind == zenoh.SampleKind.DELETE:
            # A hub restart takes every token at once: our own link's loss is known a moment later.
            time.sleep(LAST_REPORT_GRACE_S)
        with self.lock:
            if sample.kind != zenoh.SampleKind.DELETE:
                self.log.info("simulator host %s joined", host)
                self.admission.hosts.joined(host)
                self.admission.update()
                return
            if self.hub is not None and self.hub.lost_since(gone_at - 0.05):
                self.admission.hosts.live.discard(host)  # every token went with the hub: it comes back
                return
            self.log.warning("simulator host %s left the mesh", host)
            self.runs.host_lost(host)

    def _on_simulator_status(self, status: m.NodeStatus, key: str) -> None:
        host = keys.parse("node_status", key)["node"]
        if status.role != "simulator" or status.node_id != host or status.load is None:
            return
        with self.lock:
            self.admission.hosts.status(host, status.load)
            self.admission.update()
            now = time.monotonic()
            wanted = [
                model_id
                for model_id in status.load.models
                if not self.models.knows(model_id) and now > self._ask_after.get(model_id, -1e9)
            ]
            for model_id in wanted:
                self._ask_after[model_id] = now + MODEL_RETRY_S
        for model_id in wanted:  # a host's own model: fetched aside (a bundle may take a while)
            threading.Thread(target=self._fetch_model, args=(host, model_id), daemon=True).start()

    def _fetch_model(self, host: str, model_id: str) -> None:
        """Bring a model a host offers into the library (its bundle, unpacked and checked)."""
        try:
            data, _ = MeshClient(self.z, timeout=60.0, seal=self.seal).request_binary(
                keys.simulator_model(host, model_id), None
            )
            with self.lock:
                desc = self.models.add_bundle(data)
        except (RemoteError, NoReply, zenoh.ZError) as exc:
            self.log.warning("model %s of host %s not fetched: %s", model_id, host, exc)
            if isinstance(exc, NoReply):  # not served yet (a host starting): asked again soon
                with self.lock:
                    self._ask_after[model_id] = time.monotonic() + MODEL_UNANSWERED_RETRY_S
            return
        except ValueError as exc:  # the bundle refused (models.ModelFileError), or its model
            self.log.error("model %s of host %s refused: %s", model_id, host, exc)
            return
        self.log.info("model %s (%s) added to the library by host %s", desc.id, desc.name, host)

    @property
    def models(self) -> ModelLibrary:
        assert self.library is not None, "proxy not started"
        return self.library

    def _model(self, rec: SessionRecord) -> ModelDescription:
        return self.models.describe(rec.model_id)

    def _columns(self, model_id: str) -> int:
        return len(self.models.describe(model_id).run_columns()[0])

    # -- library -----------------------------------------------------------------------------------
    def _on_model(self, req: Request) -> ModelDescription:
        return self.models.describe(keys.parse("model", req.key)["model"])

    def _on_doc(self, req: Request) -> DocPage:
        where = keys.parse("doc", req.key)
        return self.models.doc(where["model"], where["page"])

    def _on_mesh(self, req: Request) -> Binary:
        where = keys.parse("model_mesh", req.key)
        return Binary(self.models.mesh(where["model"], where["mesh"]))

    # -- sessions ----------------------------------------------------------------------------------
    def _on_sessions(self, req: Request) -> Any:
        user = keys.parse("sessions", req.key)["user"]  # the key says whose: never the payload
        msg = req.json(m.SessionRequest)
        if isinstance(msg, m.ListSessions):
            with self.lock:
                return self.store.of_user(user)
        desc = self.models.describe(msg.model_id)
        with self.lock:
            self.quota.new_session(user)
            rec = self.store.create(user, desc)
            self.log.info("session %s created for %s on model %s", rec.id, user, desc.id)
            return rec.snapshot()

    # -- commands ------------------------------------------------------------------------------
    def _on_cmd(self, req: Request) -> Any:
        user = keys.owner_of(req.key)[0]
        cmd = req.json(m.SessionCommand)
        # Asking the recorder what a recording holds may take a while: not under the lock.
        recording = self._recording(user, cmd.recording) if isinstance(cmd, m.Replay) else None
        # Expanding a command (inverse kinematics every millisecond of a line) may take a while too,
        # and so may asking a simulator host what a failed run left.
        plan = self._plan(req.key, cmd) if isinstance(cmd, m.SetCommand | m.Run) else None
        kept = self._kept(req.key, cmd.run_id) if isinstance(cmd, m.Continue) else None
        with self.lock:
            rec = self.store.get(req.key)
            rec.active_at = time.time()
            why = session_commands.refusal(cmd.op, rec.phase)
            if why:
                raise RequestError("conflict", why)
            if isinstance(cmd, m.Replay):
                return self._replay(rec, cmd, recording)
            if isinstance(cmd, m.SetCommand):
                return self._set_command(rec, cmd, plan)
            if isinstance(cmd, m.Continue):
                return self._continue(rec, cmd, kept)
            return self.commands[type(cmd)](rec, cmd)

    def _plan(self, key: str, cmd: m.SetCommand | m.Run) -> Any:
        """The command (the new one, or the session's for a run) planned from the session's values and
        initial pose: refused here, naming its field, if the model cannot carry it out."""
        with self.lock:
            rec = self.store.get(key)
            why = session_commands.refusal(cmd.op, rec.phase)
            if why:
                raise RequestError("conflict", why)
            command = cmd.command if isinstance(cmd, m.SetCommand) else rec.command
            open_run = isinstance(cmd, m.Run) and cmd.until_stopped
            model_id, values, initial, stop_time = (
                rec.model_id,
                dict(rec.values),
                list(rec.initial),
                self._open_settings(rec).stop_time if open_run else rec.settings.stop_time,
            )
            # a run's path is checked against the obstacles, unless the user asks for the contact
            check = isinstance(cmd, m.Run) and rec.settings.collisions == "refuse"
            obstacles = list(rec.obstacles)
        # A run until stopped without a command holds the initial pose: the arm must not touch there.
        levels = self.models.describe(model_id).command_levels if command is None and open_run else []
        if check and "joint_path" in levels:
            command = m.JointPath([m.PathNode(initial)])  # planned as a hold
        if command is None:
            if isinstance(cmd, m.Run):
                self.models.check_hold(model_id, values, initial)
            return None
        return self.models.plan(model_id, values, initial, command, stop_time, obstacles, check)

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

    def _set_command(self, rec: SessionRecord, cmd: m.SetCommand, plan: Any) -> m.CommandPlan:
        rec.command = cmd.command
        self.store.edited(rec)
        summary = plan.summary(rec.settings.stop_time)
        self.store.publish_command(rec, summary)
        return summary

    def _set_settings(self, rec: SessionRecord, cmd: m.SetSettings) -> m.RunSettings:
        desc = self._model(rec)
        names = {v.name for v in desc.variables}
        for i, name in enumerate(cmd.settings.live_vars):
            if name not in names:
                raise RequestError(
                    "bad_request", f"model {desc.id} has no variable {name!r}", f"settings.live_vars[{i}]"
                )
        joints = [link.joint for link in desc.links]
        for i, name in enumerate(cmd.settings.external_joints):
            if name not in joints:
                raise RequestError(
                    "bad_request",
                    f"model {desc.id} has no joint {name!r} ({', '.join(joints)})",
                    f"settings.external_joints[{i}]",
                )
        if cmd.settings.control_system not in desc.control_systems:
            raise RequestError(
                "bad_request",
                f"model {desc.id} offers the control systems {', '.join(desc.control_systems)}, "
                f"not {cmd.settings.control_system}",
                "settings.control_system",
            )
        why = m.control_refusal(rec.command, cmd.settings.control_system) if rec.command else ""
        if why:
            raise RequestError("bad_request", f"the session's command: {why}", "settings.control_system")
        step, period = cmd.settings.step, cmd.settings.control_period
        periodic = cmd.settings.controller == "external" or cmd.settings.control_system != "joint_independent"
        if periodic and step > 0 and abs(period / step - round(period / step)) > 1e-6:
            raise RequestError(
                "bad_request",
                f"{period:g} s is not a whole number of solver steps ({step:g} s)",
                "settings.control_period",
            )
        rec.settings = cmd.settings
        self.store.edited(rec)
        return rec.settings

    def _set_obstacles(self, rec: SessionRecord, cmd: m.SetObstacles) -> list[m.Obstacle]:
        rec.obstacles = list(cmd.obstacles)
        self.store.publish_obstacles(rec)
        self.store.edited(rec)
        return rec.obstacles

    def _close_session(self, rec: SessionRecord, cmd: m.CloseSession) -> str:
        if rec.phase in phases.GOING:
            self.runs.orphans[rec.id] = (rec.user, rec.state.run_id)
            self.runs.control(rec, "abort")
        self.admission.withdraw(rec)
        self.store.close(rec)
        self.admission.update()
        return rec.id

    def tick(self) -> None:
        """Runs queued while no simulator host is live: started when one is back, failed once the wait
        is over (--host-wait-s). Close every session idle for longer than
        `session_idle_s` (its results go with it)."""
        with self.lock:
            if self.admission.queue and not self.admission.hosts.live:
                self.admission.update()
        now = time.monotonic()
        if now - self._expiry_checked < min(60.0, self.session_idle_s / 4):
            return
        self._expiry_checked = now
        with self.lock:
            for rec in self.store.idle(self.session_idle_s):
                self.log.info(
                    "session %s of %s idle for %.0f s: closed", rec.id, rec.user, self.session_idle_s
                )
                self._close_session(rec, m.CloseSession())

    # -- runs ----------------------------------------------------------------------------------------
    def _run(self, rec: SessionRecord, cmd: m.Run) -> m.RunStarted:
        if rec.command is None and not cmd.until_stopped:
            raise RequestError(
                "bad_request",
                "no command assigned: set_command first (or run until_stopped: the arm holds its pose)",
                "command",
            )
        why = m.control_refusal(rec.command, rec.settings.control_system) if rec.command else ""
        if why:
            raise RequestError("bad_request", why, "settings.control_system")
        settings = self._open_settings(rec) if cmd.until_stopped else rec.settings
        self.quota.new_run(rec, settings, settings.stop_time)
        request = self.runs.request(rec, f"r{rec.run_counter + 1}", settings, until_stopped=cmd.until_stopped)
        return self.runs.begin(rec, request, settings.stop_time)

    def _kept(self, key: str, run_id: str) -> m.ResultsAttachment:
        """What a run's kept results say of it (its RunInfo and RunContext), from the host that holds
        them; RequestError naming the run when there are none. Asks the mesh: call without the lock."""
        user, sid = keys.owner_of(key)
        try:
            att = self.runs.described(user, sid, run_id, timeout=5.0)
        except RemoteError as exc:
            raise RequestError(exc.code, exc.error.message, "run_id") from None
        except (NoReply, zenoh.ZError):
            raise RequestError(
                "not_found", f"no simulator host holds results of run {run_id}", "run_id"
            ) from None
        if att is None:
            raise RequestError("not_found", f"run {run_id}: its results say nothing of it", "run_id")
        return att

    def _continue(
        self, rec: SessionRecord, cmd: m.Continue, kept: m.ResultsAttachment | None
    ) -> m.RunStarted:
        """A new run of the failed run `cmd.run_id`'s inputs, fast up to where its results end."""
        assert kept is not None
        info, ctx, name = kept.run, kept.context, cmd.run_id

        def refuse(why: str) -> RequestError:
            return RequestError("conflict", f"run {name} cannot be continued: {why}", "run_id")

        if info.phase != "failed":
            raise refuse(f"it {info.phase}; only a run that failed part way goes on (run starts a new one)")
        if ctx is None:
            raise refuse("its results do not say what produced it")
        if ctx.recording:
            raise refuse(f"it replayed recording {ctx.recording}: replay it again")
        if ctx.until_stopped:
            raise refuse("it ran until stopped: start a new one (run until_stopped)")
        if ctx.settings.controller == "external":
            raise refuse("a controller in the loop cannot be run ahead of its own time")
        if info.jogged_s > 0:
            raise refuse(f"it was jogged for {info.jogged_s:.2f} s, and jogs are not run again")
        if info.sim_time <= 0:
            raise refuse("it left no samples: run starts it again")
        self.quota.new_run(rec, ctx.settings, ctx.settings.stop_time)
        request = self.runs.continuing(rec, f"r{rec.run_counter + 1}", ctx, info.sim_time)
        self.log.info(
            "session %s: run %s continues run %s from t = %.3f s", rec.id, request.run_id, name, info.sim_time
        )
        return self.runs.begin(rec, request, ctx.settings.stop_time)

    def _open_settings(self, rec: SessionRecord) -> m.RunSettings:
        """The settings of a run until stopped of `rec`: real time, and as long as open_run_s allows
        and its results fit results_bytes_per_run (and samples_per_run) at its output_interval."""
        interval = rec.settings.output_interval
        row_bytes = self._columns(rec.model_id) * FLOAT_BYTES
        samples = min(limits.limit("samples_per_run"), limits.limit("results_bytes_per_run") // row_bytes - 1)
        bound = max(min(self.open_run_s, samples * interval), interval)
        return open_settings(rec.settings, bound)

    def _recording(self, user: str, name: str) -> m.RecordingInfo:
        try:
            return MeshClient(self.z, timeout=5.0, seal=self.seal).recording_info(user, name)
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
        self.quota.new_run(rec, settings, info.stop_time, replay=True)
        request = self.runs.request(rec, f"r{rec.run_counter + 1}", settings, cmd.recording, cmd.paused)
        return self.runs.begin(rec, request, info.stop_time)

    # -- results -------------------------------------------------------------------------------------
    def _on_results_list(self, req: Request) -> list[m.RunInfo]:
        with self.lock:
            return list(self.store.get(req.key).runs)

    def _on_results(self, req: Request) -> Any:
        """The simulator holding a run's results answers; the proxy says only what does not exist."""
        where = keys.parse("results", req.key)
        with self.lock:
            rec = self.store.owned(where["user"], where["session"])
            if rec is None or rec.run_info(where["run"]) is not None:
                raise NotMine()
            kept = ", ".join(r.run_id for r in rec.runs) or "none yet"
            raise RequestError(
                "not_found", f"session {rec.id} has no run {where['run']} (runs kept: {kept})", "run_id"
            )

    def stop(self) -> None:
        with self.lock:
            self.store.persist_all()


def main(argv: list[str] | None = None) -> int:
    return main_for(Proxy, argv)


if __name__ == "__main__":
    main()
