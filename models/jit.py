"""The options every compiled kernel of models/ is built with (drive.py, chain_dynamics.py, ik.py)."""

from __future__ import annotations

import os

#: numba's on-disk cache (SIMECS_NUMBA_CACHE=0 turns it off; NUMBA_CACHE_DIR moves it).
CACHE = os.environ.get("SIMECS_NUMBA_CACHE", "1") != "0"
#: fast-math without "nnan"/"ninf": NaN detection must survive.
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}
