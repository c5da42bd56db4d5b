"""models/: the numbers of a run checked against independent computations: the pose kernel against
Exudyn's sensors, rows that do not depend on the output interval or the chunks, ripple at its own
harmonic, a resolver error in the pose reached, friction at high motor speed, bias forces against the
mass matrix and the potential (no mocks)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simecs.mesh.protocol.columns import POSE_FIELDS
from simecs.mesh.rules.kinematics import link_poses
from simecs.models import SimulationError, chain_dynamics, get_model, references
from simecs.models import drive as dr

from .test_models import Q0, col, run


@pytest.fixture(scope="module")
def spider():
    return get_model("spider")


@pytest.mark.parametrize("model", ["spider", "puma560"])
def test_pose_kernel_matches_exudyn_sensors(model):
    """Rows take the link poses from q (numba forward kinematics over the chain handed to Exudyn), not
    from Exudyn sensors: both agree over a moving chain, also after a link length change."""
    pkg = get_model(model)
    d = pkg.describe()
    n = len(d.links)
    sim = pkg.build({"drives.enabled": 0})
    npos = len(d.pose_column_names()) - len(POSE_FIELDS)  # the links' and the tool's poses
    rng = np.random.default_rng(1)
    for vals in (
        {},
        {f"link{n // 2}.length": 0.9 * d.parameter(f"link{n // 2}.length").max, "payload.mass": 7.0},
    ):
        sim.set_values(vals)
        lo = np.array([lk.joint_min for lk in d.links])
        hi = np.array([lk.joint_max for lk in d.links])
        sim.set_initial(lo + (hi - lo) * rng.uniform(0.2, 0.8, n), rng.uniform(-1.5, 1.5, n))
        sim.start(0.5, 0.05)
        rows = [sim.advance(0.0)]
        checked = 0
        while not sim.finished:
            rows.append(sim.advance(sim.time + 0.05))  # each chunk ends on an output sample
            q, _ = sim.state()
            assert rows[-1][-1, 0] == pytest.approx(sim.time)
            assert np.max(np.abs(rows[-1][-1, -npos - 7 : -7] - sim._sensor_poses().reshape(-1))) <= 1e-9
            assert (
                np.max(np.abs(rows[-1][-1, -npos - 7 : -7] - link_poses(d, sim.values, q).reshape(-1)))
                <= 1e-9
            )
            checked += 1
        assert checked == 10
    sim.close()


def test_rows_independent_of_output_interval_and_chunks(spider):
    """One solver call per chunk, rows taken inside the step loop: the output interval only picks
    samples and the chunking changes nothing (every step is exactly one mechanics step)."""
    sim = spider.build({})
    sim.set_initial([0.0] * 7)
    sim.set_joint_path([(list(spider.spec.standard_target), 100.0, 100.0)])
    a = run(sim, 0.6, out=0.01)
    b = run(sim, 0.6, out=0.002)
    assert np.array_equal(a, b[::5])
    sim.start(0.6, 0.01)
    rows = [sim.advance(0.0)]
    prev = 0.0
    while not sim.finished:
        until = sim.time + 0.0137  # chunks that end between output samples and off the step grid
        r = sim.advance(until)
        assert np.all(r[:, 0] > prev + 1e-12) and np.all(r[:, 0] <= until + 1e-12)
        prev = until
        rows.append(r)
    assert np.array_equal(a, np.vstack(rows))
    # stop time off the output grid: the last row is on the step grid just after it
    sim.start(0.1234, 0.01)
    c = sim.advance(1.0)
    assert np.allclose(c[:, 0], list(np.arange(13) * 0.01) + [0.124]) and sim.finished
    assert np.array_equal(c[:-1], a[:13])
    sim.close()


@pytest.mark.parametrize(("source", "harmonic"), [("unbalance", 2), ("shape", 4)])
def test_each_ripple_source_at_its_own_harmonic(spider, source, harmonic):
    """Paper §5.1's two torque ripple sources must not look alike: phase unbalance d gives
    (d/2) kt i cos 2 th_e, the shape functions' 3rd harmonic h3 gives -h3 kt i cos 4 th_e. The motor
    kernel at a fixed current, swept over one electrical turn, ideal current loop, no detent and
    no resolver error, so that each source shows alone."""
    sim = spider.build({})
    P = sim.P.copy()
    sim.close()
    j, amps, turns = 0, 2.0, 256
    P[j, [dr.P_UNB, dr.P_H3, dr.P_DET, dr.P_EM, dr.P_EL]] = 0.0
    P[j, dr.P_IDEAL] = 1.0
    size = 0.05
    P[j, dr.P_UNB if source == "unbalance" else dr.P_H3] = size
    p = P[j, dr.P_POLES]
    out = np.zeros(dr.NO + 10)
    torque = []
    for te in np.arange(turns) * 2 * math.pi / turns:
        X = np.zeros((P.shape[0], dr.NL))
        X[j, dr.S_TH] = te / p
        dr.joint_signals(P, j, X, 0.0, 0.0, amps, 0.0, references.JM_CURRENT, 0.0, out)
        torque.append(out[10])
    spectrum = np.abs(np.fft.rfft(torque)) / turns * 2
    mean = np.mean(torque)
    assert mean == pytest.approx(P[j, dr.P_KT] * amps, rel=1e-12)
    expected = size / 2 if source == "unbalance" else size
    assert spectrum[harmonic] == pytest.approx(expected * P[j, dr.P_KT] * amps, rel=1e-9)
    others = np.delete(spectrum[1:], harmonic - 1)
    assert np.max(others) < 1e-12 * mean


def test_a_load_resolver_error_shows_in_the_pose_reached(spider):
    """The controller acts on what its load resolver reads (q' = q + e_l sin q): after a move to
    q_ref the arm rests where q' = q_ref, about e_l sin(q_ref) from the command; the planner does not
    correct for an error no real controller knows."""
    el, target = 5e-3, 1.2
    sim = spider.build({"joint2.resolver.load_error": el})
    sim.set_obstacles([])  # the move swings the arm down through where the plate is
    sim.set_initial(Q0)
    goal = list(Q0)
    goal[1] = target
    sim.set_joint_path([(goal, 100.0, 100.0)])
    data = run(sim, sim.set_points.path_duration() + 2.0, out=0.01)
    q = col(sim, data, "joint2.q")[-1]
    # within the rest limit cycle (backlash, stiction, integral action: ~0.1 mrad)
    assert q + el * math.sin(q) == pytest.approx(target, abs=3e-4)
    assert target - q == pytest.approx(el * math.sin(target), rel=0.1)
    sim.close()


def puma_fast_move(values: dict | None = None, substeps: int | None = None) -> tuple[np.ndarray, list]:
    """The PUMA at 100 % speed and acceleration to (2.5, 2, -2, 2.5, 1.5, 3): motor 1 passes 150 rad/s."""
    pkg = get_model("puma560")
    sim = pkg.build(values or {})
    sim.set_initial([0.0] * 6)
    sim.set_joint_path([([2.5, 2.0, -2.0, 2.5, 1.5, 3.0], 100, 100)])
    try:
        data = run(sim, sim.set_points.path_duration() + 0.3, out=0.002, substeps=substeps)
    finally:
        sim.close()
    return data, sim.columns


def test_friction_stays_stable_at_high_motor_speed():
    """LuGre's bristle state relaxes at s0 |w| / g(w): about 100 |w| 1/s with the catalog's s0, past
    RK4's stability at the model's 0.2 ms substep above ~139 rad/s. The drive takes more substeps
    where friction is stiff: joint 1's friction stays near its Coulomb level (not 136 N m), its lag
    as small as with 10x the substeps."""
    data, columns = puma_fast_move()
    fine, _ = puma_fast_move(substeps=50)

    def c(d, name):
        return d[:, columns.index(name)]

    assert np.max(np.abs(c(data, "joint1.qd_motor"))) > 150.0
    assert np.max(np.abs(c(data, "joint1.tau_friction"))) < 0.5
    lag = c(data, "joint1.q_ref") - c(data, "joint1.q")
    lag_fine = c(fine, "joint1.q_ref") - c(fine, "joint1.q")
    assert np.max(np.abs(lag)) < 10e-3
    assert np.max(np.abs(lag - lag_fine)) < 0.2e-3


def test_a_run_past_its_friction_accuracy_fails_and_says_why():
    """A bristle stiffness no substep count can follow at this speed: the run stops with an error
    naming the joint and the parameter, rather than return wrong numbers."""
    with pytest.raises(
        SimulationError, match=r"broke down.*joint1's friction state left its physical bound.*gear\.sigma0"
    ):
        puma_fast_move({"joint1.gear.sigma0": 1e6}, substeps=1)


@pytest.mark.parametrize("model", ["spider", "puma560"])
def test_bias_forces_agree_with_the_mass_matrix_and_the_potential(model):
    """The drives' load predictor uses M qdd = tau - bias, bias = C(q, qd) qd + g(q) by recursive
    Newton-Euler. Checked against independent formulas: the Christoffel symbols of the (separately
    validated) mass matrix, c_i = sum_jk (dM_ij/dq_k - 1/2 dM_jk/dq_i) qd_j qd_k by central
    differences, and g = dV/dq of the potential V = -sum m_k gravity . c_k by central differences."""
    from simecs.models.mechanics import chain_arrays

    pkg = get_model(model)
    sim = pkg.build({})
    chain = chain_arrays(pkg.spec, sim.values)
    pre_R, pre_p, masses, coms = chain.pre_R, chain.pre_p, chain.masses, chain.coms
    sim.close()
    n = masses.shape[0]
    rng = np.random.default_rng(7)
    eps = 1e-6

    def mass(q):
        M = np.empty((n, n))
        chain_dynamics.mass_matrix(chain, q, M)
        return M

    def bias(q, qd, gravity):
        out = np.empty(n)
        chain_dynamics.bias_forces(chain, np.asarray(gravity, float), q, qd, out)
        return out

    def potential(q, gravity):
        R, p = np.empty((n, 3, 3)), np.empty((n, 3))
        chain_dynamics.chain_frames(pre_R, pre_p, q, R, p)
        return -sum(masses[k] * gravity @ (p[k] + R[k] @ coms[k]) for k in range(n))

    for _ in range(5):
        q, qd = rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n)
        dM = np.stack([(mass(q + eps * e) - mass(q - eps * e)) / (2 * eps) for e in np.eye(n)])  # [k, i, j]
        christoffel = np.einsum("kij,j,k->i", dM, qd, qd) - 0.5 * np.einsum("ijk,j,k->i", dM, qd, qd)
        scale = np.max(np.abs(christoffel)) + 1e-9
        assert np.max(np.abs(bias(q, qd, [0, 0, 0]) - christoffel)) < 1e-6 * scale
        gravity = np.array([0.0, 0.0, -9.81])
        grad = np.array(
            [
                (potential(q + eps * e, gravity) - potential(q - eps * e, gravity)) / (2 * eps)
                for e in np.eye(n)
            ]
        )
        assert np.max(np.abs(bias(q, np.zeros(n), gravity) - grad)) < 1e-6 * (np.max(np.abs(grad)) + 1e-9)
        assert np.allclose(bias(q, qd, gravity), bias(q, qd, [0, 0, 0]) + grad, atol=1e-6 * scale)


def test_a_kernel_called_past_its_dispatch_is_looked_up_again_for_arrays_of_another_kind() -> None:
    """The step's machine code is called without numba's type dispatch (jit.compiled_for): an array
    of another layout or type would be read wrongly by code made for another, so the lookup is
    keyed on what numba's type depends on (jit.type_key; step.CompiledStep asks again on a change)."""
    from numba import njit
    from simecs.models import jit

    @njit(cache=False)
    def corner(a: np.ndarray) -> float:
        return float(a[0, 1])

    c = np.arange(12.0).reshape(3, 4)
    f = np.asfortranarray(c)
    assert jit.type_key((c, 1.0, True)) == jit.type_key((c.copy(), 2.5, False))
    assert jit.type_key((c,)) != jit.type_key((f,))
    assert jit.type_key((c,)) != jit.type_key((c.astype(np.float32),))
    assert jit.type_key((c,)) != jit.type_key((c[:, ::2],))
    assert jit.compiled_for(corner, (c,))(c) == jit.compiled_for(corner, (f,))(f) == 1.0
