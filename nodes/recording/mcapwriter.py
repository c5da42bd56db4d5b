"""Writing one run into one MCAP file, fast and crash-safely (the format itself is mcapfmt.py).

mcaprecords.py writes the records, chunks, indexes and summary, with bulk appends for the full-rate
`/vars` channel; `RunWriter` lays out a run: channels, metadata from the run's layout and context,
frames, /log, /scene, flushes about once a second, and a footer on close.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
from simecs.mesh.protocol import codec, frames
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.model import ModelDescription

from .mcapfmt import (
    CHUNK_SIZE,
    FORMAT_VERSION,
    LIBRARY,
    META_END,
    META_PARAMS,
    META_RUN,
    META_SESSION,
    TOPIC_JOINTS,
    TOPIC_LOG,
    TOPIC_SCENE,
    TOPIC_TF,
    TOPIC_VARS,
    VARS_SCHEMA,
    FormatError,
    JointEncoder,
    PoseEncoder,
    build_vars_codec,
    foxglove_schema,
    stamp,
    ts_json,
)
from .mcaprecords import zstd_file
from .mcapscene import WorldScene, scene_update


def layout_json(layout: m.RunLayout) -> str:
    return codec.dumps(layout).decode()


def params_metadata(context: m.RunContext) -> dict[str, str]:
    """`simecs.params`: every parameter value of the run, exactly (repr round-trips a float)."""
    return {k: repr(float(v)) for k, v in context.values.items()}


def session_metadata(context: m.RunContext) -> dict[str, str]:
    """`simecs.session`: who ran it, from where, with what command and settings (JSON texts)."""
    return {
        "user": context.user,
        "initial": json.dumps(list(context.initial)),
        "command": codec.dumps(context.command).decode(),
        "settings": codec.dumps(context.settings).decode(),
        "recording": context.recording,
    }


class RunWriter:
    """Writes one run into one MCAP file, crash-safely: zstd chunks of bounded size, `flush()` about
    once a second (the recorder calls it), an exclusive lock while open (recovery skips locked files),
    and `close()` that finishes the summary and fsyncs. Not thread-safe: one writer thread owns it."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        layout: m.RunLayout,
        *,
        time_origin_ns: int | None = None,
        viz_rate_hz: float = 50.0,
        chunk_size: int = CHUNK_SIZE,
        run_meta: Mapping[str, str] | None = None,
    ) -> None:
        self.path = Path(path)
        self.layout = layout
        self.t0 = int(time_origin_ns if time_origin_ns is not None else time.time_ns())
        self.created_ns = time.time_ns()  # when the file was begun (RecordingInfo.created)
        self.viz_period = 1.0 / viz_rate_hz if viz_rate_hz > 0 else 0.0
        self.vars = build_vars_codec(layout.columns, layout.units)
        self.poses = PoseEncoder(layout.columns)
        self.joints = JointEncoder(layout.columns)
        self.world = WorldScene(layout.columns, layout.context.obstacles, layout.model_id)
        self.messages = 0
        self.rows = 0
        self.frames = 0
        self.last_flush = time.monotonic()
        self.dirty = False
        self.closed = False
        self._next_viz = -math.inf
        self._stream: IO[bytes] = open(self.path, "xb")  # noqa: SIM115 - closed in close()/abandon()
        try:
            fcntl.flock(self._stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            self._w = zstd_file(self._stream, chunk_size)
            self._w.start(profile="", library=LIBRARY)
            meta = {
                "format_version": FORMAT_VERSION,
                "session": layout.session,
                "run_id": layout.run_id,
                "run_index": str(layout.run_index),
                "model_id": layout.model_id,
                "stop_time": repr(float(layout.stop_time)),
                "output_interval": repr(float(layout.output_interval)),
                "time_origin_ns": str(self.t0),
                "created_ns": str(self.created_ns),
                "layout": layout_json(layout),
            }
            meta.update(run_meta or {})
            self._w.add_metadata(META_RUN, meta)
            self._w.add_metadata(META_PARAMS, params_metadata(layout.context))
            self._w.add_metadata(META_SESSION, session_metadata(layout.context))
            self._register()
            self.flush(force=True)
        except BaseException:
            self._stream.close()
            raise

    def _register(self) -> None:
        w = self._w
        sid = w.register_schema(VARS_SCHEMA, "ros2msg", self.vars.schema.encode())
        self.ch_vars = w.register_channel(
            TOPIC_VARS,
            "cdr",
            sid,
            {
                "fields": json.dumps(self.vars.fields),
                "columns": json.dumps([self.vars.columns[i] for i in self.vars.order]),
                "units": json.dumps(
                    [self.layout.units[i] if i < len(self.layout.units) else "" for i in self.vars.order]
                ),
            },
        )
        self.ch_tf = self._json_channel(TOPIC_TF, "foxglove.FrameTransforms") if self.poses else 0
        self.ch_joints = self._json_channel(TOPIC_JOINTS, "foxglove.JointStates") if self.joints else 0
        self.ch_scene = self._json_channel(TOPIC_SCENE, "foxglove.SceneUpdate")
        self.ch_log = self._json_channel(TOPIC_LOG, "foxglove.Log")

    def _json_channel(self, topic: str, schema: str) -> int:
        sid = self._w.register_schema(schema, "jsonschema", foxglove_schema(schema))
        return self._w.register_channel(topic, "json", sid)

    def log_time(self, sim_time: float) -> int:
        return self.t0 + int(round(sim_time * 1e9))

    def write_frame(self, frame: frames.Frame, backfill: bool = False) -> int:
        """Append every row of a frame; returns the number of messages written. `backfill`: rows that
        fill an earlier gap (they get their own /tf and /joint_states samples; readers order by time)."""
        if backfill:
            resume_viz, self._next_viz = self._next_viz, -math.inf
            try:
                return self._write_rows(frame, backfill=True)
            finally:
                self._next_viz = resume_viz
        return self._write_rows(frame, backfill=False)

    def _write_rows(self, frame: frames.Frame, backfill: bool) -> int:
        rows = frame.rows
        if rows.ndim != 2 or (rows.shape[0] and rows.shape[1] != len(self.layout.columns)):
            raise FormatError(
                f"frame {frame.seq} has {rows.shape[-1] if rows.ndim == 2 else '?'} columns, "
                f"the layout {len(self.layout.columns)}"
            )
        n = rows.shape[0]
        self.frames += 1
        if n == 0:
            return 0
        w = self._w
        seq = frame.seq & 0xFFFFFFFF
        times = rows[:, 0]
        log_arr = np.round(rows[:, 0] * 1e9).astype(np.int64) + self.t0
        w.add_records(
            self.ch_vars, log_arr, self.vars.records(rows, self.ch_vars, seq, log_arr, frame.wall_ns)
        )
        log_ns = log_arr.tolist()
        written = n
        for ns, update in self.world.grasp_updates(rows, log_ns, backfill):
            self.write_json(self.ch_scene, update, ns)
        if self.poses or self.joints:
            tl = times.tolist()
            pick = []
            for i, t in enumerate(tl):
                if t >= self._next_viz or (frame.final and i == n - 1):
                    pick.append(i)
                    self._next_viz = t + self.viz_period if t >= self._next_viz else self._next_viz
            if pick:
                sel = rows[pick]
                pv = sel[:, self.poses.idx].tolist() if self.poses else None
                jv = sel[:, self.joints.idx].tolist() if self.joints else None
                finite = bool(np.isfinite(sel).all())
                for k, i in enumerate(pick):
                    ts = ts_json(log_ns[i])
                    if pv is not None and (finite or all(map(math.isfinite, pv[k]))):
                        w.add_message(self.ch_tf, log_ns[i], self.poses.encode(pv[k], ts), frame.wall_ns, seq)
                        written += 1
                    if jv is not None and (finite or all(map(math.isfinite, jv[k]))):
                        w.add_message(
                            self.ch_joints, log_ns[i], self.joints.encode(jv[k], ts), frame.wall_ns, seq
                        )
                        written += 1
                if finite:
                    for ns, update in self.world.contacts_updates(sel, [log_ns[i] for i in pick], backfill):
                        self.write_json(self.ch_scene, update, ns)
        self.rows += n
        self.messages += written
        self.dirty = True
        return written

    def write_json(self, channel: int, obj: Any, log_ns: int) -> None:
        self._w.add_message(channel, log_ns, json.dumps(obj, separators=(",", ":")).encode(), time.time_ns())
        self.messages += 1
        self.dirty = True

    def write_scene(
        self,
        model: ModelDescription,
        values: Mapping[str, float],
        meshes: Mapping[str, bytes] | None = None,
        obstacles: Sequence[Obstacle] = (),
    ) -> None:
        self.write_json(self.ch_scene, scene_update(model, values, self.t0, meshes, obstacles), self.t0)

    def write_log(self, level: int, text: str, sim_time: float | None = None, name: str = "recorder") -> None:
        """A lifecycle event on /log, at the run's simulated time when known, else at wall time."""
        ns = self.log_time(sim_time) if sim_time is not None else time.time_ns()
        msg = {"timestamp": stamp(ns), "level": level, "message": text, "name": name, "file": "", "line": 0}
        self.write_json(self.ch_log, msg, ns)

    def write_metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._w.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def write_attachment(self, name: str, media_type: str, data: bytes) -> None:
        now = time.time_ns()
        self._w.add_attachment(now, now, name, media_type, data)

    def flush(self, force: bool = False) -> None:
        """Close the open chunk and hand everything to the OS (survives a crash of this process)."""
        if self.dirty or force:
            self._w.flush()
            self.dirty = False
        self.last_flush = time.monotonic()

    def close(self, end: Mapping[str, str]) -> None:
        """Write `simecs.end`, the summary and the footer; fsync; release the lock."""
        if self.closed:
            return
        self.closed = True
        try:
            data = {"frames": str(self.frames), "rows": str(self.rows), "messages": str(self.messages)}
            data.update({str(k): str(v) for k, v in end.items()})
            self._w.add_metadata(META_END, data)
            self._w.finish()
            self._stream.flush()
            os.fsync(self._stream.fileno())
        finally:
            self._stream.close()

    def abandon(self) -> None:
        """Stop writing without a footer (the file stays recoverable); used when writing failed."""
        if not self.closed:
            self.closed = True
            try:
                self._stream.close()
            except OSError:
                pass
