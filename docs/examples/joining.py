"""Joining a simecs hub with plain zenoh, as docs/PROTOCOL.md §1 says: the examples' shared start.

With an endpoint (`tcp/HOST:7447`, an open hub) the examples join it as their demo user. Without one
they join this machine's private hub as this machine's user, from the local client file `simecs up`
writes (`.simecs/client.json5`; SIMECS_DATA names the folder, SIMECS_CLIENT_CONFIG another file):
its hub, user name, password and the CA that signed the hub's certificate.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import zenoh

OPEN_HUB = "tcp/127.0.0.1:7447"


def local_client_file() -> Path | None:
    named = os.environ.get("SIMECS_CLIENT_CONFIG")
    if named is not None:
        return Path(named) if named else None
    path = Path(os.environ.get("SIMECS_DATA", ".simecs")) / "client.json5"
    return path if path.exists() else None


def join(endpoint: str | None, demo_user: str) -> tuple[zenoh.Config, str]:
    """Zenoh's configuration and the user name to act as (the `<user>` of the keys)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("scouting/multicast/enabled", "false")
    user = demo_user
    local = local_client_file() if endpoint is None else None
    if local is not None:
        mine = json.loads(local.read_text())  # simecs writes it as plain JSON
        endpoint, user = mine["connect"][0], mine["user"]
        config.insert_json5("transport/auth/usrpwd/user", json.dumps(mine["user"]))
        config.insert_json5("transport/auth/usrpwd/password", json.dumps(mine["password"]))
        if "tls" in mine:
            ca = mine["tls"]["root_ca_certificate"]
            config.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(ca))
    config.insert_json5("connect/endpoints", json.dumps([endpoint or OPEN_HUB]))
    return config, user
