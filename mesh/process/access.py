"""Who may touch which key on a secured mesh: the hub's `access_control`, generated from the key table.

The hub checks every message twice: when it enters (against the user of the link it came by) and on
every link it leaves by (against that link's user). A rule allows a message only if one of its key
expressions includes the message's key expression as a whole, so a subscription wider than what is
granted is refused entirely. `*` and `**` never match a chunk that starts with `@`: liveliness tokens
(`simecs/@node/...`) and the history queries of cached keys (`<key>/@adv/...`) need rules of their own.
There is no "the user's own subtree" template, hence one set of rules per user, with the name in it.

Three roles (docs/LAN.md):
- **service**: the nodes (one user name); everything.
- **user**: their own keys (`simecs/u/<user>/...`): the queries and puts a client may write (the key
  table's writer `client`), every sample of their own sessions, and the public keys (the library,
  node statuses and tokens).
- **watcher**: reads every user's sessions (samples, runs and results) and commands nothing.

Measured: 50 users add ~0.03 ms to a query round trip and nothing measurable to throughput.
"""

from __future__ import annotations

from typing import Any, Literal

from ..protocol.keys import KEYS, NODE_TOKENS, ROOT, RUN_TOKENS, USERS, KeySpec, check_name, wildcard

Role = Literal["user", "watcher"]

ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]
LIVELINESS_IN = ["declare_liveliness_subscriber", "liveliness_query"]
PUBLIC = [f"{ROOT}/library/**", f"{ROOT}/nodes/**"]  # the library, node statuses


def _expr(spec: KeySpec, user: str) -> str:
    """The key expression of `spec` for `user` (`*` for a user's name means every user): every other
    chunk a wildcard."""
    return wildcard(spec.name) if user == "*" else wildcard(spec.name, user=user)


def _client_keys(kind: str, per_user: bool, read_only: bool = False) -> list[KeySpec]:
    """The keys a client writes (`writer` client) of one kind; `read_only`: queries that carry no
    payload (lists, results, infos), which a watcher may send too."""
    out = []
    for spec in KEYS.values():
        if spec.writer != "client" or spec.kind != kind or ("user" in spec.chunks) != per_user:
            continue
        if read_only and (spec.payload or spec.changes):
            continue
        out.append(spec)
    return out


def _rule(rid: str, flow: str, messages: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rid, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": key_exprs}


def _public_rules() -> list[dict[str, Any]]:
    library = [_expr(s, "*") for s in _client_keys("query", per_user=False)]
    return [
        _rule("public_query_in", "ingress", ["query"], [*library, f"{ROOT}/nodes/**/@adv/**"]),
        _rule("public_reply_out", "egress", ["reply"], PUBLIC),
        _rule("public_subscribe_in", "ingress", ["declare_subscriber"], [f"{ROOT}/nodes/**"]),
        _rule("public_put_out", "egress", ["put", "delete"], [f"{ROOT}/nodes/**"]),
        _rule("public_liveliness_in", "ingress", LIVELINESS_IN, [NODE_TOKENS, f"{ROOT}/nodes/**/@adv/**"]),
        _rule("public_token_out", "egress", ["liveliness_token"], [NODE_TOKENS, f"{ROOT}/nodes/**/@adv/**"]),
        _rule("public_declare_out", "egress", ["declare_queryable"], library),
    ]


def _user_rules(user: str) -> list[dict[str, Any]]:
    space = f"{USERS}/{user}"
    queries = [_expr(s, user) for s in _client_keys("query", per_user=True)]
    puts = [_expr(s, user) for s in _client_keys("put", per_user=True)]
    # A client's declared querier or publisher sends only once the hub has told it of a matching
    # queryable or subscriber of the service, which the service declares with wildcards over users.
    service_side = [_expr(s, "*") for s in _client_keys("query", True) + _client_keys("put", True)]
    return [
        _rule(f"user/{user}/query_in", "ingress", ["query"], [*queries, f"{space}/**/@adv/**"]),
        _rule(f"user/{user}/reply_out", "egress", ["reply"], [f"{space}/**"]),
        _rule(f"user/{user}/put_in", "ingress", ["put"], puts),
        _rule(f"user/{user}/subscribe_in", "ingress", ["declare_subscriber"], [f"{space}/**"]),
        _rule(f"user/{user}/put_out", "egress", ["put", "delete"], [f"{space}/**"]),
        _rule(f"user/{user}/liveliness_in", "ingress", LIVELINESS_IN, [f"{space}/**/@adv/**"]),
        _rule(f"user/{user}/token_out", "egress", ["liveliness_token"], [f"{space}/**/@adv/**"]),
        _rule(
            f"user/{user}/declare_out",
            "egress",
            ["declare_subscriber", "declare_queryable"],
            [f"{space}/**", *service_side],
        ),
    ]


def _watcher_rules() -> list[dict[str, Any]]:
    everyone = f"{USERS}/**"
    reads = [_expr(s, "*") for s in _client_keys("query", per_user=True, read_only=True)]
    return [
        _rule("watch_query_in", "ingress", ["query"], [*reads, f"{everyone}/@adv/**"]),
        _rule("watch_reply_out", "egress", ["reply"], [everyone]),
        _rule("watch_subscribe_in", "ingress", ["declare_subscriber"], [everyone]),
        _rule("watch_put_out", "egress", ["put", "delete"], [everyone]),
        _rule("watch_liveliness_in", "ingress", LIVELINESS_IN, [f"{everyone}/@adv/**"]),
        _rule("watch_token_out", "egress", ["liveliness_token"], [f"{everyone}/@adv/**"]),
        _rule("watch_declare_out", "egress", ["declare_queryable"], reads),
    ]


def hub_access_control(users: dict[str, Role], service_user: str) -> dict[str, Any]:
    """The hub's `access_control` section: `users` (name -> role) and the service's user name. Rule,
    subject and policy ids of a user are `user/<name>/...` (a name has no `/`: no two can clash)."""
    for name in (service_user, *users):
        check_name(name, "user name")
    if service_user in users:
        raise ValueError(f"{service_user!r} is the service's user name: no user may have it")
    rules = [
        _rule(
            "service_all",
            "ingress",
            ALL_MESSAGES,
            [f"{ROOT}/**", NODE_TOKENS, RUN_TOKENS, f"{ROOT}/**/@adv/**"],
        )
    ]
    rules[0]["flows"] = ["ingress", "egress"]
    rules += _public_rules()
    subjects: list[dict[str, Any]] = [{"id": "service", "usernames": [service_user]}]
    policies: list[dict[str, Any]] = [{"id": "service", "rules": ["service_all"], "subjects": ["service"]}]
    public = [r["id"] for r in _public_rules()]
    for name, role in sorted(users.items()):
        subjects.append({"id": f"user/{name}", "usernames": [name]})
        if role == "watcher":
            continue
        own = _user_rules(name)
        rules += own
        policies.append({"id": f"user/{name}", "rules": [r["id"] for r in own], "subjects": [f"user/{name}"]})
    watchers = [f"user/{n}" for n, role in sorted(users.items()) if role == "watcher"]
    if watchers:
        watch = _watcher_rules()
        rules += watch
        policies.append({"id": "watchers", "rules": [r["id"] for r in watch], "subjects": watchers})
    if users:
        policies.append({"id": "public", "rules": public, "subjects": [f"user/{n}" for n in sorted(users)]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
