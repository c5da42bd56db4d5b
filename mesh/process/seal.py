"""The service's seal: how a service node knows that a sample or a query comes from another service node.

Zenoh tells a receiver nothing trustworthy about who sent a sample (any field naming the sender can be
set by any client), and a payload's claims are only claims. So everything a service node puts on the
mesh, every query it sends to another service node and every JSON answer it gives carries, as its
zenoh attachment, a 16-byte keyed BLAKE2b of the key and the payload, made with a secret that only the
service nodes hold (the service key file). A service node acts only on samples and queries of service
keys that carry a valid seal; a well-formed message from any other peer changes nothing.

The secret is a file of 32 random bytes, readable by its owner only: `.simecs/service.key` by default
(`service_key_file` in the mesh configuration, or SIMECS_SERVICE_KEY_FILE). A service node creates it
when it is missing; service nodes on other hosts of a LAN need a copy (docs/LAN.md). Clients do not
need it: they can check seals when they have it (the viewer does), and never have to.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
from pathlib import Path
from typing import Any

DEFAULT_FILE = ".simecs/service.key"
SECRET_BYTES = 32
MAC_BYTES = 16
_PERSON = b"simecs-seal-1"


class SealError(Exception):
    """The service key file is missing, unreadable or too short."""


class Seal:
    """Signs and checks (key, payload) pairs with the service secret."""

    def __init__(self, secret: bytes) -> None:
        if len(secret) < 16:
            raise SealError(f"a service secret has at least 16 bytes, not {len(secret)}")
        self._secret = bytes(secret[:64])

    def mac(self, key: str, payload: bytes, description: bytes = b"") -> bytes:
        """The seal of `payload` on `key` (and of a binary answer's `description`, which follows it)."""
        h = hashlib.blake2b(key=self._secret, digest_size=MAC_BYTES, person=_PERSON)
        h.update(key.encode())
        h.update(b"\0")
        h.update(payload)
        h.update(description)
        return h.digest()

    def valid(self, key: str, payload: bytes, attachment: bytes | None) -> bool:
        return attachment is not None and hmac.compare_digest(self.mac(key, payload), attachment)

    def binary_attachment(self, key: str, payload: bytes, description: bytes) -> bytes:
        """A binary answer's attachment: the seal of its payload and description, then the description
        (JSON, or nothing): one attachment carries both, and the seal covers what describes the bytes."""
        return self.mac(key, payload, description) + description

    def binary_valid(self, key: str, payload: bytes, attachment: bytes | None) -> bool:
        if attachment is None or len(attachment) < MAC_BYTES:
            return False
        expected = self.mac(key, payload, binary_description(attachment))
        return hmac.compare_digest(expected, attachment[:MAC_BYTES])

    def sample_valid(self, sample: Any, payload: bytes | None = None) -> bool:
        """A zenoh sample (or query) with a valid seal for its key and payload (`payload`: the
        sample's payload when the caller has read it already, to spare a copy)."""
        att = sample.attachment
        if payload is None:
            payload = sample.payload.to_bytes() if sample.payload is not None else b""
        return self.valid(str(sample.key_expr), payload, att.to_bytes() if att is not None else None)


class SealedPublisher:
    """A zenoh publisher (plain or advanced) whose every sample carries the seal."""

    def __init__(self, publisher: Any, key: str, seal: Seal) -> None:
        self._pub = publisher
        self._key = key
        self._seal = seal

    def put(self, payload: bytes, **kwargs: Any) -> None:
        self._pub.put(payload, attachment=self._seal.mac(self._key, payload), **kwargs)

    def undeclare(self) -> None:
        self._pub.undeclare()

    @property
    def matching(self) -> bool:
        """Whether some subscriber matches the key now (zenoh's matching status)."""
        return bool(self._pub.matching_status.matching)

    def __getattr__(self, name: str) -> Any:  # matching_status and the like
        return getattr(self._pub, name)


def binary_description(attachment: bytes | None) -> bytes:
    """The JSON description of a binary answer (b"" when it has none), whatever its seal: a client
    without the secret reads it so, and cannot tell a service node's answer from another peer's."""
    return attachment[MAC_BYTES:] if attachment is not None else b""


def key_file(configured: str = "", env: dict[str, str] | None = None) -> Path:
    """Where the service key is: configured, else SIMECS_SERVICE_KEY_FILE, else the default."""
    env = dict(os.environ) if env is None else env
    return Path(configured or env.get("SIMECS_SERVICE_KEY_FILE") or DEFAULT_FILE).expanduser().resolve()


def load(path: str | os.PathLike[str], create: bool = False) -> Seal:
    """The seal of the key file at `path`; with `create`, a new secret is written there first if there
    is none (mode 0600, created atomically so nodes starting together agree on one)."""
    path = Path(path)
    if create and not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(secrets.token_bytes(SECRET_BYTES))
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)  # complete or absent, never half written; fails if another node won
        except FileExistsError:
            pass
        finally:
            tmp.unlink()
    try:
        secret = path.read_bytes()
    except OSError as exc:
        raise SealError(f"service key {path}: {exc.strerror or exc}") from None
    try:
        return Seal(secret)
    except SealError as exc:
        raise SealError(f"service key {path}: {exc}") from None
