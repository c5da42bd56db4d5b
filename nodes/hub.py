"""The embedded hub: a router-mode zenoh session in Python, so one machine needs no zenohd.

Every other node connects to it as a client. On a LAN, run it (or a real zenohd) on one host with
`--listen tcp/<LAN address>:7447` and point the nodes of the other hosts at it with `--connect`.
"""

from __future__ import annotations

import argparse

from simecs.mesh.process.config import DEFAULT_HUB, hub_config, load
from simecs.mesh.process.runtime import Node, main_for


class Hub(Node):
    """Router of the mesh."""

    role = "hub"
    live_path = True
    tick_s = 1.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Hub:
        base = load(args.mesh_config)
        endpoints = args.listen or base.listen or [DEFAULT_HUB]
        cfg = hub_config(endpoints[0], base)
        cfg.listen = list(endpoints)
        return cls(cfg, node_id=args.node_id)


def main(argv: list[str] | None = None) -> int:
    return main_for(Hub, argv)


if __name__ == "__main__":
    main()
