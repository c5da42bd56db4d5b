"""The names files get on their way out of the viewer (a CSV download: mesh/rules/table_csv.py writes it) and
in (an uploaded recording).
"""

from __future__ import annotations

from simecs.mesh.protocol import keys


def csv_name(model_id: str, session: str, run_id: str) -> str:
    return f"simecs_{model_id}_{session[:8]}_{run_id}.csv"


def upload_name(filename: str) -> str:
    """The recording name an uploaded file is stored under (mesh.protocol.keys decides)."""
    return keys.name_from_file(filename)
