"""What a hostile peer of the mesh can try against another user's run: well-formed messages on every key
that only service nodes write, a run request sent straight to a simulator, and a fake simulator.

Used by the tests (tests/test_forgery.py) and by `simecs bench lan` (forged_puts_effective): both run
a real run while a second client, without the service key, does all of this, and then check that the
run, its state, its results and its recording are exactly what they would have been.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import zenoh
from simecs.mesh.protocol import codec, frames, keys
from simecs.mesh.protocol import messages as m

FAKE_SIMULATOR = "evil-simulator"


def forged_messages(
    user: str, session: str, run_id: str, run_index: int, width: int
) -> list[tuple[str, bytes]]:
    """(key, payload) of every forgery against run `run_id` of `user`'s `session`: each well formed."""
    rows = np.full((5, width), 7.0)
    rows[:, 0] = np.arange(5) * 1e-3
    final = frames.encode(frames.Frame(run_index, 3, time.time_ns(), rows, frames.FLAG_FINAL))
    early = frames.encode(frames.Frame(run_index, 0, time.time_ns(), rows, 0))
    settings = m.RunSettings(stop_time=1.0, output_interval=0.001)
    context = m.RunContext(user, {}, [0.0], None, settings, recording="forged")
    columns = ["time", *[f"c{i}" for i in range(width - 1)]]
    layout = m.RunLayout(
        session,
        run_id,
        run_index,
        "spider",
        columns,
        ["s"] * width,
        columns[:1],
        50.0,
        1.0,
        1e-3,
        context,
        source="replay",
    )
    finished = m.RunStatus(session, run_id, "finished", 1.0, 1.0)
    failed = m.RunStatus(session, run_id, "failed", reason="forged")
    params = m.ParamValues(session, "spider", {"joint1.ctrl.kp_pos": 1.0})
    return [
        (keys.run_status(user, session), codec.dumps(finished)),
        (keys.run_status(user, session), codec.dumps(failed)),
        (keys.vars_full(user, session), early),
        (keys.vars_full(user, session), final),
        (keys.vars_live(user, session), final),
        (keys.layout(user, session), codec.dumps(layout)),
        (keys.state(user, session), codec.dumps(m.SessionState(session, "finished", 10**6, run_id))),
        (keys.params(user, session), codec.dumps(params)),
        (keys.obstacles(user, session), codec.dumps(m.ObstacleValues(session, []))),
        (
            keys.command(user, session),
            codec.dumps(m.CommandValue(session, m.JointPath([m.PathNode([3.0] * 7)]))),
        ),
        (
            keys.notices(user, session),
            codec.dumps(m.Notice(session, run_id, "recorder", "re-login at http://evil.example")),
        ),
        (keys.control(user, session), codec.dumps(m.RunControl("pause", run_id))),
        (keys.control(user, session), codec.dumps(m.RunControl("abort", run_id))),
        (
            keys.node_status("simulator", FAKE_SIMULATOR),
            codec.dumps(m.NodeStatus("simulator", FAKE_SIMULATOR, 1, "evil", "ready")),
        ),
    ]


def forge(z: zenoh.Session, user: str, session: str, run_id: str, run_index: int, width: int) -> int:
    """Put every forgery once; how many were put."""
    sent = forged_messages(user, session, run_id, run_index, width)
    for key, payload in sent:
        z.put(key, payload)
    return len(sent)


def direct_run_request(z: zenoh.Session, simulator: str, user: str, session: str, run_id: str) -> list[Any]:
    """A run request sent straight to a simulator host, bypassing the proxy: its replies."""
    settings = m.RunSettings(stop_time=0.05, output_interval=0.01, pacing="fast")
    request = m.RunRequest(session, run_id, int(run_id[1:]), user, "spider", {}, [0.0] * 7, None, settings)
    return list(z.get(keys.simulator_run(simulator), payload=codec.dumps(request), timeout=5.0))


class FakeSimulator:
    """A peer that declares itself a simulator host and accepts every run it is offered."""

    def __init__(self, z: zenoh.Session) -> None:
        self.offered = 0

        def accept(query: zenoh.Query) -> None:
            self.offered += 1
            query.reply(query.key_expr, codec.dumps(m.Ok(data=m.Accepted(FAKE_SIMULATOR, 1))))

        self._entities: list[Any] = [
            z.declare_queryable(keys.simulator_run(FAKE_SIMULATOR), accept),
            z.liveliness().declare_token(keys.node_token("simulator", FAKE_SIMULATOR)),
        ]

    def close(self) -> None:
        for entity in self._entities:
            entity.undeclare()


class FakeAnswers:
    """A peer that answers, in place of the simulator and the recorder, queries for a run (`run_id`)
    and a recording (`recording`) that do not exist: well-formed answers with no seal (a results
    frame of 7.0s described as `described` says, a recording's bytes and its RecordingInfo)."""

    def __init__(
        self, z: zenoh.Session, user: str, session: str, run_id: str, recording: str, described: Any
    ) -> None:
        self.asked = 0
        width = len(described.columns)
        rows = np.full((5, width), 7.0)
        rows[:, 0] = np.arange(5) * 1e-3
        frame = frames.encode(frames.Frame(1, 0, time.time_ns(), rows, frames.FLAG_FINAL))
        fake_seal = bytes(16)  # the seal's place, filled with what a peer without the secret can make
        info = m.RecordingInfo(recording, session, run_id, "spider", 11)

        def answer(payload: bytes, attachment: bytes | None) -> Any:
            def reply(query: zenoh.Query) -> None:
                self.asked += 1
                query.reply(query.key_expr, payload, attachment=attachment)

            return reply

        results = answer(frame, fake_seal + codec.dumps(described))
        mcap = answer(b"not an mcap", fake_seal + codec.dumps(info))
        info_reply = answer(codec.dumps(m.Ok(data=info)), None)
        self._entities: list[Any] = [
            z.declare_queryable(keys.results(user, session, run_id), results),
            z.declare_queryable(keys.recording(user, recording), mcap),
            z.declare_queryable(keys.recording_info(user, recording), info_reply),
        ]

    def close(self) -> None:
        for entity in self._entities:
            entity.undeclare()
