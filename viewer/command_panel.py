"""The command panel: one teach pendant per command level the model takes (paper §2.2: panels, not a
prompt), docked beside the arm: the joint path, the Cartesian path, the direct input's signals, the
tasks of actions, the jog panel and the obstacles.

The session's command is the one of the pendant edited last (`SessionController.command_kind`); the
server's plan of it (duration, the tool path drawn in 3D, the signals' preview) or its refusal (shown
beside it, naming the node or the signal's number) goes to that pendant, and the others say theirs is
not the session's command.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from simecs.mesh.protocol import messages as m

from . import events as ev
from .cartesian_pendant import CartesianPendant
from .direct_pendant import DirectInputPanel
from .jog_panel import JogPanel
from .joints import InitPanel
from .layout import Layout
from .obstacles import ObstaclePanel
from .path import clamp_to_limits
from .pendant import PendantPanel
from .program import LEVELS
from .program_pendant import ProgramPanel
from .scene import ArmScene
from .session import SessionController

INIT_TAB = "Initial pose"  # the pendant's tab of one slider per joint (paper §5.2 initialisation panel)


class CommandPanel:
    """The docked panel of command pendants of one model page."""

    def __init__(
        self,
        client: Any,
        c: SessionController,
        scene: ArmScene,
        layout: Layout,
        warn: Callable[[str], Callable[[str], None]],
    ) -> None:
        model = c.model
        assert model is not None and c.path is not None
        gui = client.gui
        self.c = c
        self.scene = scene
        self.pendant: PendantPanel | None = None
        self.cartesian: CartesianPendant | None = None
        self.panel = gui.add_panel()
        with self.panel.add_tab("Joint path"):
            if "joint_path" in model.command_levels:
                self.pendant = PendantPanel(
                    gui,
                    c.path,
                    current_q=lambda: list(c.shown_q),
                    on_changed=c.edits.command_changed,
                    on_preview=c.show_goal,
                    on_error=warn("Joint path"),
                )
            else:
                levels = ", ".join(model.command_levels) or "none"
                gui.add_markdown(f"_This model takes {levels} commands, not joint paths._")
        if c.cart is not None:
            with self.panel.add_tab("Cartesian"):
                self.cartesian = CartesianPendant(
                    gui,
                    client.scene,
                    c.cart,
                    tool_pose=lambda: c.tool_pose(list(c.shown_q)),
                    on_changed=lambda: c.edits.command_changed("cartesian_path"),
                    on_dragged=lambda: c.edits.command_dragged("cartesian_path"),
                    on_preview=c.show_goal,
                    on_error=warn("Cartesian path"),
                    reach=scene.extent(),
                )
        self.direct: DirectInputPanel | None = None
        if c.direct is not None:
            with self.panel.add_tab("Direct input"):
                self.direct = DirectInputPanel(
                    gui,
                    c.direct,
                    on_changed=lambda: c.edits.command_changed("direct_input"),
                    on_error=warn("Direct input"),
                    after=c.loop.after,
                )
        self.program: ProgramPanel | None = None
        if c.program is not None:
            program = c.program
            with self.panel.add_tab("Tasks"):
                self.program = ProgramPanel(
                    gui,
                    program,
                    current_q=lambda: list(c.shown_q),
                    tool_pose=c.tool_pose,
                    on_changed=lambda: c.edits.command_changed(program.kind),
                    on_preview=c.show_goal,
                    request=c.edits.command,
                    submit=c.submit,
                    on_error=warn("Tasks"),
                    ui=c.on_loop,
                    after=c.loop.after,
                )
        with self.panel.add_tab("Jog"):
            self.jog = JogPanel(gui, c.jog, warn("Jog"))
        with self.panel.add_tab("Obstacles"):
            self.obstacles = ObstaclePanel(
                gui, c.obstacles, model.obstacles, c.edits.set_obstacles, warn("Obstacles")
            )
        with self.panel.add_tab(INIT_TAB):  # what the toolbar's Initialise brings to the front
            self.init = InitPanel(
                gui, model.links, model.init_equations, c.initial, c.edits.set_initial, self._zero_initial
            )
        layout.place_command(self.panel)

    def _zero_initial(self) -> None:
        model = self.c.model
        if model is None:
            return
        q = clamp_to_limits([0.0] * len(model.links), model.links)
        self.init.sliders.set_q(q)
        self.c.edits.set_initial(q)

    def show_plan(self, event: ev.PlanChanged | None = None) -> None:
        """The session's command as the server planned it, on its pendant and as a tool path in 3D
        (`event`: the server's answer to an edit; None: shown again, e.g. after new settings)."""
        c = self.c
        plan, stop, kind = c.edits.plan, c.settings.stop_time, c.command_kind
        current = plan is not None and plan.kind == kind
        if self.pendant is not None:
            self.pendant.show_plan(plan if kind == "joint_path" else None, stop, kind == "joint_path")
        if self.cartesian is not None:
            self.cartesian.show_plan(plan, stop, current and kind == "cartesian_path", event is not None)
        if self.direct is not None:
            self.direct.show_plan(plan, stop, current and kind == "direct_input")
        if self.program is not None:
            self.program.show_plan(plan, stop, current and kind in LEVELS)
        self.scene.show_tool_path(plan.tool_path if current and plan is not None else [])

    def show_replaced(self, event: ev.CommandReplaced) -> None:
        """Another client set the session's command: its pendant shows it, and the plan with it."""
        if event.kind == "joint_path" and self.pendant is not None:
            self.pendant.refresh()
        elif event.kind == "cartesian_path" and self.cartesian is not None:
            self.cartesian.refresh()
        elif event.kind == "direct_input" and self.direct is not None:
            self.direct.show_joint(self.direct.joint.value)
        elif event.kind in LEVELS and self.program is not None:
            self.program.refresh()
        self.show_plan()

    def show_refusal(self, event: ev.CommandRefused) -> None:
        """The server refused the path being edited: the reason beside it, no tool path drawn."""
        if event.kind == "cartesian_path" and self.cartesian is not None:
            self.cartesian.show_refusal(event.field, event.reason)
        elif event.kind == "joint_path" and self.pendant is not None:
            self.pendant.show_refusal(event.field, event.reason)
        elif event.kind == "direct_input" and self.direct is not None:
            self.direct.show_refusal(event.field, event.reason)
        elif event.kind in LEVELS and self.program is not None:
            self.program.show_refusal(event.field, event.reason)
        self.scene.show_tool_path([])

    def show_editable(self) -> None:
        """The command and the initial pose cannot change while a run is under way."""
        self.init.sliders.set_disabled(bool(self.c.refusal("set_initial")))
        locked = bool(self.c.refusal("set_command"))
        if self.pendant is not None:
            self.pendant.set_disabled(locked)
        if self.cartesian is not None:
            self.cartesian.set_disabled(locked)
        if self.direct is not None:
            self.direct.set_disabled(locked)
        if self.program is not None:
            self.program.set_disabled(locked)

    def show_state(self, state: m.SessionState | None) -> None:
        """The run's progress through its command: the task pendant marks the step that runs."""
        if self.program is not None:
            self.program.show_state(state, self.c.command_kind in LEVELS)

    def remove(self) -> None:
        if self.cartesian is not None:
            self.cartesian.remove()
        self.panel.remove()
