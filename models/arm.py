"""A serial arm with the flexible-joint drive family: description as data, and its Exudyn simulation.

A model = an `ArmSpec` (links, drive defaults per joint, documentation text). Everything else, the
parameter tree, the variable catalog, shapes, docs, the Exudyn chain, the drives, comes from here, so
adding a model is adding a spec (see spider.py, puma.py), not editing the simulator.
"""

from __future__ import annotations

import math
import numbers
import sys
import time as _time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import msgspec
import numpy as np
from simecs.mesh.codec import DecodeError
from simecs.mesh import columns
from simecs.mesh.kinematics import rot_rpy
from simecs.mesh.model import (
    InitEquation,
    Link,
    ModelDescription,
    Parameter,
    Shape,
    Variable,
    check_values,
)

from . import drive as dr
from .errors import ParameterError, SimulationError

# ---------------------------------------------------------------------------------------------------
# specification


@dataclass
class ParamInfo:
    """Default, unit, description and bounds of one drive parameter (per joint)."""

    value: float
    unit: str
    description: str
    min: float
    max: float
    integer: bool = False


@dataclass
class LinkSpec:
    name: str
    rpy: tuple[float, float, float]
    length: float
    final: tuple[float, float, float]
    joint_min: float
    joint_max: float
    mass: float
    radius: float
    drive: str  # key into ArmSpec.drives
    length_max: float = 3.0
    com: tuple[float, float, float] | None = None  # fixed COM in the link frame; None: uniform tube
    inertia: tuple[float, float, float] | None = None  # principal inertia at COM (link axes); None: tube
    color: tuple[int, int, int] = (200, 200, 210)


@dataclass
class ArmSpec:
    id: str
    name: str
    summary: str
    links: list[LinkSpec]
    drives: dict[str, dict[str, ParamInfo]]  # size class -> DRIVE_PARAMS name -> info
    base_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tool_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    payload_mass: float = 0.0
    payload_size: float = 0.2
    default_step: float = 1e-3
    substeps: int = 5
    assumptions: str = ""
    chain_doc: str = ""
    standard_target: tuple[float, ...] = ()
    environment: list[Shape] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------------
# variable catalog per joint: (unit, description, sub-component)
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

MECH_PREFIXES = ("link", "payload.")


def _vec(a: Sequence[float]) -> np.ndarray:
    return np.asarray(a, dtype=float)


def _axis_of(v: np.ndarray) -> tuple[str, float]:
    """Nearest coordinate axis letter of a direction and its sign."""
    k = int(np.argmax(np.abs(v)))
    return "xyz"[k], float(np.sign(v[k]) or 1.0)


# ---------------------------------------------------------------------------------------------------
class ModelPackage:
    """One model of the library: its description as data, validation, and `build`."""

    def __init__(self, spec: ArmSpec) -> None:
        self.spec = spec
        self.id = spec.id
        self.n = len(spec.links)
        self._params = self._make_parameters()
        self._by_name = {p.name: p for p in self._params}
        self._description: ModelDescription | None = None

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
        return list(self._params)

    def check_values(self, values: Mapping[str, float]) -> dict[str, float]:
        """Every value checked against its bounds (the protocol's one rule), then the model's own
        cross-checks; the full value set, or ParameterError naming the culprit."""
        try:
            full = check_values(self.describe(), dict(values))
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
        if self._description is None:
            from .docs import build_docs

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
                docs=build_docs(self),
                command_levels=["joint_path"],
                environment=list(s.environment),
            )
        return self._description

    def variables(self) -> list[Variable]:
        out = []
        for i in range(1, self.n + 1):
            for name, (unit, desc, sub) in VAR_INFO.items():
                comp = f"joint{i}.{sub}" if sub else f"joint{i}"
                out.append(Variable(f"joint{i}.{name}", unit, f"joint {i}: {desc}", comp))
        return out

    def init_equations(self) -> list[InitEquation]:
        eqs = [
            InitEquation(
                "jointN.q_ref",
                "q + e_l*sin(q)  [+ i_ref/(kp_vel*n*kp_pos) if ki_vel = 0]",
                "hold the measured position (load resolver) so the position loop starts without error",
            ),
            InitEquation(
                "jointN.q_motor",
                "n * q",
                "q_m = n q_l: gear untwisted, centred in the backlash "
                "(zero gravity: no static gear load, paper §5.2)",
            ),
            InitEquation("jointN.qd_motor", "0", "robot at rest"),
            InitEquation("jointN.friction_z", "0", "LuGre bristles unloaded"),
            InitEquation(
                "jointN.i_ref",
                "(-tau_detent(q_m) - B) / A",
                "the speed-loop integrator holds the current "
                "that cancels the detent torque and the current-sensor offsets; A = torque per ampere of "
                "commanded amplitude at the rotor angle, B = torque of the offsets "
                "(see the initialisation page)",
            ),
            InitEquation("jointN.ctrl.x_vel", "i_ref", "speed PI integrator (its error is zero at rest)"),
            InitEquation(
                "jointN.i_a",
                "-i_ref*sin(p*q_m') - offset_a",
                "phase A current; q_m' = motor resolver reading",
            ),
            InitEquation("jointN.i_b", "i_ref*cos(p*q_m') - offset_b", "phase B current"),
            InitEquation(
                "jointN.current.x_a",
                "R * i_a",
                "current PI integrators = phase voltages at rest (no back-EMF, di/dt = 0)",
            ),
            InitEquation("jointN.current.x_b", "R * i_b", ""),
        ]
        return eqs

    def _shapes(self) -> list[Shape]:
        s = self.spec
        shapes: list[Shape] = []
        for i, lk in enumerate(s.links):
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

    # ---- mechanics as arrays ----
    def chain_arrays(self, values: Mapping[str, float]):
        """pre_R, pre_p (joint i frame from joint i-1 frame), masses, COMs, inertias in joint frames."""
        s = self.spec
        n = self.n
        pre_R = np.zeros((n, 3, 3))
        pre_p = np.zeros((n, 3))
        masses = np.zeros(n)
        coms = np.zeros((n, 3))
        inertias = np.zeros((n, 3, 3))
        prev_R = np.eye(3)
        prev_off = _vec(s.base_translation)
        for i, lk in enumerate(s.links):
            pre_R[i] = prev_R
            pre_p[i] = prev_off
            Rr = rot_rpy(lk.rpy)
            L = float(values[f"link{i + 1}.length"])
            m = float(values[f"link{i + 1}.mass"])
            r = float(values[f"link{i + 1}.radius"])
            if lk.com is None:
                c_l = np.array([L / 2, 0.0, 0.0])
                # thin-walled tube (wall 20 % of the radius): Ixx = m r^2 (1+0.64)/2 ...
                ri2 = (0.8 * r) ** 2
                ixx = 0.5 * m * (r * r + ri2)
                iyy = m * (3 * (r * r + ri2) + L * L) / 12.0
                I_l = np.diag([ixx, iyy, iyy])
            else:
                c_l = _vec(lk.com)
                I_l = np.diag(_vec(lk.inertia))
            if i == n - 1:
                mp = float(values["payload.mass"])
                if mp > 0:
                    a = float(values["payload.size"])
                    cp = np.array([L, 0, 0]) + _vec(lk.final) + _vec(s.tool_translation)
                    Ip = np.eye(3) * mp * a * a / 6.0
                    mt = m + mp
                    ct = (m * c_l + mp * cp) / mt if mt > 0 else c_l
                    I_new = np.zeros((3, 3))
                    for mk, ck, Ik in ((m, c_l, I_l), (mp, cp, Ip)):
                        d = ck - ct
                        I_new += Ik + mk * (d @ d * np.eye(3) - np.outer(d, d))
                    m, c_l, I_l = mt, ct, I_new
            masses[i] = m
            coms[i] = Rr @ c_l
            inertias[i] = Rr @ I_l @ Rr.T
            prev_R = Rr
            prev_off = Rr @ (np.array([L, 0.0, 0.0]) + _vec(lk.final))
        return pre_R, pre_p, masses, coms, inertias

    def drive_array(self, values: Mapping[str, float]) -> np.ndarray:
        P = np.zeros((self.n, dr.NP))
        for j in range(self.n):
            for k, name in enumerate(dr.DRIVE_PARAMS):
                P[j, k] = values[f"joint{j + 1}.{name}"]
        return P

    def build(self, values: Mapping[str, float] | None = None) -> Simulation:
        return Simulation(self, self.check_values(values or {}))


# ---------------------------------------------------------------------------------------------------
def init_states(P: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Initialisation equations (paper §5.2): drive states and held reference of a robot at rest at q."""
    n = q.shape[0]
    X = np.zeros((n, dr.NL))
    hold = np.zeros(n)
    for j in range(n):
        nn = P[j, dr.P_N]
        p = P[j, dr.P_POLES]
        th = nn * q[j]
        th_meas = th + P[j, dr.P_EM] * math.sin(p * th)
        te = p * th
        tem = p * th_meas
        h3 = P[j, dr.P_H3]
        sa = -(math.sin(te) + h3 * math.sin(3 * te))
        sb = math.cos(te) + h3 * math.cos(3 * te)
        ka = P[j, dr.P_KT] * (1 - 0.5 * P[j, dr.P_UNB])
        kb = P[j, dr.P_KT] * (1 + 0.5 * P[j, dr.P_UNB])
        ideal = P[j, dr.P_IDEAL] > 0.5
        offa = 0.0 if ideal else P[j, dr.P_OFFA]
        offb = 0.0 if ideal else P[j, dr.P_OFFB]
        A = -ka * sa * math.sin(tem) + kb * sb * math.cos(tem)
        B = -(ka * sa * offa + kb * sb * offb)
        tau_det = P[j, dr.P_DET] * math.sin(4 * p * th)
        iref = (-tau_det - B) / A if abs(A) > 1e-12 else 0.0
        iref = float(np.clip(iref, -P[j, dr.P_IMAX], P[j, dr.P_IMAX]))
        ia = -iref * math.sin(tem) - offa
        ib = iref * math.cos(tem) - offb
        q_meas = q[j] + P[j, dr.P_EL] * math.sin(q[j])
        X[j, dr.S_TH] = th
        X[j, dr.S_IA] = ia
        X[j, dr.S_IB] = ib
        X[j, dr.S_XA] = P[j, dr.P_R] * ia
        X[j, dr.S_XB] = P[j, dr.P_R] * ib
        if P[j, dr.P_KIV] > 0:
            X[j, dr.S_XV] = iref
            hold[j] = q_meas
        else:  # P-only speed loop: the current comes from a standing position error
            g = P[j, dr.P_KPV] * nn * P[j, dr.P_KPP]
            hold[j] = q_meas + (iref / g if g > 0 else 0.0)
    return X, hold


# ---------------------------------------------------------------------------------------------------
class Simulation:
    """One run of a model in Exudyn; the simulator node drives it chunk by chunk."""

    def __init__(self, package: ModelPackage, values: dict[str, float]) -> None:
        self.package = package
        self.n = package.n
        self.values = dict(values)
        self._desc = package.describe()
        self.columns, self.units = columns.run_columns(self._desc)
        self.P = package.drive_array(self.values)
        self._mech = package.chain_arrays(self.values)
        self.q0 = np.zeros(self.n)
        self.qd0 = np.zeros(self.n)
        self.X, self.hold = init_states(self.P, self.q0)
        self.seg = np.zeros((0, 3 + 2 * self.n))
        self._nodes: list[tuple[np.ndarray, float, float]] = []
        self._mbs = None
        self._solver = None
        self._running = False
        self._stop_time = 0.0
        self._time = 0.0
        self.timing = {"mechanics+drive": 0.0, "drive": 0.0, "output": 0.0}
        self._Rrpy = np.array([rot_rpy(lk.rpy) for lk in package.spec.links])
        self._tool_loc = np.zeros(3)
        self._rows = np.zeros((0, len(self.columns)))
        self._nrows = 0
        self._k_next = 0
        self._t_next = 0.0
        self._build_exudyn()

    # ---- Exudyn ----
    def _build_exudyn(self) -> None:
        exu = _exudyn()
        from exudyn.itemInterface import NodeGenericODE2, ObjectKinematicTree, SensorKinematicTree

        pre_R, pre_p, masses, coms, inertias = self._mech
        n = self.n
        self._SC = exu.SystemContainer()
        mbs = self._SC.AddSystem()
        self._node = mbs.AddNode(
            NodeGenericODE2(
                referenceCoordinates=[0.0] * n,
                initialCoordinates=[0.0] * n,
                initialCoordinates_t=[0.0] * n,
                numberOfODE2Coordinates=n,
            )
        )
        self._kt = mbs.AddObject(
            ObjectKinematicTree(
                nodeNumber=self._node,
                jointTypes=[exu.JointType.RevoluteZ] * n,
                linkParents=list(range(-1, n - 1)),
                jointHTs=self._joint_hts(),
                linkInertiasCOM=exu.Matrix3DList([inertias[i] for i in range(n)]),
                linkCOMs=exu.Vector3DList([coms[i] for i in range(n)]),
                linkMasses=list(masses),
                jointForceVector=[0.0] * n,
                gravity=[0.0, 0.0, 0.0],
            )
        )
        self._sens_p = []
        self._sens_r = []
        for i in range(n):
            for lst, ovt in (
                (self._sens_p, exu.OutputVariableType.Position),
                (self._sens_r, exu.OutputVariableType.RotationMatrix),
            ):
                lst.append(
                    mbs.AddSensor(
                        SensorKinematicTree(
                            objectNumber=self._kt,
                            linkNumber=i,
                            localPosition=[0.0, 0.0, 0.0],
                            outputVariableType=ovt,
                            writeToFile=False,
                            storeInternal=False,
                        )
                    )
                )
        self._sens_tool = mbs.AddSensor(
            SensorKinematicTree(
                objectNumber=self._kt,
                linkNumber=n - 1,
                localPosition=list(self._tool_local()),
                outputVariableType=exu.OutputVariableType.Position,
                writeToFile=False,
                storeInternal=False,
            )
        )
        mbs.SetPreStepUserFunction(self._prestep)
        mbs.Assemble()
        self._mbs = mbs

    def _joint_hts(self):
        exu = _exudyn()
        pre_R, pre_p = self._mech[0], self._mech[1]
        out = []
        for i in range(self.n):
            T = np.eye(4)
            T[:3, :3] = pre_R[i]
            T[:3, 3] = pre_p[i]
            out.append(exu.HT(T) if hasattr(exu, "HT") else T)
        return out

    def _tool_local(self) -> np.ndarray:
        s = self.package.spec
        lk = s.links[-1]
        L = self.values[f"link{self.n}.length"]
        return rot_rpy(lk.rpy) @ (np.array([L, 0, 0]) + _vec(lk.final) + _vec(s.tool_translation))

    def _update_mechanics(self) -> None:
        exu = _exudyn()
        self._mech = self.package.chain_arrays(self.values)
        pre_R, pre_p, masses, coms, inertias = self._mech
        mbs = self._mbs
        mbs.SetObjectParameter(self._kt, "jointHTs", self._joint_hts())
        mbs.SetObjectParameter(self._kt, "linkMasses", list(masses))
        mbs.SetObjectParameter(self._kt, "linkCOMs", exu.Vector3DList([coms[i] for i in range(self.n)]))
        mbs.SetObjectParameter(
            self._kt, "linkInertiasCOM", exu.Matrix3DList([inertias[i] for i in range(self.n)])
        )
        mbs.SetSensorParameter(self._sens_tool, "localPosition", list(self._tool_local()))

    # ---- API ----
    def set_values(self, values: Mapping[str, float]) -> None:
        if self._running:
            self._finalize()  # parameters change between runs: a run in progress ends here
        merged = dict(self.values)
        merged.update(values)
        full = self.package.check_values(merged)
        mech_changed = any(full[k] != self.values[k] for k in full if k.startswith(MECH_PREFIXES))
        self.values = full
        self.P[:] = self.package.drive_array(full)  # in place: no rebuild
        if mech_changed:
            self._update_mechanics()  # Exudyn item parameters: no rebuild either
        self.X, self.hold = init_states(self.P, self.q0)

    def set_initial(self, q: Sequence[float], qd: Sequence[float] | None = None) -> None:
        """Joint positions at rest -> every internal state; `qd` (extension) is for drives-off studies."""
        q = _vec(q)
        if q.shape != (self.n,) or not np.all(np.isfinite(q)):
            raise ValueError(f"expected {self.n} finite joint positions")
        for i, lk in enumerate(self._desc.links):
            if not lk.joint_min - 1e-12 <= q[i] <= lk.joint_max + 1e-12:
                raise ValueError(f"{lk.joint}: {q[i]:g} rad outside [{lk.joint_min:g}, {lk.joint_max:g}]")
        self.q0 = q.copy()
        self.qd0 = np.zeros(self.n) if qd is None else _vec(qd).copy()
        self.X, self.hold = init_states(self.P, self.q0)
        self.seg = np.zeros((0, 3 + 2 * self.n))

    def set_joint_path(self, nodes: Sequence[tuple[Sequence[float], float, float]]) -> None:
        parsed = []
        for k, node in enumerate(nodes):
            try:
                dest, sp, ac = node
            except (TypeError, ValueError):
                raise ValueError(f"path node {k}: expected (joint vector, speed %, acc %)") from None
            dest = _vec(dest)
            if dest.shape != (self.n,) or not np.all(np.isfinite(dest)):
                raise ValueError(f"path node {k}: expected {self.n} finite joint positions")
            for i, lk in enumerate(self._desc.links):
                if not lk.joint_min <= dest[i] <= lk.joint_max:
                    raise ValueError(
                        f"path node {k}: {lk.joint} {dest[i]:g} rad outside "
                        f"[{lk.joint_min:g}, {lk.joint_max:g}]"
                    )
            for what, v in (("speed", sp), ("acc", ac)):
                if isinstance(v, bool) or not (isinstance(v, numbers.Real) and 0 < float(v) <= 100):
                    raise ValueError(f"path node {k}: {what} % must be in (0, 100], got {v!r}")
            parsed.append((dest, float(sp), float(ac)))
        self._nodes = parsed
        t0 = self._time if self._running else 0.0
        self.seg = self._plan(t0)

    def _plan(self, t0: float) -> np.ndarray:
        vmax = self.P[:, dr.P_VMAX]
        amax = self.P[:, dr.P_AMAX]
        if self._running:
            qr = np.empty(self.n)
            qdr = np.empty(self.n)
            dr.traj_eval(self.seg, self.hold, t0, qr, qdr)
            self.hold = qr.copy()
            q = qr
        else:
            q = self.hold.copy()
        rows = []
        t = t0
        for dest, sp, ac in self._nodes:
            # destinations are load angles; the set point is expressed in measured (resolver) angles
            dest_m = dest + self.P[:, dr.P_EL] * np.sin(dest)
            row = dr.plan_segment(q, dest_m, vmax * sp / 100.0, amax * ac / 100.0, t)
            rows.append(row)
            t += row[1]
            q = dest_m
        return np.array(rows) if rows else np.zeros((0, 3 + 2 * self.n))

    def path_duration(self) -> float:
        if self.seg.shape[0] == 0:
            return 0.0
        return float(self.seg[-1, 0] + self.seg[-1, 1] - (self.seg[0, 0]))

    def start(
        self, stop_time: float, output_interval: float, step: float | None = None, substeps: int | None = None
    ) -> None:
        """Begin a run at t = 0 from the initial state; `step` = Exudyn mechanics step (None: model default),
        `substeps` = drive RK4 substeps per mechanics step (None: model default)."""
        exu = _exudyn()
        h = float(step) if step is not None else self.package.spec.default_step
        if not (math.isfinite(stop_time) and stop_time > 0):
            raise ValueError("stop_time must be > 0")
        if not (1e-6 <= h <= 0.01):
            raise ValueError("step must be in [1e-6, 0.01] s")
        if not (math.isfinite(output_interval) and output_interval > 0):
            raise ValueError("output_interval must be > 0")
        if self._running:
            self._finalize()
        self.h = h
        self.k_out = max(1, int(round(output_interval / h)))
        self.dt_out = self.k_out * h
        self._stop_time = float(stop_time)
        self.n_steps = int(math.ceil(stop_time / h - 1e-9))
        self.nsub = int(substeps) if substeps else self.package.spec.substeps
        ss = exu.SimulationSettings()
        ss.timeIntegration.numberOfSteps = self.n_steps
        ss.timeIntegration.endTime = self.n_steps * h
        ss.timeIntegration.startTime = 0.0
        ss.timeIntegration.solverType = exu.DynamicSolverType.RK44
        # fixed steps: Exudyn takes t = startTime + i*h instead of summing (and clipping) the steps, so
        # every step is exactly h, wherever a chunk ends; advance() sets startTime per chunk
        ss.timeIntegration.adaptiveStep = False
        ss.timeIntegration.verboseMode = 0
        ss.timeIntegration.explicit.computeEndOfStepAccelerations = False
        ss.solution.file.write = False
        ss.solution.sensors.writePeriod = 1e9
        self._ss = ss
        mbs = self._mbs
        mbs.SetObjectParameter(self._kt, "jointForceVector", [0.0] * self.n)
        mbs.systemData.SetODE2Coordinates(list(self.q0), configuration=exu.ConfigurationType.Initial)
        mbs.systemData.SetODE2Coordinates_t(list(self.qd0), configuration=exu.ConfigurationType.Initial)
        self.X, self.hold = init_states(self.P, self.q0)
        self._nodes_copy = list(self._nodes)
        self.seg = self._plan(0.0) if self._nodes else np.zeros((0, 3 + 2 * self.n))
        self._Xbak = self.X.copy()
        self._last_k = -1
        self._tau = np.zeros(self.n)
        self._work = np.zeros((5, self.n, dr.NL))
        self._fail: str | None = None
        self._drives_on = self.values["drives.enabled"] > 0.5
        self._mech_arrays = self._mech
        self._tool_loc = self._tool_local()
        self._solver = exu.MainSolverExplicit()
        self._solver.InitializeSolver(mbs, ss)
        self._it = self._solver.it
        self._sd = mbs.systemData
        self._running = True
        self._time = 0.0
        self._k_next = 0  # index of the next output sample; its time is _t_next
        self._t_next = 0.0
        self.timing = {"mechanics+drive": 0.0, "drive": 0.0, "output": 0.0}

    def _prestep(self, mbs, t: float) -> bool:
        """Once per mechanics step, before it: the output row at the step start when one is due, then
        the drives over the step. Exudyn passes the time at the END of the coming step."""
        h = self._it.currentStepSize
        ts = t - h  # the step start: the chain state and the drive states are those of ts
        due = ts >= self._t_next - 0.5 * self.h
        if not (due or self._drives_on):
            return True
        t0 = _time.perf_counter()
        out0 = self.timing["output"]
        sd = self._sd
        q = sd.GetODE2Coordinates()
        qd = sd.GetODE2Coordinates_t()
        if due:
            if ts > self._t_next + 0.5 * self.h:
                self._fail = f"output sample at t = {self._t_next:.6f} s missed (step at {ts:.6f} s)"
                return False
            if not self._emit_row(q, qd):
                return False
        if not self._drives_on:
            return True
        k = round(ts / self.h)  # the step index: the drive time comes from the grid, not from a sum
        repeat = k <= self._last_k  # the same step again (a step reduction): restore the drive states
        self._last_k = k
        m = self._mech_arrays
        ok = dr.drive_prestep(
            self.P,
            self.seg,
            self.hold,
            m[0],
            m[1],
            m[2],
            m[3],
            m[4],
            self.X,
            self._Xbak,
            repeat,
            q,
            qd,
            k * self.h,
            h,
            self.nsub,
            self._tau,
            self._work,
        )
        if not ok:
            bad = [j + 1 for j in range(self.n) if not np.all(np.isfinite(self.X[j, : dr.NS]))]
            self._fail = f"drive states of joint(s) {bad or '?'} not finite at t = {ts:.6f} s"
            return False
        mbs.SetObjectParameter(self._kt, "jointForceVector", self._tau)
        self.timing["drive"] += _time.perf_counter() - t0 - (self.timing["output"] - out0)
        return True

    def _emit_row(self, q, qd) -> bool:
        """The output row of sample `_k_next` (time `_t_next`) from the chain state q, qd and the drive
        states into the chunk buffer; False (with `_fail` set) when something is not finite."""
        t0 = _time.perf_counter()
        t = self._t_next
        k = self._nrows
        if k >= self._rows.shape[0]:  # never with the size advance() reserves; kept safe anyway
            self._rows = np.concatenate([self._rows, np.empty((k + 8, self._rows.shape[1]))])
        m = self._mech_arrays
        status = dr.output_row(
            self.P,
            self.seg,
            self.hold,
            self.X,
            q,
            qd,
            t,
            m[0],
            m[1],
            self._Rrpy,
            self._tool_loc,
            self._rows,
            k,
        )
        if status:
            if status == 1:
                bad = [j + 1 for j in range(self.n) if not (math.isfinite(q[j]) and math.isfinite(qd[j]))]
                self._fail = f"chain coordinates of joint(s) {bad} not finite at t = {t:.6f} s"
            else:
                self._fail = f"non-finite output at t = {t:.6f} s"
            return False
        self._nrows = k + 1
        self._k_next += 1
        self._t_next = min(self._k_next * self.dt_out, self.n_steps * self.h)
        self.timing["output"] += _time.perf_counter() - t0
        return True

    def _row_now(self) -> None:
        """The due output row from the current chain state (between solver calls)."""
        sd = self._sd
        if not self._emit_row(sd.GetODE2Coordinates(), sd.GetODE2Coordinates_t()):
            raise SimulationError(self._fail)

    def _sensor_poses(self) -> np.ndarray:
        """Link and tool poses now, read from the Exudyn sensors: the cross-check of `dr.pose_rows`."""
        mbs = self._mbs
        n = self.n
        Rs = np.zeros((n + 1, 3, 3))
        out = np.zeros((n + 1, 7))
        for i in range(n):
            out[i, :3] = mbs.GetSensorValues(self._sens_p[i])
            Rs[i] = np.asarray(mbs.GetSensorValues(self._sens_r[i])).reshape(3, 3) @ self._Rrpy[i]
        Rs[n] = Rs[n - 1]
        out[n, :3] = mbs.GetSensorValues(self._sens_tool)
        quats = np.zeros((n + 1, 4))
        dr.quats_from_matrices(Rs, quats)
        out[:, 3:] = quats
        return out

    def advance(self, until: float) -> np.ndarray:
        """Simulate up to `until` (on the step grid); the output rows with time in (previous until, until],
        the t = 0 row on the first call. One solver call per chunk: the rows inside the chunk are taken
        in the PreStep at the start of the step that begins at their time."""
        if not self._running:
            raise SimulationError("advance() before start()")
        t_wall = _time.perf_counter()
        out_before = self.timing["output"]
        h = self.h
        t_end = self.n_steps * h
        until = float(until)
        if until >= self._stop_time - 1e-12:
            until = t_end  # the run ends on the step grid, at or just after stop_time
        until = min(until, t_end)
        n_max = int(max(until - self._time, 0.0) / self.dt_out) + 3
        self._rows = np.empty((n_max, len(self.columns)))
        self._nrows = 0
        if self._k_next == 0:
            self._row_now()  # t = 0
        # the chunk ends on the last grid point within `until`; at an output sample, exactly on its time
        t_mid = math.floor(until / h + 1e-9) * h
        t_row = t_end if t_mid > t_end - 0.5 * h else round(t_mid / self.dt_out) * self.dt_out
        row_end = abs(t_row - t_mid) < 0.5 * h and t_row > self._time + 0.5 * h
        t_stop = t_row if row_end else t_mid
        if t_stop > self._time + 0.5 * h:
            self._it.startTime = self._time
            self._it.endTime = t_stop
            try:
                self._solver.SolveSteps(self._mbs, self._ss)
            except Exception as e:  # the solver's own errors
                raise SimulationError(f"Exudyn solver failed before t = {t_stop:.6f} s: {e}") from e
            if self._fail:
                raise SimulationError(self._fail)
            t_now = self._sd.GetTime()
            if t_now < t_stop - 1e-9:
                raise SimulationError(f"Exudyn stopped at t = {t_now:.6f} s before {t_stop:.6f} s")
            self._time = t_stop  # the grid time (Exudyn's startTime + i*h may differ by rounding)
            if row_end:
                if abs(self._t_next - t_stop) > 0.5 * h:
                    raise SimulationError(f"output sample at t = {self._t_next:.6f} s missed")
                self._row_now()
        out = self._rows[: self._nrows]
        wall = _time.perf_counter() - t_wall
        self.timing["mechanics+drive"] += wall - (self.timing["output"] - out_before)
        return out

    @property
    def time(self) -> float:
        return self._time

    @property
    def finished(self) -> bool:
        return self._running and self._time >= self.n_steps * self.h - 1e-9

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Chain coordinates (q, qd) now."""
        mbs = self._mbs
        return np.array(mbs.systemData.GetODE2Coordinates()), np.array(mbs.systemData.GetODE2Coordinates_t())

    def mass_matrix(self, q: Sequence[float]) -> np.ndarray:
        M = np.zeros((self.n, self.n))
        pre_R, pre_p, masses, coms, inertias = self._mech
        dr.mass_matrix(pre_R, pre_p, masses, coms, inertias, _vec(q), M)
        return M

    def _finalize(self) -> None:
        if self._solver is not None and self._running:
            try:
                self._solver.FinalizeSolver(self._mbs, self._ss)
            except Exception:
                pass
        self._running = False

    def close(self) -> None:
        self._finalize()
        self._solver = None
        self._mbs = None
        self._SC = None


def _quat(m: np.ndarray) -> np.ndarray:
    from simecs.mesh.kinematics import quat_from_matrix

    return quat_from_matrix(m)


_EXU = None


def _exudyn():
    global _EXU
    if _EXU is None:
        if "exudyn" not in sys.modules:
            sys.exudynFast = True  # the faster build, without range checks (STACK-NOTES)
        import exudyn

        _EXU = exudyn
    return _EXU
