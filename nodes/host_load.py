"""What this simulator host carries, measured: the `SimulatorLoad` in its status (mesh/rules/load.py).

Every second it reads, from /proc, the CPU time of each worker and of the cores the host may use (so
it knows what other processes on those cores take: a hub, a proxy, a viewer), the memory free and a
worker's size; the workers tell it how far their runs got (`progress` lines on their stdout, read
without ever blocking). From these come each run's recent CPU and RTF, what each model costs per
simulated second (a moving average over the runs), and the host's capacity.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field

from simecs.mesh.process.runtime import process_mb
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import load

from .worker import COST, PROGRESS
from .worker_forks import WorkerProcess

SAMPLE_S = 1.0
COST_SMOOTHING = 0.3  # weight of a new measurement of a model's cost
MIN_COST_SIM_S = 0.2  # simulated s a measurement of a cost needs at least (a run just started has less)
OTHER_SMOOTHING = 0.3  # of a new measurement of the other processes' CPU use
START_SMOOTHING = 0.3  # of a new measurement of a start-up time
DEFAULT_WORKER_MB = 300.0
_TICK = os.sysconf("SC_CLK_TCK")


@dataclass
class HostedRun:
    """A run handed to one of this host's workers."""

    proc: WorkerProcess
    session: str
    run_id: str
    model_id: str
    settings: m.RunSettings
    replay: bool
    warm: bool  # its worker was warm when it took the run
    sim_time: float = 0.0
    behind: bool = False
    started: float = field(default_factory=time.monotonic)  # handed over
    stepping: bool = False  # it reported progress
    cpu: float = 0.0
    rtf: float = 0.0
    _last: tuple[float, float, float] | None = None  # (wall, CPU s, simulated s) at the last sample


def process_cpu_s(pid: int) -> float | None:
    """CPU seconds (user + system) process `pid` has used; None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / _TICK
    except (OSError, IndexError, ValueError):
        return None


def cores_busy_s(cpus: set[int]) -> tuple[float, float]:
    """(busy, total) CPU seconds of `cpus` since boot, from /proc/stat (steal counts as busy)."""
    busy = total = 0.0
    try:
        with open("/proc/stat") as f:
            for line in f:
                name, *values = line.split()
                if not name.startswith("cpu") or name == "cpu" or int(name[3:]) not in cpus:
                    continue
                v = [int(x) for x in values[:8]]
                idle = v[3] + v[4]  # idle + iowait
                total += sum(v)
                busy += sum(v) - idle
    except (OSError, ValueError):
        pass
    return busy / _TICK, total / _TICK


def memory_free_mb() -> float:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError):
        pass
    return 0.0


class HostLoad:
    """Runs of this host, and the measurements that make its `SimulatorLoad`. Not thread-safe: the
    simulator calls it with its lock held."""

    def __init__(self, models: list[str], max_runs: int = 0) -> None:
        self.cpus = set(os.sched_getaffinity(0))
        self.models = models
        self.max_runs = max_runs
        self.runs: dict[keys.RunRef, HostedRun] = {}
        self._partial: dict[int, bytes] = {}  # a worker's unfinished last line, by pid
        self.cost: dict[str, float] = {}  # of paced runs, by model
        self.fast_cost: dict[str, float] = {}  # of runs as fast as possible, by model
        self.other = 0.0  # cores used on our cores by processes other than the runs' workers
        self.worker_mb = DEFAULT_WORKER_MB
        self.start_s = 0.0  # moving average of hand-over to a warm worker to first progress
        self.cold_start_s = 0.0  # moving average of a worker's warm-up (or a cold run's start)
        self.warm = 0  # idle workers that said they are ready
        self.memory_mb = memory_free_mb()
        self._cores_at = (time.monotonic(), *cores_busy_s(self.cpus))
        self._sampled = 0.0
        self.current = self._build()

    # -- runs ---------------------------------------------------------------------------------------
    def refusal(self, request: m.RunRequest) -> str:
        return load.refusal(self.current, request)

    def add(self, key: keys.RunRef, proc: WorkerProcess, request: m.RunRequest, warm: bool) -> None:
        run = HostedRun(
            proc,
            request.session,
            request.run_id,
            request.model_id,
            request.settings,
            bool(request.recording),
            warm,
        )
        self.runs[key] = run
        self.current = self._build()  # counted at once: the next request sees it

    def remove(self, key: keys.RunRef) -> None:
        run = self.runs.pop(key, None)
        if run is not None:
            self._partial.pop(run.proc.pid, None)
            self.current = self._build()

    def lines(self, proc: WorkerProcess) -> list[str]:
        """The whole lines worker `proc` wrote since the last call (its stdout is non-blocking); its
        `cost` lines are taken here, the others returned."""
        if proc.stdout is None:
            return []
        try:
            chunk = os.read(proc.stdout.fileno(), 65536)
        except (BlockingIOError, OSError, ValueError):
            return []
        *whole, self._partial[proc.pid] = (self._partial.get(proc.pid, b"") + chunk).split(b"\n")
        out = []
        for raw in whole:
            line = raw.decode("utf-8", "replace")
            if line.startswith(COST):
                self.take_costs(line)
            else:
                out.append(line)
        return out

    def take_costs(self, line: str) -> None:
        """A `cost` line of a warm worker: first estimates, for models no run has measured here."""
        try:
            measured = json.loads(line.split(" ", 1)[1])
        except (IndexError, ValueError):
            return
        for model_id, cost in measured.items():
            if isinstance(cost, float | int) and cost > 0:
                self.cost.setdefault(str(model_id), float(cost))
                self.fast_cost.setdefault(str(model_id), float(cost))

    # -- measuring ------------------------------------------------------------------------------------
    def sample(self, idle_pids: list[int], warm: int) -> bool:
        """Read the workers' lines now; measure once per SAMPLE_S. Whether the load changed."""
        changed = warm != self.warm
        self.warm = warm
        for run in self.runs.values():
            changed |= self._read_lines(run)
        now = time.monotonic()
        if now - self._sampled < SAMPLE_S:
            if changed:
                self.current = self._build()
            return changed
        self._sampled = now
        workers_cpu = 0.0
        spent: dict[tuple[str, bool], list[float]] = {}  # (model, fast) -> [CPU s, simulated s]
        for run in self.runs.values():
            cpu_s = process_cpu_s(run.proc.pid)
            if cpu_s is None:
                continue
            if run._last is not None:
                wall, cpu0, sim0 = run._last
                dt = max(now - wall, 1e-3)
                run.cpu = max(cpu_s - cpu0, 0.0) / dt
                workers_cpu += run.cpu
                # a replay reads rows, a run in the loop waits spinning: neither is the model's cost
                if not run.replay and run.settings.controller != "external" and run.sim_time > sim0:
                    sums = spent.setdefault((run.model_id, not math.isfinite(run.settings.speed)), [0.0, 0.0])
                    sums[0] += max(cpu_s - cpu0, 0.0)
                    sums[1] += run.sim_time - sim0
            run._last = (now, cpu_s, run.sim_time)
        self._take_spent(spent)
        t0, busy0, total0 = self._cores_at
        busy, total = cores_busy_s(self.cpus)
        self._cores_at = (now, busy, total)
        if total > total0:
            busy_cores = (busy - busy0) / (total - total0) * len(self.cpus)
            other = max(busy_cores - workers_cpu, 0.0)
            self.other += OTHER_SMOOTHING * (other - self.other)
        sizes = [process_mb(r.proc.pid) for r in self.runs.values()] + [process_mb(p) for p in idle_pids]
        self.worker_mb = max([s for s in sizes if s > 0], default=self.worker_mb)
        self.memory_mb = memory_free_mb()
        self.current = self._build()
        return True

    def _take_spent(self, spent: dict[tuple[str, bool], list[float]]) -> None:
        """The CPU and simulated time each model's runs spent over the last sample, paced runs and runs
        as fast as possible apart, into the costs. Summed over the runs first: one run's CPU over a
        second is read in 10 ms ticks (+-25 % of a real-time Spider run's), the sum of many is not."""
        for (model_id, fast), (cpu_s, sim_s) in spent.items():
            if sim_s < MIN_COST_SIM_S:
                continue
            table = self.fast_cost if fast else self.cost
            measured = cpu_s / sim_s
            before = table.get(model_id, measured)
            table[model_id] = before + COST_SMOOTHING * (measured - before)

    def _read_lines(self, run: HostedRun) -> bool:
        """Take a run's progress lines; whether its `behind` changed."""
        changed = False
        for line in self.lines(run.proc):
            if line.startswith(PROGRESS):
                try:
                    _, t, behind, rtf = line.split()
                    run.sim_time, was = float(t), run.behind
                    run.behind = behind == "1"
                    run.rtf = float(rtf)  # the worker's own clock: exact, where ours would be late
                    changed |= was != run.behind
                    if not run.stepping:
                        run.stepping = True
                        self.started(time.monotonic() - run.started, run.warm)
                except ValueError:
                    continue
        return changed

    def started(self, took: float, warm: bool) -> None:
        """A run took `took` s from hand-over to its first step (or a worker that long to warm up)."""
        if warm:
            self.start_s = _average(self.start_s, took)
        else:
            self.cold_start_s = _average(self.cold_start_s, took)

    def demand(self, run: HostedRun) -> float:
        """The run's demand at the model's cost as measured now."""
        return load.demand(run.settings, self.cost.get(run.model_id, load.DEFAULT_COST), run.replay)

    def _build(self) -> m.SimulatorLoad:
        cores = float(len(self.cpus))
        demands = {key: self.demand(r) for key, r in self.runs.items()}
        runs = [
            m.RunLoad(
                r.session,
                r.run_id,
                r.model_id,
                round(demands[key], 4),
                round(r.cpu, 3),
                round(r.rtf, 3),
                r.behind,
            )
            for key, r in self.runs.items()
        ]
        return m.SimulatorLoad(
            cores=cores,
            capacity=round(max(cores * load.HEADROOM - self.other, 0.0), 3),
            demand=round(sum(demands.values()), 4),
            runs=runs,
            cost={k: round(v, 5) for k, v in sorted(self.cost.items())},
            fast_cost={k: round(v, 5) for k, v in sorted(self.fast_cost.items())},
            models=list(self.models),
            memory_free_mb=round(self.memory_mb, 1),
            worker_mb=round(self.worker_mb, 1),
            max_runs=self.max_runs,
            behind=sum(1 for r in self.runs.values() if r.behind),
            start_s=round(self.start_s, 3),
            cold_start_s=round(self.cold_start_s, 3),
            warm=self.warm,
            starting=sum(1 for r in self.runs.values() if not r.stepping),
        )


def _average(before: float, took: float) -> float:
    return took if not before else before + START_SMOOTHING * (took - before)
