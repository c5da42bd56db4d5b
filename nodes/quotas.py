"""What one user may hold on the server at once (mesh/protocol/limits.py): sessions, runs going, results kept,
parameter sets. The proxy asks before it creates anything; a refusal is `busy` and names the bound,
what the user holds and how to free some.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import limits, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.limits import RUNS_KEPT

from .sessions import SessionRecord, SessionStore

FLOAT_BYTES = 8


@dataclass
class Quotas:
    sessions: int = limits.limit("sessions")
    sessions_per_user: int = limits.limit("sessions_per_user")
    runs_per_user: int = limits.limit("runs_per_user")
    results_bytes_per_user: int = limits.limit("results_bytes_per_user")
    param_sets_per_user: int = limits.limit("param_sets_per_user")
    programs_per_user: int = limits.limit("programs_per_user")


def _bytes(n: int) -> str:
    return f"{n / limits.MiB:.0f} MiB"


class QuotaCheck:
    """The checks, against the proxy's sessions (called with the proxy's lock held)."""

    def __init__(self, quotas: Quotas, store: SessionStore, columns_of: Callable[[str], int]) -> None:
        self.q = quotas
        self.store = store
        self.columns_of = columns_of  # model id -> columns of its results

    def new_session(self, user: str) -> None:
        if len(self.store) >= self.q.sessions:
            raise RequestError(
                "busy",
                f"the server holds its maximum of {self.q.sessions} sessions (sessions = {self.q.sessions}): "
                "close a session you no longer need, or try again when others have closed theirs",
            )
        mine = sum(1 for r in self.store if r.user == user)
        if mine >= self.q.sessions_per_user:
            raise RequestError(
                "busy",
                f"{user} holds {mine} sessions, the most one user may (sessions_per_user = "
                f"{self.q.sessions_per_user}): close one first",
            )

    def results_bytes(self, model_id: str, samples: int) -> int:
        return (samples + 1) * self.columns_of(model_id) * FLOAT_BYTES

    def new_run(
        self, rec: SessionRecord, settings: m.RunSettings, stop_time: float, replay: bool = False
    ) -> None:
        """Before a run (or replay) of `rec` is queued: its results fit one run's bound, and its user's
        runs going and results kept stay within theirs. A replay's size is its recording's, bounded by
        the upload limit: only its user's runs going are counted."""
        samples = int(stop_time / settings.output_interval)
        size = 0 if replay else self.results_bytes(rec.model_id, samples)
        per_run = limits.limit("results_bytes_per_run")
        if size > per_run:
            raise RequestError(
                "bad_request",
                f"the run's results would take {_bytes(size)} ({samples} samples x "
                f"{self.columns_of(rec.model_id)} columns), more than results_bytes_per_run = "
                f"{_bytes(per_run)}: raise output_interval or shorten stop_time",
                "settings.output_interval",
            )
        going = [r for r in self.store if r.user == rec.user and (r.phase in phases.UNDER_WAY or r.starting)]
        if len(going) >= self.q.runs_per_user:
            raise RequestError(
                "busy",
                f"{rec.user} has {len(going)} runs going (queued, running or paused), the most one user "
                f"may (runs_per_user = {self.q.runs_per_user}): wait for one to end or abort one",
            )
        kept = self.kept_results(rec.user, leaving=rec)
        if kept + size > self.q.results_bytes_per_user:
            raise RequestError(
                "busy",
                f"{rec.user}'s results would take {_bytes(kept + size)}, more than results_bytes_per_user = "
                f"{_bytes(self.q.results_bytes_per_user)}: close sessions you no longer need",
            )

    def kept_results(self, user: str, leaving: SessionRecord | None = None) -> int:
        """Bytes of the results `user`'s sessions keep; `leaving`: its oldest run makes way for the
        next one when the session keeps its most runs already."""
        total = 0
        for r in self.store:
            if r.user != user:
                continue
            runs = r.runs[1:] if r is leaving and len(r.runs) >= RUNS_KEPT else r.runs
            for info in runs:
                samples = (
                    info.samples
                    if info.phase in phases.ENDED
                    else int(info.stop_time / r.settings.output_interval)
                )
                total += self.results_bytes(r.model_id, samples)
        return total

    def new_param_set(self, user: str, held: int, replacing: bool) -> None:
        self._one_more(
            user, held, replacing, "param_sets_per_user", self.q.param_sets_per_user, "parameter sets"
        )

    def new_program(self, user: str, held: int, replacing: bool) -> None:
        self._one_more(user, held, replacing, "programs_per_user", self.q.programs_per_user, "saved programs")

    @staticmethod
    def _one_more(user: str, held: int, replacing: bool, bound: str, most: int, what: str) -> None:
        """A new named thing of a user's library (not one replaced) within its count bound."""
        if not replacing and held >= most:
            raise RequestError(
                "busy",
                f"{user} holds {held} {what}, the most one user may ({bound} = {most}): delete one first",
                "name",
            )
