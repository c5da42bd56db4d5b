"""How a paced run's solver call is cut into frames (nodes/pacing.py): the rules, without a mesh (the
frames a real run sends are checked in test_service)."""

from __future__ import annotations

import numpy as np
import pytest
from simecs.nodes.pacing import frame_length, frame_parts, jog_frame_length


def rows_at(times: list[float]) -> np.ndarray:
    return np.column_stack([times, np.arange(len(times), dtype=float)])


def test_a_call_of_two_frames_is_cut_where_the_first_ends_and_a_row_on_the_cut_ends_it() -> None:
    rows = rows_at([0.01, 0.02, 0.025, 0.03, 0.04, 0.05])
    parts = frame_parts(rows, 0.0, 0.025, 0.05)
    assert [(list(p[:, 0]), t) for p, t in parts] == [
        ([0.01, 0.02, 0.025], 0.025),
        ([0.03, 0.04, 0.05], 0.05),
    ]


def test_a_frame_without_rows_is_left_out_and_the_last_part_ends_the_call() -> None:
    """Rows every 40 ms in 25 ms frames: the frame (0.025, 0.05] holds none."""
    parts = frame_parts(rows_at([0.04, 0.08]), 0.0, 0.025, 0.1)
    assert [(list(p[:, 0]), t) for p, t in parts] == [([0.04], 0.05), ([0.08], 0.1)]
    assert frame_parts(rows_at([]), 0.0, 0.025, 0.05) == []


def test_the_first_call_holds_the_row_at_zero_and_a_short_last_call_is_one_part() -> None:
    parts = frame_parts(rows_at([0.0, 0.02, 0.04]), 0.0, 0.025, 0.05)
    assert [len(p) for p, _ in parts] == [2, 1]
    ((part, end),) = frame_parts(rows_at([1.99, 2.0]), 1.98, 0.025, 2.0)
    assert len(part) == 2 and end == 2.0


@pytest.mark.parametrize(
    ("speed", "output_interval", "frame"),
    [
        (1.0, 0.002, 0.025),
        (2.0, 0.002, 0.05),
        (10.0, 0.002, 0.1),
        (float("inf"), 0.002, 0.1),
        (1.0, 0.04, 0.04),
    ],
)
def test_a_frame_is_25_ms_in_real_time_longer_when_faster_and_never_shorter_than_a_sample(
    speed: float, output_interval: float, frame: float
) -> None:
    assert frame_length(speed, output_interval) == pytest.approx(frame)


@pytest.mark.parametrize(
    ("speed", "output_interval", "frame"),
    [
        (1.0, 0.002, 0.005),
        (0.5, 0.001, 0.0025),
        (4.0, 0.002, 0.02),
        (10.0, 0.002, 0.05),
        (1.0, 0.01, 0.01),
        (1.0, 0.04, 0.04),
    ],
)
def test_a_jogged_run_s_frame_is_5_ms_of_wall_time_at_least_a_sample_at_most_a_usual_frame(
    speed: float, output_interval: float, frame: float
) -> None:
    assert jog_frame_length(speed, output_interval) == pytest.approx(frame)
