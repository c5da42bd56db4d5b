"""Which CPU the processes on the live path run on.

A live frame crosses several processes (worker -> hub -> hot-feedback -> hub -> viewer). On a
virtual machine, waking a thread on another, idle vCPU costs an inter-processor interrupt that the
host serves late: measured on our 2-vCPU build VMs, a pipe ping-pong between two processes has
p50 0.024 ms / p99 0.07 ms on one vCPU but p50 0.67 ms / p99 3.3 ms across two. Zenoh spreads its
threads over all CPUs, so every hop of the live path risks that cost. Pinning the processes that
route live frames (hub, hot-feedback, viewer) to one shared "mesh core" turns those hops into
same-CPU wake-ups; the simulations still use every core. One frame then pays at most one
cross-CPU wake-up (worker -> hub).

A simulator worker keeps its simulation thread free but puts its zenoh threads on the mesh core
too (`open_on_mesh_core`), so the frame it publishes reaches the hub without another cross-CPU hop;
a run paced as fast as possible lets them go again (throughput then matters, not latency).

`--cpu auto` (the default of those nodes, also `SIMECS_CPU`) picks the highest CPU this process may
use, and does nothing on a single-CPU machine; `--cpu none` leaves placement to the OS; `--cpu 3`
names a CPU.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

log = logging.getLogger("simecs.affinity")


def mesh_core(choice: str = "auto") -> int | None:
    """The CPU the live path should share, or None to leave placement to the OS."""
    choice = choice.strip().lower()
    if choice in ("none", "off", ""):
        return None
    if not hasattr(os, "sched_getaffinity"):
        return None
    allowed = sorted(os.sched_getaffinity(0))
    if choice == "auto":
        return allowed[-1] if len(allowed) >= 2 else None
    try:
        cpu = int(choice)
    except ValueError:
        raise ValueError(f"--cpu {choice!r}: expected auto, none or a CPU number") from None
    if cpu not in allowed:
        raise ValueError(f"--cpu {cpu}: this process may run on CPUs {allowed} only")
    return cpu


def thread_ids() -> set[int]:
    return {int(tid) for tid in os.listdir("/proc/self/task")}


def pin_threads(tids: set[int], cpus: set[int]) -> int:
    """Let the threads `tids` of this process run on `cpus` only; returns how many were placed."""
    count = 0
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
            count += 1
        except ProcessLookupError:  # a thread that just ended
            continue
    return count


def open_on_mesh_core(open_: Callable[[], T], choice: str = "auto") -> T:
    """Call `open_` (which opens a zenoh session) and pin the threads it started to the mesh core;
    the calling thread, and threads it starts later, stay where they were."""
    before = thread_ids()
    result = open_()
    cpu = mesh_core(choice)
    if cpu is not None:
        pin_threads(thread_ids() - before, {cpu})
    return result


def renice_process(value: int) -> None:
    """Set the nice value of every thread: on Linux `setpriority(PRIO_PROCESS, 0)` changes the
    calling thread only, and threads inherit their creator's value."""
    for tid in thread_ids():
        try:
            os.setpriority(os.PRIO_PROCESS, tid, value)
        except ProcessLookupError:
            continue


def pin_process(cpus: set[int]) -> int:
    """Let every thread of this process run on `cpus` only; threads started later inherit it from
    their creator. Returns how many threads were placed."""
    return pin_threads(thread_ids(), cpus)


def place_on_mesh_core(choice: str = "auto") -> int | None:
    """Pin this process to the mesh core chosen by `choice`; returns the CPU, or None."""
    cpu = mesh_core(choice)
    if cpu is not None:
        threads = pin_process({cpu})
        log.info("live path: %d threads pinned to CPU %d", threads, cpu)
    return cpu
