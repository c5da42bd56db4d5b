"""What a model looks like to clients: its `ModelDescription` built from its `ArmSpec`.

Parameters (with units, descriptions and bounds), the variable catalog, the shapes of the 3D arm, the
initialisation equations and the docs; and the check of a value set against them. This is all data:
a client (the viewer) never imports models/, it receives `describe()` over the mesh.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Literal

import msgspec
import numpy as np
from simecs.mesh.protocol import columns
from simecs.mesh.protocol.codec import DecodeError
from simecs.mesh.protocol.model import (
    CONTROL_SYSTEMS,
    InitEquation,
    Link,
    ModelDescription,
    Parameter,
    Shape,
    Variable,
)
from simecs.mesh.protocol.model import check_values as check_bounds
from simecs.mesh.protocol.robot_commands import COMMAND_LEVELS
from simecs.mesh.rules.kinematics import rot_rpy, rpy_of

from . import contact, grasp
from . import drive as dr
from .docs import build_docs, gravity_text
from .errors import ParameterError
from .mechanics import GRAVITY_PARAMS
from .meshes import MeshStore
from .opspace import GAIN_INFO
from .spec import ArmSpec

# variable catalog per joint: (unit, description, sub-component); the order is drive.OUTPUTS
VAR_INFO = {
    "q": ("rad", "load-side joint angle (chain coordinate)", ""),
    "qd": ("rad/s", "load-side joint speed", ""),
    "q_ref": ("rad", "joint position set point from the trajectory generator", "traj"),
    "qd_ref": ("rad/s", "joint speed set point (velocity feed-forward)", "traj"),
    "q_motor": ("rad", "motor shaft angle (motor side, before the reducer)", "motor"),
    "qd_motor": ("rad/s", "motor shaft speed", "motor"),
    "i_ref": ("A", "current amplitude set point from the speed PI (torque command)", "ctrl"),
    "i_a": ("A", "phase A current", "current"),
    "i_b": ("A", "phase B current", "current"),
    "u_a": ("V", "phase A voltage applied by the current controller", "current"),
    "tau_motor": ("N*m", "electromagnetic torque incl. ripple and detent", "motor"),
    "tau_friction": ("N*m", "LuGre + viscous friction torque at the gear input (motor side)", "gear"),
    "tau_gear": ("N*m", "load-side gear torque (elastic + damping, backlash)", "gear"),
    "twist": ("rad", "gear twist q_motor/n - q (load side)", "gear"),
}
assert tuple(VAR_INFO) == dr.OUTPUTS
TOOL_VAR_INFO = {
    "x_ref": ("m", "tool point set point x: the tool position of the joint set points"),
    "y_ref": ("m", "tool point set point y"),
    "z_ref": ("m", "tool point set point z"),
    "e_pos": ("m", "tool position error: distance of the tool point from its set point"),
    "e_rot": ("rad", "tool orientation error: the angle that turns the tool onto its set point"),
}
assert tuple(TOOL_VAR_INFO) == dr.TOOL_OUTPUTS
CONTACT_LINK_VAR_INFO = {
    "force": ("N", "contact force on the link (the sum over its spheres, magnitude)"),
    "obstacle": (
        "",
        "the obstacle pressing hardest on the link: its number in the session's list, 1..; 0 = none",
    ),
    "fx": ("N", "contact force on the link, x (world)"),
    "fy": ("N", "contact force on the link, y (world)"),
    "fz": ("N", "contact force on the link, z (world)"),
    "px": ("m", "where the contact force acts, x: the mean of the contact points (0 without contact)"),
    "py": ("m", "where the contact force acts, y"),
    "pz": ("m", "where the contact force acts, z"),
}
assert tuple(CONTACT_LINK_VAR_INFO) == contact.PER_LINK_OUTPUTS
CONTACT_VAR_INFO = {
    "depth": ("m", "the deepest penetration of the arm into an obstacle (0: no contact)"),
    "tool_fx": ("N", "contact force on the tool, x (world)"),
    "tool_fy": ("N", "contact force on the tool, y (world)"),
    "tool_fz": ("N", "contact force on the tool, z (world)"),
    "tool_fn": ("N", "the tool's normal contact force: what presses it onto the surfaces it touches"),
}
assert tuple(CONTACT_VAR_INFO) == contact.CONTACT_OUTPUTS
GRASP_VAR_INFO = {
    "object": (
        "",
        "the obstacle the tool took last: its number in the run's list, 1..; 0 = none yet (its pose: "
        "the `grasped` frame)",
    ),
    "held": ("", "1 while the tool holds that obstacle, 0 once released"),
}
assert tuple(GRASP_VAR_INFO) == grasp.GRASP_OUTPUTS


def _vec(a: Sequence[float]) -> np.ndarray:
    return np.asarray(a, dtype=float)


AXES: tuple[Literal["x", "y", "z"], ...] = ("x", "y", "z")


def _axis_of(v: np.ndarray) -> tuple[Literal["x", "y", "z"], float]:
    """Nearest coordinate axis letter of a direction and its sign."""
    k = int(np.argmax(np.abs(v)))
    return AXES[k], float(np.sign(v[k]) or 1.0)


class ArmDescription:
    """An arm model as clients see it: parameters, variables, shapes, init equations, docs, and the
    check of values against them. `ModelPackage` (package.py) adds the simulation to it."""

    def __init__(self, spec: ArmSpec) -> None:
        self.spec = spec
        self.id = spec.id
        self.n = len(spec.links)
        self._params = self._make_parameters()
        self._description: ModelDescription | None = None
        self._meshes: MeshStore | None = None

    # ---- parameters ----
    def _make_parameters(self) -> list[Parameter]:
        s = self.spec
        out: list[Parameter] = []
        out.append(
            Parameter(
                "drives.enabled",
                1.0,
                "-",
                "1: drives act on the chain; 0: drives off, the chain moves free of torques",
                0.0,
                1.0,
                "drives",
                integer=True,
            )
        )
        for i, lk in enumerate(s.links, start=1):
            c = f"link{i}"
            out.append(
                Parameter(
                    f"{c}.length",
                    lk.length,
                    "m",
                    "central translation along the link x axis (Link convention); reshapes the arm",
                    0.0,
                    lk.length_max,
                    c,
                    appearance=True,
                )
            )
            out.append(
                Parameter(f"{c}.mass", lk.mass, "kg", "link mass incl. its joint housing", 0.0, 500.0, c)
            )
            out.append(
                Parameter(
                    f"{c}.radius",
                    lk.radius,
                    "m",
                    "outer radius of the link tube (drawn shape; tube inertia where the link is a tube)",
                    0.005,
                    0.5,
                    c,
                    appearance=True,
                )
            )
        out.append(
            Parameter(
                "payload.mass", s.payload_mass, "kg", "payload at the tool point", 0.0, 500.0, "payload"
            )
        )
        out.append(
            Parameter(
                "payload.size",
                s.payload_size,
                "m",
                "edge of the cubic payload (solid, homogeneous), centred on the tool point",
                0.01,
                2.0,
                "payload",
                appearance=True,
            )
        )
        for name, value in zip(GRAVITY_PARAMS, s.gravity, strict=True):
            out.append(
                Parameter(
                    name,
                    float(value),
                    "m/s^2",
                    f"gravity along the world {name[-1]} axis (the model's: {gravity_text(s.gravity)}); "
                    "0, 0, 0 for a test in zero gravity",
                    -100.0,
                    100.0,
                    "gravity",
                )
            )
        for name, value, unit, what, top in (
            ("max_speed", s.cart_max_speed, "m/s", "tool point speed", 10.0),
            ("max_acc", s.cart_max_acc, "m/s^2", "tool point acceleration", 100.0),
            ("max_rot_speed", s.cart_max_rot_speed, "rad/s", "tool orientation speed", 20.0),
            ("max_rot_acc", s.cart_max_rot_acc, "rad/s^2", "tool orientation acceleration", 200.0),
        ):
            out.append(
                Parameter(
                    f"cart.{name}",
                    value,
                    unit,
                    f"{what} of a straight-line (lin) move at 100 %",
                    1e-3,
                    top,
                    "cart",
                )
            )
        for name, (value, unit, what, lo, hi) in GAIN_INFO.items():
            out.append(Parameter(f"control.{name}", value, unit, what, lo, hi, "control"))
        for i, lk in enumerate(s.links, start=1):
            table = s.drives[lk.drive]
            for name in dr.DRIVE_PARAMS:
                info = table[name]
                sub = name.split(".")[0]
                out.append(
                    Parameter(
                        f"joint{i}.{name}",
                        float(info.value),
                        info.unit,
                        info.description,
                        float(info.min),
                        float(info.max),
                        f"joint{i}.{sub}",
                        integer=info.integer,
                    )
                )
        return out

    def parameters(self) -> list[Parameter]:
        """Every tunable value with its default (a copy of the list: callers may not change ours)."""
        return list(self._params)

    def check_values(self, values: Mapping[str, float]) -> dict[str, float]:
        """Every value checked against its bounds (the protocol's one rule), then the model's own
        cross-checks; the full value set, or ParameterError naming the culprit."""
        try:
            full = check_bounds(self.describe(), dict(values))
        except DecodeError as exc:
            raise ParameterError(exc.field.removeprefix("values."), exc.problem) from None
        # cross-checks that single bounds cannot express
        for i in range(1, self.n + 1):
            j = f"joint{i}"
            if full[f"{j}.gear.fs"] < full[f"{j}.gear.fc"]:
                raise ParameterError(f"{j}.gear.fs", "static friction must not be below Coulomb friction")
            if full[f"{j}.motor.ideal"] < 0.5 and full[f"{j}.current.kp"] <= 0.0:
                raise ParameterError(f"{j}.current.kp", "must be > 0 unless the motor is ideal")
        return full

    # ---- description ----
    def describe(self) -> ModelDescription:
        """The model as data, built once: what the simulator sends to every client."""
        if self._description is None:
            s = self.spec
            links = [
                Link(
                    name=f"link{i}",
                    joint=f"joint{i}",
                    initial_rotation_rpy=list(lk.rpy),
                    length_param=f"link{i}.length",
                    final_translation=list(lk.final),
                    joint_min=lk.joint_min,
                    joint_max=lk.joint_max,
                )
                for i, lk in enumerate(s.links, start=1)
            ]
            self._description = ModelDescription(
                id=s.id,
                name=s.name,
                summary=s.summary,
                base_translation=list(s.base_translation),
                links=links,
                tool_translation=list(s.tool_translation),
                shapes=self._shapes(),
                parameters=[msgspec.structs.replace(p) for p in self._params],
                variables=self.variables(),
                init_equations=self.init_equations(),
                doc_root=f"{s.id}",
                docs=build_docs(s, self._params, self.init_equations()),
                command_levels=list(COMMAND_LEVELS),
                home=list(self.home()),
                environment=list(s.environment) + self._mesh_shapes(-1),
                base_rotation_rpy=list(s.base_rpy),
                control_systems=list(CONTROL_SYSTEMS),
                obstacles=list(s.obstacles),
            )
        return self._description

    def mesh_store(self) -> MeshStore:
        """The GLBs of the model's mesh shapes, made on first request."""
        if self._meshes is None:
            self._meshes = MeshStore(self.spec.visuals)
        return self._meshes

    def home(self) -> tuple[float, ...]:
        """The posture the `home` action goes to."""
        return tuple(self.spec.home) if self.spec.home else (0.0,) * self.n

    def variables(self) -> list[Variable]:
        """The variable catalog: every output column of a run but time and poses, per joint."""
        out = []
        for i in range(1, self.n + 1):
            for name, (unit, desc, sub) in VAR_INFO.items():
                comp = f"joint{i}.{sub}" if sub else f"joint{i}"
                out.append(Variable(f"joint{i}.{name}", unit, f"joint {i}: {desc}", comp))
        for name, (unit, desc) in TOOL_VAR_INFO.items():
            out.append(Variable(f"tool.{name}", unit, desc, "tool"))
        for i in range(1, self.n + 1):
            for name, (unit, desc) in CONTACT_LINK_VAR_INFO.items():
                out.append(Variable(columns.contact_column(i, name), unit, f"link {i}: {desc}", "contact"))
        for name, (unit, desc) in CONTACT_VAR_INFO.items():
            out.append(Variable(f"contact.{name}", unit, desc, "contact"))
        for name, (unit, desc) in GRASP_VAR_INFO.items():
            out.append(Variable(f"grasp.{name}", unit, desc, "grasp"))
        assert {columns.GRASP_OBJECT, columns.GRASP_HELD} <= {v.name for v in out}
        return out

    def init_equations(self) -> list[InitEquation]:
        """The initialisation equations (paper §5.2) as text; mechanics.init_states computes them."""
        eqs = [
            InitEquation(
                "jointN.q_ref",
                "q + e_l*sin(q)  [+ i_ref/(kp_vel*n*kp_pos) if ki_vel = 0]",
                "hold the measured position (load resolver) so the position loop starts without error",
            ),
            InitEquation(
                "jointN.q_motor",
                "n * (q + tau_g/k + sign(tau_g)*b/2)",
                "the gear twisted by the static load it carries, tau_g = g(q) (the gravity torque of "
                "the joint at q; 0 in zero gravity: untwisted, centred in the backlash b)",
            ),
            InitEquation("jointN.qd_motor", "0", "robot at rest"),
            InitEquation("jointN.friction_z", "0", "LuGre bristles unloaded"),
            InitEquation(
                "jointN.i_ref",
                "(tau_g*f/n - tau_detent(q_m) - B) / A",
                "the current that holds the static load at the motor shaft (f = (eta + 1/eta)/2, the "
                "efficiency's switch at rest) and cancels the detent torque and the current-sensor "
                "offsets; A = torque per ampere of commanded amplitude at the rotor angle, B = torque of "
                "the offsets (see the initialisation page)",
            ),
            InitEquation(
                "jointN.ctrl.x_vel",
                "i_ref - ff_gravity*tau_g*f/(n*kt)",
                "speed PI integrator (its error is zero at rest): the current the gravity feed-forward "
                "does not give",
            ),
            InitEquation(
                "jointN.i_a",
                "-i_ref*sin(p*q_m') - offset_a",
                "phase A current; q_m' = motor resolver reading",
            ),
            InitEquation("jointN.i_b", "i_ref*cos(p*q_m') - offset_b", "phase B current"),
            InitEquation(
                "jointN.current.x_a",
                "R * i_a  [R * (i_a*cos(p*q_m') + i_b*sin(p*q_m')) if rotor_frame]",
                "current PI integrators = phase voltages at rest (no back-EMF, di/dt = 0); with the "
                "PIs in the rotor's frame, its d and q voltages",
            ),
            InitEquation(
                "jointN.current.x_b", "R * i_b  [R * (-i_a*sin(p*q_m') + i_b*cos(p*q_m')) if rotor_frame]", ""
            ),
        ]
        return eqs

    def _mesh_shapes(self, link: int) -> list[Shape]:
        """The drawn parts (URDF visuals) of one link, or of the world for -1, as mesh shapes."""
        out = []
        for v in self.spec.visuals:
            if v.link != link:
                continue
            pose = v.geometry.pose
            out.append(
                Shape(
                    "mesh",
                    link,
                    [float(a) for a in pose[:3, 3]],
                    color=list(v.color),
                    mesh=v.name,
                    rotation_rpy=[float(a) for a in rpy_of(pose[:3, :3])],
                    scale=[float(a) for a in v.geometry.scale],
                )
            )
        return out

    def _shapes(self) -> list[Shape]:
        """Per link its drawn parts (URDF visuals) where it has some, else a joint housing, a link tube
        (resizable) and an offset beam; then the tool flange and the payload box."""
        s = self.spec
        shapes: list[Shape] = []
        for i, lk in enumerate(s.links):
            meshes = self._mesh_shapes(i)
            if meshes:
                shapes.extend(meshes)
                continue
            col = list(lk.color)
            r = lk.radius
            # joint housing: a cylinder about this link's joint axis, centred on the link frame origin
            axis_local = rot_rpy(lk.rpy).T @ np.array([0.0, 0.0, 1.0])
            ax, _ = _axis_of(axis_local)
            h = 2.6 * r
            origin = [0.0, 0.0, 0.0]
            origin["xyz".index(ax)] = -h / 2
            rad = f"link{i + 1}.radius"
            shapes.append(
                Shape(
                    "cylinder",
                    i,
                    origin,
                    ax,
                    length=h,
                    radius=1.25 * r,
                    color=[90, 95, 110],
                    scales_with={"radius": rad},
                )
            )
            # the link tube: resizable along x with the link length
            shapes.append(
                Shape(
                    "pipe",
                    i,
                    [0.0, 0.0, 0.0],
                    "x",
                    length=lk.length,
                    radius=r,
                    inner_radius=0.8 * r,
                    color=col,
                    resizable=True,
                    scales_with={"radius": rad, "inner_radius": rad},
                )
            )
            # final translation: a beam from the link end along the offset (drawn only when axis-aligned)
            f = _vec(lk.final)
            if np.linalg.norm(f) > 1e-9:
                fa, sign = _axis_of(f)
                k = "xyz".index(fa)
                if abs(f[k]) > 0.999 * np.linalg.norm(f):
                    o = [lk.length, 0.0, 0.0]
                    if sign < 0:
                        o[k] += f[k]
                    shapes.append(
                        Shape(
                            "beam",
                            i,
                            o,
                            fa,
                            length=abs(f[k]),
                            width=1.6 * r,
                            height=1.6 * r,
                            color=col,
                            scales_with={"width": rad, "height": rad},
                            anchor="end",
                        )
                    )
        # tool flange and payload on the last link
        last = len(s.links) - 1
        lk = s.links[-1]
        tool = np.array([lk.length, 0, 0]) + _vec(lk.final) + _vec(s.tool_translation)
        shapes.append(
            Shape(
                "cylinder",
                last,
                [float(tool[0]) - 0.02, float(tool[1]), float(tool[2])],
                "x",
                length=0.02,
                radius=1.3 * lk.radius,
                color=[60, 60, 60],
                scales_with={"radius": f"link{last + 1}.radius"},
                anchor="end",
            )
        )
        a = s.payload_size
        shapes.append(
            Shape(
                "box",
                last,
                [float(tool[0]) - a / 2, float(tool[1]), float(tool[2])],
                "x",
                length=a,
                width=a,
                height=a,
                color=[220, 160, 40],
                scales_with={"length": "payload.size", "width": "payload.size", "height": "payload.size"},
                anchor="end",
            )
        )
        return shapes
