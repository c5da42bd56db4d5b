"""Saved programs: a user's actions, tasks and missions per model (paper §3, the Action Level
Simulator's library), kept on the server's disk like parameter sets: written atomically, surviving
restarts, one file per program (`<user>/<model>/<kind>/<name>.json`)."""

from __future__ import annotations

import os
import time
from pathlib import Path

from simecs.mesh.process import files
from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m

KINDS = ("action", "task", "mission")


class ProgramStore:
    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)

    def _path(self, user: str, model_id: str, kind: str, name: str) -> Path:
        try:
            keys.check_name(name, "program name")
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "name") from None
        return self.folder / user / model_id / kind / f"{name}.json"

    def save(self, user: str, model_id: str, name: str, program: m.Program) -> None:
        path = self._path(user, model_id, program.kind, name)
        files.write_json(path, {"model_id": model_id, "program": program, "saved": time.time()})

    def load(self, user: str, model_id: str, kind: str, name: str) -> m.Program:
        """The stored program as it was saved (the caller checks it against the model)."""
        path = self._path(user, model_id, kind, name)
        if not path.is_file():
            raise RequestError("not_found", f"no {kind} {name!r} saved by {user} for {model_id}", "name")
        try:
            obj = files.read_json(path)["program"]
            return codec.from_obj(m.Program, obj)
        except (OSError, ValueError, KeyError, TypeError, codec.DecodeError) as exc:
            raise RequestError("bad_request", f"{kind} {name!r} is unreadable: {exc}", "name") from None

    def delete(self, user: str, model_id: str, kind: str, name: str) -> None:
        path = self._path(user, model_id, kind, name)
        if not path.is_file():
            raise RequestError("not_found", f"no {kind} {name!r} saved for {model_id}", "name")
        path.unlink()

    def exists(self, user: str, model_id: str, kind: str, name: str) -> bool:
        return self._path(user, model_id, kind, name).is_file()

    def count(self, user: str) -> int:
        """Every program of `user`, all models and kinds together (the quota counts them so)."""
        folder = self.folder / user
        return sum(1 for _ in folder.glob("*/*/*.json")) if folder.is_dir() else 0

    def entries(self, user: str, model_id: str, kind: str = "") -> list[m.ProgramEntry]:
        out: list[m.ProgramEntry] = []
        for k in [kind] if kind else KINDS:
            folder = self.folder / user / model_id / k
            if folder.is_dir():
                out.extend(m.ProgramEntry(k, p.stem) for p in sorted(folder.glob("*.json")))  # type: ignore[arg-type]
        return out
