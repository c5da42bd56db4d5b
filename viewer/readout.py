"""The digital readout (issue 32, as on a robot's teach pendant): where every joint is, in the tab's
angle unit, and where the tool is (position in mm, roll/pitch/yaw in the same angle unit), for the
arm as shown: the initial pose, a run's live pose, or a scrubbed instant. Always in sight, in the run
bar. Pure text; the tab refreshes it on its tick when it changed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .units import shown


def readout_text(joints: Sequence[str], q: Sequence[float], tool: Sequence[float] | None, angles: str) -> str:
    """Two short lines of markdown: the joints, then the tool pose (`tool`: x, y, z in m, roll,
    pitch, yaw in rad; None when not known)."""
    unit, factor = shown("rad", angles)
    digits = 1 if unit == "deg" else 3
    values = " ".join(
        f"{name.removeprefix('joint')}:{_num(x * factor, digits)}" for name, x in zip(joints, q, strict=False)
    )
    lines = [f"<small>**joints [{unit}]** {values}</small>"]
    if tool is not None and len(tool) == 6:
        xyz = " ".join(f"{axis} {_num(v * 1000.0, 0)}" for axis, v in zip("xyz", tool[:3], strict=True))
        rpy = " ".join(
            f"{axis} {_num(v * factor, digits)}" for axis, v in zip(("r", "p", "y"), tool[3:], strict=True)
        )
        lines.append(f"<small>**tool [mm, {unit}]** {xyz} · {rpy}</small>")
    return "  \n".join(lines)


def _num(x: float, digits: int) -> str:
    if not math.isfinite(x):
        return "—"
    text = f"{x:.{digits}f}"
    return "0" if text.strip("-0.") == "" else text  # no "-0.0"
