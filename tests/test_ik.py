"""Kinematics of models/ik.py against the simulator's own pose rows, and its inverse kinematics.

No network, no processes: the numba kernels run in this process (compiled once, then cached).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize
from simecs.mesh.rules.kinematics import link_frames, quat_from_matrix, rot_rpy, rpy_of
from simecs.models import ModelPackage, chain_dynamics, chain_kinematics, get_model
from simecs.models.ik import ArmKinematics, IKResult, orientation_error, turned
from simecs.models.mechanics import chain_arrays, tool_point

MODELS = ["spider", "puma560"]
Arm = tuple[ModelPackage, dict[str, float], ArmKinematics]


@pytest.fixture(scope="module", params=MODELS)
def arm(request: pytest.FixtureRequest) -> Arm:
    pkg = get_model(request.param)
    values = pkg.check_values({})
    return pkg, values, ArmKinematics(pkg.spec, values)


@pytest.fixture(scope="module")
def spider() -> ArmKinematics:
    pkg = get_model("spider")
    return ArmKinematics(pkg.spec, pkg.check_values({}))


@pytest.fixture(scope="module")
def puma() -> ArmKinematics:
    pkg = get_model("puma560")
    return ArmKinematics(pkg.spec, pkg.check_values({}))


def random_q(k: ArmKinematics, rng: np.random.Generator, shrink: float = 1.0) -> np.ndarray:
    mid = 0.5 * (k.lower + k.upper)
    half = 0.5 * (k.upper - k.lower) * shrink
    return mid + half * rng.uniform(-1.0, 1.0, k.n)


def regular_q(
    k: ArmKinematics, rng: np.random.Generator, sigma: float = 1e-2, shrink: float = 1.0
) -> np.ndarray:
    """A random configuration within the limits, away from singularities."""
    while True:
        q = random_q(k, rng, shrink)
        if k.sigma_min(q) > sigma:
            return q


def rodrigues(e: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(e))
    if th == 0.0:
        return np.eye(3)
    a = e / th
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def assert_inside(k: ArmKinematics, q: np.ndarray) -> None:
    assert np.all(q >= k.lower) and np.all(q <= k.upper), (q, k.lower, k.upper)


def assert_true_errors(k: ArmKinematics, r: IKResult, p_t: np.ndarray, R_t: np.ndarray) -> None:
    """The errors an IKResult reports are those of its q."""
    p, R = k.tool_pose(r.q)
    assert r.position_error == pytest.approx(np.linalg.norm(p - p_t), abs=1e-13)
    assert r.rotation_error == pytest.approx(np.linalg.norm(orientation_error(R, R_t)), abs=1e-12)


# ---- forward kinematics and Jacobian -------------------------------------------------------------------
def test_tool_pose_is_the_pose_row_and_the_link_frames(arm: Arm) -> None:
    pkg, values, k = arm
    spec = pkg.spec
    ch = chain_arrays(spec, values)
    Rrpy = np.array([rot_rpy(lk.rpy) for lk in spec.links])
    tool = tool_point(spec, values)
    rng = np.random.default_rng(1)
    rows = np.empty((k.n + 1, 7))
    for _ in range(20):
        q = random_q(k, rng)
        p, R = k.tool_pose(q)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-13)
        chain_dynamics.pose_rows(ch.pre_R, ch.pre_p, Rrpy, tool, q, rows)
        assert np.max(np.abs(rows[k.n, :3] - p)) < 1e-12
        assert np.max(np.abs(rows[k.n, 3:] - quat_from_matrix(R))) < 1e-12
        p_lf, R_lf = link_frames(pkg.describe(), values, list(q))[-1]
        assert np.max(np.abs(p_lf - p)) < 1e-12
        assert np.max(np.abs(R_lf - R)) < 1e-12


def test_jacobian_is_the_derivative_of_the_tool_pose(arm: Arm) -> None:
    _, _, k = arm
    rng = np.random.default_rng(2)
    h = 1e-6
    for _ in range(10):
        q = random_q(k, rng)
        J = k.jacobian(q)
        assert J.shape == (6, k.n)
        for i in range(k.n):
            d = np.zeros(k.n)
            d[i] = h
            pp, Rp = k.tool_pose(q + d)
            pm, Rm = k.tool_pose(q - d)
            assert np.max(np.abs((pp - pm) / (2 * h) - J[:3, i])) < 1e-6
            assert np.max(np.abs(orientation_error(Rm, Rp) / (2 * h) - J[3:, i])) < 1e-6
        assert k.sigma_min(q) == pytest.approx(np.linalg.svd(J, compute_uv=False)[-1])


def test_jdot_qd_is_the_derivative_of_the_jacobian_along_qd(arm: Arm) -> None:
    """The operational-space controller's Jdot qd (closed form) against a central difference of J."""
    pkg, values, k = arm
    ch = chain_arrays(pkg.spec, values)
    tool = tool_point(pkg.spec, values)
    R_last = rot_rpy(pkg.spec.links[-1].rpy)
    rng = np.random.default_rng(3)
    h = 1e-6
    R_all, p_all, p, R, out = (
        np.empty((k.n, 3, 3)),
        np.empty((k.n, 3)),
        np.empty(3),
        np.empty((3, 3)),
        np.empty(6),
    )
    for _ in range(10):
        q = random_q(k, rng)
        qd = rng.uniform(-2.0, 2.0, k.n)
        chain_kinematics.tool_frames(ch.pre_R, ch.pre_p, R_last, tool, q, R_all, p_all, p, R)
        chain_kinematics.tool_jdot_qd(R_all, p_all, p, qd, out)
        expected = (k.jacobian(q + h * qd) - k.jacobian(q - h * qd)) @ qd / (2 * h)
        assert np.max(np.abs(out - expected)) < 1e-6 * max(1.0, float(np.max(np.abs(expected))))


def test_spd_inverse_is_the_inverse_of_the_mass_matrix(arm: Arm) -> None:
    pkg, values, k = arm
    ch = chain_arrays(pkg.spec, values)
    rng = np.random.default_rng(4)
    M = np.empty((k.n, k.n))
    for _ in range(10):
        chain_dynamics.mass_matrix(ch, random_q(k, rng), M)
        Minv = chain_kinematics.spd_inverse(M)
        assert np.max(np.abs(Minv - np.linalg.inv(M))) < 1e-9 * np.max(np.abs(Minv))
        assert np.max(np.abs(M @ Minv - np.eye(k.n))) < 1e-10


# ---- inverse kinematics ------------------------------------------------------------------------------
def test_round_trip_from_a_nearby_seed(arm: Arm) -> None:
    _, _, k = arm
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = regular_q(k, rng)
        p_t, R_t = k.tool_pose(q)
        seed = np.clip(q + rng.uniform(-0.3, 0.3, k.n), k.lower, k.upper)
        r = k.solve(p_t, R_t, seed)
        assert r.ok, r.reason
        assert r.reason == ""
        assert r.position_error <= 1e-9 and r.rotation_error <= 1e-9
        assert_inside(k, r.q)
        assert_true_errors(k, r, p_t, R_t)


def test_resolved_rate_step_takes_few_iterations(arm: Arm) -> None:
    _, _, k = arm
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = regular_q(k, rng, shrink=0.9)
        qd = rng.uniform(-0.5, 0.5, k.n)  # rad/s, 1 ms of motion
        p_t, R_t = k.tool_pose(q + 1e-3 * qd)
        r = k.solve(p_t, R_t, q)
        assert r.ok and 1 <= r.iterations <= 3, (r.iterations, r.reason)
        assert np.linalg.norm(r.q - q) <= np.linalg.norm(1e-3 * qd) + 1e-9  # no longer than the move


def test_redundancy_resolved_toward_the_seed(spider: ArmKinematics) -> None:
    k = spider
    rng = np.random.default_rng(5)
    for _ in range(10):
        q_a = regular_q(k, rng, sigma=0.05, shrink=0.8)
        p_t, R_t = k.tool_pose(q_a)
        seed = q_a + rng.uniform(-0.3, 0.3, k.n)
        r = k.solve(p_t, R_t, seed)
        assert r.ok, r.reason
        # q_a also reaches the target, yet the answer is nearer the seed ...
        assert np.linalg.norm(r.q - seed) < np.linalg.norm(q_a - seed)
        assert np.linalg.norm(r.q - q_a) > 1e-6
        # ... and the nearest locally: seed - q has no component along the self-motion (null space)
        J = k.jacobian(r.q)
        N = np.eye(k.n) - np.linalg.pinv(J) @ J
        assert np.linalg.norm(N @ (seed - r.q)) < 1e-6
        # other solutions along the self-motion, either way, are farther from the seed
        v = N @ rng.standard_normal(k.n)
        v /= np.linalg.norm(v)
        for s in (-0.05, 0.05):
            moved = k.solve(p_t, R_t, r.q + s * v)  # the solution nearest the moved point
            assert moved.ok
            assert np.linalg.norm(moved.q - r.q) > 0.01
            assert np.linalg.norm(moved.q - seed) > np.linalg.norm(r.q - seed)
        # a different solution: another seed's answer, also a valid one, is farther from this seed
        other = k.solve(p_t, R_t, q_a - (seed - q_a))
        assert other.ok
        assert np.linalg.norm(r.q - seed) <= np.linalg.norm(other.q - seed) + 1e-9


def test_solve_near_restarts_and_prefers_the_seed(arm: Arm) -> None:
    _, _, k = arm
    rng = np.random.default_rng(6)
    for _ in range(5):
        q = regular_q(k, rng)
        p_t, R_t = k.tool_pose(q)
        seed = random_q(k, rng)  # far away: a point-to-point move
        r = k.solve_near(p_t, R_t, seed)
        assert r.ok, r.reason
        assert r.position_error <= 1e-9 and r.rotation_error <= 1e-9
        assert_inside(k, r.q)
        assert_true_errors(k, r, p_t, R_t)
        near = k.solve(p_t, R_t, seed)
        if near.ok:  # the seed's own solution comes first
            assert np.allclose(r.q, near.q, atol=1e-9)
    # deterministic
    a = k.solve_near(p_t, R_t, seed)
    b = k.solve_near(p_t, R_t, seed)
    assert np.array_equal(a.q, b.q) and a.iterations == b.iterations


def least_distance(k: ArmKinematics, target: np.ndarray) -> float:
    """The least distance of the tool point from the target, by a generic bounded optimizer."""

    def dist(q: np.ndarray) -> float:
        return float(np.linalg.norm(k.tool_pose(q)[0] - target))

    rng = np.random.default_rng(7)
    bounds = list(zip(k.lower, k.upper, strict=True))
    return min(
        float(minimize(dist, random_q(k, rng), method="L-BFGS-B", bounds=bounds).fun) for _ in range(10)
    )


@pytest.mark.parametrize(("model", "target"), [("puma560", (3.0, 0.0, 0.2)), ("spider", (0.0, 3.0, 0.5))])
def test_out_of_reach_reports_the_closest_pose(model: str, target: tuple[float, float, float]) -> None:
    pkg = get_model(model)
    k = ArmKinematics(pkg.spec, pkg.check_values({}))
    q0 = np.zeros(k.n)
    _, R0 = k.tool_pose(q0)
    t = np.array(target)  # 3 m from the base: the PUMA reaches about 0.9 m, the Spider 2.1 m
    least = least_distance(k, t)
    assert least > 0.5
    near = k.solve_near(t, R0, q0)
    assert "the arm reaches" in near.reason
    for r in (near, k.solve(t, R0, q0)):
        assert not r.ok
        assert r.reason.startswith("out of reach"), r.reason
        assert f"{r.position_error:.3g} m" in r.reason
        assert r.position_error == pytest.approx(least, abs=1e-5)
        assert_inside(k, r.q)
        assert_true_errors(k, r, t, R0)


@pytest.mark.parametrize(
    ("model", "joint", "past"), [("puma560", 1, 0.25), ("puma560", 4, -0.4), ("spider", 3, 0.3)]
)
def test_target_past_a_joint_limit_never_gives_q_outside(model: str, joint: int, past: float) -> None:
    pkg = get_model(model)
    k = ArmKinematics(pkg.spec, pkg.check_values({}))
    rng = np.random.default_rng(8)
    for _ in range(3):
        q = random_q(k, rng, shrink=0.5)
        q[joint] = k.upper[joint] + past if past > 0 else k.lower[joint] + past
        p_t, R_t = k.tool_pose(q)
        seed = np.clip(q, k.lower, k.upper)
        local = k.solve(p_t, R_t, seed)
        for r in (local, k.solve_near(p_t, R_t, seed)):
            assert_inside(k, r.q)
            assert_true_errors(k, r, p_t, R_t)
            if r.ok:
                assert r.position_error <= 1e-9 and r.rotation_error <= 1e-9
            else:
                assert r.reason
        if not local.ok:  # from this seed the limit is in the way, and the reason says which
            assert local.reason.startswith("joint limits:"), local.reason
            assert f"joint{joint + 1}" in local.reason


def test_clamped_seed_and_bad_input(puma: ArmKinematics) -> None:
    k = puma
    q = np.array([0.3, -0.5, 0.6, 0.4, 0.7, 0.5])
    p_t, R_t = k.tool_pose(q)
    r = k.solve(p_t, R_t, q + np.array([9.0, 0, 0, 0, 0, 0]))  # the seed is clamped first
    assert_inside(k, r.q)
    with pytest.raises(ValueError):
        k.solve(p_t, R_t, q[:5])
    with pytest.raises(ValueError):
        k.solve(p_t[:2], R_t, q)
    with pytest.raises(ValueError):
        k.solve(p_t, R_t, np.full(6, np.nan))
    with pytest.raises(ValueError):
        k.tool_pose(np.zeros(7))


# ---- rotations -----------------------------------------------------------------------------------------
def test_rpy_of_inverts_rot_rpy() -> None:
    rng = np.random.default_rng(9)
    angles = [rng.uniform(-4.0, 4.0, 3) for _ in range(200)]
    for sign in (1.0, -1.0):
        for d in [0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1e-3, -1e-15, -1e-12, -1e-9, -1e-6, -1e-3]:
            for _ in range(5):
                a = rng.uniform(-math.pi, math.pi, 3)
                a[1] = sign * math.pi / 2 + d
                angles.append(a)
    for a in angles:
        R = rot_rpy(a.tolist())
        rpy = rpy_of(R)
        assert -math.pi / 2 - 1e-12 <= rpy[1] <= math.pi / 2 + 1e-12
        assert np.max(np.abs(rot_rpy(rpy.tolist()) - R)) < 1e-12, (a, rpy)
    assert np.allclose(rpy_of(rot_rpy([0.1, -0.2, 0.3])), [0.1, -0.2, 0.3], atol=1e-14)


def test_orientation_error_is_the_rotation_vector() -> None:
    rng = np.random.default_rng(10)
    for th in [0.0, 1e-9, 1e-3, 0.5, 2.0, 3.0, math.pi - 1e-3, math.pi - 1e-7, math.pi]:
        for _ in range(10):
            R_now = rodrigues(rng.standard_normal(3))
            axis = rng.standard_normal(3)
            e_true = th * axis / np.linalg.norm(axis)
            R_target = rodrigues(e_true) @ R_now
            e = orientation_error(R_now, R_target)
            assert np.linalg.norm(e) == pytest.approx(th, abs=1e-9)
            assert np.max(np.abs(rodrigues(e) @ R_now - R_target)) < 1e-9
            assert np.max(np.abs(turned(e, R_now) - R_target)) < 1e-9  # the inverse (lines slerp with it)
            if th < math.pi - 1e-6:
                assert np.allclose(e, e_true, atol=1e-8)
