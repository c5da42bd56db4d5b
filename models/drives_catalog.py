"""Drive parameter sets (per size class) with units, descriptions and bounds.

Values are assumptions for a ~2 m, 7-joint space manipulator driven by frameless two-phase brushless
motors through harmonic-drive-like reducers; docs/MODELS.md lists the reasoning.
"""

from __future__ import annotations

import math
from typing import Any

from .drive import DRIVE_PARAMS
from .spec import ParamInfo

# (unit, description, min, max, integer)
META = {
    "motor.R": ("ohm", "phase resistance", 0.01, 100.0, False),
    "motor.L": ("H", "phase inductance", 1e-5, 0.1, False),
    "motor.kt": ("N*m/A", "torque constant (= back-EMF constant, V*s/rad) per phase", 1e-3, 5.0, False),
    "motor.pole_pairs": ("-", "pole pairs p (electrical angle = p * rotor angle)", 1, 50, True),
    "motor.J_rotor": ("kg*m^2", "rotor inertia", 1e-7, 1e-2, False),
    "motor.b_visc": ("N*m*s/rad", "motor viscous friction", 0.0, 1e-2, False),
    "motor.detent": (
        "N*m",
        "detent (cogging) torque amplitude, 4p periods per turn, present at zero current",
        0.0,
        0.5,
        False,
    ),
    "motor.unbalance": (
        "-",
        "relative torque-constant unbalance between the phases (ripple at 2x electrical frequency)",
        0.0,
        0.5,
        False,
    ),
    "motor.shape_h3": (
        "-",
        "3rd-harmonic content of the phase shape functions (ripple at 4x electrical frequency)",
        0.0,
        0.3,
        False,
    ),
    "motor.i_max": ("A", "current amplitude limit of the speed controller output", 0.1, 100.0, False),
    "motor.u_max": ("V", "phase voltage limit of the current amplifier", 1.0, 600.0, False),
    "motor.ideal": (
        "-",
        "1: ideal motor, phase currents equal their set points (no electrics, no offsets)",
        0,
        1,
        True,
    ),
    "current.kp": ("V/A", "proportional gain of each phase PI current regulator", 0.0, 1000.0, False),
    "current.ki": (
        "V/(A*s)",
        "integral gain of each phase PI current regulator (anti-windup by "
        "back-calculation, tracking time kp/ki)",
        0.0,
        1e6,
        False,
    ),
    "current.offset_a": ("A", "current sensor offset of phase A (sensor polarisation)", -1.0, 1.0, False),
    "current.offset_b": ("A", "current sensor offset of phase B (sensor polarisation)", -1.0, 1.0, False),
    "current.rotor_frame": (
        "-",
        "1: the current PIs act in the rotor's frame (field-oriented control: torque per ampere kept at "
        "speed); 0: one PI per phase in the stationary frame (the paper's analog loops, which lag the "
        "phase currents at high electrical frequency)",
        0.0,
        1.0,
        True,
    ),
    "gear.ratio": ("-", "reduction ratio n (motor angle = n * load angle)", 1.0, 1000.0, False),
    "gear.efficiency": ("-", "mechanical efficiency (applied on the power flow direction)", 0.3, 1.0, False),
    "gear.J_gear": ("kg*m^2", "gear train inertia referred to the input (motor) shaft", 0.0, 1e-2, False),
    "gear.stiffness": ("N*m/rad", "torsion stiffness at the output", 10.0, 1e8, False),
    "gear.damping": ("N*m*s/rad", "torsion damping at the output", 0.0, 1e5, False),
    "gear.backlash": ("rad", "total backlash at the output (dead zone of width b)", 0.0, 0.05, False),
    "gear.fc": ("N*m", "LuGre Coulomb friction at the input shaft", 0.0, 10.0, False),
    "gear.fs": ("N*m", "LuGre static (stiction) friction at the input shaft", 0.0, 10.0, False),
    "gear.vs": ("rad/s", "LuGre Stribeck speed (input shaft)", 1e-3, 100.0, False),
    "gear.sigma0": ("N*m/rad", "LuGre bristle stiffness", 1e-3, 1e6, False),
    "gear.sigma1": ("N*m*s/rad", "LuGre bristle damping", 0.0, 100.0, False),
    "gear.sigma2": ("N*m*s/rad", "LuGre viscous friction (input shaft)", 0.0, 1.0, False),
    "resolver.motor_error": (
        "rad",
        "motor resolver error amplitude (one period per electrical turn)",
        0.0,
        0.05,
        False,
    ),
    "resolver.load_error": ("rad", "load resolver error amplitude (one period per turn)", 0.0, 0.01, False),
    "ctrl.kp_pos": (
        "1/s",
        "outer loop: proportional gain of the joint position loop (load resolver)",
        0.0,
        1000.0,
        False,
    ),
    "ctrl.kp_vel": ("A*s/rad", "inner loop: proportional gain of the motor speed PI", 0.0, 100.0, False),
    "ctrl.ki_vel": (
        "A/rad",
        "inner loop: integral gain of the motor speed PI (0: P only; anti-windup by back-calculation)",
        0.0,
        1e4,
        False,
    ),
    "ctrl.ff_vel": ("-", "velocity feed-forward weight (0..1) of the trajectory speed", 0.0, 1.0, False),
    "ctrl.ff_gravity": (
        "-",
        "gravity feed-forward weight (0..1): the share of the model's gravity torque at the set point "
        "the controller adds (0: the position and speed loops alone carry the arm's weight)",
        0.0,
        1.0,
        False,
    ),
    "ctrl.twist_damping": (
        "-",
        "operational-space laws: damping ratio they give the motor's mode on its elastic gear, from the "
        "gear's twist rate the joint's two resolvers read (0: none)",
        0.0,
        2.0,
        False,
    ),
    "traj.max_speed": ("rad/s", "maximum joint speed (100 % of a path node's speed)", 1e-3, 10.0, False),
    "traj.max_acc": (
        "rad/s^2",
        "maximum joint acceleration (100 % of a path node's acceleration)",
        1e-3,
        100.0,
        False,
    ),
}


def drive_table(**values: float) -> dict[str, ParamInfo]:
    """Every drive parameter (`motor_R=...`: the dotted name with "_") with its unit, text and bounds."""
    out = {}
    for name in DRIVE_PARAMS:
        unit, desc, lo, hi, integer = META[name]
        out[name] = ParamInfo(
            value=float(values[name.replace(".", "_")]),
            unit=unit,
            description=desc,
            min=float(lo),
            max=float(hi),
            integer=integer,
        )
    return out


def size_class(
    *,
    R: float,
    L: float,
    kt: float,
    poles: int,
    J_rotor: float,
    ratio: float,
    J_gear: float,
    stiffness: float,
    damping: float,
    backlash: float,
    fc: float,
    i_max: float,
    max_speed: float,
    max_acc: float,
    efficiency: float = 0.85,
    detent: float = 0.0,
    current_bw_hz: float = 400.0,
    speed_bw: float = 600.0,
    kp_pos: float = 5.0,
    u_max: float = 48.0,
    offset_a: float = 0.0,
    offset_b: float = 0.0,
    current_frame: str = "rotor",
    twist_damping: float = 0.3,
) -> dict[str, ParamInfo]:
    """A drive from a few design quantities; controller gains follow documented tuning rules.

    Current PI: pole-zero cancellation, kp = L*wc, ki = R*wc with wc = 2 pi current_bw_hz.
    Speed PI: kp_vel = speed_bw * J_motor_side / kt (rotor-only crossover speed_bw rad/s), integral
    corner at 10 rad/s. LuGre bristles: 10 mrad presliding at the input (fc / sigma0).
    """
    wc = 2 * math.pi * current_bw_hz
    jm = J_rotor + J_gear
    kp_vel = speed_bw * jm / kt
    sigma0 = fc / 0.01 if fc > 0 else 1.0
    return drive_table(
        motor_R=R,
        motor_L=L,
        motor_kt=kt,
        motor_pole_pairs=poles,
        motor_J_rotor=J_rotor,
        motor_b_visc=J_rotor * 0.3,
        motor_detent=detent,
        motor_unbalance=0.02,
        motor_shape_h3=0.01,
        motor_i_max=i_max,
        motor_u_max=u_max,
        motor_ideal=0,
        current_kp=L * wc,
        current_ki=R * wc,
        current_offset_a=offset_a,
        current_offset_b=offset_b,
        current_rotor_frame=1 if current_frame == "rotor" else 0,
        gear_ratio=ratio,
        gear_efficiency=efficiency,
        gear_J_gear=J_gear,
        gear_stiffness=stiffness,
        gear_damping=damping,
        gear_backlash=backlash,
        gear_fc=fc,
        gear_fs=1.5 * fc,
        gear_vs=2.0,
        gear_sigma0=sigma0,
        gear_sigma1=2 * math.sqrt(sigma0 * jm),
        gear_sigma2=0.005 * fc if fc > 0 else 0.0,
        resolver_motor_error=0.0,
        resolver_load_error=0.0,
        ctrl_kp_pos=kp_pos,
        ctrl_kp_vel=kp_vel,
        ctrl_ki_vel=10.0 * kp_vel,
        ctrl_ff_vel=1.0,
        ctrl_ff_gravity=1.0,
        ctrl_twist_damping=twist_damping,
        traj_max_speed=max_speed,
        traj_max_acc=max_acc,
    )


#: The sizing rule's choices (docs/MODELS.md, "Drives sized from a URDF's limits").
TOP_MOTOR_SPEED = 300.0  # rad/s of the motor at the joint's URDF velocity limit (about 2900 rpm)
RATIO_RANGE = (20.0, 200.0)


def size_for_limits(effort: float, velocity: float, u_max: float = 48.0) -> dict[str, Any]:
    """`size_class` arguments for a joint that must give `effort` N m at up to `velocity` rad/s (a
    URDF's <limit>): a documented rule, so an imported model runs before its modeller tunes it.

    The gear turns the velocity limit into TOP_MOTOR_SPEED; the motor's back-EMF at that speed is half
    the bus (kt); its peak current gives `effort` through the gear (i_max); a quarter of the bus drops
    over the winding at peak current (R) with a 1 ms electrical time constant (L); rotor inertia,
    friction and cogging scale with the peak motor torque, gear stiffness with `effort` (800 N m/rad per
    N m, harmonic-drive class), like the Spider's drives.
    """
    if not (effort > 0 and velocity > 0):
        raise ValueError("the sizing rule needs a positive effort and velocity limit")
    ratio = float(min(max(round(TOP_MOTOR_SPEED / velocity), RATIO_RANGE[0]), RATIO_RANGE[1]))
    efficiency = 0.85 if effort >= 20.0 else 0.8
    tau_motor = effort / (ratio * efficiency)
    kt = 0.5 * u_max / (ratio * velocity)
    i_max = tau_motor / kt
    R = 0.25 * u_max / i_max
    J_rotor = 8e-5 * tau_motor
    stiffness = 800.0 * effort
    return {
        "R": R,
        "L": R * 1e-3,
        "kt": kt,
        "poles": 4,
        "J_rotor": J_rotor,
        "ratio": ratio,
        "J_gear": 0.3 * J_rotor,
        "stiffness": stiffness,
        "damping": 7e-4 * stiffness,
        "backlash": 1e-4,
        "fc": 0.03 * tau_motor,
        "i_max": i_max,
        "max_speed": velocity,
        "max_acc": 2.0 * velocity,
        "efficiency": efficiency,
        "detent": 0.005 * tau_motor,
        "kp_pos": 8.0,
        "u_max": u_max,
    }
