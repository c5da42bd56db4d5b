"""Full-resolution results on a simulator host's disk, `<folder>/<user>/<session>/`: one `.npy` of rows
and one `.json` of what they are per run, the last `RUNS_KEPT` runs of each session. The worker that ran
a run writes it; the simulator node serves it, to the session's user only.

While a run goes, its worker also appends every frame's rows to a partial file (`PartialResults`):
a worker that dies (killed, out of memory) leaves what it computed, and the simulator node stores that
as the run's results, ended where they end (`ResultsStore.salvage`).
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from simecs.mesh.process import files
from simecs.mesh.protocol import keys
from simecs.mesh.protocol.limits import RUNS_KEPT


@dataclass
class StoredRun:
    """What the store knows of a run besides its rows."""

    run_id: str
    run_index: int
    phase: str
    reason: str
    stop_time: float
    sim_time: float
    samples: int
    columns: list[str]
    units: list[str]
    model_id: str
    #: What produced the run (RunContext as JSON data): a client compares runs by it.
    context: dict[str, Any] | None = None
    #: Simulated s during which a jog moved the arm (RunInfo.jogged_s); 0 in runs stored before it was.
    jogged_s: float = 0.0


class ResultsStore:
    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)

    def _folder(self, user: str, session: str) -> Path:
        keys.check_name(user, "user name")
        if not keys.is_session_id(session):
            raise ValueError(f"{session!r:.40} is not a session id")
        return self.folder / user / session

    def _paths(self, user: str, session: str, run_id: str) -> tuple[Path, Path]:
        keys.check_name(run_id, "run id")
        base = self._folder(user, session)
        return base / f"{run_id}.npy", base / f"{run_id}.json"

    def save(self, user: str, session: str, run: StoredRun, rows: np.ndarray) -> None:
        """Store a run's rows and description atomically, then forget the session's oldest runs."""
        npy, meta = self._paths(user, session, run.run_id)
        npy.parent.mkdir(parents=True, exist_ok=True)
        tmp = npy.with_name(f".{npy.name}.tmp.npy")
        np.save(tmp, rows)
        os.replace(tmp, npy)
        files.write_json(meta, {**vars(run), "saved": time.time()})
        self.prune(user, session)

    def partial(self, user: str, session: str, run: StoredRun) -> PartialResults:
        """Where the worker of `run` appends its rows as they are computed."""
        return PartialResults(self._partial_path(user, session, run.run_id), run)

    def _partial_path(self, user: str, session: str, run_id: str) -> Path:
        npy, _meta = self._paths(user, session, run_id)
        return npy.with_name(f".{run_id}.partial")

    def salvage(self, user: str, session: str, run_id: str, reason: str) -> StoredRun | None:
        """Store what a dead worker's partial file holds as the run's results (phase failed, ended
        where its rows end); None when there is none (the run had not started, or ended properly)."""
        rows_path = self._partial_path(user, session, run_id)
        meta_path = PartialResults.meta_of(rows_path)
        try:
            data: dict[str, Any] = files.read_json(meta_path)
            data.pop("saved", None)
            run = StoredRun(**data)
            flat = np.fromfile(rows_path, dtype="<f8")
        except (OSError, ValueError, TypeError):
            return None
        width = len(run.columns)
        rows = flat[: flat.size - flat.size % width].reshape(-1, width)  # a row torn by the kill: left out
        run.phase, run.reason = "failed", reason
        run.samples = int(rows.shape[0])
        run.sim_time = float(rows[-1, 0]) if rows.shape[0] else 0.0
        self.save(user, session, run, rows)
        for p in (rows_path, meta_path):
            p.unlink(missing_ok=True)
        return run

    def prune(self, user: str, session: str) -> None:
        folder = self._folder(user, session)
        metas = list(folder.glob("r*.json")) if folder.is_dir() else []
        for meta in sorted(metas, key=lambda p: _run_number(p.stem))[:-RUNS_KEPT]:
            meta.unlink(missing_ok=True)
            meta.with_suffix(".npy").unlink(missing_ok=True)

    def remove(self, user: str, session: str) -> bool:
        """Forget every run of a session (it was closed); whether there was any."""
        folder = self._folder(user, session)
        if not folder.is_dir():
            return False
        shutil.rmtree(folder, ignore_errors=True)
        return True

    def load(self, user: str, session: str, run_id: str) -> tuple[StoredRun, np.ndarray] | None:
        """A run's description and rows (memory-mapped), or None when this host does not hold it."""
        npy, meta = self._paths(user, session, run_id)
        if not meta.is_file() or not npy.is_file():
            return None
        data: dict[str, Any] = files.read_json(meta)
        data.pop("saved", None)
        return StoredRun(**data), np.load(npy, mmap_mode="r")


class PartialResults:
    """A run's rows appended as they are computed (raw little-endian float64, row after row), and
    beside them what they are: a process killed mid-run leaves them on disk (each append is a write
    to the file, kept by the system when the process dies)."""

    def __init__(self, path: Path, run: StoredRun) -> None:
        self.path = path
        self.meta = self.meta_of(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        files.write_json(self.meta, vars(run))
        # unbuffered: each append is one write straight into the system's hands (no copy kept here)
        self._fh = open(path, "wb", buffering=0)  # noqa: SIM115 - open for the run's length, closed by discard()

    @staticmethod
    def meta_of(path: Path) -> Path:
        """What the rows at `path` are (their StoredRun), beside them."""
        return path.with_name(path.name + ".json")

    def append(self, rows: np.ndarray) -> None:
        np.ascontiguousarray(rows, dtype="<f8").tofile(self._fh)

    def discard(self) -> None:
        """The run's results are stored properly: the partial file goes."""
        try:
            self._fh.close()
        except (OSError, AttributeError):
            pass
        for p in (self.path, self.meta):
            p.unlink(missing_ok=True)


def _run_number(stem: str) -> int:
    return int(stem[1:]) if stem[1:].isdigit() else 0
