"""How a run is simulated: the settings a session keeps and every run carries (paper §2.2 step 6)."""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta

from .limits import limit
from .model import ControlSystem
from .primitives import FieldProblem, Name, Record

MAX_SAMPLES = limit("samples_per_run")


# -- simulation settings -------------------------------------------------------------------------------
class RunSettings(Record):
    """Paper §2.2 step 6. `set_settings` replaces the whole object: omitted fields take these defaults."""

    stop_time: Annotated[float, Meta(gt=0.0, le=3600.0, description="s, (0, 3600]")] = 5.0
    output_interval: Annotated[
        float, Meta(ge=1e-4, le=3600.0, description="s between result samples, [1e-4, stop_time]")
    ] = 0.002
    step: Annotated[
        float,
        Meta(ge=0.0, le=0.01, description="solver step in s: 0 = the model's default, else [1e-5, 0.01]"),
    ] = 0.0
    pacing: Literal["realtime", "scaled", "fast"] = "realtime"
    factor: Annotated[float, Meta(ge=0.01, le=1000.0, description="x real time, for pacing scaled")] = 1.0
    live_rate_hz: Annotated[float, Meta(ge=0.1, le=1000.0, description="live frames per wall second")] = 50.0
    live_vars: Annotated[list[Name], Meta(max_length=10_000, description="empty: every variable")] = []
    controller: Annotated[
        Literal["builtin", "external"],
        Meta(description="external: a controller on hil/actuators drives the joints (PROTOCOL.md §6.3)"),
    ] = "builtin"
    external_joints: Annotated[
        list[Name],
        Meta(max_length=64, description="controller external: the joints it drives; empty = every joint"),
    ] = []
    control_period: Annotated[
        float,
        Meta(
            ge=1e-4,
            le=0.1,
            description="s, a multiple of step: controller external, one exchange per period; "
            "control_system opspace_motion or opspace_hybrid, one controller update per period "
            "(zero-order hold)",
        ),
    ] = 0.001
    hil_timeout: Annotated[
        float,
        Meta(ge=0.05, le=60.0, description="s of wall time without an actuator frame: the run fails"),
    ] = 2.0
    control_system: Annotated[
        ControlSystem,
        Meta(
            description="controller builtin: joint_independent (each joint's cascade), opspace_motion "
            "(task-space inverse dynamics at the tool, updated every control_period) or opspace_hybrid "
            "(the same, with force control where a Cartesian node sets a force); one of the model's "
            "control_systems"
        ),
    ] = "joint_independent"
    collisions: Annotated[
        Literal["refuse", "simulate"],
        Meta(
            description="refuse: a run whose planned path makes the arm touch an obstacle or itself is "
            "refused, naming the step and the obstacle or the two links; simulate: it runs, the contact "
            "with obstacles is simulated and links touching each other are told as notices"
        ),
    ] = "refuse"

    def __post_init__(self) -> None:
        if self.output_interval > self.stop_time:
            raise FieldProblem("output_interval", f"{self.output_interval:g} s is above stop_time")
        if self.stop_time / self.output_interval > MAX_SAMPLES:
            raise FieldProblem(
                "output_interval",
                f"{self.stop_time / self.output_interval:,.0f} output samples (stop_time / output_interval), "
                f"more than samples_per_run = {MAX_SAMPLES:,}: raise output_interval or shorten stop_time",
            )
        if self.control_system != "joint_independent" and self.controller == "external":
            raise FieldProblem(
                "control_system",
                f"{self.control_system} is a built-in controller: it needs controller builtin",
            )
        if 0.0 < self.step < 1e-5:
            raise FieldProblem("step", f"{self.step:g} s is outside [1e-5, 0.01] s (0 = model default)")

    @property
    def speed(self) -> float:
        """Wanted real-time factor; math.inf for as fast as possible."""
        return {"realtime": 1.0, "scaled": self.factor, "fast": float("inf")}[self.pacing]
