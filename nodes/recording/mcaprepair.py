"""Repairing a recording torn by a crash of its writer: every complete chunk kept, the rest marked.

A file the recorder was writing when it died has no footer, but every chunk it flushed is complete and
CRC-protected. `recover()` keeps every such chunk, every metadata record and attachment, and rewrites
them as a complete file marked `simecs.recovery` (the one open chunk of the last ~1 s is what a crash
costs).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from . import mcapfmt as fmt
from .mcapread import RecordingError, has_footer, scan
from .mcaprecords import zstd_file


@dataclass
class Recovery:
    path: str
    original_bytes: int
    messages: int
    bad_chunks: int
    problem: str


def recover(path: str | os.PathLike[str]) -> Recovery | None:
    """Repair a torn file in place (atomically); None when the file is already complete."""
    p = Path(path)
    if has_footer(p):
        try:
            scan(p, strict=True, keep_messages=False)
            return None
        except RecordingError:
            pass  # a footer but damaged inside: rewrite what is readable
    sc = scan(p)
    if sc.header is None:
        raise RecordingError(f"{p}: nothing recoverable (no MCAP header): {sc.problem or 'empty file'}")
    tmp = p.with_name(f".{p.name}.recover.tmp")
    stream = open(tmp, "wb")  # noqa: SIM115 - closed below
    try:
        w = zstd_file(stream, fmt.CHUNK_SIZE)
        w.start(profile=sc.header.profile, library=sc.header.library)
        schema_ids = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in sc.schemas.items()}
        channel_ids = {
            cid: w.register_channel(
                c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata)
            )
            for cid, c in sc.channels.items()
        }
        # Metadata first, as the recorder writes it: a streaming reader knows the layout before the rows.
        for md in sc.metadata:
            w.add_metadata(md.name, dict(md.metadata))
        for att in sc.attachments:
            w.add_attachment(att.log_time, att.create_time, att.name, att.media_type, att.data)
        last_ns = 0
        kept = 0
        for msg in sc.messages:
            cid = channel_ids.get(msg.channel_id)
            if cid is None:
                continue
            w.add_message(cid, msg.log_time, msg.data, msg.publish_time, msg.sequence)
            last_ns = max(last_ns, msg.log_time)
            kept += 1
        note = (
            f"recovered after the recorder stopped mid-run: kept {kept} messages from the complete chunks "
            f"of {sc.size} bytes; lost the unflushed tail ({sc.problem or 'no footer'})"
        )
        log_cid = next((channel_ids[c.id] for c in sc.channels.values() if c.topic == fmt.TOPIC_LOG), None)
        if log_cid is not None:
            ns = last_ns + 1
            body = {
                "timestamp": fmt.stamp(ns),
                "level": fmt.LOG_WARNING,
                "message": note,
                "name": "recorder",
                "file": "",
                "line": 0,
            }
            w.add_message(log_cid, ns, json.dumps(body, separators=(",", ":")).encode(), time.time_ns())
        w.add_metadata(
            fmt.META_RECOVERY,
            {
                "recovered": "true",
                "original_bytes": str(sc.size),
                "messages": str(kept),
                "bad_chunks": str(sc.bad_chunks),
                "problem": sc.problem or "no footer",
                "recovered_ns": str(time.time_ns()),
            },
        )
        w.finish()
        stream.flush()
        os.fsync(stream.fileno())
        stream.close()
        os.replace(tmp, p)
    except BaseException:
        stream.close()
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return Recovery(str(p), sc.size, kept, sc.bad_chunks, sc.problem or "no footer")
