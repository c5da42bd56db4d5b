"""Where a run's samples come from: a simulation of a model, or a recording played back.

The worker drives either through the same few calls (start, advance chunk by chunk, seek, end), so a
replay is a run like any other: paced, paused, aborted, streamed and stored the same way.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process.seal import Seal
from simecs.mesh.protocol import columns
from simecs.mesh.protocol import messages as m

from .recording import mcapread


class RunSource(Protocol):
    kind: str  # "simulator" | "replay"
    model_id: str
    columns: list[str]
    units: list[str]
    stop_time: float
    output_interval: float
    context: m.RunContext

    @property
    def time(self) -> float: ...

    @property
    def finished(self) -> bool: ...

    def start(self) -> None: ...

    def advance(self, until: float) -> np.ndarray: ...

    def seek(self, t: float) -> None: ...

    def end(self) -> tuple[str, str]: ...

    def results(self, played: list[np.ndarray]) -> np.ndarray: ...

    def step_at(self, t: float) -> tuple[str, str, str]: ...

    def jog(self, msg: m.JogInput | None, horizon: float) -> str: ...

    def notices(self, rows: np.ndarray) -> list[str]: ...

    def close(self) -> None: ...


class SimulationSource:
    """A model simulated in Exudyn (models/)."""

    kind = "simulator"

    def __init__(self, req: m.RunRequest) -> None:
        from simecs import models
        from simecs.models.contact import ContactLog
        from simecs.models.planner import Planner
        from simecs.models.self_collision import SelfContactLog

        self.req = req
        self.model_id = req.model_id
        package = models.get_model(req.model_id)
        try:
            planner = Planner(
                package, req.values, req.initial, req.settings.stop_time, obstacles=req.obstacles
            )
            # Without a command (a run until stopped) the arm holds its initial pose, at rest.
            self.plan = planner.plan(req.command) if req.command is not None else None
        except models.CommandError as exc:
            field = f"command.{exc.field}" if exc.field else "command"
            raise ValueError(f"{field}: {exc.reason}") from None
        self.sim = package.build(req.values)
        self.joints = [link.joint for link in package.describe().links]
        self.columns, self.units = list(self.sim.columns), list(self.sim.units)
        self.stop_time = req.settings.stop_time
        self.output_interval = req.settings.output_interval
        self.context = m.RunContext(
            req.user,
            dict(req.values),
            list(req.initial),
            req.command,
            req.settings,
            attempt=req.attempt,
            restarted=req.restarted,
            obstacles=list(req.obstacles),
            until_stopped=req.until_stopped,
        )
        self.sim.set_obstacles(req.obstacles)
        self.contacts = ContactLog(self.columns, [ob.name for ob in req.obstacles], self.sim.n)
        q_columns = [self.columns.index(columns.joint_column(j, columns.JOINT_POSITION)) for j in self.joints]
        self.self_contacts = SelfContactLog(planner.checks.self_check, q_columns)
        self.sim.set_initial(req.initial)
        if self.plan is not None:
            self.plan.apply(self.sim)
        self.kin, self.vmax = planner.kin, planner.vmax

    @property
    def time(self) -> float:
        return float(self.sim.time)

    @property
    def finished(self) -> bool:
        return bool(self.sim.finished)

    def start(self) -> None:
        st = self.req.settings
        self.sim.set_control(st.control_system, st.control_period)
        self.sim.start(st.stop_time, st.output_interval, st.step or None)

    def advance(self, until: float) -> np.ndarray:
        return self.sim.advance(until)

    def notices(self, rows: np.ndarray) -> list[str]:
        """What the user must be told about the run's next rows (the contacts that began in them, a
        grasp that took nothing), however they were made (the source's advance, or an external
        controller's exchange)."""
        return self.sim.take_notices() + self.contacts.scan(rows) + self.self_contacts.scan(rows)

    def seek(self, t: float) -> None:
        raise ValueError("a simulation cannot seek: only replay runs can")

    def end(self) -> tuple[str, str]:
        return "finished", ""

    def results(self, played: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(played) if played else np.empty((0, len(self.columns)))

    def step_at(self, t: float) -> tuple[str, str, str]:
        """(step, task, action) of the command at simulated time t: what SessionState shows."""
        step = self.plan.step_at(t) if self.plan is not None else None
        return (step.path, step.task, step.action) if step is not None else ("", "", "")

    def jog(self, msg: m.JogInput | None, horizon: float) -> str:
        """Obey a jog (None: stop): joint speeds capped at speed_pct of traj.max_speed each, or a tool
        twist through the Jacobian's damped inverse, scaled down as a whole to keep every cap; ''
        or what is wrong with the message (the jog then stops)."""
        n = self.sim.n
        qd = np.zeros(n)
        problem = ""
        if msg is not None:
            cap = self.vmax * msg.speed_pct / 100.0
            if msg.space == "joint":
                if len(msg.qd) == n:
                    qd = np.clip(np.asarray(msg.qd, dtype=float), -cap, cap)
                else:
                    problem = f"qd has {len(msg.qd)} values for a {n}-joint arm"
            elif len(msg.twist) == 6:
                J = self.kin.jacobian(self.sim.state()[0])
                qd = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), np.asarray(msg.twist, dtype=float))
                qd /= max(1.0, float(np.max(np.abs(qd) / cap)))
            else:
                problem = f"twist has {len(msg.twist)} values, not 6 (vx, vy, vz, wx, wy, wz)"
        self.sim.jog(qd, horizon)
        return problem

    def close(self) -> None:
        self.sim.close()


class RecordingSource:
    """A recording from the server's library, played back row by row at the recorded times."""

    kind = "replay"

    def __init__(self, req: m.RunRequest, client: MeshClient) -> None:
        try:
            data = client.download_recording(req.user, req.recording, timeout=60.0)
        except RemoteError as exc:
            raise ValueError(f"recording {req.recording}: {exc.error.message}") from None
        except NoReply:
            raise ValueError(f"recording {req.recording}: no recorder on the mesh serves it") from None
        try:
            rec = mcapread.load(data)
        except mcapread.RecordingError as exc:
            raise ValueError(f"recording {req.recording}: {exc}") from None
        if rec.layout.model_id != req.model_id:
            raise ValueError(
                f"recording {req.recording} is of model {rec.layout.model_id}, the session of {req.model_id}"
            )
        if len(rec.rows) == 0:
            raise ValueError(f"recording {req.recording} holds no samples")
        problem = mcapread.playable_problem(rec)
        if problem:
            raise ValueError(f"recording {req.recording} cannot be replayed: {problem}")
        self.rec = rec
        self.model_id = rec.layout.model_id
        self.columns, self.units = list(rec.layout.columns), list(rec.layout.units)
        self.rows = rec.rows
        # A run until stopped was set its bound, not its end: its replay ends with its rows.
        last = float(self.rows[-1, 0])
        self.stop_time = last if rec.layout.context.until_stopped else rec.layout.stop_time or last
        self.output_interval = rec.layout.output_interval
        self.context = rec.context(req.recording)
        self.context.attempt, self.context.restarted = req.attempt, req.restarted
        self._next = 0  # index of the next row to play
        self._time = float(self.rows[0, 0])
        self._played_to = -1  # index of the last row played

    @property
    def time(self) -> float:
        return self._time

    @property
    def finished(self) -> bool:
        return self._next >= len(self.rows)

    def start(self) -> None:
        self._next = 0

    def advance(self, until: float) -> np.ndarray:
        """The recorded rows with time up to `until` not played yet (all that is left at the end)."""
        end = int(np.searchsorted(self.rows[:, 0], until, side="right"))
        if until >= self.stop_time:
            end = len(self.rows)
        out = self.rows[self._next : end]
        if end > self._next:
            self._time = float(self.rows[end - 1, 0])
            self._played_to = max(self._played_to, end - 1)
            self._next = end
        else:
            self._time = max(self._time, min(until, float(self.rows[-1, 0])))
        return np.asarray(out)

    def seek(self, t: float) -> None:
        self._next = int(np.searchsorted(self.rows[:, 0], t, side="left"))
        self._time = min(max(t, float(self.rows[0, 0])), float(self.rows[-1, 0]))

    def end(self) -> tuple[str, str]:
        """How the recorded run ended: a replay that plays to its end ends as the recording did."""
        end = self.rec.metadata.get("simecs.end", {})
        phase = end.get("phase", "")
        if phase in ("aborted", "failed"):
            reason = end.get("reason", "")
            return phase, f"as recorded: {reason}" if reason else "as recorded"
        if not self.rec.complete or self.rec.recovered:
            return "finished", "the recording was cut short (recovered after a crash of its recorder)"
        return "finished", ""

    def results(self, played: list[np.ndarray]) -> np.ndarray:
        """The recording up to the furthest row played (seeks may have played parts twice)."""
        return np.asarray(self.rows[: self._played_to + 1])

    def step_at(self, t: float) -> tuple[str, str, str]:
        return "", "", ""

    def jog(self, msg: m.JogInput | None, horizon: float) -> str:
        return "" if msg is None else "a replay plays its recording: it cannot be jogged"

    def notices(self, rows: np.ndarray) -> list[str]:
        return []  # the recording's own run told its user already

    def close(self) -> None:
        pass


def open_source(req: m.RunRequest, z: Any, seal: Seal) -> RunSource:
    """The source a run request asks for (a recording read from the recorder's sealed answers)."""
    if req.recording:
        return RecordingSource(req, MeshClient(z, timeout=10.0, seal=seal))
    return SimulationSource(req)
