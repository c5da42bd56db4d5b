"""`simecs replay FILE [--speed K] [--session ID]`: a recording republished onto the mesh as a session.

A client watches it exactly like a live run: the replay publishes the session's state (latched:
running / paused / finished, progress), the run's layout (latched), the parameter values (latched,
so the 3D arm has the recorded link lengths) and the recorded full-rate frames, unchanged, at the
recorded pace times `speed` (the hot-feedback node decimates them to `vars/live` as for any run).
It obeys `RunControl` on the session's `control` key (pause, resume, abort, seek to a time) and
answers the session's `cmd` key for get_session, pause, resume, abort and close_session, and its
`results` keys with the whole recording. After the end it stays `--linger` seconds so a viewer can
seek back, then exits. Its node id is `replay-<session>`, which tells the recorder not to re-record it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from simecs.mesh import codec, frames, keys
from simecs.mesh import messages as m
from simecs.mesh.results import results_reply
from simecs.mesh.runtime import Binary, Node, Request, RequestError, main_for, mesh_from_args

from . import mcapfmt as fmt
from . import mcapread

STATE_PERIOD_S = 0.1  # at most 10 progress reports per wall second
LAYOUT_LEAD_S = 0.3  # between the layout and the first frame


class Replay(Node):
    """Republishes one recording as a session, paced, with pause, resume, abort and seek."""

    role = "replay"
    tick_s = 0.2

    def __init__(
        self,
        mesh: Any,
        recording: mcapread.Recording,
        session: str = "",
        speed: float = 1.0,
        paused: bool = False,
        linger_s: float = 600.0,
        node_id: str | None = None,
    ) -> None:
        self.sid = session or keys.new_session_id()
        if not keys.is_session_id(self.sid):
            raise ValueError(f"--session {session!r} is not a session id (22 URL-safe characters)")
        super().__init__(mesh, node_id or f"replay-{self.sid}")
        if not 0.0 <= speed <= 1000.0:
            raise ValueError(f"--speed {speed} is outside [0, 1000] (0 = as fast as possible)")
        self.rec = recording
        self.speed = speed
        self.linger_s = linger_s
        self.layout = m.RunLayout(**{**vars(recording.layout), "session": self.sid, "source": "replay"})
        self.run_id = self.layout.run_id
        self.frames = list(recording.frames())
        self.rows = recording.rows
        self.stop_time = self.layout.stop_time or (float(self.rows[-1, 0]) if len(self.rows) else 0.0)
        self.cv = threading.Condition()
        self.paused = paused
        self.aborted = False
        self.closing = False
        self.halt = False  # the process is exiting: stop playing, publish nothing more
        self.seek_to: float | None = None
        self.phase = "paused" if paused else "running"
        self.sim_time = float(self.rows[0, 0]) if len(self.rows) else 0.0
        self.position = 0  # index into self.frames of the next frame to publish
        self.seq = 0
        self.published_frames = 0
        self.state_seq = 0
        self.rtf = 0.0
        self.ended_at: float | None = None

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("file", help="MCAP recording to replay")
        parser.add_argument(
            "--speed", type=float, default=1.0, help="times real time (default 1; 0 = as fast as possible)"
        )
        parser.add_argument("--session", default="", help="session id to publish under (default: a new one)")
        parser.add_argument("--paused", action="store_true", help="start paused (resume with a RunControl)")
        parser.add_argument(
            "--linger", type=float, default=600.0, help="seconds to stay after the end (for seeks)"
        )

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Replay:
        path = Path(args.file)
        if not path.is_file():
            raise SystemExit(f"simecs replay: {path}: no such file")
        try:
            rec = mcapread.load(path)
        except mcapread.RecordingError as exc:
            raise SystemExit(f"simecs replay: {exc}") from None
        if not rec.complete:
            print(
                f"simecs replay: {path} is incomplete ({rec.problem}); replaying what is readable",
                file=sys.stderr,
            )
        if len(rec.rows) == 0:
            raise SystemExit(f"simecs replay: {path}: the recording holds no samples")
        return cls(
            mesh_from_args(args), rec, args.session, args.speed, args.paused, args.linger, args.node_id
        )

    def status_detail(self) -> dict[str, Any]:
        return {
            "session": self.sid,
            "file": self.rec.path,
            "phase": self.phase,
            "sim_time": self.sim_time,
        }

    # -- startup -----------------------------------------------------------------------------------
    def start(self) -> None:
        s = self.sid
        self.state_pub = self.publisher(keys.state(s), latched=True)
        self.layout_pub = self.publisher(keys.layout(s), latched=True)
        self.params_pub = self.publisher(keys.params(s), latched=True)
        self.full_pub = self.publisher(keys.vars_full(s), congestion_control=zenoh.CongestionControl.BLOCK)
        params = self.rec.params()
        self.params_pub.put(codec.dumps(m.ParamValues(s, self.layout.model_id, params)))
        self.layout_pub.put(codec.dumps(self.layout))
        self.publish_state()
        self.subscribe(keys.control(s), self._on_control, maxlen=256)
        self.serve(keys.cmd(s), self._on_cmd)
        self.serve(keys.results(s), self._on_results_list)
        self.serve(f"{keys.results(s)}/*", self._on_results)
        self.log.info(
            "replaying %s as session %s at %s (%d samples, %d frames)",
            self.rec.path,
            s,
            "full speed" if self.speed == 0 else f"{self.speed:g}x",
            len(self.rows),
            len(self.frames),
        )
        print(f"replaying {self.rec.path} as session {s}", flush=True)
        self._player = threading.Thread(target=self._play, name="replay-player", daemon=True)
        self._player.start()

    def publish_state(self) -> None:
        self.state_seq += 1
        progress = min(1.0, max(0.0, self.sim_time / self.stop_time)) if self.stop_time > 0 else 0.0
        st = m.SessionState(
            session=self.sid,
            phase=self.phase,  # type: ignore[arg-type]
            seq=self.state_seq,
            run_id=self.run_id,
            progress=progress,
            sim_time=self.sim_time,
            rtf=self.rtf,
        )
        self.state_pub.put(codec.dumps(st))

    # -- control -----------------------------------------------------------------------------------
    def _on_control(self, sample: zenoh.Sample) -> None:
        try:
            ctl = codec.loads(m.RunControl, sample.payload.to_bytes())
        except codec.DecodeError as exc:
            self.log.warning("bad control message: %s", exc)
            return
        if ctl.run_id not in ("", self.run_id):
            return
        self.control(ctl.op, ctl.time)

    def control(self, op: str, at: float = 0.0) -> None:
        with self.cv:
            if op == "pause":
                self.paused = True
            elif op == "resume":
                self.paused = False
            elif op == "abort":
                self.aborted = True
            elif op == "seek":
                if not math.isfinite(at):
                    raise RequestError("bad_request", "seek time must be a finite number", "time")
                self.seek_to = float(at)
            self.cv.notify_all()

    def _on_cmd(self, req: Request) -> Any:
        cmd = req.json(m.Command)
        if isinstance(cmd, m.GetSession):
            return self.snapshot()
        if isinstance(cmd, m.Pause | m.Resume | m.Abort):
            wanted = {
                "pause": ("running",),
                "resume": ("paused",),
                "abort": ("running", "paused", "finished"),
            }
            if self.phase not in wanted[cmd.op]:
                raise RequestError("conflict", f"cannot {cmd.op}: the replay is {self.phase}")
            self.control(cmd.op)
            return self.run_id
        if isinstance(cmd, m.CloseSession):
            with self.cv:
                self.closing = True
                self.aborted = True
                self.cv.notify_all()
            return self.sid
        raise RequestError(
            "unsupported",
            f"a replay session accepts get_session, pause, resume, abort, close_session (and RunControl "
            f"seek on its control key), not {cmd.op}",
            "op",
        )

    def snapshot(self) -> m.SessionSnapshot:
        meta = self.rec.metadata.get(fmt.META_SESSION, {})
        command: Any = None
        settings = m.RunSettings(
            stop_time=min(max(self.stop_time, 1e-3), 3600.0),
            output_interval=min(max(self.layout.output_interval, 1e-4), max(self.stop_time, 1e-3)),
        )
        initial: list[float] = []
        try:
            if meta.get("command") not in (None, "null"):
                command = codec.from_obj(m.RobotCommand, json.loads(meta["command"]))  # type: ignore[arg-type]
            if meta.get("settings"):
                settings = codec.from_obj(m.RunSettings, json.loads(meta["settings"]))
            initial = [float(q) for q in json.loads(meta.get("initial", "[]"))]
        except (ValueError, codec.DecodeError) as exc:
            self.log.warning("recorded session metadata unreadable (%s): snapshot without it", exc)
        state = m.SessionState(
            session=self.sid,
            phase=self.phase,  # type: ignore[arg-type]
            seq=self.state_seq,
            run_id=self.run_id,
            progress=min(1.0, self.sim_time / self.stop_time) if self.stop_time > 0 else 0.0,
            sim_time=self.sim_time,
            rtf=self.rtf,
        )
        run = m.RunInfo(self.run_id, state.phase, self.stop_time, self.sim_time, len(self.rows))
        return m.SessionSnapshot(
            session=self.sid,
            user=meta.get("user", "replay") or "replay",
            model_id=self.layout.model_id,
            values=self.rec.params(),
            initial=initial,
            command=command,
            settings=settings,
            state=state,
            runs=[run],
        )

    def _on_results_list(self, req: Request) -> list[m.RunInfo]:
        return self.snapshot().runs

    def _on_results(self, req: Request) -> Binary:
        """Full-resolution transients, as the simulator serves them (vars, t0, t1, every)."""
        run_id = keys.last_chunk(req.key)
        if run_id != self.run_id:
            raise RequestError("not_found", f"replay session {self.sid} has only run {self.run_id}", "run_id")
        return results_reply(
            self.rows, self.layout.columns, self.layout.units, req.parameters, self.layout.run_index
        )

    # -- the player ----------------------------------------------------------------------------------
    def _frame_at(self, t: float) -> int:
        """Index of the first frame that holds a sample at or after time `t`."""
        row = int(np.searchsorted(self.rows[:, 0], t, side="left"))
        for i, (_seq, _a, b) in enumerate(self.frames):
            if b > row:
                return i
        return len(self.frames)

    def _publish(self, index: int, final: bool) -> None:
        _seq, a, b = self.frames[index]
        flags = frames.FLAG_FINAL if final else 0
        frame = frames.Frame(self.layout.run_index, self.seq, time.time_ns(), self.rows[a:b], flags)
        self.full_pub.put(frames.encode(frame))
        self.seq += 1
        self.published_frames += 1

    def _set_phase(self, phase: str) -> None:
        if phase != self.phase:
            self.phase = phase
            self.publish_state()

    def _play(self) -> None:
        try:
            self._play_loop()
        except Exception as exc:
            self.log.error("replay failed: %s", exc)
            self.phase = "failed"
            self.publish_state()
            self.stop_event.set()

    def _play_loop(self) -> None:
        # Subscribers (hot-feedback) handle a run's layout before its frames; a real worker spends this
        # long building its model after announcing the layout.
        self.stop_event.wait(LAYOUT_LEAD_S)
        speed = self.speed
        wall0, sim0 = time.monotonic(), self.sim_time
        last_state = 0.0
        while not self.stop_event.is_set():
            with self.cv:
                if self.aborted or self.halt:
                    break
                if self.seek_to is not None:
                    target, self.seek_to = self.seek_to, None
                    self.position = self._frame_at(target)
                    self.sim_time = min(max(target, float(self.rows[0, 0])), float(self.rows[-1, 0]))
                    wall0, sim0 = time.monotonic(), self.sim_time
                    self.ended_at = None
                    self.publish_state()
                if self.paused:
                    self._set_phase("paused")
                    self.cv.wait(0.5)
                    wall0, sim0 = time.monotonic(), self.sim_time
                    continue
                if self.position >= len(self.frames):
                    if self.phase != "finished":
                        self._set_phase("finished")
                        self.ended_at = time.monotonic()
                    self.cv.wait(0.5)
                    wall0, sim0 = time.monotonic(), self.sim_time
                    continue
            if self.phase != "running":
                self._set_phase("running")
            _seq, a, b = self.frames[self.position]
            t_frame = float(self.rows[b - 1, 0])
            if speed > 0:
                due = wall0 + (t_frame - sim0) / speed
                delay = due - time.monotonic()
                if delay > 0:
                    with self.cv:
                        self.cv.wait(min(delay, 0.25))
                    continue
            last = self.position == len(self.frames) - 1
            self._publish(self.position, final=last)
            self.position += 1
            self.sim_time = t_frame
            now = time.monotonic()
            if now > wall0:
                self.rtf = (self.sim_time - sim0) / (now - wall0) if now - wall0 > 1e-3 else self.rtf
            if last or now - last_state >= STATE_PERIOD_S:
                last_state = now
                self.publish_state()
        if self.aborted and not self.halt:
            self.full_pub.put(
                frames.encode(
                    frames.Frame(
                        self.layout.run_index,
                        self.seq,
                        time.time_ns(),
                        np.empty((0, len(self.layout.columns))),
                        1,
                    )
                )
            )
            self.phase = "closed" if self.closing else "aborted"
            self.publish_state()
            time.sleep(0.2)  # let the last state leave
            self.stop_event.set()

    def tick(self) -> None:
        if (
            self.ended_at is not None
            and self.phase == "finished"
            and time.monotonic() - self.ended_at > self.linger_s
        ):
            self.log.info("replay of %s ended %g s ago: exiting", self.rec.path, self.linger_s)
            self.stop_event.set()

    def stop(self) -> None:
        with self.cv:
            self.halt = True
            self.cv.notify_all()
        player = getattr(self, "_player", None)
        if player is not None and player.is_alive() and threading.current_thread() is not player:
            player.join(timeout=2.0)


def main(argv: list[str] | None = None) -> int:
    return main_for(Replay, argv, prog="simecs replay")


if __name__ == "__main__":
    main()
