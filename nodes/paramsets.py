"""Named parameter sets (paper §2.2 step 2: changes "can be saved as named sets and reused"), kept per
user and model on the server's disk, written atomically, surviving restarts."""

from __future__ import annotations

import os
import time
from pathlib import Path

from simecs.mesh.process import files
from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import keys


class ParamSetStore:
    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)

    def _path(self, user: str, model_id: str, name: str) -> Path:
        try:
            keys.check_name(name, "parameter set name")
        except ValueError as exc:
            raise RequestError("bad_request", str(exc), "name") from None
        return self.folder / user / model_id / f"{name}.json"

    def save(self, user: str, model_id: str, name: str, values: dict[str, float]) -> None:
        files.write_json(
            self._path(user, model_id, name), {"model_id": model_id, "values": values, "saved": time.time()}
        )

    def load(self, user: str, model_id: str, name: str) -> dict[str, float]:
        """The stored values (not yet checked against the model: the caller does)."""
        path = self._path(user, model_id, name)
        if not path.is_file():
            raise RequestError("not_found", f"no parameter set {name!r} for {user} on {model_id}", "name")
        try:
            stored = files.read_json(path)["values"]
            return {str(k): v for k, v in stored.items()}
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise RequestError(
                "bad_request", f"parameter set {name!r} is unreadable: {exc}", "name"
            ) from None

    def delete(self, user: str, model_id: str, name: str) -> None:
        path = self._path(user, model_id, name)
        if not path.is_file():
            raise RequestError("not_found", f"no parameter set {name!r}", "name")
        path.unlink()

    def exists(self, user: str, model_id: str, name: str) -> bool:
        return self._path(user, model_id, name).is_file()

    def count(self, user: str) -> int:
        """Every set of `user`, all models together (their quota counts them so)."""
        folder = self.folder / user
        return sum(1 for _ in folder.glob("*/*.json")) if folder.is_dir() else 0

    def names(self, user: str, model_id: str) -> list[str]:
        folder = self.folder / user / model_id
        return sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []
