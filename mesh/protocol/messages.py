"""Every JSON message of the protocol, defined once as msgspec Structs: this module is their one
namespace (`m.JointPath`, `m.Run`, `m.SessionState`, ...); each is defined, by subject, in

- `replies`: Ok and Error, the end of every query;
- `model`: the model library and a model's description; `environment`: obstacles;
- `run_settings`: how a run is simulated;
- `robot_commands`: what the arm is told to do (joint and Cartesian paths, direct inputs, tasks);
- `plans`: a command as the server planned it;
- `session_state`: what a session publishes and answers about itself;
- `session_commands`: the requests about sessions, each with its reply type and the phases it is
  accepted in;
- `run_messages`: between the proxy, a simulator and a run's worker; live jogging;
- `node_messages`: nodes' load, recordings and results.

These classes are the protocol's single definition: `codec` decodes into them strictly (unknown
fields, wrong types, values out of bounds and a missing `v` are refused, naming the field), and
`schema.py` turns them into `docs/protocol.schema.json` and the message tables of PROTOCOL.md.
Bounds live in the types (`Annotated[..., Meta(...)]`), so the schema states them too.

Messages that travel alone carry a tag (`type`, or `op` for commands) and `v`; robot commands are
told apart by `kind`. A newer minor field is added with a default, so `v` only changes when old
clients could misread a message.
"""

from __future__ import annotations

from .environment import Obstacle, ObstacleList, check_obstacles  # noqa: F401
from .model import ControlSystem, ModelList, ModelSummary  # noqa: F401
from .node_messages import *  # noqa: F403
from .plans import *  # noqa: F403
from .primitives import VERSION, FieldProblem  # noqa: F401
from .replies import *  # noqa: F403
from .robot_commands import *  # noqa: F403
from .run_messages import *  # noqa: F403
from .run_settings import *  # noqa: F403
from .session_commands import *  # noqa: F403
from .session_state import *  # noqa: F403
