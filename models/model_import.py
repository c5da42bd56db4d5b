"""`simecs model import` and `simecs model check`: a URDF to a starting model directory, and the check
of a model directory with what was found in it.

The import writes what it decided where a modeller can see and change it: the drive classes sized
from the URDF's limits written out in full (not "auto"), the joints it locked, the home posture, and
an assumptions page saying so. `check` loads the directory the way a simulator does, prints the chain,
the drives and the masses, and runs a short move under the drives unless told not to.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TextIO

from simecs.mesh.process.files import parse_json5

from .drives_catalog import size_for_limits
from .model_file import FORMAT, MODEL_FILE, ModelFileError, load_model_dir
from .urdf import UrdfError, UrdfJoint, UrdfRobot, read_urdf
from .urdf_chain import UrdfChain, default_tool_link, serial_chain


def _lock_value(joint: UrdfJoint) -> float:
    return min(max(0.0, joint.lower), joint.upper) if joint.type in ("revolute", "prismatic") else 0.0


def off_chain_locks(robot: UrdfRobot, base_link: str, tool_link: str) -> dict[str, float]:
    """Every movable joint that is not on the way from base to tool, locked at 0 (or its nearest limit)."""
    on_path = set()
    link = tool_link
    while link != base_link:
        joint = robot.parent_joint(link)
        if joint is None:
            break
        on_path.add(joint.name)
        link = joint.parent
    return {
        j.name: _lock_value(j)
        for j in robot.joints.values()
        if j.name not in on_path and j.type in ("revolute", "continuous", "prismatic")
    }


def _uri_for(urdf: Path, out: Path) -> str:
    """The URDF as the model file names it: package://<package>/... inside an installed package's share
    folder (as example-robot-data installs), else its path relative to the model directory."""
    parts = urdf.resolve().parts
    if "cmeel.prefix" in parts:
        at = parts.index("cmeel.prefix")
        if parts[at + 1 : at + 2] == ("share",) and len(parts) > at + 3:
            return "package://" + "/".join(parts[at + 2 :])
    return os.path.relpath(urdf.resolve(), out.resolve())


def _rounded(table: Mapping[str, float]) -> dict[str, float]:
    """Four significant digits: a table a modeller reads and tunes, not a float dump."""
    return {k: (v if isinstance(v, int) else float(f"{v:.4g}")) for k, v in table.items()}


def import_urdf(
    urdf: str | Path,
    out: str | Path,
    *,
    model_id: str = "",
    base_link: str = "",
    tool_link: str = "",
    locked: Mapping[str, float] | None = None,
    drives: Mapping[str, Any] | None = None,
    log: TextIO = sys.stdout,
) -> Path:
    """Write a model directory for `urdf` into `out`, check it by loading it, and return its path.
    `drives`: a table {"drives": {class: {...}}, "joints": {joint: {"drive": class}}}; without one, each
    joint's drive is sized from its URDF limits and written out as its own class."""
    urdf = Path(urdf)
    out = Path(out)
    robot = read_urdf(urdf)
    base = base_link or robot.root()
    locks = dict(locked or {})
    tool = tool_link or default_tool_link(robot, base, locks)
    locks = {**off_chain_locks(robot, base, tool), **locks}
    chain: UrdfChain = serial_chain(robot, base, tool, locks)
    model_id = model_id or "".join(c if c.isalnum() or c in "_-" else "_" for c in robot.name.lower())[:32]
    classes: dict[str, Any] = dict((drives or {}).get("drives", {}))
    joints: dict[str, Any] = dict((drives or {}).get("joints", {}))
    for lk in chain.links:
        if lk.joint in joints:
            continue
        if not (lk.effort > 0 and lk.velocity > 0):
            raise UrdfError(
                f'joint "{lk.joint}"',
                "has no effort and velocity limit to size its drive from: give a drive table (--drives FILE)",
            )
        name = f"{lk.joint}_drive"
        classes[name] = _rounded(size_for_limits(lk.effort, lk.velocity))
        joints[lk.joint] = {"drive": name}
    home = [min(max(0.0, lk.lower), lk.upper) for lk in chain.links]
    out.mkdir(parents=True, exist_ok=True)
    document: dict[str, Any] = {
        "format": FORMAT,
        "id": model_id,
        "name": f"{robot.name} (joint-independent control)",
        "summary": f"{len(chain.links)}-joint arm imported from {urdf.name}, "
        + ("drives from the given table" if drives else "drives sized from its URDF limits"),
        "docs": {"assumptions": "assumptions.md"},
        "urdf": {
            "file": _uri_for(urdf, out),
            "base_link": chain.base_link,
            "tool_link": chain.tool_link,
            "locked_joints": locks,
        },
        "drives": classes,
        "joints": joints,
        "home": home,
    }
    text = (
        f"// Written by `simecs model import {urdf.name}`: a starting point, edit it (docs/MODELS.md).\n"
        + json.dumps(document, indent=2)
        + "\n"
    )
    (out / MODEL_FILE).write_text(text, encoding="utf-8")
    (out / "assumptions.md").write_text(
        _assumptions(urdf, chain, locks, drives is not None), encoding="utf-8"
    )
    spec = load_model_dir(out)
    print(f"wrote {out / MODEL_FILE}: model {spec.id!r}, {len(spec.links)} joints", file=log)
    return out


def _assumptions(urdf: Path, chain: UrdfChain, locks: Mapping[str, float], table: bool) -> str:
    locked = ", ".join(f"`{k}` at {v:g}" for k, v in locks.items()) or "none"
    drives = (
        "from the drive table given to the import"
        if table
        else "sized from each joint's URDF effort and velocity limits by the rule of docs/MODELS.md "
        '("Drives sized from a URDF\'s limits"), written out in model.json5 to be tuned'
    )
    return (
        f"**Source.** `{urdf.name}` (robot `{chain.robot}`), from `{chain.base_link}` to the tool frame "
        f"`{chain.tool_link}`.\n\n**Locked joints** (off the chain, or chosen): {locked}.\n\n"
        f"**Drives** {drives}.\n\n**Gravity** is off, as for every model of this library.\n"
    )


def check_model(directory: str | Path, *, run: bool = True, log: TextIO = sys.stdout) -> bool:
    """Load a model directory as a simulator would and print what it holds; False (and the reason
    printed) if it is refused or its short run fails."""
    directory = Path(directory)
    if directory.name == MODEL_FILE:
        directory = directory.parent
    try:
        spec = load_model_dir(directory)
    except ModelFileError as exc:
        print(f"refused: {exc}", file=log)
        return False
    from . import ModelPackage

    package = ModelPackage(spec)
    d = package.describe()
    print(f"model {spec.id!r}: {spec.name}", file=log)
    print(
        f"  {len(spec.links)} joints, {len(d.parameters)} parameters, {len(d.variables)} variables, "
        f"{len(d.docs)} doc pages",
        file=log,
    )
    print(
        f"  base at {list(spec.base_translation)} m, rpy {[round(a, 6) for a in spec.base_rpy]} rad; "
        f"tool {list(spec.tool_translation)} m",
        file=log,
    )
    print("  joint  from          range (rad)          length (m)  mass (kg)  drive", file=log)
    for i, lk in enumerate(spec.links, start=1):
        info = spec.drives[lk.drive]
        print(
            f"  {i:>5}  {(lk.source_joint or lk.name)[:12]:<12}  [{lk.joint_min:>8.4f}, {lk.joint_max:>8.4f}]"
            f"  {lk.length:>10.4f}  {lk.mass:>9.3f}  {lk.drive} (n {info['gear.ratio'].value:g}, "
            f"kt {info['motor.kt'].value:.3g} N m/A, i_max {info['motor.i_max'].value:.3g} A)",
            file=log,
        )
    total = sum(lk.mass for lk in spec.links)
    print(f"  arm mass {total:.3f} kg, payload {spec.payload_mass:g} kg", file=log)
    if not run:
        return True
    from .errors import SimulationError

    sim = package.build({})
    try:
        sim.set_initial(list(package.home()))
        target = list(spec.standard_target)
        sim.set_joint_path([(target, 100.0, 100.0)])
        stop = sim.set_points.path_duration() + 0.5
        sim.start(stop, 0.01)
        rows = sim.advance(stop)
        columns = list(sim.columns)
        q = [rows[-1, columns.index(f"joint{j}.q")] for j in range(1, len(spec.links) + 1)]
        miss = max(abs(a - b) for a, b in zip(q, target, strict=True))
    except SimulationError as exc:
        print(f"  the standard move failed: {exc}", file=log)
        return False
    finally:
        sim.close()
    ok = miss < 5e-3
    print(
        f"  standard move (home to standard_target, {stop:.2f} s): largest miss {miss * 1e3:.3f} mrad "
        f"{'ok' if ok else 'TOO LARGE (tune the drives)'}",
        file=log,
    )
    return ok


def read_drive_table(path: str | Path) -> dict[str, Any]:
    """A drive table file for the import: JSON5 {drives: {class: {...}}, joints: {joint: {drive: class}}}."""
    try:
        table = parse_json5(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ModelFileError(str(path), f"cannot read the drive table ({exc})") from None
    if not isinstance(table, dict) or set(table) - {"drives", "joints"}:
        raise ModelFileError(str(path), "a drive table is an object with `drives` and `joints`")
    return table
