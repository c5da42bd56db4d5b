"""Queries of the fuzz (testing/fuzz.py) on every queryable but session commands: the model library,
recordings (uploads included), simulators' run requests and results with hostile selectors.

Apart from the session commands (testing/fuzz_commands.py): these aim at the service's other queryables,
where only uploads, which hold space, are rationed.
"""

from __future__ import annotations

import json

from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.testing import forgery
from simecs.testing.fuzz_draws import Draws
from simecs.testing.fuzz_recordings import HostileRecordings
from simecs.testing.fuzz_targets import FuzzTargets, Message, Victim
from simecs.testing.fuzz_values import UPLOAD_NAMES, to_json

#: Uploads of the valid recording the fuzz may make whole (each holds space); others go torn.
UPLOAD_BUDGET = 2


class OtherQueries:
    """Makes the queries of one seed on the queryables other than `cmd` and `sessions`."""

    def __init__(self, draw: Draws, targets: FuzzTargets) -> None:
        self.draw = draw
        self.rng = draw.rng
        self.facts = draw.facts
        self.t = targets
        self.uploads_left = UPLOAD_BUDGET
        self.recordings = HostileRecordings(draw, targets.mcap)

    def other_query(self) -> Message:
        """A query on the library, recordings (lists, infos, downloads, uploads), a simulator's run
        queryable or results, with garbage or no payload and now and then hostile parameters."""
        t, r = self.t, self.rng.random()
        victim = self.draw.pick(t.victims)
        user = self.draw.pick([t.attacker_user, victim.user, self.draw.weird_chunk()])
        rec_name = keys.recording_name(victim.session, victim.run_id)
        payload: bytes | None = None if self.draw.chance(0.7) else self.draw.garbage()
        what = "garbage"
        if r < 0.06:
            key = keys.LIBRARY
        elif r < 0.14:
            key = f"simecs/library/{self.draw.pick([self.facts.model_id, 'nope', self.draw.weird_chunk()])}"
        elif r < 0.22:
            page = self.draw.pick([*self.facts.pages[:3], "nope", self.draw.weird_chunk()])
            key = (
                f"simecs/library/{self.draw.pick([self.facts.model_id, self.draw.weird_chunk()])}/doc/{page}"
            )
        elif r < 0.3:
            key = f"simecs/u/{user}/recordings"
        elif r < 0.38:
            name = self.draw.pick(
                [rec_name, self.draw.pick(UPLOAD_NAMES[:8]), "nope", self.draw.weird_chunk()]
            )
            key = f"simecs/u/{user}/recordings/{name}/info"
            if self.draw.chance(0.5):  # its samples, as a run's results, with a selector good or bad
                selector = self.draw.pick(["", "?t0=-1;t1=-1", "?vars=nope", "?every=0", "?t0=nan", "?x=1"])
                key = f"simecs/u/{user}/recordings/{name}/results{selector}"
        elif r < 0.45:  # download (no payload)
            name = self.draw.pick(
                [rec_name, self.draw.pick(UPLOAD_NAMES[:8]), "nope", self.draw.weird_chunk()]
            )
            key = f"simecs/u/{user}/recordings/{name}"
            payload = None
        elif r < 0.7:  # upload: garbage, a torn, mutated or hostile recording
            payload, what = self.recordings.upload_payload()
            user = t.attacker_user if self.draw.chance(0.75) else user  # elsewhere only names are checked
            if user == t.attacker_user:
                # Mostly the few names replays ask for, so that accepted hostile files get replayed.
                r = self.rng.random()
                name = (
                    self.draw.pick(UPLOAD_NAMES[:8])
                    if r < 0.6
                    else self.draw.pick(UPLOAD_NAMES)
                    if r < 0.85
                    else self.draw.pick([rec_name, self.draw.weird_chunk()])
                )
                if payload == t.mcap and t.mcap:
                    if self.uploads_left <= 0:
                        payload = payload[: len(payload) // 2]
                    else:
                        self.uploads_left -= 1
            else:  # in another user's space only names the service must refuse
                name = self.draw.pick([rec_name, self.draw.bad_name()])
            key = f"simecs/u/{user}/recordings/{name}"
        elif r < 0.8:
            sim = self.draw.pick(
                [*t.simulators, forgery.FAKE_SIMULATOR, self.draw.weird_chunk()] if t.simulators else ["x"]
            )
            key = f"simecs/simulators/{sim}/run"
            payload, what = self.run_request(victim)
        elif r < 0.86:
            key = (
                keys.results(victim.user, victim.session)
                if self.draw.chance(0.7)
                else f"simecs/u/{user}/sessions/{self.draw.random_sid()}/results"
            )
        else:
            owner = self.draw.pick([victim, Victim(t.attacker_user, self.draw.pick(t.attacker_sessions))])
            run = self.draw.pick(
                [owner.run_id, "r2", "r3", "r0", "r999999999999999999999", "r-1", self.draw.weird_chunk()]
            )
            key = f"simecs/u/{owner.user}/sessions/{owner.session}/results/{run}"
            key += "?" + self.draw.selector() if self.draw.chance(0.8) else ""
            what = "results selector"
        if self.draw.chance(0.05) and "?" not in key:
            key += "?" + self.draw.selector()
        return Message("query", key, payload, self.draw.query_attachment(), what)

    def run_request(self, victim: Victim) -> tuple[bytes | None, str]:
        """A run request for `victim`'s session straight to a simulator: unsealed, or hostile too."""
        settings = m.RunSettings(stop_time=0.05, output_interval=0.01, pacing="fast")
        req = m.RunRequest(
            victim.session, "r77", 77, victim.user, self.facts.model_id, {}, [0.0] * 7, None, settings
        )
        valid = json.loads(codec.dumps(req))
        if self.draw.chance(0.3):
            return to_json(valid), "unsealed run request"
        payload, how = self.draw.hostile_payload(valid)
        return payload, f"{how} run request"
