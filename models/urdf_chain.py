"""A URDF's serial chain in the Link convention (paper §5.1), the frames every other module uses.

The path from `base_link` to `tool_link` gives the movable joints; links fixed to one another (and
locked joints) merge into one body with their masses and inertias. Joint k's frame of the Link
convention has its z on the URDF axis: A_k = align(axis) Rz(phi_k). The free turn phi_{k+1} is
chosen so the way from joint k to joint k+1 lies in the x-z plane of link frame k: then link k's
`length` (along x, >= 0) and `final` (along z) carry it, like a DH row, and a changed length moves
the next joints the way a longer tube would. With C_k the URDF child link frame:

    link frame k = J_k Rz(q_k) Rrpy_k,   C_k = J_k Rz(q_k) A_k^T,   Rrpy_k = A_k^T R_{k+1} A_{k+1}

so q_k means what it means in the URDF, and a body's data turn from C_k into link frame k by
M_k = Rrpy_k^T A_k^T. The last link's frame is the tool link's, so Cartesian commands are given in
the tool frame the modeller chose.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from simecs.mesh.rules.kinematics import rpy_of

from .urdf import Geometry, UrdfError, UrdfJoint, UrdfRobot

Vec3 = tuple[float, float, float]


@dataclass
class ChainLink:
    """Movable joint k and the body it turns, in the Link convention (see the module docstring)."""

    joint: str
    lower: float
    upper: float
    effort: float  # N m, 0 when the URDF gives none
    velocity: float  # rad/s, 0 when the URDF gives none
    rpy: Vec3
    length: float
    final: Vec3
    mass: float
    com: Vec3  # in link frame k
    inertia: tuple[float, float, float, float, float, float]  # ixx iyy izz ixy ixz iyz, link frame k
    visuals: list[Geometry] = field(default_factory=list)  # poses in link frame k
    collisions: list[Geometry] = field(default_factory=list)


@dataclass
class UrdfChain:
    robot: str
    base_link: str
    tool_link: str
    base_translation: Vec3
    base_rpy: Vec3
    tool_translation: Vec3
    links: list[ChainLink]
    base_visuals: list[Geometry]  # the parts fixed to the world, poses in the world frame
    base_collisions: list[Geometry]


def _v3(a: np.ndarray) -> Vec3:
    return (float(a[0]), float(a[1]), float(a[2]))


def _rot_axis(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    C = 1 - c
    return np.array(
        [
            [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
        ]
    )


def align_z(axis: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the z axis onto `axis` (a unit vector)."""
    cos = float(np.clip(axis[2], -1.0, 1.0))
    k = np.array([-axis[1], axis[0], 0.0])  # z x axis
    norm = float(np.linalg.norm(k))
    if norm < 1e-12:
        return np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])
    return _rot_axis(k / norm, math.atan2(norm, cos))


def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _locked_motion(joint: UrdfJoint, value: float) -> np.ndarray:
    T = np.eye(4)
    if joint.type in ("revolute", "continuous"):
        T[:3, :3] = _rot_axis(joint.axis, value)
    elif joint.type == "prismatic":
        T[:3, 3] = joint.axis * value
    return T


def _path(robot: UrdfRobot, base: str, tool: str) -> list[UrdfJoint]:
    """The joints from `base` down to `tool`, base first."""
    out = []
    link = tool
    while link != base:
        joint = robot.parent_joint(link)
        if joint is None:
            raise UrdfError(f'tool_link "{tool}"', f'is not below base_link "{base}"')
        out.append(joint)
        link = joint.parent
    return out[::-1]


def default_tool_link(robot: UrdfRobot, base: str, locked: dict[str, float]) -> str:
    """The link at the end of the only branch with movable joints; refused when there are several."""
    link = base
    while True:
        branches = robot.child_joints(link)
        if not branches:
            return link

        def movable_below(j: UrdfJoint) -> bool:
            todo = [j]
            while todo:
                k = todo.pop()
                if k.type != "fixed" and k.name not in locked:
                    return True
                todo.extend(robot.child_joints(k.child))
            return False

        moving = [j for j in branches if movable_below(j)]
        if len(moving) > 1:
            names = ", ".join(f'"{j.child}"' for j in moving)
            raise UrdfError(
                f'link "{link}"',
                f"the chain branches here (towards {names}): name the tool_link, and lock the joints of "
                "the other branches (locked_joints)",
            )
        if not moving:  # only fixed links below: follow the deepest one
            link = max(branches, key=lambda j: _depth(robot, j.child)).child
        else:
            link = moving[0].child


def _depth(robot: UrdfRobot, link: str) -> int:
    return 1 + max((_depth(robot, j.child) for j in robot.child_joints(link)), default=0)


def serial_chain(
    robot: UrdfRobot,
    base_link: str = "",
    tool_link: str = "",
    locked_joints: dict[str, float] | None = None,
) -> UrdfChain:
    """The chain from `base_link` (default: the root) to `tool_link` (default: the end of the only
    moving branch); UrdfError names what does not fit a serial chain of revolute joints."""
    locked = dict(locked_joints or {})
    for name, value in locked.items():
        joint = robot.joints.get(name)
        if joint is None:
            raise UrdfError(f'locked_joints "{name}"', "is not a joint of the URDF")
        if joint.type in ("revolute", "prismatic") and not joint.lower <= value <= joint.upper:
            raise UrdfError(
                f'locked_joints "{name}"',
                f"{value:g} is outside its limits [{joint.lower:g}, {joint.upper:g}]",
            )
        if joint.type in ("floating", "planar"):
            raise UrdfError(f'locked_joints "{name}"', f"a {joint.type} joint cannot be locked at one value")
    base = base_link or robot.root()
    if base not in robot.links:
        raise UrdfError(f'base_link "{base}"', "is not a link of the URDF")
    tool = tool_link or default_tool_link(robot, base, locked)
    if tool not in robot.links:
        raise UrdfError(f'tool_link "{tool}"', "is not a link of the URDF")
    path = _path(robot, base, tool)
    moving = []
    for j in path:
        if j.name in locked or j.type == "fixed":
            continue
        if j.type not in ("revolute", "continuous"):
            raise UrdfError(
                f'joint "{j.name}"',
                f"{j.type} joints are not supported (revolute and continuous are); lock it (locked_joints)",
            )
        if j.mimic:
            raise UrdfError(f'joint "{j.name}"', "mimic joints are not supported; lock it (locked_joints)")
        moving.append(j)
    if not moving:
        raise UrdfError(f'robot "{robot.name}"', f'no movable joint between "{base}" and "{tool}"')

    # bodies: body 0 is fixed to the world (base frame), body k hangs on movable joint k (frame C_k)
    body_of: dict[str, int] = {}
    pose_in_body: dict[str, np.ndarray] = {}
    joint_pose: list[np.ndarray] = []  # movable joint k's URDF frame in body k-1's frame
    on_path = {j.name for j in path}
    moving_names = {j.name for j in moving}
    body_of[base] = 0
    pose_in_body[base] = np.eye(4)
    k = 0
    for j in path:
        parent_pose = pose_in_body[j.parent]
        if j.name in moving_names:
            k += 1
            joint_pose.append(parent_pose @ j.origin)
            body_of[j.child] = k
            pose_in_body[j.child] = np.eye(4)
        else:
            body_of[j.child] = k
            pose_in_body[j.child] = parent_pose @ j.origin @ _locked_motion(j, locked.get(j.name, 0.0))
    # what hangs off the path must be rigid: fixed or locked joints only
    todo = [name for name in body_of]
    while todo:
        link = todo.pop()
        for j in robot.child_joints(link):
            if j.name in on_path:
                continue
            if j.type != "fixed" and j.name not in locked:
                raise UrdfError(
                    f'joint "{j.name}"',
                    f'({j.type}) branches off the chain at link "{link}": lock it (locked_joints) '
                    "or choose a tool_link below it",
                )
            body_of[j.child] = body_of[link]
            pose_in_body[j.child] = pose_in_body[link] @ j.origin @ _locked_motion(j, locked.get(j.name, 0.0))
            todo.append(j.child)

    n = len(moving)
    tool_pose = pose_in_body[tool]
    if body_of[tool] != n:
        raise UrdfError(f'tool_link "{tool}"', "is not moved by the last movable joint")
    # the Link convention's frames
    A = [np.eye(3)] * n
    A[0] = align_z(moving[0].axis)
    rpy: list[Vec3] = []
    lengths: list[float] = []
    finals: list[Vec3] = []
    for i in range(n - 1):
        R_next, p_next = joint_pose[i + 1][:3, :3], joint_pose[i + 1][:3, 3]
        A0 = align_z(moving[i + 1].axis)
        w = A0.T @ R_next.T @ p_next
        reach = math.hypot(w[0], w[1])
        phi = math.atan2(w[1], w[0]) if reach > 1e-12 else 0.0
        A[i + 1] = A0 @ _rz(phi)
        rpy.append(_v3(rpy_of(A[i].T @ R_next @ A[i + 1])))
        lengths.append(reach)
        finals.append((0.0, 0.0, float(w[2])))
    R_t, p_t = tool_pose[:3, :3], tool_pose[:3, 3]
    rpy.append(_v3(rpy_of(A[n - 1].T @ R_t)))
    v = R_t.T @ p_t
    last_length = max(float(v[0]), 0.0)
    lengths.append(last_length)
    finals.append((0.0, float(v[1]), float(v[2])))
    tool_translation = (float(v[0]) - last_length, 0.0, 0.0)
    J1 = joint_pose[0]

    from simecs.mesh.rules.kinematics import rot_rpy

    links = []
    for i, j in enumerate(moving):
        M = rot_rpy(rpy[i]).T @ A[i].T  # C_k coordinates -> link frame k coordinates
        mass, com, inertia = _body_inertia(robot, body_of, pose_in_body, i + 1)
        com_l = M @ com
        I_l = M @ inertia @ M.T
        lower, upper = (j.lower, j.upper) if j.type == "revolute" else (-2 * math.pi, 2 * math.pi)
        links.append(
            ChainLink(
                joint=j.name,
                lower=lower,
                upper=upper,
                effort=j.effort,
                velocity=j.velocity,
                rpy=rpy[i],
                length=lengths[i],
                final=finals[i],
                mass=mass,
                com=_v3(com_l),
                inertia=(I_l[0, 0], I_l[1, 1], I_l[2, 2], I_l[0, 1], I_l[0, 2], I_l[1, 2]),
                visuals=_geometries(robot, body_of, pose_in_body, i + 1, M, "visuals"),
                collisions=_geometries(robot, body_of, pose_in_body, i + 1, M, "collisions"),
            )
        )
    return UrdfChain(
        robot=robot.name,
        base_link=base,
        tool_link=tool,
        base_translation=_v3(J1[:3, 3]),
        base_rpy=_v3(rpy_of(J1[:3, :3] @ A[0])),
        tool_translation=tool_translation,
        links=links,
        base_visuals=_geometries(robot, body_of, pose_in_body, 0, np.eye(3), "visuals"),
        base_collisions=_geometries(robot, body_of, pose_in_body, 0, np.eye(3), "collisions"),
    )


def _body_inertia(
    robot: UrdfRobot, body_of: dict[str, int], pose: dict[str, np.ndarray], body: int
) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, COM and inertia at the COM of one body, in its reference frame."""
    parts = []
    for name, b in body_of.items():
        if b != body:
            continue
        link = robot.links[name]
        if link.mass <= 0:
            continue
        R, p = pose[name][:3, :3], pose[name][:3, 3]
        parts.append((link.mass, R @ link.com + p, R @ link.inertia @ R.T))
    total = sum(m for m, _, _ in parts)
    if total <= 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum((m * c for m, c, _ in parts), np.zeros(3)) / total
    inertia = np.zeros((3, 3))
    for m, c, I in parts:
        d = c - com
        inertia += I + m * (d @ d * np.eye(3) - np.outer(d, d))
    return total, com, inertia


def _geometries(
    robot: UrdfRobot,
    body_of: dict[str, int],
    pose: dict[str, np.ndarray],
    body: int,
    M: np.ndarray,
    kind: str,
) -> list[Geometry]:
    """The visuals (or collisions) of one body with their poses turned into link frame `body`."""
    to_link = np.eye(4)
    to_link[:3, :3] = M
    out = []
    for name, b in body_of.items():
        if b != body:
            continue
        for geo in getattr(robot.links[name], kind):
            out.append(dataclasses.replace(geo, pose=to_link @ pose[name] @ geo.pose))
    return out
