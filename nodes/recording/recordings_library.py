"""The recordings library: the MCAP files in the recordings folder, one folder per user, as each user
lists, downloads and uploads their own, and torn files (a recorder killed mid-run) repaired before
anything else touches the folder.

The recording pipeline tells the library which files it is still writing: those are listed with their
current size, and a download waits briefly for them to be closed.
"""

from __future__ import annotations

import fcntl
import logging
import os
import threading
import time
from collections.abc import Mapping
from pathlib import Path

import msgspec
from simecs.mesh.process import files
from simecs.mesh.process.runtime import Binary, RequestError
from simecs.mesh.protocol import keys, limits, phases
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.results import results_reply

from . import mcapfmt as fmt
from . import mcapread, mcaprepair

log = logging.getLogger("simecs.recorder")

DOWNLOAD_WAIT_S = 3.0  # a download of a run that is just ending waits this long for its file
MAX_FILE_BYTES = limits.limit("upload_bytes")  # largest recording served or accepted over the mesh
LOADED_KEPT = 2  # recordings kept read for their results (each holds its rows in memory)
_INCOMPLETE = "the recording ends before its run did (the recorder stopped, or the file was torn)"


class RecordingsLibrary:
    """`<folder>/<user>/<name>.mcap`: each user's recordings, in a folder of their own."""

    def __init__(
        self, folder: str | os.PathLike[str], quota_bytes: int = limits.limit("recordings_bytes_per_user")
    ) -> None:
        self.dir = Path(folder).resolve()
        self.quota_bytes = quota_bytes
        self.lock = threading.Condition()  # guards open_files, info_cache and loaded
        self.open_files: dict[Path, m.RecordingInfo] = {}
        self.info_cache: dict[Path, tuple[tuple[int, int], m.RecordingInfo | None]] = {}
        self.loaded: dict[Path, tuple[tuple[int, int], mcapread.Recording]] = {}  # oldest first
        self.recovered = 0

    # -- files being written --------------------------------------------------------------------------
    def opened(self, path: Path, info: m.RecordingInfo) -> None:
        with self.lock:
            self.open_files[path] = info

    def closed(self, path: Path) -> None:
        with self.lock:
            self.open_files.pop(path, None)
            self.lock.notify_all()

    def writing(self) -> list[str]:
        with self.lock:
            return sorted(f"{p.parent.name}/{i.name}" for p, i in self.open_files.items())

    def path_of(self, user: str, name: str) -> Path:
        """Where `user`'s recording `name` is (both checked: one key chunk each)."""
        try:
            keys.check_name(user, "user name")
            keys.check_name(name, "recording name")
        except keys.KeyProblem as exc:
            raise RequestError("bad_request", str(exc), "name") from None
        return self.dir / user / f"{name}.mcap"

    def free_name(self, user: str, base: str) -> str:
        """`base`, or `base.2`, `base.3`, ... when `user` has a file of that name already."""
        name, k = base, 2
        while self.path_of(user, name).exists():
            name, k = f"{base}.{k}", k + 1
        return name

    # -- crash recovery -------------------------------------------------------------------------------
    def recover_all(self) -> None:
        """Repair every torn file left by a crash; skip files another writer holds locked."""
        self.dir.mkdir(parents=True, exist_ok=True)
        for tmp in self.dir.glob("*/.*.tmp"):
            try:
                tmp.unlink()
            except OSError:
                pass
        for path in sorted(self.dir.glob("*/*.mcap")):
            if mcapread.has_footer(path) or _locked(path):
                continue
            try:
                rec = mcaprepair.recover(path)
            except (mcapread.RecordingError, OSError) as exc:
                log.error("cannot recover %s (left as it is): %s", path, exc)
                continue
            if rec is not None:
                self.recovered += 1
                log.warning(
                    "recovered torn recording %s: kept %d messages (%s)", path.name, rec.messages, rec.problem
                )

    # -- serving --------------------------------------------------------------------------------------
    def _info(self, path: Path) -> m.RecordingInfo | None:
        with self.lock:
            writing = self.open_files.get(path)
        if writing is not None:  # its size grows while the run goes on
            return msgspec.structs.replace(writing, bytes=path.stat().st_size)
        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
        cached = self.info_cache.get(path)
        if cached is not None and cached[0] == stamp:
            return cached[1]
        try:
            info: m.RecordingInfo | None = mcapread.info(path)
        except (mcapread.RecordingError, OSError) as exc:
            log.warning("not listing %s: %s", path.name, exc)
            info = None
        with self.lock:
            self.info_cache[path] = (stamp, info)
        return info

    def usage(self, user: str) -> int:
        """Bytes of every file in `user`'s folder (what their quota counts)."""
        folder = self.path_of(user, "x").parent
        total = 0
        for p in folder.glob("*.mcap") if folder.is_dir() else ():
            try:
                total += p.stat().st_size
            except FileNotFoundError:
                pass
        return total

    def over_quota(self, user: str, adding: int = 0) -> str:
        """Why `user` may not store `adding` more bytes ("" when they may)."""
        used = self.usage(user)
        if used + adding <= self.quota_bytes:
            return ""
        mib = limits.MiB
        return (
            f"{user}'s recordings use {used / mib:.1f} MiB of {self.quota_bytes / mib:.0f} MiB "
            f"(recordings_bytes_per_user): delete some first"
        )

    def delete(self, user: str, name: str) -> m.RecordingInfo:
        path = self.path_of(user, name)
        with self.lock:
            if path in self.open_files:
                raise RequestError(
                    "conflict", f"recording {name} is being written (its run is going on)", "name"
                )
            if not path.is_file():
                raise RequestError("not_found", f"{user} has no recording {name!r}", "name")
            info = self._info(path) or m.RecordingInfo(
                name, "", "", "", path.stat().st_size, created=mcapread.created_of({}, path)
            )
            path.unlink()
            self.info_cache.pop(path, None)
            self.loaded.pop(path, None)
        log.info("deleted recording %s of %s", name, user)
        return info

    def listing(self, user: str) -> m.RecordingList:
        folder = self.path_of(user, "x").parent
        paths = sorted(folder.glob("*.mcap"), key=lambda p: p.stat().st_mtime_ns, reverse=True)
        out = []
        for p in paths:
            try:
                info = self._info(p)
            except FileNotFoundError:
                continue
            if info is not None:
                out.append(info)
        return m.RecordingList(out, used_bytes=self.usage(user), quota_bytes=self.quota_bytes)

    def info(self, user: str, name: str) -> m.RecordingInfo:
        path = self.path_of(user, name)
        if not path.is_file():
            raise RequestError("not_found", f"{user} has no recording {name!r}", "name")
        info = self._info(path)
        if info is None:
            raise RequestError("bad_request", f"{name} is not a readable simecs recording", "name")
        return info

    def _closed(self, user: str, name: str, doing: str) -> Path:
        """The path of a recording that is not being written (a run just ending gets DOWNLOAD_WAIT_S
        to close its file): refused as `conflict` while its run goes on, `not_found` without it."""
        path = self.path_of(user, name)
        end = time.monotonic() + DOWNLOAD_WAIT_S
        with self.lock:
            while path in self.open_files and time.monotonic() < end:
                self.lock.wait(0.1)
            if path in self.open_files:
                raise RequestError(
                    "conflict",
                    f"recording {name} is still being written (its run is going on): "
                    f"{doing} it when the run has ended",
                    "name",
                )
        if not path.is_file():
            raise RequestError("not_found", f"{user} has no recording {name!r}", "name")
        return path

    @staticmethod
    def _servable(name: str, size: int) -> None:
        """Refuse a recording too big to serve over the mesh (downloaded, or read for its results)."""
        if size > MAX_FILE_BYTES:
            raise RequestError(
                "unsupported", f"recording {name} is {size} bytes, more than the {MAX_FILE_BYTES} served"
            )

    def download(self, user: str, name: str) -> Binary:
        path = self._closed(user, name, "download")
        self._servable(name, path.stat().st_size)
        info = self._info(path)
        return Binary(path.read_bytes(), attachment=info)

    def results(self, user: str, name: str, parameters: Mapping[str, str]) -> Binary:
        """The recorded run's samples as a run's results (mesh/rules/results.py: the same selector and
        reply), so runs are compared with recordings without replaying them."""
        path = self._closed(user, name, "compare")
        rec = self._loaded(path, name)
        end = rec.metadata.get(fmt.META_END, {})
        phase = end.get("phase", "")
        reason = end.get("reason", "")
        if phase not in phases.ENDED:  # "ended" without its last rows, "incomplete", or torn
            phase, reason = ("finished", reason) if phase == "ended" else ("failed", _INCOMPLETE)
        rows = rec.rows
        info = m.RunInfo(
            rec.layout.run_id,
            phase,  # type: ignore[arg-type]
            rec.layout.stop_time,
            float(rows[-1, 0]) if rows.shape[0] else 0.0,
            int(rows.shape[0]),
            reason,
            recording=name,
            until_stopped=rec.layout.context.until_stopped,
            jogged_s=rec.jogged_s,
        )
        layout = rec.layout
        return results_reply(
            rows, layout.columns, layout.units, parameters, layout.run_index, info, rec.context()
        )

    def _loaded(self, path: Path, name: str) -> mcapread.Recording:
        """`path` read whole, from the last LOADED_KEPT read while the file is unchanged (a comparison
        asks for each plot and each zoom)."""
        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
        with self.lock:
            kept = self.loaded.get(path)
        if kept is not None and kept[0] == stamp:
            return kept[1]
        self._servable(name, st.st_size)
        try:
            rec = mcapread.load(path)
        except (mcapread.RecordingError, OSError) as exc:
            raise RequestError(
                "bad_request", f"{name} is not a readable simecs recording: {exc}", "name"
            ) from None
        with self.lock:
            self.loaded[path] = (stamp, rec)
            while len(self.loaded) > LOADED_KEPT:
                self.loaded.pop(next(iter(self.loaded)))
        return rec

    def upload(self, user: str, name: str, data: bytes) -> m.RecordingInfo:
        path = self.path_of(user, name)
        if keys.is_run_recording_name(name):
            raise RequestError(
                "bad_request",
                f"{name!r}: names of the form <session>_r<N> are kept for the recordings of runs; "
                "choose another name",
                "name",
            )
        if len(data) > MAX_FILE_BYTES:
            raise RequestError(
                "bad_request",
                f"upload {name}: {len(data)} bytes is more than upload_bytes = {MAX_FILE_BYTES}",
                "payload",
            )
        full = self.over_quota(user, len(data))
        if full:
            raise RequestError("busy", f"upload {name} refused: {full}")
        try:
            mcapread.validate(data)
            rec = mcapread.load(data, strict=True)
            problem = mcapread.playable_problem(rec)
            if problem:
                raise mcapread.RecordingError(f"it cannot be replayed: {problem}")
        except mcapread.RecordingError as exc:
            raise RequestError(
                "bad_request",
                f"upload {name} refused: {str(exc).replace('uploaded file', 'the file', 1)}",
                "payload",
            ) from None
        with self.lock:
            if path.exists() or path in self.open_files:
                raise RequestError(
                    "conflict", f"a recording named {name!r} already exists; choose another name", "name"
                )
            files.atomic_write(path, data)
        log.info(
            "stored uploaded recording %s of %s (%d bytes, %d samples)", name, user, len(data), len(rec.rows)
        )
        lay = rec.layout
        created = mcapread.created_of(rec.metadata.get(fmt.META_RUN, {}), path)
        return m.RecordingInfo(
            name, lay.session, lay.run_id, lay.model_id, len(data), rec.recovered, lay.stop_time, created
        )


def _locked(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    except OSError:
        return True
    return False
