"""A typed client of the simecs protocol (the paper's Simulation Client).

The viewer, the tests and the benchmarks drive the product through this and nothing else; it is
plain zenoh underneath, so any other client written from docs/PROTOCOL.md is its equal.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import zenoh
import zenoh.ext

from .process import seal as seals
from .process.config import MeshConfig, load_client, open_session
from .process.seal import Seal
from .process.workers import BoundedWorker
from .protocol import codec, frames, keys
from .protocol import messages as m
from .protocol.model import DocPage, ModelDescription, ModelSummary
from .rules.results import selector_query


class RemoteError(Exception):
    """The other side answered with an Error."""

    def __init__(self, error: m.Error) -> None:
        super().__init__(f"{error.code}: {error.message}")
        self.error = error

    @property
    def code(self) -> str:
        return self.error.code

    @property
    def field(self) -> str:
        return self.error.field


class NoReply(Exception):
    """Nobody answered a query in time (the serving node is not on the mesh)."""


def _decode_error(payload: bytes) -> m.Error:
    try:
        return codec.loads(m.Error, payload)
    except codec.DecodeError:
        return m.Error(code="internal", message=payload.decode("utf-8", "replace")[:500])


class MeshClient:
    """Server-wide requests; `session(id)` gives the per-session API.

    With the service's `seal` (only processes of the service have it: the viewer, tests), what a
    session publishes is shown only if a service node put it (mesh/process/seal.py); other clients take it
    as it comes."""

    def __init__(
        self,
        session: zenoh.Session,
        timeout: float = 10.0,
        owns_session: bool = False,
        seal: Seal | None = None,
    ) -> None:
        self.z = session
        self.timeout = timeout
        self._owns = owns_session
        self.seal = seal

    @classmethod
    def open(cls, cfg: MeshConfig | None = None, timeout: float = 10.0) -> MeshClient:
        """A client of the mesh `cfg` describes (by default this machine's: `config.load_client`, which
        finds the credentials `simecs up` wrote); it checks seals when `cfg.service_key_file` names a
        key file that exists (the local client file does)."""
        cfg = load_client() if cfg is None else cfg
        path = seals.key_file(cfg.service_key_file) if cfg.service_key_file else None
        seal = seals.load(path) if path is not None and path.exists() else None
        return cls(open_session(cfg), timeout=timeout, owns_session=True, seal=seal)

    def close(self) -> None:
        if self._owns:
            self.z.close()

    def __enter__(self) -> MeshClient:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- raw requests ---------------------------------------------------------------------------
    def _replies(self, key: str, payload: Any, timeout: float | None) -> list[zenoh.Reply]:
        body = None if payload is None else (payload if isinstance(payload, bytes) else codec.dumps(payload))
        # With the seal, every answer is wanted: zenoh's consolidation would keep one per key, perhaps
        # another peer's (unsealed) in place of the service node's.
        consolidation = zenoh.ConsolidationMode.NONE if self.seal is not None else None
        return list(
            self.z.get(key, payload=body, timeout=timeout or self.timeout, consolidation=consolidation)
        )

    def request(self, key: str, payload: Any = None, timeout: float | None = None, reply: Any = Any) -> Any:
        """Send a get and return the `data` of its Ok reply decoded as `reply`; RemoteError / NoReply
        otherwise. One node answers each key (PROTOCOL.md §4)."""
        answers = self._replies(key, payload, timeout)
        forged = 0
        for answer in answers:
            if answer.ok is not None:
                body = answer.ok.payload.to_bytes()
                if self.seal is not None and not self.seal.sample_valid(answer.ok, body):
                    forged += 1  # not a service node's answer (mesh/process/seal.py): another peer's, ignored
                    continue
                data: Any = codec.loads(m.Ok, body).data
                return data if reply is Any else codec.from_obj(reply, data)
        for answer in answers:
            if answer.err is not None:
                raise RemoteError(_decode_error(answer.err.payload.to_bytes()))
        extra = f" ({forged} answer(s) without the service's seal ignored)" if forged else ""
        raise NoReply(f"no node answered {key}{extra}")

    def request_binary(self, key: str, attachment: Any, timeout: float | None = None) -> tuple[bytes, Any]:
        """A get answered with bytes; returns them and the reply's description (the JSON after its
        seal, PROTOCOL.md §4) decoded as `attachment` (None when it has none)."""
        answers = self._replies(key, None, timeout)
        forged = 0
        for answer in answers:
            if answer.ok is not None:
                body = answer.ok.payload.to_bytes()
                att = answer.ok.attachment.to_bytes() if answer.ok.attachment is not None else None
                if self.seal is not None and not self.seal.binary_valid(str(answer.ok.key_expr), body, att):
                    forged += 1  # not a service node's answer: another peer's, ignored
                    continue
                described = seals.binary_description(att)
                return body, (codec.loads(attachment, described) if described else None)
        for answer in answers:
            if answer.err is not None:
                raise RemoteError(_decode_error(answer.err.payload.to_bytes()))
        extra = f" ({forged} answer(s) without the service's seal ignored)" if forged else ""
        raise NoReply(f"no node answered {key}{extra}")

    # -- library --------------------------------------------------------------------------------
    def list_models(self) -> list[ModelSummary]:
        return self.request(keys.LIBRARY, reply=m.ModelList).models

    def describe(self, model_id: str) -> ModelDescription:
        return self.request(keys.model(model_id), reply=ModelDescription)

    def doc(self, model_id: str, page: str) -> DocPage:
        return self.request(keys.doc(model_id, page), reply=DocPage)

    def model_mesh(self, model_id: str, mesh: str, timeout: float = 30.0) -> bytes:
        """The binary glTF of a `mesh` shape of the model."""
        return self.request_binary(keys.model_mesh(model_id, mesh), None, timeout=timeout)[0]

    # -- sessions -------------------------------------------------------------------------------
    def create_session(self, user: str, model_id: str) -> SessionClient:
        """A new session of `user` on a model (the user is part of every key of the session)."""
        snap = self.request(keys.sessions(user), m.CreateSession(model_id), reply=m.REPLIES[m.CreateSession])
        return SessionClient(self, user, snap.session, snap)

    def list_sessions(self, user: str) -> list[m.SessionEntry]:
        return self.request(keys.sessions(user), m.ListSessions(), reply=m.REPLIES[m.ListSessions])

    def session(self, user: str, session_id: str) -> SessionClient:
        return SessionClient(self, user, session_id)

    def recordings(self, user: str) -> list[m.RecordingInfo]:
        return self.request(keys.recordings(user), reply=m.RecordingList).recordings

    def recording_info(self, user: str, name: str) -> m.RecordingInfo:
        return self.request(keys.recording_info(user, name), reply=m.RecordingInfo)

    def download_recording(self, user: str, name: str, timeout: float = 30.0) -> bytes:
        """The MCAP bytes of one of `user`'s recordings (`keys.recording_name(session, run)` for a run)."""
        return self.request_binary(keys.recording(user, name), m.RecordingInfo, timeout=timeout)[0]

    def upload_recording(self, user: str, name: str, data: bytes, timeout: float = 60.0) -> m.RecordingInfo:
        return self.request(keys.recording(user, name), data, timeout, reply=m.RecordingInfo)

    def recording_results(
        self,
        user: str,
        name: str,
        variables: Sequence[str] | None = None,
        t0: float | None = None,
        t1: float | None = None,
        every: int = 1,
    ) -> tuple[m.ResultsAttachment, np.ndarray]:
        """A recording's samples as a run's results (`SessionClient.results_of`), without replaying it."""
        key = keys.recording_results(user, name) + selector_query(variables, t0, t1, every)
        payload, att = self.request_binary(key, m.ResultsAttachment)
        return att, frames.decode(payload).rows

    def delete_recording(self, user: str, name: str) -> m.RecordingInfo:
        return self.request(keys.recording_delete(user, name), reply=m.RecordingInfo)

    def live_nodes(self, timeout: float = 1.0) -> list[tuple[str, str]]:
        """(role, node id) of every node whose liveliness token is up."""
        out = []
        for reply in self.z.liveliness().get(keys.NODE_TOKENS, timeout=timeout):
            if reply.ok is not None:
                token = keys.parse("node_token", reply.ok.key_expr)
                out.append((token["role"], token["node"]))
        return sorted(out)


class Watch:
    """Subscriptions of one session; callbacks run in worker threads. Close to undeclare."""

    def __init__(self) -> None:
        self._entities: list[Any] = []
        self._workers: list[BoundedWorker] = []

    def close(self) -> None:
        for e in self._entities:
            try:
                e.undeclare()
            except Exception:
                pass
        for w in self._workers:
            w.stop(timeout=1.0)
        self._entities.clear()

    def __enter__(self) -> Watch:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SessionClient:
    """Commands, state and results of one session."""

    def __init__(
        self, client: MeshClient, user: str, session_id: str, snapshot: m.SessionSnapshot | None = None
    ) -> None:
        if not keys.is_session_id(session_id):
            raise ValueError(f"{session_id!r} is not a session id")
        self.client = client
        self.user = keys.check_name(user, "user name")
        self.id = session_id
        self.created = snapshot

    def command(self, cmd: Any, timeout: float | None = None) -> Any:
        """Send a session command; its reply `data`, typed as messages.REPLIES says."""
        return self.client.request(keys.cmd(self.user, self.id), cmd, timeout, reply=m.REPLIES[type(cmd)])

    def snapshot(self) -> m.SessionSnapshot:
        return self.command(m.GetSession())

    def set_params(self, values: dict[str, float]) -> dict[str, float]:
        return self.command(m.SetParams(values))

    def reset_params(self, names: Sequence[str] = ()) -> dict[str, float]:
        return self.command(m.ResetParams(list(names)))

    def set_initial(self, joints: Sequence[float]) -> Any:
        return self.command(m.SetInitial([float(q) for q in joints]))

    def set_command(self, command: m.RobotCommand) -> m.CommandPlan:
        """Assign a robot command of any level; the server's plan of it (duration, steps, tool path)."""
        return self.command(m.SetCommand(command))

    def set_joint_path(self, nodes: Sequence[tuple[Sequence[float], float, float]]) -> m.CommandPlan:
        path = m.JointPath([m.PathNode([float(x) for x in q], float(s), float(a)) for q, s, a in nodes])
        return self.set_command(path)

    def set_settings(self, **settings: Any) -> Any:
        return self.command(m.SetSettings(m.RunSettings(**settings)))

    def set_obstacles(self, obstacles: Sequence[m.Obstacle]) -> list[m.Obstacle]:
        """Replace what the arm can touch in this session; the list as stored."""
        return self.command(m.SetObstacles(list(obstacles)))

    def run(self, until_stopped: bool = False) -> str:
        """Start a run; returns its run id. `until_stopped`: a real-time run that lasts until `stop`
        (at most open_run_s), holding the initial pose without a command: to jog an idle arm."""
        return self.command(m.Run(until_stopped=until_stopped)).run_id

    def continue_run(self, run_id: str) -> str:
        """Start a run that goes on from where the failed run `run_id` ended (`Continue`); its run id."""
        return self.command(m.Continue(run_id)).run_id

    def replay(self, recording: str, speed: float = 1.0, paused: bool = False) -> str:
        """Start a run that replays `recording` (of this session's model); returns its run id."""
        return self.command(m.Replay(recording, speed, paused)).run_id

    def seek(self, time_s: float) -> str:
        return self.command(m.Seek(time_s))

    def pause(self) -> Any:
        return self.command(m.Pause())

    def resume(self) -> Any:
        return self.command(m.Resume())

    def stop(self) -> Any:
        """End the run going now as finished, its results kept (abort ends it as aborted)."""
        return self.command(m.Stop())

    def abort(self) -> Any:
        return self.command(m.Abort())

    def close(self) -> Any:
        return self.command(m.CloseSession())

    def save_param_set(self, name: str) -> Any:
        return self.command(m.SaveParamSet(name))

    def load_param_set(self, name: str) -> dict[str, float]:
        return self.command(m.LoadParamSet(name))

    def delete_param_set(self, name: str) -> Any:
        return self.command(m.DeleteParamSet(name))

    def list_param_sets(self) -> list[str]:
        return self.command(m.ListParamSets())

    def save_program(self, name: str, program: m.Program) -> str:
        return self.command(m.SaveProgram(name, program))

    def load_program(self, kind: str, name: str) -> m.Program:
        return self.command(m.LoadProgram(kind, name))  # type: ignore[arg-type]

    def delete_program(self, kind: str, name: str) -> str:
        return self.command(m.DeleteProgram(kind, name))  # type: ignore[arg-type]

    def list_programs(self, kind: str = "") -> list[m.ProgramEntry]:
        return self.command(m.ListPrograms(kind))  # type: ignore[arg-type]

    def jog(self, jog: m.JogInput) -> None:
        """Put a jog velocity for a running run (held by the worker for JOG_DEADMAN_S)."""
        self.client.z.put(keys.jog(self.user, self.id), codec.dumps(jog))

    def runs(self) -> list[m.RunInfo]:
        return self.client.request(keys.results(self.user, self.id), reply=list[m.RunInfo])

    def results(
        self,
        run_id: str,
        variables: Sequence[str] | None = None,
        t0: float | None = None,
        t1: float | None = None,
        every: int = 1,
    ) -> tuple[list[str], np.ndarray]:
        """Full-resolution transients of a finished (or running) run: (column names, rows)."""
        att, rows = self.results_of(run_id, variables, t0, t1, every)
        return list(att.columns), rows

    def results_of(
        self,
        run_id: str,
        variables: Sequence[str] | None = None,
        t0: float | None = None,
        t1: float | None = None,
        every: int = 1,
    ) -> tuple[m.ResultsAttachment, np.ndarray]:
        """As `results`, with what the reply says of the run: its columns, units, RunInfo and the
        context it ran with (what a comparison of runs needs)."""
        key = keys.results(self.user, self.id, run_id) + selector_query(variables, t0, t1, every)
        payload, att = self.client.request_binary(key, m.ResultsAttachment)
        return att, frames.decode(payload).rows

    def watch(
        self,
        on_state: Callable[[m.SessionState], None] | None = None,
        on_live: Callable[[frames.Frame], None] | None = None,
        on_full: Callable[[frames.Frame], None] | None = None,
        on_layout: Callable[[m.RunLayout], None] | None = None,
        on_params: Callable[[m.ParamValues], None] | None = None,
        on_obstacles: Callable[[m.ObstacleValues], None] | None = None,
        on_command: Callable[[m.CommandValue], None] | None = None,
    ) -> Watch:
        watch = Watch()
        z = self.client.z

        seal = self.client.seal

        def add(key: str, cb: Callable[[Any], None], decode: Callable[[bytes], Any], latched: bool) -> None:
            def handle(sample: zenoh.Sample) -> None:
                if seal is None or seal.sample_valid(sample):
                    cb(decode(sample.payload.to_bytes()))

            worker = BoundedWorker(f"watch:{key}", handle, maxlen=4096)
            watch._workers.append(worker)
            if latched:
                history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
                watch._entities.append(
                    zenoh.ext.declare_advanced_subscriber(z, key, worker.push, history=history)
                )
            else:
                watch._entities.append(z.declare_subscriber(key, worker.push))

        if on_state:
            add(keys.state(self.user, self.id), on_state, lambda b: codec.loads(m.SessionState, b), True)
        if on_params:
            add(keys.params(self.user, self.id), on_params, lambda b: codec.loads(m.ParamValues, b), True)
        if on_obstacles:
            add(
                keys.obstacles(self.user, self.id),
                on_obstacles,
                lambda b: codec.loads(m.ObstacleValues, b),
                True,
            )
        if on_command:
            add(keys.command(self.user, self.id), on_command, lambda b: codec.loads(m.CommandValue, b), True)
        if on_layout:
            add(keys.layout(self.user, self.id), on_layout, lambda b: codec.loads(m.RunLayout, b), True)
        if on_live:
            add(keys.vars_live(self.user, self.id), on_live, frames.decode, False)
        if on_full:
            add(keys.vars_full(self.user, self.id), on_full, frames.decode, False)
        return watch

    def wait_for(
        self, phases: Sequence[str], timeout: float = 60.0, run_id: str | None = None
    ) -> m.SessionState:
        """Block until the session's state reaches one of `phases` (for `run_id` if given)."""
        done = threading.Event()
        seen: list[m.SessionState] = []

        def on_state(st: m.SessionState) -> None:
            seen.append(st)
            if st.phase in phases and (run_id is None or st.run_id == run_id):
                done.set()

        with self.watch(on_state=on_state):
            end = time.monotonic() + timeout
            # The subscription sees every change from now on; one direct look covers the state that
            # was current before it was declared, and a look per second guards against a lost sample.
            on_state(self.snapshot().state)
            while not done.wait(1.0):
                if time.monotonic() > end:
                    last = seen[-1].phase if seen else "nothing"
                    raise TimeoutError(
                        f"session {self.id} did not reach {list(phases)} in {timeout} s (last: {last})"
                    )
                on_state(self.snapshot().state)
        return next(s for s in reversed(seen) if s.phase in phases)
