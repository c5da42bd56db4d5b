"""The obstacles panel: what the arm can touch in this session (paper §6), added, moved and removed by
the user. Pick an obstacle (or a new one), edit its fields, Apply: the whole list goes to the server
(`set_obstacles`), which checks it and names a wrong field. Graspable objects are those with a mass.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Any

from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.protocol.environment import MAX_OBSTACLES, OBSTACLE_KINDS, check_obstacles
from simecs.mesh.protocol.primitives import FieldProblem

NEW = "(new obstacle)"


def obstacle_from_form(form: dict[str, Any]) -> m.Obstacle:
    """An obstacle from the panel's fields, checked as the server checks it (DecodeError names the
    field)."""
    return codec.loads(m.Obstacle, json.dumps(form))


def edited_list(obstacles: Sequence[m.Obstacle], selected: str, new: m.Obstacle) -> list[m.Obstacle]:
    """`obstacles` with `selected` replaced by `new` (appended when `selected` is NEW); DecodeError when
    the list breaks a rule (a name twice, too many)."""
    out = list(obstacles)
    index = next((k for k, ob in enumerate(out) if ob.name == selected), -1)
    if index >= 0:
        out[index] = new
    else:
        out.append(new)
    try:
        check_obstacles(out)
    except FieldProblem as exc:
        raise DecodeError(exc.field, exc.problem) from None
    return out


class ObstaclePanel:
    """The form; `on_apply` gets the whole new list, `on_error` a message for the user."""

    def __init__(
        self,
        gui: Any,
        obstacles: Sequence[m.Obstacle],
        model_obstacles: Sequence[m.Obstacle],
        on_apply: Callable[[list[m.Obstacle]], None],
        on_error: Callable[[str], None],
    ) -> None:
        self.obstacles = list(obstacles)
        self.model_obstacles = list(model_obstacles)
        self.on_apply = on_apply
        self.on_error = on_error
        self.pick = gui.add_dropdown("Obstacle", self._options(), initial_value=NEW)
        self.name = gui.add_text("Name", "box1", hint="unique in the session; a grasp action names it")
        self.kind = gui.add_dropdown("Kind", OBSTACLE_KINDS, initial_value="box")
        self.position = gui.add_vector3("Position [m]", (0.5, 0.0, 0.05), step=0.01, hint="its centre")
        self.rpy = gui.add_vector3("Rotation rpy [rad]", (0.0, 0.0, 0.0), step=0.01)
        self.size = gui.add_vector3("Box edges [m]", (0.1, 0.1, 0.1), step=0.01, hint="box: x, y, z")
        self.radius = gui.add_number("Radius [m]", 0.05, step=0.005, hint="cylinder, sphere")
        self.length = gui.add_number("Length [m]", 0.1, step=0.01, hint="cylinder: along its z")
        self.mass = gui.add_number(
            "Mass [kg]", 0.0, step=0.1, hint="0: fixed to the world; with a mass the tool can grasp it"
        )
        self.friction = gui.add_number("Friction", 0.3, step=0.05, hint="Coulomb coefficient [0, 2]")
        self.stiffness = gui.add_number("Stiffness [N/m]", 1e5, step=1e4, hint="[100, 1e7]")
        self.damping = gui.add_number("Damping [N s/m]", 300.0, step=10.0, hint="[0, 1e5]")
        self.apply_button = gui.add_button("Apply obstacle", color="green")
        self.remove_button = gui.add_button("Remove obstacle", color="red")
        self.reset_button = gui.add_button("The model's obstacles", color="gray")
        self.pick.on_update(lambda _e: self._fill())
        self.kind.on_update(lambda _e: self._show_fields())
        self.apply_button.on_click(lambda _e: self.apply())
        self.remove_button.on_click(lambda _e: self.remove())
        self.reset_button.on_click(lambda _e: self.on_apply(list(self.model_obstacles)))
        self._show_fields()

    def _options(self) -> tuple[str, ...]:
        return (*[ob.name for ob in self.obstacles], NEW)

    def show(self, obstacles: Sequence[m.Obstacle]) -> None:
        """The session's list (after anyone's edit): the choice stays on the same name if it is kept."""
        self.obstacles = list(obstacles)
        keep = self.pick.value if self.pick.value in self._options() else NEW
        self.pick.options = self._options()
        self.pick.value = keep
        self._fill()

    def form(self) -> dict[str, Any]:
        picked = self._selected()
        return {
            "name": str(self.name.value).strip(),
            "kind": str(self.kind.value),
            "position": [float(v) for v in self.position.value],
            "rotation_rpy": [float(v) for v in self.rpy.value],
            "size": [float(v) for v in self.size.value],
            "radius": float(self.radius.value),
            "length": float(self.length.value),
            "mass": float(self.mass.value),
            "friction": float(self.friction.value),
            "stiffness": float(self.stiffness.value),
            "damping": float(self.damping.value),
            "color": list(picked.color) if picked is not None else [150, 110, 90],
        }

    def _selected(self) -> m.Obstacle | None:
        return next((ob for ob in self.obstacles if ob.name == self.pick.value), None)

    def _fill(self) -> None:
        ob = self._selected()
        if ob is None:
            taken = {o.name for o in self.obstacles}
            self.name.value = next(f"box{k}" for k in range(1, MAX_OBSTACLES + 2) if f"box{k}" not in taken)
            return
        self.name.value = ob.name
        self.kind.value = ob.kind
        self.position.value = tuple(ob.position)
        self.rpy.value = tuple(ob.rotation_rpy)
        self.size.value = tuple(ob.size)
        self.radius.value = ob.radius
        self.length.value = ob.length
        self.mass.value = ob.mass
        self.friction.value = ob.friction
        self.stiffness.value = ob.stiffness
        self.damping.value = ob.damping
        self._show_fields()

    def _show_fields(self) -> None:
        kind = self.kind.value
        self.size.visible = kind == "box"
        self.radius.visible = kind in ("cylinder", "sphere")
        self.length.visible = kind == "cylinder"
        self.mass.visible = kind != "plane"
        self.remove_button.disabled = self._selected() is None

    def apply(self) -> None:
        """The edited obstacle into the list (in place of the one picked, or added), sent whole."""
        try:
            new = obstacle_from_form(self.form())
            obstacles = edited_list(self.obstacles, str(self.pick.value), new)
        except DecodeError as exc:
            self.on_error(f"{exc.field}: {exc.problem}" if exc.field else exc.problem)
            return
        self.pick.options = (*[ob.name for ob in obstacles], NEW)
        self.pick.value = new.name
        self.on_apply(obstacles)

    def remove(self) -> None:
        picked = self._selected()
        if picked is not None:
            self.pick.value = NEW
            self.on_apply([ob for ob in self.obstacles if ob.name != picked.name])
