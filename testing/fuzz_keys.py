"""What the fuzz (testing/fuzz.py) sends in the name of the service: puts on every key only service nodes
write (forgeries of testing/forgery.py, hostile JSON, lying stream frames, garbage) and liveliness
tokens of runs and nodes that are not the attacker's.

Both families pretend to be a service node; neither gets an answer, so the fuzz checks their effect on
the victims afterwards (tests/test_fuzz.py).
"""

from __future__ import annotations

import json
import struct

from simecs.mesh.protocol import frames, keys
from simecs.testing import forgery
from simecs.testing.fuzz_draws import Draws
from simecs.testing.fuzz_targets import FuzzTargets, Message, Victim, next_runs

#: Outstanding fake liveliness tokens at most (all are undeclared before `fuzz()` returns).
MAX_TOKENS = 6


class ServiceKeyPuts:
    """Makes the puts of one seed on the keys of the victims, the attacker and the service nodes."""

    def __init__(self, draw: Draws, targets: FuzzTargets) -> None:
        self.draw = draw
        self.rng = draw.rng
        self.t = targets
        self.forged: list[tuple[str, bytes]] = []
        for v in targets.victims:
            for i, run_id in enumerate(next_runs(v.run_id)):
                self.forged += forgery.forged_messages(
                    v.user, v.session, run_id, v.run_index + i, targets.width
                )
        for sid in targets.attacker_sessions:
            self.forged += forgery.forged_messages(targets.attacker_user, sid, "r1", 1, targets.width)

    def put(self, index: int) -> Message:
        """A put on a key only service nodes write: a forgery, hostile JSON, a lying frame or garbage;
        `index` (of the message in the seed) stamps frames in place of a clock."""
        t, r = self.t, self.rng.random()
        if r < 0.35:
            key, payload = self.draw.pick(self.forged)
            what = "forged"
        else:
            owner = self.draw.pick([*t.victims, Victim(t.attacker_user, self.draw.pick(t.attacker_sessions))])
            u, s = owner.user, owner.session
            writers = [
                keys.run_status(u, s),
                keys.layout(u, s),
                keys.vars_full(u, s),
                keys.vars_live(u, s),
                keys.state(u, s),
                keys.params(u, s),
                keys.obstacles(u, s),
                keys.command(u, s),
                keys.notices(u, s),
                keys.control(u, s),
                keys.jog(u, s),
                keys.results(u, s),
                keys.results(u, s, owner.run_id),
                keys.cmd(u, s),
                keys.sessions(u),
                *[keys.simulator_run(sim) for sim in t.simulators],
                *[keys.node_status(role, node) for role, node in t.nodes],
                keys.node_status("simulator", forgery.FAKE_SIMULATOR),
                f"simecs/u/{u}/sessions/{self.draw.random_sid()}/run",
            ]
            key = self.draw.pick(writers)
            if r < 0.6:
                json_forged = [(k, p) for k, p in self.forged if p[:1] == b"{"]
                base = [p for k, p in json_forged if k == key] or [p for _k, p in json_forged]
                payload, how = self.draw.hostile_payload(json.loads(self.draw.pick(base)))
                what = f"{how} json"
            elif r < 0.85:
                payload, what = self.frame(owner, index), "frame"
            else:
                payload, what = self.draw.garbage() or b"", "garbage"
        attachment = self.draw.pick(
            [None, None, b"", self.rng.randbytes(16), bytes(16), self.rng.randbytes(64)]
        )
        return Message("put", key, payload if payload is not None else b"", attachment, what)

    def frame(self, owner: Victim, index: int) -> bytes:
        """A stream frame, usually lying about itself: sizes, magic, version, run, values."""
        rng, width = self.rng, self.t.width
        rows = [[rng.uniform(-1, 1) for _ in range(width)] for _ in range(rng.randrange(0, 4))]
        for row in rows:
            if self.draw.chance(0.3):
                row[rng.randrange(width)] = self.draw.pick([float("nan"), float("inf"), -float("inf"), 1e308])
        data = b"".join(struct.pack(f"<{width}d", *row) for row in rows)
        magic, version = b"SMF1", 1
        n_rows, n_cols = len(rows), width
        run_index, flags = owner.run_index, self.draw.pick([0, 1, 2, 3, 0xFFFF])
        r = rng.random()
        if r < 0.15:
            magic = self.draw.pick([b"SMF2", b"\x00\x00\x00\x00", b"smf1"])
        elif r < 0.25:
            version = self.draw.pick([0, 2, 0xFFFF])
        elif r < 0.45:
            n_rows = self.draw.pick([2**32 - 1, n_rows + 1, 2**31])
        elif r < 0.6:
            n_cols = self.draw.pick([0, 1, 2**32 - 1, width + 1, width - 1])
        elif r < 0.7:
            run_index = self.draw.pick([0, 2**32 - 1, run_index + 1])
        wall_ns = 1_700_000_000_000_000_000 + index * 1_000_000  # no clock: the same every time
        head = frames.HEADER.pack(magic, version, flags, run_index, 0, 0, wall_ns, n_rows, n_cols)
        body = head + data
        if self.draw.chance(0.2):
            body = body[: rng.randrange(len(body) + 1)]
        return body


class LivelinessTokens:
    """Makes the token messages of one seed: declared tokens stay in `tokens` (at most MAX_TOKENS), and
    the undeclaring of a short-lived one waits in `pending` to be the next message."""

    def __init__(self, draw: Draws, targets: FuzzTargets) -> None:
        self.draw = draw
        self.rng = draw.rng
        self.t = targets
        self.tokens: list[str] = []
        self.pending: list[Message] = []

    def token(self) -> Message:
        """Declare a liveliness token of a run or a node that is not the attacker's, or drop one."""
        t = self.t
        if self.tokens and (len(self.tokens) >= MAX_TOKENS or self.draw.chance(0.5)):
            key = self.tokens.pop(self.rng.randrange(len(self.tokens)))
            return Message("token", key, None, None, "undeclare")
        victim = self.draw.pick(t.victims)
        run_id = self.draw.pick(next_runs(victim.run_id))  # run ids are predictable: r1, r2, ...
        # Mostly the tokens that decide other users' runs; sometimes nodes' and the attacker's own.
        key = self.draw.pick(
            [
                *[keys.run_token(victim.user, victim.session, run_id)] * 8,
                keys.run_token(t.attacker_user, self.draw.pick(t.attacker_sessions), "r1"),
                *[keys.node_token(role, node) for role, node in t.nodes],
                keys.node_token("simulator", forgery.FAKE_SIMULATOR),
                keys.node_token("proxy", "evil-proxy"),
            ]
        )
        if key in self.tokens:
            return Message("token", key, None, None, "undeclare")
        if self.draw.chance(0.7):  # most go as quickly as they came
            self.pending.append(Message("token", key, None, None, "undeclare"))
        else:
            self.tokens.append(key)
        return Message("token", key, None, None, "declare")
