"""models/: the Spider drive train in Exudyn, validated by real simulation (no mocks)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from simecs.mesh.protocol.columns import GRASPED_FRAME, POSE_FIELDS, pose_column
from simecs.mesh.rules.kinematics import link_poses
from simecs.models import ParameterError, SimulationError, get_model, list_models
from simecs.models import drive as dr

Q0 = [0.3, -0.4, 0.5, 1.1, -0.6, 0.7, -0.2]


def run(sim, stop, out=0.01, step=None, substeps=None):
    sim.start(stop, out, step, substeps)
    rows = [sim.advance(0.0)]
    while not sim.finished:
        rows.append(sim.advance(sim.time + 0.25))
    return np.vstack(rows)


def col(sim, data, name):
    return data[:, sim.columns.index(name)]


@pytest.fixture(scope="module")
def spider():
    return get_model("spider")


# ---------------------------------------------------------------------------------------------------
def test_library_and_columns(spider):
    ids = [m.id for m in list_models()]
    assert "spider" in ids and "puma560" in ids
    with pytest.raises(KeyError, match="unknown model"):
        get_model("nope")
    d = spider.describe()
    sim = spider.build({})
    assert sim.columns[0] == "time"
    assert sim.columns[1 : 1 + len(d.variables)] == [v.name for v in d.variables]
    assert sim.columns[1 + len(d.variables) :] == d.pose_column_names()
    assert len(sim.units) == len(sim.columns)
    assert 10 <= len(d.variables) / len(d.links) <= 25  # per joint, the tool's, the contacts', the grasp's
    assert sim.columns[-7:] == [pose_column(GRASPED_FRAME, f) for f in POSE_FIELDS]
    sim.close()


def test_rest_without_command_stays_put_10s(spider):
    sim = spider.build({})
    sim.set_initial(Q0)
    data = run(sim, 10.0, out=0.1)
    q = np.stack([col(sim, data, f"joint{j}.q") for j in range(1, 8)], axis=1)
    assert data[-1, 0] == pytest.approx(10.0)
    assert np.max(np.abs(q - np.array(Q0))) < 1e-6
    sim.close()


def test_zero_initial_transients(spider):
    """Detent torque, sensor offsets, friction all on: the init equations hold every state still."""
    sim = spider.build({})
    sim.set_initial(Q0)
    data = run(sim, 0.5, out=0.001)
    for j in range(1, 8):
        for v in ("q", "q_motor", "i_a", "i_b", "i_ref", "u_a", "tau_motor", "tau_gear"):
            x = col(sim, data, f"joint{j}.{v}")
            assert np.max(np.abs(x - x[0])) <= 1e-9 * max(1.0, abs(x[0])), (j, v)
        assert abs(col(sim, data, f"joint{j}.qd")).max() < 1e-9
    # the motor sits at q_m = n q, and a non-zero current holds the detent torque
    n3 = sim.values["joint3.gear.ratio"]
    assert col(sim, data, "joint3.q_motor")[0] == pytest.approx(n3 * Q0[2])
    assert abs(col(sim, data, "joint3.i_ref")[0]) > 1e-4
    sim.close()


def test_single_joint_rigid_ideal_matches_second_order(spider):
    """Joint 1, gear ~rigid, ideal motor, no friction, P/P cascade: q'' = c (kp (q_r - q) - q')."""
    from scipy import signal

    j = "joint1"
    n, kt, kp = 160.0, 0.12, 5.0
    vals = {
        f"{j}.motor.ideal": 1,
        f"{j}.motor.detent": 0,
        f"{j}.motor.unbalance": 0,
        f"{j}.motor.shape_h3": 0,
        f"{j}.motor.b_visc": 0,
        f"{j}.motor.i_max": 100,
        f"{j}.gear.ratio": n,
        f"{j}.gear.efficiency": 1,
        f"{j}.gear.stiffness": 1e7,
        f"{j}.gear.damping": 2000,
        f"{j}.gear.backlash": 0,
        f"{j}.gear.fc": 0,
        f"{j}.gear.fs": 0,
        f"{j}.gear.sigma2": 0,
        f"{j}.ctrl.kp_pos": kp,
        f"{j}.ctrl.ki_vel": 0,
        f"{j}.ctrl.ff_vel": 0,
        f"{j}.current.offset_a": 0,
        f"{j}.current.offset_b": 0,
    }
    sim = spider.build(vals)
    q0 = np.array([0.0, 0.5, 0.0, 1.0, 0.0, 0.5, 0.0])
    M = sim.mass_matrix(q0)
    J = n * n * (sim.values[f"{j}.motor.J_rotor"] + sim.values[f"{j}.gear.J_gear"]) + M[0, 0]
    c = 2.0 * kp  # damping ratio 1/sqrt(2)
    kpv = c * J / (n * n * kt)
    sim.set_values({f"{j}.ctrl.kp_vel": kpv})
    sim.set_initial(q0)
    q1 = q0.copy()
    q1[0] = 0.2
    sim.set_joint_path([(q1, 100.0, 100.0)])
    data = run(sim, 3.0, out=0.001)
    t = data[:, 0]
    qr = col(sim, data, f"{j}.q_ref")
    q = col(sim, data, f"{j}.q")
    sys2 = signal.lti([c * kp], [1.0, c, c * kp])
    _, q_an, _ = signal.lsim(sys2, qr, t)
    err = np.max(np.abs(q - q_an)) / 0.2
    assert err < 0.01, err
    # and it is a real response: the lag is well above the tolerance
    assert np.max(np.abs(q - qr)) / 0.2 > 0.05
    sim.close()


def test_energy_drives_off_no_damping(spider):
    sim = spider.build({"drives.enabled": 0})
    qd0 = np.array([0.3, -0.2, 0.4, 0.3, -0.5, 0.6, 0.8])
    sim.set_initial(Q0, qd0)
    data = run(sim, 10.0, out=0.05)
    q = np.stack([col(sim, data, f"joint{j}.q") for j in range(1, 8)], axis=1)
    qd = np.stack([col(sim, data, f"joint{j}.qd") for j in range(1, 8)], axis=1)
    energy = np.array([0.5 * v @ sim.mass_matrix(x) @ v for x, v in zip(q, qd, strict=True)])
    assert np.ptp(q[:, 0]) > 1.0  # it really moved
    drift = np.max(np.abs(energy - energy[0])) / energy[0]
    assert drift < 1e-3, drift
    sim.close()


def test_move_settles_where_gains_predict(spider):
    """P/P speed loop (ki_vel = 0) with a current-sensor offset: a standing error set by the gains."""
    j = "joint4"
    off = 0.2
    vals = {
        f"{j}.ctrl.ki_vel": 0,
        f"{j}.current.offset_a": off,
        f"{j}.current.offset_b": 0,
        f"{j}.gear.fc": 0,
        f"{j}.gear.fs": 0,
        f"{j}.gear.backlash": 0,
        f"{j}.motor.detent": 0,
    }
    sim = spider.build(vals)
    sim.set_initial(Q0)
    target = np.array(Q0)
    target[3] = 0.8
    target[0] = 0.6  # a PI joint moving too: it settles on its target
    sim.set_joint_path([(target, 100.0, 100.0)])
    data = run(sim, sim.set_points.path_duration() + 2.5, out=0.01)
    P = sim.P[3]
    th = col(sim, data, f"{j}.q_motor")[-1]
    p = P[dr.P_POLES]
    te = p * th
    ka = P[dr.P_KT] * (1 - 0.5 * P[dr.P_UNB])
    kb = P[dr.P_KT] * (1 + 0.5 * P[dr.P_UNB])
    sa = -(math.sin(te) + P[dr.P_H3] * math.sin(3 * te))
    sb = math.cos(te) - P[dr.P_H3] * math.cos(3 * te)
    A = -ka * sa * math.sin(te) + kb * sb * math.cos(te)
    B = -(ka * sa * off)
    i_needed = -B / A
    e_pred = i_needed / (P[dr.P_KPV] * P[dr.P_N] * P[dr.P_KPP])
    e_sim = col(sim, data, f"{j}.q_ref")[-1] - col(sim, data, f"{j}.q")[-1]
    assert abs(e_pred) > 1e-4
    assert e_sim == pytest.approx(e_pred, rel=0.02)
    assert col(sim, data, "joint1.q")[-1] == pytest.approx(0.6, abs=1e-4)
    assert abs(col(sim, data, f"{j}.qd")[-1]) < 1e-4
    sim.close()


def test_backlash_dead_zone(spider):
    j = "joint5"
    b = 4e-3
    sim = spider.build({f"{j}.gear.backlash": b})
    sim.set_initial(Q0)
    target = np.array(Q0)
    target[4] += 0.3
    back = np.array(Q0)
    sim.set_joint_path([(target, 100.0, 100.0), (back, 100.0, 100.0)])
    data = run(sim, sim.set_points.path_duration() + 0.5, out=0.001)
    tw = col(sim, data, f"{j}.twist")
    tau = col(sim, data, f"{j}.tau_gear")
    inside = np.abs(tw) < 0.5 * b - 1e-6
    outside = np.abs(tw) > 0.5 * b + 1e-5
    assert inside.sum() > 20 and outside.sum() > 20
    assert np.all(tau[inside] == 0.0)
    # in contact the gear only pushes (a separating damper force is cut to zero, never pulls)
    assert np.all(tau[outside] * np.sign(tw[outside]) >= 0.0)
    pushing = outside & (tau != 0.0)
    assert pushing.sum() > 0.8 * outside.sum()
    # outside the dead zone the torque grows with the excess twist at roughly the gear stiffness
    e = tw[pushing] - np.sign(tw[pushing]) * 0.5 * b
    k_fit = np.polyfit(e, tau[pushing], 1)[0]
    assert k_fit == pytest.approx(sim.values[f"{j}.gear.stiffness"], rel=0.1)
    sim.close()


def _smooth_values():
    v = {}
    for j in range(1, 8):
        v.update({f"joint{j}.gear.backlash": 0, f"joint{j}.gear.fc": 0, f"joint{j}.gear.fs": 0})
    return v


def test_step_halving_order(spider):
    """Mechanics alone: RK4 (order 4). Full coupled drive (smooth settings): order >= ~2."""
    # mechanics, drives off
    sim = spider.build({"drives.enabled": 0})
    sim.set_initial(Q0, [0.5, -0.4, 0.6, 0.5, -0.7, 0.8, 1.0])
    qi = [sim.columns.index(f"joint{j}.q") for j in range(1, 8)]
    res = {h: run(sim, 1.0, 0.04, step=h)[:, qi] for h in (8e-3, 4e-3, 2e-3, 2.5e-4)}
    e = [np.max(np.abs(res[h] - res[2.5e-4])) for h in (8e-3, 4e-3, 2e-3)]
    assert e[0] / e[1] > 10 and e[1] / e[2] > 10, e
    sim.close()
    # coupled: the standard move with smooth gears (backlash/stiction make errors non-smooth)
    sim = spider.build(_smooth_values())
    sim.set_initial([0.0] * 7)
    sim.set_joint_path([(list(spider.spec.standard_target), 100.0, 100.0)])
    res = {h: run(sim, 1.0, 0.01, step=h)[:, qi] for h in (2e-3, 1e-3, 2.5e-4)}
    e = [np.max(np.abs(res[h] - res[2.5e-4])) for h in (2e-3, 1e-3)]
    assert e[0] / e[1] > 3.0, e
    sim.close()


def test_parameters_complete_and_refused(spider):
    d = spider.describe()
    names = set()
    for p in d.parameters:
        assert p.unit and p.description and p.component and p.name.startswith(p.component)
        assert p.min < p.max and p.min <= p.value <= p.max, p.name
        names.add(p.name)
    assert len(names) == len(d.parameters)
    for nm in (
        "joint3.motor.R",
        "joint3.gear.ratio",
        "joint3.gear.backlash",
        "link3.length",
        "payload.mass",
        "joint3.ctrl.kp_pos",
        "joint3.traj.max_speed",
    ):
        assert nm in names
    assert d.parameter("link3.length").appearance
    p = d.parameter("joint3.gear.ratio")
    with pytest.raises(ParameterError) as ei:
        spider.check_values({"joint3.gear.ratio": p.max * 2})
    assert ei.value.name == "joint3.gear.ratio" and "outside" in ei.value.reason
    for bad, why in ((float("nan"), "finite"), ("x", "number")):
        with pytest.raises(ParameterError, match=why):
            spider.check_values({"joint3.gear.ratio": bad})
    with pytest.raises(ParameterError, match="unknown"):
        spider.check_values({"joint9.gear.ratio": 1})
    with pytest.raises(ParameterError, match="whole"):
        spider.check_values({"joint3.motor.pole_pairs": 2.5})
    full = spider.check_values({"joint3.gear.ratio": 100})
    assert full["joint3.gear.ratio"] == 100 and full["joint2.gear.ratio"] == p.value
    sim = spider.build({})
    before = dict(sim.values)
    with pytest.raises(ParameterError):
        sim.set_values({"joint1.motor.R": 2.0, "joint2.motor.R": -1})
    assert sim.values == before  # nothing applied partially
    sim.close()


def test_poses_agree_with_description_and_follow_link_length(spider):
    d = spider.describe()
    sim = spider.build({})
    q = np.array(Q0)
    sim.set_initial(q)
    npos = len(d.pose_column_names()) - len(POSE_FIELDS)  # the links' and the tool's poses
    sim.start(0.01, 0.01)
    row = sim.advance(0.0)[0]
    ref = link_poses(d, sim.values, q).reshape(-1)
    assert np.max(np.abs(row[-npos - 7 : -7] - ref)) < 1e-9
    # a new link length reshapes the simulated chain without a rebuild
    mbs = sim._mbs
    sim.set_values({"link3.length": 0.9, "payload.mass": 20.0})
    assert sim._mbs is mbs
    sim.set_initial(q)
    sim.start(0.01, 0.01)
    row = sim.advance(0.0)[0]
    ref = link_poses(d, sim.values, q).reshape(-1)
    assert np.max(np.abs(row[-npos - 7 : -7] - ref)) < 1e-9
    sim.close()


def test_all_path_nodes_executed(spider):
    sim = spider.build({})
    sim.set_initial([0.0] * 7)
    a = np.array([0.2, 0.1, -0.1, 0.3, 0.2, -0.2, 0.3])
    b = -a
    c = 0.5 * a
    sim.set_joint_path([(a, 100, 100), (b, 50, 80), (c, 100, 30)])
    assert sim.set_points.seg.shape[0] == 3
    data = run(sim, sim.set_points.path_duration() + 1.5, out=0.005)
    t = data[:, 0]
    qr = np.stack([col(sim, data, f"joint{j}.q_ref") for j in range(1, 8)], axis=1)
    for k, dest in enumerate((a, b, c)):
        t_end = sim.set_points.seg[k, 0] + sim.set_points.seg[k, 1]
        i = int(np.argmin(np.abs(t - t_end)))
        assert np.max(np.abs(qr[i] - dest)) < 1e-3
    q = np.stack([col(sim, data, f"joint{j}.q") for j in range(1, 8)], axis=1)
    assert np.max(np.abs(q[-1] - c)) < 3e-4  # stiction: the integrators finish the last 0.1 mrad slowly
    sim.close()


def test_numerical_failure_is_an_error(spider):
    sim = spider.build({})
    sim.set_initial(Q0)
    sim.start(1.0, 0.01)
    sim.advance(0.05)
    sim.X[2, dr.S_IA] = float("nan")  # a diverged state
    with pytest.raises(SimulationError, match=r"joint\(s\) \[3\].*t = 0\.05"):
        sim.advance(0.1)
    sim.close()


def test_docs_navigable(spider):
    d = spider.describe()
    ids = {p.id for p in d.docs}
    assert d.doc_root in ids
    for p in d.docs:
        for target in re.findall(r"\(doc:([^)]+)\)|doc:([\w.]+)", p.markdown):
            tid = target[0] or target[1]
            assert tid.rstrip(".") in ids, (p.id, tid)
        for ch in p.children:
            assert ch in ids
    resizable = [s for s in d.shapes if s.resizable]
    assert sorted(s.link for s in resizable) == list(range(len(d.links)))
    assert d.init_equations and any("n * (q + tau_g/k" in e.expression for e in d.init_equations)


def test_specs_are_keyword_only_and_docs_need_no_package(spider):
    """A link has nine numbers and names: a positional slip must fail, not build a wrong arm. The docs
    are built from the spec and the parameter list alone (docs.py does not know the package)."""
    from simecs.models import docs
    from simecs.models.spec import ArmSpec, LinkSpec, ParamInfo

    lk = spider.spec.links[0]
    with pytest.raises(TypeError):
        LinkSpec(
            lk.name, lk.rpy, lk.length, lk.final, lk.joint_min, lk.joint_max, lk.mass, lk.radius, "large"
        )
    with pytest.raises(TypeError):
        ParamInfo(1.0, "-", "x", 0.0, 2.0)
    with pytest.raises(TypeError):
        ArmSpec("x", "x", "x", [], {})
    with pytest.raises(ValueError, match="com and inertia"):
        LinkSpec(
            name="l",
            rpy=(0, 0, 0),
            length=1.0,
            final=(0, 0, 0),
            joint_min=-1,
            joint_max=1,
            mass=1.0,
            radius=0.05,
            drive="large",
            com=(0.5, 0, 0),
        )
    d = spider.describe()
    pages = docs.build_docs(spider.spec, d.parameters, d.init_equations)
    assert [p.markdown for p in pages] == [p.markdown for p in d.docs]


@pytest.mark.parametrize("model_id", [m.id for m in list_models()])
def test_every_model_runs_the_same_drive_family(model_id):
    """Each model of the library (hand-written or imported from URDF) reaches its standard target from
    home under its drives, and its streamed poses are those of its description's kinematics."""
    pkg = get_model(model_id)
    d = pkg.describe()
    sim = pkg.build({})
    sim.set_initial(list(pkg.home()))
    target = list(pkg.spec.standard_target)
    sim.set_joint_path([(target, 100, 100)])
    data = run(sim, sim.set_points.path_duration() + 0.7, out=0.01)
    q = np.stack([col(sim, data, f"joint{j}.q") for j in range(1, len(d.links) + 1)], axis=1)
    assert np.max(np.abs(q[-1] - target)) < 2e-3
    npos = len(d.pose_column_names()) - len(POSE_FIELDS)  # the links' and the tool's poses
    ref = link_poses(d, sim.values, q[-1]).reshape(-1)
    assert np.max(np.abs(data[-1, -npos - 7 : -7] - ref)) < 1e-9
    sim.close()


def test_runs_repeat_and_drive_parameters_change_without_rebuild(spider):
    sim = spider.build({})
    sim.set_initial([0.0] * 7)
    sim.set_joint_path([([0.1] * 7, 100, 100)])
    a = run(sim, 0.5, out=0.01)
    b = run(sim, 0.5, out=0.01)
    assert np.array_equal(a, b)  # a new start() restarts from the initial state, identically
    mbs = sim._mbs
    sim.set_values({"joint2.ctrl.kp_pos": 1.0})
    c = run(sim, 0.5, out=0.01)
    assert sim._mbs is mbs
    k = sim.columns.index("joint2.q")
    assert np.max(np.abs(c[:, k] - a[:, k])) > 1e-4
    k1 = sim.columns.index("joint1.q")
    assert np.max(np.abs(c[:, k1] - a[:, k1])) < 1e-3  # other joints barely notice
    # chunked advance gives rows with time in (previous until, until]
    sim.start(0.1, 0.01)
    r0 = sim.advance(0.0)
    r1 = sim.advance(0.035)
    assert list(r0[:, 0]) == [0.0] and np.allclose(r1[:, 0], [0.01, 0.02, 0.03])
    assert sim.time == pytest.approx(0.035) and not sim.finished
    r2 = sim.advance(1.0)
    assert np.allclose(r2[:, 0], np.arange(0.04, 0.1001, 0.01)) and sim.finished
    sim.close()


# ---------------------------------------------------------------------------------------------------
# The period hook: a controller in the loop exchanges its period inside one solver call (nodes/hil.py)

PERIOD_STEPS = 2  # the hook every 2 solver steps


def hooked_sim(spider):
    """A Spider at Q0 with every joint's current from a digital P controller on the load angle."""
    sim = spider.build()
    sim.set_initial(Q0)
    sim.set_joint_path([([q + 0.2 for q in Q0], 100.0, 100.0)])
    sim.set_points.set_external([True] * sim.n)
    sim.start(0.2, 0.002)
    return sim


def digital_controller(sim, log):
    """The hook: sensors at the period's start -> current set points held over the period."""
    row = np.empty(1 + 9 * sim.n)

    def period() -> None:
        sim.sensors(row)
        log.append(row[0])
        q = row[1::9][: sim.n]
        sim.set_points.set_actuators(-20.0 * (q - (np.array(Q0) + 0.1)))

    return period


def test_a_period_hook_inside_one_solver_call_gives_what_a_call_per_period_gives(spider):
    per_call = hooked_sim(spider)
    hook_times: list[float] = []
    control = digital_controller(per_call, hook_times)
    period = PERIOD_STEPS * per_call.h
    parts = []
    while not per_call.finished:  # the reference: one solver call per period, the exchange between
        control()
        parts.append(per_call.advance(per_call.time + period))
    expected = np.vstack(parts)

    hooked = hooked_sim(spider)
    times: list[float] = []
    hooked.set_period_hook(PERIOD_STEPS, digital_controller(hooked, times))
    # chunks that end off the period grid
    got = np.vstack([hooked.advance(0.013), hooked.advance(0.1), hooked.advance(1.0)])
    assert hooked.finished
    # The same motion to the last bit. A row on a period's start shows the current set point held from
    # there (as at t = 0); a call per period emitted it at the end of the period before, with that one's.
    held = [i for i, c in enumerate(hooked.columns) if c.endswith((".i_ref", ".u_a"))]
    others = np.setdiff1d(np.arange(len(hooked.columns)), held)
    assert len(held) == 2 * hooked.n
    np.testing.assert_array_equal(got[:, others], expected[:, others])
    i_ref = [hooked.columns.index(f"joint{j + 1}.i_ref") for j in range(hooked.n)]
    np.testing.assert_array_equal(got[:-1, i_ref], expected[1:, i_ref])
    assert times == pytest.approx(hook_times, abs=1e-12)  # once per period, at its start
    assert np.ptp(col(hooked, got, "joint1.i_ref")) > 0.1 and np.ptp(col(hooked, got, "joint1.q")) > 1e-3


def test_what_a_period_hook_raises_comes_out_of_advance_once_the_call_has_ended(spider):
    sim = hooked_sim(spider)
    calls: list[float] = []

    def silent_at_the_third_period() -> None:
        calls.append(sim.time)
        if len(calls) == 3:
            raise ValueError("the controller went silent")

    sim.set_period_hook(PERIOD_STEPS, silent_at_the_third_period)
    with pytest.raises(ValueError, match="went silent"):
        sim.advance(0.05)
    assert calls == pytest.approx([0.0, PERIOD_STEPS * sim.h, 2 * PERIOD_STEPS * sim.h], abs=1e-12)
    assert sim.time == pytest.approx(0.05, abs=1e-12)  # the call went on, without the hook
    with pytest.raises(ValueError, match="at least one solver step"):
        sim.set_period_hook(0, silent_at_the_third_period)
