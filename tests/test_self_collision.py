"""The arm's own shape (issue 34 §2): an imported arm touches obstacles with its URDF collision solids,
and no arm may pass through itself.

On the geometry: the spheres stay within MAX_BULGE of each solid's hull and reach nearly all of its
surface; an obstacle 5 mm into a link's solid is touched there, one 2 cm clear of it is not. On the
simulation: a box pressed into the Panda's hand pushes on link7. Through the service (real nodes):
a path folding the Panda's hand into its forearm is refused naming both links; simulated on purpose,
the run says when they touched.
"""

from __future__ import annotations

import numpy as np
import pytest
from simecs import models
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import messages as m
from simecs.models.collision_spheres import MAX_BULGE, coverage, solid_hull, solid_spheres
from simecs.models.planner import Planner
from simecs.models.self_collision import SAMPLE_POSES
from simecs.testing.collision import fold_target, link_hull_points

from tests.conftest import Service
from tests.test_commands import run_to_end

URDF_MODELS = ["panda", "ur5", "jaco2"]
#: The Panda at home with joint 6 turned down to 0.265 rad: the hand folds into link5.
PANDA_FOLD = (5, 0.265)


@pytest.mark.parametrize("model_id", URDF_MODELS)
def test_the_spheres_of_each_collision_solid_stay_near_it_and_reach_its_surface(model_id: str) -> None:
    spec = models.get_model(model_id).spec
    assert spec.collisions, "the URDF's <collision> solids are read"
    far = []
    for solid in spec.collisions:
        hull = solid_hull(solid.geometry, solid.near)
        spheres = solid_spheres(solid.geometry, solid.near)
        normals = np.asarray(hull.face_normals)
        offsets = np.einsum("ij,ij->i", normals, np.asarray(hull.triangles[:, 0]))
        inner = np.min(offsets[None, :] - spheres[:, :3] @ normals.T, axis=1)
        assert (inner >= -1e-9).all(), f"{solid.name}: a sphere's centre is outside its solid"
        # a sphere within `inner` of the boundary everywhere reaches at most r - inner past the hull
        assert (spheres[:, 3] - inner <= MAX_BULGE + 1e-9).all(), solid.name
        _gap, beyond = coverage(hull, spheres)
        far.append(beyond)
    assert np.mean(far) <= 0.01, f"{np.mean(far):.1%} of the solids' surface is more than 5 mm from a sphere"


@pytest.mark.parametrize("model_id", URDF_MODELS)
def test_an_obstacle_touches_a_link_where_its_collision_solid_is(model_id: str) -> None:
    """A 1 cm ball beside the last link's solids, away from the arm's axis: 5 mm into them it is
    touched by that link, 2 cm clear of them it is not."""
    pkg = models.get_model(model_id)
    values = pkg.describe().default_values()
    q = np.array(pkg.spec.home)
    world = link_hull_points(pkg, q, pkg.n - 1)
    outward = np.array([*world.mean(axis=0)[:2], 0.0])
    outward /= np.linalg.norm(outward)
    extreme = world[np.argmax(world @ outward)]
    for into, touched in ((0.005, True), (-0.02, False)):
        ball = m.Obstacle("ball", "sphere", list(extreme + outward * (0.01 - into)), radius=0.01)
        planner = Planner(pkg, values, q, 1.0, obstacles=[ball])
        problem = planner.checks.collision(planner.plan(m.JointPath([m.PathNode(list(q))])))
        if touched:
            assert problem is not None and f"link{pkg.n} would touch obstacle ball" in problem[1], problem
        else:
            assert problem is None, problem


def test_a_box_pressed_into_the_pandas_hand_pushes_on_link7() -> None:
    pkg = models.get_model("panda")
    values = pkg.describe().default_values()
    q = np.array(pkg.spec.home)
    hand = link_hull_points(pkg, q, 6)
    lowest, (x, y) = float(hand[:, 2].min()), hand[np.argmin(hand[:, 2]), :2]
    forces = {}
    for into in (0.004, -0.02):
        top = lowest + into
        box = m.Obstacle("box", "box", [float(x), float(y), top - 0.05], size=[0.3, 0.3, 0.1], friction=0.0)
        sim = pkg.build(values)
        try:
            sim.set_obstacles([box])
            sim.set_initial(q)
            sim.start(0.05, 0.002)
            rows = sim.advance(0.05)
        finally:
            sim.close()
        forces[into] = rows[:, sim.columns.index("contact.link7.force")].max()
    assert forces[0.004] > 10.0 and forces[-0.02] == 0.0, forces


def test_neighbours_and_pairs_touching_at_home_are_not_checked() -> None:
    pkg = models.get_model("spider")
    planner = Planner(pkg, pkg.describe().default_values(), pkg.spec.home, 1.0)
    check = planner.checks.self_check
    n = pkg.n
    for g in range(n):
        assert not check.checked[g, g + 1] and not check.checked[g + 1, g]
    for g, h, why in check.skipped:
        assert not check.checked[g, h]
        assert why in (
            "neighbours",
            "touching at the home pose",
            f"touching at all {SAMPLE_POSES} sampled poses",
        )
    assert check.first_touch(np.array(pkg.spec.home)[None, :]) is None
    assert check.checked.any(), "the Spider's far links are checked against each other"


def test_an_initial_pose_inside_itself_is_refused_as_the_initial_pose() -> None:
    pkg = models.get_model("panda")
    q = np.array(pkg.spec.home)
    q[PANDA_FOLD[0]] = PANDA_FOLD[1]
    planner = Planner(pkg, pkg.describe().default_values(), q, 1.0)
    problem = planner.checks.self_touch(planner.plan(m.JointPath([m.PathNode(list(q))])))
    assert problem is not None and problem[0] == "initial", problem
    assert "link5 would touch link7" in problem[1], problem


@pytest.mark.shares_service
def test_a_path_folding_the_arm_into_itself_is_refused_then_reported(service: Service) -> None:
    s = service.client.create_session("ann", "panda")
    home = list(models.get_model("panda").spec.home)
    s.set_initial(home)
    folded = list(home)
    folded[PANDA_FOLD[0]] = PANDA_FOLD[1]
    plan = s.set_command(m.JointPath([m.PathNode(folded, 60.0, 60.0)]))
    with pytest.raises(RemoteError) as refused:
        s.run()
    error = refused.value.error
    assert error.code == "bad_request" and error.field == "command.nodes[0]", error
    assert "link5 would touch link7" in error.message and "settings.collisions" in error.message, error
    t_refused = float(error.message.split("at t = ")[1].split(" s")[0])
    # simulated on purpose: the run goes through and tells when the links met
    run_to_end(s, plan, 0.2, collisions="simulate")
    warnings = [w for w in s.snapshot().state.warnings if "touched" in w]
    assert len(warnings) == 1 and "link5 touched link7 at t = " in warnings[0], warnings
    t_touched = float(warnings[0].split("at t = ")[1].split(" s")[0])
    assert abs(t_touched - t_refused) < 0.05, (t_touched, t_refused)  # the set points lead the arm a little


@pytest.mark.parametrize("model_id", ["panda", "ur5", "jaco2", "spider"])
def test_every_model_that_can_fold_into_itself_is_refused_there(model_id: str) -> None:
    found = fold_target(models.get_model(model_id))
    assert found is not None, f"no single joint folds the {model_id} into itself"
    _q, refusal = found
    assert " would touch link" in refusal, refusal


def test_the_puma_cannot_fold_into_itself_within_its_ranges() -> None:
    """Its forearm sits beside the upper arm (d3 = 0.15 m): no random pose within the joint ranges
    makes two checked links touch, so no motion is refused for it."""
    pkg = models.get_model("puma560")
    planner = Planner(pkg, pkg.describe().default_values(), pkg.spec.home, 1.0)
    lo, hi = (np.array([getattr(lk, a) for lk in pkg.spec.links]) for a in ("joint_min", "joint_max"))
    poses = lo + (hi - lo) * np.random.default_rng(3).random((20000, pkg.n))
    assert planner.checks.self_check.first_touch(poses) is None
