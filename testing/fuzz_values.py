"""The hostile values of the fuzz (testing/fuzz.py): JSON texts nothing in Python's json module would
write, and the tables its seeded draws pick from.

Fixed data only, built once at import: every random choice among them is made in testing/fuzz_draws.py,
so the same seed gives the same messages.
"""

from __future__ import annotations

import json
from typing import Any

#: Names the attacker uploads recordings under (and replays them from): few, so names collide too.
UPLOAD_NAMES = tuple(f"fzu{i}" for i in range(24))


# -- JSON texts nothing in Python's json module would write -------------------------------------------
class Raw(str):
    """A JSON text put in verbatim: numbers beyond float64, NaN, deep nesting..."""


def to_json(value: Any) -> bytes:
    """`value` as JSON text; `Raw` parts verbatim, strings with lone surrogates as `\\ud800` escapes."""
    return _text(value).encode("utf-8")


def _text(value: Any) -> str:
    if isinstance(value, Raw):
        return str(value)
    if isinstance(value, dict):
        return "{" + ",".join(f"{_text(str(k))}:{_text(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ",".join(_text(v) for v in value) + "]"
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)  # json.dumps refuses ints of more than 4300 digits
    return json.dumps(value)  # ensure_ascii: a lone surrogate becomes an escape, never invalid UTF-8


# -- hostile values ---------------------------------------------------------------------------------
HUGE_DIGITS = "1" + "0" * 5000
NUMBERS = [
    Raw("NaN"),
    Raw("Infinity"),
    Raw("-Infinity"),
    Raw("1e999"),
    Raw("-1e999"),
    Raw(HUGE_DIGITS),
    Raw("-" + "9" * 5000),
    Raw("1" + "0" * 400 + ".5"),
    Raw("0." + "0" * 5000 + "1"),
    Raw("1e-400"),
    Raw("-0"),
    Raw("1E+309"),
    Raw("0x10"),
    Raw("01"),
    Raw(".5"),
    Raw("1."),
    Raw("+1"),
    Raw("1e"),
    2**63,
    -(2**63) - 1,
    2**64,
    10**30,
    -1,
    0,
    1.5,
    -1e308,
]
STRINGS = [
    "\ud800",
    "a\udfffb",
    "\udc00\ud800",
    "",
    " ",
    "\u0000",
    "x" * 65,
    "../../../../etc/passwd",
    "a/b",
    "*",
    "**",
    "$*",
    "@x",
    "-lead",
    "_lead",
    ".",
    "..",
    "\U0001f600",
    "é" * 64,
    "op",
    "null",
    "r1",
    "\\",
    '"',
    "\n",
]


def _many(item: str, n: int) -> Raw:
    return Raw("[" + ",".join([item] * n) + "]")


# Built once: lists and maps past every bound of §5 (64 joints, 1000 nodes, 100000 entries).
BIG = [_many("0", n) for n in (65, 1001, 100_001)]
BIG_MAPS = [Raw("{" + ",".join(f'"p{i}":1.0' for i in range(n)) + "}") for n in (65, 100_001)]
BIG_FLOATS = _many("1.0", 100_001)
MANY_LISTS = _many("[]", 1001)


def _deep_list(n: int) -> Raw:
    return Raw("[" * n + "]" * n)


def _deep_object(n: int) -> Raw:
    return Raw('{"a":' * n + "1" + "}" * n)


DEEP = [_deep_list(64), _deep_list(2000), _deep_list(100_000), _deep_object(5000)]
DEEP_BYTES = _deep_list(200_000).encode()


#: Key chunks zenoh accepts that are no name or session id (some are names, but not session ids).
WEIRD_CHUNKS = (
    "a b",
    "ü",
    "x" * 65,
    "-x",
    "_x",
    ".x",
    "a%2Fb",
    "a:b",
    "'",
    '"',
    "<x>",
    "\\",
    "A" * 21,
    "A" * 23,
    "A" * 21 + "=",
    "\u200b",
    "nul\u0000",
    "\U0001f600",
    "x" * 300,
    "@x",
)
