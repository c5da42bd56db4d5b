"""Every zenoh key expression of the protocol: one table, and the builders and parsers made from it.

`KEYS` says for each key its layout, how it is used (query, put, cached put, liveliness token), which
role writes it (the querier of a query, the publisher of a put, the declarer of a token), which role
answers a query, and what it carries. Builders and parsers read the layout from the table, so a key
changes in one place; PROTOCOL.md §3 and docs/protocol.schema.json are generated from it, and a test
forbids taking keys apart anywhere else.
"""

from __future__ import annotations

import re
import secrets
from dataclasses import dataclass

from .limits import RUNS_KEPT
from .primitives import NAME_PATTERN, SESSION_ID_PATTERN

ROOT = "simecs"
SESSION_ID_RE = re.compile(SESSION_ID_PATTERN)
NAME_RE = re.compile(NAME_PATTERN)
_PLACEHOLDER = re.compile(r"<(\w+)>")


class KeyProblem(ValueError):
    """A key (or a chunk for one) that is not what the protocol allows; `chunk` names the part."""

    def __init__(self, chunk: str, problem: str) -> None:
        self.chunk = chunk
        super().__init__(problem)


@dataclass(frozen=True, kw_only=True)
class KeySpec:
    """One key of the protocol.

    `writer` is the role that puts it, sends the query, or declares the token; `answerer` the role that
    answers a query. Roles: client, proxy, simulator, worker (a simulator's run process), hotfeedback,
    recorder, any node. `payload` and `reply` name what travels: a message type of mesh/messages.py or
    mesh/model.py (replies are `Ok{data: <type>}` or an `Error`), `frame` (a binary frame, §6),
    `mcap` (the bytes of an MCAP file), `glb` (binary glTF 2.0), `bundle` (a model directory as a
    gzip-compressed tar, models/bundle.py), or `per command` (messages.REPLIES);
    `|` separates choices.
    """

    name: str
    pattern: str
    kind: str  # query | put | cached put | token
    writer: str
    answerer: str = ""
    payload: str = ""
    reply: str = ""
    meaning: str
    #: A query without payload that still changes something (a watcher may not send it).
    changes: bool = False

    @property
    def chunks(self) -> list[str]:
        return _PLACEHOLDER.findall(self.pattern)


_TABLE = (
    # -- server-wide ----------------------------------------------------------------------------------
    KeySpec(
        name="library",
        pattern="simecs/library",
        kind="query",
        writer="client",
        answerer="proxy",
        reply="ModelList",
        meaning="the model library",
    ),
    KeySpec(
        name="model",
        pattern="simecs/library/<model>",
        kind="query",
        writer="client",
        answerer="proxy",
        reply="ModelDescription",
        meaning="everything a client needs to show, animate, parametrise and command a model",
    ),
    KeySpec(
        name="doc",
        pattern="simecs/library/<model>/doc/<page>",
        kind="query",
        writer="client",
        answerer="proxy",
        reply="DocPage",
        meaning="one page of the model's hypertext documentation",
    ),
    KeySpec(
        name="model_mesh",
        pattern="simecs/library/<model>/mesh/<mesh>",
        kind="query",
        writer="client",
        answerer="proxy",
        reply="glb",
        meaning="the triangle mesh a `mesh` shape of the model names, as binary glTF 2.0 (binary reply; "
        "colours as face colours; decimated toward 4000 triangles), for drawing",
    ),
    KeySpec(
        name="sessions",
        pattern="simecs/u/<user>/sessions",
        kind="query",
        writer="client",
        answerer="proxy",
        payload="SessionRequest",
        reply="per command",
        meaning="create a session of <user>, or list <user>'s sessions",
    ),
    KeySpec(
        name="recordings",
        pattern="simecs/u/<user>/recordings",
        kind="query",
        writer="client",
        answerer="recorder",
        reply="RecordingList",
        meaning="<user>'s recordings kept on the server, newest first",
    ),
    KeySpec(
        name="recording",
        pattern="simecs/u/<user>/recordings/<name>",
        kind="query",
        writer="client",
        answerer="recorder",
        payload="mcap",
        reply="mcap | RecordingInfo",
        meaning="without payload: download the recording (binary reply, attachment RecordingInfo; one still "
        "being written is answered when its run ends, after at most 3 s, else `conflict`); with an "
        "MCAP file as payload: upload it under <name> (reply RecordingInfo)",
    ),
    KeySpec(
        name="recording_info",
        pattern="simecs/u/<user>/recordings/<name>/info",
        kind="query",
        writer="client",
        answerer="recorder",
        reply="RecordingInfo",
        meaning="what one recording holds",
    ),
    KeySpec(
        name="recording_results",
        pattern="simecs/u/<user>/recordings/<name>/results",
        kind="query",
        writer="client",
        answerer="recorder",
        reply="frame",
        meaning="the recorded run's samples, as a run's results (§6.2: the same selector, binary reply, "
        "attachment ResultsAttachment): runs compared without replaying them",
    ),
    KeySpec(
        name="recording_delete",
        pattern="simecs/u/<user>/recordings/<name>/delete",
        kind="query",
        writer="client",
        answerer="recorder",
        reply="RecordingInfo",
        meaning="delete one recording (not while its run is being recorded); the reply says what it was",
        changes=True,
    ),
    KeySpec(
        name="simulator_run",
        pattern="simecs/simulators/<node>/run",
        kind="query",
        writer="proxy",
        answerer="simulator",
        payload="RunRequest",
        reply="Accepted",
        meaning="hand one run to a simulator host, which starts it in a worker process",
    ),
    KeySpec(
        name="simulator_model",
        pattern="simecs/simulators/<node>/models/<model>",
        kind="query",
        writer="proxy",
        answerer="simulator",
        reply="bundle",
        meaning="a model the host offers (its status lists it), as a bundle of its model directory: how a "
        "host's own model reaches the proxy's library",
    ),
    KeySpec(
        name="node_status",
        pattern="simecs/nodes/<role>/<node>/status",
        kind="cached put",
        writer="any node",
        payload="NodeStatus",
        meaning="a node's state and figures: on start, on change (at most 5 per s), every 5 s",
    ),
    # -- per session ----------------------------------------------------------------------------------
    KeySpec(
        name="cmd",
        pattern="simecs/u/<user>/sessions/<session>/cmd",
        kind="query",
        writer="client",
        answerer="proxy",
        payload="SessionCommand",
        reply="per command",
        meaning="every change to a session, and its runs (§5.2)",
    ),
    KeySpec(
        name="params",
        pattern="simecs/u/<user>/sessions/<session>/params",
        kind="cached put",
        writer="proxy",
        payload="ParamValues",
        meaning="every parameter value, after each change",
    ),
    KeySpec(
        name="obstacles",
        pattern="simecs/u/<user>/sessions/<session>/obstacles",
        kind="cached put",
        writer="proxy",
        payload="ObstacleValues",
        meaning="the session's obstacles, after each set_obstacles (what every client of it draws)",
    ),
    KeySpec(
        name="command",
        pattern="simecs/u/<user>/sessions/<session>/command",
        kind="cached put",
        writer="proxy",
        payload="CommandValue",
        meaning="the session's command and its plan, after each set_command (what every client's pendants "
        "show)",
    ),
    KeySpec(
        name="state",
        pattern="simecs/u/<user>/sessions/<session>/state",
        kind="cached put",
        writer="proxy",
        payload="SessionState",
        meaning="lifecycle and progress (progress at most 5 per s, and on every phase or step change)",
    ),
    KeySpec(
        name="control",
        pattern="simecs/u/<user>/sessions/<session>/control",
        kind="put",
        writer="proxy",
        payload="RunControl",
        meaning="pause, resume, stop, abort or seek, to the worker of the session's run",
    ),
    KeySpec(
        name="run_status",
        pattern="simecs/u/<user>/sessions/<session>/run",
        kind="put",
        writer="worker",
        payload="RunStatus",
        meaning="a worker's report on its run (at most 5 per s, and at once on every phase or step change)",
    ),
    KeySpec(
        name="layout",
        pattern="simecs/u/<user>/sessions/<session>/vars/layout",
        kind="cached put",
        writer="worker",
        payload="RunLayout",
        meaning="what the frames of a run mean, once per run before its first frame; cached only while "
        "the run's worker lives (a finished run's columns come with its results/<run>)",
    ),
    KeySpec(
        name="vars_full",
        pattern="simecs/u/<user>/sessions/<session>/vars/full",
        kind="put",
        writer="worker",
        payload="frame",
        meaning="every output sample, all columns",
    ),
    KeySpec(
        name="vars_live",
        pattern="simecs/u/<user>/sessions/<session>/vars/live",
        kind="put",
        writer="hotfeedback",
        payload="frame",
        meaning="the newest sample, live columns only, at most live_rate_hz per wall second",
    ),
    KeySpec(
        name="results_list",
        pattern="simecs/u/<user>/sessions/<session>/results",
        kind="query",
        writer="client",
        answerer="proxy",
        reply="RunList",
        meaning=f"the runs the session keeps (the last {RUNS_KEPT}), oldest first",
    ),
    KeySpec(
        name="results",
        pattern="simecs/u/<user>/sessions/<session>/results/<run>",
        kind="query",
        writer="client",
        answerer="simulator",
        reply="frame",
        meaning="full-resolution results of a run (§6.2), answered by the host that holds them (binary "
        "reply, attachment ResultsAttachment); the proxy answers not_found for a run the session lacks",
    ),
    KeySpec(
        name="notices",
        pattern="simecs/u/<user>/sessions/<session>/notices",
        kind="put",
        writer="recorder, simulator",
        payload="Notice",
        meaning="something the user must know about a run; the proxy lists it in SessionState.warnings",
    ),
    KeySpec(
        name="jog",
        pattern="simecs/u/<user>/sessions/<session>/jog",
        kind="put",
        writer="client",
        payload="JogInput",
        meaning="live jogging of a running run: a velocity superposed on its command (§5.4, JogInput)",
    ),
    KeySpec(
        name="hil_sensors",
        pattern="simecs/u/<user>/sessions/<session>/hil/sensors",
        kind="put",
        writer="worker",
        payload="frame",
        meaning="controller external: the sensors at the start of each control period, one row (§6.3)",
    ),
    KeySpec(
        name="hil_actuators",
        pattern="simecs/u/<user>/sessions/<session>/hil/actuators",
        kind="put",
        writer="client",
        payload="frame",
        meaning="controller external: the current set points answering a sensor frame, same seq (§6.3)",
    ),
    # -- liveliness tokens: under '@' chunks, so `simecs/**` data subscribers never match them ----------
    KeySpec(
        name="node_token",
        pattern="simecs/@node/<role>/<node>",
        kind="token",
        writer="any node",
        meaning="the node is up and ready; its loss: stopped, crashed or cut off",
    ),
    KeySpec(
        name="run_token",
        pattern="simecs/@run/<user>/<session>/<run>",
        kind="token",
        writer="worker",
        meaning="the worker of a run is alive; its loss fails the run within 1 s",
    ),
)
KEYS: dict[str, KeySpec] = {k.name: k for k in _TABLE}

# Wildcards used by nodes that serve or watch every user's sessions (and in PROTOCOL.md §3.4).
LIBRARY = "simecs/library"
USERS = "simecs/u"


def wildcard(name: str, **fixed: str) -> str:
    """The key of `name` with every chunk a `*` but those given (`user=...`: one user's, what a user
    of a private mesh may watch): what serves or watches all of them."""
    for chunk, value in fixed.items():
        check_name(value, chunk)
    return _PLACEHOLDER.sub(lambda mt: fixed.get(mt.group(1), "*"), KEYS[name].pattern)


NODES_STATUS = wildcard("node_status")
NODE_TOKENS = f"{ROOT}/@node/**"
RUN_TOKENS = f"{ROOT}/@run/**"
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
    return _PLACEHOLDER.sub(lambda m: _check(m.group(1), chunks[m.group(1)]), spec.pattern)


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
    name: re.compile("^" + _PLACEHOLDER.sub(r"(?P<\1>[^/]+)", spec.pattern) + "$")
    for name, spec in KEYS.items()
}


def parse(name: str, key: object) -> dict[str, str]:
    """The chunks of `key` read as key `name`, each checked; KeyProblem if it is not one."""
    found = _MATCHERS[name].match(str(key))
    if found is None:
        raise KeyProblem("", f"key {str(key)!r:.80} is not a {name} key ({KEYS[name].pattern})")
    return {chunk: _check(chunk, value) for chunk, value in found.groupdict().items()}


def owner_of(key: object) -> tuple[str, str]:
    """(user, session) of any per-session key (`simecs/u/<user>/sessions/<session>/...`), each checked;
    KeyProblem if it is not one."""
    parts = str(key).split("/", 5)
    if len(parts) < 6 or parts[:2] != [ROOT, "u"] or parts[3] != "sessions":
        raise KeyProblem("session", f"key {str(key)!r:.80} is not a per-session key")
    return _check("user", parts[2]), _check("session", parts[4])
