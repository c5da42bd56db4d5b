"""What the viewer's logic tests drive the viewer with, without a browser or a server: small model
descriptions, a fake mesh client answering from memory (the Drake way of testing GUI logic), and the
messages a server would send (states, layouts, live frames).
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.protocol import columns, frames, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import (
    DocPage,
    InitEquation,
    Link,
    ModelDescription,
    Parameter,
    Shape,
    Variable,
)
from simecs.mesh.rules.kinematics import link_poses
from simecs.viewer import (
    session,
)
from simecs.viewer.host import Claims
from simecs.viewer.loop import TabLoop
from simecs.viewer.tab import Tab

H = math.pi / 2


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


def settle(tab: Tab) -> None:
    """Run what values assigned from code to the tab's widgets set off: viser hands their callbacks
    (coroutines, `TabLoop.wrap_widget`) to its event loop, which posts them to the tab's loop; a task
    scheduled there after them has run once they have."""
    viser_loop = tab.client.server.gui._event_loop  # type: ignore[attr-defined]
    asyncio.run_coroutine_threadsafe(asyncio.sleep(0), viser_loop).result(10)
    tab.controller.drain()


def loaded_tab(server: Any, model: ModelDescription) -> tuple[Tab, FakeClient, Any, FakeSession]:
    """A started tab that loaded `model`: the tab, its client, its page and the fake session behind it."""
    tab, client, mesh = started_tab(server, model)
    ctl = tab.controller
    ctl.opening.load_model(model.id)
    ctl.drain()
    assert tab.page is not None and ctl.session is not None
    return tab, client, tab.page, mesh.sessions[ctl.session.id]


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
