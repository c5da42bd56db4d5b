"""The full-resolution results reply (PROTOCOL.md §6.2), built the same way by every node that serves
`simecs/<session>/results/<run>`: the simulator from its stored runs, a replay from its recording."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from . import frames
from .runtime import Binary, RequestError


def results_reply(
    data: np.ndarray,
    columns: Sequence[str],
    units: Sequence[str],
    parameters: Mapping[str, str],
    run_index: int,
) -> Binary:
    """Select `vars`, the time window `t0`..`t1` and one sample in `every` from `data` (time first)."""
    idx = list(range(len(columns)))
    if parameters.get("vars"):
        idx = [0]
        for name in parameters["vars"].split(","):
            if name not in columns:
                raise RequestError("bad_request", f"the run has no variable {name!r}", "vars")
            idx.append(list(columns).index(name))
    try:
        t0 = float(parameters.get("t0", "-inf"))
        t1 = float(parameters.get("t1", "inf"))
        every = int(parameters.get("every", "1"))
    except ValueError as exc:
        raise RequestError("bad_request", f"bad t0/t1/every: {exc}", "parameters") from None
    if every < 1:
        raise RequestError("bad_request", "every must be >= 1", "every")
    if data.shape[0]:
        keep = (data[:, 0] >= t0) & (data[:, 0] <= t1)
        rows = np.asarray(data[keep][::every][:, idx])
    else:
        rows = np.empty((0, len(idx)))
    frame = frames.Frame(run_index=run_index, seq=0, wall_ns=0, rows=rows)
    unit_of = [units[i] if i < len(units) else "" for i in idx]
    return Binary(frames.encode(frame), {"columns": [columns[i] for i in idx], "units": unit_of})
