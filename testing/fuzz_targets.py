"""What the fuzz of testing/fuzz.py aims at (its targets and the model's facts) and what it sends.

Apart from the fuzz itself so that every family of messages (testing/fuzz_*.py) can name them without
importing the sender; testing/fuzz.py re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass

from simecs.mesh.protocol.model import ModelDescription


@dataclass(frozen=True)
class Victim:
    """A session of another user that the fuzz aims at: nothing it sends may change it."""

    user: str
    session: str
    run_id: str = "r1"
    run_index: int = 1


@dataclass(frozen=True)
class FuzzTargets:
    """Who the attacker is and what it aims at.

    `attacker_sessions` are the attacker's own sessions (every command goes there); the victim's
    session and its run `victim_run_id` (frames of `width` columns) get forgeries and refused commands
    only; `bystanders` are more victims (e.g. one whose runs go on during the fuzz). Run ids are
    predictable (r1, r2, ...): forgeries and tokens aim at each victim's run and its next three too.
    `simulators` and
    `nodes` (role, node id) name the live service nodes, for their run and status keys; `mcap` is a
    valid recording, mutated for uploads (none: uploads of garbage only)."""

    attacker_user: str
    attacker_sessions: tuple[str, ...]
    victim_user: str
    victim_session: str
    victim_run_id: str
    victim_run_index: int
    width: int
    model_id: str = "spider"
    simulators: tuple[str, ...] = ()
    nodes: tuple[tuple[str, str], ...] = ()
    bystanders: tuple[Victim, ...] = ()
    mcap: bytes = b""

    @property
    def victim(self) -> Victim:
        return Victim(self.victim_user, self.victim_session, self.victim_run_id, self.victim_run_index)

    @property
    def victims(self) -> tuple[Victim, ...]:
        return (self.victim, *self.bystanders)


@dataclass(frozen=True)
class Message:
    """One thing the attacker does: a query, a put, or declaring/undeclaring a liveliness token."""

    kind: str  # cmd | query | put | token
    key: str  # a key expression; a query's may carry `?parameters`
    payload: bytes | None = None
    attachment: bytes | None = None
    what: str = ""  # how it was made, for reports


@dataclass(frozen=True)
class ModelFacts:
    """What the model offers, for valid-looking values out of range: its parameters and joints with
    their ranges, its variables, command levels and documentation pages."""

    model_id: str
    params: tuple[tuple[str, float, float, bool], ...]  # name, min, max, integer
    joints: tuple[tuple[float, float], ...]
    variables: tuple[str, ...]
    command_levels: tuple[str, ...]
    pages: tuple[str, ...]

    @classmethod
    def of(cls, desc: ModelDescription) -> ModelFacts:
        return cls(
            desc.id,
            tuple((p.name, p.min, p.max, p.integer) for p in desc.parameters),
            tuple((link.joint_min, link.joint_max) for link in desc.links),
            tuple(v.name for v in desc.variables),
            tuple(desc.command_levels),
            tuple(p.id for p in desc.docs),
        )

    @classmethod
    def fallback(cls, model_id: str) -> ModelFacts:
        """When the library does not answer: enough to build every command."""
        joints = ((-3.14, 3.14),) * 7
        return cls(model_id, (("joint1.ctrl.kp_pos", 0.0, 1e4, False),), joints, ("joint1.q",), (), ())


def next_runs(run_id: str, more: int = 3) -> list[str]:
    """`run_id` and the ids the next runs of its session will get."""
    try:
        n = int(run_id[1:])
    except ValueError:
        return [run_id]
    return [f"r{i}" for i in range(n, n + more + 1)]
