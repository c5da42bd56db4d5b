"""An MCAP file written record by record: chunks, message indexes, the summary and the footer.

The recorder appends the full-rate `/vars` channel in bulk (`add_records`: rows already laid out as
Message records) and needs the chunk's bookkeeping at that speed; the mcap package's writer offers one
message at a time (~10 us each), and adding bulk appends to it meant reaching into its private state.
This writes the format (mcap.dev/spec) itself, with the same choices as that writer: schemas and
channels inside the first chunk that has messages and repeated in the summary, a message index per
channel after each chunk, metadata and attachments between chunks, statistics, every index and the
summary offsets, data and summary CRCs. The tests read every file back with the mcap package's
reader, CRCs checked.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Mapping
from typing import IO

import numpy as np
import zstandard
from mcap.opcode import Opcode

MAGIC = b"\x89MCAP0\r\n"

_RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, length, channel id, sequence, log time, publish time
_MESSAGE_FIXED = 22  # channel id, sequence, log time, publish time
_INDEX_ENTRY = struct.Struct("<QQ")  # a message index entry: log time, offset in the chunk


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _string_map(items: Mapping[str, str]) -> bytes:
    body = b"".join(_string(k) + _string(v) for k, v in items.items())
    return struct.pack("<I", len(body)) + body


def _id_map(items: Mapping[int, int]) -> bytes:
    """A map<uint16, uint64> (channel id to a count or an offset)."""
    body = b"".join(struct.pack("<HQ", k, v) for k, v in items.items())
    return struct.pack("<I", len(body)) + body


def record(opcode: int, content: bytes) -> bytes:
    return _RECORD_HEAD.pack(opcode, len(content)) + content


class McapRecords:
    """One MCAP file on `stream` (opened for writing at its start), chunked, its chunks compressed by
    `compress` (named `compression` in the file: "zstd", "lz4" or "" for none). Not thread-safe."""

    def __init__(
        self,
        stream: IO[bytes],
        chunk_size: int,
        compression: str,
        compress: Callable[[bytes], bytes],
    ) -> None:
        self._out = stream
        self._chunk_size = chunk_size
        self._compression = compression
        self._compress = compress
        self._offset = 0  # bytes written to the stream
        self._data_crc = 0  # of the data section, up to the DataEnd record
        self._schemas: dict[int, bytes] = {}  # id -> Schema record
        self._channels: dict[int, bytes] = {}  # id -> Channel record
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = 0
        self._chunk_end = 0
        self._chunk_index: dict[int, bytearray] = {}  # channel -> its message index entries in the chunk
        self._chunk_indexes: list[bytes] = []
        self._attachment_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._channel_counts: dict[int, int] = {}
        self._messages = 0
        self._start = 0
        self._end = 0
        self._chunks = 0
        self._attachments = 0
        self._metadata = 0

    # ---- the data section ------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        self._out.write(data)
        self._data_crc = zlib.crc32(data, self._data_crc)
        self._offset += len(data)

    def start(self, profile: str, library: str) -> None:
        self._write(MAGIC)
        self._write(record(Opcode.HEADER, _string(profile) + _string(library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = len(self._schemas) + 1
        content = struct.pack("<H", schema_id) + _string(name) + _string(encoding)
        self._schemas[schema_id] = record(Opcode.SCHEMA, content + struct.pack("<I", len(data)) + data)
        self._chunk += self._schemas[schema_id]
        return schema_id

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str] | None = None
    ) -> int:
        channel_id = len(self._channels) + 1
        content = struct.pack("<HH", channel_id, schema_id) + _string(topic) + _string(message_encoding)
        self._channels[channel_id] = record(Opcode.CHANNEL, content + _string_map(metadata or {}))
        self._channel_counts[channel_id] = 0
        self._chunk += self._channels[channel_id]
        return channel_id

    def _counted(self, channel_id: int, n: int, first: int, last: int) -> None:
        """Chunk and file statistics for n messages of a channel logged from `first` to `last`."""
        if self._chunk_messages == 0 or first < self._chunk_start:
            self._chunk_start = first
        self._chunk_end = max(self._chunk_end, last)
        self._chunk_messages += n
        if self._messages == 0 or first < self._start:
            self._start = first
        self._end = max(self._end, last)
        self._messages += n
        self._channel_counts[channel_id] += n

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        self._chunk_index.setdefault(channel_id, bytearray()).extend(
            _INDEX_ENTRY.pack(log_time, len(self._chunk))
        )
        self._chunk += _MESSAGE_HEAD.pack(
            Opcode.MESSAGE, _MESSAGE_FIXED + len(data), channel_id, sequence, log_time, publish_time
        )
        self._chunk += data
        self._counted(channel_id, 1, log_time, log_time)
        self._maybe_end_chunk()

    def add_records(self, channel_id: int, log_times: np.ndarray, records: np.ndarray) -> None:
        """Messages already laid out as whole Message records (one per element of `records`, a
        structured array: `VarsCodec.records`) and their log times, in one write."""
        n = len(records)
        if n == 0:
            return
        base = len(self._chunk)
        size = records.dtype.itemsize
        entries = np.empty((n, 2), dtype="<u8")
        entries[:, 0] = log_times
        entries[:, 1] = np.arange(base, base + n * size, size)
        self._chunk_index.setdefault(channel_id, bytearray()).extend(entries.tobytes())
        self._chunk += records.tobytes()
        self._counted(channel_id, n, int(log_times.min()), int(log_times.max()))
        self._maybe_end_chunk()

    def _maybe_end_chunk(self) -> None:
        if len(self._chunk) > self._chunk_size:
            self.end_chunk()

    def end_chunk(self) -> None:
        """Write the chunk in progress and its message indexes (nothing while it has no message)."""
        if self._chunk_messages == 0:
            return
        raw = bytes(self._chunk)
        packed = self._compress(raw) if self._compression else raw
        chunk_start = self._offset
        head = struct.pack("<QQQI", self._chunk_start, self._chunk_end, len(raw), zlib.crc32(raw))
        content = head + _string(self._compression) + struct.pack("<Q", len(packed))
        self._write(_RECORD_HEAD.pack(Opcode.CHUNK, len(content) + len(packed)) + content)
        self._write(packed)
        chunk_length = self._offset - chunk_start
        index_offsets: dict[int, int] = {}
        indexes_start = self._offset
        for channel_id, entries in self._chunk_index.items():
            index_offsets[channel_id] = self._offset
            self._write(record(Opcode.MESSAGE_INDEX, struct.pack("<HI", channel_id, len(entries)) + entries))
        self._chunk_indexes.append(
            record(
                Opcode.CHUNK_INDEX,
                struct.pack("<QQQQ", self._chunk_start, self._chunk_end, chunk_start, chunk_length)
                + _id_map(index_offsets)
                + struct.pack("<Q", self._offset - indexes_start)
                + _string(self._compression)
                + struct.pack("<QQ", len(packed), len(raw)),
            )
        )
        self._chunks += 1
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = self._chunk_end = 0
        self._chunk_index = {}

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        offset = self._offset
        self._write(record(Opcode.METADATA, _string(name) + _string_map(data)))
        self._metadata_indexes.append(
            record(Opcode.METADATA_INDEX, struct.pack("<QQ", offset, self._offset - offset) + _string(name))
        )
        self._metadata += 1

    def add_attachment(
        self, log_time: int, create_time: int, name: str, media_type: str, data: bytes
    ) -> None:
        offset = self._offset
        content = (
            struct.pack("<QQ", log_time, create_time)
            + _string(name)
            + _string(media_type)
            + struct.pack("<Q", len(data))
            + data
        )
        self._write(record(Opcode.ATTACHMENT, content + struct.pack("<I", zlib.crc32(content))))
        self._attachment_indexes.append(
            record(
                Opcode.ATTACHMENT_INDEX,
                struct.pack("<QQQQQ", offset, self._offset - offset, log_time, create_time, len(data))
                + _string(name)
                + _string(media_type),
            )
        )
        self._attachments += 1

    def flush(self) -> None:
        """End the chunk in progress and hand everything written to the operating system."""
        self.end_chunk()
        self._out.flush()

    # ---- the summary -----------------------------------------------------------------------------
    def finish(self) -> None:
        """End the data section and write the summary, its offsets, the footer and the closing magic."""
        self.end_chunk()
        self._write(record(Opcode.DATA_END, struct.pack("<I", self._data_crc)))
        summary_start = self._offset
        statistics = record(
            Opcode.STATISTICS,
            struct.pack(
                "<QHIIIIQQ",
                self._messages,
                len(self._schemas),
                len(self._channels),
                self._attachments,
                self._metadata,
                self._chunks,
                self._start,
                self._end,
            )
            + _id_map(self._channel_counts),
        )
        groups = [
            (Opcode.SCHEMA, b"".join(self._schemas.values())),
            (Opcode.CHANNEL, b"".join(self._channels.values())),
            (Opcode.STATISTICS, statistics),
            (Opcode.CHUNK_INDEX, b"".join(self._chunk_indexes)),
            (Opcode.ATTACHMENT_INDEX, b"".join(self._attachment_indexes)),
            (Opcode.METADATA_INDEX, b"".join(self._metadata_indexes)),
        ]
        summary = bytearray()
        offsets = bytearray()
        for opcode, group in groups:
            if group:
                offsets += record(
                    Opcode.SUMMARY_OFFSET,
                    struct.pack("<BQQ", opcode, summary_start + len(summary), len(group)),
                )
                summary += group
        offsets_start = summary_start + len(summary)
        summary += offsets
        footer_head = _RECORD_HEAD.pack(Opcode.FOOTER, 20) + struct.pack("<QQ", summary_start, offsets_start)
        summary_crc = zlib.crc32(footer_head, zlib.crc32(bytes(summary)))
        self._out.write(bytes(summary) + footer_head + struct.pack("<I", summary_crc) + MAGIC)
        self._offset += len(summary) + len(footer_head) + 4 + len(MAGIC)


def zstd_file(stream: IO[bytes], chunk_size: int) -> McapRecords:
    """The recordings' MCAP file: zstd chunks at level 1 (level 3, the mcap package's, runs ~80 MB/s
    here and gains only ~10 % on float data; level 1 runs ~3x faster)."""
    return McapRecords(stream, chunk_size, "zstd", zstandard.ZstdCompressor(level=1).compress)
