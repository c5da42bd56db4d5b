"""Every zenoh key expression of the protocol, built and parsed here and nowhere else.

docs/PROTOCOL.md documents each of them; tests/test_protocol_doc.py checks that it does.
"""

from __future__ import annotations

import re
import secrets

ROOT = "simecs"

#: Session ids are 128 random bits in URL-safe base64: unguessable, and safe as one key chunk.
SESSION_ID_RE = re.compile(r"^[A-Za-z0-9_-]{22}$")
#: Model ids, run ids, node ids, parameter-set and recording names: one plain key chunk.
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")

# -- server-wide keys (queryables) ------------------------------------------------------------
LIBRARY = f"{ROOT}/library"  # get: ModelList
SESSIONS = f"{ROOT}/sessions"  # get with CreateSession / ListSessions payload
RECORDINGS = f"{ROOT}/recordings"  # get: RecordingList
NODES_STATUS = f"{ROOT}/nodes/*/*/status"  # every node's NodeStatus

# -- liveliness tokens: under '@' chunks, so `simecs/**` data subscribers never match them ------
NODE_TOKENS = f"{ROOT}/@node/**"
RUN_TOKENS = f"{ROOT}/@run/**"


def new_session_id() -> str:
    return secrets.token_urlsafe(16)


def is_session_id(text: str) -> bool:
    return bool(SESSION_ID_RE.match(text))


def check_name(text: str, what: str) -> str:
    """Raise ValueError naming `what` unless `text` is a safe single key chunk."""
    if not isinstance(text, str) or not NAME_RE.match(text):
        raise ValueError(f"{what} {text!r:.60} must be 1-64 characters of letters, digits, '_', '-', '.'")
    return text


def model(model_id: str) -> str:
    """get: ModelDescription of one model of the library."""
    return f"{LIBRARY}/{check_name(model_id, 'model id')}"


def doc(model_id: str, page: str) -> str:
    """get: one DocPage of a model's hypertext documentation."""
    return f"{model(model_id)}/doc/{check_name(page, 'doc page')}"


def recording(name: str) -> str:
    """get: the bytes of one MCAP recording."""
    return f"{RECORDINGS}/{check_name(name, 'recording name')}"


def recording_replay(name: str) -> str:
    """get with a ReplayRequest: replay one recording onto the mesh as a session; reply {session}."""
    return f"{recording(name)}/replay"


def recording_name(session: str, run_id: str) -> str:
    """The name under which the recorder stores the run `run_id` of `session`."""
    return f"{_sid(session)}_{check_name(run_id, 'run id')}"


def node_token(role: str, node_id: str) -> str:
    return f"{ROOT}/@node/{check_name(role, 'role')}/{check_name(node_id, 'node id')}"


def node_status(role: str, node_id: str) -> str:
    return f"{ROOT}/nodes/{check_name(role, 'role')}/{check_name(node_id, 'node id')}/status"


def simulator_run(host_id: str) -> str:
    """get (proxy -> simulator host): RunRequest; the host starts a worker process."""
    return f"{ROOT}/simulators/{check_name(host_id, 'simulator id')}/run"


def run_token(session: str, run_id: str) -> str:
    """Liveliness of the worker that runs `run_id`: its loss fails the run."""
    return f"{ROOT}/@run/{_sid(session)}/{check_name(run_id, 'run id')}"


def _sid(session: str) -> str:
    if not is_session_id(session):
        raise ValueError(f"session id {session!r:.60} is not a valid session id")
    return session


# -- per-session keys ---------------------------------------------------------------------------
def cmd(session: str) -> str:
    """get: a Command; reply Ok or Error (proxy)."""
    return f"{ROOT}/{_sid(session)}/cmd"


def params(session: str) -> str:
    """put (proxy, cached): ParamValues after every change."""
    return f"{ROOT}/{_sid(session)}/params"


def state(session: str) -> str:
    """put (proxy, cached): SessionState on every lifecycle change and progress tick."""
    return f"{ROOT}/{_sid(session)}/state"


def control(session: str) -> str:
    """put (proxy -> worker): RunControl pause / resume / abort."""
    return f"{ROOT}/{_sid(session)}/control"


def run_status(session: str) -> str:
    """put (worker -> proxy): RunStatus."""
    return f"{ROOT}/{_sid(session)}/run"


def layout(session: str) -> str:
    """put (worker, cached): RunLayout, once per run before its first frame."""
    return f"{ROOT}/{_sid(session)}/vars/layout"


def vars_full(session: str) -> str:
    """put (worker): binary frames, every output sample, all columns."""
    return f"{ROOT}/{_sid(session)}/vars/full"


def vars_live(session: str) -> str:
    """put (hot-feedback): binary frames, at most R per second, live columns only."""
    return f"{ROOT}/{_sid(session)}/vars/live"


def results(session: str, run_id: str | None = None) -> str:
    """get (simulator host): list of runs, or one run's full-resolution results."""
    base = f"{ROOT}/{_sid(session)}/results"
    return base if run_id is None else f"{base}/{check_name(run_id, 'run id')}"


def notices(session: str) -> str:
    """put (any node, e.g. the recorder): Notice about a session's run; the proxy adds it to `state`."""
    return f"{ROOT}/{_sid(session)}/notices"


def jog(session: str) -> str:
    """put (client -> worker): JogInput while a real-time run goes on (reserved, see PROTOCOL.md)."""
    return f"{ROOT}/{_sid(session)}/jog"


# -- wildcards for nodes that serve every session ------------------------------------------------
ALL_CMD = f"{ROOT}/*/cmd"
ALL_RUN_STATUS = f"{ROOT}/*/run"
ALL_LAYOUT = f"{ROOT}/*/vars/layout"
ALL_FULL = f"{ROOT}/*/vars/full"
ALL_LIVE = f"{ROOT}/*/vars/live"
ALL_STATE = f"{ROOT}/*/state"
ALL_NOTICES = f"{ROOT}/*/notices"
ALL_PARAMS = f"{ROOT}/*/params"
ALL_RESULTS = f"{ROOT}/*/results/**"
ALL_RESULTS_LIST = f"{ROOT}/*/results"
ALL_DOCS = f"{LIBRARY}/*/doc/*"
ALL_MODELS = f"{LIBRARY}/*"
ALL_RECORDINGS = f"{RECORDINGS}/*"
ALL_REPLAYS = f"{RECORDINGS}/*/replay"


def session_of(key: str) -> str:
    """The session id in a per-session key; ValueError if there is none."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != ROOT or not is_session_id(parts[1]):
        raise ValueError(f"key {key!r:.80} is not a per-session key")
    return parts[1]


def last_chunk(key: str) -> str:
    return str(key).rsplit("/", 1)[-1]
