"""The binary sample frame: a fixed header and a row-major block of little-endian float64.

The columns of a run are announced once in its `RunLayout`; frames carry only numbers. Layout of a
frame (all little-endian), 40 bytes of header then the data:

    offset size  field
    0      4     magic  b"SMF1"
    4      2     version (1)
    6      2     flags  (1 = final frame of the run, 2 = decimated live frame)
    8      4     run_index (matches RunLayout.run_index)
    12     4     attempt (matches RunLayout.context.attempt; 0: the producer does not say)
    16     8     seq: frame number within the run, from 0
    24     8     wall_ns: wall-clock time the producer sent it (ns since the Unix epoch)
    32     4     n_rows
    36     4     n_cols
    40     8*n_rows*n_cols float64 data, row after row
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

MAGIC = b"SMF1"
VERSION = 1
FLAG_FINAL = 1
FLAG_LIVE = 2
HEADER = struct.Struct("<4sHHIIQQII")
#: The header, field by field: (name, offset, size, meaning); PROTOCOL.md §6.1 and the schema show it.
HEADER_FIELDS = (
    ("magic", 0, 4, 'b"SMF1"'),
    ("version", 4, 2, "1"),
    ("flags", 6, 2, "1 = final frame of the run, 2 = decimated live frame"),
    ("run_index", 8, 4, "= RunLayout.run_index"),
    ("attempt", 12, 4, "= RunLayout.context.attempt (0: not said); a frame of another attempt is ignored"),
    ("seq", 16, 8, "frame number within the run (per stream), from 0"),
    ("wall_ns", 24, 8, "when the producer sent the sample (ns since the Unix epoch); live frames keep it"),
    ("n_rows", 32, 4, "rows of samples"),
    ("n_cols", 36, 4, "columns per row"),
)
MAX_CELLS = 16_000_000  # 128 MB of float64: refuse anything larger before allocating


class FrameError(ValueError):
    """A frame could not be decoded; the message says which field was wrong."""


@dataclass
class Frame:
    run_index: int
    seq: int
    wall_ns: int
    rows: np.ndarray  # (n_rows, n_cols) float64
    flags: int = 0
    attempt: int = 0  # the run's attempt it belongs to (0: not said)

    @property
    def final(self) -> bool:
        return bool(self.flags & FLAG_FINAL)

    def of(self, run_index: int, attempt: int) -> bool:
        """Whether it belongs to the run and attempt a layout announces (`belongs`)."""
        return belongs(self.run_index, self.attempt, run_index, attempt)


def belongs(run_index: int, attempt: int, layout_run_index: int, layout_attempt: int) -> bool:
    """A frame belongs to a layout's run when the run indexes match and, if both say one, the attempts
    too: a frame of an earlier attempt (a host taken for lost that goes on) is nobody's now."""
    return run_index == layout_run_index and (not attempt or not layout_attempt or attempt == layout_attempt)


def superseded(run_index: int, attempt: int, layout_run_index: int, layout_attempt: int) -> bool:
    """A frame of the layout's run from an earlier attempt than the layout's: nobody's, for good (a
    later attempt's frame only came before its layout)."""
    return run_index == layout_run_index and 0 < attempt < layout_attempt


@dataclass
class Header:
    """A frame's header, read without touching its data (e.g. to count what is dropped)."""

    flags: int
    run_index: int
    seq: int
    wall_ns: int
    n_rows: int
    n_cols: int
    attempt: int = 0


def peek(payload: bytes | bytearray | memoryview) -> Header:
    """The header of a frame; FrameError if it is too short or not a frame."""
    if len(payload) < HEADER.size:
        raise FrameError(f"frame of {len(payload)} bytes is shorter than its {HEADER.size}-byte header")
    magic, version, flags, run_index, attempt, seq, wall_ns, n_rows, n_cols = HEADER.unpack_from(payload)
    if magic != MAGIC:
        raise FrameError(f"magic {bytes(magic)!r} is not {MAGIC!r}")
    if version != VERSION:
        raise FrameError(f"frame version {version} not supported (this node speaks {VERSION})")
    return Header(flags, run_index, seq, wall_ns, n_rows, n_cols, attempt)


def encode(frame: Frame) -> bytes:
    rows = np.ascontiguousarray(frame.rows, dtype="<f8")
    if rows.ndim != 2:
        raise FrameError(f"rows must be 2-D, got {rows.ndim}-D")
    head = HEADER.pack(
        MAGIC,
        VERSION,
        frame.flags,
        frame.run_index,
        frame.attempt,
        frame.seq,
        frame.wall_ns,
        rows.shape[0],
        rows.shape[1],
    )
    return head + rows.tobytes()


def decode(payload: bytes | bytearray | memoryview, last_row_only: bool = False) -> Frame:
    """Decode a frame, checking every header field; `last_row_only` keeps (and copies) only the
    newest sample, for consumers such as the hot-feedback node that forward nothing else."""
    buf = memoryview(payload)
    head = peek(buf)
    n_rows, n_cols = head.n_rows, head.n_cols
    if n_rows * n_cols > MAX_CELLS:
        raise FrameError(f"n_rows*n_cols = {n_rows * n_cols} exceeds {MAX_CELLS}")
    expected = HEADER.size + 8 * n_rows * n_cols
    if len(buf) != expected:
        raise FrameError(f"frame has {len(buf)} bytes, header announces {n_rows}x{n_cols} = {expected}")
    if last_row_only and n_rows > 1:
        offset = HEADER.size + 8 * (n_rows - 1) * n_cols
        rows = np.frombuffer(buf, dtype="<f8", offset=offset, count=n_cols).reshape(1, n_cols)
    else:
        rows = np.frombuffer(buf, dtype="<f8", offset=HEADER.size, count=n_rows * n_cols).reshape(
            n_rows, n_cols
        )
    return Frame(head.run_index, head.seq, head.wall_ns, rows.astype(np.float64), head.flags, head.attempt)
