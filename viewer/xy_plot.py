"""One variable against another (issue 12, runs compared: e.g. the tool's x against its y), drawn as
an SVG picture in an HTML widget.

uPlot, viser's chart, needs an ascending x shared by every series (its other mode takes data viser
cannot send), so a curve such as the tool's path in a plane, which turns back on itself, is drawn here
instead: a polyline per run, decimated to `XY_POINTS`, nice ticks, and a dot where the time cursor is.
Only numbers we computed and escaped labels reach the markup.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape

import numpy as np

XY_POINTS = 1500  # points per curve drawn (a run's full resolution is decimated to this)
WIDTH, HEIGHT = 360, 260
LEFT, RIGHT, TOP, BOTTOM = 52, 10, 10, 40  # margins for tick labels and axis names
#: Drawn in WIDTH x HEIGHT units and scaled to the panel's width (a narrow dock shrinks it).
FRAME = f'viewBox="0 0 {WIDTH} {HEIGHT}" width="100%" xmlns="http://www.w3.org/2000/svg"'


@dataclass
class XYLine:
    """One run's curve: y against x, in the units shown."""

    label: str
    colour: str
    xs: np.ndarray
    ys: np.ndarray
    dash: str = ""  # SVG stroke-dasharray ('' : solid)


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """About `count` round values covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(count - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]


def _finite(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(xs) & np.isfinite(ys)
    xs, ys = xs[ok], ys[ok]
    if len(xs) > XY_POINTS:
        keep = np.linspace(0, len(xs) - 1, XY_POINTS).astype(int)
        xs, ys = xs[keep], ys[keep]
    return xs, ys


def svg(
    lines: Sequence[XYLine], x_label: str, y_label: str, marks: Sequence[tuple[float, float]] = ()
) -> str:
    """The picture: every line on shared axes fitted to all of them, and a dot at each mark."""
    curves = [(line, *_finite(np.asarray(line.xs, float), np.asarray(line.ys, float))) for line in lines]
    xs_all = np.concatenate([c[1] for c in curves]) if curves else np.empty(0)
    ys_all = np.concatenate([c[2] for c in curves]) if curves else np.empty(0)
    if not len(xs_all):
        return (
            f"<svg {FRAME}>"
            f'<text x="{WIDTH / 2}" y="{HEIGHT / 2}" text-anchor="middle" font-size="12" fill="#888">'
            "no data yet</text></svg>"
        )
    x0, x1 = _padded(float(xs_all.min()), float(xs_all.max()))
    y0, y1 = _padded(float(ys_all.min()), float(ys_all.max()))
    w, h = WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM

    def px(x: float) -> float:
        return LEFT + (x - x0) / (x1 - x0) * w

    def py(y: float) -> float:
        return TOP + (y1 - y) / (y1 - y0) * h

    out = [
        f'<svg {FRAME} font-size="11" font-family="sans-serif">',
        f'<rect x="{LEFT}" y="{TOP}" width="{w}" height="{h}" fill="none" stroke="#ccc"/>',
    ]
    for t in nice_ticks(x0, x1):
        out.append(f'<line x1="{px(t):.1f}" y1="{TOP}" x2="{px(t):.1f}" y2="{TOP + h}" stroke="#eee"/>')
        out.append(f'<text x="{px(t):.1f}" y="{TOP + h + 14}" text-anchor="middle">{t:g}</text>')
    for t in nice_ticks(y0, y1):
        out.append(f'<line x1="{LEFT}" y1="{py(t):.1f}" x2="{LEFT + w}" y2="{py(t):.1f}" stroke="#eee"/>')
        out.append(f'<text x="{LEFT - 4}" y="{py(t) + 4:.1f}" text-anchor="end">{t:g}</text>')
    out.append(f'<text x="{LEFT + w / 2}" y="{HEIGHT - 6}" text-anchor="middle">{escape(x_label)}</text>')
    out.append(
        f'<text x="12" y="{TOP + h / 2}" text-anchor="middle" transform="rotate(-90 12 {TOP + h / 2})">'
        f"{escape(y_label)}</text>"
    )
    for line, xs, ys in curves:
        points = " ".join(f"{px(x):.1f},{py(y):.1f}" for x, y in zip(xs, ys, strict=True))
        dash = f' stroke-dasharray="{escape(line.dash)}"' if line.dash else ""
        stroke = f'stroke="{escape(line.colour)}" stroke-width="1.5"{dash}'
        out.append(
            f'<polyline points="{points}" fill="none" {stroke}><title>{escape(line.label)}</title></polyline>'
        )
    for x, y in marks:
        if math.isfinite(x) and math.isfinite(y):
            out.append(f'<circle cx="{px(x):.1f}" cy="{py(y):.1f}" r="4" fill="#444"/>')
    out.append("</svg>")
    legend = " · ".join(
        f'<span style="color:{escape(line.colour)}">━</span> {escape(line.label)}' for line, _x, _y in curves
    )
    return "".join(out) + f'<div style="font-size:11px">{legend}</div>'


def _padded(lo: float, hi: float) -> tuple[float, float]:
    if hi <= lo:
        return lo - 0.5, hi + 0.5
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad
