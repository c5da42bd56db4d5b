"""viewer/ logic that needs no browser: trees, shapes and their kinematics, the joint path editor,
plot windows, documentation links, CSV, settings; the session controller driven by injected messages
and a fake mesh client (no server, no browser: the Drake way of testing GUI logic); and the panels
and the tab driven on a real viser server with no page attached (user events are given to the same
callbacks a click would reach).
"""

from __future__ import annotations

import ast
import math
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import msgspec
import numpy as np
import pytest
from simecs.benchmarks.viewer import viewer_latency
from simecs.mesh import codec, columns, frames, keys, session_commands, shapes, table_csv
from simecs.mesh import messages as m
from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.codec import DecodeError
from simecs.mesh.kinematics import link_poses
from simecs.mesh.model import DocPage, InitEquation, Link, ModelDescription, Parameter, Shape, Variable
from simecs.nodes.local_mesh import wait_until
from simecs.viewer import (
    browser,
    compare,
    compare_panel,
    docs,
    events,
    export,
    identity,
    joints,
    library,
    params,
    path,
    pendant,
    plot_dock,
    plots,
    results,
    run,
    scene,
    series,
    session,
    tree,
    xy_plot,
)
from simecs.viewer.errors import describe_error
from simecs.viewer.host import Claims
from simecs.viewer.loop import TabLoop
from simecs.viewer.tab import Tab

VIEWER = Path(__file__).resolve().parent.parent / "viewer"
H = math.pi / 2
#: Modules of the session controller and what it uses: no viser, no GUI.
HEADLESS = (
    "session",
    "loop",
    "tab_state",
    "opening",
    "edits",
    "results_io",
    "runs",
    "workers",
    "events",
    "errors",
    "host",
    "identity",
    "stream",
    "series",
    "path",
    "cartesian",
    "direct",
    "program",
    "export",
    "tree",
    "jog",
    "compare",
    "markup",
    "units",
)


def arm() -> ModelDescription:
    """A 3-joint arm in the Link convention, with a resizable pipe per link and a tool box."""
    links = [
        Link("link1", "joint1", [0.0, -H, 0.0], "link1.length", [0.0, 0.0, 0.0], -math.pi, math.pi),
        Link("link2", "joint2", [-H, 0.0, 0.0], "link2.length", [0.0, 0.0, 0.0], -2.0, 2.0),
        Link("link3", "joint3", [0.0, 0.0, 0.0], "link3.length", [0.0, 0.1, 0.0], -2.0, 2.0),
    ]
    parameters = [
        Parameter("link1.length", 0.4, "m", "column", 0.0, 3.0, "link1", appearance=True),
        Parameter("link2.length", 0.5, "m", "upper arm", 0.0, 3.0, "link2", appearance=True),
        Parameter("link2.mass", 4.0, "kg", "mass", 0.0, 100.0, "link2"),
        Parameter("link3.length", 0.3, "m", "forearm", 0.0, 3.0, "link3", appearance=True),
        Parameter("joint1.motor.R", 1.2, "ohm", "winding resistance", 0.01, 50.0, "joint1.motor"),
        Parameter("joint1.motor.kt", 0.12, "N*m/A", "torque constant", 0.001, 5.0, "joint1.motor"),
        Parameter("joint1.gear.ratio", 160.0, "-", "reduction", 1.0, 1000.0, "joint1.gear"),
        Parameter("drives.enabled", 1.0, "-", "drives on", 0.0, 1.0, "drives", integer=True),
    ]
    variables = [
        Variable("joint1.q", "rad", "joint angle", "joint1"),
        Variable("joint1.qd", "rad/s", "joint speed", "joint1"),
        Variable("joint1.motor.i", "A", "current", "joint1.motor"),
        Variable("joint2.q", "rad", "joint angle", "joint2"),
        Variable("joint3.q", "rad", "joint angle", "joint3"),
    ]
    shapes = [
        Shape("cylinder", 0, [0.0, 0.0, -0.05], "z", length=0.1, radius=0.06),
        Shape("pipe", 0, [0.0, 0.0, 0.0], "x", length=0.4, radius=0.05, inner_radius=0.04, resizable=True),
        Shape("pipe", 1, [0.0, 0.0, 0.0], "x", length=0.5, radius=0.05, inner_radius=0.04, resizable=True),
        Shape("beam", 2, [0.0, 0.0, 0.0], "x", length=0.3, width=0.06, height=0.04, resizable=True),
        Shape("sphere", 2, [0.3, 0.0, 0.0], radius=0.05),
    ]
    pages = [
        DocPage(
            "arm", "Arm", "See the [joint drive](doc:arm.joint) and doc:arm.chain.", children=["arm.chain"]
        ),
        DocPage(
            "arm.joint", "Joint drive", "Motor: doc:arm.motor. Back to [the arm](doc:arm).", parent="arm"
        ),
        DocPage("arm.chain", "Chain", "Links.", parent="arm"),
    ]
    return ModelDescription(
        id="arm3",
        name="Three-link arm",
        summary="for tests",
        base_translation=[0.0, 0.0, 0.1],
        links=links,
        tool_translation=[0.05, 0.0, 0.0],
        shapes=shapes,
        parameters=parameters,
        variables=variables,
        init_equations=[InitEquation("jointN.q_motor", "n * q", "gear untwisted")],
        doc_root="arm",
        docs=pages,
        command_levels=["joint_path"],
        environment=[Shape("box", -1, [-1.0, 0.0, -0.02], "x", length=2.0, width=2.0, height=0.02)],
    )


@dataclass
class Event:
    """What viser hands a callback when a user acted (client set) or code assigned (client None)."""

    target: Any
    client: Any = "user"
    client_id: int | None = 1


# -- a fake mesh client: what the controller asks, answered from memory -------------------------------
class FakeWatch:
    def close(self) -> None:
        pass


class FakeSession:
    """A session as `SessionClient` shows it; every command is kept in `sent`."""

    def __init__(self, mesh: FakeMesh, sid: str, snap: m.SessionSnapshot | None) -> None:
        self.client = mesh
        self.id = sid
        self.created = snap
        self.snap = snap
        self.sent: list[Any] = []
        self.refuse: dict[type, Exception] = {}
        self.run_list: list[m.RunInfo] = []
        self.asked: list[tuple[str, Any]] = []
        self.watched: dict[str, Any] = {}
        self.counter = 0
        self.plan_duration = 1.0  # what the server's plan of a command says it takes
        self.jogs: list[m.JogInput] = []
        self.unanswered = 0  # snapshot queries that get no reply (a server not reachable yet)
        self.contexts: dict[str, m.RunContext] = {}  # what each run ran with, as results replies say

    def command(self, cmd: Any) -> Any:
        self.sent.append(cmd)
        if type(cmd) in self.refuse:
            raise self.refuse[type(cmd)]
        snap = self.snap
        assert snap is not None
        if isinstance(cmd, m.SetParams):
            snap.values.update(cmd.values)
            return dict(snap.values)
        if isinstance(cmd, (m.ResetParams, m.LoadParamSet)):
            return dict(snap.values)
        if isinstance(cmd, m.SetSettings):
            snap.settings = cmd.settings
            return cmd.settings
        if isinstance(cmd, (m.Run, m.Replay, m.Continue)):
            self.counter += 1
            return m.RunStarted(f"r{self.counter}", "queued", 0)
        if isinstance(cmd, m.ListParamSets):
            return ["light"]
        if isinstance(cmd, m.GetSession):
            return snap
        if isinstance(cmd, m.SetCommand) and isinstance(cmd.command, m.CartesianPath):
            return self.plan_cartesian(cmd.command)
        if isinstance(cmd, m.SetCommand):
            snap.command = cmd.command
            return m.CommandPlan("joint_path", self.plan_duration, [], [0.0])
        return ""

    def plan_cartesian(self, path: m.CartesianPath) -> m.CommandPlan:
        """The server's answer to a Cartesian path, as far as the pendant sees it: a node below the
        floor is refused naming it; each node's joint targets are its height, a second per node."""
        for i, node in enumerate(path.nodes):
            if node.position[2] < 0.0:
                raise RemoteError(
                    m.Error("bad_request", "out of reach: 12 mm too far", f"command.nodes[{i}].position")
                )
        assert self.snap is not None
        self.snap.command = path
        steps = [
            m.PlanStep(f"nodes[{i}]", n.move, i, i + 1.0, q_end=[n.position[2], 0.0, 0.0])
            for i, n in enumerate(path.nodes)
        ]
        tool = [list(n.position) for n in path.nodes]
        return m.CommandPlan("cartesian_path", len(steps), steps, steps[-1].q_end, [[0, 0, 0.5], *tool])

    def jog(self, jog: m.JogInput) -> None:
        self.jogs.append(jog)

    def snapshot(self) -> m.SessionSnapshot:
        if self.unanswered > 0:
            self.unanswered -= 1
            raise NoReply(f"no node answered simecs/{self.id}/cmd within 10.0 s")
        if self.snap is None:
            raise RemoteError(m.Error("not_found", f"no session {self.id}"))
        return self.snap

    def close(self) -> Any:
        return self.command(m.CloseSession())

    def runs(self) -> list[m.RunInfo]:
        return list(self.run_list)

    def results(
        self, run_id: str, variables: Any = None, t0: Any = None, t1: Any = None, every: int = 1
    ) -> Any:
        self.asked.append((run_id, variables))
        names = ["time", *(variables or ["joint1.q", "joint2.q"])]
        t = np.linspace(0.0, 1.0, 11)
        return names, np.column_stack([t] + [t * (k + 1) for k in range(len(names) - 1)])

    def results_of(
        self, run_id: str, variables: Any = None, t0: Any = None, t1: Any = None, every: int = 1
    ) -> tuple[m.ResultsAttachment, np.ndarray]:
        names, rows = self.results(run_id, variables, t0, t1, every)
        info = next((r for r in self.run_list if r.run_id == run_id), m.RunInfo(run_id, "finished", 1.0, 1.0))
        return m.ResultsAttachment(names, [""] * len(names), info, self.contexts.get(run_id)), rows

    def watch(self, **callbacks: Any) -> FakeWatch:
        self.watched = callbacks
        return FakeWatch()

    def of(self, kind: type) -> list[Any]:
        return [c for c in self.sent if isinstance(c, kind)]


class FakeMesh:
    """The server-wide requests of `MeshClient`, answered from memory."""

    def __init__(self, *models: ModelDescription) -> None:
        self.models = {d.id: d for d in models}
        self.sessions: dict[str, FakeSession] = {}
        self.uploaded: list[str] = []
        self.upload_model = ""
        self.kept: list[m.RecordingInfo] = []  # the user's recordings on the server
        self.read: list[tuple[str, Any]] = []  # recording results asked for: (name, variables)
        self.recorded_context: m.RunContext | None = None
        self.no_recorder = False

    def list_models(self) -> list[Any]:
        return [d.summary_entry() for d in self.models.values()]

    def describe(self, model_id: str) -> ModelDescription:
        return self.models[model_id]

    def doc(self, model_id: str, page: str) -> DocPage:
        raise RemoteError(m.Error("not_found", f"no page {page}", "page"))

    def create_session(self, user: str, model_id: str) -> FakeSession:
        sid = keys.new_session_id()
        desc = self.models[model_id]
        state = m.SessionState(session=sid, phase="created", seq=1)
        snap = m.SessionSnapshot(
            session=sid,
            user=user,
            model_id=model_id,
            values=desc.default_values(),
            initial=[0.0] * len(desc.links),
            command=None,
            settings=m.RunSettings(),
            state=state,
        )
        self.sessions[sid] = FakeSession(self, sid, snap)
        return self.sessions[sid]

    def list_sessions(self, user: str) -> list[m.SessionEntry]:
        return [
            m.SessionEntry(s.id, s.snap.model_id, s.snap.state.phase)
            for s in self.sessions.values()
            if s.snap and s.snap.user == user
        ]

    def session(self, user: str, sid: str) -> FakeSession:
        found = self.sessions.get(sid)
        if found is not None and found.snap is not None and found.snap.user == user:
            return found
        return FakeSession(self, sid, None)  # another user's session is as unknown as a closed one

    def download_recording(self, user: str, name: str) -> bytes:
        return b"\x89MCAP0\r\n" + name.encode()

    def recordings(self, user: str) -> list[m.RecordingInfo]:
        if self.no_recorder:
            raise NoReply("no node answered simecs/u/tester/recordings within 10.0 s")
        return list(self.kept)

    def recording_results(
        self, user: str, name: str, variables: Any = None, t0: Any = None, t1: Any = None, every: int = 1
    ) -> tuple[m.ResultsAttachment, np.ndarray]:
        """A recording read on the server: 21 samples over 2 s, each variable k+1 times the time."""
        info = next((r for r in self.kept if r.name == name), None)
        if info is None:
            raise RemoteError(m.Error("not_found", f"{user} has no recording {name!r}", "name"))
        self.read.append((name, variables))
        names = ["time", *(variables or ["joint1.q", "joint2.q"])]
        t = np.linspace(0.0, 2.0, 21)
        if t0 is not None and t1 is not None and t1 < t0:
            t = t[:0]
        rows = np.column_stack([t] + [t * (k + 1) for k in range(len(names) - 1)])
        run = m.RunInfo(info.run_id, "finished", info.stop_time, 2.0, 21, recording=name)
        return m.ResultsAttachment(names, [""] * len(names), run, self.recorded_context), rows

    def upload_recording(self, user: str, name: str, data: bytes) -> m.RecordingInfo:
        self.uploaded.append(name)
        return m.RecordingInfo(name, "s", "r1", self.upload_model or "arm3", len(data))


class FakeHost:
    """The viewer node as a tab sees it (`host.Host`); `passwords` make it a secured one."""

    def __init__(self, mc: FakeMesh, passwords: dict[str, str] | None = None) -> None:
        self.secured = passwords is not None
        self.passwords = passwords or {}
        self.mc: Any = LibraryOnly(mc) if self.secured else mc
        self.default_user = "tester"
        self.claims = Claims(lambda claimant: not claimant.closed)
        self.logins: list[AsUser] = []

    def describe(self, model_id: str) -> ModelDescription:
        return self.mc.describe(model_id)

    def meshes(self, model: ModelDescription) -> dict[str, bytes]:
        return {}

    def login(self, user: str, password: str) -> Any:
        if self.passwords.get(user) != password:
            raise ValueError(f"the hub did not let {user} in: wrong user name or password?")
        client = AsUser(self.mc.mesh, user)
        self.logins.append(client)
        return client


class LibraryOnly:
    """The viewer's own client on a secured mesh: the library, and nothing of any user."""

    def __init__(self, mesh: FakeMesh) -> None:
        self.mesh = mesh
        self.list_models, self.describe, self.doc = mesh.list_models, mesh.describe, mesh.doc


class AsUser:
    """A client joined as one user: the hub lets nothing of another user's keys through."""

    def __init__(self, mesh: FakeMesh, user: str) -> None:
        self.mesh, self.user, self.closed = mesh, user, False

    def _own(self, user: str) -> None:
        if user != self.user or self.closed:
            raise NoReply(f"no node answered simecs/u/{user}/...")

    def create_session(self, user: str, model_id: str) -> FakeSession:
        self._own(user)
        return self.mesh.create_session(user, model_id)

    def list_sessions(self, user: str) -> list[m.SessionEntry]:
        self._own(user)
        return self.mesh.list_sessions(user)

    def session(self, user: str, sid: str) -> FakeSession:
        self._own(user)
        return self.mesh.session(user, sid)

    def close(self) -> None:
        self.closed = True


class Recorder(list):
    """A listener that keeps every event."""

    def __call__(self, event: Any) -> None:
        self.append(event)

    def of(self, kind: type) -> list[Any]:
        return [e for e in self if isinstance(e, kind)]


def controller(*models: ModelDescription) -> tuple[session.SessionController, FakeMesh, Recorder]:
    mesh = FakeMesh(*(models or (arm(),)))
    ctl = session.SessionController(
        FakeHost(mesh), tab_id=3, sync_delay_s=0.05, loop=TabLoop("t", driven=True)
    )
    got = Recorder()
    ctl.subscribe(got)
    return ctl, mesh, got


def attached(*models: ModelDescription) -> tuple[session.SessionController, FakeSession, Recorder]:
    """A controller that loaded the first model (as the Load button does), workers drained."""
    ctl, mesh, got = controller(*models)
    ctl.start()
    ctl.opening.load_model((models or (arm(),))[0].id)
    ctl.drain()
    assert ctl.session is not None
    return ctl, mesh.sessions[ctl.session.id], got


def state(sc: FakeSession, phase: str, run_id: str = "r1", seq: int = 10, **kw: Any) -> m.SessionState:
    return m.SessionState(session=sc.id, phase=phase, seq=seq, run_id=run_id, **kw)  # type: ignore[arg-type]


def layout(
    sc: FakeSession, model: ModelDescription, run_id: str = "r1", recording: str = "", **values: float
) -> m.RunLayout:
    names, units = model.run_columns()
    context = m.RunContext("tester", {**model.default_values(), **values}, [0.0] * 3, None, m.RunSettings())
    context.recording = recording
    return m.RunLayout(
        session=sc.id,
        run_id=run_id,
        run_index=int(run_id[1:]),
        model_id=model.id,
        columns=names,
        units=units,
        live_columns=columns.live_columns(names, []),
        live_rate_hz=50.0,
        stop_time=1.0,
        output_interval=0.002,
        context=context,
        source="replay" if recording else "simulator",
    )


def live_frame(lay: m.RunLayout, model: ModelDescription, q: list[float], t: float = 0.1) -> frames.Frame:
    """One live row: time, the joint positions `q`, and the link poses the kinematics give for them."""
    row = np.zeros(len(lay.live_columns))
    where = {c: i for i, c in enumerate(lay.live_columns)}
    row[where[columns.TIME]] = t
    for name, qi in zip(model.joint_position_columns(), q, strict=True):
        row[where[name]] = qi
    poses = link_poses(model, lay.context.values, q)
    for frame, pose in zip(model.pose_frames()[: len(poses)], poses, strict=True):
        for field, value in zip(columns.POSE_FIELDS, pose, strict=True):
            row[where[columns.pose_column(frame, field)]] = value
    return frames.Frame(lay.run_index, 0, time.time_ns(), row[None, :], frames.FLAG_LIVE)


# -- architecture ---------------------------------------------------------------------------------
def imports_of(path: Path) -> list[tuple[str, int]]:
    """(module, level) of every import in a file (relative imports keep their level)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, 0) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out += [(node.module or "", node.level)]
            if node.level and not node.module:
                out += [(a.name, node.level) for a in node.names]
    return out


def test_the_controller_knows_nothing_of_viser_and_nothing_imports_the_app() -> None:
    """The session controller and what it uses import no viser and no panel; only the CLI entry
    point needs app.py (no import loop between the app and the tab)."""
    for stem in HEADLESS:
        for name, level in imports_of(VIEWER / f"{stem}.py"):
            assert "viser" not in name, (stem, name)
            if level:
                assert name in HEADLESS or name == "", (stem, name)
    for file in VIEWER.glob("*.py"):
        if file.stem != "app":
            assert all(name not in ("app", "simecs.viewer.app") for name, _ in imports_of(file)), file


def test_the_viewer_builds_no_column_names_keys_or_phase_sets_of_its_own() -> None:
    """Columns come from mesh.columns, keys from mesh.keys, phases from mesh.phases, shape geometry
    from mesh.shapes; a replay is a run of the session (no parallel replay session)."""
    source = "\n".join(p.read_text() for p in VIEWER.glob("*.py"))
    for banned in ('.q"', '"pose.', "pose.{", 'split("/")', "replay_id", "ACTIVE =", "def shape_geometry"):
        assert banned not in source, banned
    assert "def effective_shape" not in source and "def pipe_mesh" not in source


def viewer_imports() -> dict[str, set[str]]:
    """Module stem -> the viewer modules it imports, type-checking imports included."""
    graph: dict[str, set[str]] = {}
    for file in VIEWER.glob("*.py"):
        wanted = set()
        for name, level in imports_of(file):
            stem = name.removeprefix("simecs.viewer.") if not level else name
            if (VIEWER / f"{stem}.py").is_file():
                wanted.add(stem)
        graph[file.stem] = wanted
    return graph


def test_viewer_modules_import_each_other_without_a_cycle() -> None:
    """The parts of the session controller see the tab through its state and dispatcher, never through
    the controller: no module of the viewer reaches back to one that imports it (a circle means a
    part reaching into its owner's privates, one idea badly cut)."""
    graph = viewer_imports()
    done: set[str] = set()

    def visit(stem: str, path: list[str]) -> None:
        assert stem not in path, " -> ".join([*path, stem])
        if stem in done:
            return
        for dep in sorted(graph.get(stem, ())):
            visit(dep, [*path, stem])
        done.add(stem)

    for stem in sorted(graph):
        visit(stem, [])
    for part in ("edits", "runs", "results_io", "opening", "jog"):
        assert "session" not in graph[part], part


def test_viewer_binds_loopback_by_default_and_hides_sharing() -> None:
    from simecs.viewer import app

    parser = __import__("argparse").ArgumentParser()
    app.Viewer.add_arguments(parser)
    args = parser.parse_args([])
    assert args.host == "127.0.0.1" and args.port == 8080
    assert app._no_share() is None
    source = (VIEWER / "app.py").read_text()
    assert "show_share_button=False" in source and "request_share_url = _no_share" in source


def test_claims_give_a_session_to_one_live_tab() -> None:
    a = SimpleNamespace(tab_id=1, closed=False)
    b = SimpleNamespace(tab_id=2, closed=False)
    claims = Claims(lambda c: not c.closed)
    assert claims.claim("s", a) and claims.claim("s", a)
    assert not claims.claim("s", b, wait_s=0.0) and claims.held_by_other("s", b)
    a.closed = True  # the other tab went away (closed, or reloading)
    assert claims.claim("s", b, wait_s=0.0) and not claims.held_by_other("s", b)
    claims.release("s", b)
    assert claims.claim("s", a, wait_s=0.0)


# -- trees ------------------------------------------------------------------------------------------
def test_component_tree_groups_by_component() -> None:
    model = arm()
    roots = tree.build_tree(model.parameters)
    assert [r.path for r in roots] == ["link1", "link2", "link3", "joint1", "drives"]
    joint1 = tree.find(roots, "joint1")
    assert joint1 is not None and not joint1.items and [c.label for c in joint1.children] == ["motor", "gear"]
    assert joint1.count() == 3
    motor = tree.find(roots, "joint1.motor")
    assert motor is not None and [tree.short_name(p) for p in motor.items] == ["R", "kt"]
    assert sum(r.count() for r in roots) == len(model.parameters)


def test_labels_and_hints_carry_unit_bounds_description() -> None:
    p = arm().parameter("joint1.motor.R")
    assert tree.param_label(p) == "R [ohm]"
    hint = tree.param_hint(p, 1.2)
    assert "winding resistance" in hint and "0.01 … 50 ohm" in hint and "Default 1.2 ohm" in hint
    assert tree.param_label(arm().parameter("drives.enabled")) == "enabled"
    assert "whole numbers" in tree.param_hint(arm().parameter("drives.enabled"))
    assert "Changes the 3D shape" in tree.param_hint(arm().parameter("link2.length"))
    assert tree.var_label(arm().variables[1]) == "qd [rad/s]"
    assert [p.name for p in tree.search(arm().parameters, "torque")] == ["joint1.motor.kt"]
    assert tree.search(arm().parameters, "  ") == []
    assert tree.fmt(0.1 + 0.2) == "0.3" and tree.fmt(160.0) == "160" and tree.fmt(1.5e-3) == "0.0015"


def test_number_step_keeps_four_significant_digits() -> None:
    model = arm()
    assert params.number_step(model.parameter("drives.enabled"), 1.0) == 1.0
    assert params.number_step(model.parameter("joint1.motor.kt"), 0.12) == pytest.approx(1e-4)
    assert params.number_step(model.parameter("joint1.gear.ratio"), 160.0) == pytest.approx(0.1)
    assert params.number_step(model.parameter("joint1.motor.kt"), 1.5e-3) == pytest.approx(1e-6)
    assert params.number_step(model.parameter("link2.mass"), 0.0) == pytest.approx(0.01)


def test_real_spider_description_builds_trees_and_shapes() -> None:
    """The Spider as the server sends it: every parameter and variable in the trees, shapes drawable."""
    models = pytest.importorskip("simecs.models")
    desc = models.get_model("spider").describe()
    roots = tree.build_tree(desc.parameters)
    assert sum(r.count() for r in roots) == len(desc.parameters)
    assert sum(r.count() for r in tree.build_tree(desc.variables)) == len(desc.variables)
    drawn = list(shapes.solids(desc, desc.default_values()))
    assert len(drawn) == len(desc.shapes) + len(desc.environment)
    assert all(np.all(np.isfinite(s.geometry.position)) for s in drawn)
    names, _units = desc.run_columns()
    assert columns.pose_indices(names, desc.pose_frames()) is not None
    assert len(desc.joint_position_columns()) == len(desc.links)


# -- scene: geometry from mesh.shapes, drawn by ArmScene ------------------------------------------------
def test_shape_geometry_follows_the_shape_convention() -> None:
    cyl = shapes.shape_geometry(Shape("cylinder", 0, [0.0, 0.0, -0.05], "z", length=0.1, radius=0.06))
    assert (
        cyl.kind == "cylinder" and np.allclose(cyl.position, [0, 0, 0]) and cyl.wxyz == (1.0, 0.0, 0.0, 0.0)
    )
    pipe = shapes.shape_geometry(Shape("pipe", 0, [0.1, 0, 0], "x", 0.8, 0.05, 0.04))
    assert (
        pipe.kind == "pipe"
        and np.allclose(pipe.position, [0.5, 0, 0])
        and pipe.inner_ratio == pytest.approx(0.8)
    )
    # the rotation takes local z onto the shape axis
    w, x, y, z = pipe.wxyz
    rz = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    assert np.allclose(rz, [1, 0, 0])
    w, x, y, z = shapes.AXIS_WXYZ["y"]
    assert np.allclose([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], [0, 1, 0])
    box = shapes.shape_geometry(Shape("box", -1, [-1.0, 0.0, -0.02], "x", length=2.0, width=3.0, height=0.02))
    assert box.dimensions == (2.0, 3.0, 0.02) and np.allclose(box.position, [0, 0, -0.02])
    beam = shapes.shape_geometry(Shape("beam", 0, [0, 0, 0], "z", length=1.0, width=0.2, height=0.1))
    assert beam.dimensions == (0.2, 0.1, 1.0)
    solid = shapes.shape_geometry(Shape("pipe", 0, [0, 0, 0], "x", 1.0, 0.05, 0.0))
    assert solid.kind == "cylinder"
    assert shapes.shape_geometry(Shape("sphere", 0, [1, 2, 3], radius=0.1)).position.tolist() == [1, 2, 3]
    assert not shapes.shape_geometry(Shape("cylinder", 0, [0, 0, 0], length=0.0, radius=0.1)).visible


def test_resizable_shape_takes_the_link_length() -> None:
    model = arm()
    defaults = model.default_values()
    values = {**defaults, "link2.length": 1.25}
    assert shapes.effective_shape(model.shapes[2], model, values, defaults).length == 1.25
    assert shapes.effective_shape(model.shapes[0], model, values, defaults).length == 0.1  # not resizable
    link2 = [s for s in shapes.solids(model, values) if s.frame == "link2"]
    assert len(link2) == 1 and link2[0].geometry.length == 1.25


def test_shapes_follow_bound_parameters_when_the_description_carries_them() -> None:
    """`scales_with` and `anchor` reshape and move solids proportionally."""
    model = arm()
    model.parameters.append(Parameter("link3.radius", 0.05, "m", "tube", 0.01, 0.5, "link3", appearance=True))
    defaults = model.default_values()
    tube = Shape("pipe", 2, [0.0, 0.0, 0.0], "x", 0.3, 0.05, 0.04, resizable=True)
    tube.scales_with = {"radius": "link3.radius", "inner_radius": "link3.radius"}
    flange = Shape("cylinder", 2, [0.3, 0.0, 0.0], "x", length=0.02, radius=0.06)
    flange.anchor = "end"
    values = {**defaults, "link3.radius": 0.1, "link3.length": 0.5}
    t = shapes.effective_shape(tube, model, values, defaults)
    assert (t.length, t.radius, t.inner_radius) == pytest.approx((0.5, 0.1, 0.08))
    f = shapes.effective_shape(flange, model, values, defaults)
    assert f.origin[0] == pytest.approx(0.5) and flange.origin[0] == 0.3  # the description is untouched
    plain = shapes.effective_shape(model.shapes[0], model, values, defaults)
    assert plain == model.shapes[0]
    assert "link3.radius" in shapes.appearance_parameters(model)


def test_pipe_mesh_is_closed_and_outward() -> None:
    v, f = shapes.pipe_mesh(0.8, segments=16)
    assert v.shape == (8 * 16, 3) and f.shape == (8 * 16, 3) and f.max() < len(v)
    assert np.allclose(np.abs(v[:, 2]), 0.5)
    # outer-wall triangles face away from the axis
    tri = v[f[:32]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1)
    assert np.all((normal[:, :2] * centre[:, :2]).sum(axis=1) > 0)


def test_pose_indices_map_the_pose_columns() -> None:
    model = arm()
    names, _units = model.run_columns()
    idx = columns.pose_indices(names, model.pose_frames())
    # three links, the tool and the grasped object
    assert idx is not None and idx.shape == (5, 7) and names[idx[1, 0]] == "pose.link2.x"
    assert columns.pose_indices([columns.TIME, "joint1.q"], model.pose_frames()) is None


def test_arm_scene_builds_poses_and_reshapes(server: Any) -> None:
    model = arm()
    values = model.default_values()
    s = scene.ArmScene(server.scene, model, values, root="/t_arm")
    s.build()
    try:
        assert len(s.frames) == 3 and len(s.solids) == 5
        q = [0.3, -0.5, 0.7]
        s.show_q(q)
        expected = link_poses(model, values, q)
        for frame, row in zip(s.frames, expected, strict=False):
            assert np.allclose(frame.position, row[:3]) and np.allclose(frame.wxyz, row[3:])
        # a longer upper arm: its pipe stretches and the next link frame moves along
        before = np.array(s.frames[2].position)
        assert s.set_values({**values, "link2.length": 1.0})
        pipe = s.solids[2][0]
        assert pipe.scale[2] == pytest.approx(1.0) and np.allclose(pipe.position, [0.5, 0, 0])
        beam = s.solids[3][0]
        assert s.set_values({**values, "link2.length": 1.0, "link3.length": 0.8})
        assert beam.dimensions[0] == pytest.approx(0.8)
        assert not np.allclose(s.frames[2].position, before)
        assert not s.set_values({**values, "link2.length": 1.0, "link3.length": 0.8, "link2.mass": 9.0})
    finally:
        s.remove()


# -- joint path -----------------------------------------------------------------------------------
def test_joint_path_editor_add_teach_remove_reorder() -> None:
    ed = path.JointPathEditor(arm().links)
    with pytest.raises(path.PathError, match="empty"):
        ed.to_command()
    ed.teach([0.1, 0.2, 0.3])
    ed.duplicate([0.0, 0.0, 0.0])
    ed.set_q([1.0, 5.0, -5.0])  # clamped into the joint ranges
    assert ed.nodes[1].q == [1.0, 2.0, -2.0] and ed.selected == 1
    ed.set_pct(50, 25)
    ed.select(0)
    ed.teach([0.5, 0.5, 0.5])  # inserted after the selected node
    assert [n.q[0] for n in ed.nodes] == [0.1, 0.5, 1.0] and ed.selected == 1
    ed.move(+1)
    assert [n.q[0] for n in ed.nodes] == [0.1, 1.0, 0.5] and ed.selected == 2
    with pytest.raises(path.PathError, match="already last"):
        ed.move(+1)
    with pytest.raises(path.PathError, match="speed"):
        ed.set_pct(0, 50)
    with pytest.raises(path.PathError, match="3 joint positions"):
        ed.teach([0.0])
    ed.remove()
    assert len(ed.nodes) == 2 and ed.selected == 1
    cmd = ed.to_command()
    assert isinstance(cmd, m.JointPath) and cmd.nodes[1].speed_pct == 50 and cmd.nodes[1].acc_pct == 25
    assert codec.loads(m.SetCommand, codec.dumps(m.SetCommand(cmd))).command == cmd  # valid on the wire
    table = ed.table_markdown()
    assert "**▶2**" in table and "57.3" in table and "| 50 | 25 |" in table
    again = path.JointPathEditor(arm().links)
    again.load(cmd)
    assert [n.q for n in again.nodes] == [n.q for n in ed.nodes] and again.selected == 0


def test_pendant_panel_buttons_and_sliders(server: Any) -> None:
    ed = path.JointPathEditor(arm().links)
    changes, previews, errors = [], [], []
    current = [0.2, -0.3, 0.4]
    panel = pendant.PendantPanel(
        server.gui,
        ed,
        current_q=lambda: list(current),
        on_changed=lambda: changes.append(len(ed.nodes)),
        on_preview=previews.append,
        on_error=errors.append,
    )

    def click(label: str) -> None:
        panel._clicked(Event(SimpleNamespace(value=label)))

    click("Teach")
    click("Teach")
    assert len(ed.nodes) == 2 and changes == [1, 2]
    assert panel.node.options == ("1", "2") and panel.node.value == "2"
    panel.sliders.sliders[0].value = 30.0
    panel.sliders._moved(Event(panel.sliders.sliders[0]))
    assert ed.nodes[1].q[0] == pytest.approx(math.radians(30)) and previews[-1][0] == pytest.approx(
        math.radians(30)
    )
    panel.speed.value = 150.0
    panel._pct(Event(panel.speed))
    assert errors and "speed 150" in errors[-1] and ed.nodes[1].speed_pct == 100.0
    panel.set_disabled(True)
    click("Remove")
    assert len(ed.nodes) == 2 and "cannot change" in errors[-1]
    panel.set_disabled(False)
    click("Up")
    assert ed.selected == 0 and ed.nodes[0].q[0] == pytest.approx(math.radians(30))
    assert "**▶1**" in panel.table.content


def test_a_slider_value_newer_than_its_callback_is_not_undone(server: Any) -> None:
    """viser stores a slider's value on its own thread when the browser sends it, and calls back on
    the tab's loop: typing "30" sends 3, then 30, and the 30 may be stored while the callback of 3
    runs. That callback must not write its node (3 deg) back over the slider: the callback of 30
    comes next and reads the slider (the fresh-clone failure: the path's node kept 3 deg)."""
    ed = path.JointPathEditor(arm().links)
    arrivals: list[float] = []

    def preview(_q: list[float]) -> None:  # called inside the callback: the browser's next value lands
        if arrivals:
            panel.sliders.sliders[0].value = arrivals.pop()

    panel = pendant.PendantPanel(
        server.gui, ed, lambda: [0.0, 0.0, 0.0], lambda: None, preview, lambda _e: None
    )
    panel._clicked(Event(SimpleNamespace(value="Teach")))
    slider = panel.sliders.sliders[0]
    slider.value = 3.0  # the browser's "3"; its "30" lands during the callback of "3"
    arrivals.append(30.0)
    panel.sliders._moved(Event(slider))
    assert slider.value == 30.0, "the callback of 3 wrote its node back over the newer 30"
    panel.sliders._moved(Event(slider))
    assert ed.nodes[0].q[0] == pytest.approx(math.radians(30))


def test_joint_sliders_are_in_degrees_within_limits(server: Any) -> None:
    got = []
    s = joints.JointSliders(server.gui, arm().links, [0.5, 0.0, -3.0], got.append)
    assert s.sliders[0].value == pytest.approx(28.648) and s.sliders[2].value == pytest.approx(-114.5)
    assert s.sliders[1].min == pytest.approx(-114.5) and s.sliders[1].max == pytest.approx(114.5)
    s.sliders[1].value = 10.0  # code assigning: no callback to the tab
    s._moved(Event(s.sliders[1], client=None))
    assert got == []
    s._moved(Event(s.sliders[1]))
    assert got[-1][1] == pytest.approx(math.radians(10.0))
    assert "`jointN.q_motor`" in joints.init_equations_markdown(arm().init_equations)


# -- parameters / variables panels ------------------------------------------------------------------
def test_param_panel_shows_a_component_and_sends_only_applied_edits(server: Any) -> None:
    """Issue 12, 0: a value typed key by key is a draft (checked as typed, never sent half-typed,
    never overwritten by the server's values); Apply sends the drafts at once; a refusal stays beside
    the fields with the server's reason; Discard goes back to the stored values."""
    model = arm()
    sent, resets, ops = [], [], []
    panel = params.ParamPanel(
        server.gui,
        model,
        model.default_values(),
        lambda changes: sent.append(dict(changes)),
        resets.append,
        lambda op, name: ops.append((op, name)),
    )
    assert list(panel.fields) == ["link1.length"]  # the first component with items
    assert panel.tree.folder.label == "Components · link1"  # folded under what it shows
    panel.tree.buttons["joint1.motor"]._impl.update_cb[0](Event(panel.tree.buttons["joint1.motor"]))
    assert list(panel.fields) == ["joint1.motor.R", "joint1.motor.kt"]
    assert panel.tree.folder.label == "Components · joint1.motor" and panel.tree.picked == "joint1.motor"
    field = panel.fields["joint1.motor.R"]
    assert field.label == "R [ohm]" and "winding resistance" in field.hint
    R = model.parameter("joint1.motor.R")
    assert panel.apply.disabled and panel.discard.disabled
    for typed in (0.0, 2.0, 2.5):  # "0" on the way is out of bounds: shown, not sent
        field.value = typed
        panel._edited(Event(field), R)
        if typed == 0.0:
            assert "outside" in panel.notice.content and panel.apply.disabled
    assert sent == [] and field.label == "R [ohm]" + params.DRAFT_MARK and not panel.apply.disabled
    # the server's values (another field changed meanwhile) leave the draft as typed
    panel.show_values({**model.default_values(), "joint1.motor.kt": 0.2})
    assert field.value == 2.5 and panel.fields["joint1.motor.kt"].label.endswith("•")
    panel._apply()
    assert sent == [{"joint1.motor.R": 2.5}]
    panel.refused("joint1.motor.R", "values.joint1.motor.R: too hot")
    assert "too hot" in panel.notice.content and field.value == 2.5
    panel.show_values({**model.default_values(), "joint1.motor.kt": 0.2, "joint1.motor.R": 2.5})
    assert (
        panel.drafts == {} and field.label == "R [ohm]" + params.CHANGED_MARK and panel.notice.content == ""
    )
    field.value = 3.0
    panel._edited(Event(field), R)
    panel._discard()
    assert field.value == 2.5 and panel.drafts == {} and panel.apply.disabled
    panel.search.value = "torque"
    panel._on_search(Event(panel.search))
    assert list(panel.fields) == ["joint1.motor.kt"]
    panel.set_names(["a", "b"])
    assert panel.sets.options == ("a", "b")
    # "Reset all" asks first: keeping the values sends nothing, agreeing resets every parameter
    click = lambda button: button._impl.update_cb[0](Event(button))  # noqa: E731
    click(panel.reset_all)
    assert panel.confirm is not None and resets == []
    click(panel.confirm[1])
    assert resets == []
    click(panel.reset_all)
    click(panel.confirm[0])
    assert resets == [[]]


def test_variable_panel_streams_and_plots(server: Any) -> None:
    model = arm()
    streamed, plotted = [], []
    panel = params.VariablePanel(server.gui, model, {"joint1.q"}, streamed.append, plotted.append)
    assert set(panel.checks) == {"joint1.q", "joint1.qd"}
    check = panel.checks["joint1.qd"]
    check.value = True
    panel._ticked(Event(check), model.variables[1])
    assert streamed[-1] == {"joint1.q", "joint1.qd"}
    panel.show_streamed({"joint1.qd"})
    assert panel.checks["joint1.q"].value is False and "Streaming **1**" in panel.summary.content
    # the component shown first, picked in the tree: its rows stay (a click on them is not lost)
    rows = list(panel.rows)
    panel.tree.pick(panel.tree.first)
    assert panel.rows == rows and not any(r._impl.removed for r in rows)
    rows[1]._impl.update_cb[0](Event(rows[1]))
    assert plotted == ["joint1.q"]


# -- plots ---------------------------------------------------------------------------------------------
def test_live_buffer_is_a_bounded_window() -> None:
    buf = series.LiveBuffer(capacity=100)
    buf.reset(["time", "a", "b"])
    for k in range(25):
        t = np.arange(k * 10, k * 10 + 10) * 0.01
        buf.append(np.column_stack([t, t * 2, -t]))
    assert len(buf) == 100
    t, (a, b) = buf.window(["a", "b"])
    assert len(t) == 100 and t[0] == pytest.approx(1.5) and t[-1] == pytest.approx(2.49)
    assert np.allclose(a, 2 * t) and np.all(np.diff(t) > 0)
    t, (a,) = buf.window(["a"], seconds=0.2)
    assert t[0] >= 2.29 - 1e-9
    _, (missing,) = buf.window(["nope"])
    assert np.all(missing == 0)
    buf.append(np.zeros((3, 2)))  # wrong width: ignored
    assert len(buf) == 100


def test_full_resolution_requests_stay_bounded() -> None:
    assert series.every_for(2501, None, None, 5.0) == 1
    assert series.every_for(2_000_001, None, None, 3600.0) == math.ceil(2_000_001 / series.MAX_POINTS)
    assert series.every_for(2_000_001, 0.0, 36.0, 3600.0) == 2  # a 1 % zoom is (nearly) full resolution


def test_overlay_puts_two_runs_on_one_time_axis() -> None:
    t = np.linspace(0, 1, 11)
    t_prev = np.linspace(0, 2, 5)
    x, cur, (prev,) = series.overlay(t, [t * 2], [(t_prev, [t_prev * 3])])
    assert x[0] == 0 and x[-1] == 2 and np.all(np.diff(x) > 0)
    assert np.allclose(np.interp(0.5, x, cur[0]), 1.0) and np.allclose(np.interp(1.5, x, prev[0]), 4.5)
    # a shorter run is drawn to its own end, never held flat beyond it (uPlot draws no NaN)
    beyond = x > 1.0
    assert beyond.any() and np.isnan(cur[0][beyond]).all() and not np.isnan(cur[0][~beyond]).any()
    assert not np.isnan(prev[0]).any()
    x, cur, (prev,) = series.overlay(np.empty(0), [np.empty(0)], [(t_prev, [t_prev])])
    assert np.array_equal(x, t_prev) and np.isnan(cur[0]).all()
    # several compared runs: each interpolated onto the union of all times, each to its own end
    t3 = np.linspace(0, 0.5, 6)
    x, cur, (_, (b,)) = series.overlay(t, [t], [(t_prev, [t_prev]), (t3, [-t3])])
    assert set(t3) <= set(x) and np.isnan(b[x > 0.5]).all() and np.allclose(np.interp(0.25, x, b), -0.25)


def test_the_time_cursor_is_a_vertical_line_that_breaks_no_other_line() -> None:
    x = np.linspace(0, 1, 11)
    y = 2 * x
    y_short = np.where(x <= 0.5, -x, np.nan)  # a compared run that ended at 0.5 s
    x2, (y2, s2), line = series.with_cursor(x, [y, y_short], 0.25)
    k = int(np.flatnonzero(np.isfinite(line))[0])
    assert x2[k] == 0.25 and 0.25 < x2[k + 1] < 0.25 + 1e-5 and np.all(np.diff(x2) > 0) and len(x2) == 13
    assert (line[k], line[k + 1]) == (-0.5, 2.0)  # spans every run's values
    assert np.isfinite(line).sum() == 2 and y2[k] == 0.5 and s2[k] == -0.25
    _, (_, s3), _ = series.with_cursor(x, [y, y_short], 0.75)
    assert np.isnan(s3[np.searchsorted(x, 0.75) :][:2]).all()  # past the short run's end: no value
    x5, (y5,), line5 = series.with_cursor(x, [y], 0.5)  # on a sample: one point added after it
    assert len(x5) == 12 and np.all(np.diff(x5) > 0) and line5[5] == 0.0 and line5[6] == 2.0
    x4, _, none = series.with_cursor(x, [y], 2.0)  # outside the data: no line
    assert np.array_equal(x4, x) and np.isnan(none).all()


def test_plot_redraws_live_then_full_resolution(server: Any) -> None:
    actions = plots.PlotActions(
        load_full=lambda *a: None,
        close=lambda p: None,
        error=lambda msg: None,
        added=lambda p, n: None,
        variable_names=lambda: ["joint1.q", "joint2.q"],
        batch=server.atomic,
    )
    plot = plots.Plot(server.gui, 1, ["joint1.q"], {"joint1.q": "rad"}, actions)
    buf = series.LiveBuffer()
    buf.reset(["time", "joint1.q"])
    plot.redraw(buf)  # no sample yet: the live window's span, nothing drawn in it, a y axis all the same
    assert list(plot.chart.data[0]) == [0.0, 10.0] and np.isnan(plot.chart.data[1]).all()
    assert plot.chart.scales["y"]["range"] == [-0.5, 0.5] and plot.chart.scales["x"]["range"] == [0, 10]
    plot.stop_time = 2.0  # a run shorter than the window: its own span, from its start
    plot.redraw(buf)
    assert plot.chart.scales["x"]["range"] == [0, 2]
    buf.append(np.column_stack([np.linspace(0, 1, 50), np.linspace(0, 2, 50)]))
    plot.redraw(buf)
    assert len(plot.chart.data) == 2 and len(plot.chart.data[0]) == 50
    assert plot.chart.series[1]["label"] == "joint1.q [rad]"
    plot.full = series.Transient("r2", np.linspace(0, 1, 500), {"joint1.q": np.ones(500)})
    plot.others = [series.Transient("r1", np.linspace(0, 1, 300), {"joint1.q": np.zeros(300)})]
    plot.redraw(buf)
    assert len(plot.chart.data) == 3 and len(plot.chart.data[0]) >= 500
    assert plot.chart.series[2]["dash"] == [6, 4] and "r2 full res" in plot.title()
    assert (
        plot.chart.series[2]["label"] == "joint1.q (r1)" and plot.chart.series[2]["stroke"] == plots.COLORS[1]
    )
    plot.cursor = 0.5
    plot.redraw(buf)
    assert len(plot.chart.data) == 4 and plot.chart.series[-1]["label"] == "cursor"
    plot.cursor = None
    plot.add_var.value = "joint2.q"
    plot._add_variable(Event(plot.add_var))
    assert plot.variables == ["joint1.q", "joint2.q"] and plot.add_var.value == "—"
    # Reset zoom: a drag-zoom lives in the browser's chart; new scales make it draw the chart anew
    # (the same chart: nothing is removed under the user's pointer)
    old, scaled = plot.chart, dict(plot.chart.scales)
    plot.reset_zoom()
    assert plot.dirty
    plot.redraw(buf)
    assert plot.chart is old and plot.chart.scales != scaled
    assert plot.chart.scales["x"]["range"] == [0, 1]  # the full resolution's span
    assert len(plot.chart.data) == 5 and plot.chart.series[2]["label"] == "joint2.q"  # 2 + 2 overlaid
    plot._transient(Event(SimpleNamespace(value="Live")))  # back to live: no drag-zoom left over
    plot.redraw(buf)
    assert plot.full is None and plot.chart is old and plot.chart.scales["x"]["range"] == [0, 2]
    plot.remove()


def test_the_live_time_axis_shows_the_runs_span_or_sweeps_the_window() -> None:
    """Issue 32, 1: the live time axis is never wider than the live window or the run, whichever is
    shorter; past the window it moves on a quarter at a time, keeping its span."""
    assert plots.live_axis(0.3, 10.0, 2.0, None) == (0.0, 2.0)
    assert plots.live_axis(1.9, 10.0, 2.0, (0.0, 2.0)) == (0.0, 2.0)
    assert plots.live_axis(4.0, 10.0, 60.0, None) == (0.0, 10.0)
    lo, hi = plots.live_axis(10.5, 10.0, 60.0, (0.0, 10.0))
    assert (lo, hi) == pytest.approx((3.0, 13.0))
    assert plots.live_axis(12.9, 10.0, 60.0, (lo, hi)) == (lo, hi)  # kept while the trace is inside
    assert plots.live_axis(5.0, 4.0, 0.0, None)[1] - plots.live_axis(5.0, 4.0, 0.0, None)[0] == 4.0


def test_a_variable_against_another_is_drawn_as_a_curve(server: Any) -> None:
    loaded: list[Any] = []
    actions = plots.PlotActions(
        load_full=lambda p, t0, t1: loaded.append((p.names(), t0, t1)),
        close=lambda p: None,
        error=lambda msg: None,
        added=lambda p, n: loaded.append(n),
        variable_names=lambda: ["joint1.q", "joint2.q"],
        batch=server.atomic,
    )
    units = {"joint1.q": "rad", "joint2.q": "rad"}
    plot = plots.Plot(server.gui, 1, ["joint1.q"], units, actions)
    plot.set_choices(["joint1.q", "joint2.q"])
    assert plot.x_axis.options == ("time", "joint2.q")
    plot.x_axis.value = "joint2.q"
    plot._x_axis_changed(Event(plot.x_axis))
    assert plot.names() == ["joint1.q", "joint2.q"] and loaded == ["joint2.q"]  # streamed from now on
    assert not plot.chart.visible and plot.xy.visible and "vs joint2.q" in plot.title()
    buf = series.LiveBuffer()
    buf.reset(["time", "joint1.q", "joint2.q"])
    t = np.linspace(0, 2 * np.pi, 200)
    buf.append(np.column_stack([t, np.cos(t), np.sin(t)]))  # a circle: x turns back on itself
    plot.cursor = np.pi / 2
    plot.redraw(buf)
    content = plot.xy.content
    assert content.count("<polyline") == 1 and "joint2.q [rad]" in content and "<circle" in content
    plot.others = [series.Transient("r1", t, {"joint1.q": 0.5 * np.cos(t), "joint2.q": 0.5 * np.sin(t)})]
    plot.redraw(buf)
    assert plot.xy.content.count("<polyline") == 2 and "stroke-dasharray" in plot.xy.content
    assert xy_plot.nice_ticks(-1.05, 1.05) == [-1.0, 0.0, 1.0]
    assert xy_plot.nice_ticks(0.0, 1.0) == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert "no data yet" in xy_plot.svg([], "x", "y")
    assert "&lt;b&gt;" in xy_plot.svg([xy_plot.XYLine("<b>", "#000", t, t)], "x", "y")  # labels escaped
    plot.full = series.Transient("r2", t, {"joint1.q": t})
    plot.x_axis.value = "time"
    plot._x_axis_changed(Event(plot.x_axis))
    assert plot.chart.visible and not plot.xy.visible and plot.names() == ["joint1.q"]
    plot.remove()


def test_plot_dock_opens_and_closes_with_its_plots(server: Any) -> None:
    closed: list[Any] = []
    actions = plots.PlotActions(
        load_full=lambda *a: None,
        close=closed.append,
        error=lambda msg: None,
        added=lambda p, n: None,
        variable_names=lambda: ["joint1.q"],
        batch=server.atomic,
    )
    placed: list[Any] = []

    def place() -> tuple[Any, Any]:  # what the page does on a wide screen: a column of their own
        panel = server.gui.add_panel()
        placed.append(panel)
        return panel, panel.add_tab("Plots")

    dock = plot_dock.PlotDock(server.gui, {}, actions, place)
    a = dock.open("joint1.q", ["joint1.q", "joint2.q"])
    b = dock.open("joint2.q", ["joint1.q", "joint2.q"])
    assert (a.number, b.number) == (1, 2) and dock.get(2) is b and dock.plotted() == {"joint1.q", "joint2.q"}
    assert placed == [dock.panel]  # the panel is placed once, by the layout
    a.full = series.Transient("r1", np.zeros(2))
    dock.new_run()
    assert a.full is None and a.dirty
    dock.close(a)
    assert dock.panel is not None and dock.get(1) is None
    dock.close(b)
    assert dock.panel is None and not dock.plots


# -- documentation ---------------------------------------------------------------------------------
def test_doc_links_become_buttons_and_history_goes_back(server: Any) -> None:
    model = arm()
    titles = {p.id: p.title for p in model.docs}
    r = docs.render(model.docs[1], titles)
    assert r.links == [("arm", "the arm")]  # doc:arm.motor does not exist: plain text, no button
    # an in-text link names the button that follows it (the tab's script clicks that button)
    assert f"[the arm]({docs.LINK_PREFIX}%E2%86%92%20Arm)" in r.markdown
    assert docs.button_label("Arm") == "→ Arm" and "doc:" not in r.markdown.replace("arm.motor", "")
    # a page's raw HTML is shown as text, its code as typed
    shown = docs.render(DocPage("x", "X", "a <script>alert(1)</script> `<link>`"), titles).markdown
    assert "<script>" not in shown and "&lt;script>" in shown and "`<link>`" in shown
    r0 = docs.render(model.docs[0], titles)
    assert r0.links == [("arm.joint", "joint drive"), ("arm.chain", "Chain")]
    h = docs.DocHistory("arm")
    h.go("arm.joint")
    h.go("arm.chain")
    assert h.back() and h.current == "arm.joint" and h.back() and h.current == "arm" and not h.back()

    asked: list[str] = []
    window = docs.DocsWindow(server.gui, model.docs, "arm", asked.append, lambda panel: None)
    window.open()
    window.follow("arm.joint")
    assert window.history.current == "arm.joint"
    window.back()
    assert window.history.current == "arm"
    window.follow("arm.motor")  # not carried in the description: asked from the server, off-thread
    assert asked == ["arm.motor"] and "Loading" in window.widgets[1].content
    window.receive(DocPage("arm.motor", "Motor", "The motor."))
    assert "The motor." in window.widgets[1].content and asked == ["arm.motor"]
    window.close()
    assert not window.is_open


# -- results, run, library --------------------------------------------------------------------------
def test_csv_has_units_and_full_precision() -> None:
    rows = np.array([[0.0, 1 / 3], [0.002, 2.0]])
    data = table_csv.table_bytes(["time", "joint1.q"], rows, ["s", "rad"], {"run": "r1"}).decode()
    lines = data.splitlines()
    assert lines[:3] == ["# run: r1", "time,joint1.q", "s,rad"]
    assert float(lines[3].split(",")[1]) == 1 / 3
    back = np.loadtxt(data.splitlines()[3:], delimiter=",")
    assert np.array_equal(back, rows)
    assert export.csv_name("spider", "abcdefghijkl", "r3") == "simecs_spider_abcdefgh_r3.csv"


def test_uploaded_files_get_key_safe_recording_names() -> None:
    assert export.upload_name("C:\\\\runs\\\\my run (2).MCAP") == "my_run__2_"
    assert export.upload_name("/tmp/..hidden.mcap") == "hidden"
    assert export.upload_name("été.mcap") == "t_"
    assert export.upload_name(".mcap") == "upload"
    assert keys.check_name(export.upload_name("x" * 200 + ".mcap"), "recording name")
    # A run's name stays the run's: its downloaded file comes back as a copy.
    sid = keys.new_session_id()
    assert export.upload_name(f"{sid}_r12.mcap") == f"{sid}_r12-copy"
    assert export.upload_name(f"{sid}_r12.2.mcap") == f"{sid}_r12.2-copy"
    assert not keys.is_run_recording_name(export.upload_name(f"{sid}_r12.mcap"))


def test_results_panel_lists_runs_and_replays(server: Any) -> None:
    got: list[tuple[str, str]] = []
    panel = results.ResultsPanel(server.gui, lambda a, r: got.append((a, r)), lambda n, d: None)
    runs = [m.RunInfo("r1", "finished", 1.0, 1.0), m.RunInfo("r2", "running", 1.0, 0.4, recording="s_r1")]
    panel.show_runs(runs, "r2")
    assert panel.runs.options[0].startswith("r2") and "replay of s_r1" in panel.runs.options[0]
    assert panel.selected() == "r2"
    panel.runs.value = panel.runs.options[1]
    assert panel.selected() == "r1"


def test_text_from_a_model_or_the_server_is_shown_never_run() -> None:
    """viser renders raw HTML in markdown, scripts included: a model's names, summaries and equations
    and a server's reasons are escaped wherever they reach markdown (markup.py)."""
    evil = "<img src=x onerror=alert(1)>"
    model = arm()
    summary = library.model_markdown(msgspec.structs.replace(model.summary_entry(), name=evil, summary=evil))
    eqs = joints.init_equations_markdown([InitEquation("x", "q", evil)])
    failed = m.SessionState("s" * 22, "failed", run_id="r2", reason=evil, warnings=[evil])
    for shown in (summary, eqs, run.status_detail(failed)):
        assert "<img" not in shown and "&lt;img" in shown, shown


def test_status_line_and_run_buttons() -> None:
    st = m.SessionState("s" * 22, "running", run_id="r2", progress=0.5, sim_time=1.0, rtf=0.98)
    assert run.status_text(st) == "**running** run r2 · t = 1.000 s · 50 % · RTF 0.98"
    assert "**running** replay r2 of `s_r1`" in run.status_text(st, replay="s_r1")
    doing = msgspec.structs.replace(st, step="tasks[1].actions[0]", task="back", action="home")
    assert run.status_detail(doing) == "⏵ back · home"  # the step that runs, beside the run bar
    unnamed = msgspec.structs.replace(doing, task="", action="")
    assert run.status_detail(unnamed) == "⏵ task 2, action 1"  # counted as the tables count (issue 32, 9)
    assert path.step_words("nodes[0]") == "node 1" and path.step_words("signals") == "signals"
    failed = m.SessionState("s" * 22, "failed", run_id="r2", reason="diverged: 2*pi*f")
    assert "diverged" not in run.status_text(failed)  # the reason is in the session panel, as written:
    assert r"diverged: 2\*pi\*f" in run.status_detail(failed)  # stars, not emphasis (issue 32, 9)
    queued = m.SessionState("s" * 22, "queued", run_id="r3", queue_position=2)
    assert "position 2" in run.status_text(queued)
    assert run.applicable("finished") == ["Run"] and run.applicable("paused") == ["Resume", "Abort"]
    assert run.applicable("running") == ["Pause", "Abort"] and run.applicable("queued") == ["Abort"]
    assert set(run.RUN_BUTTONS.values()) == {"run", "pause", "resume", "abort"}


def test_settings_form_is_checked_before_sending() -> None:
    s = run.settings_from_form(2.0, 0.002, 0.0, "N x real time", 4.0, 50.0, ["joint1.q"])
    assert s.pacing == "scaled" and s.factor == 4.0 and s.live_vars == ["joint1.q"]
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(-1.0, 0.002, 0.0, "real time", 1.0, 50.0, [])
    assert err.value.field == "stop_time"
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(1.0, 2.0, 0.0, "real time", 1.0, 50.0, [])
    assert err.value.field == "output_interval"
    with pytest.raises(DecodeError):
        run.settings_from_form(1.0, 0.002, 0.0, "warp", 1.0, 50.0, [])
    # The control system by its title; the settings the form does not show are kept from `base`.
    base = m.RunSettings(controller="external", control_period=0.002, hil_timeout=5.0)
    s = run.settings_from_form(2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], base=base)
    assert (s.controller, s.control_period, s.hil_timeout, s.stop_time) == ("external", 0.002, 5.0, 2.0)
    s = run.settings_from_form(
        2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], "operational-space motion control"
    )
    assert s.control_system == "opspace_motion"
    with pytest.raises(DecodeError) as err:  # opspace_motion is built in: not with an external controller
        run.settings_from_form(
            2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], run.CONTROL_LABEL["opspace_motion"], base
        )
    assert err.value.field == "control_system"
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(2.0, 0.002, 0.0, "real time", 1.0, 50.0, [], "fuzzy control")
    assert err.value.field == "control_system"
    # what the service had and the page did not offer (issue 32): collisions, the external controller
    form = dict(stop_time=2.0, output_interval=0.002, step=0.0, pacing_label="real time", factor=1.0)
    s = run.settings_from_form(
        **form,
        live_rate=50.0,
        live_vars=[],
        collisions_label="simulate the contact",
        controller_label="external (on hil/actuators)",
        external_joints="joint1, joint3",
        control_period=0.002,
        hil_timeout=3.0,
    )
    assert (s.collisions, s.controller, s.external_joints) == ("simulate", "external", ["joint1", "joint3"])
    assert (s.control_period, s.hil_timeout) == (0.002, 3.0)
    with pytest.raises(DecodeError) as err:
        run.settings_from_form(**form, live_rate=50.0, live_vars=[], control_period=1.0)
    assert err.value.field == "control_period"


def test_errors_read_as_sentences() -> None:
    e = RemoteError(
        m.Error("bad_request", "values.link2.mass: 9999 kg is outside [0, 500] kg", "values.link2.mass")
    )
    assert describe_error(e) == "9999 kg is outside [0, 500] kg (values.link2.mass)"
    assert describe_error(RemoteError(m.Error("conflict", "a run is running"))) == "a run is running"
    text = describe_error(NoReply("no node answered simecs/library within 10.0 s"))
    assert text == "no simecs node answered: is the service running? (simecs/library)"
    assert describe_error(path.PathError("the path is empty")) == "the path is empty"


def test_user_names_and_model_summaries() -> None:
    assert identity.valid_user(" ada ") == "ada"
    with pytest.raises(ValueError):
        identity.valid_user("no spaces")
    assert identity.valid_user(identity.new_user_name())
    text = library.model_markdown(arm().summary_entry())
    assert "3 joints" in text and "joint path" in text
    entry = m.SessionEntry("abcdefghijklmnopqrstuv", "arm3", "finished")
    assert library.session_label(entry) == "arm3 · finished · abcdefgh"


def test_bench_reads_the_viewer_latency_from_its_log() -> None:
    log = "x\n2026 INFO viewer tab 0: first live frame of r1 drawn 129 ms after the click\n"
    assert viewer_latency(log) == pytest.approx(0.129)
    assert viewer_latency("nothing") is None


def test_spider_appearance_parameters_reshape_its_shapes() -> None:
    """Every appearance parameter of the real Spider description reshapes what the viewer draws."""
    from simecs.models import get_model  # the description as the proxy sends it; the viewer gets it as data

    desc = get_model("spider").describe()
    defaults = desc.default_values()
    changed = dict(defaults)
    changed.update(
        {"payload.size": 2 * defaults["payload.size"], "link7.radius": 1.5 * defaults["link7.radius"]}
    )
    changed["link7.length"] = defaults["link7.length"] + 0.1
    before = [shapes.effective_shape(s, desc, defaults, defaults) for s in desc.shapes]
    after = [shapes.effective_shape(s, desc, changed, defaults) for s in desc.shapes]
    payload = next(i for i, s in enumerate(desc.shapes) if s.kind == "box" and s.link == 6)
    assert after[payload].width == pytest.approx(2 * before[payload].width)
    assert after[payload].origin[0] == pytest.approx(before[payload].origin[0] + 0.1)
    tube = next(i for i, s in enumerate(desc.shapes) if s.resizable and s.link == 6)
    assert after[tube].radius == pytest.approx(1.5 * before[tube].radius)
    assert after[tube].length == pytest.approx(before[tube].length + 0.1)
    appearance = {p.name for p in desc.parameters if p.appearance}
    tied = {v for s in desc.shapes for v in s.scales_with.values()} | {lk.length_param for lk in desc.links}
    assert appearance == tied
    assert shapes.appearance_parameters(desc) == appearance | {lk.length_param for lk in desc.links}


def test_status_line_shows_warnings() -> None:
    st = m.SessionState(session="s", phase="finished", run_id="r1", warnings=["recorder: gaps"])
    assert "⚠ recorder: gaps" in run.status_detail(st)


# -- the session controller, driven by injected messages ------------------------------------------------
def test_controller_starts_with_the_library_then_attaches_a_new_session() -> None:
    ctl, mesh, got = controller()
    ctl.start(remembered_session="", remembered_user="")
    ctl.drain()
    assert got.of(events.UserChanged)[0].user == "tester"  # the viewer's --user for a new browser
    listed = got.of(events.LibraryListed)[-1]
    assert [s.id for s in listed.models] == ["arm3"] and not listed.can_dismiss and listed.current == ""
    ctl.opening.load_model("arm3")
    ctl.drain()
    sc = mesh.sessions[ctl.session.id]
    assert got.of(events.SessionRemembered)[-1].session == sc.id
    assert got.of(events.ModelLoaded)[-1].model.id == "arm3" and got.of(events.LibraryClosed)
    assert set(sc.watched) == {"on_state", "on_params", "on_obstacles", "on_command", "on_layout", "on_live"}
    assert ctl.values == arm().default_values() and ctl.streamed == {v.name for v in arm().variables}
    assert got.of(events.ParamSetsChanged)[-1].names == ["light"]
    assert got.of(events.StateShown)[-1].state.phase == "created"


def test_on_a_secured_mesh_a_tab_logs_in_first_and_acts_as_its_user_only() -> None:
    mesh = FakeMesh(arm())
    host = FakeHost(mesh, passwords={"ann": "ann-password", "bob": "bob-password"})
    kept = mesh.create_session("ann", "arm3")  # from an earlier visit of this browser
    ctl = session.SessionController(host, tab_id=3, sync_delay_s=0.05, loop=TabLoop("t", driven=True))
    got = Recorder()
    ctl.subscribe(got)
    ctl.start(remembered_session=kept.id, remembered_user="ann")
    ctl.drain()
    listed = got.of(events.LibraryListed)[-1]
    assert listed.login and listed.sessions == [] and ctl.session is None  # nothing before the password
    ctl.opening.load_model("arm3")
    ctl.drain()
    assert "log in first" in got.of(events.Notice)[-1].body and ctl.session is None
    ctl.login("not-her-password")
    ctl.drain()
    assert "did not let ann in" in got.of(events.Notice)[-1].body and host.logins == []
    ctl.login("ann-password")
    ctl.drain()
    assert [c.user for c in host.logins] == ["ann"]
    assert ctl.session is not None and ctl.session.id == kept.id  # the remembered session, reopened
    ctl.opening.load_model("arm3")
    ctl.drain()
    assert mesh.sessions[ctl.session.id].snap.user == "ann"
    # Another name logs ann out: her client is closed, nothing is asked as her any more.
    ctl.opening.set_user("bob")
    ctl.drain()
    assert host.logins[0].closed and not ctl.identity.logged_in
    ctl.opening.open_library()
    ctl.drain()
    assert got.of(events.LibraryListed)[-1].login and got.of(events.LibraryListed)[-1].sessions == []
    ctl.close()


def test_controller_reopens_the_remembered_session_and_forgets_a_vanished_one() -> None:
    ctl, mesh, got = controller()
    sc = mesh.create_session("ada", "arm3")
    sc.snap.values["link2.length"] = 0.9
    ctl.start(remembered_session=sc.id, remembered_user="ada")
    ctl.drain()
    assert ctl.user == "ada" and not got.of(events.UserChanged)
    assert ctl.session is not None and ctl.session.id == sc.id and ctl.values["link2.length"] == 0.9
    other, mesh2, got2 = controller()
    other.start(remembered_session=keys.new_session_id(), remembered_user="ada")
    other.drain()
    assert got2.of(events.SessionRemembered)[-1].session == ""
    assert got2.of(events.Notice)[-1].title == "Previous session ended" and got2.of(events.LibraryListed)


def test_a_remembered_session_is_asked_again_when_the_server_does_not_answer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(session, "REOPEN_PAUSE_S", 0.0)
    ctl, mesh, got = controller()
    sc = mesh.create_session("ada", "arm3")
    sc.unanswered = session.REOPEN_TRIES - 1  # a viewer restarted before the mesh had its routes
    ctl.start(remembered_session=sc.id, remembered_user="ada")
    ctl.drain()
    assert ctl.session is not None and ctl.session.id == sc.id and not got.of(events.Notice)

    other, mesh2, got2 = controller()
    gone = mesh2.create_session("ada", "arm3")
    gone.unanswered = session.REOPEN_TRIES  # the server stays silent: the user is told, and
    other.start(remembered_session=gone.id, remembered_user="ada")
    other.drain()
    assert other.session is None and got2.of(events.Notice)[-1].title == "Cannot open the session"
    assert got2.of(events.LibraryListed)  # they can pick a model or a session,
    assert not got2.of(events.SessionRemembered)  # and the tab still remembers its session
    other.opening.open_session(gone.id)  # which opens once the server answers
    other.drain()
    assert other.session is not None and other.session.id == gone.id


def test_one_tab_per_session() -> None:
    ctl, sc, got = attached()
    second = session.SessionController(ctl.host, tab_id=4, loop=TabLoop("t2", driven=True))
    seen = Recorder()
    second.subscribe(seen)
    second.start()  # the same browser: the same user
    second.drain()
    second.opening.open_session(sc.id)
    second.drain()
    assert second.session is None and seen.of(events.Notice)[-1].title == "Session already open"
    ctl.close()  # the first tab went away: the session is free
    second.opening.open_session(sc.id)
    second.drain()
    assert second.session is not None and second.session.id == sc.id


def test_a_state_update_reaches_the_toolbar_listener() -> None:
    ctl, sc, got = attached()
    st = state(sc, "running", progress=0.5, sim_time=0.5, rtf=1.0)
    sc.watched["on_state"](st)
    shown = got.of(events.StateShown)[-1]
    assert shown.state is st and shown.replay == "" and ctl.phase == "running"
    sc.watched["on_state"](state(sc, "running", seq=3))  # an older publication arriving late
    assert ctl.state is st
    sc.watched["on_state"](m.SessionState(session=keys.new_session_id(), phase="failed"))  # not ours
    assert ctl.state is st


def test_a_finished_run_is_told_once_and_the_runs_are_listed_from_the_proxy() -> None:
    ctl, sc, got = attached()
    sc.run_list = [
        m.RunInfo("r1", "finished", 1.0, 1.0, samples=501),
        m.RunInfo("r2", "running", 1.0, 0.2, recording="rec_r1"),
    ]
    sc.watched["on_state"](state(sc, "finished", sim_time=1.0, rtf=2.0))
    sc.watched["on_state"](state(sc, "finished", seq=11, sim_time=1.0, rtf=2.0))
    ctl.drain()
    assert [n.title for n in got.of(events.Notice)].count("Run r1 finished") == 1
    listed = got.of(events.RunsChanged)[-1]
    assert [r.run_id for r in listed.runs] == ["r1", "r2"] and listed.newest == "r2"
    assert ctl.replay_of("r2") == "rec_r1" and ctl.replay_of("r1") == ""


@pytest.mark.parametrize(
    ("phase", "op"),
    [
        ("finished", "pause"),
        ("finished", "resume"),
        ("created", "abort"),
        ("running", "run"),
        ("paused", "pause"),
    ],
)
def test_run_buttons_are_refused_locally_with_the_phase_table(phase: str, op: str) -> None:
    ctl, sc, got = attached()
    sc.watched["on_state"](state(sc, phase))
    sent = len(sc.sent)
    ctl.control.run_action(op)
    ctl.drain()
    note = got.of(events.Notice)[-1]
    assert note.body == session_commands.refusal(op, phase) and note.kind == "warning"
    assert len(sc.sent) == sent


def test_run_sends_the_pending_path_first_and_pause_resume_abort_go_through() -> None:
    ctl, sc, got = attached()
    ctl.control.run_action("run")
    ctl.drain()
    assert "joint path is empty" in got.of(events.Notice)[-1].body and not sc.of(m.Run)
    ctl.path.teach([0.1, 0.2, 0.3])
    ctl.edits.command_changed()
    ctl.control.run_action("run")  # before the edit pause: the path goes first anyway
    ctl.drain()
    assert [type(c) for c in sc.sent[-2:]] == [m.SetCommand, m.Run]
    assert sc.of(m.SetCommand)[-1].command.nodes[0].q == [0.1, 0.2, 0.3]
    assert got.of(events.Notice)[-1].body == "Run **r1** assigned."
    # typed but not applied parameter values: the run would not take them, so it does not start
    ctl.pending_params = lambda: ["link2.mass"]
    sc.watched["on_state"](state(sc, "finished", seq=10))
    sent = len(sc.sent)
    ctl.control.run_action("run")
    ctl.drain()
    assert len(sc.sent) == sent and "not applied yet (link2.mass)" in got.of(events.Notice)[-1].body
    ctl.pending_params = lambda: []
    sc.watched["on_state"](state(sc, "running", seq=10))
    sc.watched["on_state"](state(sc, "running"))
    ctl.control.run_action("pause")
    sc.watched["on_state"](state(sc, "paused", seq=11))
    ctl.control.run_action("resume")
    sc.watched["on_state"](state(sc, "running", seq=12))
    ctl.control.run_action("abort")
    ctl.drain()
    assert [type(c) for c in sc.sent[-3:]] == [m.Pause, m.Resume, m.Abort]


def test_an_edit_burst_sends_one_request_after_the_pause() -> None:
    ctl, sc, got = attached()
    for k in range(20):  # a slider dragged: an event per move
        ctl.edits.set_initial([0.01 * k, 0.0, 0.0])
    assert len(got.of(events.PosePreview)) == 20 and ctl.shown_q == [0.19, 0.0, 0.0]
    ctl.tick()  # the user has not paused yet
    ctl.drain()
    assert not sc.of(m.SetInitial)
    ctl.tick(time.monotonic() + 1.0)
    ctl.tick(time.monotonic() + 2.0)
    ctl.drain()
    assert [c.joints for c in sc.of(m.SetInitial)] == [[0.19, 0.0, 0.0]]
    ctl.edits.set_streamed({"joint1.qd"}, plotted=set())
    ctl.tick(time.monotonic() + 1.0)
    ctl.drain()
    live = sc.of(m.SetSettings)[-1].settings.live_vars
    assert live == ["joint1.q", "joint1.qd", "joint2.q", "joint3.q"]  # joint positions always streamed


def test_a_refused_parameter_comes_back_to_the_server_value() -> None:
    ctl, sc, got = attached()
    sc.refuse[m.SetParams] = RemoteError(
        m.Error("bad_request", "values.link2.mass: 9999 kg is outside [0, 100] kg", "values.link2.mass")
    )
    ctl.edits.set_param("link2.mass", 9999.0)
    ctl.drain()
    assert got.of(events.ValuesChanged)[-1].values["link2.mass"] == 4.0
    note = got.of(events.Notice)[-1]
    assert note.title == "link2.mass not changed" and "outside [0, 100] kg (values.link2.mass)" in note.body
    # an appearance parameter reshapes the arm at once, and back when refused
    ctl.edits.set_param("link2.length", 2.5)
    ctl.drain()
    assert [e.values["link2.length"] for e in got.of(events.ShapesChanged)][-2:] == [2.5, 0.5]
    # accepted: the server's values are shown
    del sc.refuse[m.SetParams]
    ctl.edits.set_param("link2.length", 0.75)
    ctl.drain()
    assert (
        ctl.values["link2.length"] == 0.75 and got.of(events.ShapesChanged)[-1].values["link2.length"] == 0.75
    )
    # while a run is under way the edit is refused here, with the phase table's reason
    sc.watched["on_state"](state(sc, "running"))
    sent = len(sc.sent)
    ctl.edits.set_param("link2.mass", 5.0)
    ctl.drain()
    assert len(sc.sent) == sent and got.of(events.Notice)[-1].body == session_commands.refusal(
        "set_params", "running"
    )
    sc.watched["on_params"](m.ParamValues(sc.id, "arm3", {**ctl.values, "link2.mass": 7.0}))
    assert got.of(events.ValuesChanged)[-1].values["link2.mass"] == 7.0


def test_live_frames_pose_the_arm_and_teach_knows_the_pose() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    lay = layout(sc, model, "r1")
    sc.watched["on_layout"](lay)
    assert got.of(events.LayoutChanged)[-1].layout is lay
    sc.watched["on_live"](live_frame(lay, model, [0.3, -0.2, 0.1]))
    sample = got.of(events.LiveSamples)[-1]
    assert sample.poses is not None and sample.poses.shape == (3, 7)
    assert np.allclose(sample.poses, link_poses(model, model.default_values(), [0.3, -0.2, 0.1])[:3])
    assert ctl.shown_q == pytest.approx([0.3, -0.2, 0.1]) and ctl.stream.live.has("joint1.q")
    old = frames.Frame(7, 0, 0, live_frame(lay, model, [0.0] * 3).rows)  # another run: dropped
    sc.watched["on_live"](old)
    assert len(got.of(events.LiveSamples)) == 1
    ctl.path.teach(ctl.shown_q)
    assert ctl.path.nodes[0].q == pytest.approx([0.3, -0.2, 0.1])


def test_skipped_live_frames_are_counted_and_said_once_per_run() -> None:
    """The hub drops live frames for a tab that cannot keep up: the tab says so once, and counts them."""
    model = arm()
    ctl, sc, got = attached(model)
    lay = layout(sc, model, "r1")
    sc.watched["on_layout"](lay)
    rows = live_frame(lay, model, [0.1, 0.1, 0.1]).rows
    for seq in (0, 1, 4, 5, 9):  # 2, 3, 6, 7, 8 never came
        sc.watched["on_live"](frames.Frame(lay.run_index, seq, 0, rows))
    assert ctl.stream.missed == 5 and len(got.of(events.LiveSamples)) == 5
    said = [n for n in got.of(events.Notice) if n.title == "Live view behind"]
    assert len(said) == 1 and said[0].kind == "warning"
    sc.watched["on_layout"](layout(sc, model, "r2"))  # a new run counts afresh
    assert ctl.stream.missed == 0


def test_a_replay_is_a_run_of_the_session_shaped_by_the_recorded_values() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    sc.run_list = [m.RunInfo("r1", "finished", 1.0, 1.0, samples=501)]
    ctl.refresh_runs()
    ctl.control.replay_run("r1")
    ctl.drain()
    recording = keys.recording_name(sc.id, "r1")
    assert sc.of(m.Replay)[-1].recording == recording and ctl.session.id == sc.id  # no other session
    sc.watched["on_state"](state(sc, "queued", "r2"))
    lay = layout(sc, model, "r2", recording, **{"link2.length": 1.0})
    sc.watched["on_layout"](lay)
    assert ctl.replaying is lay
    assert got.of(events.ShapesChanged)[-1].values["link2.length"] == 1.0
    assert ctl.values["link2.length"] == 0.5  # the session's own values are untouched
    sc.watched["on_state"](state(sc, "running", "r2", seq=11))
    shown = got.of(events.StateShown)[-1]
    assert shown.replay == recording and f"replay r2 of `{recording}`" in run.status_text(
        shown.state, shown.replay
    )
    sc.watched["on_live"](live_frame(lay, model, [0.2, 0.2, 0.2]))
    assert np.allclose(  # the poses of the recorded arm
        got.of(events.LiveSamples)[-1].poses, link_poses(model, lay.context.values, [0.2] * 3)[:3]
    )
    ctl.control.run_action("pause")  # the buttons act on the replay as on any run
    ctl.drain()
    assert isinstance(sc.sent[-1], m.Pause)
    sc.watched["on_state"](state(sc, "finished", "r2", seq=12, sim_time=1.0))
    ctl.drain()
    assert got.of(events.Notice)[-1].title == f"Replay r2 of {recording} finished"
    # replaying a replay run replays its recording (replays are not recorded again)
    ctl.control.replay_run("r2")
    ctl.drain()
    assert sc.of(m.Replay)[-1].recording == recording
    # the user's own configuration again: the session's values shape the arm
    ctl.preview([0.0, 0.0, 0.0])
    assert ctl.replaying is None and got.of(events.ShapesChanged)[-1].values["link2.length"] == 0.5


def test_a_run_that_failed_part_way_is_offered_to_continue_and_the_server_says_why_not() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    sc.watched["on_state"](state(sc, "running", "r1", seq=11))
    crashed = "the simulator process of run r1 disappeared (crashed or killed)"
    sc.watched["on_state"](state(sc, "failed", "r1", seq=12, sim_time=0.4, reason=crashed))
    ctl.drain()
    said = got.of(events.Notice)[-1]
    assert said.title == "Run r1 failed" and crashed in said.body and "**Continue** (Results)" in said.body
    sc.counter = 1  # r1 is the server's last run
    ctl.control.continue_run("r1")
    ctl.drain()
    assert sc.of(m.Continue)[-1].run_id == "r1"
    assert "Run **r2** goes on from where **r1** ended" in got.of(events.Notice)[-1].body
    why = "run r1 cannot be continued: it was jogged for 0.20 s, and jogs are not run again"
    sc.refuse[m.Continue] = RemoteError(m.Error("conflict", why, "run_id"))
    ctl.control.continue_run("r1")
    ctl.drain()
    refused = got.of(events.Notice)[-1]
    assert refused.title == "Continue refused" and why in refused.body


def test_a_replay_already_over_when_the_tab_attaches_does_not_reshape_the_arm() -> None:
    model = arm()
    ctl, sc, got = attached(model)
    sc.watched["on_state"](state(sc, "finished", "r2"))
    sc.watched["on_layout"](layout(sc, model, "r2", "rec_r1", **{"link2.length": 1.0}))
    assert ctl.replaying is None and got.of(events.StateShown)[-1].replay == "rec_r1"


def test_an_upload_replays_here_or_in_a_new_session_on_its_model() -> None:
    model = arm()
    other = msgspec.structs.replace(arm(), id="arm3b", name="Other arm")
    ctl, sc, got = attached(model, other)
    mesh = ctl.host.mc
    ctl.results.upload("/home/ada/kept run.mcap", b"MCAP")
    ctl.drain()
    assert mesh.uploaded == ["kept_run"] and sc.of(m.Replay)[-1].recording == "kept_run"
    mesh.upload_model = "arm3b"
    ctl.results.upload("other.mcap", b"MCAP")
    ctl.drain()
    assert ctl.session.id != sc.id and ctl.model.id == "arm3b"
    assert mesh.sessions[ctl.session.id].of(m.Replay)[-1].recording == "other"
    assert len(sc.of(m.Replay)) == 1


def test_full_resolution_overlay_and_downloads() -> None:
    ctl, sc, got = attached()
    sc.run_list = [m.RunInfo("r1", "finished", 1.0, 1.0, 11), m.RunInfo("r2", "finished", 1.0, 1.0, 11)]
    ctl.refresh_runs()
    ctx = m.RunContext("tester", {"joint1.ctrl.kp_pos": 20.0}, [0.0, 0.0, 0.0], None, m.RunSettings())
    sc.contexts["r1"] = ctx
    ctl.results.load_full(5, ["joint1.q"], None, None, run_id="", compare=["r1", "r2"])
    ctl.drain()
    loaded = got.of(events.TransientLoaded)[-1]
    assert loaded.plot == 5 and loaded.full.run_id == "r2" and [o.run_id for o in loaded.others] == ["r1"]
    assert loaded.others[0].context == ctx and loaded.full.context is None
    assert np.allclose(loaded.full.ys["joint1.q"], np.linspace(0, 1, 11))
    ctl.results.load_compared(5, ["joint1.q", "joint2.q"], ["r1"], 0.2, 0.4)
    ctl.drain()
    compared = got.of(events.ComparedLoaded)[-1]
    assert compared.plot == 5 and set(compared.others[0].ys) == {"joint1.q", "joint2.q"}
    assert compared.others[0].t0 == 0.2 and sc.asked[-1] == ("r1", ["joint1.q", "joint2.q"])
    ctl.results.load_compared(5, ["joint1.q"], ["r9"])
    ctl.drain()
    assert "r9 is no longer kept" in got.of(events.Notice)[-1].body
    ctl.results.load_track("r1")
    ctl.drain()
    track = got.of(events.TrackLoaded)[-1].track
    assert track.run_id == "r1" and track.context == ctx and track.poses.shape == (11, 3, 7)
    assert sc.asked[-1] == ("r1", compare.track_columns(ctl.model))
    sc.watched["on_state"](state(sc, "running", "r3"))
    sc.run_list.append(m.RunInfo("r3", "running", 1.0, 0.3))
    ctl.refresh_runs()
    ctl.results.load_full(5, ["joint1.q"])
    ctl.drain()
    assert "still going on" in got.of(events.Notice)[-1].body
    ctl.results.load_track("r3")
    ctl.drain()
    assert "r3 is still going on: compare it once it ends" in got.of(events.Notice)[-1].body
    ctl.results.download_csv("r1", ["joint1.q"])
    ctl.results.download_mcap("r1")
    ctl.drain()
    csv, mcap = got.of(events.Download)[-2:]
    assert csv.filename.endswith("_r1.csv") and b"# run: r1" in csv.data
    assert b"time,joint1.q\ns,rad\n" in csv.data
    assert mcap.filename == f"{keys.recording_name(sc.id, 'r1')}.mcap" and mcap.data.startswith(b"\x89MCAP")


def test_undo_puts_back_what_the_last_change_of_values_replaced() -> None:
    ctl, sc, got = attached()
    name, other = ctl.model.parameters[0].name, ctl.model.parameters[1].name
    old, old_other = ctl.values[name], ctl.values[other]
    assert ctl.edits.undo_what() == ""
    ctl.edits.set_params({name: old * 2})
    ctl.drain()
    assert got.of(events.UndoChanged)[-1].what == f"{name} back to {old:g}"
    ctl.edits.set_params({name: old * 3, other: old_other * 0.9})
    ctl.drain()
    assert ctl.edits.undo_what() == "2 parameters back to their values before the last change"
    ctl.edits.undo_params()
    ctl.drain()
    assert sc.of(m.SetParams)[-1].values == {name: old * 2, other: old_other}
    assert ctl.values[name] == old * 2 and got.of(events.Notice)[-1].title == "Undone"
    ctl.edits.undo_params()
    ctl.drain()
    assert ctl.values[name] == old and ctl.edits.undo_what() == ""
    assert got.of(events.UndoChanged)[-1].what == ""
    ctl.edits.undo_params()  # nothing left: said, nothing sent
    ctl.drain()
    assert "no change of parameter values to undo" in got.of(events.Notice)[-1].body
    assert len(sc.of(m.SetParams)) == 4
    ctl.edits.set_params({name: old * 2})
    ctl.drain()
    ctl.opening.load_model(ctl.model.id)  # another session: the last one's changes are not undone here
    ctl.drain()
    assert ctl.session.id != sc.id and ctl.edits.undo_what() == ""


def test_documentation_pages_not_carried_are_fetched_off_thread() -> None:
    ctl, sc, got = attached()
    ctl.fetch_doc("arm.motor")
    ctl.drain()
    page = got.of(events.DocFetched)[-1].page
    assert page.id == "arm.motor" and page.title == "Missing page"
    assert got.of(events.Notice)[-1].title == "Documentation"


# -- the tab: controller events on real panels --------------------------------------------------------
class FakeClient:
    """A viser client without a browser: the server's gui and scene, notifications and downloads kept."""

    def __init__(self, server: Any) -> None:
        self.client_id = 7
        self.server = server
        self.gui = server.gui
        self.scene = server.scene
        self.camera = SimpleNamespace(position=None, look_at=None)
        self.notes: list[tuple[str, str]] = []
        self.downloads: list[str] = []
        self.stored: dict[str, str] = {}
        self.local_storage = SimpleNamespace(set_item=self.stored.__setitem__)
        self._websock_connection = SimpleNamespace(queue_message=lambda message: None)

    def atomic(self) -> Any:
        return self.server.atomic()

    def add_notification(self, title: str, body: str, **_kw: Any) -> None:
        self.notes.append((title, body))

    def send_file_download(self, name: str, data: bytes, save_immediately: bool = True) -> None:
        self.downloads.append(name)


def started_tab(server: Any, model: ModelDescription) -> tuple[Tab, FakeClient, FakeMesh]:
    """A tab on a fake mesh offering `model`, started (its models window open)."""
    mesh = FakeMesh(model)
    client = FakeClient(server)
    tab = Tab(FakeHost(mesh), client, TabLoop("tab", driven=True))
    tab.build_frame()
    tab.controller.start()
    tab.controller.drain()
    return tab, client, mesh


def loaded_tab(server: Any, model: ModelDescription) -> tuple[Tab, FakeClient, Any, FakeSession]:
    """A started tab that loaded `model`: the tab, its client, its page and the fake session behind it."""
    tab, client, mesh = started_tab(server, model)
    ctl = tab.controller
    ctl.opening.load_model(model.id)
    ctl.drain()
    assert tab.page is not None and ctl.session is not None
    return tab, client, tab.page, mesh.sessions[ctl.session.id]


def test_the_tab_applies_controller_events_to_its_panels(server: Any) -> None:
    model = arm()
    tab, client, mesh = started_tab(server, model)
    ctl = tab.controller
    assert tab.library is not None and client.stored["simecs.user"] == "tester"
    ctl.opening.load_model("arm3")
    ctl.drain()
    page = tab.page
    assert page is not None and tab.library is None
    sc = mesh.sessions[ctl.session.id]
    try:
        # the toolbar follows the state; the pendant locks while a run goes on
        sc.watched["on_state"](state(sc, "running", progress=0.5, sim_time=0.5, rtf=1.0))
        assert tab.run_bar.status.content.startswith("**running** run r1")
        assert "Pause or Abort" in tab.run_bar.status.content and page.commands.pendant.locked
        assert "keys: Space pauses, Esc aborts" in tab.run_bar.status.content  # the keys said in the page
        # a replay run: the status names the recording, the arm takes the recorded link length
        sc.watched["on_state"](state(sc, "queued", "r2", seq=11))
        lay = layout(sc, model, "r2", "rec_r1", **{"link2.length": 1.0})
        sc.watched["on_layout"](lay)
        sc.watched["on_state"](state(sc, "running", "r2", seq=12))
        assert "replay r2 of `rec_r1`" in tab.run_bar.status.content
        assert page.scene.solids[2][0].scale[2] == pytest.approx(1.0)
        sc.watched["on_live"](live_frame(lay, model, [0.4, 0.1, -0.2]))
        expected = link_poses(model, lay.context.values, [0.4, 0.1, -0.2])
        assert np.allclose(page.scene.frames[2].position, expected[2, :3])
        sc.watched["on_state"](state(sc, "finished", "r2", seq=13, sim_time=1.0))
        assert not page.commands.pendant.locked
        # the user's own pose: the session's shapes come back
        ctl.preview([0.0, 0.0, 0.0])
        assert page.scene.solids[2][0].scale[2] == pytest.approx(0.5)
        # a plot of a streamed variable shows the live window; Full resolution loads the run
        sc.run_list = [m.RunInfo("r2", "finished", 1.0, 1.0, 11, recording="rec_r1")]
        ctl.refresh_runs()
        page.open_plot("joint1.q")
        ctl.drain()
        plot = page.plots.get(1)
        assert plot is not None and plot.full is None
        plot._transient(Event(SimpleNamespace(value="Full resolution")))
        ctl.drain()
        assert plot.full is not None and plot.full.run_id == "r2" and "r2 full res" in plot.folder.label
        page._results_action("CSV", "r2")
        ctl.drain()
        assert client.downloads[-1].endswith("_r2.csv")
        assert any(title == "Replay r2 of rec_r1 finished" for title, _ in client.notes)
        tab.tick()
    finally:
        tab.close()
        page.remove()


def test_recordings_are_listed_and_compared_without_replaying_them() -> None:
    ctl, sc, got = attached()
    mesh = ctl.host.mc
    sc.run_list = [m.RunInfo("r1", "finished", 1.0, 1.0, 11)]
    ctl.refresh_runs()
    ctx = m.RunContext("tester", {"joint1.ctrl.kp_pos": 7.0}, [0.0, 0.0, 0.0], None, m.RunSettings())
    mesh.recorded_context = ctx
    mesh.kept = [
        m.RecordingInfo("old_r4", "sOld", "r4", "arm3", 2000, stop_time=2.0),
        m.RecordingInfo("puma_r1", "sP", "r1", "puma560", 3000, stop_time=1.0),
    ]
    ctl.results.list_recordings()
    ctl.drain()
    assert [r.name for r in got.of(events.RecordingsListed)[-1].recordings] == ["old_r4"]  # this model's
    old = compare.recording_key("old_r4")
    assert compare.recording_of_key(old) == "old_r4" and compare.recording_of_key("r1") == ""
    # compared beside a run: read on the server (not replayed), each to its own end, with its context
    ctl.results.load_full(5, ["joint1.q"], None, None, run_id="r1", compare=[old])
    ctl.drain()
    loaded = got.of(events.TransientLoaded)[-1]
    (other,) = loaded.others
    assert other.run_id == old and other.context == ctx and other.t[-1] == 2.0
    assert mesh.read[-1] == ("old_r4", ["joint1.q"]) and not sc.of(m.Replay)
    ctl.results.load_track(old)
    ctl.drain()
    track = got.of(events.TrackLoaded)[-1].track
    assert track.run_id == old and track.end == 2.0 and track.poses.shape == (21, 3, 7)
    # a recording deleted meanwhile, or no recorder: said, not silent
    ctl.results.load_compared(5, ["joint1.q"], [compare.recording_key("gone")])
    ctl.drain()
    assert "no recording 'gone'" in got.of(events.Notice)[-1].body
    mesh.no_recorder = True
    ctl.results.list_recordings()
    ctl.drain()
    assert got.of(events.RecordingsListed)[-1].available is False


def test_runs_compared_on_every_plot_with_a_time_cursor_that_poses_the_arm(server: Any) -> None:
    model = arm()
    tab, client, page, sc = loaded_tab(server, model)
    ctl = tab.controller
    try:
        ctl.drain()  # a fresh session has no run yet: its recordings are listed all the same
        assert "None yet" in page.compare.recordings_note.content
        base = m.RunContext("tester", model.default_values(), [0.0, 0.0, 0.0], None, m.RunSettings())
        kp = model.parameters[0].name
        sc.contexts = {
            "r1": base,
            "r2": msgspec.structs.replace(base, values={**base.values, kp: 1.5}),
            "r3": base,
        }
        sc.run_list = [m.RunInfo(r, "finished", 1.0, 1.0, 11) for r in ("r1", "r2")]
        sc.run_list.append(m.RunInfo("r3", "running", 1.0, 0.2))
        ctl.refresh_runs()
        ctl.drain()
        cmp = page.compare
        assert list(cmp.boxes) == ["r1", "r2"] and page.results.selected() == "r3"  # a run going on: no box
        sc.run_list[-1] = m.RunInfo("r3", "aborted", 1.0, 0.4, 5)
        ctl.refresh_runs()
        ctl.drain()
        page.results.runs.value = next(o for o in page.results.runs.options if o.startswith("r2"))
        plot = page.open_plot("joint1.q")
        plot._transient(Event(SimpleNamespace(value="Full resolution")))
        ctl.drain()
        assert plot.full is not None and plot.full.run_id == "r2" and plot.others == []
        # tick r1 and r3: both drawn on the plot beside r2, and listed in how the runs differ
        for run_id in ("r1", "r3"):
            cmp.boxes[run_id].value = True
            cmp._ticked(Event(cmp.boxes[run_id]))
        ctl.drain()
        assert [o.run_id for o in plot.others] == ["r1", "r3"]
        stale = series.Transient("r1", np.linspace(0, 1, 3), {"joint1.q": np.zeros(3)})
        cmp.apply(events.ComparedLoaded(plot.number, [stale]))  # an answer to an older tick
        assert [o.run_id for o in plot.others] == ["r1", "r3"] and plot.others[0] is not stale
        plot.redraw(ctl.stream.live)
        labels = [s["label"] for s in plot.chart.series]
        assert labels[2:] == ["joint1.q (r1)", "joint1.q (r3)"]
        assert f"| {kp} |" in cmp.diff.content and "1.5" in cmp.diff.content
        # a recording of another session's run: listed, ticked, drawn beside them to its own end; the
        # recording of a run the session still keeps is not listed twice
        ctl.host.mc.kept = [
            m.RecordingInfo(keys.recording_name(sc.id, "r1"), sc.id, "r1", model.id, 100, stop_time=1.0),
            m.RecordingInfo("old_r4", "sOld", "r4", model.id, 2000, stop_time=2.0),
        ]
        ctl.results.list_recordings()
        ctl.drain()
        old = compare.recording_key("old_r4")
        assert list(cmp.recording_boxes) == [old] and "not replayed" in cmp.recordings_note.content
        cmp.recording_boxes[old].value = True
        cmp._ticked(Event(cmp.recording_boxes[old]))
        ctl.drain()
        assert [o.run_id for o in plot.others] == ["r1", "r3", old] and plot.others[-1].t[-1] == 2.0
        # a listing no recorder answered (a busy one) takes no box away, the ticked one least of all
        box = cmp.recording_boxes[old]
        ctl.host.mc.no_recorder = True
        ctl.results.list_recordings()
        ctl.drain()
        assert (
            cmp.recording_boxes == {old: box}
            and box.value
            and "No recorder answered" in cmp.recordings_note.content
        )
        ctl.host.mc.no_recorder = False
        # many recordings: the newest are offered, and a ticked one stays even when it is no longer
        many = [
            m.RecordingInfo(f"new_r{k}", "sNew", f"r{k}", model.id, 100, stop_time=1.0) for k in range(25)
        ]
        ctl.host.mc.kept = [*many, *ctl.host.mc.kept]
        ctl.results.list_recordings()
        ctl.drain()
        assert len(cmp.recording_boxes) == compare_panel.RECORDINGS_LISTED + 1 and old in cmp.recording_boxes
        assert (
            f"The {compare_panel.RECORDINGS_LISTED} newest of your 26 are listed"
            in cmp.recordings_note.content
        )
        cmp.recording_boxes[old].value = False
        cmp._ticked(Event(cmp.recording_boxes[old]))
        ctl.drain()
        assert [o.run_id for o in plot.others] == ["r1", "r3"]
        # the cursor: every plot marks it, the arm takes r2's pose there, values are read per run
        line = cmp.timeline  # one timeline, in the run bar (timeline.py)
        assert line.cursor.disabled
        line.cursor_on.value = True
        line._toggled(Event(line.cursor_on))
        assert not line.cursor.disabled and cmp.follow.options == ("r2", "r1", "r3")
        line.cursor.value = 0.5
        ctl.drain()
        assert plot.cursor == 0.5
        assert np.allclose(page.scene.frames[0].position, [0.5, 1.0, 1.5])  # the fake's pose.link1.x/y/z
        assert "| joint1.q [deg] | 28.6479 | 28.6479 | 28.6479 |" in cmp.values.content  # degrees first
        plot.redraw(ctl.stream.live)
        assert plot.chart.series[-1]["label"] == "cursor"
        page.plots.angle_choice.value = "rad"
        assert plot.angles == "rad" and "| joint1.q [rad] | 0.5 | 0.5 | 0.5 |" in cmp.values.content
        # angles in degrees, chosen once: every plot and the values read at the cursor; remembered
        page.plots.angle_choice.value = "deg"
        assert (
            plot.angles == "deg" and "| joint1.q [deg] | 28.6479 | 28.6479 | 28.6479 |" in cmp.values.content
        )
        plot.redraw(ctl.stream.live)
        assert plot.chart.series[1]["label"] == "joint1.q [deg]" and plot.chart.axes[1]["label"] == "deg"
        assert max(plot.chart.data[1]) == pytest.approx(math.degrees(1.0))
        assert page.view_state()["angles"] == "deg"
        page.plots.set_angles("grad")  # a reload's memory is the browser's: only known choices are taken
        assert page.plots.angles == "deg"
        # the timeline plays: the cursor, and with it the arm, every plot and the values, on to the end
        line.speed.value = "4×"
        line._transport("▶ Play")
        seen = set()
        end = time.monotonic() + 10.0
        while time.monotonic() < end and line.playing:
            time.sleep(0.01)
            tab.loop.run_pending()
            seen.add(round(plot.cursor or 0.0, 3))
        assert line.at == pytest.approx(float(line.cursor.max)) and plot.cursor == pytest.approx(line.at)
        assert len(seen) >= 3  # it moved on step by step, not in one jump
        line._transport("To start")
        assert line.at == 0.0
        # a variable on the X axis: remembered over a reload, drawn against it again
        other = next(v.name for v in ctl.model.variables if v.name != "joint1.q")
        plot.x_axis.value = other
        plot._x_axis_changed(Event(plot.x_axis))
        view = page.view_state()
        assert view["plots"] == [["joint1.q"]] and view["x_axes"] == [other]
        page.plots.close(plot)
        page.restore({**view, "x_axes": [other, "joint1.q"]})  # a second entry for no plot: ignored
        (again,) = page.plots.plots.values()
        assert again.x_var == other and again.x_axis.value == other and again.xy.visible
        page.plots.close(again)
        page.restore({**view, "x_axes": ["no.such"]})  # a name the model lacks: over time
        (plot,) = page.plots.plots.values()
        assert plot.x_var == "time" and plot.chart.visible
        # a new run takes the arm back: the cursor goes
        sc.watched["on_state"](state(sc, "running", "r4", seq=20))
        assert line.cursor_on.disabled and not line.on and plot.cursor is None
    finally:
        tab.close()
        page.remove()


def test_what_runs_differ_in_is_listed_and_values_at_the_cursor_read() -> None:
    model = arm()
    base = m.RunContext("u", model.default_values(), [0.0, 0.1, 0.0], None, m.RunSettings())
    same = compare.differences({"r1": base, "r2": base}, model)
    assert same == "_r1, r2 ran with the same parameters, initial pose, command and settings, none jogged._"
    name = model.parameters[0].name
    other = msgspec.structs.replace(
        base,
        values={**base.values, name: base.values[name] * 2},
        initial=[0.0, 0.2, 0.0],
        settings=m.RunSettings(stop_time=2.0),
        command=m.JointPath([m.PathNode([0.1, 0.0, 0.0])]),
    )
    table = compare.differences({"r1": base, "r2": other}, model)
    assert f"| {name} |" in table and "| initial pose [deg] | 0.0 5.7 0.0 | 0.0 11.5 0.0 |" in table
    assert "| stop time [s] |" in table and "| command | none | joint path, 1 node |" in table
    jogged = compare.differences({"r1": base, "r2": base}, model, {"r1": 0.0, "r2": 1.25})
    assert "| jogged [s] | no | 1.25 |" in jogged  # a jogged run is not said to have run the same
    info = m.RunInfo("r3", "finished", 5.0, 5.0, jogged_s=2.0, until_stopped=True)
    assert (
        results.run_label(info, other)
        == "r3 · finished · 5.00 s · joint path, 1 node · until stopped · jogged 2.0 s"
    )
    assert "older server" in compare.differences({"r1": base, "r2": None}, model)
    t = np.linspace(0.0, 1.0, 11)
    runs = {"r1": {"joint1.q": (t, t)}, "r2": {"joint1.q": (t[:6], -t[:6])}}
    text = compare.values_table(0.75, runs, ["joint1.q"], {"joint1.q": "rad"})
    assert "| joint1.q [rad] | 0.75 | — |" in text  # r2 ended at 0.5 s
    track = compare.RunTrack("r1", t, np.arange(11 * 2 * 7, dtype=float).reshape(11, 2, 7))
    assert track.at(0.24)[0, 0] == 28.0 and track.at(0.26)[0, 0] == 42.0 and track.at(9.0)[0, 0] == 140.0


@pytest.mark.parametrize(
    "changes",
    [{"link2.length": 0.9, "link4.length": 0.2}, {"link3.radius": 0.09}, {"payload.size": 0.5}],
    ids=["lengths", "radii", "payload"],
)
def test_the_browser_and_the_recordings_scene_draw_every_solid_alike(
    server: Any, changes: dict[str, float]
) -> None:
    """The 3D arm and Foxglove's /scene come from one rule: after a change of link lengths, radii or
    the payload's size, every solid sits and measures the same in both."""
    from simecs.models import get_model
    from simecs.nodes import mcapscene

    desc = get_model("spider").describe()
    values = {**desc.default_values(), **changes}
    arm_scene = scene.ArmScene(server.scene, desc, desc.default_values(), root="/t_alike")
    arm_scene.build()
    try:
        assert arm_scene.set_values(values)
        entities = {e["id"]: e for e in mcapscene.scene_update(desc, values, 1)["entities"]}
        taken: dict[tuple[str, str], int] = {}
        for solid in shapes.solids(desc, values):
            if solid.frame == shapes.WORLD or not solid.geometry.visible:
                continue
            kind = {"cylinder": "cylinders", "pipe": "cylinders", "box": "cubes", "sphere": "spheres"}
            listed = kind[solid.geometry.kind]
            k = taken.get((solid.frame, listed), 0)
            taken[(solid.frame, listed)] = k + 1
            prim = entities[solid.frame][listed][k]
            handle, drawn = arm_scene.solids[solid.index]
            pos, rot, size = prim["pose"]["position"], prim["pose"]["orientation"], prim["size"]
            assert np.allclose(handle.position, [pos["x"], pos["y"], pos["z"]])
            if drawn in ("cylinder", "pipe"):
                assert np.allclose(handle.wxyz, [rot["w"], rot["x"], rot["y"], rot["z"]])
            if drawn == "pipe":
                assert np.allclose(handle.scale, [size["x"] / 2, size["y"] / 2, size["z"]])
            elif drawn == "cylinder":
                assert (2 * handle.radius, handle.height) == pytest.approx((size["x"], size["z"]))
            elif drawn == "box":
                assert np.allclose(handle.dimensions, [size["x"], size["y"], size["z"]])
            else:
                assert 2 * handle.radius == pytest.approx(size["x"])
    finally:
        arm_scene.remove()


def test_the_path_duration_is_shown_and_a_run_cut_short_by_its_stop_time_says_so() -> None:
    ctl, sc, got = attached()
    assert ctl.path is not None
    sc.plan_duration = 2.5
    ctl.path.teach([0.1] * len(ctl.path.links))
    ctl.edits.command_changed()
    ctl.edits.flush()
    ctl.drain()
    plan = got.of(events.PlanChanged)[-1].plan
    assert plan is not None and plan.duration == 2.5 and ctl.edits.plan is plan
    assert "ends the run before the path is done (2.50 s)" in path.plan_text(plan, 1.0)
    assert path.plan_text(plan, 5.0) == "Path duration **2.50 s** (stop time 5 s)."
    # a line too fast for a joint is time-scaled by the server, not refused: the pendant says so
    steps = [m.PlanStep("nodes[0]", "lin", 0.0, 1.0), m.PlanStep("nodes[1]", "lin", 1.0, 2.5, slowed=1.23)]
    slowed = m.CommandPlan("cartesian_path", 2.5, steps, [0.0], slowed=1.23)
    assert "Slowed **×1.23** (node 2) to keep every joint within its speed" in path.plan_text(slowed, 5.0)
    sc.watched["on_state"](state(sc, "finished", sim_time=1.0, rtf=2.0))
    ctl.drain()
    told = [n for n in got.of(events.Notice) if n.title == "Run r1 finished"]
    assert len(told) == 1 and told[0].kind == "warning"
    assert "stopped before its command was done (the command takes 2.50 s)" in told[0].body
    sc.plan_duration = 0.5
    ctl.edits.command_changed()
    ctl.edits.flush()
    sc.watched["on_state"](state(sc, "finished", run_id="r2", sim_time=1.0, rtf=2.0))
    ctl.drain()
    told = [n for n in got.of(events.Notice) if n.title == "Run r2 finished"]
    assert told[0].kind == "ok" and "before its command" not in told[0].body


def test_a_held_jog_is_resent_until_let_go_and_an_idle_arm_is_jogged_in_a_run_until_stopped() -> None:
    """Issue 32: jogging as on a pendant. A hold moves the axis, the release stops it at once (and
    hold messages that stop coming do too); an idle arm gets a run until stopped, ended as finished."""
    ctl, sc, got = attached()
    ctl.path.teach([0.0, 0.0, 0.0])
    ctl.edits.command_changed()
    # idle: the first hold asks for a run until stopped (edits first), once
    assert ctl.jog.hold("joint", "joint1", 1.0) == ""
    assert ctl.jog.hold("joint", "joint1", 1.0) == ""
    ctl.drain()
    runs = sc.of(m.Run)
    assert len(runs) == 1 and runs[0].until_stopped and sc.of(m.SetCommand)
    assert not sc.jogs  # nothing is sent before the run runs
    sc.watched["on_state"](state(sc, "paused", sim_time=0.1))
    assert "Resume" in ctl.jog.hold("joint", "joint1", 1.0)
    sc.watched["on_state"](state(sc, "running", seq=11, sim_time=0.1))
    ctl.settings = m.RunSettings(pacing="fast")  # a timed run paced fast cannot be jogged...
    lay = layout(sc, ctl.model, "r1")
    sc.watched["on_layout"](lay)
    assert "wall time" in ctl.jog.hold("joint", "joint1", 1.0)
    lay.context.until_stopped = True  # ...a run until stopped always can (it runs in real time)
    ctl.jog.speed_pct = 40.0
    assert ctl.jog.hold("joint", "joint2", -1.0) == ""
    wait_until(lambda: len(sc.jogs) >= 2, timeout=2.0, what="the held jog re-sent")
    first = sc.jogs[0]
    assert first.run_id == "r1" and first.space == "joint" and first.speed_pct == 40.0
    assert first.qd[1] < 0 and all(v == 0 for k, v in enumerate(first.qd) if k != 1)
    ctl.jog.release()  # let go: a zero velocity at once
    sent = len(sc.jogs)
    assert not any(sc.jogs[-1].qd) and ctl.jog.label == ""
    time.sleep(0.3)
    assert len(sc.jogs) == sent  # nothing after the release
    # hold messages that stop coming (a release the page did not report) end the jog by themselves
    assert ctl.jog.hold("cartesian", "z", -1.0) == ""
    wait_until(lambda: len(sc.jogs) > sent, timeout=2.0, what="a Cartesian jog")
    assert sc.jogs[sent].twist[2] < 0 and sc.jogs[sent].space == "cartesian"
    wait_until(lambda: ctl.jog.active is None, timeout=2.0, what="the jog let go without hold messages")
    assert not any(sc.jogs[-1].qd)
    # Stop jogging ends the run until stopped as finished (stop, not abort)
    assert ctl.jog.finish() == ""
    ctl.drain()
    assert isinstance(sc.sent[-1], m.Stop)
    sc.watched["on_state"](state(sc, "finished", seq=12, sim_time=1.0))
    assert "no run until stopped" in ctl.jog.finish()
    ctl.close()


def test_notifications_show_plain_text_not_markdown_marks() -> None:
    assert browser.plain("Run **r1** assigned; see `joint2.q` and **both** marks.") == (
        "Run r1 assigned; see joint2.q and both marks."
    )
    assert browser.plain("2 * 3 ** 2") == "2 * 3 ** 2"


def test_an_imported_models_meshes_are_drawn_where_its_description_puts_them(server: Any) -> None:
    """Each mesh shape becomes a GLB node with the bytes the proxy would serve, at its pose on its
    link frame, and the same mesh goes into the recording's /scene, embedded; a mesh the server did not
    give leaves an empty node (the indices stay whole)."""
    import base64
    import json

    import jsonschema
    from simecs.models import get_model
    from simecs.nodes import mcapfmt, mcapscene

    pkg = get_model("ur5")
    desc = pkg.describe()
    store = pkg.mesh_store()
    meshes = {name: store.glb(name) for name in store.names()}
    assert all(data[:4] == b"glTF" for data in meshes.values())
    values = desc.default_values()
    arm_scene = scene.ArmScene(server.scene, desc, values, root="/t_meshes", meshes=meshes)
    arm_scene.build()
    try:
        drawn = {i: h for i, (h, kind) in arm_scene.solids.items() if kind == "mesh"}
        mesh_shapes = {i: s for i, s in enumerate(desc.shapes) if s.kind == "mesh"}
        assert set(drawn) == set(mesh_shapes) and len(drawn) == len(desc.links)
        for i, shape in mesh_shapes.items():
            geom = shapes.shape_geometry(shape)
            assert np.allclose(drawn[i].position, geom.position) and np.allclose(drawn[i].wxyz, geom.wxyz)
        update = mcapscene.scene_update(desc, values, 1, meshes)
        schema = json.loads(mcapfmt.foxglove_schema("foxglove.SceneUpdate"))
        jsonschema.Draft202012Validator(schema).validate(update)
        entities = {e["id"]: e for e in update["entities"]}
        for link in desc.links:
            models = entities[link.name]["models"]
            assert len(models) == 1 and models[0]["media_type"] == "model/gltf-binary"
            assert base64.b64decode(models[0]["data"])[:4] == b"glTF"
        # without the meshes: nothing drawn, nothing embedded, nothing broken
        assert not any(e["models"] for e in mcapscene.scene_update(desc, values, 1)["entities"])
    finally:
        arm_scene.remove()
    bare = scene.ArmScene(server.scene, desc, values, root="/t_bare")
    bare.build()
    try:
        assert sum(1 for _h, kind in bare.solids.values() if kind == "mesh") == len(desc.links)
    finally:
        bare.remove()


def test_a_switch_parameter_is_a_check_box_and_applies_as_0_or_1(server: Any) -> None:
    from simecs.models import get_model

    desc = get_model("spider").describe()
    sent: list[dict[str, float]] = []
    panel = params.ParamPanel(server.gui, desc, desc.default_values(), sent.append, print, print)
    drives = next(c for root in panel.roots for c in root.walk() if c.path == "drives")
    panel.show_component(drives)
    box = panel.fields["drives.enabled"]
    assert box.value is True and not hasattr(box, "step")
    box.value = False
    panel._edited(Event(box), desc.parameter("drives.enabled"))
    panel._apply()
    assert sent == [{"drives.enabled": 0.0}]
    panel.show_values({**desc.default_values(), "drives.enabled": 0.0})
    assert box.value is False and panel.drafts == {}
    panel.show_values(desc.default_values())
    assert box.value is True


# -- obstacles: the session's list, a run's grasps and contacts, the panel ---------------------------------
def grasp_layout(sc: FakeSession, model: ModelDescription) -> m.RunLayout:
    """A run's layout with the grasp's and the contacts' columns (a simulated model has them)."""
    lay = layout(sc, model)
    extra = [columns.GRASP_OBJECT, columns.GRASP_HELD]
    extra += [
        columns.contact_column(i, f) for i in (1, 2, 3) for f in ("force", "fx", "fy", "fz", "px", "py", "pz")
    ]
    lay.columns = [*lay.columns, *extra]
    lay.units = [*lay.units, *[""] * len(extra)]
    lay.live_columns = columns.live_columns(lay.columns, model.joint_position_columns())
    return lay


def test_the_page_draws_the_sessions_obstacles_and_a_runs_grasps_and_contacts(server: Any) -> None:
    from simecs.viewer.obstacles import NEW

    model = arm()
    tab, client, page, sc = loaded_tab(server, model)
    ctl = tab.controller
    try:
        # another client's set_obstacles reaches this tab: drawn, and offered in the panel
        box = m.Obstacle("box1", "box", [0.5, 0.0, 0.1], size=[0.1, 0.1, 0.1], mass=1.0)
        sc.watched["on_obstacles"](m.ObstacleValues(sc.id, [box]))
        assert ctl.obstacles == [box] and len(page.scene._obstacles) == 1
        assert tuple(page.commands.obstacles.pick.options) == ("box1", NEW)
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.5, 0.0, 0.1))
        # a run grasps box1 and pushes link2 onto something: the box moves with the rows, the force
        # shows as an arrow; the live columns carry what the scene draws even when few are chosen
        lay = grasp_layout(sc, model)
        assert columns.GRASP_OBJECT in lay.live_columns and "contact.link2.fx" in lay.live_columns
        assert "contact.link2.force" not in lay.live_columns
        sc.watched["on_layout"](lay)
        frame = live_frame(lay, model, [0.1, 0.2, 0.3])
        row = frame.rows[0]
        where = {c: i for i, c in enumerate(lay.live_columns)}
        pose = [0.2, 0.3, 0.4, 1.0, 0.0, 0.0, 0.0]
        for f, v in zip(columns.POSE_FIELDS, pose, strict=True):
            row[where[columns.pose_column(columns.GRASPED_FRAME, f)]] = v
        row[where[columns.GRASP_OBJECT]], row[where[columns.GRASP_HELD]] = 1.0, 1.0
        for f, v in zip(("fx", "fy", "fz", "px", "py", "pz"), (0.0, 0.0, 50.0, 0.1, 0.1, 0.1), strict=True):
            row[where[columns.contact_column(2, f)]] = v
        sc.watched["on_live"](frame)
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.2, 0.3, 0.4))
        assert page.scene._contacts is not None
        assert np.allclose(page.scene._arrows, [[[0.1, 0.1, 0.1], [0.1, 0.1, 0.15]]])
        # the user poses the arm again: the run's world is over, the box is back, no arrows
        ctl.preview([0.0, 0.0, 0.0])
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.5, 0.0, 0.1))
        assert page.scene._contacts is None
        sc.watched["on_live"](frame)
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.2, 0.3, 0.4))
        # the next run starts from the list: the box is back where it is listed, no arrows
        sc.watched["on_layout"](grasp_layout(sc, model))
        assert tuple(page.scene._obstacles[0].position) == pytest.approx((0.5, 0.0, 0.1))
        assert page.scene._contacts is None
        # the panel: a new sphere, applied, goes to the server with the list it joins
        panel = page.commands.obstacles
        panel.pick.value = NEW
        panel.name.value = "ball"
        panel.kind.value = "sphere"
        panel.radius.value = 0.04
        panel.position.value = (0.3, 0.3, 0.2)
        panel.apply()
        ctl.drain()
        sent = sc.of(m.SetObstacles)[-1].obstacles
        assert [ob.name for ob in sent] == ["box1", "ball"] and sent[1].radius == 0.04
        assert len(page.scene._obstacles) == 2 and tuple(panel.pick.options) == ("box1", "ball", NEW)
        # a wrong field is named and nothing is sent; a name twice neither
        panel.radius.value = -1.0
        panel.apply()
        panel.pick.value = NEW
        panel.name.value = "box1"
        panel.radius.value = 0.04
        panel.apply()
        assert len(sc.of(m.SetObstacles)) == 1
        assert client.notes[-2][1].startswith("radius:") and "box1" in client.notes[-1][1]
        # refused by the server: the list drawn comes back to the stored one
        sc.refuse[m.SetObstacles] = RemoteError(m.Error("bad_request", "no", "obstacles[0].name"))
        panel.pick.value = "ball"
        panel.remove()
        ctl.drain()
        assert [ob.name for ob in ctl.obstacles] == ["box1", "ball"] and len(page.scene._obstacles) == 2
    finally:
        tab.close()
        page.remove()


def test_a_command_another_client_set_shows_in_its_pendant_and_an_echo_changes_nothing(server: Any) -> None:
    model = msgspec.structs.replace(arm(), command_levels=["joint_path", "direct_input"])
    tab, client, page, sc = loaded_tab(server, model)
    ctl = tab.controller
    commands = page.commands
    assert commands.pendant is not None and commands.direct is not None and ctl.path is not None
    try:
        # another client's joint path: the pendant shows its nodes and the plan that came with it
        path = m.JointPath([m.PathNode([0.1, 0.2, 0.3], 50.0, 100.0), m.PathNode([0.0, 0.0, 0.0])])
        plan = m.CommandPlan("joint_path", 2.5, [], [0.0, 0.0, 0.0])
        sc.watched["on_command"](m.CommandValue(sc.id, path, plan))
        assert ctl.path.to_command() == path and ctl.command_kind == "joint_path"
        assert "| 5.7 | 11.5 | 17.2 | 50 | 100 |" in commands.pendant.table.content
        assert "Path duration **2.50 s**" in commands.pendant.duration.content
        # then a direct input: its pendant takes it, the joint path says it is not the command
        signals = m.DirectInput("closed_loop", {"joint2": m.StepSignal(0.2)}, "speed")
        preview = m.SignalPreview("rad/s", [0.0, 1.0], {"joint2": [0.2, 0.2]})
        planned = m.CommandPlan("direct_input", 1.0, [], [0.0, 0.0, 0.0], signals=preview)
        sc.watched["on_command"](m.CommandValue(sc.id, signals, planned))
        assert ctl.command_kind == "direct_input" and ctl.direct is not None
        assert ctl.direct.to_command() == signals
        assert commands.direct.mode.value == "Speed set point (closed loop)"
        assert "step 0 → 0.2 rad/s" in commands.direct.table.content
        assert "Not the session's command" in commands.pendant.duration.content
        # this tab's own send comes back while the user edits on: the newer edit stays
        ctl.path.teach([0.2, 0.2, 0.2])
        ctl.edits.command_changed()
        ctl.edits.flush()
        ctl.drain()
        sent = sc.of(m.SetCommand)[-1].command
        ctl.path.set_q([0.3, 0.3, 0.3])
        sc.watched["on_command"](m.CommandValue(sc.id, sent, plan))
        assert ctl.path.nodes[ctl.path.selected].q == [0.3, 0.3, 0.3]
        # another session's publication, and a session without a command: nothing changes
        sc.watched["on_command"](m.CommandValue("x" * 22, path, plan))
        sc.watched["on_command"](m.CommandValue(sc.id, None, None))
        assert ctl.path.nodes[ctl.path.selected].q == [0.3, 0.3, 0.3] and ctl.command_kind == "joint_path"
        assert not client.notes
    finally:
        tab.close()
        page.remove()


def test_the_digital_readout_shows_joints_and_tool_in_the_tabs_angle_unit() -> None:
    """Issue 32: the joints (in the tab's angle unit) and the tool pose, always in the run bar."""
    from simecs.viewer.readout import readout_text

    deg = readout_text(["joint1", "joint2"], [math.pi / 2, -1e-9], [0.5, 0.0, 1.25, 0.0, H, 0.0], "deg")
    assert "**joints [deg]** 1:90.0 2:0" in deg and "x 500 y 0 z 1250 · r 0 p 90.0 y 0" in deg
    rad = readout_text(["joint1"], [math.pi / 2], None, "rad")
    assert "1:1.571" in rad and "tool" not in rad
