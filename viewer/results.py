"""Result saving (paper §2.2 step 11): the chosen variables of a run as CSV, the run's MCAP recording
(written by the recorder node), and replaying a recording as a live run.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from simecs.mesh import messages as m


def to_csv(
    columns: Sequence[str], units: Sequence[str], rows: np.ndarray, meta: dict[str, str] | None = None
) -> bytes:
    """CSV with a header of `name [unit]`, full float precision, '#' comment lines for `meta` first."""
    out = io.StringIO()
    for key, value in (meta or {}).items():
        out.write(f"# {key}: {value}\n")
    head = [f"{c} [{u}]" if u and u != "-" else c for c, u in zip(columns, units, strict=True)]
    out.write(",".join(head) + "\n")
    if rows.size:
        np.savetxt(out, np.asarray(rows, dtype=float), delimiter=",", fmt="%.17g")
    return out.getvalue().encode("utf-8")


def csv_name(model_id: str, session: str, run_id: str) -> str:
    return f"simecs_{model_id}_{session[:8]}_{run_id}.csv"


def run_label(info: m.RunInfo) -> str:
    return f"{info.run_id} · {info.phase} · {info.sim_time:.2f}/{info.stop_time:.2f} s"


class ResultsPanel:
    """Pick a run; load its transients into the plots; download CSV or MCAP; replay the recording."""

    def __init__(
        self,
        gui: Any,
        on_action: Callable[[str, str], None],
        on_upload: Callable[[str, bytes], None],
    ) -> None:
        self.gui = gui
        gui.add_markdown(
            "After a run: load the **full-resolution** transients into the open plots, save the chosen "
            "variables as **CSV**, download the run's **MCAP** recording (opens in Foxglove), or replay it."
        )
        self.runs = gui.add_dropdown("Run", ("—",), hint="runs of this session, newest first")
        self.info = gui.add_markdown("_No run yet._")
        self.actions = gui.add_button_group("Results", ("Full resolution", "CSV", "MCAP", "Replay"))
        self.actions.on_click(lambda e: on_action(e.target.value, self.selected()))
        self.csv_scope = gui.add_dropdown(
            "CSV columns",
            ("streamed + plotted variables", "every variable"),
            hint="what the CSV download holds",
        )
        self.upload = gui.add_upload_button(
            "Upload a recording and replay it", mime_type=".mcap", hint="an MCAP file downloaded earlier"
        )
        self.upload.on_upload(
            lambda e: e.client is not None and on_upload(e.target.value.name, e.target.value.content)
        )

    def selected(self) -> str:
        value = str(self.runs.value)
        return "" if value == "—" else value.split(" ", 1)[0]

    def show_runs(self, runs: Sequence[m.RunInfo], newest: str = "") -> None:
        options = tuple(run_label(r) for r in reversed(runs)) or ("—",)
        keep = self.selected()
        if tuple(self.runs.options) != options:
            self.runs.options = options
        want = newest or keep
        match = next((o for o in options if o.split(" ", 1)[0] == want), options[0])
        if self.runs.value != match:
            self.runs.value = match
        if runs:
            self.info.content = f"{len(runs)} run(s) kept by the server for this session."
