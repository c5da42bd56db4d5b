"""The results panel (paper §2.2 steps 9-11): pick a run of the session (replays are runs too), load
its transients into the plots, download it as CSV or its MCAP recording, replay it, or upload a
recording to replay. The requests are the session controller's (`results_io.py`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from simecs.mesh.protocol import messages as m

from .compare import run_summary

ACTIONS = ("Full resolution", "CSV", "MCAP", "Replay", "Continue")


def run_label(info: m.RunInfo, context: m.RunContext | None = None) -> str:
    """A run as the lists offer it: which, how it ended, how long, and what it did (compare.py)."""
    length = f"{info.sim_time:.2f} s" if info.until_stopped else f"{info.sim_time:.2f}/{info.stop_time:.2f} s"
    label = f"{info.run_id} · {info.phase} · {length}"
    what = run_summary(info, context)
    return f"{label} · {what}" if what else label


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
            "variables as **CSV**, download the run's **MCAP** recording (opens in Foxglove), or **replay** "
            "it as a new run of this session. A run that failed part way (its simulator crashed) "
            "**continues** from where its results end, as a new run."
        )
        self.runs = gui.add_dropdown("Run", ("—",), hint="runs of this session (replays too), newest first")
        self.info = gui.add_markdown("_No run yet._")
        self.actions = gui.add_button_group("Results", ACTIONS)
        self.actions.on_click(lambda e: on_action(e.target.value, self.selected()))
        self.csv_scope = gui.add_dropdown(
            "CSV columns",
            ("streamed + plotted variables", "every variable"),
            hint="what the CSV download holds",
        )
        self.upload = gui.add_upload_button(
            "Upload a recording and replay it", mime_type=".mcap", hint="an MCAP file downloaded earlier"
        )
        self.on_upload = on_upload
        self.upload.on_upload(self._uploaded)

    def _uploaded(self, event: Any) -> None:
        if event.client is not None:
            self.on_upload(event.target.value.name, event.target.value.content)

    def selected(self) -> str:
        value = str(self.runs.value)
        return "" if value == "—" else value.split(" ", 1)[0]

    def show_runs(
        self,
        runs: Sequence[m.RunInfo],
        newest: str = "",
        contexts: Mapping[str, m.RunContext | None] | None = None,
    ) -> None:
        known = contexts or {}
        options = tuple(run_label(r, known.get(r.run_id)) for r in reversed(runs)) or ("—",)
        keep = self.selected()
        if tuple(self.runs.options) != options:
            self.runs.options = options
        want = newest or keep
        match = next((o for o in options if o.split(" ", 1)[0] == want), options[0])
        if self.runs.value != match:
            self.runs.value = match
        if runs:
            self.info.content = f"{len(runs)} run(s) kept by the server for this session."
