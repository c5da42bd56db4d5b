"""A process for the fork server's tests (tests/test_forks.py): says what it was started with, as
JSON on stdout, then exits with the code its first argument names ("sleep": waits to be killed)."""

from __future__ import annotations

import json
import os
import sys
import time


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    seen = {
        "args": args,
        "argv": sys.argv,
        "cwd": os.getcwd(),
        "env": dict(os.environ),
        "pid": os.getpid(),
        "pgid": os.getpgid(0),
        "stdin": sys.stdin.read(),
        "fd5": os.path.exists("/proc/self/fd/5") and os.readlink("/proc/self/fd/5"),
    }
    print(json.dumps(seen), flush=True)
    if args and args[0] == "sleep":
        time.sleep(600)
    if args and args[0] == "raise":
        raise RuntimeError("the probe was asked to fail")
    return int(args[0]) if args and args[0].lstrip("-").isdigit() else 0


if __name__ == "__main__":
    sys.exit(main())
