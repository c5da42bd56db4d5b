"""The options every compiled kernel of models/ is built with (drive.py, chain_dynamics.py, ik.py).

numba keys a cached kernel on its own file's time stamp only: a kernel that calls one of another file
keeps the old callee compiled in when only that file changes, and returns stale results. So the cache
lives in a directory named after the contents of every module here: any change starts a fresh cache.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import numba
import numpy as np

#: numba's on-disk cache (SIMECS_NUMBA_CACHE=0 turns it off; NUMBA_CACHE_DIR moves it).
CACHE = os.environ.get("SIMECS_NUMBA_CACHE", "1") != "0"
#: fast-math without "nnan"/"ninf": NaN detection must survive.
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


def _sources_stamp() -> str:
    """A digest of every module of models/ (about 1 ms to read them)."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> str:
    base = os.environ.get("NUMBA_CACHE_DIR") or str(Path(__file__).resolve().parent / "__pycache__" / "numba")
    return str(Path(base) / _sources_stamp())


if CACHE:
    # read by numba when each kernel is decorated: every module here imports this one first
    numba.config.CACHE_DIR = _cache_dir()  # type: ignore[attr-defined]

#: numba's private option that compiles a kernel (and what it calls) without reference counting: for a
#: hot loop that makes no array (numba then refuses to compile one there). Spelled as a mapping because
#: numba's type stubs do not list it.
NO_REFCOUNTS: dict[str, Any] = {"_nrt": False}


def type_key(value: Any) -> Hashable:
    """What numba's type of `value` depends on (for an array: dtype, dimensions, layout, flags), in
    microseconds where `numba.typeof` of a tuple of arrays takes most of a millisecond."""
    if isinstance(value, np.ndarray):
        flags = value.flags
        return (
            value.dtype.str,
            value.ndim,
            flags.c_contiguous,
            flags.f_contiguous,
            flags.writeable,
            flags.aligned,
        )
    if isinstance(value, tuple):
        return (type(value), *(type_key(v) for v in value))
    return (type(value),)


def compiled_for(kernel: Any, args: tuple[Any, ...]) -> Callable[..., Any]:
    """The kernel's machine code for the types of `args` (loaded from the cache or compiled, as a first
    call would), to be called with arguments of exactly those types (same `type_key`) without numba's
    type dispatch: for named tuples of arrays that dispatch costs a third of a whole Spider step."""
    entry: Callable[..., Any] = kernel.compile(tuple(numba.typeof(a) for a in args))
    return entry
