"""Hostile recordings for the fuzz's uploads (testing/fuzz.py): a valid recording torn, bit-flipped,
spliced, or written again with every CRC right and hostile simecs content inside.

Apart from the queries that carry them (testing/fuzz_queries.py): taking an MCAP file apart and writing
it again is an idea of its own, and the largest of the values the fuzz makes.
"""

from __future__ import annotations

import io
import json
import struct
from collections import Counter
from collections.abc import Callable
from typing import Any

from mcap.reader import make_reader
from mcap.writer import Writer
from simecs.testing.fuzz_draws import Draws
from simecs.testing.fuzz_values import to_json


class McapTemplate:
    """A valid recording taken apart, to be written again with hostile content and correct CRCs: what
    an upload must survive beyond torn and bit-flipped bytes."""

    def __init__(self, data: bytes) -> None:
        reader = make_reader(io.BytesIO(data))
        summary = reader.get_summary()
        if summary is None:
            raise ValueError("a recording without a summary")
        header = reader.get_header()
        self.profile, self.library = header.profile, header.library
        self.schemas = {i: (sc.name, sc.encoding, sc.data) for i, sc in summary.schemas.items()}
        self.channels = {
            i: (ch.topic, ch.message_encoding, ch.schema_id, dict(ch.metadata))
            for i, ch in summary.channels.items()
        }
        self.messages = [
            (ch.id, msg.log_time, msg.data, msg.publish_time, msg.sequence)
            for _sc, ch, msg in reader.iter_messages(log_time_order=False)
        ]
        self.metadata = {md.name: dict(md.metadata) for md in reader.iter_metadata()}
        self.attachments = [
            (a.create_time, a.log_time, a.name, a.media_type, a.data) for a in reader.iter_attachments()
        ]

    def write(
        self,
        metadata: dict[str, dict[str, str]],
        channel_metadata: dict[str, dict[str, str]] | None = None,
        edits: dict[str, Callable[[int, bytes], bytes | None]] | None = None,
    ) -> bytes:
        """The recording with `metadata`, more metadata on the channels of some topics, and the messages
        of some topics through `edits[topic](i, data)` (None drops the message)."""
        channel_metadata, edits = channel_metadata or {}, edits or {}
        out = io.BytesIO()
        writer = Writer(out)
        writer.start(self.profile, self.library)
        schema_ids = {i: writer.register_schema(*sc) for i, sc in self.schemas.items()}
        channel_ids = {}
        for i, (topic, encoding, schema, meta) in self.channels.items():
            meta = {**meta, **channel_metadata.get(topic, {})}
            channel_ids[i] = writer.register_channel(topic, encoding, schema_ids.get(schema, 0), meta)
        counts: Counter[int] = Counter()
        for channel, log_time, data, publish_time, seq in self.messages:
            edit = edits.get(self.channels[channel][0])
            if edit is not None:
                edited = edit(counts[channel], data)
                counts[channel] += 1
                if edited is None:
                    continue
                data = edited
            writer.add_message(channel_ids[channel], log_time, data, publish_time, seq)
        for attachment in self.attachments:
            writer.add_attachment(*attachment)
        for name, meta in metadata.items():
            writer.add_metadata(name, meta)
        writer.finish()
        return out.getvalue()


class HostileRecordings:
    """Makes the uploads of one seed from the valid recording `data` (none: garbage uploads only)."""

    def __init__(self, draw: Draws, data: bytes) -> None:
        self.draw = draw
        self.rng = draw.rng
        self.facts = draw.facts
        self.data = data
        self.mcap: McapTemplate | None = None
        if data:
            try:
                self.mcap = McapTemplate(data)
            except Exception:  # not a recording this fuzz can take apart: bytes-level uploads only
                self.mcap = None

    def upload_payload(self) -> tuple[bytes | None, str]:
        """What an upload carries: garbage, the valid recording, or it torn, bit-flipped, spliced or
        hostile inside."""
        data, rng = self.data, self.rng
        if not data or self.draw.chance(0.1):
            return self.draw.garbage() or b"", "garbage upload"
        r = rng.random()
        if r < 0.05:
            return data, "valid upload"
        if r < 0.5 and self.mcap is not None:
            return self.hostile_recording()
        if r < 0.6:
            return data[: rng.randrange(len(data))], "torn upload"
        if r < 0.8:
            # Records outside chunks (metadata, summary, footer) carry no CRC of their own: aim there.
            spots = [i for i in range(len(data)) if data.startswith(b"simecs.", i)] if r < 0.7 else []
            spots = spots or [len(data) - rng.randrange(1, min(len(data), 30_000))]
            out = bytearray(data)
            for _ in range(rng.randrange(1, 6)):
                i = min(len(out) - 1, max(0, self.draw.pick(spots) + rng.randrange(-64, 400)))
                out[i] = rng.getrandbits(8)
            return bytes(out), "bit-flipped upload"
        if r < 0.8:
            i = rng.randrange(len(data))
            return data[:i] + rng.randbytes(rng.randrange(1, 512)) + data[i:], "spliced upload"
        if r < 0.9:
            return data + rng.randbytes(rng.randrange(1, 512)), "trailing garbage upload"
        i = rng.randrange(8, len(data))
        return data[:i] + data[i - 8 : i] * 3 + data[i:], "repeated record upload"

    def hostile_recording(self) -> tuple[bytes, str]:
        """A structurally valid MCAP (every CRC right) whose simecs content is hostile: the layout, the
        run's context, the columns or the rows lie, or the format is another one."""
        assert self.mcap is not None
        rng = self.rng
        meta = {name: dict(values) for name, values in self.mcap.metadata.items()}
        run = meta.setdefault("simecs.run", {})
        layout: Any = json.loads(run.get("layout", "{}"))
        channels: dict[str, dict[str, str]] = {}
        edits: dict[str, Callable[[int, bytes], bytes | None]] = {}
        # Often JSON nested past any parser's depth, in each JSON text the file carries (json.loads then
        # raises RecursionError, which a reader catching ValueError does not expect).
        deep = self.draw.pick(["[" * 100_000, "[" * 3000 + "]" * 3000, '{"a":' * 3000 + "1" + "}" * 3000])
        nested = self.draw.chance(0.4)
        r = rng.random()
        if r < 0.22:
            for _ in range(rng.randrange(1, 3)):
                layout = self.draw.mutate_object(layout)
            what = "recording with a mutated layout"
        elif r < 0.4:
            what = "recording with a lying layout: " + self.lying_layout(layout)
        elif r < 0.54:
            run["format_version"] = "1"
            session = meta.setdefault("simecs.session", {})
            field_name = self.draw.pick(["initial", "command", "settings", "user"])
            session[field_name] = (
                deep
                if nested
                else self.draw.pick(
                    [
                        "[1e999]",
                        '["a"]',
                        "{}",
                        "nan",
                        "{",
                        "[]",
                        '{"kind":"nope"}',
                        '{"stop_time":-1}',
                        "x" * 70,
                    ]
                    + [
                        deep,
                        deep,
                        "null",
                        '{"stop_time":1,"output_interval":1e-9}',
                        "",
                        "[" + "1," * 100_000 + "1]",
                    ]
                )
            )
            if self.draw.chance(0.5):
                params = meta.setdefault("simecs.params", {})
                params[self.draw.pick(self.facts.params)[0] if self.facts.params else "p"] = self.draw.pick(
                    ["nan", "inf", "-inf", "1e999", "x", "", "0x10", "1_000"]
                )
            what = f"format 1 recording with a hostile {field_name}"
        elif r < 0.66:
            columns = (
                deep
                if nested
                else self.draw.pick(
                    [
                        '["time"]',
                        '"x"',
                        "[1,2]",
                        '{"a":1}',
                        "null",
                        "[]",
                        '["time","time"]',
                        '["\\ud800"]',
                        deep,
                        deep,
                    ]
                )
            )
            channels["/vars"] = {"columns": columns}
            what = "recording whose /vars columns lie"
        elif r < 0.74:
            text = (
                deep.encode() if nested else self.draw.pick([b"\xff\xfe", b"[]", b"1e999", b'"x"', b"{" * 10])
            )
            edits["/log"] = lambda i, data: text if i % 2 == 0 else data
            what = "recording with hostile /log messages"
        elif r < 0.86:
            how = self.draw.pick(["nan time", "backwards", "one short", "no rows", "huge time", "same time"])

            def edit(i: int, data: bytes, how: str = how) -> bytes | None:
                values = list(struct.unpack(f"<{(len(data) - 4) // 8}d", data[4:]))
                if how == "nan time":
                    values[0] = float("nan")
                elif how == "backwards":
                    values[0] = -values[0]
                elif how == "huge time":
                    values[0] = 1e300 * (i + 1)
                elif how == "same time":
                    values[0] = 0.0
                elif how == "no rows":
                    return None
                elif how == "one short" and i == 3:
                    values = values[:-1]
                return data[:4] + struct.pack(f"<{len(values)}d", *values)

            edits["/vars"] = edit
            what = f"recording whose rows lie ({how})"
        else:
            what = "recording with hostile run metadata"
            target = self.draw.pick(["simecs.run", "simecs.end", "simecs.recovery", "simecs.run"])
            values = meta.setdefault(target, {})
            values[self.draw.pick([*list(values)[:12], "format_version", "gaps", "x"])] = self.draw.pick(
                ["", "3", "-1", "nan", "x" * 100_001, "\u0000", "1e999", "r1"]
            )
            if self.draw.chance(0.2):
                meta.pop("simecs.run", None)
        if "layout" in run or layout:
            run["layout"] = to_json(layout).decode("utf-8")
        return self.mcap.write(meta, channels, edits), what

    def lying_layout(self, layout: Any) -> str:
        """A change to a well-formed layout that a reader must notice (or survive)."""
        if not isinstance(layout, dict):
            return "not an object"
        found = layout.get("context")
        ctx: dict[str, Any] = found if isinstance(found, dict) else {}
        first = self.facts.params[0][0] if self.facts.params else "p"
        edits: list[tuple[str, Callable[[], None]]] = [
            ("model puma560", lambda: layout.update(model_id="puma560")),
            ("unknown model", lambda: layout.update(model_id="nope")),
            ("one column less", lambda: layout.update(columns=layout["columns"][:-1])),
            ("only time", lambda: layout.update(columns=["time"], units=["s"])),
            ("unknown live column", lambda: layout.update(live_columns=["time", "nope"])),
            ("stop time 0", lambda: layout.update(stop_time=0.0)),
            ("stop time 1e300", lambda: layout.update(stop_time=1e300)),
            ("output interval 0", lambda: layout.update(output_interval=0.0)),
            ("largest run index", lambda: layout.update(run_index=2**32 - 1)),
            ("source replay", lambda: layout.update(source="replay")),
            ("no values", lambda: ctx.update(values={})),
            ("unknown value", lambda: ctx.update(values={"nope": 1.0})),
            ("value 1e300", lambda: ctx.update(values={**ctx.get("values", {}), first: 1e300})),
            ("no joints", lambda: ctx.update(initial=[])),
            ("100 joints", lambda: ctx.update(initial=[0.0] * 100)),
            ("joints 1e300", lambda: ctx.update(initial=[1e300] * len(self.facts.joints))),
            ("no command", lambda: ctx.update(command=None)),
            (
                "command out of range",
                lambda: ctx.update(command={"kind": "joint_path", "nodes": [{"q": [9.0] * 7}]}),
            ),
            ("another user", lambda: ctx.update(user="ann")),
            ("realtime, an hour", lambda: ctx.update(settings={"stop_time": 3600.0, "pacing": "realtime"})),
        ]
        what, edit = self.draw.pick(edits)
        edit()
        return what
