"""The simulator node: the paper's Low Level Simulator Machine, one process per run.

It accepts `RunRequest`s from the proxy, hands each to a warm worker process (models imported and
drives compiled ahead, so a run starts in milliseconds), keeps one warm worker in reserve, and serves
the full-resolution results of the last runs of every session from disk.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh import codec, files, keys
from simecs.mesh import messages as m
from simecs.mesh.results import results_reply
from simecs.mesh.runtime import Binary, Node, Request, RequestError, main_for, mesh_from_args

KEEP_RUNS = 10  # full-resolution results kept per session


class Simulator(Node):
    """Runs simulations in worker processes and serves their results."""

    role = "simulator"
    tick_s = 0.1

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        results_dir: str = ".simecs/results",
        max_runs: int | None = None,
        warm: int = 1,
    ) -> None:
        super().__init__(mesh, node_id)
        self.results_dir = Path(results_dir)
        self.max_runs = max_runs or max(os.cpu_count() or 1, 1) * 4
        self.warm_target = warm
        self.lock = threading.Lock()
        self.idle: list[subprocess.Popen[str]] = []
        self.busy: dict[str, subprocess.Popen[str]] = {}
        self.fast: set[str] = set()  # busy runs paced as fast as possible (CPU-bound)
        self.mesh_config_path = ""

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--results-dir",
            default=os.path.join(os.environ.get("SIMECS_DATA", ".simecs"), "results"),
            help="where full-resolution results are kept",
        )
        parser.add_argument("--max-runs", type=int, default=None, help="runs this host accepts at once")
        parser.add_argument("--warm", type=int, default=1, help="idle worker processes kept ready")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Simulator:
        node = cls(mesh_from_args(args), args.node_id, args.results_dir, args.max_runs, args.warm)
        node.mesh_config_path = args.mesh_config or ""
        return node

    def status_detail(self) -> dict[str, Any]:
        with self.lock:
            return {"running": len(self.busy), "warm": len(self.idle), "max_runs": self.max_runs}

    def start(self) -> None:
        self.results_dir.mkdir(parents=True, exist_ok=True)
        self.serve(keys.simulator_run(self.node_id), self._on_run)
        self.serve(keys.ALL_RESULTS_LIST, self._on_list, threaded=True)
        self.serve(f"{keys.ROOT}/*/results/*", self._on_results, threaded=True)
        self._refill()

    # -- worker processes ----------------------------------------------------------------------
    def _spawn(self) -> subprocess.Popen[str]:
        cmd = [sys.executable, "-m", "simecs.nodes.simworker", "--results-dir", str(self.results_dir)]
        for ep in self.mesh.connect:
            cmd += ["--connect", ep]
        cmd += ["--cpu", self.cpu_choice]  # where its zenoh threads go (mesh.affinity)
        env = dict(os.environ)
        if self.mesh_config_path:
            env["SIMECS_MESH_CONFIG"] = self.mesh_config_path
        return subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env)

    def _refill(self) -> None:
        with self.lock:
            self.idle = [p for p in self.idle if p.poll() is None]
            while len(self.idle) < self.warm_target:
                self.idle.append(self._spawn())

    def tick(self) -> None:
        with self.lock:
            for key, proc in list(self.busy.items()):
                code = proc.poll()
                if code is not None:
                    del self.busy[key]
                    self.fast.discard(key)
                    if code not in (0, 3):
                        self.log.warning("worker of %s exited with code %s", key, code)
                        self._report_lost(key, code)
            # Warming a worker up (seconds of compiling) would steal CPU from a run going as fast as
            # possible, even at nice 10 on a 2-vCPU machine: wait until no such run is going.
            defer = bool(self.fast)
        if not defer:
            self._refill()

    def _report_lost(self, key: str, code: int) -> None:
        """A worker that died (perhaps before its liveliness token was up) fails its run.

        The proxy ignores this if the worker's own final status or the loss of its token came first.
        """
        session, run_id = key.split("/")
        reason = f"the simulator process of run {run_id} disappeared (exit code {code})"
        status = m.RunStatus(session=session, run_id=run_id, phase="failed", reason=reason)
        self.z.put(keys.run_status(session), codec.dumps(status))

    def _on_run(self, req: Request) -> dict[str, Any]:
        run = req.json(m.RunRequest)
        with self.lock:
            if len(self.busy) >= self.max_runs:
                raise RequestError(
                    "busy", f"simulator {self.node_id} already runs {len(self.busy)} simulations"
                )
            proc = self.idle.pop(0) if self.idle else self._spawn()
            if proc.poll() is not None:
                proc = self._spawn()
            assert proc.stdin is not None
            try:
                proc.stdin.write(codec.dumps(run).decode() + "\n")
                proc.stdin.flush()
                proc.stdin.close()
            except OSError as exc:
                raise RequestError("internal", f"worker process could not take the run: {exc}") from None
            key = f"{run.session}/{run.run_id}"
            self.busy[key] = proc
            if run.settings.pacing == "fast":
                self.fast.add(key)
            else:
                threading.Thread(target=self._refill, daemon=True).start()
        self._prune(run.session)
        self.log.info("run %s/%s handed to worker pid %d", run.session, run.run_id, proc.pid)
        return {"simulator": self.node_id, "pid": proc.pid}

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

    # -- results -------------------------------------------------------------------------------
    def _prune(self, session: str) -> None:
        folder = self.results_dir / session
        if not folder.is_dir():
            return
        metas = sorted(folder.glob("r*.json"), key=lambda p: int(p.stem[1:]) if p.stem[1:].isdigit() else 0)
        for meta in metas[:-KEEP_RUNS]:
            meta.unlink(missing_ok=True)
            meta.with_suffix(".npy").unlink(missing_ok=True)

    def _runs(self, session: str) -> list[dict[str, Any]]:
        folder = self.results_dir / session
        if not folder.is_dir():
            raise RequestError("not_found", f"simulator {self.node_id} holds no results of session {session}")
        out = []
        for meta in sorted(folder.glob("r*.json")):
            try:
                info = files.read_json(meta)
            except (OSError, ValueError):
                continue
            out.append(info)
        return out

    def _on_list(self, req: Request) -> list[m.RunInfo]:
        session = keys.session_of(req.key)
        return [
            m.RunInfo(
                run_id=i["run_id"],
                phase=i["phase"],
                stop_time=i["stop_time"],
                sim_time=i["sim_time"],
                samples=i["samples"],
                reason=i.get("reason", ""),
            )
            for i in self._runs(session)
        ]

    def _on_results(self, req: Request) -> Binary:
        session = keys.session_of(req.key)
        run_id = keys.last_chunk(req.key)
        try:
            keys.check_name(run_id, "run id")
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "run_id") from None
        from simecs.nodes.simworker import results_paths

        npy, meta_path = results_paths(self.results_dir, session, run_id)
        if not meta_path.is_file():
            raise RequestError("not_found", f"no results of run {run_id} in session {session}", "run_id")
        meta = files.read_json(meta_path)
        data = np.load(npy, mmap_mode="r")
        run_index = int(run_id[1:]) if run_id[1:].isdigit() else 0
        return results_reply(data, meta["columns"], meta["units"], req.parameters, run_index)


def main(argv: list[str] | None = None) -> int:
    return main_for(Simulator, argv)


if __name__ == "__main__":
    main()
