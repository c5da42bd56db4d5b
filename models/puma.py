"""PUMA 560 from `exudyn.robotics.models` with the same drive family (proves "any manipulator").

The standard DH rows [theta, d, a, alpha] convert to the Link convention exactly: initial rotation
Rx(alpha) (no component about the joint axis), central translation a along x, final translation
(0, d sin(alpha), d cos(alpha)). Masses, COMs and inertias come from the DH link frame (at the end of
the link), shifted to the Link frame (at the joint); gravity is off like the Spider's.
"""

from __future__ import annotations

import math

import numpy as np

from .drives_catalog import size_class
from .spec import ArmSpec, LinkSpec, Vec3

BIG = size_class(
    R=0.6,
    L=1.2e-3,
    kt=0.2,
    poles=4,
    J_rotor=2e-4,
    ratio=100,
    J_gear=5e-5,
    stiffness=6.6e4,
    damping=100.0,
    backlash=5e-5,
    fc=0.03,
    i_max=8.0,
    load_inertia=5.0,
    max_speed=1.5,
    max_acc=3.0,
    detent=3e-3,
    kp_pos=8.0,
)
WRIST = size_class(
    R=1.6,
    L=1.0e-3,
    kt=0.05,
    poles=4,
    J_rotor=3e-5,
    ratio=70,
    J_gear=5e-6,
    stiffness=2e3,
    damping=2.0,
    backlash=1e-4,
    fc=0.004,
    i_max=4.0,
    load_inertia=0.05,
    max_speed=2.5,
    max_acc=5.0,
    detent=5e-4,
    kp_pos=10.0,
    efficiency=0.8,
)


def _vec3(v: np.ndarray) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


def _links() -> list[LinkSpec]:
    """The PUMA's DH rows and link data converted to the Link convention (see the module docstring)."""
    from exudyn.robotics.models import ManipulatorPuma560

    robot = ManipulatorPuma560()
    out = []
    for i, lk in enumerate(robot["links"]):
        theta, d, a, alpha = (float(v) for v in lk["stdDH"])
        assert theta == 0.0
        final = (0.0, d * math.sin(alpha), d * math.cos(alpha))
        shift = np.array([a, 0.0, 0.0]) + np.array(final)
        com = _vec3(np.asarray(lk["COM"], float) + shift)
        inertia = _vec3(np.diag(np.asarray(lk["inertia"], float)))
        lo, hi = (float(v) for v in lk["jointLimits"])
        out.append(
            LinkSpec(
                name=f"link{i + 1}",
                rpy=(alpha, 0.0, 0.0),
                length=a,
                final=final,
                joint_min=lo,
                joint_max=hi,
                mass=float(lk["mass"]),
                radius=0.06 if i < 3 else 0.035,
                drive="big" if i < 3 else "wrist",
                length_max=1.5,
                com=com,
                inertia=inertia,
                color=(210, 200, 180),
            )
        )
    return out


ASSUMPTIONS = """\
Kinematics, masses, COMs and inertias: `exudyn.robotics.models.ManipulatorPuma560` (Corke). Gravity
is off (the drive family and the comparison with the Spider matter here, not the PUMA's gravity load).
Drives are the Spider family resized: joints 1-3 kt 0.2 N m/A, n = 100, gear stiffness 6.6e4 N m/rad
(KIM1995 values of the exudyn model); wrist kt 0.05 N m/A, n = 70, 2e3 N m/rad. Link lengths follow
the DH `a`; the link tubes' inertias are the model's, so a changed length moves the next joints but
does not change the tabulated inertias.
"""


def spec() -> ArmSpec:
    """The PUMA 560's spec (a new one per call)."""
    return ArmSpec(
        id="puma560",
        name="PUMA 560 (joint-independent control)",
        summary="6-joint industrial arm from exudyn.robotics.models with the Spider drive family "
        "(two-phase motors, current loops, elastic gears, P/PI cascade), zero gravity",
        links=_links(),
        drives={"big": BIG, "wrist": WRIST},
        tool_translation=(0.0, 0.0, 0.05),
        payload_mass=1.0,
        payload_size=0.08,
        default_step=1e-3,
        substeps=5,
        assumptions=ASSUMPTIONS,
        chain_doc="Standard DH rows of the PUMA 560 converted to the Link convention (see the summary).",
        standard_target=(0.5, -0.5, 0.6, 0.5, 0.7, 0.5),
    )
