"""What a run costs a simulator host, and whether a host can take one more: the rules the simulator
(its `SimulatorLoad` status, its own refusals) and the proxy (admission, placement, wait estimates)
share, so the two never disagree about a run's size. docs/LAN.md explains them to whoever sizes a server.

A run's *demand* is in cores: a run paced as fast as possible (or in lockstep with an external
controller, whose worker never sleeps) takes a whole core; a paced run takes what its model costs
per simulated second times its speed, with a margin for jitter, capped at one core (a run is one
thread). A host's *capacity* is the cores its runs may use times `HEADROOM`, less what other processes
on those cores use (a hub, a proxy, a viewer on the same machine).
"""

from __future__ import annotations

import math

from ..protocol import messages as m

#: Share of a host's cores offered to runs: the rest absorbs the frames' routing and bursts.
HEADROOM = 0.95
#: A paced run's demand is its measured cost times its speed times this.
COST_MARGIN = 1.15
#: CPU s per simulated s of a model no run has measured yet on the host (pessimistic: RTF 4).
DEFAULT_COST = 0.25
#: A paced replay reads rows from memory: about this per simulated second.
REPLAY_COST = 0.01
#: No run is cheaper than this (its worker wakes up for every chunk and every frame).
MIN_DEMAND = 0.01
#: A paced run slower than its pace (RTF below BEHIND_RTF of it, over 1 s windows) for this long is
#: falling behind: its user is told, and the host takes no new run until it catches up.
BEHIND_GRACE_S = 3.0
BEHIND_RTF = 0.99
#: Memory a host keeps free beyond its runs' (the warm worker, the page cache).
MEMORY_SPARE_MB = 256.0


def demand(settings: m.RunSettings, cost: float, replay: bool = False) -> float:
    """Cores the run needs on a host whose measured cost of its model is `cost` (CPU s per sim s)."""
    if settings.controller == "external" and not replay:
        return 1.0  # lockstep: the worker waits for each answer spinning on the mesh core
    if not math.isfinite(settings.speed):
        return 1.0
    per_sim_s = REPLAY_COST if replay else cost
    return min(1.0, max(MIN_DEMAND, per_sim_s * settings.speed * COST_MARGIN))


def measured_cost(
    load: m.SimulatorLoad | None, model_id: str, replay: bool = False, fast: bool = False
) -> float | None:
    """CPU s per simulated s of a run of `model_id` on a host, as the host measured it (None: not yet).
    A paced run sleeps between its solver calls and finds its caches cold each time; a run as fast as
    possible (`fast`) never sleeps and costs less: the host measures the two apart."""
    if replay:
        return REPLAY_COST
    if load is None:
        return None
    return (load.fast_cost.get(model_id) if fast else None) or load.cost.get(model_id)


def model_cost(load: m.SimulatorLoad | None, model_id: str, replay: bool = False) -> float:
    """The measured cost, or DEFAULT_COST: pessimistic, so that admission never overcommits."""
    cost = measured_cost(load, model_id, replay)
    return DEFAULT_COST if cost is None else cost


def request_cost(request: m.RunRequest, load: m.SimulatorLoad | None) -> float:
    return model_cost(load, request.model_id, bool(request.recording))


def request_demand(request: m.RunRequest, load: m.SimulatorLoad | None) -> float:
    return demand(request.settings, request_cost(request, load), bool(request.recording))


def free_cores(load: m.SimulatorLoad, reserved: float = 0.0) -> float:
    """Cores the host still offers, after its runs and the runs on their way to it (`reserved`)."""
    return load.capacity - load.demand - reserved


def offers(load: m.SimulatorLoad | None, model_id: str) -> bool:
    """Whether a host can run the model at all (one that has not said which it runs may)."""
    return load is None or not load.models or model_id in load.models


def refusal(
    load: m.SimulatorLoad, request: m.RunRequest, reserved: float = 0.0, reserved_runs: int = 0
) -> str:
    """Why the host cannot take the run now ('' when it can)."""
    if not offers(load, request.model_id) and not request.recording:
        return f"it does not offer model {request.model_id}"
    if load.behind:
        return f"{load.behind} of its runs fall behind their pace"
    runs = len(load.runs) + reserved_runs
    if not load.warm and load.starting + reserved_runs >= max(1, int(load.cores)):
        # Without a warm worker a run starts cold (imports, compiled drives: a CPU-second or more):
        # a burst of cold starts would starve the runs going.
        return f"{load.starting + reserved_runs} runs are starting and no warm worker is ready"
    if load.max_runs and runs >= load.max_runs:
        return f"it runs {runs} simulations (its limit)"
    if load.worker_mb and load.memory_free_mb - reserved_runs * load.worker_mb < (
        load.worker_mb + MEMORY_SPARE_MB
    ):
        return f"{load.memory_free_mb:.0f} MB of memory free, a run takes {load.worker_mb:.0f} MB"
    need, free = request_demand(request, load), free_cores(load, reserved)
    # An idle host always takes one run: a core that other processes share still runs it.
    if need > free + 1e-9 and runs > 0:
        return f"{free:.2f} of its cores are free, the run needs {need:.2f}"
    return ""
