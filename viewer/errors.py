"""How a failed request reads to the user: a sentence they can act on, and how serious it is.

The session controller turns every exception of a request into a notice with these; nothing else in
the viewer formats errors.
"""

from __future__ import annotations

import re

from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.protocol.codec import DecodeError

#: Failures a user causes or the server explains: shown, not logged with a traceback.
EXPECTED = (RemoteError, NoReply, TimeoutError, DecodeError, ValueError)


def describe_error(exc: BaseException) -> str:
    """A sentence a user can act on, from whatever a remote call raised."""
    if isinstance(exc, RemoteError):
        message, field = exc.error.message, exc.field
        if field and message.startswith(field + ": "):
            message = message[len(field) + 2 :]
        return f"{message} ({field})" if field else message
    if isinstance(exc, NoReply):
        found = re.search(r"answered (\S+)", str(exc))
        where = f" ({found.group(1)})" if found else ""
        return f"no simecs node answered: is the service running?{where}"
    if isinstance(exc, TimeoutError):
        return f"the server took too long to answer: {exc}"
    if isinstance(exc, DecodeError):
        return f"{exc.field}: {exc.problem}" if exc.field else exc.problem
    if isinstance(exc, ValueError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def error_kind(exc: BaseException) -> str:
    """'warning' for a conflict (the session is busy, not broken), else 'error'."""
    return "warning" if isinstance(exc, RemoteError) and exc.code == "conflict" else "error"
