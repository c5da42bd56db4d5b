"""What the session controller tells its listeners: one small dataclass per kind of change.

The controller (`session.py`) knows nothing of viser; the tab subscribes to it and applies each
event to its panels. Tests subscribe a list and look at what arrived. Events carry the data a panel
needs; anything else a panel may read from the controller's attributes after `ModelLoaded`.
Listeners are called on the controller's worker threads and on zenoh's: they must return at once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import DocPage, ModelDescription, ModelSummary

from .compare import RunTrack
from .series import Transient


@dataclass
class Notice:
    """Something to tell the user (a notification): kind is info, ok, warning or error."""

    title: str
    body: str
    kind: str = "info"


@dataclass
class UserChanged:
    """The tab's user name changed (remember it on this browser)."""

    user: str


@dataclass
class LibraryListed:
    """The models window's content: the library, the user's sessions, the tab's own session."""

    user: str
    models: list[ModelSummary]
    sessions: list[m.SessionEntry]
    current: str
    can_dismiss: bool
    login: bool = False  # a secured mesh: the user must log in (password) before anything else


@dataclass
class LibraryClosed:
    """A session is open: the models window may go."""


@dataclass
class SessionRemembered:
    """The session this tab keeps across reloads ('' forgets it)."""

    session: str


@dataclass
class ModelLoaded:
    """A session was attached: build every panel from the model and the controller's fields (values,
    initial pose, joint path, settings, streamed variables, runs)."""

    model: ModelDescription
    session: str


@dataclass
class StateShown:
    """The session's state for the toolbar; `replay` names the recording when its run replays one."""

    state: m.SessionState | None
    replay: str = ""
    until_stopped: bool = False  # the run runs until stopped: its time counts, its progress does not


@dataclass
class ValuesChanged:
    """The session's parameter values (the server's truth, after a change or a refusal)."""

    values: dict[str, float]


@dataclass
class ParamsRefused:
    """The server refused applied edits: `field` is the parameter it names ("" when none)."""

    field: str
    reason: str


@dataclass
class ShapesChanged:
    """The values the 3D arm's shapes follow: the session's, an edit not yet confirmed, or the
    recorded values of a replay being shown."""

    values: dict[str, float]


@dataclass
class StreamedChanged:
    streamed: set[str]


@dataclass
class SettingsChanged:
    settings: m.RunSettings


@dataclass
class PlanChanged:
    """The server planned the session's command (its reply to set_command); `kind` is the pendant's
    path that was sent (joint_path, cartesian_path)."""

    plan: m.CommandPlan | None
    kind: str = "joint_path"


@dataclass
class CommandRefused:
    """The server refused the path of `kind`: `field` names the part (command.nodes[2].position)."""

    kind: str
    field: str
    reason: str


@dataclass
class RunsChanged:
    """The session's runs, oldest first (queued and running ones too); `newest` to select."""

    runs: list[m.RunInfo]
    newest: str = ""


@dataclass
class RunsDescribed:
    """What produced some of the session's runs came (TabState.contexts): the run lists say what each
    run did."""


@dataclass
class ParamSetsChanged:
    names: list[str]


@dataclass
class LayoutChanged:
    """A run announced its columns: live plots start over, loaded transients are stale."""

    layout: m.RunLayout


@dataclass
class LiveSamples:
    """Decimated samples of the shown run; `poses` (links, 7) of the newest row, when streamed; where
    the run's grasps left its obstacles (index -> pose), the newest row's contact arrows, and the
    tool's position at every row (k, 3) for its trace."""

    rows: np.ndarray
    poses: np.ndarray | None
    moved: dict[int, np.ndarray] = field(default_factory=dict)
    arrows: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    tool: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


@dataclass
class CommandReplaced:
    """Another client set the session's command: the pendant of `kind` shows it (with its plan)."""

    kind: str


@dataclass
class ObstaclesChanged:
    """The session's obstacles (the user's edit, or another client's): draw them."""

    obstacles: list[m.Obstacle]


@dataclass
class GoalShown:
    """Show the goal ghost at joint positions `q` (where the picked node or action puts the arm; the arm
    itself stays where the run starts); None hides it."""

    q: list[float] | None


@dataclass
class PosePreview:
    """Show the arm at joint positions `q` (kinematic simulation of a slider or a path node)."""

    q: list[float]


@dataclass
class UndoChanged:
    """What Undo would put back now ('' when the user changed no parameter value yet)."""

    what: str


@dataclass
class TransientLoaded:
    """Full-resolution data for plot `plot`, with the compared runs' over the same window."""

    plot: int
    full: Transient
    others: list[Transient] = field(default_factory=list)


@dataclass
class ComparedLoaded:
    """The compared runs' data for plot `plot` (the runs picked in the comparison, in its order)."""

    plot: int
    others: list[Transient]


@dataclass
class RecordingsListed:
    """The user's recordings of the session's model, to compare runs with; `available` False when no
    recorder answered (the server keeps no recordings)."""

    recordings: list[m.RecordingInfo]
    available: bool = True


@dataclass
class TrackLoaded:
    """What the time cursor needs of a run: its link poses over time and what produced it."""

    track: RunTrack


@dataclass
class DocFetched:
    """A documentation page the description did not carry, as the server sent it."""

    page: DocPage


@dataclass
class Download:
    """A file for the browser to save."""

    filename: str
    data: bytes = field(repr=False)


Event = (
    Notice
    | UserChanged
    | LibraryListed
    | LibraryClosed
    | SessionRemembered
    | ModelLoaded
    | StateShown
    | ValuesChanged
    | ParamsRefused
    | ShapesChanged
    | StreamedChanged
    | SettingsChanged
    | PlanChanged
    | CommandRefused
    | RunsChanged
    | RunsDescribed
    | ParamSetsChanged
    | LayoutChanged
    | LiveSamples
    | ObstaclesChanged
    | CommandReplaced
    | PosePreview
    | GoalShown
    | TransientLoaded
    | ComparedLoaded
    | UndoChanged
    | TrackLoaded
    | RecordingsListed
    | DocFetched
    | Download
)
Listener = Callable[[Event], None]
