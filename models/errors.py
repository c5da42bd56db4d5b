"""Errors raised by models/: a refused parameter value, a failed simulation."""

from __future__ import annotations


class ParameterError(ValueError):
    """A parameter value was refused; `name` is the parameter, `reason` says why."""

    def __init__(self, name: str, reason: str) -> None:
        self.name = name
        self.reason = reason
        super().__init__(f"{name}: {reason}")


class SimulationError(RuntimeError):
    """A numerical failure: the message names what diverged and when."""


class CommandError(ValueError):
    """A robot command the model cannot carry out; `field` is its path inside the command (e.g.
    `nodes[2]`, `tasks[0].actions[1].args.speed_pct`), `reason` says why."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}" if field else reason)
