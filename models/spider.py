"""The Spider arm (SIMECS-RI §5.1): 7 revolute joints, zero gravity, joint-independent control."""

from __future__ import annotations

import math

from simecs.mesh.model import Shape

from .drives_catalog import size_class
from .spec import ArmSpec, LinkSpec

H = math.pi / 2

# Drive sizes. Large: shoulder/elbow (joints 1-4); small: wrist (joints 5-7).
LARGE = size_class(
    R=1.2,
    L=1.5e-3,
    kt=0.12,
    poles=8,
    J_rotor=6e-5,
    ratio=160,
    J_gear=2e-5,
    stiffness=8e4,
    damping=60.0,
    backlash=1e-4,
    fc=0.02,
    i_max=6.0,
    load_inertia=30.0,
    max_speed=0.35,
    max_acc=0.7,
    detent=4e-3,
    kp_pos=5.0,
    offset_a=0.01,
    offset_b=-0.005,
)
SMALL = size_class(
    R=2.0,
    L=1.2e-3,
    kt=0.06,
    poles=6,
    J_rotor=1.5e-5,
    ratio=100,
    J_gear=5e-6,
    stiffness=1.5e4,
    damping=10.0,
    backlash=1.5e-4,
    fc=0.008,
    i_max=4.0,
    load_inertia=1.0,
    max_speed=0.5,
    max_acc=1.0,
    detent=2e-3,
    efficiency=0.8,
    kp_pos=6.0,
    offset_a=0.005,
    offset_b=0.005,
)

LINKS = [
    # shoulder roll: the column rises along the joint-1 axis; joint 2 axis horizontal
    LinkSpec(
        name="link1",
        rpy=(0.0, -H, 0.0),
        length=0.30,
        final=(0.0, 0.0, 0.0),
        joint_min=-math.pi,
        joint_max=math.pi,
        mass=9.0,
        radius=0.075,
        drive="large",
        color=(200, 205, 215),
    ),
    # shoulder pitch: short offset block; joint 3 axis across it
    LinkSpec(
        name="link2",
        rpy=(-H, 0.0, 0.0),
        length=0.12,
        final=(0.0, 0.0, 0.0),
        joint_min=-2.6,
        joint_max=2.6,
        mass=6.0,
        radius=0.075,
        drive="large",
    ),
    # upper arm: rolls about joint 3, i.e. about its own axis
    LinkSpec(
        name="link3",
        rpy=(0.0, -H, 0.0),
        length=0.70,
        final=(0.0, 0.0, 0.0),
        joint_min=-math.pi,
        joint_max=math.pi,
        mass=8.0,
        radius=0.06,
        drive="large",
        color=(235, 235, 240),
    ),
    # elbow pitch block
    LinkSpec(
        name="link4",
        rpy=(H, 0.0, 0.0),
        length=0.12,
        final=(0.0, 0.0, 0.0),
        joint_min=-2.6,
        joint_max=2.6,
        mass=5.0,
        radius=0.06,
        drive="large",
    ),
    # forearm: rolls about joint 5
    LinkSpec(
        name="link5",
        rpy=(0.0, -H, 0.0),
        length=0.65,
        final=(0.0, 0.0, 0.0),
        joint_min=-math.pi,
        joint_max=math.pi,
        mass=6.0,
        radius=0.05,
        drive="small",
        color=(235, 235, 240),
    ),
    # wrist pitch block
    LinkSpec(
        name="link6",
        rpy=(H, 0.0, 0.0),
        length=0.10,
        final=(0.0, 0.0, 0.0),
        joint_min=-2.2,
        joint_max=2.2,
        mass=3.5,
        radius=0.05,
        drive="small",
    ),
    # wrist roll and tool flange
    LinkSpec(
        name="link7",
        rpy=(0.0, -H, 0.0),
        length=0.15,
        final=(0.0, 0.0, 0.0),
        joint_min=-math.pi,
        joint_max=math.pi,
        mass=2.5,
        radius=0.045,
        drive="small",
        color=(180, 185, 195),
    ),
]

# the standard case of `simecs bench model`: from all joints at zero to this target, 100 % / 100 %
STANDARD_TARGET = (0.8, 0.6, -0.7, 1.0, 0.9, -0.8, 1.2)

ASSUMPTIONS = """\
The Spider of the paper is a 7-joint space arm; its real data are not public, so the values here are
assumptions for a ~2 m arm (reach 2.14 m, arm mass 40 kg) operating in zero gravity:

- **Links**: carbon/aluminium tubes modelled as thin-walled cylinders (inner radius 0.8 r) whose mass
  includes the next joint housing; COM at mid-length. Masses 2.5-9 kg, radii 45-75 mm.
- **Payload**: 5 kg homogeneous cube (0.2 m) at the tool point by default (0-500 kg allowed).
- **Motors**: frameless two-phase brushless motors, 48 V bus. Large (joints 1-4): kt 0.12 N m/A,
  R 1.2 ohm, L 1.5 mH, rotor 6e-5 kg m^2, 8 pole pairs, 6 A. Small (joints 5-7): kt 0.06 N m/A,
  R 2 ohm, L 1.2 mH, rotor 1.5e-5 kg m^2, 6 pole pairs, 4 A. Detent torque 2-4 mN m, phase unbalance 2 %,
  3rd-harmonic shape error 1 %, current-sensor offsets of 5-10 mA.
- **Gears**: harmonic-drive class reducers. Large: n = 160, efficiency 0.85, stiffness 8e4 N m/rad,
  backlash 0.1 mrad; small: n = 100, efficiency 0.8, stiffness 1.5e4 N m/rad, backlash 0.15 mrad.
  LuGre friction at the input: Coulomb 20 / 8 mN m, stiction 1.5x, Stribeck speed 2 rad/s,
  bristles with 10 mrad presliding at the motor (0.06-0.1 mrad at the joint).
- **Control**: analog current loops of 400 Hz bandwidth (pole-zero cancellation), motor-speed PI with
  a 600 rad/s rotor-only crossover and a 10 rad/s integral corner, joint-position P of 5-6 1/s,
  full velocity feed-forward.
- **Trajectory**: max joint speeds 0.35 rad/s (large) and 0.5 rad/s (small), accelerations 0.7 and
  1.0 rad/s^2: slow, as space arms are.
- **Sensors**: ideal resolvers unless their error amplitudes are set.
"""

CHAIN_DOC = """\
Alternating roll and pitch joints (S-R-S-like): joint 1 rolls the shoulder column about the base z axis,
joint 2 pitches, joint 3 rolls the upper arm about its own axis, joint 4 is the elbow, joint 5 rolls the
forearm, joint 6 pitches the wrist, joint 7 rolls the tool. Roll links use the initial rotation
Ry(-pi/2) so the link axis x lies on the joint axis; pitch blocks use Rx(+-pi/2) so the next joint axis
is perpendicular to the previous one. No final translations. At q = 0 the shoulder column rises 0.42 m along
the base z axis, the upper arm (0.7 m) lies along +y, the forearm (0.65 m) along -x, and the tool
points up along +z: the arm is folded in a horizontal L, clear of the floor.
"""


def spec() -> ArmSpec:
    """The Spider's spec (a new one per call)."""
    return ArmSpec(
        id="spider",
        name="Spider arm (joint-independent control)",
        summary="7-joint ~2 m space manipulator in zero gravity: two-phase brushless motors, analog current "
        "loops, elastic gears with LuGre friction and backlash, P/PI cascade, trapezoid trajectories",
        links=LINKS,
        drives={"large": LARGE, "small": SMALL},
        base_translation=(0.0, 0.0, 0.0),
        tool_translation=(0.1, 0.0, 0.0),
        payload_mass=5.0,
        payload_size=0.2,
        default_step=1e-3,
        substeps=5,
        assumptions=ASSUMPTIONS,
        chain_doc=CHAIN_DOC,
        standard_target=STANDARD_TARGET,
        environment=[
            Shape("cylinder", -1, [0.0, 0.0, -0.25], "z", length=0.25, radius=0.15, color=[120, 120, 130]),
            Shape("box", -1, [-1.5, 0.0, -0.27], "x", length=3.0, width=3.0, height=0.04, color=[70, 75, 90]),
        ],
    )
