"""Hypertext documentation of an arm model: components, sub-components, connections, equations, constants.

Pages link to each other with `doc:<id>` markdown links. Constants tables are generated from the
parameter defaults, so the documentation never disagrees with the model.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from simecs.mesh.protocol.model import DocPage, InitEquation, Parameter

from . import drive as dr
from .spec import ArmSpec

SUBS = {
    "motor": (
        "Brushless two-phase motor",
        """Electrical dynamics of both phases, electro-mechanical conversion with torque disturbances,
rotor inertia and viscous friction. Electrical angle `th_e = p * q_m`.

Shape functions (3rd-harmonic imperfection h3) and phase constants (unbalance d):

    s_a = -(sin th_e + h3 sin 3 th_e)        s_b = cos th_e - h3 cos 3 th_e   (s_a shifted by 90 deg)
    k_a = kt (1 - d/2)                        k_b = kt (1 + d/2)

Phase equations (back-EMF e = k s w_m, power-consistent with the torque):

    L di_a/dt = u_a - R i_a - k_a s_a w_m
    L di_b/dt = u_b - R i_b - k_b s_b w_m

Torque: `tau_motor = k_a s_a i_a + k_b s_b i_b + T_det sin(4 p q_m)`: the unbalance gives a ripple at
2x and the shape error at 4x the electrical frequency; the detent term exists at zero current.

Rotor (with the gear train inertia of doc:{id}.gear on the same shaft):

    (J_rotor + J_gear) dw_m/dt = tau_motor - b_visc w_m - tau_friction - tau_in

With `motor.ideal = 1` the phase currents equal their set points (no electrics, no offsets).
Connections: voltages from doc:{id}.current, angle to doc:{id}.resolver, shaft to doc:{id}.gear.""",
    ),
    "current": (
        "Current controller",
        """Two PI regulators with anti-windup by back-calculation and a current offset that models sensor
polarisation. Set points come from the commutation of the speed controller output:

    i_a* = -i_ref sin(p q_m')     i_b* = i_ref cos(p q_m')     (q_m': motor resolver angle)
    e_x = i_x* - (i_x + offset_x)

`current.rotor_frame` = 0, the paper's analog loops: one PI per phase, in the stationary frame,

    u_x = sat(kp e_x + x_x, u_max)
    dx_x/dt = ki e_x + (ki/kp) (u_x - (kp e_x + x_x))

Their set points are sinusoids at the electrical frequency p w_m, which the PIs follow with a lag
that grows with speed: the torque per ampere falls when the motor turns fast (about 0.2-0.7 of kt at
the rated speed).

`current.rotor_frame` = 1, field-oriented control as servo drives do it: the errors turned into the
rotor's frame (d along the magnet, q across it) at the resolver's angle th = p q_m', where the set
points are constant (d* = 0, q* = i_ref) at any speed, one PI per axis, with the cross-coupling and
back-EMF fed forward from the measured currents and speed, the voltages turned back:

    e_d = e_a cos th + e_b sin th       e_q = -e_a sin th + e_b cos th
    u_d = kp e_d + x_d - p w_m' L i_q'  u_q = kp e_q + x_q + p w_m' L i_d' + kt w_m'
    u_a, u_b = sat(u_d cos th - u_q sin th, u_max), sat(u_d sin th + u_q cos th, u_max)

The torque per ampere stays within a few % of kt up to the rated speed (tests/test_current_loop.py).

Default gains cancel the electrical pole: kp = L wc, ki = R wc (wc: current-loop bandwidth).
An offset makes the true current differ from the set point: a torque disturbance at the motor.""",
    ),
    "gear": (
        "Gear box",
        """Input shaft (motor side) -> LuGre friction -> efficiency -> ideal reducer n -> torsion spring
and damper with backlash -> output (load side). Gear train inertia is referred to the input shaft.

LuGre friction (input shaft speed w = w_m):

    g(w) = fc + (fs - fc) exp(-(w/vs)^2)
    dz/dt = w - sigma0 |w| z / g(w)
    tau_friction = sigma0 z + sigma1 dz/dt + sigma2 w

Twist and elastic torque with backlash b (dead zone |twist| <= b/2, contact only pushes):

    twist = q_m / n - q
    e = twist - b/2 (twist > b/2),  twist + b/2 (twist < -b/2),  else no contact
    tau_gear = K e + D d(twist)/dt  in contact, and 0 if it would pull

Efficiency on the power flow: the motor sees `tau_in = tau_gear / n * f`, f = 1/eta when the motor
drives the load, eta when the load drives the motor (smooth switch over 10 mW). tau_gear acts on the
chain joint (doc:{id}.chain).""",
    ),
    "resolver": (
        "Resolvers",
        """One resolver at the motor, one at the load. Optional periodic errors:

    q_m' = q_m + e_m sin(p q_m)          w_m' = w_m (1 + e_m p cos(p q_m))
    q'   = q + e_l sin(q)

q' closes the position loop, q_m' commutates the phases and w_m' closes the speed loop. The controller
knows only what its resolvers read: at rest after a move to q_ref the load resolver reads q_ref, so
the arm stands at q with q + e_l sin(q) = q_ref, about e_l sin(q_ref) short of the command.""",
    ),
    "ctrl": (
        "Cascade joint controller",
        """Outer P position loop on the load resolver, inner PI motor-speed loop with anti-windup and
velocity feed-forward:

    w_ref = n (kp_pos (q_ref - q') + ff_vel qd_ref)
    e_v = w_ref - w_m'
    i_g = ff_gravity g_j(q_ref) f / (n kt),   f = (eta + 1/eta) / 2
    i_ref = sat(kp_vel e_v + x_v + i_g, i_max)
    dx_v/dt = ki_vel e_v + (ki_vel/kp_vel) (i_ref - (kp_vel e_v + x_v + i_g))

i_g is the model-based gravity feed-forward: the current whose motor torque holds the joint's gravity
torque g_j at the set points (the model's own chain and gravity, renewed every step); ff_gravity = 0
leaves the arm's weight to the loops, which let it sag until the integrator has caught up.
i_ref goes to the commutation of doc:{id}.current. With ki_vel = 0 a constant disturbance torque
tau_d at the joint (at the gear's output) leaves a position error tau_d / (kt n kp_vel n kp_pos).""",
    ),
    "traj": (
        "Trajectory generator",
        """Joint-space trapezoidal speed profiles. A path is a list of nodes (destination, speed %,
acceleration %); every node is executed, one after the other, stopping at each. Per segment with
distances d_j and limits V_j = max_speed_j * speed%, A_j = max_acc_j * acc%:

    t_a = max_j min(V_j / A_j, sqrt(d_j / A_j))
    T - t_a = max(t_a, max_j d_j / V_j, max_j d_j / (A_j t_a))

All joints share t_a and T (synchronised), none exceeds its limits. The profile gives q_ref and the
feed-forward speed qd_ref.""",
    ),
}


def _const_table(n: int, by: dict[str, Parameter], sub: str) -> str:
    """The constants of one sub-component, one column per joint, from the parameter defaults."""
    names = [nm for nm in dr.DRIVE_PARAMS if nm.startswith(sub + ".")]
    joints = " | ".join(f"j{i}" for i in range(1, n + 1))
    head = f"| parameter | unit | {joints} | bounds | description |"
    sep = "|" + "---|" * (n + 4)
    rows = [head, sep]
    for nm in names:
        ps = [by[f"joint{i}.{nm}"] for i in range(1, n + 1)]
        vals = " | ".join(f"{p.value:.4g}" for p in ps)
        rows.append(
            f"| {nm} | {ps[0].unit} | {vals} | [{ps[0].min:g}, {ps[0].max:g}] | {ps[0].description} |"
        )
    return "\n".join(rows)


def gravity_text(g: Sequence[float]) -> str:
    """The gravity vector as a reader wants it: its size and direction, or "zero gravity"."""
    norm = math.sqrt(sum(x * x for x in g))
    if norm == 0.0:
        return "zero gravity"
    return f"{norm:g} m/s^2 along ({', '.join(f'{x / norm:.3g}' for x in g)})"


def build_docs(
    s: ArmSpec, parameters: Sequence[Parameter], init_equations: Sequence[InitEquation]
) -> list[DocPage]:
    """Every page of the model's docs, from its spec, its parameters (constants tables) and its
    initialisation equations: what the client receives, so nothing here needs the simulator."""
    mid = s.id
    n = len(s.links)
    by = {p.name: p for p in parameters}
    pages: list[DocPage] = []
    sub_ids = [f"{mid}.{k}" for k in SUBS]
    children = [
        f"{mid}.chain",
        f"{mid}.joint",
        f"{mid}.payload",
        f"{mid}.control",
        f"{mid}.init",
        f"{mid}.numerics",
        f"{mid}.assumptions",
    ]
    target = ", ".join(f"{v:g}" for v in s.standard_target)
    pages.append(
        DocPage(
            mid,
            s.name,
            f"""# {s.name}

{s.summary}.

## Components
- [Mechanical chain](doc:{mid}.chain): {n} revolute joints, links in the Link convention, Exudyn
  KinematicTree.
- [Joint drive](doc:{mid}.joint), one per joint: [motor](doc:{mid}.motor),
  [current controller](doc:{mid}.current), [gear box](doc:{mid}.gear),
  [resolvers](doc:{mid}.resolver), [cascade controller](doc:{mid}.ctrl),
  [trajectory generator](doc:{mid}.traj).
- [Payload](doc:{mid}.payload) at the tool.
- [Control systems](doc:{mid}.control): joint-independent control (each joint's cascade) or
  operational-space motion control (the tool tracked in task space), chosen per run.

## Using it
- [Initialisation equations](doc:{mid}.init): joint positions at rest -> every internal state.
- [Numerics](doc:{mid}.numerics): how Exudyn and the compiled drives are coupled; steps and errors.
- [Assumptions](doc:{mid}.assumptions) behind the parameter values.

Standard case (`simecs bench model`): from q = 0 to q = ({target}) rad at 100 % speed and acceleration.
""",
            children=children,
        )
    )
    link_rows = [
        "| link | initial rotation rpy (rad) | length (m) | final translation (m) | mass (kg) "
        "| joint range (rad) |",
        "|---|---|---|---|---|---|",
    ]
    for i, lk in enumerate(s.links, start=1):
        link_rows.append(
            f"| link{i} | ({lk.rpy[0]:.3f}, {lk.rpy[1]:.3f}, {lk.rpy[2]:.3f}) | {lk.length:g} | "
            f"({lk.final[0]:g}, {lk.final[1]:g}, {lk.final[2]:g}) | {lk.mass:g} | [{lk.joint_min:.3f}, "
            f"{lk.joint_max:.3f}] |"
        )
    pages.append(
        DocPage(
            f"{mid}.chain",
            "Mechanical chain",
            f"""# Mechanical chain

Link convention (paper §5.1): joint i turns about the local z axis by q_i; link i then applies an
**initial rotation** (roll-pitch-yaw, none about the joint axis), a **central translation** along x equal
to the link length (`linkN.length`), and a **final translation** without x component. The link frame
sits at the joint, x along the link; shapes hang on it, and one pipe per link is resized with the length.

{s.chain_doc}

{chr(10).join(link_rows)}

Base at {list(s.base_translation)}, tool point {list(s.tool_translation)} in the last link's frame after
its final translation. Gravity: {gravity_text(s.gravity)} (the `gravity.*` parameters).

Equations of motion (Exudyn ObjectKinematicTree, minimal coordinates q):

    M(q) q'' + c(q, q') = tau_gear

with tau_gear from the [gear boxes](doc:{mid}.gear). Link inertias: `linkN.mass`, `linkN.radius`
(thin-walled tube, COM at mid-length, unless the model tabulates them). Back to [{s.name}](doc:{mid}).
""",
            parent=mid,
        )
    )
    pages.append(
        DocPage(
            f"{mid}.joint",
            "Joint drive",
            f"""# Joint drive

Connections (signal flow of one joint):

    trajectory -> q_ref, qd_ref -> cascade controller (P position on q', PI speed on w_m') -> i_ref
    i_ref -> commutation (q_m') -> current controller (two PI) -> phase voltages u_a, u_b
    u_a, u_b -> motor electrics -> currents -> torque -> rotor shaft
    rotor shaft -> gear box (LuGre, efficiency, reducer n, spring/damper/backlash) -> chain joint q
    resolvers: motor (q_m', w_m') and load (q')

Sub-components: [motor](doc:{mid}.motor), [current controller](doc:{mid}.current),
[gear box](doc:{mid}.gear), [resolvers](doc:{mid}.resolver), [controller](doc:{mid}.ctrl),
[trajectory](doc:{mid}.traj). Parameters are per joint (`jointN.<sub>.<name>`), so one joint can be tuned
alone. States per joint: q_m, w_m, i_a, i_b, two current integrators, speed integrator, LuGre z.
""",
            parent=mid,
            children=sub_ids,
        )
    )
    for key, (title, body) in SUBS.items():
        pages.append(
            DocPage(
                f"{mid}.{key}",
                title,
                f"# {title}\n\n{body.format(id=mid)}\n\n## Constants\n\n{_const_table(n, by, key)}\n\n"
                f"Part of the [joint drive](doc:{mid}.joint).\n",
                parent=f"{mid}.joint",
            )
        )
    pages.append(
        DocPage(
            f"{mid}.payload",
            "Payload",
            f"""# Payload

A homogeneous cube of mass `payload.mass` and edge `payload.size`, centred on the tool point and rigidly
attached to the last link (its inertia m a^2/6 about every axis is added to that link's).
Default {s.payload_mass:g} kg, {s.payload_size:g} m. Back to [{s.name}](doc:{mid}).
""",
            parent=mid,
        )
    )
    gain_rows = ["| parameter | default | unit | what it does |", "|---|---|---|---|"]
    for p in parameters:
        if p.component == "control":
            gain_rows.append(f"| `{p.name}` | {p.value:g} | {p.unit} | {p.description} |")
    pages.append(
        DocPage(
            f"{mid}.control",
            "Control systems",
            f"""# Control systems

A run chooses its motion control system (paper §5) in its settings, `control_system`; the mechanics
and the drives stay the same, only what computes each joint's current set point changes.

- **joint_independent** (default): each joint's [cascade controller](doc:{mid}.ctrl) (P position on the
  load resolver, PI motor speed, velocity feed-forward) follows that joint's set point; the joints do
  not know of each other.
- **opspace_motion**: one digital controller for the whole arm, updated every `control_period`
  (default 1 ms, zero-order hold), reads every load resolver and computes every joint's current set
  point by task-space inverse dynamics at the tool:

      a     = xdd_r + kp e + kd (xd_r - J qd) + ki int(e)     (position and orientation rows)
      tau   = J^T Lambda (a - Jdot qd) + posture in the null space + velocity terms
      i_ref = (tau / n + friction feed-forward) / kt

  with Lambda = (J M^-1 J^T)^-1 from the chain's mass matrix plus each rotor reflected through its
  reducer. The tool's reference is the tool pose of the command's joint set points: a `lin` move is
  tracked as its straight line, a joint move as the curve its joints draw. On an arm with more than
  six joints the remaining freedom follows the planner's joint set points (the posture task), without
  disturbing the tool. The speed and position loops of the cascade are bypassed; the current loops,
  motors, friction, backlash and elastic gears are the same as under joint-independent control.
  Direct input of currents or speeds needs joint_independent (the proxy refuses the run).
- **opspace_hybrid**: the same controller, with force control along an axis (paper §5's hybrid
  force/motion control): where a Cartesian node sets a `force` (N) along its `force_axis`, the motion
  law is replaced along that axis by a force law on the contact force the tool feels (what a force
  sensor at the tool reads), and the force wanted is fed forward; along the other directions and in
  orientation the tool follows its path as under opspace_motion:

      a_n   = kf_force (f - f_meas) + ki_force int(f - f_meas) - kd_force (n . v)
      F     = Lambda (S' a + n a_n - Jdot qd) + n f           (S' = I - n n^T on the position rows)

  so the tool slides along a surface pressing on it with f (its measured normal force is the
  variable `contact.tool_fn`). The force integral runs only while the tool touches.

Both operational-space laws act on the link side, where the motor ringing on its elastic gear is not
seen (the link held, as in contact); each joint's current set point is damped against it from the
gear's twist rate its two resolvers read, with k the gear's stiffness:

    i_ref <- i_ref - d (w_m' - n qd') / kt,   d = 2 ctrl.twist_damping sqrt(k / n^2 (J_rotor + J_gear))

All three report the tool against its reference: `tool.x_ref`, `tool.y_ref`, `tool.z_ref`, `tool.e_pos`
(m) and `tool.e_rot` (rad), so runs of one command under two systems compare directly.

## Gains

{chr(10).join(gain_rows)}

Back to [{s.name}](doc:{mid}).
""",
            parent=mid,
        )
    )
    eqs = "\n".join(f"- `{e.state} = {e.expression}`: {e.description}" for e in init_equations)
    pages.append(
        DocPage(
            f"{mid}.init",
            "Initialisation equations",
            f"""# Initialisation equations

The user only chooses joint positions of a robot at rest (paper §5.2): the arm stands still there,
each gear carrying the joint's gravity torque tau_g = g(q) (none in zero gravity: the gear is untwisted
and centred in its backlash). The remaining unknowns follow from "every derivative is zero":

{eqs}

with, at the motor angle q_m (n q plus the gear's twist under load) and its resolver reading q_m'
(p pole pairs):

    A = -k_a s_a sin(p q_m') + k_b s_b cos(p q_m')
    B = -(k_a s_a offset_a + k_b s_b offset_b)
    tau_motor = A i_ref + B = tau_g f / n - T_det sin(4 p q_m)

so the load, the detent torque and the current-sensor offsets are held (by the gravity feed-forward
and the speed-loop integrator) from t = 0, and the run starts without transients. See
[the motor](doc:{mid}.motor) for s_a, s_b, k_a, k_b.
""",
            parent=mid,
        )
    )
    pages.append(
        DocPage(
            f"{mid}.numerics",
            "Numerics",
            f"""# Numerics

- **Exudyn** integrates the kinematic tree (ObjectKinematicTree, explicit RK4) with the mechanics step h
  (default {s.default_step * 1e3:g} ms, `step` of a run).
- A **PreStep** user function integrates the drives of all joints, compiled with numba, over [t, t+h]
  with {s.substeps} classical RK4 substeps (h/{s.substeps}), more at high motor speed where the LuGre
  friction stiffens: electrics, current loops, LuGre, gear, control, trajectory. Inside the step the load
  angles follow a predictor q'' = M(q(t))^-1 (tau_gear - C(q, q') q' - g(q)) (M and the Newton-Euler
  bias from the same link data as the Exudyn chain), which keeps the stiff gear stable; Exudyn then
  receives the mean gear torque over the step as `jointForceVector`. The next step starts again from
  Exudyn's q, q'.
- Output samples are taken every `output_interval` (rounded to a multiple of h): the state after the
  step that ends at the sample time, read inside the step loop (one Exudyn call per chunk of a run, so
  the output interval and the chunking change no result). Link poses come from q by the forward
  kinematics of the chain handed to Exudyn (checked against Exudyn's own sensors to 1e-9).
- A NaN in the drive or the chain stops the run with an error naming the joint and the time; so does a
  friction state past its physical bound (the step too coarse for the friction stiffness).
- Accuracy of the standard case: see `simecs bench model` and docs/MODELS.md.
""",
            parent=mid,
        )
    )
    pages.append(
        DocPage(f"{mid}.assumptions", "Assumptions", "# Assumptions\n\n" + s.assumptions, parent=mid)
    )
    return pages
