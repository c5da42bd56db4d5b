"""`simecs replay FILE [--speed K] [--session ID]`: a recording played back onto the mesh as a run.

The file goes into the server's recordings library (unless it is there already), then a session of
the recording's model (a new one, or `--session`) replays it: the frames come out exactly as
recorded, paced at `--speed` x real time (0 = as fast as possible), and any client watches the run
like a live one (state, live plots, the 3D arm, full-resolution results). The command prints the
session id and waits for the replay to end (`--detach`: returns at once).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process.config import DEFAULT_HUB, load_client
from simecs.mesh.protocol import keys, phases

from .recording import mcapread


def put_in_library(client: MeshClient, user: str, path: Path, rec: mcapread.Recording) -> str:
    """The name of `path` in `user`'s recordings: the recording already there, or a fresh upload."""
    data = path.read_bytes()

    def already_there(name: str) -> bool:
        try:
            info = client.recording_info(user, name)
        except ValueError:  # not a name at all
            return False
        except RemoteError as exc:
            if exc.code in ("not_found", "bad_request"):
                return False
            raise
        return info.bytes == len(data) and (info.session, info.run_id) == (
            rec.layout.session,
            rec.layout.run_id,
        )

    if already_there(path.stem):  # a file of the library itself, e.g. recordings/ann/<session>_r1.mcap
        return path.stem
    base = keys.name_from_file(path.name)
    for k in range(1, 100):
        name = base if k == 1 else f"{base}.{k}"[:64]
        try:
            info = client.recording_info(user, name)
        except RemoteError as exc:
            if exc.code != "not_found":
                raise
            client.upload_recording(user, name, data)
            return name
        if info.bytes == len(data) and (info.session, info.run_id) == (rec.layout.session, rec.layout.run_id):
            return name  # this very file is in the library already
    raise RuntimeError(f"no free recording name for {path.name}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="simecs replay", description=__doc__)
    parser.add_argument("file", help="MCAP recording to replay")
    parser.add_argument(
        "--speed", type=float, default=1.0, help="x real time (default 1; 0 = as fast as possible)"
    )
    parser.add_argument(
        "--session", default="", help="replay in this session (same model) instead of a new one"
    )
    parser.add_argument(
        "--user",
        default="",
        help="whose recordings and session: the user name (default: the mesh config's user, or replay)",
    )
    parser.add_argument("--paused", action="store_true", help="start paused (resume from a client)")
    parser.add_argument("--detach", action="store_true", help="return once the replay has started")
    parser.add_argument("--connect", default=None, help=f"hub endpoint (default {DEFAULT_HUB})")
    parser.add_argument("--mesh-config", default=None, help="JSON5 mesh configuration file")
    args = parser.parse_args(argv)
    path = Path(args.file)
    if not path.is_file():
        print(f"simecs replay: {path}: no such file", file=sys.stderr)
        return 2
    try:
        rec = mcapread.load(path)
    except mcapread.RecordingError as exc:
        print(f"simecs replay: {exc}", file=sys.stderr)
        return 2
    if len(rec.rows) == 0:
        print(f"simecs replay: {path}: the recording holds no samples", file=sys.stderr)
        return 2
    cfg = load_client(args.mesh_config).with_overrides(connect=[args.connect] if args.connect else None)
    args.user = args.user or cfg.user or "replay"  # on a private mesh, a user acts in their own space
    try:
        with MeshClient.open(cfg, timeout=30.0) as client:
            name = put_in_library(client, args.user, path, rec)
            if args.session:
                session = client.session(args.user, args.session)
            else:
                session = client.create_session(args.user, rec.layout.model_id)
            run_id = session.replay(name, args.speed, args.paused)
            print(f"replaying {path} (recording {name}) as session {session.id} run {run_id}", flush=True)
            if args.detach:
                return 0
            end = session.wait_for(list(phases.ENDED), timeout=24 * 3600.0, run_id=run_id)
            print(f"run {run_id} {end.phase}" + (f": {end.reason}" if end.reason else ""), flush=True)
            return 0 if end.phase != "failed" else 1
    except (RemoteError, NoReply, RuntimeError, ValueError, OSError) as exc:
        print(f"simecs replay: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
