"""A seeded, bounded fuzz of every key of the protocol, sent by a peer without the service key.

What any client of an open mesh can send (issue 14): hostile JSON on every session command and on the
other queryables (wrong types, missing and extra fields, numbers beyond float64, NaN, lone surrogates,
deep nesting, very long texts, bytes that are not UTF-8, truncated or binary payloads, valid-looking
commands with values out of range), forged and garbage samples on every key only service nodes write,
and liveliness tokens of runs and nodes that are not its own. The service must refuse each with an
`Error` (never `internal`: that is a bug of the node that answered), keep every node up, and leave every
other session's state, results and recordings as they were.

The messages are a function of the seed and the targets alone (`messages()`; only the forgeries of
testing/forgery.py stamp frames with the clock), so a problem found once is found again; `fuzz()` sends
them one by one and counts the answers by error code. Used by tests/test_fuzz.py; a benchmark can call
`fuzz()` on any mesh it can reach.

Each family of messages has its module: session commands (testing/fuzz_commands.py), queries on the
other queryables and uploads (fuzz_queries.py, fuzz_recordings.py), puts and tokens in the service's
name (fuzz_keys.py); all draw their hostile values (fuzz_values.py) from one seeded `Draws`
(fuzz_draws.py). The targets and messages are in fuzz_targets.py, re-exported here.
"""

from __future__ import annotations

import random
import re
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import zenoh
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription
from simecs.testing.fuzz_commands import SessionCommands
from simecs.testing.fuzz_draws import Draws
from simecs.testing.fuzz_keys import LivelinessTokens, ServiceKeyPuts
from simecs.testing.fuzz_queries import OtherQueries
from simecs.testing.fuzz_targets import FuzzTargets, Message, ModelFacts, Victim
from simecs.testing.fuzz_values import to_json

__all__ = [
    "FuzzReport",
    "FuzzTargets",
    "Message",
    "ModelFacts",
    "Victim",
    "fuzz",
    "messages",
    "model_facts",
]

QUERY_TIMEOUT_S = 5.0
#: Characters of a request or reply kept in a report: enough to reproduce, not to flood a log.
EXCERPT = 240


@dataclass
class FuzzReport:
    """What was sent and how the service answered. A reply is counted under its error code, `ok`,
    `timeout` (no answer within QUERY_TIMEOUT_S), or `malformed` (an error reply that is no `Error`);
    a query nobody answered counts as `unanswered`."""

    sent: int = 0
    replies_by_code: dict[str, int] = field(default_factory=dict)
    #: (key, request excerpt, reply excerpt) of every `internal` answer.
    internal: list[tuple[str, str, str]] = field(default_factory=list)
    #: The same for `malformed` and `timeout` answers, and for queries answered more than once.
    malformed: list[tuple[str, str, str]] = field(default_factory=list)
    timeouts: list[tuple[str, str, str]] = field(default_factory=list)
    multiple: list[tuple[str, str, str]] = field(default_factory=list)
    #: Requests that the local zenoh session refused to send (counted, not sent).
    unsendable: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    #: Replies by code for each kind of request ("cmd mutated set_params": {"bad_request": 40, ...}).
    by_request: dict[str, dict[str, int]] = field(default_factory=dict)
    elapsed_s: float = 0.0
    out_of_time: bool = False
    created_sessions: list[str] = field(default_factory=list)
    #: How the runs started in the attacker's own sessions ended: "<session> <run>: <phase> <reason>".
    own_runs: list[str] = field(default_factory=list)

    @property
    def internal_replies(self) -> int:
        return self.replies_by_code.get("internal", 0)

    def summary(self) -> str:
        codes = ", ".join(f"{k} {v}" for k, v in sorted(self.replies_by_code.items()))
        kinds = ", ".join(f"{k} {v}" for k, v in sorted(self.by_kind.items()))
        return (
            f"sent {self.sent} messages in {self.elapsed_s:.1f} s ({kinds}); replies: {codes}; "
            f"unsendable {self.unsendable}{'; OUT OF TIME' if self.out_of_time else ''}"
        )


def model_facts(attacker: zenoh.Session, model_id: str) -> ModelFacts:
    """The model's description, asked as any client would."""
    try:
        for reply in attacker.get(keys.model(model_id), timeout=QUERY_TIMEOUT_S):
            if reply.ok is not None:
                data = codec.loads(m.Ok, reply.ok.payload.to_bytes()).data
                return ModelFacts.of(codec.from_obj(ModelDescription, data))
    except Exception:
        pass
    return ModelFacts.fallback(model_id)


class _Generator:
    """Makes the messages of one seed: draws the family of each message and lets it make it, every
    choice from one `rng` (testing/fuzz_draws.py)."""

    def __init__(self, targets: FuzzTargets, facts: ModelFacts, seed: int, count: int) -> None:
        draw = Draws(random.Random(seed), facts)
        self.rng = draw.rng
        self.index = 0
        self.commands = SessionCommands(draw, targets, count)
        self.puts = ServiceKeyPuts(draw, targets)
        self.queries = OtherQueries(draw, targets)
        self.tokens = LivelinessTokens(draw, targets)

    def next(self) -> Message:
        self.index += 1
        if self.tokens.pending:
            return self.tokens.pending.pop(0)
        r = self.rng.random()
        if r < 0.45:
            return self.commands.command(self.index)
        if r < 0.5:
            return self.commands.sessions_query()
        if r < 0.65:
            return self.queries.other_query()
        if r < 0.96:
            return self.puts.put(self.index)
        return self.tokens.token()


def messages(targets: FuzzTargets, facts: ModelFacts, seed: int = 1, count: int = 3000) -> Iterator[Message]:
    """The messages of `seed`, in order: the same targets and seed give the same messages."""
    gen = _Generator(targets, facts, seed, count)
    for _ in range(count):
        yield gen.next()


# -- sending -----------------------------------------------------------------------------------------
_RUN_OF_BYTES = re.compile(rb"(.)\1{15,}", re.S)


def _excerpt(data: bytes | None) -> str:
    """The start of `data`, with long runs of one byte shortened (`x` * 100000 reads `xxx<*100000>`)."""
    if data is None:
        return "<no payload>"
    if data.startswith(b"\x89MCAP"):  # what was wrong with it is in the request's description
        return f"<an MCAP file of {len(data)} bytes>"
    short = _RUN_OF_BYTES.sub(lambda g: g.group(1) * 3 + b"<*%d>" % len(g.group(0)), data[: EXCERPT * 100])
    shown = repr(short[:EXCERPT])
    return f"{shown}{'…' if len(short) > EXCERPT else ''} ({len(data)} bytes)"


def _code_of(reply: zenoh.Reply) -> tuple[str, bytes, str]:
    """(code, payload, why an error reply is no Error) of one reply."""
    if reply.ok is not None:
        return "ok", reply.ok.payload.to_bytes(), ""
    assert reply.err is not None
    body = reply.err.payload.to_bytes()
    try:
        return codec.loads(m.Error, body).code, body, ""
    except Exception as exc:
        # zenoh's own answer when nobody replied in time is a bare text
        if body.strip().lower().startswith(b"timeout"):
            return "timeout", body, ""
        return "malformed", body, f"{type(exc).__name__}: {str(exc)[:EXCERPT]} in "


def fuzz(
    attacker: zenoh.Session,
    targets: FuzzTargets,
    seed: int = 1,
    count: int = 3000,
    deadline_s: float = 60.0,
) -> FuzzReport:
    """Send the `count` messages of `seed` from `attacker` (a session without the service key), one by
    one, until `deadline_s`; then undeclare its tokens and end the runs and sessions it started.
    Returns what was sent and how the service answered."""
    report = FuzzReport()
    replies: Counter[str] = Counter()
    kinds: Counter[str] = Counter()
    tokens: dict[str, Any] = {}
    t0 = time.monotonic()
    end = t0 + deadline_s
    facts = model_facts(attacker, targets.model_id)
    own_sessions = keys.sessions(targets.attacker_user)
    try:
        for msg in messages(targets, facts, seed, count):
            if time.monotonic() > end:
                report.out_of_time = True
                break
            kinds[msg.kind] += 1
            report.sent += 1
            try:
                if msg.kind == "put":
                    attacker.put(msg.key, msg.payload or b"", attachment=msg.attachment)
                    continue
                if msg.kind == "token":
                    if msg.what == "declare":
                        if msg.key in tokens:
                            tokens.pop(msg.key).undeclare()
                        tokens[msg.key] = attacker.liveliness().declare_token(msg.key)
                    elif msg.key in tokens:
                        tokens.pop(msg.key).undeclare()
                    continue
                timeout = max(0.5, min(QUERY_TIMEOUT_S, end - time.monotonic()))
                answers = list(
                    attacker.get(msg.key, payload=msg.payload, attachment=msg.attachment, timeout=timeout)
                )
            except zenoh.ZError:
                report.unsendable += 1
                continue
            entry_of = (msg.key, f"{msg.what}: {_excerpt(msg.payload)}")
            if not answers:
                replies["unanswered"] += 1
            if len(answers) > 1:
                report.multiple.append((*entry_of, "; ".join(_code_of(a)[0] for a in answers)))
            family = report.by_request.setdefault(f"{msg.kind} {msg.what}", {})
            for answer in answers:
                code, body, why = _code_of(answer)
                replies[code] += 1
                family[code] = family.get(code, 0) + 1
                entry = (*entry_of, why + _excerpt(body))
                if code == "internal":
                    report.internal.append(entry)
                elif code == "malformed":
                    report.malformed.append(entry)
                elif code == "timeout":
                    report.timeouts.append(entry)
                elif code == "ok" and msg.key == own_sessions:
                    try:
                        snap = codec.loads(m.Ok, body).data
                        if isinstance(snap, dict) and "session" in snap:
                            report.created_sessions.append(str(snap["session"]))
                    except Exception:
                        pass
    finally:
        for token in tokens.values():
            try:
                token.undeclare()
            except Exception:
                pass
        _clean_up(attacker, targets, report)
        report.replies_by_code = dict(replies)
        report.by_kind = dict(kinds)
        report.elapsed_s = time.monotonic() - t0
    return report


def _clean_up(attacker: zenoh.Session, targets: FuzzTargets, report: FuzzReport) -> None:
    """End what the fuzz started in the attacker's name: its runs, and the sessions it created."""
    user = targets.attacker_user
    for sid in targets.attacker_sessions:
        try:
            for reply in attacker.get(keys.results(user, sid), timeout=QUERY_TIMEOUT_S):
                if reply.ok is not None:
                    runs = codec.from_obj(
                        list[m.RunInfo], codec.loads(m.Ok, reply.ok.payload.to_bytes()).data
                    )
                    report.own_runs += [f"{sid} {r.run_id}: {r.phase} {r.reason}".strip() for r in runs]
        except Exception:
            pass
    for sid, op in [(s, "abort") for s in targets.attacker_sessions] + [
        (s, "close_session") for s in report.created_sessions
    ]:
        try:
            list(
                attacker.get(
                    keys.cmd(user, sid), payload=to_json({"op": op, "v": 1}), timeout=QUERY_TIMEOUT_S
                )
            )
        except Exception:
            pass
