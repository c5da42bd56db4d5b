"""The binary frame codec: round trips and refusal of malformed frames."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simecs.mesh.protocol import frames


def test_round_trip() -> None:
    rows = np.arange(12, dtype=float).reshape(3, 4) * 0.5
    f = frames.Frame(run_index=7, seq=42, wall_ns=123456789, rows=rows, flags=frames.FLAG_FINAL, attempt=3)
    back = frames.decode(frames.encode(f))
    assert (back.run_index, back.seq, back.wall_ns, back.flags) == (7, 42, 123456789, frames.FLAG_FINAL)
    assert back.attempt == 3 == frames.peek(frames.encode(f)).attempt
    assert back.final
    np.testing.assert_array_equal(back.rows, rows)


def test_empty_frame() -> None:
    back = frames.decode(frames.encode(frames.Frame(1, 0, 0, np.empty((0, 5)))))
    assert back.rows.shape == (0, 5)


def test_header_layout_is_the_documented_one() -> None:
    data = frames.encode(frames.Frame(2, 3, 4, np.array([[1.5]]), flags=1))
    assert data[:4] == b"SMF1"
    assert int.from_bytes(data[4:6], "little") == 1
    assert int.from_bytes(data[6:8], "little") == 1
    assert int.from_bytes(data[8:12], "little") == 2
    assert int.from_bytes(data[16:24], "little") == 3
    assert int.from_bytes(data[24:32], "little") == 4
    assert int.from_bytes(data[32:36], "little") == 1
    assert int.from_bytes(data[36:40], "little") == 1
    assert np.frombuffer(data[40:], "<f8")[0] == 1.5


@pytest.mark.parametrize(
    ("mutate", "words"),
    [
        (lambda b: b[:10], "shorter than"),
        (lambda b: b"XXXX" + b[4:], "magic"),
        (lambda b: b[:4] + (9).to_bytes(2, "little") + b[6:], "version 9"),
        (lambda b: b[:-8], "header announces"),
        (
            lambda b: b[:32] + (10**6).to_bytes(4, "little") + (10**6).to_bytes(4, "little") + b[40:],
            "exceeds",
        ),
    ],
)
def test_malformed_frames_are_refused(mutate, words: str) -> None:  # noqa: ANN001
    good = frames.encode(frames.Frame(1, 0, 0, np.ones((2, 3))))
    with pytest.raises(frames.FrameError, match=words):
        frames.decode(mutate(good))


@settings(max_examples=300, deadline=None)
@given(blob=st.binary(max_size=120))
def test_random_bytes_never_crash(blob: bytes) -> None:
    try:
        frames.decode(blob)
    except frames.FrameError:
        pass


def test_last_row_only() -> None:
    rows = np.arange(12, dtype=float).reshape(4, 3)
    back = frames.decode(frames.encode(frames.Frame(1, 0, 0, rows)), last_row_only=True)
    np.testing.assert_array_equal(back.rows, rows[-1:])
    empty = frames.decode(frames.encode(frames.Frame(1, 0, 0, np.empty((0, 3)))), last_row_only=True)
    assert empty.rows.shape == (0, 3)
