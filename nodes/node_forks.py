"""What a fork server of nodes loads once (mesh/process/forks.py): every node's imports and the
kernels the proxy's planner and the simulator's workers load from numba's cache. A node forked from
it is ready in a fraction of a CPU second instead of 0.3-2.2 (the proxy's start was 2.1 CPU s, most
of it its planner's kernels), and the simulator's worker fork server, forked from it too, skips the
imports and kernels it would load again.
"""

from __future__ import annotations

import importlib

#: The modules a node runs as `python -m`: imported once, before any fork.
NODE_MODULES = (
    "simecs.nodes.hub",
    "simecs.nodes.proxy",
    "simecs.nodes.simulator",
    "simecs.nodes.hotfeedback",
    "simecs.nodes.recorder",
    "simecs.nodes.worker_forks",
)
#: The `--warm` hook of such a fork server.
WARM = f"{__name__}:warm"


def warm() -> None:
    for name in NODE_MODULES:
        importlib.import_module(name)
    from simecs import models

    models.warmup()  # the drives' kernels, then the planner's
    models.forget_library()  # each child reads the library with its own SIMECS_MODELS
