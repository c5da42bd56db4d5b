"""`simecs bench control`: the control systems of paper §5 on the Spider's full drive train.

- `rtf_opspace`: simulated s per wall s of the standard LIN move (benchmarks/commands.py: 0.5 m at
  50 %, and 1 s after it) under operational-space motion control, as fast as possible on one core,
  best of 3; `rtf_joint_independent` the same under the joint cascade, for scale;
- `opspace_tracking_error_mm`: the largest distance of the tool from its set point (`tool.e_pos`, the
  tool pose of the joint set points) over that run, operational-space control;
  `joint_independent_tracking_error_mm` the same move under the joint cascade, in the same bench run;
  `*_rms_mm` their RMS, `*_orientation_error_mrad` the largest `tool.e_rot`;
- `*_hold_error_mm`: the largest `tool.e_pos` over the last 0.5 s (the target held at rest).

Per model in `per_model` (Spider and PUMA 560); the top-level keys are the Spider's.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from .commands import run_line, standard_line

SYSTEMS = ("opspace", "joint_independent")
SYSTEM_NAMES = {"opspace": "opspace_motion", "joint_independent": "joint_independent"}
MODELS = ("spider", "puma560")
HOLD_WINDOW_S = 0.5


def _figures(model_id: str) -> dict[str, float]:
    line = standard_line(model_id)
    out: dict[str, float] = {}
    for short in SYSTEMS:
        cols, rows, wall = run_line(line, SYSTEM_NAMES[short])
        e_pos = rows[:, cols.index("tool.e_pos")]
        e_rot = rows[:, cols.index("tool.e_rot")]
        hold = rows[:, 0] >= rows[-1, 0] - HOLD_WINDOW_S
        out[f"rtf_{short}"] = float(rows[-1, 0] / wall)
        out[f"{short}_tracking_error_mm"] = float(e_pos.max() * 1e3)
        out[f"{short}_tracking_rms_mm"] = float(np.sqrt(np.mean(e_pos**2)) * 1e3)
        out[f"{short}_orientation_error_mrad"] = float(e_rot.max() * 1e3)
        out[f"{short}_hold_error_mm"] = float(e_pos[hold].max() * 1e3)
    return out


def run_control_bench(as_json: bool = False) -> dict[str, Any]:
    from simecs.models import warmup

    warmup()
    per_model = {model_id: _figures(model_id) for model_id in MODELS}
    result: dict[str, Any] = dict(per_model["spider"])
    result["per_model"] = per_model
    if as_json:
        print(json.dumps(result, indent=1))
    else:
        for model_id, figures in per_model.items():
            print(model_id)
            for k, v in figures.items():
                print(f"  {k:40s} {v:12.4g}")
    return result
