"""Simulations from a Python script with simecs' client library (`simecs.mesh`), as docs/CLIENT.md
shows: one run to its end with its results, then a small sweep of a controller gain with the
overshoot and peak current of each case.

    python docs/examples/batch_client.py                      # this machine's private hub (simecs up)
    python docs/examples/batch_client.py tcp/127.0.0.1:7447    # an open hub (simecs up --open)

tests/test_examples.py runs it against real nodes.
"""

from __future__ import annotations

import sys

from simecs.mesh import batch
from simecs.mesh.client import MeshClient
from simecs.mesh.process.config import MeshConfig, load_client
from simecs.mesh.protocol import messages as m


def main(endpoint: str | None) -> int:
    # An open hub named, or this machine's private one (the credentials `simecs up` wrote, found alone).
    cfg = MeshConfig(mode="client", connect=[endpoint]) if endpoint else load_client()
    user = cfg.user or "scripts"  # on a private hub, your own name: the keys you may use
    client = MeshClient.open(cfg)
    try:
        path = m.JointPath([m.PathNode([0.3, 0.4, 0.0, 0.3, 0.0, 0.2, 0.0], speed_pct=80.0)])
        settings = m.RunSettings(stop_time=2.0, output_interval=0.002, pacing="fast")
        initial = [0.0, 0.2, 0.0, 0.3, 0.0, 0.0, 0.0]

        # One run: the outcome holds how it ended and its full-resolution results.
        run = batch.run_simulation(
            client, user, "spider", path, initial=initial, settings=settings, variables=["joint2.q"]
        )
        end = run.column("joint2.q")[-1]
        print(f"{run.run_id}: {run.phase}, {run.rows.shape[0]} samples, joint2 ends at {end:.4f} rad")

        # A sweep: every case is a session of its own, several run at once.
        cases = batch.variations({"joint2.ctrl.kp_pos": [5.0, 20.0, 60.0]})
        rows = batch.sweep(
            client, user, "spider", path, cases, ["overshoot:joint2.q", "max_abs:joint2.i_ref"],
            initial=initial, settings=settings, parallel=3,
        )  # fmt: skip
        for row in rows:
            gain = row.values["joint2.ctrl.kp_pos"]
            overshoot, current = row.measures["overshoot:joint2.q"], row.measures["max_abs:joint2.i_ref"]
            print(f"kp_pos {gain:5.1f}: overshoot {overshoot:.3f} %, peak current {current:.3f} A")
    finally:
        client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
