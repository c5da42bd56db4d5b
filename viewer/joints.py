"""One slider per joint (paper §5.2): the initialisation panel, and the destination editor of the
joint path, which the paper says are identical. The 3D arm follows every move at once: the tab
poses it with the forward kinematics of the model description (a kinematic simulation).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from simecs.mesh.protocol.model import InitEquation, Link

from .markup import escape_html
from .path import DEG, clamp_to_limits


def to_deg(q: Sequence[float]) -> list[float]:
    return [round(float(x) * DEG, 3) for x in q]


def to_rad(deg: Sequence[float]) -> list[float]:
    return [float(x) / DEG for x in deg]


class JointSliders:
    """Sliders in degrees, one per joint, within the joint ranges; `on_change(q_rad)` on user moves."""

    def __init__(
        self,
        gui: Any,
        links: Sequence[Link],
        q: Sequence[float],
        on_change: Callable[[list[float]], None],
        label: str = "{joint} [deg]",
    ):
        self.links = list(links)
        self.on_change = on_change
        self.moved = -1  # the slider the user moved last (its joint's index)
        self.sliders = []
        for link, deg in zip(self.links, to_deg(q), strict=True):
            lo, hi = math.ceil(link.joint_min * DEG * 10) / 10, math.floor(link.joint_max * DEG * 10) / 10
            slider = gui.add_slider(
                label.format(joint=link.joint),
                min=lo,
                max=hi,
                step=0.1,
                initial_value=min(max(deg, lo), hi),
                hint=f"{link.joint}: {lo:g} … {hi:g} deg ({link.joint_min:.4g} … {link.joint_max:.4g} rad)",
            )
            slider.on_update(self._moved)
            self.sliders.append(slider)

    def _moved(self, event: Any) -> None:
        if event.client is None:
            return
        self.moved = next((k for k, s in enumerate(self.sliders) if s is event.target), -1)
        self.on_change(self.q)

    @property
    def q(self) -> list[float]:
        return clamp_to_limits(to_rad([s.value for s in self.sliders]), self.links)

    def set_q(self, q: Sequence[float]) -> None:
        for slider, deg in zip(self.sliders, to_deg(q), strict=True):
            deg = min(max(deg, slider.min), slider.max)
            if abs(slider.value - deg) > 1e-9:
                slider.value = deg

    def set_disabled(self, disabled: bool) -> None:
        for s in self.sliders:
            s.disabled = disabled


def init_equations_markdown(eqs: Sequence[InitEquation]) -> str:
    """The model's initialisation equations (paper §5.2) as a table the user can read."""
    if not eqs:
        return "_The model computes its internal states at rest from the joint positions._"
    rows = ["| state | = | meaning |", "|---|---|---|"]
    for e in eqs:
        expr = e.expression.replace("|", "\\|")
        rows.append(f"| `{e.state}` | `{expr}` | {escape_html(e.description).replace('|', '/')} |")
    return "\n".join(rows)


class InitPanel:
    """The initialisation panel: the robot starts at rest where these sliders put it."""

    def __init__(
        self,
        gui: Any,
        links: Sequence[Link],
        eqs: Sequence[InitEquation],
        q: Sequence[float],
        on_change: Callable[[list[float]], None],
        on_reset: Callable[[], None],
    ) -> None:
        gui.add_markdown(
            "Move the joints: the 3D arm follows at once. The run starts **at rest** in this pose; "
            "the server computes every internal state from it with the model's equations:"
        )
        self.sliders = JointSliders(gui, links, q, on_change)
        zero = gui.add_button("All joints to zero")
        zero.on_click(lambda _e: on_reset())
        with gui.add_folder("Initialisation equations", expand_by_default=False):
            gui.add_markdown(init_equations_markdown(eqs))
