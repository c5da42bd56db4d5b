"""Reading a URDF file: its links and joints as checked data, every refusal naming its element.

Our own reader (the standard library's XML parser) rather than yourdfpy's: a refusal must name the
element and the attribute (`joint "panda_joint4": axis [0, 0, 0] is not a unit vector`), and a
simulator should not pay trimesh's import to read six joints. yourdfpy stays what the tests and
`simecs bench model` compare our kinematics with, an independent reading of the same file.
`urdf_chain.py` turns what this module reads into a serial chain in the Link convention.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from simecs.mesh.rules.kinematics import rot_rpy

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
#: How far an axis may be from unit length: URDF asks for a normalised axis, files round it.
AXIS_TOLERANCE = 1e-3


class UrdfError(ValueError):
    """A URDF the importer refuses: `element` names the culprit (`joint "j4"`), `reason` says why."""

    def __init__(self, element: str, reason: str) -> None:
        self.element = element
        self.reason = reason
        super().__init__(f"{element}: {reason}" if element else reason)


@dataclass
class Geometry:
    """A visual or collision solid in its link's frame: `pose` (4x4), and its kind's sizes."""

    kind: str  # "mesh", "box", "cylinder", "sphere"
    pose: np.ndarray
    filename: str = ""  # mesh: as written in the file (package://..., relative, or absolute)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)  # box edges
    radius: float = 0.0  # cylinder, sphere
    length: float = 0.0  # cylinder, along its local z
    color: tuple[int, int, int] | None = None


@dataclass
class UrdfLink:
    name: str
    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))  # in the link frame
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # at the COM, link axes
    visuals: list[Geometry] = field(default_factory=list)
    collisions: list[Geometry] = field(default_factory=list)


@dataclass
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # 4x4: the joint frame in the parent link's frame
    axis: np.ndarray  # unit vector in the joint frame
    lower: float = 0.0
    upper: float = 0.0
    effort: float = 0.0  # N m (0: not given)
    velocity: float = 0.0  # rad/s (0: not given)
    mimic: str = ""


@dataclass
class UrdfRobot:
    name: str
    path: Path
    links: dict[str, UrdfLink]
    joints: dict[str, UrdfJoint]

    def root(self) -> str:
        children = {j.child for j in self.joints.values()}
        roots = [name for name in self.links if name not in children]
        if len(roots) != 1:
            raise UrdfError(
                f'robot "{self.name}"', f"has {len(roots)} root links ({', '.join(roots)}); one is needed"
            )
        return roots[0]

    def parent_joint(self, link: str) -> UrdfJoint | None:
        for j in self.joints.values():
            if j.child == link:
                return j
        return None

    def child_joints(self, link: str) -> list[UrdfJoint]:
        return [j for j in self.joints.values() if j.parent == link]


def transform(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot_rpy([float(a) for a in rpy])
    T[:3, 3] = xyz
    return T


def _numbers(element: str, attribute: str, text: str | None, count: int, default: float | None) -> np.ndarray:
    if text is None:
        if default is None:
            raise UrdfError(element, f"{attribute} is missing")
        return np.full(count, default)
    parts = text.split()
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        raise UrdfError(element, f"{attribute} {text.strip()!r} is not {count} numbers") from None
    if values.shape[0] != count:
        raise UrdfError(element, f"{attribute} {text.strip()!r} is not {count} numbers")
    if not np.all(np.isfinite(values)):
        raise UrdfError(element, f"{attribute} {text.strip()!r} has a value that is not finite")
    return values


def _number(element: str, node: ET.Element, attribute: str, default: float | None = None) -> float:
    return float(_numbers(element, f"{node.tag} {attribute}", node.get(attribute), 1, default)[0])


def _origin(element: str, parent: ET.Element) -> np.ndarray:
    node = parent.find("origin")
    if node is None:
        return np.eye(4)
    xyz = _numbers(element, "origin xyz", node.get("xyz"), 3, 0.0)
    rpy = _numbers(element, "origin rpy", node.get("rpy"), 3, 0.0)
    return transform(xyz, rpy)


def _geometry(element: str, node: ET.Element, materials: dict[str, tuple[int, int, int]]) -> Geometry | None:
    pose = _origin(element, node)
    geo = node.find("geometry")
    if geo is None or len(geo) == 0:
        raise UrdfError(element, f"{node.tag} has no geometry")
    shape = geo[0]
    color = _material(element, node.find("material"), materials)
    if shape.tag == "mesh":
        filename = shape.get("filename")
        if not filename:
            raise UrdfError(element, f"{node.tag} mesh has no filename")
        scale = _numbers(element, "mesh scale", shape.get("scale"), 3, 1.0)
        return Geometry("mesh", pose, filename=filename, scale=(scale[0], scale[1], scale[2]), color=color)
    if shape.tag == "box":
        size = _numbers(element, "box size", shape.get("size"), 3, None)
        if np.any(size <= 0):
            raise UrdfError(element, f"box size {list(size)} must be positive")
        return Geometry("box", pose, size=(size[0], size[1], size[2]), color=color)
    if shape.tag == "cylinder":
        radius = _number(element, shape, "radius")
        length = _number(element, shape, "length")
        if radius <= 0 or length <= 0:
            raise UrdfError(element, "cylinder radius and length must be positive")
        return Geometry("cylinder", pose, radius=radius, length=length, color=color)
    if shape.tag == "sphere":
        radius = _number(element, shape, "radius")
        if radius <= 0:
            raise UrdfError(element, "sphere radius must be positive")
        return Geometry("sphere", pose, radius=radius, color=color)
    raise UrdfError(element, f"{node.tag} geometry <{shape.tag}> is not one of mesh, box, cylinder, sphere")


def _material(
    element: str, node: ET.Element | None, materials: dict[str, tuple[int, int, int]]
) -> tuple[int, int, int] | None:
    if node is None:
        return None
    rgba = node.find("color")
    if rgba is not None:
        c = _numbers(element, "material color rgba", rgba.get("rgba"), 4, None)
        return (
            int(round(255 * min(max(c[0], 0), 1))),
            int(round(255 * min(max(c[1], 0), 1))),
            int(round(255 * min(max(c[2], 0), 1))),
        )
    return materials.get(node.get("name", ""))


def _inertial(link: UrdfLink, element: str, node: ET.Element) -> None:
    mass_node = node.find("mass")
    if mass_node is None:
        raise UrdfError(element, "inertial has no mass")
    mass = _number(element, mass_node, "value")
    if mass < 0:
        raise UrdfError(element, f"mass {mass:g} kg is negative")
    origin = _origin(element, node)
    inertia_node = node.find("inertia")
    if inertia_node is None:
        raise UrdfError(element, "inertial has no inertia")
    names = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
    ixx, iyy, izz, ixy, ixz, iyz = (_number(element, inertia_node, n, 0.0) for n in names)
    local = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    eig = np.linalg.eigvalsh(local)
    scale = max(float(np.max(np.abs(eig))), 1e-12)
    if eig[0] < -1e-9 * scale:
        raise UrdfError(element, f"inertia has a negative principal moment ({eig[0]:.3g} kg m^2)")
    if eig[2] > (eig[0] + eig[1]) * (1 + 1e-6) + 1e-12:
        raise UrdfError(
            element,
            "inertia violates the triangle inequality (principal moments "
            f"{', '.join(f'{e:.3g}' for e in eig)} kg m^2)",
        )
    R = origin[:3, :3]
    link.mass = mass
    link.com = origin[:3, 3].copy()
    link.inertia = R @ local @ R.T


def _joint(element: str, node: ET.Element, name: str) -> UrdfJoint:
    kind = node.get("type", "")
    if kind not in JOINT_TYPES:
        raise UrdfError(element, f"type {kind!r} is not a URDF joint type ({', '.join(JOINT_TYPES)})")
    parent = node.find("parent")
    child = node.find("child")
    if parent is None or not parent.get("link"):
        raise UrdfError(element, "has no <parent link=...>")
    if child is None or not child.get("link"):
        raise UrdfError(element, "has no <child link=...>")
    axis_node = node.find("axis")
    axis = (
        _numbers(element, "axis", None if axis_node is None else axis_node.get("xyz"), 3, None)
        if axis_node is not None
        else np.array([1.0, 0.0, 0.0])
    )
    if kind in ("revolute", "continuous", "prismatic"):
        norm = float(np.linalg.norm(axis))
        if abs(norm - 1.0) > AXIS_TOLERANCE:
            shown = ", ".join(f"{a:g}" for a in axis)
            raise UrdfError(element, f"axis [{shown}] is not a unit vector")
        axis = axis / norm
    joint = UrdfJoint(name, kind, parent.get("link", ""), child.get("link", ""), _origin(element, node), axis)
    limit = node.find("limit")
    if kind in ("revolute", "prismatic") and limit is None:
        raise UrdfError(element, f"a {kind} joint needs a <limit> (lower, upper, effort, velocity)")
    if limit is not None:
        joint.effort = _number(element, limit, "effort", 0.0)
        joint.velocity = _number(element, limit, "velocity", 0.0)
        if joint.effort < 0 or joint.velocity < 0:
            raise UrdfError(element, "limit effort and velocity must not be negative")
        if kind != "continuous":
            joint.lower = _number(element, limit, "lower", 0.0)
            joint.upper = _number(element, limit, "upper", 0.0)
            if kind in ("revolute", "prismatic") and not joint.lower < joint.upper:
                raise UrdfError(element, f"limit lower {joint.lower:g} is not below upper {joint.upper:g}")
    mimic = node.find("mimic")
    if mimic is not None:
        joint.mimic = mimic.get("joint", "")
    return joint


def _named(node: ET.Element, where: str, seen: Mapping[str, object]) -> tuple[str, str]:
    """A <link> or <joint>'s name, and how refusals name it (`joint "j4"`); refused without a name
    or when one of its kind already has it."""
    name = node.get("name")
    if not name:
        raise UrdfError(where, f"a <{node.tag}> has no name")
    element = f'{node.tag} "{name}"'
    if name in seen:
        raise UrdfError(element, "is defined twice")
    return name, element


def read_urdf(path: str | Path) -> UrdfRobot:
    """The links and joints of a URDF file, checked: UrdfError names the first element refused."""
    path = Path(path)
    where = f"{path.name}"
    try:
        tree = ET.parse(path)
    except FileNotFoundError:
        raise UrdfError(where, "no such file") from None
    except ET.ParseError as exc:
        raise UrdfError(where, f"not well-formed XML ({exc})") from None
    top = tree.getroot()
    if top.tag != "robot":
        raise UrdfError(where, f"the top element is <{top.tag}>, not <robot>")
    robot_name = top.get("name", path.stem)
    materials: dict[str, tuple[int, int, int]] = {}
    for node in top.findall("material"):
        color = _material(f'material "{node.get("name", "")}"', node, {})
        if color is not None:
            materials[node.get("name", "")] = color
    links: dict[str, UrdfLink] = {}
    for node in top.findall("link"):
        name, element = _named(node, where, links)
        link = UrdfLink(name)
        inertial = node.find("inertial")
        if inertial is not None:
            _inertial(link, element, inertial)
        for tag, out in (("visual", link.visuals), ("collision", link.collisions)):
            for geo_node in node.findall(tag):
                geo = _geometry(element, geo_node, materials)
                if geo is not None:
                    out.append(geo)
        links[name] = link
    joints: dict[str, UrdfJoint] = {}
    parents: dict[str, str] = {}
    for node in top.findall("joint"):
        name, element = _named(node, where, joints)
        joint = _joint(element, node, name)
        for role, link_name in (("parent", joint.parent), ("child", joint.child)):
            if link_name not in links:
                raise UrdfError(element, f'{role} link "{link_name}" is not defined')
        if joint.child in parents:
            raise UrdfError(
                element,
                f'link "{joint.child}" is already the child of joint "{parents[joint.child]}": '
                "closed loops are not supported",
            )
        parents[joint.child] = name
        joints[name] = joint
    if not links:
        raise UrdfError(where, "defines no links")
    robot = UrdfRobot(robot_name, path, links, joints)
    root = robot.root()
    _refuse_cycles(robot, root)
    return robot


def _refuse_cycles(robot: UrdfRobot, root: str) -> None:
    seen = {root}
    todo = [root]
    while todo:
        for j in robot.child_joints(todo.pop()):
            if j.child in seen:
                raise UrdfError(f'joint "{j.name}"', "closes a loop: closed loops are not supported")
            seen.add(j.child)
            todo.append(j.child)
    unreached = [name for name in robot.links if name not in seen]
    if unreached:
        raise UrdfError(f'link "{unreached[0]}"', "is not connected to the root link")


def resolve_uri(uri: str, near: Path) -> Path:
    """The file a URDF reference names: `package://<package>/<path>` (an installed package's share
    folder, as example-robot-data installs it, or a folder `<package>` above `near`), `file://<path>`,
    or a path relative to `near`. UrdfError says where it looked."""
    if uri.startswith("package://"):
        package, _, rest = uri.removeprefix("package://").partition("/")
        tried = []
        try:
            from importlib.metadata import PackageNotFoundError, distribution

            candidate = Path(str(distribution(package).locate_file(f"cmeel.prefix/share/{package}/{rest}")))
            if candidate.is_file():
                return candidate
            tried.append(str(candidate))
        except PackageNotFoundError:
            pass
        for folder in (near, *near.parents):
            candidate = folder / rest if folder.name == package else folder / package / rest
            if candidate.is_file():
                return candidate
        raise UrdfError(
            uri, f'no installed package "{package}" and no folder "{package}" above {near} holds "{rest}"'
        )
    path = Path(uri.removeprefix("file://"))
    path = path if path.is_absolute() else near / path
    if not path.is_file():
        raise UrdfError(uri, f"no such file ({path})")
    return path
