"""What a tab holds of its session: the data its panels show and its requests are made from.

One object, owned by the tab's loop (loop.py): the panels read it there, the session controller and
its parts change it there (a worker hands its answers over with `Dispatcher.on_loop`). The parts of
the controller (edits, runs, results, opening, jog) see the tab through this and the dispatcher
only, never through the controller, so none of them imports another or reaches into one.
"""

from __future__ import annotations

from collections.abc import Callable

from simecs.mesh.client import SessionClient
from simecs.mesh.protocol import keys, session_commands
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import ModelDescription

from .cartesian import CartesianPathEditor, Pose, tool_pose
from .direct import DirectInputEditor
from .path import JointPathEditor
from .program import LEVELS, ProgramEditor
from .stream import RunStream

Editor = JointPathEditor | CartesianPathEditor | DirectInputEditor | ProgramEditor


class TabState:
    """The session shown in one tab (see the module docstring); empty until a session is attached."""

    def __init__(self) -> None:
        self.session: SessionClient | None = None
        self.model: ModelDescription | None = None
        self.meshes: dict[str, bytes] = {}  # the GLB of each mesh shape of the model (host.meshes)
        #: The parameters typed but not applied (the page's parameter panel answers it).
        self.pending_params: Callable[[], list[str]] = lambda: []
        self.values: dict[str, float] = {}
        self.initial: list[float] = []
        self.obstacles: list[m.Obstacle] = []  # what the arm can touch (the session's list)
        self.shown_q: list[float] = []  # the pose the arm shows: what Teach records
        self.path: JointPathEditor | None = None
        self.cart: CartesianPathEditor | None = None  # when the model takes Cartesian paths
        self.direct: DirectInputEditor | None = None  # when the model takes direct inputs
        self.program: ProgramEditor | None = None  # when the model takes tasks
        self.command_kind = "joint_path"  # whose path is the session's command (the last one edited)
        self.settings = m.RunSettings()
        self.streamed: set[str] = set()
        self.state: m.SessionState | None = None
        self.runs: list[m.RunInfo] = []
        self.stream: RunStream | None = None
        self.replaying: m.RunLayout | None = None  # the replay whose recorded values shape the arm
        self.recordings: dict[str, str] = {}  # run id -> the recording it replays
        self.contexts: dict[str, m.RunContext | None] = {}  # run id -> what produced it (asked once)

    @property
    def phase(self) -> str:
        return self.state.phase if self.state is not None else "created"

    def refusal(self, op: str) -> str:
        """Why command `op` would be refused now ('' when it applies): `phases.refusal`."""
        return session_commands.refusal(op, self.phase)

    def replay_of(self, run_id: str) -> str:
        """The recording run `run_id` replays ('' for a simulation)."""
        return self.recordings.get(run_id, "")

    def recording_of(self, run_id: str) -> str:
        """The recording that holds run `run_id`: the recorder's for a simulation, the replayed one
        for a replay (replays are not recorded again)."""
        assert self.session is not None
        return self.replay_of(run_id) or keys.recording_name(self.session.id, run_id)

    def until_stopped(self) -> bool:
        """The run going (or last shown) runs until stopped (its layout says so): its stop time is
        only a bound, and its progress means little."""
        st, layout = self.state, self.stream.layout if self.stream is not None else None
        return (
            st is not None
            and layout is not None
            and layout.run_id == st.run_id
            and layout.context.until_stopped
        )

    def editor(self, kind: str) -> Editor | None:
        """The pendant's command of level `kind` (None: this viewer does not edit that level)."""
        if kind in LEVELS:
            return self.program
        editors = {"joint_path": self.path, "cartesian_path": self.cart, "direct_input": self.direct}
        return editors.get(kind)

    def tool_pose(self, q: list[float]) -> Pose:
        """The tool pose at joint positions `q` with the session's values (what Teach records)."""
        assert self.model is not None
        return tool_pose(self.model, self.values, q)

    def shape_values(self) -> dict[str, float]:
        """The values the 3D arm's shapes follow: the session's, or a shown replay's recorded ones."""
        if self.replaying is None:
            return dict(self.values)
        recorded = self.replaying.context.values
        return {k: float(recorded.get(k, v)) for k, v in self.values.items()}
