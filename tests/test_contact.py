"""Environment and contact (issue 17, item 3): obstacles as session data, contact simulated, reported
and checked before a run.

On the simulation: the tool pressed onto a plane settles where the contact force, read back from the
joint torques through the Jacobian (an independent path: the drive side and the kinematics), equals
stiffness x the penetration the pose columns show. Through the service (real processes, a real mesh):
a path through a box is refused naming the step and the box; simulated on purpose, the contact begins
at the sample where the tool's geometry reaches the box, on its face, and a notice says so; bad
obstacle lists are refused naming the field and leave the stored list as it was.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from simecs import models
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import scene_state
from simecs.mesh.rules.kinematics import rpy_of
from simecs.models.contact_geometry import TOOL_RADIUS
from simecs.models.ik import ArmKinematics

from tests.conftest import Service
from tests.test_commands import SPIDER_Q0, kinematics, run_to_end

K_PLANE = 1e5  # N/m


def test_the_tool_pressed_on_a_plane_settles_at_force_over_stiffness() -> None:
    """A frictionless plane 5 mm into the tool tip at the start: the position loops push back until
    the joint torques hold the plane's force. At rest, with the chain in zero gravity, tau_gear =
    -J^T F on the load side whatever the controller; F from the torques must be K x depth."""
    pkg = models.get_model("spider")
    values = pkg.describe().default_values()
    kin = ArmKinematics(pkg.spec, values)
    q0 = np.zeros(pkg.n)
    p, _R = kin.tool_pose(q0)
    z_plane = p[2] + TOOL_RADIUS - 0.005
    position = [float(p[0]), float(p[1]), float(z_plane)]
    lid = m.Obstacle("lid", "plane", position, [math.pi, 0.0, 0.0], stiffness=K_PLANE, friction=0.0)
    sim = pkg.build(values)
    try:
        sim.set_obstacles([lid])
        sim.set_initial(q0)
        sim.set_joint_path([(q0, 50.0, 50.0)])
        sim.start(1.5, 0.002)
        rows = sim.advance(1.5)
    finally:
        sim.close()
    c = {name: k for k, name in enumerate(sim.columns)}
    last = rows[-1]
    q = np.array([last[c[f"joint{j}.q"]] for j in range(1, pkg.n + 1)])
    tau_gear = np.array([last[c[f"joint{j}.tau_gear"]] for j in range(1, pkg.n + 1)])
    J = kin.jacobian(q)[:3]
    F = -np.linalg.lstsq(J.T, tau_gear, rcond=None)[0]
    tool = np.array([last[c[f"pose.tool.{a}"]] for a in "xyz"])
    depth = TOOL_RADIUS - (z_plane - tool[2])  # the geometry, from the pose columns
    assert 0.5e-3 < depth < 5e-3, depth
    # The plane pushes straight down (no friction), with K x depth, to 0.1 % (the arm settles).
    assert abs(F[2] + K_PLANE * depth) < 1e-3 * K_PLANE * depth, (F, K_PLANE * depth)
    assert np.linalg.norm(F[:2]) < 1e-3 * abs(F[2])
    # The contact variables say the same (the force with what is left of the damping: the arm still
    # creeps by some 10 um/s).
    assert abs(last[c["contact.depth"]] - depth) < 1e-12
    assert abs(last[c["contact.tool_fz"]] + K_PLANE * depth) < 1e-4 * K_PLANE * depth
    assert last[c["contact.link7.obstacle"]] == 1
    assert all(last[c[f"contact.link{j}.force"]] == 0.0 for j in range(1, pkg.n))
    # The link's force vector is the tool's (only the tip touches), and it acts on the plane's surface
    # right under the tip: what the viewer and /scene draw as an arrow.
    link_f = np.array([last[c[f"contact.link7.f{a}"]] for a in "xyz"])
    tool_f = np.array([last[c[f"contact.tool_f{a}"]] for a in "xyz"])
    assert (
        np.array_equal(link_f, tool_f) and abs(np.linalg.norm(link_f) - last[c["contact.link7.force"]]) < 1e-9
    )
    point = np.array([last[c[f"contact.link7.p{a}"]] for a in "xyz"])
    assert abs(point[2] - z_plane) < 1e-12 and np.linalg.norm(point[:2] - tool[:2]) < 1e-12
    arrows = scene_state.WorldColumns(sim.columns).arrows(last)
    assert arrows.shape == (1, 2, 3) and np.array_equal(arrows[0, 0], point) and arrows[0, 1, 2] < point[2]


@pytest.mark.parametrize("model_id", ["spider", "puma560", "panda", "ur5", "jaco2"])
def test_a_models_own_poses_are_clear_of_its_own_obstacles(model_id: str) -> None:
    """Home and the standard move's target touch nothing: a new session's first run is never refused."""
    pkg = models.get_model(model_id)
    desc = pkg.describe()
    assert desc.obstacles, "every library model stands on something the arm can touch"
    sim = pkg.build(desc.default_values())
    try:
        for q in (desc.home or [0.0] * pkg.n, pkg.spec.standard_target):
            sim.set_initial(q)
            sim.start(0.01, 0.002)
            rows = sim.advance(0.01)
            assert rows[:, sim.columns.index("contact.depth")].max() == 0.0, (model_id, q)
    finally:
        sim.close()


def _box_above_the_tool(p0: np.ndarray, gap: float) -> m.Obstacle:
    """A 10 cm box whose underside is `gap` m above the tool point."""
    size = [0.1, 0.1, 0.05]
    centre = [float(p0[0]), float(p0[1]), float(p0[2] + gap + size[2] / 2)]
    return m.Obstacle("box1", "box", centre, size=size, friction=0.2)


@pytest.mark.shares_service
def test_a_path_through_a_box_is_refused_then_simulated_on_purpose(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    assert [ob.name for ob in s.snapshot().obstacles] == ["plate"]  # the model's own
    s.set_initial(SPIDER_Q0)
    kin = kinematics("spider")
    p0, R0 = kin.tool_pose(np.array(SPIDER_Q0))
    plate = s.snapshot().obstacles[0]
    box = _box_above_the_tool(p0, 0.05)
    stored = s.set_obstacles([plate, box])
    assert [ob.name for ob in stored] == ["plate", "box1"]
    assert s.snapshot().obstacles == stored
    p1 = p0 + np.array([0.0, 0.0, 0.1])  # the tool points up: its tip leads into the box
    plan = s.set_command(m.CartesianPath([m.CartesianNode(list(p1), list(rpy_of(R0)), "lin", 30.0, 30.0)]))
    with pytest.raises(RemoteError) as refused:
        s.run()
    assert refused.value.error.code == "bad_request"
    assert refused.value.error.field == "command.nodes[0]"
    assert "link7 would touch obstacle box1" in refused.value.error.message
    # Simulated on purpose: the contact begins where the geometry says, on the box's underside.
    layouts: list[m.RunLayout] = []
    with s.watch(on_layout=layouts.append):
        cols, rows = run_to_end(s, plan, 0.5, collisions="simulate")
    c = {name: k for k, name in enumerate(cols)}
    t = rows[:, 0]
    tip = rows[:, [c[f"pose.tool.{a}"] for a in "xyz"]]
    underside = box.position[2] - box.size[2] / 2
    inside = (np.abs(tip[:, 0] - box.position[0]) < box.size[0] / 2) & (
        np.abs(tip[:, 1] - box.position[1]) < box.size[1] / 2
    )
    reaches = inside & (tip[:, 2] + TOOL_RADIUS > underside)
    force = rows[:, c["contact.link7.force"]]
    assert reaches.any() and (force > 0).any()
    k_geo, k_force = int(np.argmax(reaches)), int(np.argmax(force > 0))
    assert k_force == k_geo, (t[k_geo], t[k_force])
    assert rows[k_force, c["contact.link7.obstacle"]] == 2  # box1, second in the list
    # The box stops the tool: it never gets more than a few mm into it, and it pushes down.
    assert (tip[:, 2] + TOOL_RADIUS - underside).max() < 5e-3
    assert rows[-1, c["contact.tool_fz"]] < -1.0
    warnings = " | ".join(s.snapshot().state.warnings)
    assert f"link7 hit obstacle box1 at t = {t[k_force]:.3f} s" in warnings, warnings
    # The run's context (what its recording keeps) says what the arm could touch.
    assert layouts and layouts[-1].context.obstacles == stored


@pytest.mark.shares_service
def test_bad_obstacles_are_refused_by_field_and_change_nothing(service: Service) -> None:
    s = service.client.create_session("bob", "spider")
    before = s.snapshot().obstacles
    box = {"name": "b", "kind": "box", "position": [1.0, 0.0, 0.0]}
    bad = [
        ([box, box], "obstacles[1].name"),
        ([{**box, "size": [0.1, 0.0, 0.1]}], "obstacles[0].size"),
        ([{**box, "kind": "cone"}], "obstacles[0].kind"),
        ([{**box, "position": [1.0, 0.0]}], "obstacles[0].position"),
        ([{**box, "stiffness": -5}], "obstacles[0].stiffness"),
        ([{**box, "name": "a b"}], "obstacles[0].name"),
        ([{"name": "c", "kind": "cylinder", "position": [0, 0, 0], "radius": 0.0}], "obstacles[0].radius"),
        ([{**box, "name": f"b{k}"} for k in range(33)], "obstacles"),
    ]
    key = keys.cmd(s.user, s.id)
    for obstacles, field in bad:
        raw = {"op": "set_obstacles", "v": 1, "obstacles": obstacles}
        with pytest.raises(RemoteError) as err:
            service.client.request(key, json.dumps(raw).encode())
        assert err.value.code == "bad_request" and err.value.error.field == field, (field, err.value.error)
    assert s.snapshot().obstacles == before
    raw = {"op": "set_obstacles", "v": 1, "obstacles": [box]}
    stored = service.client.request(key, json.dumps(raw).encode(), reply=list[m.Obstacle])
    assert stored[0].stiffness == 1e5  # the defaults filled in
    assert [ob.name for ob in s.snapshot().obstacles] == ["b"]
