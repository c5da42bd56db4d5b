"""Every zenoh key expression of the protocol, as one table: for each key its layout, how it is used
(query, put, cached put, liveliness token), which role writes it (the querier of a query, the publisher
of a put, the declarer of a token), which role answers a query, and what it carries. `keys.py` builds
and parses keys from it, so a key changes here only; PROTOCOL.md §3 and docs/protocol.schema.json are
generated from it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from .limits import RUNS_KEPT

ROOT = "simecs"
#: A chunk of a key's layout: `<user>`, `<session>`, ...
PLACEHOLDER = re.compile(r"<(\w+)>")


@dataclass(frozen=True, kw_only=True)
class KeySpec:
    """One key of the protocol.

    `writer` is the role that puts it, sends the query, or declares the token; `answerer` the role that
    answers a query. Roles: client, proxy, simulator, worker (a simulator's run process), hotfeedback,
    recorder, any node. `payload` and `reply` name what travels: a message type named in messages.py or
    model.py (replies are `Ok{data: <type>}` or an `Error`), `frame` (a binary frame, §6), `mcap` (the
    bytes of an MCAP file), `glb` (binary glTF 2.0), `bundle` (a model directory as a gzip-compressed
    tar, models/bundle.py), or `per command` (each command's `reply`, session_commands.py);
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
        return PLACEHOLDER.findall(self.pattern)


TABLE = (
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
KEYS: dict[str, KeySpec] = {k.name: k for k in TABLE}
