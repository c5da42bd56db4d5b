"""`simecs export FILE --csv [--vars ...]`: a recording's samples as CSV, for spreadsheets and scripts.

The CSV is the one format of mesh/rules/table_csv.py (the viewer's download is the same file): reading it
back gives the recorded float64 values exactly. `--vars` takes column names or shell patterns (`joint1.*`);
`time` is always the first column.
"""

from __future__ import annotations

import argparse
import fnmatch
import io
import sys
from collections.abc import Sequence
from pathlib import Path

from simecs.mesh.rules.table_csv import write_table

from ..recording import mcapread


class ExportError(ValueError):
    """What the user asked for cannot be exported; the message says why."""


def select_columns(columns: Sequence[str], patterns: Sequence[str]) -> list[int]:
    """Indices of `time` and every column matching one of `patterns`, in recording order."""
    if not patterns:
        return list(range(len(columns)))
    chosen = {0}
    for pat in patterns:
        hits = [i for i, c in enumerate(columns) if fnmatch.fnmatchcase(c, pat)]
        if not hits:
            close = [c for c in columns if pat.split("*")[0].split(".")[0] in c][:8]
            hint = f"; similar: {', '.join(close)}" if close else f"; columns: {', '.join(columns[:12])} ..."
            raise ExportError(f"no column matches {pat!r}{hint}")
        chosen.update(hits)
    return sorted(chosen)


def write_csv(
    rec: mcapread.Recording,
    out: io.TextIOBase,
    patterns: Sequence[str] = (),
    units: bool = False,
    t0: float | None = None,
    t1: float | None = None,
) -> int:
    """Write the selected columns as CSV; returns the number of data rows."""
    idx = select_columns(rec.columns, patterns)
    rows = rec.rows
    if t0 is not None:
        rows = rows[rows[:, 0] >= t0]
    if t1 is not None:
        rows = rows[rows[:, 0] <= t1]
    unit_row = [rec.layout.units[i] if i < len(rec.layout.units) else "" for i in idx] if units else None
    return write_table(out, [rec.columns[i] for i in idx], rows[:, idx], unit_row)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="simecs export", description=__doc__)
    parser.add_argument("file", help="MCAP recording")
    parser.add_argument(
        "--csv", action="store_true", required=True, help="export as CSV (the format available)"
    )
    parser.add_argument(
        "--vars", nargs="+", default=[], metavar="NAME", help="columns or patterns (default all)"
    )
    parser.add_argument("-o", "--output", help="output file (default FILE with .csv; '-' for stdout)")
    parser.add_argument("--units", action="store_true", help="add a second header line with the units")
    parser.add_argument("--t0", type=float, default=None, help="first time to export (s)")
    parser.add_argument("--t1", type=float, default=None, help="last time to export (s)")
    args = parser.parse_args(argv)
    path = Path(args.file)
    try:
        rec = mcapread.load(path)
        if not rec.complete:
            print(f"simecs export: warning: {path} is incomplete ({rec.problem})", file=sys.stderr)
        select_columns(rec.columns, args.vars)  # unknown names fail before any file is written
        if args.output == "-":
            n = write_csv(rec, sys.stdout, args.vars, args.units, args.t0, args.t1)  # type: ignore[arg-type]
            return 0
        out_path = Path(args.output) if args.output else path.with_suffix(".csv")
        tmp = out_path.with_name(f".{out_path.name}.tmp")
        with open(tmp, "w", newline="") as fh:
            n = write_csv(rec, fh, args.vars, args.units, args.t0, args.t1)  # type: ignore[arg-type]
        tmp.replace(out_path)
    except (mcapread.RecordingError, ExportError, OSError) as exc:
        print(f"simecs export: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {n} rows to {out_path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
