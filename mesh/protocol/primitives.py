"""The primitive value types of the protocol: names, session ids, texts, number lists.

Every message field uses one of these (or a bounded number), so the bounds a decoder enforces and
the ones `docs/protocol.schema.json` states are the same. A cross-field check (a struct's
`__post_init__`) raises `FieldProblem`, which the codec reports with the field's full path.
"""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta, Struct

#: Session ids are 128 random bits in URL-safe base64: unguessable, and safe as one key chunk.
SESSION_ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_-]{21}$"
#: Model ids, run ids, node ids, user, parameter-set and recording names: one plain key chunk.
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
MAX_TEXT = 100_000
MAX_NUMBERS = 100_000
#: The protocol's version: every message that travels alone carries it as `v`.
VERSION: Literal[1] = 1

#: 1-64 letters, digits, '_', '-', '.', starting with a letter or digit (PROTOCOL.md calls it "name").
Name = Annotated[str, Meta(pattern=NAME_PATTERN)]
#: 22 characters of A-Z a-z 0-9 _ -, the first a letter or digit (PROTOCOL.md: "session id").
SessionId = Annotated[str, Meta(pattern=SESSION_ID_PATTERN)]
Text = Annotated[str, Meta(max_length=MAX_TEXT)]
Numbers = Annotated[list[float], Meta(max_length=MAX_NUMBERS)]


class FieldProblem(ValueError):
    """A value that fits its type but not the rest of its message; `field` is relative to it."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


class Record(Struct, forbid_unknown_fields=True):
    """A value inside a message: no tag, no version of its own."""


class Message(Record, kw_only=True, tag_field="type"):
    """A message that travels alone: told apart by `type`, versioned by `v` (required on the wire)."""

    v: Literal[1] = VERSION
