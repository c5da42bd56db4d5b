"""Reading simecs recordings back: strict validation and tolerant loading (mcaprepair.py repairs torn
files). Every error names the file and what is wrong with it.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import msgspec
import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import StreamReader, breakup_chunk
from simecs.mesh.protocol import codec, limits
from simecs.mesh.protocol import messages as m

from . import mcapfmt as fmt

MAGIC = b"\x89MCAP0\r\n"
FOOTER_LEN = 1 + 8 + 8 + 8 + 4  # opcode, record length, summary_start, summary_offset_start, crc


class RecordingError(ValueError):
    """A file is not a usable recording; the message starts with the file name."""


class BoundExceeded(ValueError):
    """A chunk beyond an upload bound (PROTOCOL.md §4.1): not damaged, too large to be read."""


def _name(source: str | os.PathLike[str] | bytes) -> str:
    return "uploaded file" if isinstance(source, bytes | bytearray) else str(source)


def _open(source: str | os.PathLike[str] | bytes) -> IO[bytes]:
    if isinstance(source, bytes | bytearray):
        return io.BytesIO(source)
    try:
        return open(source, "rb")  # noqa: SIM115 - callers close it
    except OSError as exc:
        raise RecordingError(f"{source}: cannot open: {exc.strerror}") from None


def has_footer(path: str | os.PathLike[str]) -> bool:
    """True when the file ends with a footer and the closing magic (a finished file)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            if size < 2 * len(MAGIC) + FOOTER_LEN:
                return False
            fh.seek(size - len(MAGIC) - FOOTER_LEN)
            tail = fh.read()
    except OSError:
        return False
    return tail[-len(MAGIC) :] == MAGIC and tail[0] == 0x02


@dataclass
class Scan:
    """Everything readable in a file, in file order."""

    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    attachments: list[Attachment] = field(default_factory=list)
    statistics: Statistics | None = None
    complete: bool = False  # footer and closing magic read
    bad_chunks: int = 0
    problem: str = ""  # why reading stopped before the footer ("" when it did not)
    size: int = 0
    unpacked: int = 0  # bytes of chunks decompressed so far (bounded: mesh/protocol/limits.py)
    records: int = 0  # records read so far, those inside chunks too (bounded: mesh/protocol/limits.py)


class _KnownRecordsReader(StreamReader):
    """A StreamReader that stops at a record of no MCAP opcode instead of skipping it: the library
    skips them silently, so a file of zero bytes after the magic (9-byte records of opcode 0) kept a
    node reading for minutes. A recording is only ever made of MCAP's own records."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode not in _OPCODES:
            raise McapError(f"record of unknown opcode {opcode:#04x} (not an MCAP record)")
        return super()._read_record(opcode, length)


_OPCODES = frozenset(int(op) for op in Opcode)


def scan(source: str | os.PathLike[str] | bytes, strict: bool = False, keep_messages: bool = True) -> Scan:
    """Read every record with CRC validation. `strict`: any defect raises RecordingError; otherwise a
    bad chunk is skipped and a torn end stops the scan, both reported in `problem`."""
    name = _name(source)
    out = Scan()
    stream = _open(source)
    try:
        stream.seek(0, os.SEEK_END)
        out.size = stream.tell()
        stream.seek(0)
        if out.size < len(MAGIC) or stream.read(len(MAGIC)) != MAGIC:
            raise RecordingError(f"{name}: not an MCAP file (it does not start with the MCAP magic bytes)")
        stream.seek(0)
        reader = (_KnownRecordsReader if strict else StreamReader)(
            stream, emit_chunks=True, validate_crcs=True, record_size_limit=limits.limit("upload_bytes")
        )
        records = reader.records
        while True:
            try:
                record = next(records)
            except StopIteration:
                out.complete = True
                if stream.tell() != out.size:
                    out.complete = False
                    out.problem = f"{out.size - stream.tell()} bytes after the footer's magic (not MCAP)"
                break
            except McapError as exc:
                what = (
                    "data section CRC mismatch"
                    if "crc" in str(exc).lower()
                    else str(exc) or type(exc).__name__
                )
                if type(exc).__name__ == "EndOfFile":
                    what = "the file ends in the middle of a record (torn write)"
                out.problem = f"{what} (after byte {stream.tell()} of {out.size})"
                break
            except (struct.error, ValueError, UnicodeDecodeError) as exc:
                out.problem = f"unreadable record near byte {stream.tell()}: {exc}"
                break
            if isinstance(record, Chunk):
                try:
                    inner = _chunk_records(record, out)
                except BoundExceeded as exc:  # too large to read: no part of it is taken
                    msg = f"chunk ending near byte {stream.tell()}: {exc}"
                    if strict:
                        raise RecordingError(f"{name}: {msg}") from None
                    out.bad_chunks += 1
                    out.problem = out.problem or msg
                    continue
                except (McapError, ValueError, zlib.error, struct.error, zstandard.ZstdError) as exc:
                    out.bad_chunks += 1
                    msg = f"chunk ending near byte {stream.tell()} is damaged: {exc}"
                    if strict:
                        raise RecordingError(f"{name}: {msg}") from None
                    out.problem = out.problem or msg
                    continue
                for rec in inner:
                    _take(out, rec, keep_messages)
            else:
                try:
                    _count(out, 1)
                except BoundExceeded as exc:  # a flood of small records: read no further
                    if strict:
                        raise RecordingError(f"{name}: {exc}") from None
                    out.problem = str(exc)
                    break
                _take(out, record, keep_messages)
    finally:
        stream.close()
    if strict and not out.complete:
        raise RecordingError(f"{name}: incomplete MCAP: {out.problem or 'no footer'}")
    return out


def _json(text: str | bytes) -> Any:
    """JSON of a file's metadata or log: any defect is a ValueError (deep nesting too, which json
    reports as RecursionError), so a hostile upload is refused, never a crash of its reader."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("JSON nested too deeply") from None


def _chunk_records(chunk: Chunk, out: Scan) -> list[Any]:
    """A chunk's records, decompressed within the bounds of mesh/protocol/limits.py (a few KB of zstd
    can claim gigabytes): the chunk's size as declared and as it comes out, and the whole file's so far."""
    per_chunk, per_file = limits.LIMITS["upload_chunk_bytes"], limits.LIMITS["upload_decompressed_bytes"]
    if chunk.uncompressed_size > per_chunk.value:
        raise BoundExceeded(
            f"a chunk declares {chunk.uncompressed_size:,} bytes decompressed, more than "
            f"upload_chunk_bytes = {limits.human(per_chunk.value, per_chunk.unit)}"
        )
    if out.unpacked + chunk.uncompressed_size > per_file.value:
        raise BoundExceeded(
            f"its chunks declare more than upload_decompressed_bytes = "
            f"{limits.human(per_file.value, per_file.unit)} decompressed"
        )
    if chunk.compression == "zstd":
        reader = zstandard.ZstdDecompressor().stream_reader(chunk.data)
        data = reader.read(chunk.uncompressed_size + 1)
        while len(data) <= chunk.uncompressed_size:
            more = reader.read(chunk.uncompressed_size + 1 - len(data))
            if not more:
                break
            data += more
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=chunk.uncompressed_size + 1)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unknown chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise ValueError(
            f"a chunk declares {chunk.uncompressed_size} bytes decompressed and holds {len(data)}"
        )
    out.unpacked += len(data)
    _count(out, _records_in(data, limits.limit("upload_records") - out.records))
    plain = dataclasses.replace(chunk, compression="", data=data)
    return breakup_chunk(plain, validate_crc=True)


def _records_in(data: bytes, most: int) -> int:
    """How many records a chunk's data holds (its records' headers walked, none decoded), counting
    no further than one past `most`: a 64 MiB chunk of empty messages holds two million."""
    count, pos, end = 0, 0, len(data)
    while pos + 9 <= end and count <= most:
        pos += 9 + int.from_bytes(data[pos + 1 : pos + 9], "little")
        count += 1
    return count


def _count(out: Scan, records: int) -> None:
    """Add `records` to those read; more than upload_records is a recording no run makes."""
    out.records += records
    bound = limits.LIMITS["upload_records"]
    if out.records > bound.value:
        most = limits.human(bound.value, bound.unit)
        raise BoundExceeded(f"more than upload_records = {most} MCAP records")


def _take(out: Scan, rec: Any, keep_messages: bool) -> None:
    if isinstance(rec, Message):
        if keep_messages:
            out.messages.append(rec)
    elif isinstance(rec, Schema):
        out.schemas.setdefault(rec.id, rec)
    elif isinstance(rec, Channel):
        out.channels.setdefault(rec.id, rec)
    elif isinstance(rec, Metadata):
        out.metadata.append(rec)
    elif isinstance(rec, Attachment):
        out.attachments.append(rec)
    elif isinstance(rec, Header):
        out.header = rec
    elif isinstance(rec, Statistics):
        out.statistics = rec
    elif isinstance(rec, DataEnd | Footer):
        pass


@dataclass
class Validation:
    """What a strict read of a finished file found."""

    messages: int
    per_topic: dict[str, int]
    chunks: int
    metadata: dict[str, dict[str, str]]
    attachments: list[str]


def validate(source: str | os.PathLike[str] | bytes) -> Validation:
    """Strict check of a finished file: magic, every chunk CRC, the data section CRC, the summary CRC,
    and the statistics' message counts against the messages actually stored."""
    name = _name(source)
    sc = scan(source, strict=True)
    data = source if isinstance(source, bytes | bytearray) else Path(source).read_bytes()
    footer_at = len(data) - len(MAGIC) - FOOTER_LEN
    summary_start, summary_offset_start, summary_crc = struct.unpack_from("<QQI", data, footer_at + 9)
    if summary_crc:
        start = summary_start if summary_start else footer_at
        actual = zlib.crc32(data[start : footer_at + 1 + 8 + 8 + 8])
        if actual != summary_crc:
            raise RecordingError(
                f"{name}: summary CRC mismatch (stored {summary_crc:#x}, computed {actual:#x})"
            )
    per_channel: dict[int, int] = {}
    for msg in sc.messages:
        if msg.channel_id not in sc.channels:
            raise RecordingError(f"{name}: message on undeclared channel {msg.channel_id}")
        per_channel[msg.channel_id] = per_channel.get(msg.channel_id, 0) + 1
    st = sc.statistics
    if st is not None:
        if st.message_count != len(sc.messages):
            raise RecordingError(
                f"{name}: statistics announce {st.message_count} messages, the file holds {len(sc.messages)}"
            )
        for cid, count in st.channel_message_counts.items():
            if per_channel.get(cid, 0) != count:
                topic = sc.channels[cid].topic if cid in sc.channels else cid
                raise RecordingError(
                    f"{name}: statistics announce {count} messages on {topic}, the file holds "
                    f"{per_channel.get(cid, 0)}"
                )
    per_topic = {sc.channels[cid].topic: n for cid, n in per_channel.items()}
    return Validation(
        messages=len(sc.messages),
        per_topic=per_topic,
        chunks=st.chunk_count if st else 0,
        metadata={md.name: dict(md.metadata) for md in sc.metadata},
        attachments=[a.name for a in sc.attachments],
    )


# -- loading a recording --------------------------------------------------------------------------
@dataclass
class Recording:
    """A run read back: its layout, every row at full resolution, metadata and log."""

    path: str
    layout: m.RunLayout
    rows: np.ndarray  # (n, len(layout.columns)) float64, in layout column order
    seqs: np.ndarray  # frame number of each row (the MCAP sequence of its /vars message)
    metadata: dict[str, dict[str, str]]
    logs: list[dict[str, Any]]
    complete: bool
    recovered: bool
    problem: str = ""
    attachments: dict[str, bytes] = field(default_factory=dict)

    @property
    def columns(self) -> list[str]:
        return list(self.layout.columns)

    @property
    def duration(self) -> float:
        return float(self.rows[-1, 0] - self.rows[0, 0]) if len(self.rows) > 1 else 0.0

    def frames(self) -> Iterator[tuple[int, int, int]]:
        """(frame seq, first row, end row) of the frames the rows arrived in."""
        n = len(self.seqs)
        if n == 0:
            return
        cuts = np.flatnonzero(np.diff(self.seqs)) + 1
        starts = [0, *cuts.tolist()]
        ends = [*cuts.tolist(), n]
        for a, b in zip(starts, ends, strict=True):
            yield int(self.seqs[a]), a, b

    def params(self) -> dict[str, float]:
        return dict(self.layout.context.values)

    @property
    def jogged_s(self) -> float:
        """Simulated s during which a jog moved the arm, as the run's last report said (`simecs.end`);
        0 when the file does not say (not jogged, closed without its end, or written before)."""
        return _float(self.metadata.get(fmt.META_END, {}).get("jogged_s", "0"))

    def context(self, recording: str = "") -> m.RunContext:
        """What produced the recorded run; `recording`: the name it is replayed under."""
        return msgspec.structs.replace(
            self.layout.context, recording=recording or self.layout.context.recording
        )


def _layout_of(name: str, metadata: dict[str, dict[str, str]]) -> m.RunLayout:
    run = metadata.get(fmt.META_RUN)
    if run is None or "layout" not in run:
        raise RecordingError(f"{name}: not a simecs recording (no {fmt.META_RUN} metadata with a layout)")
    version = run.get("format_version", "")
    if version not in fmt.READABLE_VERSIONS:
        raise RecordingError(
            f"{name}: recording format version {version!r} is not supported "
            f"(this reader: {', '.join(fmt.READABLE_VERSIONS)})"
        )
    try:
        if version == "1":  # the context lived in other metadata records then
            layout = _json(run["layout"])
            layout["context"] = codec.to_obj(_context_of_metadata(metadata))
            return codec.from_obj(m.RunLayout, layout)
        return codec.loads(m.RunLayout, run["layout"])
    except (codec.DecodeError, ValueError, TypeError) as exc:
        raise RecordingError(f"{name}: its layout metadata is invalid: {exc}") from None


def _context_of_metadata(metadata: dict[str, dict[str, str]]) -> m.RunContext:
    """The run's context from `simecs.params` and `simecs.session` (how format 1 kept it)."""
    session = metadata.get(fmt.META_SESSION, {})
    values = {k: float(v) for k, v in metadata.get(fmt.META_PARAMS, {}).items()}
    command = _json(session["command"]) if session.get("command") not in (None, "", "null") else None
    return m.RunContext(
        user=session.get("user") or "unknown",
        values=values,
        initial=[float(q) for q in _json(session.get("initial") or "[]")],
        command=codec.from_obj(m.RobotCommand, command) if command is not None else None,  # type: ignore[arg-type]
        settings=codec.from_obj(m.RunSettings, _json(session["settings"]))
        if session.get("settings")
        else m.RunSettings(),
    )


#: The longest run a recording can hold (RunSettings.stop_time's bound), s.
MAX_RUN_S = 3600.0


def playable_problem(rec: Recording) -> str:
    """What keeps a recording from being replayed as a run ('' if nothing): every value finite, times
    from 0 on, never decreasing, within a run's longest stop time."""
    rows, columns = rec.rows, rec.layout.columns
    if rows.size and not np.all(np.isfinite(rows)):
        r, c = (int(x[0]) for x in np.nonzero(~np.isfinite(rows)))
        return f"sample {r}: {columns[c]} is not a finite number"
    times = rows[:, 0] if rows.size else np.zeros(0)
    outside = np.nonzero((times < 0) | (times > MAX_RUN_S))[0]
    if outside.size:
        k = int(outside[0])
        return f"sample {k}: time {times[k]:g} s is outside [0, {MAX_RUN_S:g}] s"
    back = np.nonzero(np.diff(times) < 0)[0]
    if back.size:
        k = int(back[0]) + 1
        return f"sample {k}: time {times[k]:g} s goes back from {times[k - 1]:g} s"
    stop = rec.layout.stop_time
    if not (math.isfinite(stop) and 0 <= stop <= MAX_RUN_S):
        return f"stop_time {stop:g} s is outside [0, {MAX_RUN_S:g}] s"
    return ""


def load(source: str | os.PathLike[str] | bytes, strict: bool = False) -> Recording:
    """Read a recording (finished, or torn and not yet repaired: whatever is readable)."""
    name = _name(source)
    sc = scan(source, strict=strict)
    metadata = {md.name: dict(md.metadata) for md in sc.metadata}
    layout = _layout_of(name, metadata)
    vars_ch = next((c for c in sc.channels.values() if c.topic == fmt.TOPIC_VARS), None)
    log_ch = next((c.id for c in sc.channels.values() if c.topic == fmt.TOPIC_LOG), None)
    ncols = len(layout.columns)
    order = np.arange(ncols)
    if vars_ch is not None:
        try:
            msg_cols = _json(vars_ch.metadata.get("columns", "null")) or list(layout.columns)
            index = {c: i for i, c in enumerate(layout.columns)}
            order = np.array([index[c] for c in msg_cols], dtype=np.int64)
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordingError(
                f"{name}: {fmt.TOPIC_VARS} channel columns do not match the layout: {exc}"
            ) from None
        if vars_ch.message_encoding != "cdr":
            raise RecordingError(f"{name}: {fmt.TOPIC_VARS} is encoded {vars_ch.message_encoding!r}, not cdr")
    payloads = [msg for msg in sc.messages if vars_ch is not None and msg.channel_id == vars_ch.id]
    rows = np.empty((len(payloads), ncols))
    seqs = np.empty(len(payloads), dtype=np.int64)
    log_times = np.array([msg.log_time for msg in payloads], dtype=np.int64)
    expected = len(fmt.CDR_HEADER) + 8 * len(order)
    for i, msg in enumerate(payloads):
        data = msg.data
        if len(data) != expected or data[:4] != fmt.CDR_HEADER:
            raise RecordingError(
                f"{name}: {fmt.TOPIC_VARS} message {i} has {len(data)} bytes, expected {expected}"
            )
        rows[i, order] = np.frombuffer(data, dtype="<f8", offset=4)
        seqs[i] = msg.sequence
    if len(rows) > 1 and np.any(np.diff(log_times) < 0):  # a gap filled after the run (RECORDINGS.md)
        # in the order every MCAP reader shows them: by log time (the recorder's is the sample's
        # time); a time column that still goes back is the file's own fault (playable_problem)
        by_log_time = np.argsort(log_times, kind="stable")
        rows, seqs = rows[by_log_time], seqs[by_log_time]
    logs = []
    for msg in sc.messages:
        if msg.channel_id == log_ch:
            try:
                logs.append(_json(msg.data))
            except ValueError:
                logs.append({"message": "<unreadable log message>", "level": 0})
    return Recording(
        path=name,
        layout=layout,
        rows=rows,
        seqs=seqs,
        metadata=metadata,
        logs=logs,
        complete=sc.complete,
        recovered=fmt.META_RECOVERY in metadata,
        problem=sc.problem,
        attachments={a.name: a.data for a in sc.attachments},
    )


# -- listing --------------------------------------------------------------------------------------
def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, str]]:
    """The metadata records of a file: from the summary index when finished, else a linear scan."""
    if has_footer(path):
        try:
            with open(path, "rb") as fh:
                return {md.name: dict(md.metadata) for md in SeekingReader(fh).iter_metadata()}
        except (McapError, OSError, ValueError, struct.error):
            pass
    return {md.name: dict(md.metadata) for md in scan(path, keep_messages=False).metadata}


def info(path: str | os.PathLike[str]) -> m.RecordingInfo:
    """What the recording list shows for one file."""
    p = Path(path)
    meta = read_metadata(p)
    run = meta.get(fmt.META_RUN)
    if run is None:
        raise RecordingError(f"{p}: not a simecs recording (no {fmt.META_RUN} metadata)")
    return m.RecordingInfo(
        name=p.name[: -len(".mcap")] if p.name.endswith(".mcap") else p.name,
        session=run.get("session", ""),
        run_id=run.get("run_id", ""),
        model_id=run.get("model_id", ""),
        bytes=p.stat().st_size,
        recovered=fmt.META_RECOVERY in meta,
        stop_time=_float(run.get("stop_time", "0")),
        created=created_of(run, p),
    )


def created_of(run_meta: dict[str, str], path: str | os.PathLike[str]) -> str:
    """When a recording was made (RecordingInfo.created): its `created_ns`, else the file's mtime."""
    try:
        ns = int(run_meta.get("created_ns", ""))
    except ValueError:
        ns = 0
    if not 0 < ns < 2**63:
        try:
            ns = os.stat(path).st_mtime_ns
        except OSError:
            return ""
    return iso_utc(ns)


def iso_utc(ns: int) -> str:
    """A time in ns since the Unix epoch as UTC ISO 8601 to the second: 2026-11-27T16:18:42Z."""
    try:
        return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(ns // 1_000_000_000))
    except (OverflowError, OSError, ValueError):
        return ""


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        return 0.0
    return value if 0.0 <= value < 1e9 else 0.0
