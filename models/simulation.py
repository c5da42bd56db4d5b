"""One run of a model: Exudyn integrates the chain, the compiled drives act in its PreStep.

The simulator node drives a `Simulation` chunk by chunk: `set_values` / `set_initial` /
`set_joint_path` between runs, then `start` and `advance` until `finished`; each `advance` is one
Exudyn solver call, and the output rows are taken inside the step loop (docs/MODELS.md, "Coupling").
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.model import CONTROL_SYSTEMS
from simecs.mesh.rules.kinematics import rot_rpy

from . import chain_dynamics, drive_integrator, references
from . import drive as dr
from .chain_dynamics import gravity_torques
from .contact import contact_prestep
from .description import ArmDescription
from .drive_integrator import DriveArrays
from .errors import SimulationError
from .exudyn_chain import ExudynChain, exudyn
from .mechanics import MECH_PREFIXES, chain_arrays, drive_array, gravity_of, init_states, tool_point, vec
from .opspace import OpspaceController
from .output_row import output_row
from .run_world import RunWorld
from .sensors import sensor_row
from .set_points import SetPoints
from .step import CompiledStep, StepArrays, StepKernel, gravity_feedforward


class Simulation:
    """One run of a model in Exudyn; the simulator node drives it chunk by chunk.

    `package` is the model (a `ModelPackage`); `values` a full, checked value set (`check_values`)."""

    def __init__(self, package: ArmDescription, values: dict[str, float]) -> None:
        self.package = package
        self.n = package.n
        self.values = dict(values)
        self._desc = package.describe()
        self.columns, self.units = self._desc.run_columns()
        self.P = drive_array(self.n, self.values)
        self._mech = chain_arrays(package.spec, self.values)
        self._gravity = gravity_of(self.values)  # changed in place: the step's argument tuples hold it
        self.q0 = np.zeros(self.n)
        self.qd0 = np.zeros(self.n)
        #: what the drives follow (a joint path, a sampled reference, forces, live inputs)
        self.set_points = SetPoints(self._desc.links, self.P)
        self._rest()
        self._control = ("joint_independent", 0.001)  # the built-in control system and its period
        self._opspace: OpspaceController | None = None
        self._no_control = OpspaceController.idle(self.n)  # what the step kernel is handed without one
        #: what happens during a run: (t, parameter changes, grasp: an object's name, '' a release, None
        #: neither), in time order
        self._events: list[tuple[float, dict[str, float], str | None]] = []
        self._pending_events: list[tuple[float, dict[str, float], str | None]] = []
        self._run_values: dict[str, float] | None = None  # the values a run started with
        self._solver: Any = None
        self._running = False
        self._stop_time = 0.0
        self._time = 0.0
        self.timing = {"mechanics+drive": 0.0, "drive": 0.0, "output": 0.0}
        self._Rrpy = np.array([rot_rpy(lk.rpy) for lk in package.spec.links])
        self._tool_loc = np.zeros(3)
        self._rows = np.zeros((0, len(self.columns)))
        self._nrows = 0
        self._k_next = 0
        self._t_next = 0.0
        self._world = RunWorld(package.spec, self._desc.obstacles)
        self._contact_tables()
        self._chain = ExudynChain(self._mech, self._tool_local(), self._gravity, self._prestep)
        self._mbs: Any = self._chain.mbs  # the hot path reads these two on every step
        self._kt = self._chain.kt
        self._step_args: tuple[StepArrays, int] | None = None
        self._compiled_step = CompiledStep()
        self._step_kernel: StepKernel | None = None  # once checked in a solver call
        self._period_hook: tuple[int, Callable[[], None]] | None = None  # (solver steps, hook)
        self._hooked_k = -1  # the last step index the hook was called at
        self._hook_error: Exception | None = None  # what it raised in the solver's call

    def _tool_local(self) -> np.ndarray:
        return tool_point(self.package.spec, self.values)

    @property
    def gravity(self) -> np.ndarray:
        """m/s^2 in world axes (the `gravity.*` parameters)."""
        return self._gravity.copy()

    def _rest(self) -> None:
        """The drive states and held set points of the arm at rest at q0, its gears carrying gravity."""
        self.X, hold = init_states(self.P, self.q0, self.holding_torques(self.q0))
        self.set_points.hold_at(hold)

    def _update_mechanics(self) -> None:
        self._mech = chain_arrays(self.package.spec, self.values, self._world.carried())
        self._chain.update(self._mech, self._tool_local())
        self._contact_tables()

    def _contact_tables(self) -> None:
        """The world's contact tables at the values now, and what the step reads of them."""
        self._contact = self._world.build_tables(self.values)
        self._touching = self._world.obstacle_table.shape[0] > 0

    def set_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        """What the arm can touch in the runs that follow (the model's own obstacles until then)."""
        self._world.set_obstacles(obstacles)
        if self._running:
            self._finalize()
        self._reset_world()

    @property
    def obstacles(self) -> list[Obstacle]:
        return self._world.obstacles

    @property
    def world(self) -> list[Obstacle]:
        """The run's obstacles now: those of `obstacles`, a released object where the tool left it."""
        return self._world.objects

    def take_notices(self) -> list[str]:
        """What the run has to tell its user since the last call (a grasp that missed its object)."""
        return self._world.take_notices()

    def _reset_world(self, rebuild: bool = False) -> None:
        """The world of the coming run (the obstacles as set, nothing held, the run's grasps known); the
        chain rebuilt when something was held (or `rebuild`: the values changed), else only the contact
        tables."""
        if self._world.reset({name for _t, _c, name in self._events if name}) or rebuild:
            self._update_mechanics()
        else:
            self._contact_tables()

    # ---- API ----
    def set_values(self, values: Mapping[str, float]) -> None:
        """Change parameters between runs, in place (drive array, Exudyn item parameters): a new
        value set never rebuilds the system. All or nothing: ParameterError leaves every value as is."""
        if self._running:
            self._finalize()  # parameters change between runs: a run in progress ends here
        merged = dict(self.values)
        merged.update(values)
        full = self.package.check_values(merged)
        mech_changed = any(full[k] != self.values[k] for k in full if k.startswith(MECH_PREFIXES))
        self.values = full
        self.P[:] = drive_array(self.n, full)  # in place: no rebuild
        if mech_changed:
            self._update_mechanics()  # Exudyn item parameters: no rebuild either
        gravity = gravity_of(full)
        if not np.array_equal(gravity, self._gravity):
            self._gravity[:] = gravity
            self._chain.set_gravity(gravity)
        self._rest()

    def set_initial(self, q: Sequence[float] | np.ndarray, qd: Sequence[float] | None = None) -> None:
        """Joint positions at rest -> every internal state; `qd` (extension) is for drives-off studies."""
        qv = np.asarray(q, dtype=float)
        if qv.shape != (self.n,) or not np.all(np.isfinite(qv)):
            raise ValueError(f"expected {self.n} finite joint positions")
        for i, lk in enumerate(self._desc.links):
            if not lk.joint_min - 1e-12 <= qv[i] <= lk.joint_max + 1e-12:
                raise ValueError(f"{lk.joint}: {qv[i]:g} rad outside [{lk.joint_min:g}, {lk.joint_max:g}]")
        self.q0 = qv.copy()
        self.qd0 = np.zeros(self.n) if qd is None else vec(qd).copy()
        self._rest()

    def set_joint_path(self, nodes: Sequence[tuple[Sequence[float], float, float]]) -> None:
        """The path of the next run (or, during a run, from now on): every node (destination in rad,
        speed %, acceleration %) is reached and stopped at. Checked here, so a bad node fails early."""
        self.set_points.follow_path(nodes, self._time if self._running else None)
        self._events = []

    def set_reference(
        self,
        tab: np.ndarray,
        jmode: np.ndarray,
        events: Sequence[tuple[float, Mapping[str, float]]] = (),
        grasps: Sequence[tuple[float, str]] = (),
    ) -> None:
        """The next run follows a sampled reference (rows [t, r, rd], references.ref_eval) with each joint in
        its mode (references.JM_*), applies `events` (parameter changes, e.g. a payload) at their times and
        takes (a name) or releases ('') an obstacle at the times of `grasps`. The planner (planner.py)
        makes these from a robot command; it has checked them."""
        for _t, changes in events:
            self.package.check_values({**self.values, **changes})
            if any(not k.startswith("payload.") for k in changes):
                raise ValueError("only payload.* parameters change during a run")
        names = self._world.names
        for _t, name in grasps:
            if name and name not in names:
                raise ValueError(f"grasp: no obstacle named {name}")
        self.set_points.follow_reference(tab, jmode)
        timed: list[tuple[float, dict[str, float], str | None]] = [
            (float(t), dict(c), None) for t, c in events
        ]
        timed += [(float(t), {}, name) for t, name in grasps]
        self._events = sorted(timed, key=lambda e: e[0])  # stable: the plan's order at one time

    def jog(self, rates: np.ndarray, horizon: float) -> np.ndarray:
        """Move the set points at `rates` (rad/s per joint) from now on, on top of the command (live
        jogging): SetPoints.jog. Returns the rates applied."""
        return self.set_points.jog(rates, horizon, self._time)

    def set_control(self, system: str, period: float) -> None:
        """The built-in control system of the runs that follow (mesh.protocol.model.CONTROL_SYSTEMS), updated
        every `period` s (a whole number of solver steps: checked at start)."""
        if system not in CONTROL_SYSTEMS:
            raise ValueError(
                f"settings.control_system: {system!r} is not one of {', '.join(CONTROL_SYSTEMS)}"
            )
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"settings.control_period: {period!r} s is not a positive time")
        self._control = (system, float(period))

    def set_period_hook(self, steps: int, hook: Callable[[], None] | None) -> None:
        """Call `hook()` at the start of every `steps`-th solver step (0, steps, 2 steps, ...), before
        that step's output row and drives, with `time` and `sensors()` at that step; None: no hook.
        A controller in the loop exchanges its period there, inside one solver call for a whole chunk:
        one call per period cost more than the period's own steps. The call does not stop for the
        hook: what it raises, `advance` raises once the call has ended (the hook is not called again
        in that call), and a hook that has nothing more to do returns at once."""
        if hook is not None and steps < 1:
            raise ValueError(f"a period hook needs at least one solver step per period, not {steps}")
        self._period_hook = None if hook is None else (int(steps), hook)

    def _call_hook(self, ts: float) -> None:
        """The period hook at the step starting at ts, when a period starts there and it was not
        called there yet."""
        assert self._period_hook is not None
        steps, hook = self._period_hook
        k = round(ts / self.h)
        if k <= self._hooked_k or k % steps or self._hook_error is not None:
            return
        self._hooked_k = k
        self._time = k * self.h  # what the hook reads (`time`, `sensors()`): the step's start, on the grid
        try:
            hook()
        except Exception as exc:  # raised by advance() once out of the solver's call
            self._hook_error = exc

    def _period_starts(self, t: float) -> bool:
        """Whether the period hook is due at the step starting at t."""
        return self._period_hook is not None and round(t / self.h) % self._period_hook[0] == 0

    def _raise_hook_error(self) -> None:
        error, self._hook_error = self._hook_error, None
        if error is not None:
            raise error

    def sensors(self, out: np.ndarray) -> None:
        """What an external controller reads now into `out` (models/sensors.py, mesh/protocol/hil.py)."""
        sd = self._sd
        ok = sensor_row(
            self.P,
            self.set_points.arrays(),
            self.X,
            np.asarray(sd.GetODE2Coordinates()),
            np.asarray(sd.GetODE2Coordinates_t()),
            self._time,
            out,
        )
        if not ok:
            raise SimulationError(f"a sensor value is not finite at t = {self._time:.6f} s")

    def start(
        self, stop_time: float, output_interval: float, step: float | None = None, substeps: int | None = None
    ) -> None:
        """Begin a run at t = 0 from the initial state; `step` = Exudyn mechanics step (None: model default),
        `substeps` = drive RK4 substeps per mechanics step (None: model default)."""
        exu = exudyn()
        h = float(step) if step is not None else self.package.spec.default_step
        if not (math.isfinite(stop_time) and stop_time > 0):
            raise ValueError("stop_time must be > 0")
        if not (1e-6 <= h <= 0.01):
            raise ValueError("step must be in [1e-6, 0.01] s")
        if not (math.isfinite(output_interval) and output_interval > 0):
            raise ValueError("output_interval must be > 0")
        if self._running:
            self._finalize()
        values_changed = self._run_values is not None and self._run_values != self.values
        if values_changed:
            self.values = dict(self._run_values or {})  # undo the previous run's events
        self._reset_world(rebuild=values_changed)
        self._run_values = dict(self.values)
        self._pending_events = list(self._events)
        self._opspace = self._make_opspace(h)
        self.set_points.start_run(self._opspace is not None)
        self.h = h
        self.k_out = max(1, int(round(output_interval / h)))
        self.dt_out = self.k_out * h
        self._stop_time = float(stop_time)
        self.n_steps = int(math.ceil(stop_time / h - 1e-9))
        self.nsub = int(substeps) if substeps else self.package.spec.substeps
        ss = exu.SimulationSettings()
        ss.timeIntegration.numberOfSteps = self.n_steps
        ss.timeIntegration.endTime = self.n_steps * h
        ss.timeIntegration.startTime = 0.0
        ss.timeIntegration.solverType = exu.DynamicSolverType.RK44
        # the mass matrix solved by Eigen's dense LU at every stage: 0.4 us a step less than Exudyn's own
        ss.linearSolver.solverType = exu.LinearSolverType.EigenDense
        # fixed steps: Exudyn takes t = startTime + i*h instead of summing (and clipping) the steps, so
        # every step is exactly h, wherever a chunk ends; advance() sets startTime per chunk
        ss.timeIntegration.adaptiveStep = False
        ss.timeIntegration.verboseMode = 0
        ss.timeIntegration.explicit.computeEndOfStepAccelerations = False
        ss.solution.file.write = False
        ss.solution.sensors.writePeriod = 1e9
        self._ss = ss
        mbs = self._mbs
        mbs.SetObjectParameter(self._kt, "jointForceVector", [0.0] * self.n)
        mbs.systemData.SetODE2Coordinates(list(self.q0), configuration=exu.ConfigurationType.Initial)
        mbs.systemData.SetODE2Coordinates_t(list(self.qd0), configuration=exu.ConfigurationType.Initial)
        self._rest()
        self._Xbak = self.X.copy()
        self._last_k = -1
        self._tau = np.zeros(self.n)
        self._f_tool = np.zeros(3)
        self._world.caps[:] = 0.0
        self._work = np.zeros((5, self.n, dr.NL))
        self._fail: str | None = None
        self._drives_on = self.values["drives.enabled"] > 0.5
        self._mech_arrays = self._mech
        self._tool_loc = self._tool_local()
        self._solver = exu.MainSolverExplicit()
        self._solver.InitializeSolver(mbs, ss)
        self._it = self._solver.it
        self._sd = mbs.systemData
        self._running = True
        self._time = 0.0
        self._hooked_k = -1
        self._hook_error = None
        self._k_next = 0  # index of the next output sample; its time is _t_next
        self._t_next = 0.0
        self.timing = {"mechanics+drive": 0.0, "drive": 0.0, "output": 0.0}

    def _make_opspace(self, h: float) -> OpspaceController | None:
        """The operational-space controller of the coming run, or None under joint-independent control."""
        system, period = self._control
        sp = self.set_points
        pushing = bool(np.any(sp.forces[:, 4] > 0))
        if pushing and system != "opspace_hybrid":
            raise ValueError(f"settings.control_system: the command sets forces: {system} cannot follow them")
        if system == "joint_independent":
            return None
        k = round(period / h)
        if k < 1 or abs(period / h - k) > 1e-6:
            raise ValueError(
                f"settings.control_period: {period:g} s is not a whole number of solver steps ({h:g} s)"
            )
        if np.any((sp.jmode == references.JM_SPEED) | (sp.jmode == references.JM_CURRENT)):
            raise ValueError(
                f"settings.control_system: {system} tracks positions; this command sets joint speeds or "
                "currents directly (run it under joint_independent)"
            )
        if sp.external.any():
            raise ValueError(f"settings.control_system: {system} is built in: it needs controller builtin")
        return OpspaceController(self.values, self.n, k, h, sp.forces if pushing else np.zeros((0, 5)))

    def _prestep(self, mbs: Any, t: float) -> bool:
        """Once per mechanics step, before it: the output row at the step start when one is due, then
        the drives over the step. Exudyn passes the time at the END of the coming step."""
        h = self._it.currentStepSize
        ts = t - h  # the step start: the chain state and the drive states are those of ts
        if self._period_hook is not None:
            self._call_hook(ts)
        due = ts >= self._t_next - 0.5 * self.h
        if not (due or self._drives_on or self._touching):
            return True
        t0 = _time.perf_counter()
        out0 = self.timing["output"]
        sd = self._sd
        q = sd.GetODE2Coordinates()
        qd = sd.GetODE2Coordinates_t()
        if due:
            if ts > self._t_next + 0.5 * self.h:
                self._fail = f"output sample at t = {self._t_next:.6f} s missed (step at {ts:.6f} s)"
                return False
            if not self._emit_row(q, qd):
                return False
        m = self._mech_arrays
        if not self._drives_on:  # nothing acts on the joints but the contacts
            if self._touching:
                contact_prestep(m, self._gravity, self._contact, q, qd, h, self.nsub, self._tau)
                mbs.SetObjectParameter(self._kt, "jointForceVector", self._tau)
            return True
        k = round(ts / self.h)  # the step index: the drive time comes from the grid, not from a sum
        repeat = k <= self._last_k  # the same step again (a step reduction): restore the drive states
        self._last_k = k
        assert self._step_args is not None  # taken before each solver call
        (drives, sp, chain, gravity, ctl, tables), control_steps = self._step_args
        control_due = control_steps > 0 and not repeat and k % control_steps == 0  # a period starts
        args = (drives, sp, chain, gravity, ctl, tables, q, qd, k * self.h, h, self.nsub, repeat, control_due)
        if self._step_kernel is None:  # a solver call's first step: its arguments' types are checked
            self._step_kernel = self._compiled_step.for_args(args)
        status = self._step_kernel(*args)
        if status == drive_integrator.STEP_NOT_FINITE:
            bad = [j + 1 for j in range(self.n) if not np.all(np.isfinite(self.X[j, : dr.NS]))]
            self._fail = (
                f"the drive integration broke down: drive states of joint(s) {bad or '?'} not finite at "
                f"t = {ts:.6f} s: take a smaller step (settings.step)"
            )
            return False
        if status == drive_integrator.STEP_FRICTION:
            self._fail = self._friction_failure(ts)
            return False
        mbs.SetObjectParameter(self._kt, "jointForceVector", self._tau)
        self.timing["drive"] += _time.perf_counter() - t0 - (self.timing["output"] - out0)
        return True

    def _step_arguments(self) -> tuple[StepArrays, int]:
        """What `step.chain_step` reads besides the step's own values, and the solver steps per control
        period (0: no controller). Taken once per solver call: each step saves the lookups."""
        ctl = self._opspace or self._no_control
        arrays = (
            DriveArrays(self.P, self.X, self._Xbak, self._tau, self._work),
            self.set_points.arrays(),
            self._mech_arrays,
            self._gravity,
            ctl.arrays(self._Rrpy[-1], self._tool_loc, self._f_tool),
            self._contact,
        )
        return arrays, ctl.steps if self._opspace is not None else 0

    def _friction_failure(self, ts: float) -> str:
        """Why a step left the friction model's accuracy: wrong numbers are not returned as results."""
        bad = [
            j for j in range(self.n) if abs(self.X[j, dr.S_Z]) > drive_integrator.friction_bound(self.P, j)
        ]
        j = bad[0] if bad else 0
        return (
            f"the drive integration broke down at t = {ts:.6f} s: joint{j + 1}'s friction state left its "
            f"physical bound (motor speed {self.X[j, dr.S_OM]:.1f} rad/s, step {self.h:g} s with up to "
            f"{drive_integrator.MAX_SUBSTEP_FACTOR * self.nsub} drive substeps, "
            f"gear.sigma0 = {self.P[j, dr.P_S0]:g}): "
            "take a smaller step (settings.step) or a softer gear.sigma0"
        )

    def _emit_row(self, q: np.ndarray, qd: np.ndarray) -> bool:
        """The output row of sample `_k_next` (time `_t_next`) from the chain state q, qd and the drive
        states into the chunk buffer; False (with `_fail` set) when something is not finite."""
        t0 = _time.perf_counter()
        t = self._t_next
        k = self._nrows
        if k >= self._rows.shape[0]:  # never with the size advance() reserves; kept safe anyway
            self._rows = np.concatenate([self._rows, np.empty((k + 8, self._rows.shape[1]))])
        status = output_row(
            self.P,
            self.set_points.arrays(),
            self.X,
            q,
            qd,
            t,
            self._mech_arrays,
            self._Rrpy,
            self._tool_loc,
            self._contact,
            self._world.grasp_state,
            self._rows,
            k,
        )
        if status:
            if status == 1:
                bad = [j + 1 for j in range(self.n) if not (math.isfinite(q[j]) and math.isfinite(qd[j]))]
                self._fail = f"chain coordinates of joint(s) {bad} not finite at t = {t:.6f} s"
            else:
                self._fail = f"non-finite output at t = {t:.6f} s"
            return False
        self._nrows = k + 1
        self._k_next += 1
        self._t_next = min(self._k_next * self.dt_out, self.n_steps * self.h)
        self.timing["output"] += _time.perf_counter() - t0
        return True

    def _row_now(self) -> None:
        """The due output row from the current chain state (between solver calls)."""
        sd = self._sd
        if not self._emit_row(sd.GetODE2Coordinates(), sd.GetODE2Coordinates_t()):
            raise SimulationError(self._fail)

    def _sensor_poses(self) -> np.ndarray:
        """Link and tool poses now, read from the Exudyn sensors: the cross-check of
        `chain_dynamics.pose_rows`."""
        return self._chain.sensor_poses(self._Rrpy)

    def advance(self, until: float) -> np.ndarray:
        """Simulate up to `until` (on the step grid); the output rows with time in (previous until, until],
        the t = 0 row on the first call. A parameter event due on the way (a payload change) splits the
        chunk: the chain changes on the step grid point at or just before its time. With a period hook,
        a row at `until` where a period starts comes with the next call, after that period's hook (it
        shows what the hook set, whatever the calls; and the hook's exchange waits for the caller's
        next call, as a call per period did)."""
        if not self._running:
            raise SimulationError("advance() before start()")
        parts = []
        while self._pending_events and self._pending_events[0][0] <= float(until) and not self.finished:
            t_event, changes, name = self._pending_events.pop(0)
            if t_event > self._time + 0.5 * self.h or self._k_next == 0:
                parts.append(self._advance_chunk(t_event))
            self.values.update(changes)
            if name is not None:
                self._grasp(name)
            self._update_mechanics()
            self._mech_arrays = self._mech
            if self._opspace is not None:
                self._opspace.forget()
        parts.append(self._advance_chunk(until))
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _grasp(self, name: str) -> None:
        """Take obstacle `name` ('': release what the tool holds) at the pose the arm has now. A grasp
        whose object is out of the tool's reach (the arm did not get there) takes nothing: the user
        is told."""
        q = np.asarray(self._sd.GetODE2Coordinates(), dtype=float)
        R_all, p_all = np.empty((self.n, 3, 3)), np.empty((self.n, 3))
        chain_dynamics.chain_frames(self._mech.pre_R, self._mech.pre_p, q, R_all, p_all)
        R, p = R_all[-1], p_all[-1]
        self._world.grasp(name, R, p, p + R @ self._tool_loc, self._time)

    def _advance_chunk(self, until: float) -> np.ndarray:
        """One solver call up to `until`: the rows inside the chunk are taken in the PreStep at the
        start of the step that begins at their time."""
        t_wall = _time.perf_counter()
        out_before = self.timing["output"]
        h = self.h
        t_end = self.n_steps * h
        until = float(until)
        if until >= self._stop_time - 1e-12:
            until = t_end  # the run ends on the step grid, at or just after stop_time
        until = min(until, t_end)
        n_max = int(max(until - self._time, 0.0) / self.dt_out) + 3
        self._rows = np.empty((n_max, len(self.columns)))
        self._nrows = 0
        if self._period_hook is not None and self._k_next == 0:
            self._call_hook(0.0)
            self._raise_hook_error()
        if self._k_next == 0:
            # the t = 0 row's currents with the feed-forward of the first step
            gravity_feedforward(self.P, self.set_points.arrays(), self._mech_arrays, self._gravity, 0.0)
            self._row_now()  # t = 0
        # the chunk ends on the last grid point within `until`; at an output sample, exactly on its time
        t_mid = math.floor(until / h + 1e-9) * h
        t_row = t_end if t_mid > t_end - 0.5 * h else round(t_mid / self.dt_out) * self.dt_out
        row_end = abs(t_row - t_mid) < 0.5 * h and t_row > self._time + 0.5 * h
        if row_end and self._period_starts(t_row) and t_row < t_end - 0.5 * h:
            row_end = False  # the row after the period's hook, in the next call: see advance()
        t_stop = t_row if row_end else t_mid
        if t_stop > self._time + 0.5 * h:
            self._it.startTime = self._time
            self._it.endTime = t_stop
            self._step_args = self._step_arguments()
            self._step_kernel = None  # checked against the types of the new arguments at the first step
            try:
                self._solver.SolveSteps(self._mbs, self._ss)
            except Exception as e:  # the solver's own errors
                raise SimulationError(f"Exudyn solver failed before t = {t_stop:.6f} s: {e}") from e
            if self._fail:
                raise SimulationError(self._fail)
            t_now = self._sd.GetTime()
            if t_now < t_stop - 1e-9:
                raise SimulationError(f"Exudyn stopped at t = {t_now:.6f} s before {t_stop:.6f} s")
            self._time = t_stop  # the grid time (Exudyn's startTime + i*h may differ by rounding)
            if row_end:
                if abs(self._t_next - t_stop) > 0.5 * h:
                    raise SimulationError(f"output sample at t = {self._t_next:.6f} s missed")
                self._row_now()
            self._raise_hook_error()
        out = self._rows[: self._nrows]
        wall = _time.perf_counter() - t_wall
        self.timing["mechanics+drive"] += wall - (self.timing["output"] - out_before)
        return out

    @property
    def time(self) -> float:
        """Simulated time reached by the last `advance` (on the step grid)."""
        return self._time

    @property
    def finished(self) -> bool:
        """The run reached its stop time (on the step grid): no more rows will come."""
        return self._running and self._time >= self.n_steps * self.h - 1e-9

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Chain coordinates (q, qd) now."""
        mbs = self._mbs
        return np.array(mbs.systemData.GetODE2Coordinates()), np.array(mbs.systemData.GetODE2Coordinates_t())

    def mass_matrix(self, q: Sequence[float]) -> np.ndarray:
        """M(q) of the chain as the drive kernel sees it (energy checks, controller tuning)."""
        M = np.zeros((self.n, self.n))
        chain_dynamics.mass_matrix(self._mech, vec(q), M)
        return M

    def holding_torques(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        """g(q): the joint torques that hold the arm still at q against gravity (N m)."""
        out = np.zeros(self.n)
        gravity_torques(self._mech, self._gravity, vec(q), out)
        return out

    def _finalize(self) -> None:
        if self._solver is not None and self._running:
            try:
                self._solver.FinalizeSolver(self._mbs, self._ss)
            except Exception:
                pass
        self._running = False

    def close(self) -> None:
        """End the run and free the Exudyn system; the simulation cannot be used afterwards."""
        self._finalize()
        self._solver = None
        self._mbs = None
        self._chain.close()
