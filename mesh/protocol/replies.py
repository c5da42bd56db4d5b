"""The two replies every query ends with: `Ok` carrying the request's data, or an `Error` saying what
was wrong (sent as a Zenoh error reply)."""

from __future__ import annotations

from typing import Any, Literal

from .primitives import Message, Text

ErrorCode = Literal["bad_request", "not_found", "forbidden", "conflict", "busy", "internal", "unsupported"]


class Error(Message, tag="error"):
    """A refusal, sent as a Zenoh error reply: what was wrong, and in which field ("" = the whole
    message or request)."""

    code: ErrorCode
    message: Text
    field: Text = ""


class Ok(Message, tag="ok"):
    """A successful reply; the type of `data` is given per request (each command's `reply`,
    PROTOCOL.md §5)."""

    data: Any = None
