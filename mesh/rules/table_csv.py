"""A run's samples as CSV: the one format every simecs tool writes (the viewer's download, `simecs
export`, `simecs run` and `sweep`), so the same run gives the same file whichever wrote it.

Optional `# key: value` lines first (which model, session and run), then a header of the column names
(`time` first), optionally a line of their units, then one line per sample. Values are written in
Python's shortest round-trip form: reading the file back gives the float64 values exactly.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import TextIO

import numpy as np


def write_table(
    out: TextIO | io.TextIOBase,
    columns: Sequence[str],
    rows: np.ndarray,
    units: Sequence[str] | None = None,
    meta: Mapping[str, str] | None = None,
) -> int:
    """Write the table to `out`; returns the number of samples written."""
    for key, value in (meta or {}).items():
        out.write(f"# {key}: {' '.join(str(value).splitlines())}\n")
    out.write(",".join(_cell(c) for c in columns) + "\n")
    if units is not None:
        out.write(",".join(_cell(u) for u in units) + "\n")
    line = ",".join(["%r"] * len(columns)) + "\n"
    table = np.asarray(rows, dtype=float).reshape(-1, len(columns))
    for row in table.tolist():
        out.write(line % tuple(row))
    return int(table.shape[0])


def table_bytes(
    columns: Sequence[str],
    rows: np.ndarray,
    units: Sequence[str] | None = None,
    meta: Mapping[str, str] | None = None,
) -> bytes:
    """The table as a file's bytes (UTF-8)."""
    out = io.StringIO()
    write_table(out, columns, rows, units, meta)
    return out.getvalue().encode("utf-8")


def _cell(text: str) -> str:
    return '"' + text.replace('"', '""') + '"' if any(ch in text for ch in ',"\n') else text
