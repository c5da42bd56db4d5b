"""The recorder node: every run saved as one MCAP file (`recording_pipeline.py`), and the recordings
served to users (`recordings_library.py`): the list, one recording's description, downloads and
uploads. Torn files from a crash are repaired before the node says it is ready.
"""

from __future__ import annotations

import argparse
from typing import Any

from simecs.mesh.process.runtime import Node, Request, main_for, mesh_from_args
from simecs.mesh.protocol import keys, limits

from .recording.recording_files import VIZ_RATE_HZ
from .recording.recording_pipeline import RecordingPipeline
from .recording.recordings_library import RecordingsLibrary


class Recorder(Node):
    """Records every run as an MCAP file; lists, serves and accepts recordings."""

    role = "recorder"
    tick_s = 0.5

    def __init__(
        self,
        mesh: Any,
        node_id: str | None = None,
        directory: str = "recordings",
        viz_rate_hz: float = VIZ_RATE_HZ,
        queue_frames: int = 4096,
        queue_mb: float = limits.limit("recorder_queue_bytes") / limits.MiB,
        idle_timeout_s: float = 30.0,
        mb_per_user: float = limits.limit("recordings_bytes_per_user") / limits.MiB,
    ) -> None:
        super().__init__(mesh, node_id)
        self.library = RecordingsLibrary(directory, int(mb_per_user * limits.MiB))
        self.pipeline = RecordingPipeline(
            self.library,
            self.node_id,
            self.log,
            lambda: self.publish_status("ready"),
            viz_rate_hz,
            queue_frames,
            queue_mb,
            idle_timeout_s,
        )

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--dir", default="recordings", help="where recordings are written (default recordings)"
        )
        parser.add_argument(
            "--viz-rate",
            type=float,
            default=VIZ_RATE_HZ,
            help=f"max /tf and /joint_states samples per simulated second (default {VIZ_RATE_HZ:g})",
        )
        parser.add_argument(
            "--queue-frames",
            type=int,
            default=4096,
            help="frames buffered before dropping (0: none; each run is then written from its results)",
        )
        parser.add_argument(
            "--queue-mb",
            type=float,
            default=limits.limit("recorder_queue_bytes") / limits.MiB,
            help="frame bytes buffered before dropping",
        )
        parser.add_argument(
            "--max-mb-per-user",
            type=float,
            default=limits.limit("recordings_bytes_per_user") / limits.MiB,
            help="recordings kept per user",
        )
        parser.add_argument(
            "--idle-timeout",
            type=float,
            default=30.0,
            help="close a run silent this long whose worker is gone",
        )

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Recorder:
        return cls(
            mesh_from_args(args),
            args.node_id,
            args.dir,
            args.viz_rate,
            args.queue_frames,
            args.queue_mb,
            args.idle_timeout,
            args.max_mb_per_user,
        )

    def status_detail(self) -> dict[str, Any]:
        return {
            "dir": str(self.library.dir),
            "recording": self.library.writing(),
            **self.pipeline.files.stats,
            "recovered": self.library.recovered,
            "dropped_frames": self.pipeline.ingest.dropped_total,
        }

    def run(self) -> int:
        """Repair torn files before joining the mesh: ready means every old file is whole again."""
        self.library.recover_all()
        return super().run()

    def start(self) -> None:
        self.pipeline.start(self.z, self.declare, self.seal)
        self.serve(keys.ALL_RECORDING_LISTS, self._on_list, threaded=True)
        self.serve(keys.ALL_RECORDINGS, self._on_file, threaded=True)
        self.serve(keys.ALL_RECORDING_INFOS, self._on_info, threaded=True)
        self.serve(keys.ALL_RECORDING_DELETES, self._on_delete, threaded=True)
        self.serve(keys.ALL_RECORDING_RESULTS, self._on_results, threaded=True)

    def _on_list(self, req: Request) -> Any:
        return self.library.listing(keys.parse("recordings", req.key)["user"])

    def _on_file(self, req: Request) -> Any:
        where = keys.parse("recording", req.key)
        if req.payload is not None:
            return self.library.upload(where["user"], where["name"], req.payload)
        return self.library.download(where["user"], where["name"])

    def _on_info(self, req: Request) -> Any:
        where = keys.parse("recording_info", req.key)
        return self.library.info(where["user"], where["name"])

    def _on_delete(self, req: Request) -> Any:
        where = keys.parse("recording_delete", req.key)
        return self.library.delete(where["user"], where["name"])

    def _on_results(self, req: Request) -> Any:
        where = keys.parse("recording_results", req.key)
        return self.library.results(where["user"], where["name"], req.parameters)

    def stop(self) -> None:
        self.pipeline.stop()


def main(argv: list[str] | None = None) -> int:
    return main_for(Recorder, argv)


if __name__ == "__main__":
    main()
