"""Simulations from a script: one run to its end, or a sweep of parameter variations, and the outcome
measures a sweep tabulates. What `simecs run` and `simecs sweep` do, for integrators' own code
(docs/CLIENT.md); every step is an ordinary protocol request, made through `client.MeshClient`.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .client import MeshClient, SessionClient
from .protocol import messages as m
from .protocol import phases

#: Outcome measures of a variable over a run: `kind:variable`, e.g. `overshoot:joint2.q`.
MEASURES: dict[str, str] = {
    "final": "the last sample",
    "max": "the largest sample",
    "min": "the smallest sample",
    "max_abs": "the largest magnitude",
    "rms": "the root mean square over the run",
    "overshoot": "how far past its final value it went, in percent of its change from the first sample",
    "settling_time": "s from the start until it stays within 2 % of its change around its final value",
}
SETTLING_BAND = 0.02


@dataclass
class RunOutcome:
    """How one run ended and its full-resolution results (every column unless asked for fewer)."""

    session: str
    run_id: str
    phase: str
    reason: str
    sim_time: float
    rtf: float
    plan: m.CommandPlan
    columns: list[str] = field(default_factory=list)
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 1)))

    @property
    def ok(self) -> bool:
        return self.phase == "finished"

    def column(self, name: str) -> np.ndarray:
        return self.rows[:, self.columns.index(name)]


def measure(spec: str, outcome: RunOutcome) -> float:
    """One outcome measure (`kind:variable`, kinds in MEASURES) of a run's results."""
    kind, _, variable = spec.partition(":")
    if kind not in MEASURES or not variable:
        raise ValueError(f"measure {spec!r}: write kind:variable, kind one of {', '.join(MEASURES)}")
    if variable not in outcome.columns:
        raise ValueError(f"measure {spec!r}: the run has no variable {variable!r}")
    x = outcome.column(variable)
    if x.size == 0:
        return float("nan")
    t = outcome.column("time")
    if kind == "final":
        return float(x[-1])
    if kind == "max":
        return float(x.max())
    if kind == "min":
        return float(x.min())
    if kind == "max_abs":
        return float(np.abs(x).max())
    if kind == "rms":
        return float(np.sqrt(np.mean(x * x)))
    change = x[-1] - x[0]
    if kind == "overshoot":
        if change == 0:
            return 0.0
        past = (x - x[-1]) * np.sign(change)
        return float(max(0.0, past.max()) / abs(change) * 100.0)
    outside = np.abs(x - x[-1]) > SETTLING_BAND * abs(change)  # settling_time
    return float(t[np.nonzero(outside)[0][-1] + 1]) if outside.any() and not outside[-1] else 0.0


def prepare(
    session: SessionClient,
    command: m.RobotCommand,
    values: Mapping[str, float] | None = None,
    initial: Sequence[float] | None = None,
    settings: m.RunSettings | None = None,
) -> m.CommandPlan:
    """Give a session its values, initial pose, settings and command (each refused with its field)."""
    if values:
        session.set_params(dict(values))
    if initial is not None:
        session.set_initial(initial)
    if settings is not None:
        session.command(m.SetSettings(settings))
    return session.set_command(command)


def run_simulation(
    client: MeshClient,
    user: str,
    model_id: str,
    command: m.RobotCommand,
    values: Mapping[str, float] | None = None,
    initial: Sequence[float] | None = None,
    settings: m.RunSettings | None = None,
    variables: Sequence[str] | None = None,
    progress: Callable[[m.SessionState], None] | None = None,
    timeout: float = 3600.0,
    close: bool = True,
) -> RunOutcome:
    """Create a session, run `command` to its end, fetch its results; the session is closed after
    unless `close` is False (its recording stays with the recorder either way)."""
    session = client.create_session(user, model_id)
    try:
        plan = prepare(session, command, values, initial, settings)
        latest: list[m.SessionState] = []
        ended = threading.Event()
        run_id = ""

        def on_state(st: m.SessionState) -> None:
            if run_id and st.run_id == run_id:
                latest.append(st)
                if progress is not None:
                    progress(st)
                if st.phase in phases.ENDED:
                    ended.set()

        with session.watch(on_state=on_state):
            run_id = session.run()
            now = session.snapshot().state  # a short run may have ended before its id came back
            if now.run_id == run_id and now.phase in phases.ENDED:
                latest.append(now)
                ended.set()
            if not ended.wait(timeout):
                raise TimeoutError(f"run {run_id} of session {session.id} did not end within {timeout:g} s")
        st = latest[-1] if latest and latest[-1].phase in phases.ENDED else session.snapshot().state
        outcome = RunOutcome(session.id, run_id, st.phase, st.reason, st.sim_time, st.rtf, plan)
        if any(r.run_id == run_id and r.samples for r in session.runs()):
            outcome.columns, outcome.rows = session.results(run_id, variables)
        return outcome
    finally:
        if close:
            session.close()


def variations(grid: Mapping[str, Sequence[float]]) -> list[dict[str, float]]:
    """Every combination of the grid's values (the last name varies fastest)."""
    names = list(grid)
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*(grid[n] for n in names))]


@dataclass
class SweepRow:
    index: int
    values: dict[str, float]
    outcome: RunOutcome | None
    measures: dict[str, float]
    error: str = ""


def sweep(
    client: MeshClient,
    user: str,
    model_id: str,
    command: m.RobotCommand,
    cases: Sequence[Mapping[str, float]],
    measures: Sequence[str],
    base: Mapping[str, float] | None = None,
    initial: Sequence[float] | None = None,
    settings: m.RunSettings | None = None,
    parallel: int = 4,
    done: Callable[[SweepRow], None] | None = None,
    timeout: float = 3600.0,
) -> list[SweepRow]:
    """Run every case (parameter values over `base`) at most `parallel` at once (the service queues
    what its simulators cannot take yet) and tabulate the measures; a refused or failed case is a
    row with its error, not the end of the sweep."""
    variables = sorted({spec.partition(":")[2] for spec in measures} | {"time"})

    def one(index: int, case: Mapping[str, float]) -> SweepRow:
        row = SweepRow(index, dict(case), None, {})
        try:
            values = {**(base or {}), **case}
            out = run_simulation(
                client, user, model_id, command, values, initial, settings, variables, timeout=timeout
            )
            row.outcome = out
            if out.ok:
                row.measures = {spec: measure(spec, out) for spec in measures}
            else:
                row.error = f"{out.phase}: {out.reason}"
        except Exception as exc:  # a refusal names its field; the sweep goes on
            row.error = str(exc)
        if done is not None:
            done(row)
        return row

    with ThreadPoolExecutor(max_workers=max(1, parallel)) as pool:
        rows = list(pool.map(lambda ic: one(*ic), enumerate(cases)))
    return rows


def wait_for_recording(client: MeshClient, user: str, name: str, timeout: float = 30.0) -> m.RecordingInfo:
    """A run's recording once the recorder has closed it (a moment after the run ends)."""
    end = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < end:
        try:
            return client.recording_info(user, name)
        except Exception as exc:
            last = exc
            time.sleep(0.1)
    raise TimeoutError(f"recording {name} not available within {timeout:g} s ({last})")
