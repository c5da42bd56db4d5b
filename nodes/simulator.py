"""The simulator node: the paper's Low Level Simulator Machine, one process per run.

It accepts `RunRequest`s from the proxy (a model to simulate, or a recording to replay), hands each to
a warm worker process (models imported and drives compiled ahead, so a run starts in milliseconds),
keeps one warm worker in reserve, and serves the full-resolution results of the runs it holds. It
says it is ready (its liveliness token) only once its first worker is warm: a first run then starts
at once.
"""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from simecs.mesh.process import seal as seals
from simecs.mesh.process.runtime import Binary, Node, NotMine, Request, RequestError, main_for, mesh_from_args
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.results import results_reply

from .host_load import HostLoad
from .results_store import ResultsStore
from .worker import READY
from .worker_forks import WorkerForks, WorkerProcess

CLOSED_KEPT = 4096
WARM_TIMEOUT_S = 600.0  # a first start compiles the drives (tens of seconds on a cold cache)


class Simulator(Node):
    """Runs simulations and replays in worker processes and serves their results."""

    role = "simulator"
    tick_s = 0.1

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        results_dir: str = ".simecs/results",
        max_runs: int | None = None,
        warm: int = 2,
    ) -> None:
        super().__init__(mesh, node_id)
        self.store = ResultsStore(results_dir)
        from simecs.models import list_models, load_problems

        for problem in load_problems():
            self.log.error("model left out: %s", problem)
        #: What this host carries and can carry: runs are refused by it, the proxy places runs by it.
        self.load = HostLoad([s.id for s in list_models()], max_runs or 0)
        self.warm_target = warm
        self.lock = threading.Lock()
        self.idle: list[WorkerProcess] = []
        self.ready: set[int] = set()  # pids of idle workers that said they are warm
        self.spawned_at: dict[int, float] = {}  # pids of workers not warm yet: when they were started
        #: Sessions closed lately: an aborted run's worker may store results after the close.
        self.closed: dict[tuple[str, str], None] = {}
        self.busy: dict[keys.RunRef, WorkerProcess] = {}
        self.forks: WorkerForks | None = None  # started with the node (start)
        self.fast: set[keys.RunRef] = set()  # busy runs paced as fast as possible (CPU-bound)
        self.mesh_config_path = ""
        self._bundles: dict[str, bytes] = {}  # model id -> its bundle, made on the first ask

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--results-dir",
            default=os.path.join(os.environ.get("SIMECS_DATA", ".simecs"), "results"),
            help="where full-resolution results are kept",
        )
        parser.add_argument(
            "--max-runs", type=int, default=None, help="a ceiling of runs at once (default: by capacity)"
        )
        parser.add_argument("--warm", type=int, default=2, help="idle worker processes kept ready")
        parser.add_argument(
            "--models",
            action="append",
            default=[],
            metavar="DIR",
            help="this host's own models: a model directory or a folder of them (repeatable; adds to "
            "SIMECS_MODELS); the host offers them on the mesh",
        )

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Simulator:
        if args.models:  # read by simecs.models here and in every worker (they inherit the environment)
            from simecs.models import EXTRA_ENV

            extra = [str(Path(d).resolve()) for d in args.models]
            os.environ[EXTRA_ENV] = os.pathsep.join([*extra, os.environ.get(EXTRA_ENV, "")]).strip(os.pathsep)
        node = cls(mesh_from_args(args), args.node_id, args.results_dir, args.max_runs, args.warm)
        node.mesh_config_path = args.mesh_config or ""
        return node

    def status_detail(self) -> dict[str, Any]:
        with self.lock:
            return {"running": len(self.busy), "warm": len(self.idle)}

    def status_load(self) -> m.SimulatorLoad:
        with self.lock:
            return self.load.current

    def start(self) -> None:
        self.store.folder.mkdir(parents=True, exist_ok=True)
        self.serve(keys.simulator_run(self.node_id), self._on_run)
        self.serve(keys.ALL_RESULTS, self._on_results, threaded=True)
        self.serve(keys.simulator_models(self.node_id), self._on_model_bundle, threaded=True)
        # A closed session (by its user, or expired) takes its results with it (mesh/protocol/limits.py).
        self.subscribe_messages(keys.ALL_STATE, m.SessionState, self._on_state, maxlen=1024, sealed=True)
        if self.warm_target:
            # Workers are forked warm from one process that warms up once (nodes/worker_forks.py).
            self.log.info("warming up the workers (compiling the drives the first time takes a while)")
            t0 = time.monotonic()
            self.forks = WorkerForks(self._worker_argv(), self._worker_env(), WARM_TIMEOUT_S)
            if not self.forks.wait_ready():
                self.log.warning("the worker fork server is not there: each worker warms up on its own")
            self._refill()
            self._wait_warm(self.idle[0], t0)
        else:
            self._refill()

    # -- worker processes ----------------------------------------------------------------------
    def _worker_argv(self) -> list[str]:
        argv = ["--results-dir", str(self.store.folder), "--simulator", self.node_id]
        for ep in self.mesh.connect:
            argv += ["--connect", ep]
        return [*argv, "--cpu", self.cpu_choice]  # where its zenoh threads go (mesh.process.affinity)

    def _worker_env(self) -> dict[str, str]:
        env = dict(os.environ)  # BLAS on one thread, as every node's (nodes/__init__.py)
        env["SIMECS_SERVICE_KEY_FILE"] = str(seals.key_file(self.mesh.service_key_file))
        if self.mesh_config_path:
            env["SIMECS_MESH_CONFIG"] = self.mesh_config_path
        return env

    def _spawn(self) -> WorkerProcess:
        """A worker: forked warm, or (no fork server) a process of its own that warms up itself."""
        proc: WorkerProcess | None = self.forks.fork() if self.forks is not None else None
        if proc is None:
            cmd = [sys.executable, "-m", "simecs.nodes.worker", *self._worker_argv()]
            proc = subprocess.Popen(
                cmd,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                env=self._worker_env(),
                bufsize=1,
            )
        assert proc.stdout is not None
        os.set_blocking(proc.stdout.fileno(), False)  # read in tick(), never waited on
        self.spawned_at[proc.pid] = time.monotonic()
        return proc

    def _poll_idle(self) -> None:
        """Read what idle workers said: their measured costs, and that they are warm."""
        for proc in self.idle:
            if proc.pid not in self.ready and READY in self.load.lines(proc):
                self.ready.add(proc.pid)
                # A run that finds no warm worker waits about this long.
                spawned = self.spawned_at.pop(proc.pid, None)
                if spawned is not None:
                    self.load.started(time.monotonic() - spawned, warm=False)

    def _wait_warm(self, proc: WorkerProcess, t0: float) -> None:
        """Block until `proc` says it is warm (or dies, or the time is up from t0: then runs still
        start, only slower)."""
        assert proc.stdout is not None
        end = t0 + WARM_TIMEOUT_S
        while time.monotonic() < end and not self.stop_event.is_set() and proc.poll() is None:
            select.select([proc.stdout], [], [], 0.5)
            with self.lock:
                self._poll_idle()
                if proc.pid in self.ready:
                    took = time.monotonic() - t0
                    self.log.info("worker warm after %.1f s", took)
                    return
        self.log.warning("no warm worker after %.0f s: runs start cold", time.monotonic() - t0)

    def _refill(self) -> None:
        with self.lock:
            self.idle = [p for p in self.idle if p.poll() is None]
            self.ready &= {p.pid for p in self.idle}
            self.spawned_at = {p.pid: self.spawned_at[p.pid] for p in self.idle if p.pid in self.spawned_at}
            while len(self.idle) < self.warm_target:
                self.idle.append(self._spawn())

    def tick(self) -> None:
        with self.lock:
            for key, proc in list(self.busy.items()):
                code = proc.poll()
                if code is not None:
                    del self.busy[key]
                    self.load.remove(key)
                    self.fast.discard(key)
                    if (key.user, key.session) in self.closed:  # its worker stored results after the close
                        self.store.remove(key.user, key.session)
                    if code not in (0, 3):
                        self.log.warning("worker of %s exited with code %s", key, code)
                        self._report_lost(key, code)
            # Warming a worker up (seconds of compiling) would steal CPU from a run going as fast as
            # possible, even at nice 10 on a 2-vCPU machine: wait until no such run is going.
            defer = bool(self.fast)
            self._poll_idle()
            self.load.sample([p.pid for p in self.idle], sum(1 for p in self.idle if p.pid in self.ready))
        if not defer:
            self._refill()

    def _report_lost(self, key: keys.RunRef, code: int) -> None:
        """A worker that died (perhaps before its liveliness token was up) fails its run.

        The proxy ignores this if the worker's own final status or the loss of its token came first.
        """
        user, session, run_id = key
        reason = f"the simulator process of run {run_id} disappeared (exit code {code})"
        # what it computed, from its partial file (not for a closed session: its results went with it)
        kept = None if (user, session) in self.closed else self.store.salvage(user, session, run_id, reason)
        if kept is not None:
            reason += f"; its results up to t = {kept.sim_time:.3f} s are kept"
            self.log.info(
                "run %s/%s: %d samples its worker left are kept as its results", session, run_id, kept.samples
            )
        status = m.RunStatus(
            session=session,
            run_id=run_id,
            phase="failed",
            reason=reason,
            sim_time=kept.sim_time if kept is not None else 0.0,
            samples=kept.samples if kept is not None else 0,
        )
        self.put(keys.run_status(user, session), codec.dumps(status))

    def _on_run(self, req: Request) -> m.Accepted:
        req.from_service("run requests")  # the proxy's: its admission and its sessions' owners
        run = req.json(m.RunRequest)
        key = keys.RunRef.of(run)
        with self.lock:
            taken = self.busy.get(key)
            if taken is not None and taken.poll() is None:
                # Offered again: the proxy did not get our answer (the hub went away meanwhile).
                return m.Accepted(self.node_id, taken.pid)
            why = self.load.refusal(run)
            if why:
                raise RequestError("busy", f"simulator {self.node_id} cannot take the run: {why}")
            ready = [p for p in self.idle if p.pid in self.ready]
            proc = (ready or self.idle)[0] if self.idle else self._spawn()
            if proc in self.idle:
                self.idle.remove(proc)
            warm = proc.pid in self.ready
            self.spawned_at.pop(proc.pid, None)  # its start is measured as the run's, not as a warm-up
            self.ready.discard(proc.pid)
            self.load.warm = sum(1 for p in self.idle if p.pid in self.ready)
            if proc.poll() is not None:
                proc, warm = self._spawn(), False
            assert proc.stdin is not None
            try:
                proc.stdin.write(codec.dumps(run).decode() + "\n")
                proc.stdin.flush()
                proc.stdin.close()
            except OSError as exc:
                raise RequestError("internal", f"worker process could not take the run: {exc}") from None
            self.busy[key] = proc
            self.load.add(key, proc, run, warm)
            if run.settings.pacing == "fast":
                self.fast.add(key)
            else:
                threading.Thread(target=self._refill, daemon=True).start()
        state = "warm" if warm else "cold"
        self.log.info("run %s/%s handed to %s worker pid %d", run.session, run.run_id, state, proc.pid)
        return m.Accepted(self.node_id, proc.pid)

    def stop(self) -> None:
        with self.lock:
            procs = self.idle + list(self.busy.values())
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=3)
            except subprocess.TimeoutExpired:
                p.kill()
        if self.forks is not None:
            self.forks.close()

    # -- results -------------------------------------------------------------------------------
    def _on_state(self, state: m.SessionState, key: str) -> None:
        if state.phase != "closed":
            return
        user, sid = keys.owner_of(key)
        if state.session != sid:
            return
        with self.lock:
            self.closed[(user, sid)] = None
            while len(self.closed) > CLOSED_KEPT:
                del self.closed[next(iter(self.closed))]
        if self.store.remove(user, sid):
            self.log.info("session %s of %s closed: its results removed", sid, user)

    def _on_model_bundle(self, req: Request) -> Binary:
        """A model this host offers, as a bundle of its directory (the proxy adds it to the library)."""
        from simecs import models
        from simecs.models.bundle import bundle

        model_id = keys.parse("simulator_model", req.key)["model"]
        try:
            package = models.get_model(model_id)
        except KeyError:
            raise RequestError(
                "not_found", f"host {self.node_id} has no model {model_id!r}", "model"
            ) from None
        with self.lock:
            data = self._bundles.get(model_id)
        if data is None:
            data = bundle(package.spec)
            with self.lock:
                self._bundles[model_id] = data
        return Binary(data)

    def _on_results(self, req: Request) -> Binary:
        """A run's results if this host holds them; other hosts (and the proxy, for runs it knows)
        leave the query to the one that does."""
        try:
            where = keys.parse("results", req.key)
        except ValueError:
            raise NotMine() from None
        found = self.store.load(where["user"], where["session"], where["run"])
        if found is None:
            raise NotMine()
        run, data = found
        info = m.RunInfo(run.run_id, run.phase, run.stop_time, run.sim_time, run.samples, run.reason)  # type: ignore[arg-type]
        info.jogged_s = run.jogged_s
        context = None
        if run.context is not None:
            try:
                context = codec.from_obj(m.RunContext, run.context)
            except codec.DecodeError as exc:  # a damaged file: its rows are still worth serving
                self.log.warning(
                    "run %s: its stored context is unreadable (%s): sent without it", run.run_id, exc
                )
        info.until_stopped = context is not None and context.until_stopped
        return results_reply(data, run.columns, run.units, req.parameters, run.run_index, info, context)


def main(argv: list[str] | None = None) -> int:
    return main_for(Simulator, argv)


if __name__ == "__main__":
    main()
