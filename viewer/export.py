"""What leaves the viewer as a file (paper §2.2 step 11): a run's variables as CSV, and the names
files get on the way out (CSV download) and in (an uploaded recording).
"""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np
from simecs.mesh import keys

from .units import labelled


def to_csv(
    columns: Sequence[str], units: Sequence[str], rows: np.ndarray, meta: dict[str, str] | None = None
) -> bytes:
    """CSV with a header of `name [unit]`, full float precision, '#' comment lines for `meta` first."""
    out = io.StringIO()
    for key, value in (meta or {}).items():
        out.write(f"# {key}: {value}\n")
    head = [labelled(c, u) for c, u in zip(columns, units, strict=True)]
    out.write(",".join(head) + "\n")
    if rows.size:
        np.savetxt(out, np.asarray(rows, dtype=float), delimiter=",", fmt="%.17g")
    return out.getvalue().encode("utf-8")


def csv_name(model_id: str, session: str, run_id: str) -> str:
    return f"simecs_{model_id}_{session[:8]}_{run_id}.csv"


def upload_name(filename: str) -> str:
    """The recording name an uploaded file is stored under (mesh.keys decides)."""
    return keys.name_from_file(filename)
