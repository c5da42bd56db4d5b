"""The tool's trace in 3D (issue 12, build item 6), without a browser: it grows with the shown run's
live rows, is sent at most every REDRAW_S and whole at a run's end, stays bounded, and starts again
with the next run."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from simecs.mesh.rules.kinematics import link_poses
from simecs.viewer import trace

from .viewer_fakes import arm, layout, live_frame, loaded_tab, state


class Scene:
    """The scene calls a trace makes, kept."""

    def __init__(self) -> None:
        self.lines: list[np.ndarray] = []

    def add_line_segments(self, name: str, segments: np.ndarray, **_kw: Any) -> Any:
        self.lines.append(segments)
        return self

    def remove(self) -> None:
        pass


def test_the_trace_is_throttled_bounded_and_cleared() -> None:
    scene = Scene()
    tr = trace.ToolTrace(scene)
    tr.add(np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]), now=100.0)
    assert len(scene.lines) == 1 and scene.lines[-1].shape == (1, 2, 3)
    tr.add(np.array([[0.2, 0.0, 0.0]]), now=100.05)  # within REDRAW_S: not sent yet
    assert len(scene.lines) == 1
    tr.add(np.array([[np.nan, 0.0, 0.0]]), now=100.06)  # a row without the tool is no point
    tr.draw(now=100.1)  # the run ended: the whole trace goes out
    assert scene.lines[-1].shape == (2, 2, 3) and scene.lines[-1][-1, 1, 0] == pytest.approx(0.2)
    tr.draw(now=100.2)
    assert len(scene.lines) == 2  # nothing new: nothing sent
    many = np.column_stack([np.linspace(0, 1, trace.MAX_POINTS + 10), np.zeros((trace.MAX_POINTS + 10, 2))])
    tr.add(many, now=200.0)
    assert tr.points.shape[0] <= trace.MAX_POINTS and tr.points[-1, 0] == pytest.approx(1.0)
    tr.clear()
    assert tr.points.shape == (0, 3)


def test_the_page_draws_the_tools_trace_of_the_shown_run(server: Any) -> None:
    model = arm()
    tab, _client, page, sc = loaded_tab(server, model)
    try:
        lay = layout(sc, model, "r1")
        sc.watched["on_layout"](lay)
        qs = [[0.1 * k, -0.05 * k, 0.02 * k] for k in range(5)]
        for k, q in enumerate(qs):
            sc.watched["on_live"](live_frame(lay, model, q, t=0.1 * k))
        sc.watched["on_state"](state(sc, "finished", "r1", seq=20, sim_time=0.5))
        expected = np.array([link_poses(model, lay.context.values, q)[-1, :3] for q in qs])
        np.testing.assert_allclose(page.trace.points, expected, atol=1e-12)
        assert page.trace._drawn == len(qs)  # the whole trace sent once the run ended
        sc.watched["on_layout"](layout(sc, model, "r2"))  # the next run starts its own
        assert page.trace.points.shape == (0, 3) and page.trace._line is None
    finally:
        tab.close()
        page.remove()
