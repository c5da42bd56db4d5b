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

from .files import parse_json5

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
    service_key_file: str = ""  # the service nodes' shared secret (mesh/process/seal.py); "" = the default
    extra: dict[str, Any] = field(default_factory=dict)  # any other zenoh key -> JSON value

    def with_overrides(self, **changes: Any) -> MeshConfig:
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    @property
    def secured(self) -> bool:
        """Whether this mesh tells users apart (the hub checks names and passwords)."""
        return bool(self.user)

    def as_user(self, user: str, password: str, timeout_ms: int = 3000) -> MeshConfig:
        """This (a service node's) configuration, joining as `user` instead: how the viewer acts for
        a user who logged in on a secured mesh, so the hub's rules for that user apply to all it does.
        A wrong password fails after `timeout_ms` (zenoh says no more than that it could not join)."""
        tls = TlsConfig(root_ca_certificate=self.tls.root_ca_certificate) if self.tls else None
        extra = {"connect/timeout_ms": {"client": timeout_ms}}
        return MeshConfig(
            mode="client", connect=list(self.connect), user=user, password=password, tls=tls, extra=extra
        )

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
            # A client retries its router instead of failing at once (a hub that is restarting comes back).
            entries["connect/timeout_ms"] = {"client": 10000}
            entries["connect/exit_on_failure"] = {"client": True}
            # After losing the hub (a restart), look for it again every 0.1 s, backing off to 1 s:
            # zenoh's default waits up to 4 s between tries. Must be set as one object.
            entries["connect/retry"] = dict(HUB_RETRY)
        if self.mode == "router":
            entries.update(router_entries())
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
            data = parse_json5(Path(path).read_text())
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


#: Where `simecs up` (private, its default) writes the client configuration of this machine's user.
CLIENT_FILE = "client.json5"


def local_client_file(env: Mapping[str, str] | None = None) -> Path | None:
    """The client configuration a client of this machine's service uses when told nothing else:
    SIMECS_CLIENT_CONFIG (empty: none), else `client.json5` in the data folder (SIMECS_DATA, default
    `.simecs`) if `simecs up` wrote one there."""
    env = os.environ if env is None else env
    named = env.get("SIMECS_CLIENT_CONFIG")
    if named is not None:
        return Path(named) if named else None
    path = Path(env.get("SIMECS_DATA", ".simecs")) / CLIENT_FILE
    return path if path.exists() else None


def load_client(
    path: str | os.PathLike[str] | None = None, env: Mapping[str, str] | None = None
) -> MeshConfig:
    """A client's configuration: `path`, else SIMECS_MESH_CONFIG, else this machine's user's file
    (`local_client_file`: the private default finds its credentials without flags), else the open
    defaults."""
    env = os.environ if env is None else env
    if not path and not env.get("SIMECS_MESH_CONFIG"):
        path = local_client_file(env)
    return load(path, env)


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


def router_entries() -> dict[str, Any]:
    """What a hub needs so that a slow subscriber slows only itself (PROTOCOL.md §3, docs/LAN.md).

    Workers publish `vars/full` with blocking congestion control (lossless as far as the hub), and
    run reports, notices and session states are blocking too (a report dropped on a busy link loses a
    step or a phase for good). A subscriber whose link is full would then hold the hub's thread for
    that publisher for up to 5 s, and every other key with it. The hub instead drops them on their way
    out to a link that cannot take them within SLOW_LINK_WAIT_US; the recorder fills such gaps from the
    run's results, and a state is read again from its cache."""
    from ..protocol import keys

    streams = [keys.wildcard(name) for name in DROPPED_FOR_SLOW_LINKS]
    return {
        "qos/network": [
            {
                "id": "drop_for_slow_links",
                "messages": ["put"],
                "flows": ["egress"],
                "key_exprs": streams,
                "overwrite": {"congestion_control": "drop"},
            }
        ],
        "transport/link/tx/queue/congestion_control/drop/wait_before_drop": SLOW_LINK_WAIT_US,
    }


#: Keys put with blocking congestion control, lossless as far as the hub (`lossless_put`): the full
#: sample stream, and the run reports, notices and session values each put once (a report dropped on a
#: busy link would lose a step or a phase for good).
LOSSLESS_KEYS = ("vars_full", "run_status", "notices", "state", "params", "obstacles", "command")
#: What the hub drops on its way out to a link with no room for SLOW_LINK_WAIT_US: those, and the
#: decimated live stream.
DROPPED_FOR_SLOW_LINKS = (*LOSSLESS_KEYS, "vars_live")


def lossless_put() -> Any:
    """The congestion control of every key in LOSSLESS_KEYS: blocking (zenoh's default drops after
    1 ms on a full link); the hub drops them only for a slow subscriber (`router_entries`)."""
    import zenoh

    return zenoh.CongestionControl.BLOCK


#: How long the hub waits for room on a full link before it drops a sample stream's sample (µs). The
#: wait holds the hub's thread for the sample's publisher, and every other subscriber of that publisher
#: waits with it (the hot-feedback node publishes every session's live frames), once each time the slow
#: link takes a batch: at 20 ms a subscriber reading a sample per 200 ms stretched other users' live
#: p99 by 1.3-1.7x (`simecs bench lan`), at 5 ms it is within noise. Shorter drops more for a subscriber
#: that is only busy: at 1 ms (zenoh's own default) the recorder lost a flood's frames that it takes
#: whole at 5 ms (`simecs bench recorder`).
SLOW_LINK_WAIT_US = 5_000

#: How a client retries its hub after losing it (milliseconds).
HUB_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2.0}


def hub_config(endpoint: str = DEFAULT_HUB, base: MeshConfig | None = None) -> MeshConfig:
    """The embedded hub: a router-mode Python session listening on `endpoint` only."""
    base = base or MeshConfig()
    return replace(base, mode="router", listen=[endpoint], connect=[])
