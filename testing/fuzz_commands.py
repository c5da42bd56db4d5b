"""Session commands of the fuzz (testing/fuzz.py): hostile, out-of-range and valid commands on the
attacker's, the victims' and nobody's sessions, and hostile create and list requests.

Apart from the other families because what may go where is decided here: a command that decodes goes to
a victim only if it must be refused or changes nothing, and runs, replays and new sessions are rationed.
"""

from __future__ import annotations

from typing import Any

from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.testing.fuzz_draws import Draws
from simecs.testing.fuzz_targets import FuzzTargets, Message
from simecs.testing.fuzz_values import UPLOAD_NAMES, to_json

#: Session commands that change nothing: the only ones that decode which the fuzz sends to a victim.
READ_ONLY = frozenset({"get_session", "list_param_sets", "list_programs", "load_program"})
#: Runs and sessions the fuzz may start in the attacker's name: every one holds a worker or a slot.
RUN_BUDGET = 8
CREATE_BUDGET = 4
#: The robot command levels besides joint paths.
OTHER_LEVELS = ("cartesian_path", "direct_input", "action", "task", "mission")
#: Every session command, drawn evenly.
OPS = (
    "set_params",
    "reset_params",
    "set_initial",
    "set_command",
    "set_settings",
    "run",
    "replay",
    "pause",
    "resume",
    "abort",
    "stop",
    "seek",
    "save_param_set",
    "load_param_set",
    "delete_param_set",
    "list_param_sets",
    "save_program",
    "load_program",
    "delete_program",
    "list_programs",
    "get_session",
    "close_session",
)


class SessionCommands:
    """Makes the messages on `cmd` keys and on the `sessions` queryable of one seed's `count`."""

    def __init__(self, draw: Draws, targets: FuzzTargets, count: int) -> None:
        self.draw = draw
        self.rng = draw.rng
        self.facts = draw.facts
        self.t = targets
        self.count = count
        self.runs_left = RUN_BUDGET
        self.creates_left = CREATE_BUDGET
        own = targets.attacker_sessions
        self.closable = own[-1] if len(own) > 1 else ""

    # -- the messages ----------------------------------------------------------------------------
    def command(self, index: int) -> Message:
        """A command on a `cmd` key; `index` (of the message in the seed) lets the last tenth close a
        session of the attacker's."""
        t, r = self.t, self.rng.random()
        victim = self.draw.pick(t.victims)
        if r < 0.55:
            owner, key = "own", keys.cmd(t.attacker_user, self.draw.pick(t.attacker_sessions))
        elif r < 0.8:
            owner, key = "victim", keys.cmd(victim.user, victim.session)
        elif r < 0.87:  # someone else's session under the attacker's name: not_found
            owner, key = "cross", keys.cmd(t.attacker_user, victim.session)
        elif r < 0.93:
            owner, key = "cross", keys.cmd(victim.user, self.draw.random_sid())
        else:
            owner = "cross"
            user = self.draw.pick([self.draw.weird_chunk(), t.attacker_user])
            sid = self.draw.pick([self.draw.weird_chunk(), self.draw.pick(t.attacker_sessions)])
            key = f"simecs/u/{user}/sessions/{sid}/cmd"
        op = self.draw.pick(OPS)
        mode = self.rng.random()
        trusted_bad = False
        if mode < 0.08:
            payload: bytes | None = to_json(self.valid_command(op))
            what = f"valid {op}"
        elif mode < 0.25 and (bad := self.out_of_range(op)) is not None:
            payload, what, trusted_bad = to_json(bad), f"out of range {op}", True
        else:
            payload, how = self.draw.hostile_payload(self.valid_command(op))
            what = f"{how} {op}"
        if self.draw.chance(0.03):
            key += "?" + self.draw.selector()
        key, payload = self.guard(owner, key, payload, trusted_bad, index)
        return Message("cmd", key, payload, self.draw.query_attachment(), what)

    def sessions_query(self) -> Message:
        """A create or list request on a user's `sessions` queryable; creations are rationed."""
        t = self.t
        user = self.draw.pick([t.attacker_user, t.attacker_user, t.victim_user, self.draw.weird_chunk()])
        key = f"simecs/u/{user}/sessions"
        op = self.draw.pick(["create", "list"])
        if self.draw.chance(0.15):
            body = self.out_of_range("create") if op == "create" else {"op": "list", "v": 1}
            payload: bytes | None = to_json(body)
            what = f"out of range {op}"
        elif self.draw.chance(0.1):
            payload, what = to_json(self.valid_command(op)), f"valid {op}"
        else:
            payload, how = self.draw.hostile_payload(self.valid_command(op))
            what = f"{how} {op}"
        try:
            request = codec.loads(m.SessionRequest, payload) if payload is not None else None
        except Exception:
            request = None
        if isinstance(request, m.CreateSession):
            if user != t.attacker_user:
                key = keys.sessions(t.attacker_user)
            if self.creates_left <= 0:
                payload = to_json({"op": "list", "v": 1})
            else:
                self.creates_left -= 1
        return Message("query", key, payload, self.draw.query_attachment(), what)

    # -- commands, well formed or not -------------------------------------------------------------
    def settings(self) -> dict[str, Any]:
        return {
            "stop_time": self.draw.pick([0.05, 0.1, 0.2]),
            "output_interval": 0.01,
            "step": 0.0,
            "pacing": "fast",
            "factor": 1.0,
            "live_rate_hz": 20.0,
            "live_vars": list(self.facts.variables[:2]),
        }

    def valid_command(self, op: str) -> dict[str, Any]:
        """A well-formed command of `op` (what a correct client sends), as a JSON object."""
        facts, rng = self.facts, self.rng
        body: dict[str, Any] = {"op": op, "v": 1}
        if op == "set_params" and facts.params:
            chosen = [self.draw.pick(facts.params) for _ in range(rng.randrange(1, 4))]
            body["values"] = {
                n: (round(rng.uniform(lo, hi)) if integer else rng.uniform(lo, hi))
                for n, lo, hi, integer in chosen
            }
        elif op == "reset_params":
            body["names"] = (
                [self.draw.pick(facts.params)[0]] if facts.params and self.draw.chance(0.5) else []
            )
        elif op == "set_initial":
            body["joints"] = self.draw.joints()
        elif op == "set_command":
            level = self.draw.pick(["joint_path", "joint_path", *OTHER_LEVELS])
            if level == "joint_path":
                nodes = [
                    {
                        "q": self.draw.joints(),
                        "speed_pct": rng.uniform(1, 100),
                        "acc_pct": rng.uniform(1, 100),
                    }
                    for _ in range(rng.randrange(1, 4))
                ]
                body["command"] = {"kind": "joint_path", "nodes": nodes}
            else:
                body["command"] = self.other_level(level)
        elif op == "set_settings":
            body["settings"] = self.settings()
        elif op == "run" and self.draw.chance(0.25):
            body["until_stopped"] = True  # real time until stopped: the clean-up aborts what is left
        elif op == "replay":
            name = self.draw.pick(
                [*UPLOAD_NAMES[:8], keys.recording_name(self.t.victim_session, self.t.victim_run_id)]
            )
            body.update(recording=name, speed=self.draw.pick([0, 1.0, 10.0]), paused=self.draw.chance(0.3))
        elif op == "seek":
            body["time"] = rng.uniform(0, 2)
        elif op in ("save_param_set", "load_param_set", "delete_param_set"):
            body["name"] = self.draw.pick(["fz1", "fz2", "default"])
        elif op == "save_program":
            body["name"] = self.draw.pick(["fz1", "fz2"])
            body["program"] = self.other_level(self.draw.pick(["action", "task", "mission"]))
        elif op in ("load_program", "delete_program"):
            body.update(
                kind=self.draw.pick(["action", "task", "mission"]), name=self.draw.pick(["fz1", "fz2"])
            )
        elif op == "list_programs":
            body["kind"] = self.draw.pick(["", "action", "task", "mission"])
        elif op == "create":
            body["model_id"] = facts.model_id
        return body

    def out_of_range(self, op: str) -> dict[str, Any] | None:
        """A command of `op` that decodes but that the service must refuse (bad value, unknown name,
        wrong level): safe to send to a victim, since any acceptance is a bug."""
        facts, rng = self.facts, self.rng
        body = self.valid_command(op)
        if op == "set_params" and facts.params:
            name, lo, hi, integer = self.draw.pick(facts.params)
            bad = self.draw.pick(
                [hi + max(1.0, abs(hi)), lo - max(1.0, abs(lo)), 1e308, -1e308]
                + ([lo + 0.5] if integer else [])
            )
            values = dict(body["values"])
            values[name] = bad
            if self.draw.chance(0.3):
                values = {**body["values"], "no.such.param": 1.0}
            body["values"] = values
        elif op == "reset_params":
            body["names"] = [*body["names"], self.draw.pick(["no.such.param", "joint99.q", "a"])]
        elif op == "set_initial":
            joints = self.draw.joints()
            r = rng.random()
            if r < 0.3:
                joints = joints[:-1]
            elif r < 0.5:
                joints = [*joints, 0.0]
            elif r < 0.6:
                joints = []
            else:
                i = rng.randrange(len(joints))
                lo, hi = facts.joints[i]
                joints[i] = self.draw.pick([hi + 0.01, lo - 0.01, 1e300, -1e300])
            body["joints"] = joints
        elif op == "set_command":
            r = rng.random()
            unsupported = [level for level in OTHER_LEVELS if level not in facts.command_levels]
            lo, hi = facts.joints[0]
            if r < 0.2 and unsupported:
                body["command"] = self.other_level(self.draw.pick(unsupported))
            elif r < 0.4:
                q = self.draw.joints()
                q[0] = self.draw.pick([hi + 0.5, lo - 0.5])
                body["command"] = {"kind": "joint_path", "nodes": [{"q": self.draw.pick([q, q[:-1]])}]}
            elif r < 0.55:
                far = [self.draw.pick([50.0, -50.0]), 0.0, 0.0]
                body["command"] = {"kind": "cartesian_path", "nodes": [{"position": far, "rpy": [0, 0, 0]}]}
            elif r < 0.7:
                signal = {"type": "step", "amplitude": self.draw.pick([1e6, -1e6])}
                body["command"] = {"kind": "direct_input", "mode": "open_loop", "signals": {"joint1": signal}}
            elif r < 0.85:
                args = self.draw.pick([{"duration": -1.0}, {"nope": 1.0}, {}, {"duration": [1.0, 2.0]}])
                body["command"] = {"kind": "action", "primitive": "wait", "args": args}
            else:
                bad = {
                    "kind": "action",
                    "primitive": "move_joints",
                    "args": {"q": [hi + 1.0] * len(facts.joints)},
                }
                ok = {"kind": "action", "primitive": "wait", "args": {"duration": 0.1}}
                body["command"] = {
                    "kind": "mission",
                    "name": "m",
                    "tasks": [{"kind": "task", "name": "t", "actions": [ok, bad]}],
                }
        elif op == "set_settings":
            s = body["settings"]
            r = rng.random()
            if r < 0.35:
                s["output_interval"] = s["stop_time"] * 2
            elif r < 0.6:
                s["live_vars"] = ["no.such.variable"]
            elif r < 0.8:
                s["step"] = 1e-6
            else:
                s["stop_time"], s["output_interval"] = 3600.0, 1e-4  # too many samples
        elif op == "seek":
            pass  # a simulation cannot seek (unsupported), a finished session has no run (conflict)
        elif op in ("load_param_set", "delete_param_set", "load_program", "delete_program"):
            body["name"] = f"fz-none-{rng.randrange(10**6)}"
        elif op == "save_program":
            body["program"] = {"kind": "action", "primitive": "wait", "args": {"duration": 1e9}}
        elif op == "replay":
            body["recording"] = self.draw.pick([f"fz-none-{rng.randrange(10**6)}", "x" * 64])
        elif op == "create":
            body["model_id"] = self.draw.pick(["no-such-model", "x" * 64, "spider2"])
        else:
            return None
        return body

    def other_level(self, level: str) -> dict[str, Any]:
        """A well-formed command of another level than joint paths (it may still be refused: a pose
        out of reach, a current above i_max)."""
        rng = self.rng
        action: dict[str, Any] = self.draw.pick(
            [
                {"kind": "action", "primitive": "wait", "args": {"duration": rng.uniform(0, 0.5)}},
                {"kind": "action", "primitive": "home", "name": "back", "args": {"speed_pct": 50.0}},
                {"kind": "action", "primitive": "move_joints", "args": {"q": self.draw.joints()}},
                {"kind": "action", "primitive": "set_payload", "args": {"mass": rng.uniform(0, 5)}},
                {"kind": "action", "primitive": "move_to_pose", "args": {"position": [0.5, 0.1, 0.2]}},
            ]
        )
        task: dict[str, Any] = {"kind": "task", "name": "t", "actions": [action, action]}
        signal = self.draw.pick(
            [
                {"type": "step", "amplitude": rng.uniform(-0.5, 0.5), "start": 0.1},
                {"type": "table", "points": [[0, 0.0], [0.2, rng.uniform(-0.5, 0.5)]]},
                {"type": "sine", "amplitude": 0.1, "frequency_hz": rng.uniform(0.1, 5)},
            ]
        )
        levels: dict[str, dict[str, Any]] = {
            "cartesian_path": {
                "kind": "cartesian_path",
                "nodes": [
                    {
                        "position": [0.5, 0.1, 0.2],
                        "rpy": [0.0, 0.0, 0.0],
                        "move": self.draw.pick(["lin", "ptp"]),
                    }
                ],
            },
            "direct_input": {"kind": "direct_input", "mode": "open_loop", "signals": {"joint1": signal}},
            "action": action,
            "task": task,
            "mission": {"kind": "mission", "name": "m", "tasks": [task]},
        }
        return levels[level]

    # -- the guard: what may go where ---------------------------------------------------------------
    def guard(
        self, owner: str, key: str, payload: bytes | None, trusted_bad: bool, index: int
    ) -> tuple[str, bytes | None]:
        """A command that decodes goes to a victim only if it changes nothing or must be refused; runs,
        replays, new sessions and closing the attacker's sessions are rationed (each holds a worker,
        a slot or a session)."""
        try:
            cmd = codec.loads(m.SessionCommand, payload) if payload is not None else None
        except Exception:  # refused by the decoder (or a decoder bug: the node will tell)
            return key, payload
        if cmd is None:
            return key, payload
        t = self.t
        if key.split("?", 1)[0] in {keys.cmd(t.attacker_user, s) for s in t.attacker_sessions}:
            owner = "own"
        if owner == "victim" and not (trusted_bad or cmd.op in READ_ONLY):
            key = keys.cmd(t.attacker_user, self.draw.pick(t.attacker_sessions))
            owner = "own"
        if owner == "own" and cmd.op in ("run", "replay") and not trusted_bad:
            if self.runs_left <= 0:
                return key, to_json({"op": "get_session", "v": 1})
            self.runs_left -= 1
        if cmd.op == "close_session" and not (
            owner == "own"
            and self.closable  # one own session only: it stays open
            and key.split("?", 1)[0] == keys.cmd(t.attacker_user, self.closable)
            and index > self.count * 0.9
        ):
            return key, to_json({"op": "list_param_sets", "v": 1})
        return key, payload
