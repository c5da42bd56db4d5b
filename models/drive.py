"""The compiled drive train: motor electrics, current loop, gear box, cascade control, trajectory.

Each joint's signals and state derivatives at one instant (`drive_rhs`), which drive_integrator.py
integrates over a mechanics step, and the variables a run reports (`drive_outputs`); the set points
come from references.py. See docs/MODELS.md, "Coupling".

Per-joint parameters live in a float array P[joint, k] with the indices below; per-joint states in
X[joint, k]. The order of `DRIVE_PARAMS` is the contract between this file and the descriptions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .jit import CACHE as _CACHE
from .jit import FAST as _FAST
from .references import JM_CURRENT, JM_SPEED, LV_EXTERNAL, LV_GRAVITY, LV_IREF, ref_eval

# ---- per-joint parameter layout -------------------------------------------------------------------
DRIVE_PARAMS = (
    "motor.R",
    "motor.L",
    "motor.kt",
    "motor.pole_pairs",
    "motor.J_rotor",
    "motor.b_visc",
    "motor.detent",
    "motor.unbalance",
    "motor.shape_h3",
    "motor.i_max",
    "motor.u_max",
    "motor.ideal",
    "current.kp",
    "current.ki",
    "current.offset_a",
    "current.offset_b",
    "current.rotor_frame",
    "gear.ratio",
    "gear.efficiency",
    "gear.J_gear",
    "gear.stiffness",
    "gear.damping",
    "gear.backlash",
    "gear.fc",
    "gear.fs",
    "gear.vs",
    "gear.sigma0",
    "gear.sigma1",
    "gear.sigma2",
    "resolver.motor_error",
    "resolver.load_error",
    "ctrl.kp_pos",
    "ctrl.kp_vel",
    "ctrl.ki_vel",
    "ctrl.ff_vel",
    "ctrl.ff_gravity",
    "ctrl.twist_damping",
    "traj.max_speed",
    "traj.max_acc",
)
PI = {name: k for k, name in enumerate(DRIVE_PARAMS)}
NP = len(DRIVE_PARAMS)
(
    P_R,
    P_L,
    P_KT,
    P_POLES,
    P_JR,
    P_BM,
    P_DET,
    P_UNB,
    P_H3,
    P_IMAX,
    P_UMAX,
    P_IDEAL,
    P_KPI,
    P_KII,
    P_OFFA,
    P_OFFB,
    P_FOC,
    P_N,
    P_ETA,
    P_JG,
    P_K,
    P_D,
    P_BL,
    P_FC,
    P_FS,
    P_VS,
    P_S0,
    P_S1,
    P_S2,
    P_EM,
    P_EL,
    P_KPP,
    P_KPV,
    P_KIV,
    P_FF,
    P_FFG,
    P_TWD,
    P_VMAX,
    P_AMAX,
) = range(NP)

# ---- per-joint persistent states --------------------------------------------------------------------
STATES = ("theta_m", "omega_m", "i_a", "i_b", "x_a", "x_b", "x_v", "z")
NS = len(STATES)
S_TH, S_OM, S_IA, S_IB, S_XA, S_XB, S_XV, S_Z = range(NS)
# local (per step) states appended for integration: load angle, load speed, gear-torque impulse
NL = NS + 3
S_QL, S_QDL, S_IMP = NS, NS + 1, NS + 2

# ---- per-joint outputs (the variable catalog order per joint) ----------------------------------------
OUTPUTS = (
    "q",
    "qd",
    "q_ref",
    "qd_ref",
    "q_motor",
    "qd_motor",
    "i_ref",
    "i_a",
    "i_b",
    "u_a",
    "tau_motor",
    "tau_friction",
    "tau_gear",
    "twist",
)
NO = len(OUTPUTS)
#: The tool's outputs after every joint's (the variable catalog's order): the tool position of the
#: joint set points (the task-space reference) and the tool's distance and turn from it.
TOOL_OUTPUTS = ("x_ref", "y_ref", "z_ref", "e_pos", "e_rot")
NT = len(TOOL_OUTPUTS)

EFF_POWER_EPS = 1e-2  # W: width of the smooth switch between driving and driven efficiency


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def _sat(x, lim):
    if x > lim:
        return lim
    if x < -lim:
        return -lim
    return x


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def resting_gear_factor(eta):
    """tau_in / (tau_gear / n) of a gear at rest: the efficiency's smooth switch (joint_signals) is
    halfway between driving (1/eta) and driven (eta) when no power flows. The motor torque that holds a
    static load tau is tau / n times this (init_states, the gravity feed-forward)."""
    return 0.5 * (eta + 1.0 / eta)


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def phase_shapes(h3, s1, c1):
    """(s_a, s_b): the phases' shape functions at electrical angle th_e (s1 = sin, c1 = cos), each with
    a 3rd harmonic h3; phase b is phase a shifted by 90 degrees electrical, so with balanced phases the
    shape error gives a torque ripple at 4x th_e (1 - h3 cos 4 th_e), apart from the unbalance's 2x."""
    s3 = 3.0 * s1 - 4.0 * s1 * s1 * s1  # sin 3 th_e
    c3 = 4.0 * c1 * c1 * c1 - 3.0 * c1  # cos 3 th_e
    return -(s1 + h3 * s3), c1 - h3 * c3


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def gear_torque(P, j, theta_m, omega_m, ql, qdl):
    n = P[j, P_N]
    d = theta_m / n - ql
    dd = omega_m / n - qdl
    b = 0.5 * P[j, P_BL]
    if b <= 0.0:
        return P[j, P_K] * d + P[j, P_D] * dd
    if d > b:
        e = d - b
    elif d < -b:
        e = d + b
    else:
        return 0.0
    tau = P[j, P_K] * e + P[j, P_D] * dd
    if tau * e < 0.0:  # a backlash contact pushes, it never pulls
        return 0.0
    return tau


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def motor_resolver(P, j, th, om):
    """(angle, speed) the motor resolver reads: its error is em*sin(p*theta) (mechanical rad)."""
    em = P[j, P_EM]
    if em == 0.0:
        return th, om
    p = P[j, P_POLES]
    return th + em * math.sin(p * th), om * (1.0 + em * p * math.cos(p * th))


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def load_resolver(P, j, ql, qdl):
    """(angle, speed) the load resolver reads: its error is el*sin(q)."""
    el = P[j, P_EL]
    if el == 0.0:
        return ql, qdl
    return ql + el * math.sin(ql), qdl * (1.0 + el * math.cos(ql))


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def joint_signals(P, j, X, ql, qdl, qr, qdr, mode, i_ff, out):
    """All algebraic signals of joint j; fills out[0..NO) in OUTPUTS order and returns nothing.

    `mode` (JM_*) says what qr, qdr are: position and speed set points (JM_POSITION, JM_HOLD), a
    speed set point in qdr with the position loop bypassed (JM_SPEED), or the current amplitude set
    point in qr with the position and speed loops bypassed (JM_CURRENT, the speed integrator frozen).
    i_ff: a current fed forward past the speed loop (the gravity feed-forward), not in JM_CURRENT.

    Extra slots: out[NO] = u_b, out[NO+1] = d x_v/dt, out[NO+2] = d x_a/dt, out[NO+3] = d x_b/dt,
    out[NO+4] = z_dot, out[NO+5] = tau_in (gear reaction at motor shaft), out[NO+6] = tau_detent.
    """
    th = X[j, S_TH]
    om = X[j, S_OM]
    n = P[j, P_N]
    p = P[j, P_POLES]
    te = p * th
    s1 = math.sin(te)
    c1 = math.cos(te)
    # resolvers
    th_meas, om_meas = motor_resolver(P, j, th, om)
    if th_meas != th:
        sm = math.sin(p * th_meas)
        cm = math.cos(p * th_meas)
    else:
        sm = s1
        cm = c1
    q_meas = load_resolver(P, j, ql, qdl)[0]
    # cascade joint control: P position (load side), PI motor speed with anti-windup and feed-forward
    if mode == JM_CURRENT:
        iref = _sat(qr, P[j, P_IMAX])
        dxv = 0.0
    else:
        if mode == JM_SPEED:
            w_ref = n * qdr
        else:
            w_ref = n * (P[j, P_KPP] * (qr - q_meas) + P[j, P_FF] * qdr)
        ev = w_ref - om_meas
        kpv = P[j, P_KPV]
        kiv = P[j, P_KIV]
        iu = kpv * ev + X[j, S_XV] + i_ff
        iref = _sat(iu, P[j, P_IMAX])
        dxv = 0.0
        if kiv > 0.0:
            dxv = kiv * ev
            if kpv > 0.0:
                dxv += (kiv / kpv) * (iref - iu)
    # commutation from the motor resolver
    ia_s = -iref * sm
    ib_s = iref * cm
    # motor shape functions (true rotor angle), phase unbalance
    sa, sb = phase_shapes(P[j, P_H3], s1, c1)
    kt = P[j, P_KT]
    ka = kt * (1.0 - 0.5 * P[j, P_UNB])
    kb = kt * (1.0 + 0.5 * P[j, P_UNB])
    emf_a = ka * sa * om
    emf_b = kb * sb * om
    if P[j, P_IDEAL] > 0.5:
        ia = ia_s
        ib = ib_s
        ua = P[j, P_R] * ia + emf_a
        ub = P[j, P_R] * ib + emf_b
        dxa = 0.0
        dxb = 0.0
    else:
        ia = X[j, S_IA]
        ib = X[j, S_IB]
        kpi = P[j, P_KPI]
        kii = P[j, P_KII]
        umax = P[j, P_UMAX]
        ea = ia_s - (ia + P[j, P_OFFA])
        eb = ib_s - (ib + P[j, P_OFFB])
        if P[j, P_FOC] > 0.5:
            # field-oriented: the PIs act on the errors in the rotor's frame (d, q at the resolver's
            # electrical angle), where the set points are constant at any speed; x_a, x_b hold u_d, u_q
            ed = ea * cm + eb * sm
            eq = -ea * sm + eb * cm
            # decoupling and back-EMF feed-forward from the measured currents and speed, as servo
            # drives do: the PIs then only correct what the motor model misses
            ma = ia + P[j, P_OFFA]
            mb = ib + P[j, P_OFFB]
            wl = p * om_meas * P[j, P_L]
            udu = kpi * ed + X[j, S_XA] - wl * (-ma * sm + mb * cm)
            uqu = kpi * eq + X[j, S_XB] + wl * (ma * cm + mb * sm) + kt * om_meas
            ua = _sat(udu * cm - uqu * sm, umax)
            ub = _sat(udu * sm + uqu * cm, umax)
            dxa = kii * ed + (kii / kpi) * (ua * cm + ub * sm - udu)
            dxb = kii * eq + (kii / kpi) * (-ua * sm + ub * cm - uqu)
        else:  # one PI per phase in the stationary frame (the paper's analog loops)
            uau = kpi * ea + X[j, S_XA]
            ubu = kpi * eb + X[j, S_XB]
            ua = _sat(uau, umax)
            ub = _sat(ubu, umax)
            dxa = kii * ea + (kii / kpi) * (ua - uau)
            dxb = kii * eb + (kii / kpi) * (ub - ubu)
    tau_em = ka * sa * ia + kb * sb * ib
    tau_det = P[j, P_DET] * 4.0 * s1 * c1 * (c1 * c1 - s1 * s1)  # T_det sin(4 p th)
    # LuGre friction at the gear input
    fc = P[j, P_FC]
    fs = P[j, P_FS]
    z = X[j, S_Z]
    if fc > 0.0 or fs > 0.0:
        vs = P[j, P_VS]
        g = fc + (fs - fc) * math.exp(-((om / vs) ** 2))
        zd = om - P[j, P_S0] * abs(om) * z / g
        tau_f = P[j, P_S0] * z + P[j, P_S1] * zd + P[j, P_S2] * om
    else:
        zd = 0.0
        tau_f = P[j, P_S2] * om
    # gear: elastic with backlash, efficiency depending on the power flow, ideal reducer
    tau_g = gear_torque(P, j, th, om, ql, qdl)
    eta = P[j, P_ETA]
    sw = 0.5 * (1.0 + math.tanh(tau_g * om / n / EFF_POWER_EPS))
    f = eta + (1.0 / eta - eta) * sw
    tau_in = tau_g / n * f
    out[0] = ql
    out[1] = qdl
    out[2] = qr
    out[3] = qdr
    out[4] = th
    out[5] = om
    out[6] = iref
    out[7] = ia
    out[8] = ib
    out[9] = ua
    out[10] = tau_em + tau_det
    out[11] = tau_f
    out[12] = tau_g
    out[13] = th / n - ql
    out[NO] = ub
    out[NO + 1] = dxv
    out[NO + 2] = dxa
    out[NO + 3] = dxb
    out[NO + 4] = zd
    out[NO + 5] = tau_in
    out[NO + 6] = tau_det
    out[NO + 7] = emf_a
    out[NO + 8] = emf_b


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def controlled_signals(P, j, X, ql, qdl, qr, qdr, sp, out):
    """`joint_signals` of joint j under whichever controller has it: the built-in cascade in the
    command's mode, or an external controller's current set point (live[j, LV_IREF]), in which
    case out[2], out[3] keep the command's set points (what the controller was sent). `sp`: the
    set points (references.SetPointArrays)."""
    live = sp.live
    external = live[j, LV_EXTERNAL] > 0.5
    if external:
        a, b, mode = live[j, LV_IREF], 0.0, JM_CURRENT
    else:
        a, b, mode = qr, qdr, sp.jmode[j]
    # one call: its body is inlined here, and compiling it twice doubled the kernels' compile time
    joint_signals(P, j, X, ql, qdl, a, b, mode, live[j, LV_GRAVITY], out)
    if external:
        out[2] = qr
        out[3] = qdr


@njit(cache=_CACHE, inline="always", error_model="numpy", fastmath=_FAST)
def drive_rhs(P, sp, Minv, bias, tc, t, X, dX, sig, qr, qdr, tau, new_t=True):
    """dX = f(t, X), the load accelerating with M^-1 (tau_gear + tc - bias), tc the contacts' torques
    at X (`contact_stage`); the set points qr, qdr are evaluated at t unless `new_t` is False (same t
    as the previous call: RK4 stages 2 and 3)."""
    n = X.shape[0]
    if new_t:
        ref_eval(sp, t, qr, qdr)
    for j in range(n):  # X[j, k], not a row view X[j]: a view costs reference counting in a hot loop
        controlled_signals(P, j, X, X[j, S_QL], X[j, S_QDL], qr[j], qdr[j], sp, sig)
        om = X[j, S_OM]
        dX[j, S_TH] = om
        jm = P[j, P_JR] + P[j, P_JG]
        dX[j, S_OM] = (sig[10] - P[j, P_BM] * om - sig[11] - sig[NO + 5]) / jm
        if P[j, P_IDEAL] > 0.5:
            dX[j, S_IA] = 0.0
            dX[j, S_IB] = 0.0
        else:
            L = P[j, P_L]
            R = P[j, P_R]
            dX[j, S_IA] = (sig[9] - R * X[j, S_IA] - sig[NO + 7]) / L
            dX[j, S_IB] = (sig[NO] - R * X[j, S_IB] - sig[NO + 8]) / L
        dX[j, S_XA] = sig[NO + 2]
        dX[j, S_XB] = sig[NO + 3]
        dX[j, S_XV] = sig[NO + 1]
        dX[j, S_Z] = sig[NO + 4]
        dX[j, S_QL] = X[j, S_QDL]
        dX[j, S_IMP] = sig[12]
        tau[j] = sig[12]
    for j in range(n):
        acc = 0.0
        for k in range(n):
            acc += Minv[j, k] * (tau[k] + tc[k] - bias[k])
        dX[j, S_QDL] = acc


@njit(cache=_CACHE, error_model="numpy", fastmath=_FAST)
def drive_outputs(P, sp, X, q, qd, t, out):
    """Variables of every joint at time t from the drive states and the chain state: out[j, :NO]."""
    n = q.shape[0]
    qr = np.empty(n)
    qdr = np.empty(n)
    ref_eval(sp, t, qr, qdr)
    sig = np.empty(NO + 10)
    for j in range(n):
        controlled_signals(P, j, X, q[j], qd[j], qr[j], qdr[j], sp, sig)
        for k in range(NO):
            out[j, k] = sig[k]
        if (
            sp.jmode[j] == JM_CURRENT and sp.live[j, LV_EXTERNAL] <= 0.5
        ):  # q_ref, qd_ref: the position set point the current replaced
            out[j, 2] = sp.hold[j]
            out[j, 3] = 0.0
