"""Run as a process by test_codec: threads decode, all at once, into Struct types none of them has used
yet (a segfault kills the process, so a test cannot run it in its own)."""

from __future__ import annotations

import faulthandler
import json
import sys
import threading
import types

import msgspec
from simecs.mesh.protocol import codec

TYPES = """
from __future__ import annotations
from typing import Annotated, Literal
import msgspec

class Leaf(msgspec.Struct, forbid_unknown_fields=True):
    a: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    b: list[int] = []
    c: str = "x"

class Mid(msgspec.Struct, forbid_unknown_fields=True):
    leaves: list[Leaf] = []
    d: dict[str, float] = {}
    e: Literal["p", "q"] = "p"

class Top(msgspec.Struct, forbid_unknown_fields=True):
    mid: Mid = msgspec.field(default_factory=Mid)
    f: tuple[float, float] = (0.0, 0.0)
    g: int | None = None
"""
VALUE = {"mid": {"leaves": [{"a": 1.0, "b": [1, 2]}], "d": {"x": 1.0}, "e": "q"}, "f": [1.0, 2.0], "g": 3}


def fresh_type(k: int) -> type[msgspec.Struct]:
    """A Struct type (with nested ones) that nothing has decoded into yet."""
    module = types.ModuleType(f"codec_race_types_{k}")
    sys.modules[module.__name__] = module
    exec(TYPES, module.__dict__)
    return module.Top  # type: ignore[no-any-return]


def main(rounds: int, threads: int) -> None:
    faulthandler.enable()
    sys.setswitchinterval(1e-6)  # switch threads as often as the interpreter can: the race shows at once
    for k in range(rounds):
        top = fresh_type(k)
        start = threading.Barrier(threads)

        def decode(i: int, top: type[msgspec.Struct] = top, start: threading.Barrier = start) -> None:
            start.wait()
            if i % 2:
                codec.from_obj(top, VALUE)
            else:
                codec.loads(top, json.dumps(VALUE))

        workers = [threading.Thread(target=decode, args=(i,)) for i in range(threads)]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
    print("decoded", rounds, "fresh types in", threads, "threads each")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))
