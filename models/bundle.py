"""A model directory as one file: how a simulator host hands a model of its own to the proxy.

`bundle` packs model.json5, its documentation pages and, for a URDF model, the URDF and every mesh
file it names (rewritten to point inside the bundle), so the receiver needs none of the sender's
installed packages. `unpack` refuses what a hostile bundle could do (paths out of its folder, links,
too many or too large members) and gives the directory `load_model_dir` reads.
"""

from __future__ import annotations

import gzip
import io
import json
import tarfile
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

from simecs.mesh.process.files import parse_json5

from .model_file import MODEL_FILE, ModelFileError, read_model_file
from .spec import ArmSpec
from .urdf import UrdfError, resolve_uri

MAX_MEMBERS = 2000
MAX_BYTES = 256 * 1024 * 1024  # unpacked, all members together
WHERE = "model bundle"


def bundle(spec: ArmSpec) -> bytes:
    """The model directory `spec` was read from, with what it references, as a tar.gz."""
    if spec.source is None:
        raise ValueError(f"model {spec.id} was not read from a model directory")
    directory = spec.source
    model = read_model_file(directory)
    raw = parse_json5((directory / MODEL_FILE).read_text(encoding="utf-8"))
    files: dict[str, bytes] = {}
    for name in (model.docs.assumptions, model.docs.chain):
        if name:
            files[name] = (directory / name).read_bytes()
    if model.urdf is not None:
        urdf_path = resolve_uri(model.urdf.file, directory)
        tree = ET.parse(urdf_path)
        for k, mesh in enumerate(tree.getroot().iter("mesh")):
            filename = mesh.get("filename", "")
            try:
                found = resolve_uri(filename, urdf_path.parent)
            except UrdfError:
                continue  # the receiver refuses it as the sender would have, naming it
            inside = f"meshes/{k}{found.suffix.lower()}"
            files[f"urdf/{inside}"] = found.read_bytes()
            mesh.set("filename", inside)
        out = io.BytesIO()
        tree.write(out, encoding="utf-8", xml_declaration=True)
        files["urdf/robot.urdf"] = out.getvalue()
        raw["urdf"]["file"] = "urdf/robot.urdf"
    files[MODEL_FILE] = (json.dumps(raw, indent=1) + "\n").encode()
    packed = io.BytesIO()
    with tarfile.open(fileobj=packed, mode="w:gz", compresslevel=6) as tar:
        for name in sorted(files):
            info = tarfile.TarInfo(f"{spec.id}/{name}")
            info.size = len(files[name])
            info.mode = 0o644
            tar.addfile(info, io.BytesIO(files[name]))
    return packed.getvalue()


def unpack(data: bytes, into: Path) -> Path:
    """Unpack a bundle under `into`; the model directory it holds. ModelFileError says what was refused."""
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
            return _unpack(tar, into)
    except (tarfile.TarError, EOFError, zlib.error, gzip.BadGzipFile) as exc:
        raise ModelFileError(WHERE, f"not a gzip-compressed tar ({exc})") from None


def _unpack(tar: tarfile.TarFile, into: Path) -> Path:
    members = tar.getmembers()
    if not members or len(members) > MAX_MEMBERS:
        raise ModelFileError(WHERE, f"{len(members)} members (1 to {MAX_MEMBERS})")
    tops = {Path(m.name).parts[0] for m in members if Path(m.name).parts}
    if len(tops) != 1:
        raise ModelFileError(WHERE, "must hold one model directory")
    total = 0
    for member in members:
        parts = Path(member.name).parts
        if member.name.startswith("/") or ".." in parts or not (member.isfile() or member.isdir()):
            raise ModelFileError(WHERE, f"member {member.name!r} is not a plain file inside the model")
        total += member.size
        if total > MAX_BYTES:
            raise ModelFileError(WHERE, f"larger than {MAX_BYTES // (1024 * 1024)} MB unpacked")
    into.mkdir(parents=True, exist_ok=True)
    for member in members:
        if member.isdir():
            continue
        target = into / member.name
        target.parent.mkdir(parents=True, exist_ok=True)
        source = tar.extractfile(member)
        assert source is not None
        target.write_bytes(source.read())
    return into / tops.pop()
