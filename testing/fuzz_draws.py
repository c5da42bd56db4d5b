"""The seeded draws every family of fuzz messages shares: small choices, hostile values, JSON objects and
texts changed for the worse, garbage payloads and hostile query parameters.

One `Draws` per seed, handed to each family (testing/fuzz_commands.py, fuzz_keys.py, fuzz_queries.py,
fuzz_recordings.py): they all draw from its one `rng`, so the messages are a function of the seed.
"""

from __future__ import annotations

import json
import random
from typing import Any

from simecs.mesh.protocol import keys
from simecs.testing.fuzz_targets import ModelFacts
from simecs.testing.fuzz_values import (
    BIG,
    BIG_FLOATS,
    BIG_MAPS,
    DEEP,
    DEEP_BYTES,
    HUGE_DIGITS,
    MANY_LISTS,
    NUMBERS,
    STRINGS,
    WEIRD_CHUNKS,
    Raw,
    to_json,
)


class Draws:
    """Every random choice of one seed comes from `rng`; `facts` give valid-looking values."""

    def __init__(self, rng: random.Random, facts: ModelFacts) -> None:
        self.rng = rng
        self.facts = facts

    # -- small choices ----------------------------------------------------------------------------
    def pick(self, seq: Any) -> Any:
        return seq[self.rng.randrange(len(seq))]

    def chance(self, p: float) -> bool:
        return self.rng.random() < p

    def hostile(self, depth: int = 0) -> Any:
        """A value no field expects: a number beyond float64, a bad string, deep or big JSON..."""
        r = self.rng.random()
        if r < 0.35:
            return self.pick(NUMBERS)
        if r < 0.6:
            return self.pick(STRINGS)
        if r < 0.7:
            return "x" * self.pick([1000, 100_001, 300_000])
        if r < 0.8:
            return self.pick(DEEP)
        if r < 0.85:
            return self.pick(BIG)
        if r < 0.9 and depth < 2:
            return {self.pick(STRINGS): self.hostile(depth + 1)}
        if r < 0.95 and depth < 2:
            return [self.hostile(depth + 1) for _ in range(self.rng.randrange(1, 4))]
        return self.pick([True, False, None, [], {}])

    def weird_chunk(self) -> str:
        return str(self.pick(WEIRD_CHUNKS))

    def bad_name(self) -> str:
        """A chunk that is no name: refused whatever the payload."""
        return str(self.pick([c for c in WEIRD_CHUNKS if not keys.NAME_RE.match(c)]))

    def random_sid(self) -> str:
        alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-"
        return "Z" + "".join(self.pick(alphabet) for _ in range(21))

    def joints(self) -> list[float]:
        return [round(self.rng.uniform(lo, hi) * 0.5, 3) for lo, hi in self.facts.joints]

    # -- payloads ---------------------------------------------------------------------------------
    def mutate_object(self, obj: Any) -> Any:
        """One structural change somewhere in a JSON object: a value swapped for a hostile one, a field
        dropped or added, the tag or version changed, a list or map grown past its bound."""
        paths: list[tuple[Any, Any]] = []  # (container, key or index)

        def walk(node: Any, depth: int) -> None:
            if depth > 5:
                return
            if isinstance(node, dict):
                for k in list(node):
                    paths.append((node, k))
                    walk(node[k], depth + 1)
            elif isinstance(node, list):
                for i in range(len(node)):
                    paths.append((node, i))
                    walk(node[i], depth + 1)

        walk(obj, 0)
        r = self.rng.random()
        if not paths or r < 0.08:
            return self.hostile()
        container, where = self.pick(paths)
        if r < 0.45:
            container[where] = self.hostile()
        elif r < 0.6 and isinstance(container, dict):
            del container[where]
        elif r < 0.72:
            dicts = [c for c, _ in paths if isinstance(c, dict)]
            if dicts:
                self.pick(dicts)[self.pick([*STRINGS, "extra", "v", "type", "kind"])] = self.hostile()
        elif r < 0.8 and isinstance(obj, dict):
            obj[self.pick(["op", "v", "type", "kind"])] = self.pick(
                ["", "run", "set_params", "create", "nope", "error", 2, 0, -1, "1", 1.0, True, None]
                + ["x" * 100_001, "\U0001f600" * 100_001]
                + [Raw(HUGE_DIGITS), Raw("NaN"), "\ud800", [], {}]
            )
        elif r < 0.88:
            big_map = BIG_MAPS[1] if self.chance(0.1) else BIG_MAPS[0]  # 1.3 MB: rarely
            container[where] = self.pick([BIG_FLOATS, big_map, [self.joints()] * 3, MANY_LISTS])
        else:
            container[where] = self.pick(NUMBERS)
        return obj

    def mutate_text(self, text: bytes) -> bytes:
        """A change to the bytes of a JSON text: truncated, bytes that are not UTF-8, a flipped byte,
        trailing garbage, duplicate keys, a BOM, JSON5 syntax, a payload over the size limit."""
        rng = self.rng
        r = rng.random()
        cut = rng.randrange(len(text) + 1) if text else 0
        if r < 0.2:
            return text[:cut]
        if r < 0.4:
            bad = self.pick(
                [b"\xff", b"\xc0\xaf", b"\xed\xa0\x80", b"\xf8\x88\x80\x80\x80", b"\x00", b"\x80"]
            )
            quote = text.find(b'"', cut)
            at = quote + 1 if quote >= 0 else cut
            return text[:at] + bad + text[at:]
        if r < 0.5 and text:
            i = rng.randrange(len(text))
            return text[:i] + bytes([text[i] ^ (1 << rng.randrange(8))]) + text[i + 1 :]
        if r < 0.58:
            return text + self.pick([b"}", b" x", b"{}", b"\x00", b'{"op":"run","v":1}'])
        if r < 0.66 and text.startswith(b"{"):
            return b'{"op":"run","v":1,' + text[1:]  # a duplicate tag
        if r < 0.72:
            return b"\xef\xbb\xbf" + text
        if r < 0.8:
            return self.pick(
                [
                    text.replace(b'"', b"'"),
                    text[:-1] + b",}" if text.endswith(b"}") else text + b",",
                    b"/* c */" + text,
                    text.replace(b":", b" : ", 1),
                    text.replace(b"1", b"1_0"),
                ]
            )
        if r < 0.82 and text.endswith(b"}"):  # just past the 4 MiB a message may have
            pad = 4 * 1024 * 1024 + 16 - len(text)
            return text[:-1] + b',"pad":"' + b"a" * max(pad, 1) + b'"}'
        if r < 0.9:
            return b"[" + text + b"]"
        return b" " * rng.randrange(1, 64) + text + b"\n" * rng.randrange(1, 64)

    def garbage(self) -> bytes | None:
        """A payload that is no message at all (None: no payload)."""
        rng = self.rng
        return self.pick(
            [
                None,
                b"",
                b"null",
                b"[]",
                b'"op"',
                b"1",
                b"true",
                b"{",
                b"}",
                b"{}",
                b'{"v":1}',
                b'{"op":null}',
                bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 2048))),
                b"\x00" * rng.randrange(1, 64),
                b"\xff\xfe" + "{}".encode("utf-16-le"),
                DEEP_BYTES,
                b"SMF1" + bytes(36),
            ]
        )

    def hostile_payload(self, valid: dict[str, Any]) -> tuple[bytes | None, str]:
        """`valid` made hostile: mutated as an object, as a text, or replaced by garbage; and how."""
        r = self.rng.random()
        if r < 0.55:
            obj = json.loads(json.dumps(valid))
            for _ in range(self.rng.randrange(1, 3)):
                obj = self.mutate_object(obj)
            return to_json(obj), "mutated"
        if r < 0.85:
            return self.mutate_text(to_json(valid)), "text"
        return self.garbage(), "garbage"

    # -- queries ----------------------------------------------------------------------------------
    def selector(self) -> str:
        """The `?parameters` of a query, each a value its parser must refuse or bound."""
        params = [
            "vars="
            + ",".join(self.pick([*self.facts.variables[:5], "time", "nope", "a b"]) for _ in range(3)),
            "vars=" + ",".join(["joint1.q"] * 5000),
            "vars=",
            "vars=" + "x" * 70,
            "vars=time,time,time",
            "t0=" + self.pick(["nan", "inf", "-inf", "1e999", "-1e999", "1e400", "", "x", "0x10", "1e-400"]),
            "t1=" + self.pick(["nan", "-1", "1e308", "0", "--1", "1" + "0" * 5000]),
            "t0=2;t1=1",
            "every=" + self.pick(["0", "-1", "1.5", "99999999999999999999999", "", "nan", "1e3", "+1", " 1"]),
            "every=1;every=2",
            "x=1",
            "=",
            ";;;",
            "%ff",
            "vars=\u00e9",
            "t0",
            "_time=[..]",
        ]
        return ";".join(self.pick(params) for _ in range(self.rng.randrange(1, 4)))

    def query_attachment(self) -> bytes | None:
        """Mostly none; else an attachment that is no seal."""
        if self.chance(0.8):
            return None
        return self.pick([b"", bytes(16), self.rng.randbytes(16), self.rng.randbytes(100), b"\xff" * 4096])
