"""A session's runs, from `run` to their end: the outcome of handing a run to a simulator, the workers'
reports, a worker that disappears, pause / resume / seek / abort, and settling runs after a restart of
the proxy. Every phase change goes through the session store (mesh/protocol/phases.py decides what may
happen).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process.hublink import HubLink
from simecs.mesh.process.runtime import RequestError
from simecs.mesh.process.seal import Seal
from simecs.mesh.protocol import codec, keys, phases
from simecs.mesh.protocol import messages as m

from .admission import QUEUE_WAITS_FOR_HOST_S, Admission
from .placement import Hosts
from .sessions import SessionRecord, SessionStore

MAX_WARNINGS = 20
ALIVE_AFTER_S = 0.15  # a report this long after a run's token went proves its worker alive
#: How long a lost run token waits before it is judged: for the worker's own last report (it travels
#: another way), and long enough that a live worker reports after ALIVE_AFTER_S (a running one reports
#: every RUNNING_REPORT_S; a window shorter than that let a peer's dropped copy of the token, on a busy
#: machine, pass a live run for lost).
LAST_REPORT_GRACE_S = ALIVE_AFTER_S + 1.75 * m.RUNNING_REPORT_S
TOKEN_QUERY_S = 1.0  # asking whether a run's token is still up
# A worker reports at least this often (running: every RUNNING_REPORT_S; paused: every 1 s,
# worker.PAUSED_REPORT_S): one heard from within it lives on when its simulator node is lost. Reports
# are sealed, tokens not.
WORKER_REPORTS_S = 3.0
TOKEN_QUERY_TRIES = 3  # queries that time out before one counts as an answer
#: How long runs whose tokens went with the hub wait for it to come back before they are settled.
RUNS_WAIT_FOR_HUB_S = 120.0

log = logging.getLogger("simecs.proxy")


def open_settings(settings: m.RunSettings, bound: float) -> m.RunSettings:
    """The settings a run until stopped runs with: paced in real time whatever the session's say (it
    is jogged in wall time), and `bound` s long at most (open_run_s, PROTOCOL.md §4.1)."""
    return msgspec.structs.replace(settings, pacing="realtime", factor=1.0, stop_time=bound)


class RunTracker:
    """The run lifecycle of every session, admission included. Methods are called with the proxy's lock
    held, except the report handlers, which take it."""

    def __init__(
        self,
        store: SessionStore,
        zenoh_session: Callable[[], zenoh.Session],
        seal: Callable[[], Seal],
        lock: threading.RLock,
        max_running: int | None = None,
        max_queue: int = 16,
        hosts: Hosts | None = None,
        host_wait_s: float = QUEUE_WAITS_FOR_HOST_S,
    ) -> None:
        self.store = store
        self.admission = Admission(
            store, zenoh_session, seal, lock, self.handed_over, max_running, max_queue, hosts, host_wait_s
        )
        self.z = zenoh_session
        self.seal = seal
        self.lock = lock
        self.log = log
        #: Runs of closed sessions that were told to abort: session id -> (user, run id). They hold
        #: their simulator slot until their worker ends, so admission counts them.
        self.orphans: dict[str, tuple[str, str]] = {}
        self.admission.orphans = self.orphans
        #: Runs whose token disappeared with the hub: (user, session) -> run id, checked when it is back.
        self.suspended: dict[tuple[str, str], str] = {}
        #: The request of each session's run going: what a restart on another host sends again.
        self.going: dict[str, m.RunRequest] = {}
        #: Runs told to stop: session id -> run id. The stop is repeated on the run's reports until it
        #: ends (a worker that had just started may have missed the first).
        self.stopping: dict[str, str] = {}
        self.hub: HubLink | None = None  # set once the proxy's session is open
        self._hub_check: threading.Thread | None = None

    def request(
        self,
        rec: SessionRecord,
        run_id: str,
        settings: m.RunSettings | None = None,
        recording: str = "",
        paused: bool = False,
        until_stopped: bool = False,
    ) -> m.RunRequest:
        """The request of run `run_id` of `rec` as the session stands (a replay: of `recording`)."""
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
            recording=recording,
            paused=paused,
            obstacles=list(rec.obstacles),
            until_stopped=until_stopped,
        )

    def continuing(
        self, rec: SessionRecord, run_id: str, ctx: m.RunContext, fast_until: float
    ) -> m.RunRequest:
        """The request of run `run_id` of `rec` that continues a failed run: that run's inputs (`ctx`),
        run as fast as possible up to `fast_until`."""
        return msgspec.structs.replace(
            self.request(rec, run_id, ctx.settings),
            values=dict(ctx.values),
            initial=list(ctx.initial),
            command=ctx.command,
            obstacles=list(ctx.obstacles),
            fast_until=fast_until,
        )

    def again(self, rec: SessionRecord) -> m.RunRequest:
        """The request of `rec`'s current run made again from the session (the proxy restarted since it
        was sent): its settings cannot have changed while it was under way, and its list entry says
        whether it replays a recording or runs until stopped (its stop_time then is the bound)."""
        run_id = rec.state.run_id
        info = rec.run_info(run_id)
        if info is not None and info.until_stopped:
            return self.request(rec, run_id, open_settings(rec.settings, info.stop_time), until_stopped=True)
        return self.request(rec, run_id, recording=info.recording if info is not None else "")

    def begin(self, rec: SessionRecord, request: m.RunRequest, stop_time: float) -> m.RunStarted:
        """A new run of `rec`: queued now, started when admission finds it a slot."""
        if rec.starting:
            raise RequestError("conflict", "the previous run is still being handed to a simulator")
        self.admission.enqueue(rec, request)  # refuses with busy when the server is full
        rec.run_counter += 1
        rec.add_run(
            m.RunInfo(
                request.run_id,
                "queued",
                stop_time,
                0.0,
                recording=request.recording,
                until_stopped=request.until_stopped,
            )
        )
        queued = phases.after(rec.phase, "queued")
        rec.state = m.SessionState(session=rec.id, phase=queued, seq=rec.state.seq, run_id=request.run_id)  # type: ignore[arg-type]
        self.store.publish_state(rec)
        self.admission.update()
        return m.RunStarted(request.run_id, rec.phase, rec.state.queue_position)  # type: ignore[arg-type]

    def handed_over(self, request: m.RunRequest, host: str, hosts: list[str], errors: list[str]) -> None:
        """Admission's outcome of handing a run to a simulator host (called with the lock held)."""
        sid, run_id = request.session, request.run_id
        rec = self.store.owned(request.user, sid)
        if rec is None or rec.abort_run == run_id:
            if host:  # aborted or closed while it was being handed over: stop it at once
                self.log.info(
                    "session %s run %s started on %s after its abort: aborting it", sid, run_id, host
                )
                if rec is None:
                    self.orphans[sid] = (request.user, run_id)
                self.send_control(request.user, sid, run_id, "abort")
            return
        if rec.state.run_id != run_id:
            return
        if host:
            self.log.info("session %s run %s started on simulator %s", sid, run_id, host)
            self.going[sid] = request
            rec.state.host = host
            self.run_info(rec, run_id, host=host, attempt=request.attempt)
            if rec.phase == "queued":  # its first status report may have come first
                self.started(rec)
            else:
                self.store.publish_state(rec)
        elif rec.phase == "queued":
            if hosts:
                why = "no simulator accepted the run: " + "; ".join(errors)
            else:  # refused before any host was asked: admission says why
                why = "; ".join(errors) or "no simulator node is on the mesh"
            self.end_run(rec, "failed", why)

    def started(self, rec: SessionRecord) -> None:
        self.store.move(
            rec, "started", queue_position=0, progress=0.0, sim_time=0.0, rtf=0.0, reason="", hil=None
        )
        self.run_info(rec, rec.state.run_id, phase="running")

    def run_info(self, rec: SessionRecord, run_id: str, **fields: Any) -> None:
        info = rec.run_info(run_id)
        if info is not None:
            for k, v in fields.items():
                setattr(info, k, v)

    def end_run(self, rec: SessionRecord, phase: str, reason: str = "") -> None:
        self.going.pop(rec.id, None)
        self.stopping.pop(rec.id, None)
        self.admission.hosts.release(rec.state.host, rec.id, rec.state.run_id)
        rec.active_at = time.time()  # a run that ends is activity: idle expiry counts from here
        self.run_info(rec, rec.state.run_id, phase=phase, reason=reason, sim_time=rec.state.sim_time)
        self.store.move(rec, phase, reason=reason, queue_position=0)
        if phase == "failed":
            self.log.warning("session %s run %s failed: %s", rec.id, rec.state.run_id, reason)

    def control(self, rec: SessionRecord, op: str, at: float = 0.0) -> None:
        if op == "abort":
            rec.abort_run = rec.state.run_id
        self.send_control(rec.user, rec.id, rec.state.run_id, op, at)

    def send_control(
        self, user: str, sid: str, run_id: str, op: str, at: float = 0.0, attempt: int = 0
    ) -> None:
        control = m.RunControl(op=op, run_id=run_id, time=at, attempt=attempt)  # type: ignore[arg-type]
        key, payload = keys.control(user, sid), codec.dumps(control)
        self.z().put(key, payload, attachment=self.seal().mac(key, payload))  # workers obey only this

    def pause(self, rec: SessionRecord, cmd: m.Pause) -> str:
        self.control(rec, "pause")
        return rec.state.run_id

    def resume(self, rec: SessionRecord, cmd: m.Resume) -> str:
        self.control(rec, "resume")
        return rec.state.run_id

    def seek(self, rec: SessionRecord, cmd: m.Seek) -> str:
        info = rec.run_info(rec.state.run_id)
        if info is None or not info.recording:
            raise RequestError("unsupported", "only replay runs can seek; a simulation runs forward", "op")
        self.control(rec, "seek", cmd.time)
        return rec.state.run_id

    def stop(self, rec: SessionRecord, cmd: m.Stop) -> str:
        """End the run going now as finished (the worker ends it within a frame, its results kept)."""
        self.stopping[rec.id] = rec.state.run_id
        self.control(rec, "stop")
        return rec.state.run_id

    def abort(self, rec: SessionRecord, cmd: m.Abort) -> str:
        if rec.phase == "queued" and rec.starting:
            rec.abort_run = rec.state.run_id  # _handed_over() stops it if a simulator took it
            self.end_run(rec, "aborted", "aborted while being handed to a simulator")
        elif rec.phase == "queued":
            self.admission.withdraw(rec)
            self.end_run(rec, "aborted", "aborted while queued")
            self.admission.update()
        else:
            self.control(rec, "abort")
        return rec.state.run_id

    def recover(self) -> None:
        """After a restart: runs whose worker still lives go on; the others are settled from their
        stored results; queued runs take their place in the queue again."""
        alive = set()
        for reply in self.z().liveliness().get(keys.RUN_TOKENS, timeout=1.0):
            if reply.ok is not None:
                ref = keys.RunRef.of_token(reply.ok.key_expr)
                alive.add((ref.session, ref.run_id))
        with self.lock:
            for rec in self.store:
                mine = (rec.id, rec.state.run_id) in alive
                if rec.phase in phases.GOING and not mine:
                    self._settle_ended_run(rec)
                elif rec.phase == "queued" and mine:  # it was being handed over when the proxy stopped
                    self.started(rec)
                elif rec.phase == "queued":
                    self.admission.requeue(rec, self.again(rec))
                else:
                    self.store.publish_state(rec)
                    self.store.publish_params(rec, [])
            self.admission.update()

    def described(self, user: str, sid: str, run_id: str, timeout: float = 3.0) -> m.ResultsAttachment | None:
        """What a run's stored results say of it (a ResultsAttachment: its RunInfo and RunContext),
        sealed, from the host that holds them; RemoteError or NoReply when none does. Asks the mesh:
        call without the lock."""
        selector = keys.results(user, sid, run_id) + "?t0=-1;t1=-1"  # no rows: the description only
        client = MeshClient(self.z(), timeout=timeout, seal=self.seal())
        return client.request_binary(selector, m.ResultsAttachment)[1]

    def _stored_end(self, user: str, sid: str, run_id: str) -> m.RunInfo | None:
        """How a run ended as its stored results say (a worker stores them before its last report and
        before its token goes), or None when no host holds them. Asks the mesh: call without the lock."""
        try:
            described = self.described(user, sid, run_id)
        except (RemoteError, NoReply, codec.DecodeError, zenoh.ZError):
            return None
        if described is None:
            return None
        return described.run if described.run.phase in phases.ENDED else None

    def _settle_ended_run(
        self, rec: SessionRecord, lost: str = "the run was lost while the proxy was down"
    ) -> None:
        """A run that ended while the proxy could not hear it: its stored results tell how it ended."""
        self._settle_from(rec, self._stored_end(rec.user, rec.id, rec.state.run_id), lost)

    def _settle_from(self, rec: SessionRecord, info: m.RunInfo | None, lost: str) -> None:
        """End `rec`'s run as its stored results `info` say, or as failed for `lost` without them."""
        if info is None:
            self.end_run(rec, "failed", lost)
            return
        rec.state.sim_time = info.sim_time
        rec.state.progress = min(1.0, info.sim_time / info.stop_time) if info.stop_time else 0.0
        self.run_info(rec, rec.state.run_id, jogged_s=info.jogged_s)
        self.end_run(rec, info.phase, info.reason)

    # -- reports from workers ------------------------------------------------------------------------
    def on_run_status(self, st: m.RunStatus, key: str) -> None:
        user, sid = keys.owner_of(key)
        if st.session != sid:
            log.warning("ignoring a run status of session %s published under %s", st.session, key)
            return
        with self.lock:
            rec = self.store.owned(user, sid)
            if st.phase not in phases.ENDED and (
                (rec is not None and rec.abort_run == st.run_id)
                or (rec is None and self.orphans.get(sid) == (user, st.run_id))
            ):
                self.send_control(user, sid, st.run_id, "abort")  # in case the first was missed
            elif st.phase not in phases.ENDED and self.stopping.get(sid) == st.run_id:
                self.send_control(user, sid, st.run_id, "stop")  # in case the first was missed
            if st.phase in phases.ENDED and self.orphans.get(sid) == (user, st.run_id):
                del self.orphans[sid]
                self.admission.update()
            if (
                rec is not None
                and rec.state.run_id == st.run_id
                and rec.phase not in phases.UNDER_WAY
                and st.phase not in phases.ENDED
            ):
                # A worker goes on for a run already ended here (taken for lost with its simulator
                # node, and no host left to run it again): its frames would reach a session that
                # shows it failed, and its recording. Told to stop, on each of its reports until it
                # ends (one control may be missed).
                self.send_control(user, sid, st.run_id, "abort", attempt=st.attempt)
                return
            if rec is None or rec.state.run_id != st.run_id or rec.phase not in phases.UNDER_WAY:
                return
            if st.attempt != rec.state.attempt:
                if st.phase not in phases.ENDED and st.attempt < rec.state.attempt:
                    # An attempt on a host taken for lost (cut off, not dead): it runs for no one.
                    self.send_control(user, sid, st.run_id, "abort", attempt=st.attempt)
                return
            rec.reported, rec.reported_at = st.run_id, time.monotonic()
            progress = min(1.0, st.sim_time / st.stop_time) if st.stop_time > 0 else 0.0
            self.run_info(rec, st.run_id, sim_time=st.sim_time, samples=st.samples)
            info = rec.run_info(st.run_id)
            if info is not None:  # it only grows within an attempt (a report of a lost worker says 0)
                info.jogged_s = max(info.jogged_s, st.jogged_s)
            if st.stop_time > 0:
                self.run_info(rec, st.run_id, stop_time=st.stop_time)
            rec.state.sim_time, rec.state.progress, rec.state.rtf = st.sim_time, progress, st.rtf
            rec.state.step, rec.state.task, rec.state.action = st.step, st.task, st.action
            rec.state.hil = st.hil
            if st.phase in phases.ENDED:
                self.end_run(rec, st.phase, st.reason)
                self.admission.update()
                return
            changed = False
            if rec.phase == "queued":
                self.started(rec)
                changed = True
            wanted = phases.of_worker(st.phase)
            if wanted != rec.phase:
                self.store.move(rec, "paused" if wanted == "paused" else "resumed")
                self.run_info(rec, st.run_id, phase=wanted)
                changed = True
            if not changed:
                self.store.publish_state(rec, persist=False)

    def on_notice(self, notice: m.Notice, key: str) -> None:
        user, sid = keys.owner_of(key)
        with self.lock:
            rec = self.store.owned(user, sid)
            if rec is None or notice.session != sid or rec.state.run_id != notice.run_id:
                return
            if self.warn(rec, notice.message, notice.source):
                self.store.publish_state(rec)

    def on_run_token(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        try:
            user, sid, run_id = keys.RunRef.of_token(sample.key_expr)
        except ValueError:
            return
        gone_at = time.monotonic()
        # The worker's last RunStatus may still be on its way (another channel than liveliness):
        # give it a moment before calling the run lost. Still within the 1 s promise.
        time.sleep(LAST_REPORT_GRACE_S)
        with self.lock:
            if self.orphans.get(sid) == (user, run_id):  # a closed session's run: its slot is free
                del self.orphans[sid]
                self.admission.update()
            rec = self.store.owned(user, sid)
            if rec is None or rec.state.run_id != run_id or rec.phase not in phases.GOING:
                return
            reported = rec.reported == run_id
        if self._token_up(user, sid, run_id):
            self.log.warning(
                "session %s run %s: a token vanished while the worker's is up (another peer's): ignored",
                sid,
                run_id,
            )
            return
        with self.lock:
            rec = self.store.owned(user, sid)
            if rec is None or rec.state.run_id != run_id or rec.phase not in phases.GOING:
                return
            if reported and self.hub is not None and self.hub.lost_since(gone_at - 0.05):
                # Every token went with the hub: the worker most likely runs on. Decide when it is back.
                self.suspended[(user, sid)] = run_id
                self.log.warning("session %s run %s: the hub went away; run kept meanwhile", sid, run_id)
                self._check_when_hub_back()
                return
            attempt, host = rec.state.attempt, rec.state.host
        # The worker is gone: with its host (restart the run elsewhere), or alone: it ended and its last
        # report is still on its way on a busy mesh, or before a restarted proxy heard from it (its
        # stored results say how), or it crashed. Tokens carry no seal: any peer may declare and drop one
        # under a predictable name, so before its worker's first (sealed) report only stored results
        # end a run; else it is the simulator's to report lost.
        host_gone = reported and bool(host) and not self._token_up_at(keys.node_token("simulator", host))
        stored = None if host_gone else self._stored_end(user, sid, run_id)
        with self.lock:
            rec = self.store.owned(user, sid)
            if rec is None or rec.state.run_id != run_id or rec.phase not in phases.GOING:
                return
            if rec.state.attempt != attempt:
                return  # restarted meanwhile (its host's token went first)
            if rec.reported_at > gone_at + ALIVE_AFTER_S:
                # A running worker reports every RUNNING_REPORT_S: one that reported well after its token
                # went is alive (another peer's copy of the token went, and a busy mesh answered the queries
                # without the worker's own); a crashed one sends nothing after its token is gone.
                self.log.warning(
                    "session %s run %s: a token vanished but its worker reported since: ignored", sid, run_id
                )
                return
            if host_gone:
                self.host_lost(host, worker_gone=sid)
                return
            if stored is None and not reported:
                self.log.warning(
                    "session %s run %s: a token vanished before the worker reported: ignored", sid, run_id
                )
                return
            if stored is not None:
                self.log.info(
                    "session %s run %s: its token went before this proxy had its last report", sid, run_id
                )
            crashed = f"the simulator process of run {run_id} disappeared (crashed or killed)"
            self._settle_from(rec, stored, crashed)
            self.admission.update()

    def host_lost(self, host: str, worker_gone: str = "") -> None:
        """Simulator host `host` left the mesh. A run whose worker still reports goes on: a worker is
        a process of its own, its simulator node only started it (its results go where the node's
        successor serves them from). Each other run, and that of session `worker_gone` (its worker's
        token went too), starts again from the start on another host (the simulation is deterministic:
        same result), or fails if no host is left."""
        self.admission.hosts.left(host)
        now = time.monotonic()
        for rec in list(self.store):
            if rec.state.host != host or rec.phase not in phases.GOING:
                continue
            if (
                rec.id != worker_gone
                and rec.reported == rec.state.run_id
                and now - rec.reported_at < WORKER_REPORTS_S
            ):
                self.log.warning(
                    "session %s run %s: simulator host %s was lost; its worker goes on with the run",
                    rec.id,
                    rec.state.run_id,
                    host,
                )
                continue
            request = self.going.get(rec.id) or self.again(rec)
            at = rec.state.sim_time
            why = f"simulator host {host} was lost at t = {at:.2f} s"
            if self.stopping.get(rec.id) == rec.state.run_id:  # the user ended it: not run again
                self.log.warning("session %s run %s: %s while being stopped", rec.id, request.run_id, why)
                self.end_run(rec, "failed", f"{why} while it was being stopped: its results went with it")
                continue
            self.log.warning(
                "session %s run %s: %s; restarting it on another host", rec.id, rec.state.run_id, why
            )
            attempt = rec.state.attempt + 1
            restarted = msgspec.structs.replace(
                request, attempt=attempt, restarted=why, paused=rec.phase == "paused"
            )
            self.going.pop(rec.id, None)
            rec.reported = ""
            text = f"{why}: run {rec.state.run_id} starts again from the start on another host"
            self.warn(rec, text)
            self.store.move(
                rec, "restarted", attempt=attempt, host="", progress=0.0, sim_time=0.0, rtf=0.0, hil=None
            )
            self.run_info(
                rec, rec.state.run_id, phase="queued", sim_time=0.0, attempt=attempt, host="", jogged_s=0.0
            )
            self.notify(rec, text)
            self.admission.requeue(rec, restarted, first=True)
        self.admission.update()

    def notify(self, rec: SessionRecord, text: str) -> None:
        """A notice from the proxy to the session's user (listed in its warnings by `warn`)."""
        notice = m.Notice(session=rec.id, run_id=rec.state.run_id, source="proxy", message=text)
        key, payload = keys.notices(rec.user, rec.id), codec.dumps(notice)
        self.z().put(key, payload, attachment=self.seal().mac(key, payload))

    def warn(self, rec: SessionRecord, text: str, source: str = "proxy") -> bool:
        """List a notice in the session's warnings (once; at most MAX_WARNINGS); whether it is new."""
        line = f"{source}: {text}"
        if line in rec.state.warnings or len(rec.state.warnings) >= MAX_WARNINGS:
            return False
        rec.state.warnings.append(line)
        return True

    def _token_up(self, user: str, sid: str, run_id: str) -> bool:
        """Whether a token of the run is still declared (asked without the lock: it takes a round trip)."""
        return self._token_up_at(keys.run_token(user, sid, run_id))

    def _token_up_at(self, key: str) -> bool:
        """Whether a token is declared under `key`. A query that ran into its timeout (a mesh busy
        with a flood) proves nothing and is asked again: only a complete answer without the token
        means gone, else a peer's dropped copy of a token could end a run whose worker is fine."""
        for _ in range(TOKEN_QUERY_TRIES):
            began = time.monotonic()
            try:
                replies = list(self.z().liveliness().get(key, timeout=TOKEN_QUERY_S))
            except zenoh.ZError:
                return False
            if any(r.ok is not None for r in replies):
                return True
            if time.monotonic() - began < 0.9 * TOKEN_QUERY_S:
                return False
        return False

    def _check_when_hub_back(self) -> None:
        """Once the hub is back and every node had time to reconnect: runs whose worker is back go on;
        the others ended meanwhile, and their stored results tell how (or they failed)."""
        if self._hub_check is not None and self._hub_check.is_alive():
            return

        def check() -> None:
            assert self.hub is not None
            back = self.hub.wait_back(RUNS_WAIT_FOR_HUB_S)
            alive = set()
            if back:
                for reply in self.z().liveliness().get(keys.RUN_TOKENS, timeout=1.0):
                    if reply.ok is not None:
                        alive.add(keys.RunRef.of_token(reply.ok.key_expr))
            with self.lock:
                for (user, sid), run_id in list(self.suspended.items()):
                    del self.suspended[(user, sid)]
                    rec = self.store.owned(user, sid)
                    if rec is None or rec.state.run_id != run_id or rec.phase not in phases.GOING:
                        continue
                    if keys.RunRef(user, sid, run_id) in alive:
                        self.log.info("session %s run %s: its worker is back with the hub", sid, run_id)
                    elif back:
                        self._settle_ended_run(rec, "its simulator process was lost while the hub was away")
                    else:
                        away = f"the hub was unreachable for more than {RUNS_WAIT_FOR_HUB_S:g} s"
                        self.end_run(rec, "failed", away)
                self.admission.update()

        self._hub_check = threading.Thread(target=check, name="hub-check", daemon=True)
        self._hub_check.start()
