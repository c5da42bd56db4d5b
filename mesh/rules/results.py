"""Full-resolution results (PROTOCOL.md §6.2): the selector a client asks with, and the reply frame.

Every node that serves `<session>/results/<run>` builds its reply here, so the selector's rules
(which parameters, their bounds) are the same wherever the run's data lives.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..process.runtime import Binary, RequestError
from ..protocol import frames
from ..protocol.messages import ResultsAttachment, RunContext, RunInfo

#: The selector parameters a results query may carry (anything else is refused).
SELECTOR_PARAMETERS = ("vars", "t0", "t1", "every")


@dataclass
class Selector:
    """Which columns, which time window and one sample in how many."""

    variables: list[str]
    t0: float = -math.inf
    t1: float = math.inf
    every: int = 1


def selector_query(
    variables: Sequence[str] | None = None,
    t0: float | None = None,
    t1: float | None = None,
    every: int = 1,
) -> str:
    """The `?vars=..;t0=..` tail a client adds to a results key ('' when it asks for everything)."""
    params = []
    if variables:
        params.append("vars=" + ",".join(variables))
    if t0 is not None:
        params.append(f"t0={t0!r}")
    if t1 is not None:
        params.append(f"t1={t1!r}")
    if every != 1:
        params.append(f"every={int(every)}")
    return "?" + ";".join(params) if params else ""


def parse_selector(parameters: Mapping[str, str]) -> Selector:
    """Read a selector strictly: unknown parameters, non-numbers and non-finite times are refused."""
    for name in parameters:
        if name not in SELECTOR_PARAMETERS:
            raise RequestError(
                "bad_request",
                f"unknown selector parameter {name!r} (allowed: {', '.join(SELECTOR_PARAMETERS)})",
                name,
            )
    sel = Selector([v for v in parameters.get("vars", "").split(",") if v])
    for name in ("t0", "t1"):
        if name in parameters:
            try:
                value = float(parameters[name])
            except ValueError:
                raise RequestError(
                    "bad_request", f"{name}={parameters[name]!r:.40} is not a number", name
                ) from None
            if not math.isfinite(value):
                raise RequestError("bad_request", f"{name} must be a finite time in s", name)
            setattr(sel, name, value)
    if "every" in parameters:
        text = parameters["every"]
        if not text.isdigit() or int(text) < 1 or len(text) > 9:
            raise RequestError("bad_request", f"every={text!r:.40} must be a whole number >= 1", "every")
        sel.every = int(text)
    return sel


def results_reply(
    data: np.ndarray,
    columns: Sequence[str],
    units: Sequence[str],
    parameters: Mapping[str, str],
    run_index: int,
    run: RunInfo,
    context: RunContext | None = None,
) -> Binary:
    """Select the columns, the time window `t0`..`t1` and one sample in `every` from `data` (time
    first); the reply frame's attachment names the columns and their units."""
    sel = parse_selector(parameters)
    idx = list(range(len(columns)))
    if sel.variables:
        where = {c: i for i, c in enumerate(columns)}
        idx = [0]
        for name in sel.variables:
            if name not in where:
                raise RequestError("bad_request", f"the run has no variable {name!r}", "vars")
            idx.append(where[name])
    if data.shape[0]:
        keep = (data[:, 0] >= sel.t0) & (data[:, 0] <= sel.t1)
        rows = np.asarray(data[keep][:: sel.every][:, idx])
    else:
        rows = np.empty((0, len(idx)))
    frame = frames.Frame(run_index=run_index, seq=0, wall_ns=0, rows=rows)
    names = [columns[i] for i in idx]
    unit_of = [units[i] if i < len(units) else "" for i in idx]
    return Binary(frames.encode(frame), ResultsAttachment(names, unit_of, run, context))
