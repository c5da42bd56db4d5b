"""Building, checking and taking apart the protocol's keys, from their one table (`key_table.KEYS`,
re-exported here with `KeySpec`): a key's layout changes in the table only, and a test forbids taking
keys apart anywhere else.
"""

from __future__ import annotations

import re
import secrets
from typing import NamedTuple, Protocol

from .key_table import KEYS, PLACEHOLDER, ROOT, KeySpec  # noqa: F401 (keys.KeySpec, keys.ROOT)
from .primitives import NAME_PATTERN, SESSION_ID_PATTERN

SESSION_ID_RE = re.compile(SESSION_ID_PATTERN)
NAME_RE = re.compile(NAME_PATTERN)


class KeyProblem(ValueError):
    """A key (or a chunk for one) that is not what the protocol allows; `chunk` names the part."""

    def __init__(self, chunk: str, problem: str) -> None:
        self.chunk = chunk
        super().__init__(problem)


def _fixed_part(name: str) -> str:
    """The layout of key `name` before its first chunk (`simecs/u` of `simecs/u/<user>/sessions`)."""
    return KEYS[name].pattern.split("/<", 1)[0]


# Wildcards used by nodes that serve or watch every user's sessions (and in PROTOCOL.md §3.4).
LIBRARY = KEYS["library"].pattern
USERS = _fixed_part("sessions")


def wildcard(name: str, **fixed: str) -> str:
    """The key of `name` with every chunk a `*` but those given (`user=...`: one user's, what a user
    of a private mesh may watch): what serves or watches all of them."""
    for chunk, value in fixed.items():
        check_name(value, chunk)
    return PLACEHOLDER.sub(lambda mt: fixed.get(mt.group(1), "*"), KEYS[name].pattern)


NODES_STATUS = wildcard("node_status")
NODE_TOKENS = _fixed_part("node_token") + "/**"
RUN_TOKENS = _fixed_part("run_token") + "/**"
#: The simulator hosts: their tokens (up = ready to take runs) and their statuses (their load).
SIMULATOR_TOKENS = KEYS["node_token"].pattern.replace("<role>", "simulator").replace("<node>", "*")
SIMULATOR_STATUS = KEYS["node_status"].pattern.replace("<role>", "simulator").replace("<node>", "*")
ALL_SESSION_REQUESTS = wildcard("sessions")
ALL_CMD = wildcard("cmd")
ALL_RUN_STATUS = wildcard("run_status")
ALL_LAYOUT = wildcard("layout")
ALL_FULL = wildcard("vars_full")
ALL_LIVE = wildcard("vars_live")
ALL_STATE = wildcard("state")
ALL_NOTICES = wildcard("notices")
ALL_PARAMS = wildcard("params")
ALL_RESULTS = wildcard("results")
ALL_RESULTS_LIST = wildcard("results_list")
ALL_DOCS = wildcard("doc")
ALL_MODELS = wildcard("model")
ALL_MESHES = wildcard("model_mesh")
ALL_RECORDING_LISTS = wildcard("recordings")
ALL_RECORDINGS = wildcard("recording")
ALL_RECORDING_INFOS = wildcard("recording_info")
ALL_RECORDING_DELETES = wildcard("recording_delete")
ALL_RECORDING_RESULTS = wildcard("recording_results")


def user_space(user: str) -> str:
    """Every key of one user (`simecs/u/<user>/**`): what the router's access rules give that user."""
    return f"{USERS}/{check_name(user, 'user name')}/**"


# -- checking chunks ------------------------------------------------------------------------------------
def new_session_id() -> str:
    """128 random bits, starting with a letter or digit like every name (a recording is named
    `<session>_<run>`, and a leading `-` would read as an option on a command line)."""
    while True:
        sid = secrets.token_urlsafe(16)
        if sid[0].isalnum():
            return sid


def is_session_id(text: str) -> bool:
    return isinstance(text, str) and bool(SESSION_ID_RE.match(text))


def check_name(text: str, what: str) -> str:
    """Raise KeyProblem naming `what` unless `text` is a safe single key chunk."""
    if not isinstance(text, str) or not NAME_RE.match(text):
        raise KeyProblem(
            what, f"{what} {text!r:.60} must be 1-64 characters of letters, digits, '_', '-', '.'"
        )
    return text


_CHUNK_WHAT = {
    "user": "user name",
    "session": "session id",
    "model": "model id",
    "mesh": "mesh name",
    "page": "doc page",
    "name": "recording name",
    "run": "run id",
    "role": "role",
    "node": "node id",
}


def _check(chunk: str, value: str) -> str:
    if chunk == "session":
        if not is_session_id(value):
            raise KeyProblem("session", f"session id {value!r:.60} is not a valid session id")
        return value
    if not isinstance(value, str) or not NAME_RE.match(value):
        what = _CHUNK_WHAT[chunk]
        raise KeyProblem(
            chunk, f"{what} {value!r:.60} must be 1-64 characters of letters, digits, '_', '-', '.'"
        )
    return value


# -- building ---------------------------------------------------------------------------------------
def build(key: str, /, **chunks: str) -> str:
    """The key named `key` with its chunks filled in, each checked (no wildcard or path slips in)."""
    spec = KEYS[key]
    missing = set(spec.chunks) - set(chunks)
    if missing or set(chunks) - set(spec.chunks):
        raise TypeError(f"key {key} takes chunks {spec.chunks}, got {sorted(chunks)}")
    return PLACEHOLDER.sub(lambda m: _check(m.group(1), chunks[m.group(1)]), spec.pattern)


def model(model_id: str) -> str:
    return build("model", model=model_id)


def doc(model_id: str, page: str) -> str:
    return build("doc", model=model_id, page=page)


def model_mesh(model_id: str, mesh: str) -> str:
    return build("model_mesh", model=model_id, mesh=mesh)


def sessions(user: str) -> str:
    return build("sessions", user=user)


def recordings(user: str) -> str:
    return build("recordings", user=user)


def recording(user: str, name: str) -> str:
    return build("recording", user=user, name=name)


def recording_info(user: str, name: str) -> str:
    return build("recording_info", user=user, name=name)


def recording_results(user: str, name: str) -> str:
    return build("recording_results", user=user, name=name)


def recording_delete(user: str, name: str) -> str:
    return build("recording_delete", user=user, name=name)


def recording_name(session: str, run_id: str) -> str:
    """The name under which the recorder stores the run `run_id` of `session` (in its user's space)."""
    return f"{_check('session', session)}_{check_name(run_id, 'run id')}"


_RUN_RECORDING = re.compile(SESSION_ID_PATTERN[:-1] + r"_r[0-9]+(\.[0-9]+)?$")


def is_run_recording_name(name: str) -> bool:
    """Whether `name` has the form the recorder gives runs (`<session>_<run>`, `.2`... for a
    continuation): such names are kept for runs, never taken by uploads (an upload could otherwise
    stand in for the recording of a run still to come)."""
    return bool(_RUN_RECORDING.match(name))


def name_from_file(filename: str) -> str:
    """The recording name a file is uploaded under: its stem (without folders and `.mcap`), reduced to
    one key chunk, with `-copy` added to a run's name (the CLI's replay and the viewer's upload both
    name files this way)."""
    stem = filename.replace("\\", "/").rpartition("/")[2]
    stem = stem[: -len(".mcap")] if stem.lower().endswith(".mcap") else stem
    name = "".join(c if (c.isascii() and c.isalnum()) or c in "_-." else "_" for c in stem)
    name = name.lstrip("._-")[:64] or "upload"
    return f"{name[:59]}-copy" if is_run_recording_name(name) else name


def node_token(role: str, node_id: str) -> str:
    return build("node_token", role=role, node=node_id)


def node_status(role: str, node_id: str) -> str:
    return build("node_status", role=role, node=node_id)


def simulator_run(host_id: str) -> str:
    return build("simulator_run", node=host_id)


def simulator_model(host_id: str, model_id: str) -> str:
    return build("simulator_model", node=host_id, model=model_id)


def simulator_models(host_id: str) -> str:
    """Every model bundle one host serves."""
    return KEYS["simulator_model"].pattern.replace("<node>", _check("node", host_id)).replace("<model>", "*")


class RunOf(Protocol):
    """Anything that names a run by its user, session and run id (a RunRequest, a RunRef)."""

    user: str
    session: str
    run_id: str


class RunRef(NamedTuple):
    """One run as the protocol names it: its user, session and run id (the chunks of its token)."""

    user: str
    session: str
    run_id: str

    @classmethod
    def of(cls, run: RunOf) -> RunRef:
        """The run a RunRequest (or anything with user, session and run_id) is about."""
        return cls(run.user, run.session, run.run_id)

    @classmethod
    def of_token(cls, key: object) -> RunRef:
        """The run whose liveliness token is `key`; KeyProblem if it is not a run token."""
        chunks = parse("run_token", key)
        return cls(chunks["user"], chunks["session"], chunks["run"])

    def __str__(self) -> str:
        return f"{self.session}/{self.run_id}"


def run_token(user: str, session: str, run_id: str) -> str:
    return build("run_token", user=user, session=session, run=run_id)


def cmd(user: str, session: str) -> str:
    return build("cmd", user=user, session=session)


def params(user: str, session: str) -> str:
    return build("params", user=user, session=session)


def obstacles(user: str, session: str) -> str:
    return build("obstacles", user=user, session=session)


def command(user: str, session: str) -> str:
    return build("command", user=user, session=session)


def state(user: str, session: str) -> str:
    return build("state", user=user, session=session)


def control(user: str, session: str) -> str:
    return build("control", user=user, session=session)


def run_status(user: str, session: str) -> str:
    return build("run_status", user=user, session=session)


def layout(user: str, session: str) -> str:
    return build("layout", user=user, session=session)


def vars_full(user: str, session: str) -> str:
    return build("vars_full", user=user, session=session)


def vars_live(user: str, session: str) -> str:
    return build("vars_live", user=user, session=session)


def results(user: str, session: str, run_id: str | None = None) -> str:
    """The list of a session's runs, or (with `run_id`) one run's full-resolution results."""
    if run_id is None:
        return build("results_list", user=user, session=session)
    return build("results", user=user, session=session, run=run_id)


def notices(user: str, session: str) -> str:
    return build("notices", user=user, session=session)


def jog(user: str, session: str) -> str:
    return build("jog", user=user, session=session)


def hil_sensors(user: str, session: str) -> str:
    return build("hil_sensors", user=user, session=session)


def hil_actuators(user: str, session: str) -> str:
    return build("hil_actuators", user=user, session=session)


# -- parsing ----------------------------------------------------------------------------------------
_MATCHERS = {
    name: re.compile("^" + PLACEHOLDER.sub(r"(?P<\1>[^/]+)", spec.pattern) + "$")
    for name, spec in KEYS.items()
}


def parse(name: str, key: object) -> dict[str, str]:
    """The chunks of `key` read as key `name`, each checked; KeyProblem if it is not one."""
    found = _MATCHERS[name].match(str(key))
    if found is None:
        raise KeyProblem("", f"key {str(key)!r:.80} is not a {name} key ({KEYS[name].pattern})")
    return {chunk: _check(chunk, value) for chunk, value in found.groupdict().items()}


#: Any per-session key: the layout of `cmd` up to its session, then the rest.
_PER_SESSION = re.compile(
    "^" + PLACEHOLDER.sub(r"(?P<\1>[^/]+)", KEYS["cmd"].pattern.rsplit("/", 1)[0]) + "/"
)


def owner_of(key: object) -> tuple[str, str]:
    """(user, session) of any per-session key (`simecs/u/<user>/sessions/<session>/...`), each checked;
    KeyProblem if it is not one."""
    found = _PER_SESSION.match(str(key))
    if found is None:
        raise KeyProblem("session", f"key {str(key)!r:.80} is not a per-session key")
    return _check("user", found["user"]), _check("session", found["session"])
