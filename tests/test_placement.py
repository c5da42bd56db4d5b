"""The proxy's placement and wait estimates (nodes/placement.py), driven by injected `SimulatorLoad`
statuses as the hosts publish them: the decisions, without a mesh (the mesh runs in test_scale)."""

from __future__ import annotations

import math

import pytest
from simecs.mesh.protocol import messages as m
from simecs.nodes.host_load import COST_SMOOTHING, HostLoad
from simecs.nodes.placement import GoingRun, Hosts


def host_load(capacity: float, cost: dict[str, float] | None = None, **fields: object) -> m.SimulatorLoad:
    given: dict[str, object] = {"models": ["spider"], "memory_free_mb": 8000.0, "worker_mb": 100.0}
    given.update(fields)
    cost = cost if cost is not None else {"spider": 0.05}
    return m.SimulatorLoad(cores=2.0, capacity=capacity, cost=cost, **given)  # type: ignore[arg-type]


def request(n: int, pacing: str = "fast", stop_time: float = 20.0) -> m.RunRequest:
    return m.RunRequest(
        session=f"s{n:03d}",
        run_id="r1",
        run_index=1,
        user="ann",
        model_id="spider",
        values={},
        initial=[],
        command=None,
        settings=m.RunSettings(stop_time=stop_time, pacing=pacing),  # type: ignore[arg-type]
    )


def hosts(**loads: m.SimulatorLoad) -> Hosts:
    out = Hosts()
    for node_id, status in loads.items():
        out.joined(node_id)
        out.status(node_id, status)
    return out


def test_fast_runs_queue_per_core_and_wait_for_each_other() -> None:
    """A fast run takes a core: on a host offering 1.9 cores, with one going and 2 s left, the next
    waits for it, the one after for that one too (20 s at cost 0.05 = 1 s, plus the measured 0.5 s
    start-up)."""
    h = hosts(a=host_load(1.9, start_s=0.5))
    waits = h.wait_estimates([GoingRun("a", 1.0, 2.0)], [request(1), request(2)])
    assert waits == pytest.approx([2.0, 3.5])
    assert hosts(a=host_load(2.9)).wait_estimates([GoingRun("a", 1.0, 2.0)], [request(1)]) == [0.0]


def test_a_run_that_finds_no_warm_worker_waits_for_one() -> None:
    """One warm worker, warm-up 2 s, hand-over 0.1 s, one fast run at a time (0.95 cores): the first
    queued run takes the warm worker (ends at 1 + 0.1 + 1), the second waits for the replacement,
    warm 2 s after the first took its predecessor (starts at 3.0 + 0.1, ends at 4.1), the third
    finds the second's replacement warm."""
    h = hosts(a=host_load(0.95, warm=1, start_s=0.1, cold_start_s=2.0))
    waits = h.wait_estimates([GoingRun("a", 1.0, 1.0)], [request(1), request(2), request(3)])
    assert waits == pytest.approx([1.0, 2.1, 4.1])


def test_a_configured_ceiling_counts_runs() -> None:
    """--max-runs 1: real-time runs that would fit by demand still wait their turn."""
    h = hosts(a=host_load(1.9, max_runs=1))
    waits = h.wait_estimates(
        [GoingRun("a", 0.06, 5.0)], [request(1, "realtime", 10.0), request(2, "realtime")]
    )
    assert waits == pytest.approx([5.0, 15.0])


def test_a_wait_that_hangs_on_an_unmeasured_cost_is_unknown() -> None:
    """Before the host has measured the model's cost a fast run's length is a guess several times off:
    the runs waiting for it are told 'unknown' (nan; 0 on the wire), not a wrong number; a run that
    fits at once still waits 0."""
    h = hosts(a=host_load(1.9, cost={}))
    going = [GoingRun("a", 1.0, math.nan)]
    waits = h.wait_estimates(going, [request(1, "realtime"), request(2)])
    assert waits[0] == 0.0 and math.isnan(waits[1])


def test_the_least_loaded_host_wins_and_no_host_means_never() -> None:
    h = hosts(a=host_load(0.9), b=host_load(1.9))
    assert h.choose(request(1)) == ("b", "")
    assert hosts().wait_estimates([], [request(1)]) == [math.inf]


def test_a_host_that_does_not_offer_the_model_is_never_chosen() -> None:
    h = hosts(a=host_load(1.9, models=["puma560"]))
    host, why = h.choose(request(1))
    assert host == "" and "spider" in why


def test_a_run_over_before_the_hosts_status_lists_it_gives_its_core_back() -> None:
    """One core for fast runs: a run handed over holds it (its host has not listed it yet); once it
    ended (a short run can end between two statuses) the next one takes the core at once."""
    h = hosts(a=host_load(1.0))
    first, second = request(1), request(2)
    h.reserve("a", first)
    assert h.choose(second)[0] == ""
    h.status("a", host_load(1.0))  # the host's next status does not list it: it is still on its way
    assert h.choose(second)[0] == ""
    h.release("a", first.session, first.run_id)
    assert h.choose(second) == ("a", "")


def test_a_fast_run_lasts_what_fast_runs_cost_not_what_paced_runs_do() -> None:
    """A paced run sleeps between its solver calls and pays cold caches each time: the host measures the
    two apart. A queued fast run of 20 s takes 20 x its fast cost (0.03: 0.6 s), not 20 x 0.05."""
    h = hosts(a=host_load(0.95, fast_cost={"spider": 0.03}))
    waits = h.wait_estimates([GoingRun("a", 1.0, 2.0)], [request(1), request(2)])
    assert waits == pytest.approx([2.0, 2.6])


def test_a_host_measures_the_costs_of_paced_and_fast_runs_apart_over_all_its_runs() -> None:
    """Each second the host sums its runs' CPU and simulated time by model and pacing, then smooths:
    one run's CPU is read in 10 ms ticks, the sum of many is steadier. The warm-up's calibration is
    the first estimate of both."""
    hl = HostLoad(["spider"])
    hl.take_costs('cost {"spider": 0.03}')
    assert hl.cost == hl.fast_cost == {"spider": 0.03}
    # 30 real-time runs of 1 simulated s at 0.03 to 0.05 CPU s each; one fast run of 25 s in 0.75 CPU s
    hl._take_spent({("spider", False): [1.2, 30.0], ("spider", True): [0.75, 25.0]})
    assert hl.cost["spider"] == pytest.approx(0.03 + COST_SMOOTHING * (0.04 - 0.03))
    assert hl.fast_cost["spider"] == pytest.approx(0.03)
    hl._take_spent({("spider", False): [0.01, 0.1]})  # a run that just started: too little to say
    assert hl.cost["spider"] == pytest.approx(0.033)
    status = hl._build()
    assert status.cost == {"spider": 0.033} and status.fast_cost == {"spider": 0.03}
