"""The model file: a directory a modeller publishes without writing code (docs/MODELS.md, guide).

`model.json5` says what the arm is, either as Link-convention rows (`links`, like the Spider) or as a
URDF (`urdf`, read by urdf.py and turned into a chain by urdf_chain.py), with its drive classes, the
run's defaults and its documentation pages (markdown files beside it). `load_model_dir` checks it all
and gives the `ArmSpec` the rest of models/ is built from; every refusal is a `ModelFileError` naming
the file and the element (`model.json5: links[2].mass: ...`, `panda.urdf: joint "j4": ...`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import msgspec
from msgspec import Meta
from simecs.mesh.process.files import parse_json5
from simecs.mesh.protocol.codec import DecodeError, from_obj
from simecs.mesh.protocol.environment import ObstacleList, check_obstacles
from simecs.mesh.protocol.model import Shape
from simecs.mesh.protocol.primitives import Name, Record, Text

from .drives_catalog import size_class, size_for_limits
from .spec import ArmSpec, LinkSpec, ParamInfo, Visual
from .urdf import UrdfError, read_urdf, resolve_uri
from .urdf_chain import UrdfChain, serial_chain

#: The format this code reads; a file states it, so a later format can be told apart.
FORMAT = 1
MODEL_FILE = "model.json5"

Vec3 = Annotated[list[float], Meta(min_length=3, max_length=3)]
#: m/s^2 per world axis (the bounds of the `gravity.*` parameters)
Acceleration3 = Annotated[list[Annotated[float, Meta(ge=-100.0, le=100.0)]], Meta(min_length=3, max_length=3)]
Positive = Annotated[float, Meta(gt=0.0)]
NonNegative = Annotated[float, Meta(ge=0.0)]
#: Drive size class name -> DRIVE_PARAMS name -> its value and metadata (as ArmSpec.drives).
DriveTables = dict[str, dict[str, ParamInfo]]
RGB = Annotated[list[Annotated[int, Meta(ge=0, le=255)]], Meta(min_length=3, max_length=3)]


class ModelFileError(ValueError):
    """A model file refused: `where` is the file and element, `reason` says why."""

    def __init__(self, where: str, reason: str) -> None:
        self.where = where
        self.reason = reason
        super().__init__(f"{where}: {reason}")


class DriveClass(Record, kw_only=True):
    """A drive size class by its design quantities (`drives_catalog.size_class` derives the rest)."""

    R: Positive
    L: Positive
    kt: Positive
    poles: Annotated[int, Meta(ge=1, le=50)]
    J_rotor: Positive
    ratio: Annotated[float, Meta(ge=1.0)]
    J_gear: NonNegative
    stiffness: Positive
    damping: NonNegative
    backlash: NonNegative
    fc: NonNegative
    i_max: Positive
    max_speed: Positive
    max_acc: Positive
    efficiency: Annotated[float, Meta(ge=0.3, le=1.0)] = 0.85
    detent: NonNegative = 0.0
    current_bw_hz: Positive = 400.0
    speed_bw: Positive = 600.0
    kp_pos: NonNegative = 5.0
    u_max: Positive = 48.0
    offset_a: float = 0.0
    offset_b: float = 0.0
    #: where the current PIs act: "rotor" (field-oriented) or "stationary" (one per phase, the paper's)
    current_frame: Literal["rotor", "stationary"] = "rotor"
    #: damping ratio the operational-space laws give the motor's mode on its elastic gear
    #: (ctrl.twist_damping)
    twist_damping: Annotated[float, Meta(ge=0.0, le=2.0)] = 0.3


class LinkRow(Record, kw_only=True):
    """Joint i and link i in the Link convention (models/spec.py's LinkSpec)."""

    name: Name
    rpy: Vec3
    length: NonNegative
    final: Vec3
    joint_min: float
    joint_max: float
    mass: NonNegative
    radius: Positive
    drive: Name
    length_max: Positive = 3.0
    com: Vec3 | None = None
    inertia: Annotated[list[float], Meta(min_length=3, max_length=6)] | None = None
    color: RGB = msgspec.field(default_factory=lambda: [200, 200, 210])


class UrdfSource(Record, kw_only=True):
    """Where the chain comes from: a URDF file and the part of it that is the arm."""

    file: Annotated[str, Meta(min_length=1, max_length=1024)]
    base_link: str = ""
    tool_link: str = ""
    locked_joints: dict[str, float] = {}


class JointOptions(Record, kw_only=True):
    """Per URDF joint: its drive class ("auto": sized from the URDF's limits) and drawn radius."""

    drive: Name = "auto"
    radius: Positive | None = None  # default: drawn_radius(effort)
    color: RGB | None = None


class Payload(Record, kw_only=True):
    mass: Annotated[float, Meta(ge=0.0, le=500.0)] = 0.0
    size: Annotated[float, Meta(ge=0.01, le=2.0)] = 0.1


class Cartesian(Record, kw_only=True):
    """The maxima of a straight-line move at 100 % (the `cart.*` parameters' defaults)."""

    max_speed: Positive = 0.25
    max_acc: Positive = 0.5
    max_rot_speed: Positive = 0.5
    max_rot_acc: Positive = 1.0


class DocFiles(Record, kw_only=True):
    """Markdown files beside model.json5: the model's assumptions, and how its chain is built."""

    assumptions: Annotated[str, Meta(min_length=1, max_length=256)]
    chain: Annotated[str, Meta(max_length=256)] = ""


class ModelFile(Record, kw_only=True):
    """model.json5 as data (docs/MODELS.md lists every field)."""

    format: int
    id: Annotated[str, Meta(pattern=r"^[a-z0-9][a-z0-9_-]{0,31}$")]
    name: Text
    summary: Text
    docs: DocFiles
    links: list[LinkRow] | None = None
    urdf: UrdfSource | None = None
    drives: dict[Name, DriveClass] = {}
    joints: dict[str, JointOptions] = {}
    base_translation: Vec3 = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    tool_translation: Vec3 = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    payload: Payload = msgspec.field(default_factory=Payload)
    #: m/s^2 in world axes: Earth's, pointing down the world z axis, unless the file says otherwise
    gravity: Acceleration3 = msgspec.field(default_factory=lambda: [0.0, 0.0, -9.81])
    default_step: Annotated[float, Meta(ge=1e-5, le=0.01)] = 1e-3
    substeps: Annotated[int, Meta(ge=1, le=100)] = 5
    standard_target: list[float] = []
    home: list[float] = []
    cart: Cartesian = msgspec.field(default_factory=Cartesian)
    environment: list[Shape] = []
    obstacles: ObstacleList = []

    def __post_init__(self) -> None:
        check_obstacles(self.obstacles)


def read_model_file(directory: str | Path) -> ModelFile:
    """model.json5 of `directory`, parsed and checked against the format (not yet the URDF)."""
    path = Path(directory) / MODEL_FILE
    try:
        raw = parse_json5(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ModelFileError(str(path), "no such file: a model directory holds a model.json5") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ModelFileError(str(path), f"not valid JSON5 ({exc})") from None
    if not isinstance(raw, dict):
        raise ModelFileError(str(path), "the file must hold one object")
    if raw.get("format") != FORMAT:
        raise ModelFileError(
            f"{path}: format", f"{raw.get('format')!r} is not a format this simecs reads ({FORMAT})"
        )
    try:
        model = from_obj(ModelFile, raw)
    except DecodeError as exc:
        raise ModelFileError(f"{path}: {exc.field}" if exc.field else str(path), exc.problem) from None
    if (model.links is None) == (model.urdf is None):
        raise ModelFileError(str(path), "give the chain as either `links` or `urdf` (exactly one of them)")
    return model


def load_model_dir(directory: str | Path) -> ArmSpec:
    """The `ArmSpec` of a model directory; ModelFileError names the first thing refused."""
    directory = Path(directory)
    model = read_model_file(directory)
    where = str(directory / MODEL_FILE)
    docs = {
        name: _read_doc(directory, where, name, file)
        for name, file in (("assumptions", model.docs.assumptions), ("chain", model.docs.chain))
        if file
    }
    chain: UrdfChain | None = None
    visuals: list[Visual] = []
    collisions: list[Visual] = []
    if model.links is not None:
        links, drives = _links_from_rows(model, where)
        base_rpy = (0.0, 0.0, 0.0)
        base_translation = _t3(model.base_translation)
        tool_translation = _t3(model.tool_translation)
    else:
        assert model.urdf is not None
        chain, urdf_dir = _urdf_chain(directory, model.urdf, where)
        links, drives = _links_from_urdf(model, chain, where)
        visuals = _visuals(chain, links, urdf_dir)
        collisions = _visuals(chain, links, urdf_dir, collision=True)
        base_rpy = chain.base_rpy
        base_translation = chain.base_translation
        tool_translation = _t3(
            [a + b for a, b in zip(chain.tool_translation, model.tool_translation, strict=True)]
        )
    n = len(links)
    for field_name in ("standard_target", "home"):
        values = getattr(model, field_name)
        if values and len(values) != n:
            raise ModelFileError(f"{where}: {field_name}", f"{len(values)} values for a {n}-joint arm")
        for i, (value, lk) in enumerate(zip(values, links, strict=False)):
            if not lk.joint_min <= value <= lk.joint_max:
                raise ModelFileError(
                    f"{where}: {field_name}[{i}]",
                    f"{value:g} rad is outside joint {i + 1}'s range [{lk.joint_min:g}, {lk.joint_max:g}]",
                )
    home = tuple(model.home) if model.home else tuple(_clamp(0.0, lk) for lk in links)
    target = tuple(model.standard_target) if model.standard_target else _default_target(links, home)
    try:
        return ArmSpec(
            id=model.id,
            name=model.name,
            summary=model.summary,
            links=links,
            drives=drives,
            base_translation=base_translation,
            base_rpy=base_rpy,
            tool_translation=tool_translation,
            payload_mass=model.payload.mass,
            payload_size=model.payload.size,
            gravity=_t3(model.gravity),
            default_step=model.default_step,
            substeps=model.substeps,
            assumptions=docs["assumptions"],
            chain_doc=docs.get("chain", "") or (_urdf_chain_doc(chain) if chain else ""),
            standard_target=target,
            home=home,
            cart_max_speed=model.cart.max_speed,
            cart_max_acc=model.cart.max_acc,
            cart_max_rot_speed=model.cart.max_rot_speed,
            cart_max_rot_acc=model.cart.max_rot_acc,
            environment=list(model.environment),
            obstacles=list(model.obstacles),
            source=directory,
            visuals=visuals,
            collisions=collisions,
        )
    except ValueError as exc:
        raise ModelFileError(where, str(exc)) from None


def _t3(v: list[float]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _clamp(value: float, lk: LinkSpec) -> float:
    return min(max(value, lk.joint_min), lk.joint_max)


def _default_target(links: list[LinkSpec], home: tuple[float, ...]) -> tuple[float, ...]:
    """Half a radian from home on every joint, turned back where the range ends first."""
    out = []
    for lk, h in zip(links, home, strict=True):
        step = 0.5 if h + 0.5 <= lk.joint_max else -0.5
        out.append(_clamp(h + step, lk))
    return tuple(out)


def _read_doc(directory: Path, where: str, name: str, file: str) -> str:
    path = (directory / file).resolve()
    if directory.resolve() not in path.parents:
        raise ModelFileError(f"{where}: docs.{name}", f"{file!r} is not inside the model directory")
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{where}: docs.{name}", f"cannot read {file!r} ({exc})") from None


def _drive_tables(model: ModelFile, where: str) -> DriveTables:
    tables = {}
    for name, drive in model.drives.items():
        try:
            tables[name] = size_class(**msgspec.structs.asdict(drive))
        except (ValueError, KeyError) as exc:
            raise ModelFileError(f"{where}: drives.{name}", str(exc)) from None
        for param, info in tables[name].items():
            if not info.min <= info.value <= info.max:
                raise ModelFileError(
                    f"{where}: drives.{name}",
                    f"gives {param} = {info.value:.4g} {info.unit}, outside [{info.min:g}, {info.max:g}]",
                )
    return tables


def _links_from_rows(model: ModelFile, where: str) -> tuple[list[LinkSpec], DriveTables]:
    assert model.links is not None
    drives = _drive_tables(model, where)
    if model.joints:
        raise ModelFileError(f"{where}: joints", "is for URDF models; a `links` row names its drive")
    links = []
    for i, row in enumerate(model.links):
        at = f"{where}: links[{i}]"
        if row.drive not in drives:
            raise ModelFileError(
                f"{at}.drive", f"{row.drive!r} is not one of the drives ({', '.join(drives) or 'none'})"
            )
        if not row.joint_min < row.joint_max:
            raise ModelFileError(
                f"{at}.joint_min", f"{row.joint_min:g} is not below joint_max {row.joint_max:g}"
            )
        if abs(row.final[0]) > 1e-12:
            raise ModelFileError(f"{at}.final", "has no x component in the Link convention (x is `length`)")
        if row.length > row.length_max:
            raise ModelFileError(f"{at}.length", f"{row.length:g} m is above length_max {row.length_max:g} m")
        if (row.com is None) != (row.inertia is None):
            raise ModelFileError(at, "give com and inertia together, or neither (a uniform tube)")
        if row.inertia is not None and len(row.inertia) not in (3, 6):
            raise ModelFileError(f"{at}.inertia", "has 3 values (principal) or 6 (ixx iyy izz ixy ixz iyz)")
        links.append(
            LinkSpec(
                name=row.name,
                rpy=_t3(row.rpy),
                length=row.length,
                final=_t3(row.final),
                joint_min=row.joint_min,
                joint_max=row.joint_max,
                mass=row.mass,
                radius=row.radius,
                drive=row.drive,
                length_max=row.length_max,
                com=None if row.com is None else _t3(row.com),
                inertia=None if row.inertia is None else tuple(row.inertia),
                color=(row.color[0], row.color[1], row.color[2]),
            )
        )
    if not links:
        raise ModelFileError(f"{where}: links", "is empty")
    return links, drives


def _visuals(chain: UrdfChain, links: list[LinkSpec], near: Path, collision: bool = False) -> list[Visual]:
    """The URDF's visuals (or collision solids) as parts: those fixed to the world, then each link's."""
    out = []
    kind = "collisions" if collision else "visuals"
    parts = [(-1, "base", getattr(chain, f"base_{kind}"), (150, 150, 160))]
    parts += [(i, f"link{i + 1}", getattr(lk, kind), links[i].color) for i, lk in enumerate(chain.links)]
    for link, prefix, geometries, color in parts:
        for k, geo in enumerate(geometries):
            out.append(
                Visual(link=link, name=f"{prefix}.{k}", geometry=geo, near=near, color=geo.color or color)
            )
    return out


def _urdf_chain(directory: Path, source: UrdfSource, where: str) -> tuple[UrdfChain, Path]:
    try:
        path = resolve_uri(source.file, directory)
    except UrdfError as exc:
        raise ModelFileError(f"{where}: urdf.file", exc.reason) from None
    try:
        robot = read_urdf(path)
        return serial_chain(robot, source.base_link, source.tool_link, source.locked_joints), path.parent
    except UrdfError as exc:
        raise ModelFileError(path.name, str(exc)) from None


def _links_from_urdf(model: ModelFile, chain: UrdfChain, where: str) -> tuple[list[LinkSpec], DriveTables]:
    drives = _drive_tables(model, where)
    known = {lk.joint for lk in chain.links}
    for name in model.joints:
        if name not in known:
            raise ModelFileError(
                f"{where}: joints.{name}", f"is not a movable joint of the chain ({', '.join(sorted(known))})"
            )
    links = []
    for i, lk in enumerate(chain.links):
        options = model.joints.get(lk.joint, JointOptions())
        drive = options.drive
        if drive == "auto":
            if not (lk.effort > 0 and lk.velocity > 0):
                raise ModelFileError(
                    f"{where}: joints.{lk.joint}.drive",
                    "the URDF gives this joint no effort and velocity limit to size its drive: "
                    "name a drive class",
                )
            drive = f"auto_{lk.joint}"
            drives[drive] = size_class(**size_for_limits(lk.effort, lk.velocity))
        elif drive not in drives:
            raise ModelFileError(
                f"{where}: joints.{lk.joint}.drive",
                f"{drive!r} is not one of the drives ({', '.join(model.drives) or 'none'})",
            )
        color = options.color or next((g.color for g in lk.visuals if g.color), None) or (200, 200, 210)
        links.append(
            LinkSpec(
                name=f"link{i + 1}",
                rpy=lk.rpy,
                length=lk.length,
                final=lk.final,
                joint_min=lk.lower,
                joint_max=lk.upper,
                mass=lk.mass,
                radius=options.radius or drawn_radius(lk.effort),
                drive=drive,
                length_max=max(3.0, 2.0 * lk.length),
                com=lk.com,
                inertia=lk.inertia,
                color=(int(color[0]), int(color[1]), int(color[2])),
                source_joint=lk.joint,
            )
        )
    return links, drives


def drawn_radius(effort: float) -> float:
    """The radius a joint's tube is drawn with when the modeller gives none: a motor's size grows about
    with the cube root of its torque (12 mm per (N m)^(1/3)), between 2 and 8 cm."""
    return min(max(0.012 * effort ** (1.0 / 3.0), 0.02), 0.08) if effort > 0 else 0.04


def _urdf_chain_doc(chain: UrdfChain) -> str:
    """How an imported chain maps onto the Link convention, for the model's chain page."""
    rows = "\n".join(
        f"| {i + 1} | `{lk.joint}` | {lk.lower:.4g} .. {lk.upper:.4g} | {lk.effort:g} | {lk.velocity:g} | "
        f"{lk.length:.4g} | {lk.final[2]:.4g} | {lk.mass:.4g} |"
        for i, lk in enumerate(chain.links)
    )
    deg = ", ".join(f"{math.degrees(a):.4g}" for a in chain.base_rpy)
    return (
        f"Imported from the URDF robot `{chain.robot}`: the serial chain from link `{chain.base_link}` to "
        f"link `{chain.tool_link}` (the tool frame). Links joined by fixed or locked joints are one body, "
        "their masses and inertias merged. Each joint's frame has its z axis on the URDF axis, turned so "
        "the way to the next joint lies along the link's x (`length`) and z (`final`).\n\n"
        f"Joint 1's frame: at {list(chain.base_translation)} m, turned by rpy ({deg}) deg.\n\n"
        "| joint | URDF joint | range, rad | effort, N m | velocity, rad/s | length, m | final z, m "
        "| mass, kg |\n"
        "|---|---|---|---|---|---|---|---|\n" + rows + "\n"
    )
