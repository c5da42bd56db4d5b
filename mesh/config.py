"""How a process joins the mesh: mode, endpoints, scouting, lease, security.

Zenoh's own defaults listen on every interface and scout by multicast; ours listen on nothing but
what is asked, never scout by multicast unless told, and use a 1 s lease so a frozen node is noticed
within about a second. Values come from (later wins): defaults, a JSON5 file (`SIMECS_MESH_CONFIG` or
`--mesh-config`), environment variables, command-line flags.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import json5

DEFAULT_HUB = "tcp/127.0.0.1:7447"

Mode = Literal["peer", "client", "router"]


@dataclass
class TlsConfig:
    root_ca_certificate: str = ""
    listen_certificate: str = ""
    listen_private_key: str = ""
    connect_certificate: str = ""
    connect_private_key: str = ""
    enable_mtls: bool = False


@dataclass
class MeshConfig:
    mode: Mode = "client"
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=lambda: [DEFAULT_HUB])
    multicast_scouting: bool = False
    shared_memory: bool = False
    lease_ms: int = 1000
    user: str = ""
    password: str = ""
    users_file: str = ""  # router only: "user:password" lines accepted by the hub
    tls: TlsConfig | None = None
    access_control: dict[str, Any] | None = None  # router only: zenoh `access_control` section
    extra: dict[str, Any] = field(default_factory=dict)  # any other zenoh key -> JSON value

    def with_overrides(self, **changes: Any) -> MeshConfig:
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def to_zenoh(self) -> Any:
        """The zenoh.Config for this mesh configuration."""
        import zenoh

        cfg = zenoh.Config()
        for key, value in self.zenoh_entries().items():
            cfg.insert_json5(key, json.dumps(value))
        return cfg

    def zenoh_entries(self) -> dict[str, Any]:
        entries: dict[str, Any] = {
            "mode": self.mode,
            "listen/endpoints": list(self.listen),
            "connect/endpoints": list(self.connect) if self.mode != "router" or self.connect else [],
            "scouting/multicast/enabled": self.multicast_scouting,
            "scouting/gossip/enabled": self.mode != "client",
            "transport/shared_memory/enabled": self.shared_memory,
            "transport/link/tx/lease": int(self.lease_ms),
            # Latched keys (params, state, layout) use zenoh.ext advanced publishers, which need it.
            "timestamping/enabled": True,
        }
        if self.mode == "client":
            # A client retries its router instead of failing at once (STACK-NOTES).
            entries["connect/timeout_ms"] = {"client": 10000}
            entries["connect/exit_on_failure"] = {"client": True}
        if self.user:
            entries["transport/auth/usrpwd/user"] = self.user
            entries["transport/auth/usrpwd/password"] = self.password
        if self.users_file:
            entries["transport/auth/usrpwd/dictionary_file"] = self.users_file
        if self.tls is not None:
            for name, value in vars(self.tls).items():
                if value not in ("", None):
                    entries[f"transport/link/tls/{name}"] = value
        if self.access_control is not None:
            entries["access_control"] = self.access_control
        entries.update(self.extra)
        return entries


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def load(path: str | os.PathLike[str] | None = None, env: Mapping[str, str] | None = None) -> MeshConfig:
    """Defaults, then the JSON5 file, then SIMECS_* environment variables."""
    env = os.environ if env is None else env
    cfg = MeshConfig()
    path = path or env.get("SIMECS_MESH_CONFIG") or None
    if path:
        try:
            data = json5.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"mesh config {path}: {exc}") from None
        if not isinstance(data, dict):
            raise ValueError(f"mesh config {path}: top level must be an object")
        tls = data.pop("tls", None)
        known = {f for f in MeshConfig.__dataclass_fields__}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"mesh config {path}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})"
            )
        cfg = replace(cfg, **data)
        if tls is not None:
            cfg.tls = TlsConfig(**tls)
    if env.get("SIMECS_MODE"):
        cfg.mode = env["SIMECS_MODE"]  # type: ignore[assignment]
    if env.get("SIMECS_CONNECT"):
        cfg.connect = _split(env["SIMECS_CONNECT"])
    if env.get("SIMECS_LISTEN"):
        cfg.listen = _split(env["SIMECS_LISTEN"])
    if env.get("SIMECS_USER"):
        cfg.user = env["SIMECS_USER"]
        cfg.password = env.get("SIMECS_PASSWORD", "")
    if cfg.mode not in ("peer", "client", "router"):
        raise ValueError(f"mesh mode {cfg.mode!r} must be peer, client or router")
    return cfg


def open_session(cfg: MeshConfig, deadline_s: float = 20.0) -> Any:
    """Open a zenoh session, retrying while the hub is not up yet (it may start after us)."""
    import zenoh

    end = time.monotonic() + deadline_s
    while True:
        try:
            return zenoh.open(cfg.to_zenoh())
        except zenoh.ZError as exc:
            if time.monotonic() > end:
                raise RuntimeError(f"cannot join the mesh at {cfg.connect or cfg.listen}: {exc}") from None
            time.sleep(0.1)


def hub_config(endpoint: str = DEFAULT_HUB, base: MeshConfig | None = None) -> MeshConfig:
    """The embedded hub: a router-mode Python session listening on `endpoint` only."""
    base = base or MeshConfig()
    return replace(base, mode="router", listen=[endpoint], connect=[])
