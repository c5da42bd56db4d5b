"""Writing state to disk so that nothing is lost when a process dies mid-write, and reading the JSON5
files people write (model files, mesh configurations)."""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import pyjson5

from ..protocol import codec


def atomic_write(path: str | os.PathLike[str], data: bytes) -> None:
    """Write `data` to `path` via a temporary file, fsync and rename: readers see old or new, never half."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def remove_leftovers(folder: str | os.PathLike[str]) -> int:
    """Remove the temporary files `atomic_write` left under `folder` when its process was killed
    mid-write (their target kept its old content); how many. Only for a folder no live process
    writes: its owner, at start."""
    removed = 0
    for tmp in Path(folder).rglob(".*.tmp"):
        try:
            tmp.unlink()
            removed += 1
        except OSError:
            pass
    return removed


def write_json(path: str | os.PathLike[str], obj: Any) -> None:
    atomic_write(path, json.dumps(codec.to_obj(obj), indent=1, allow_nan=False).encode("utf-8"))


def read_json(path: str | os.PathLike[str]) -> Any:
    return json.loads(Path(path).read_text("utf-8"))


def parse_json5(text: str) -> Any:
    """JSON5 `text` (comments, unquoted keys, trailing commas) as Python values; ValueError naming the
    line and column of what is wrong. pyjson5 parses in C: the pure-Python json5 took 0.1 s per model
    file, paid at every start of every process that lists the models."""
    try:
        return pyjson5.loads(text)
    except pyjson5.Json5Exception as exc:
        message = str(exc.args[0]) if exc.args else type(exc).__name__
        at = re.search(r"near (\d+)", message)
        if at:
            pos = int(at.group(1))
            line, column = text.count("\n", 0, pos) + 1, pos - text.rfind("\n", 0, pos)
            message = message.replace(at.group(0), f"at line {line}, column {column}")
        raise ValueError(message.replace("b'", "'")) from None
