"""How every simecs process logs: text lines `time level node message` on stderr, or one JSON object
per line for log collectors (SIMECS_LOG_FORMAT=json); the level from --log-level or SIMECS_LOG."""

from __future__ import annotations

import json
import logging
import os
import sys


class JsonFormatter(logging.Formatter):
    """One JSON object per line, for log collectors (SIMECS_LOG_FORMAT=json)."""

    def __init__(self, node: str) -> None:
        super().__init__()
        self.node = node

    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "ts": round(record.created, 6),
            "level": record.levelname,
            "node": self.node,
            "pid": record.process,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        if record.exc_info:
            entry["exc"] = self.formatException(record.exc_info)
        return json.dumps(entry)


def setup_logging(name: str, level: str | None = None) -> None:
    """Text lines `time level node message` on stderr, or JSON lines with SIMECS_LOG_FORMAT=json."""
    level = level or os.environ.get("SIMECS_LOG", "INFO")
    handler = logging.StreamHandler(sys.stderr)
    if os.environ.get("SIMECS_LOG_FORMAT", "text") == "json":
        handler.setFormatter(JsonFormatter(name))
    else:
        handler.setFormatter(logging.Formatter(f"%(asctime)s %(levelname)s {name} %(message)s"))
    logging.basicConfig(level=level.upper(), handlers=[handler], force=True)
