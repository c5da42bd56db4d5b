"""Model files and URDF import: the shipped library, refusals that name their element, the CLI.

The imported chains are judged against yourdfpy (testing/urdf_reference.py, an independent reading
of the same URDF): tool poses on random configurations, and the mass, COM and inertia of the arm.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from simecs import models
from simecs.mesh.client import RemoteError
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules.kinematics import link_frames, rot_rpy
from simecs.models.model_file import ModelFileError, load_model_dir
from simecs.models.urdf import UrdfError, read_urdf
from simecs.testing.urdf_reference import UrdfReference, urdf_models

from tests.conftest import Mesh, Service, start_service, wait_until

URDF_MODELS = urdf_models()


def test_the_library_holds_five_models_defined_one_way() -> None:
    ids = [m.id for m in models.list_models()]
    assert ids[:2] == ["spider", "puma560"] and len(ids) >= 5
    assert set(URDF_MODELS) >= {"panda", "ur5", "jaco2"}
    for directory in models.library_dirs():
        assert (directory / "model.json5").is_file()
        assert models.get_model(directory.name).spec.source == directory


@pytest.mark.parametrize("model_id", URDF_MODELS)
def test_imported_kinematics_match_an_independent_urdf_reader(model_id: str) -> None:
    ref = UrdfReference(model_id)
    rng = np.random.default_rng(7)
    worst = max(ref.tool_error(ref.random_q(rng)) for _ in range(40))
    assert worst < 1e-9, f"{model_id}: tool pose {worst:.2e} off yourdfpy's"


@pytest.mark.parametrize("model_id", URDF_MODELS)
def test_imported_masses_and_inertias_match_the_urdf(model_id: str) -> None:
    """The merged bodies carry the URDF's mass, centre of mass and inertia (about the world origin) in
    every posture: what the dynamics needs of the conversion."""
    ref = UrdfReference(model_id)
    rng = np.random.default_rng(3)
    for _ in range(5):
        theirs, ours = ref.mass_properties(ref.random_q(rng))
        assert abs(theirs[0] - ours[0]) < 1e-12
        assert np.abs(np.array(theirs) - np.array(ours)).max() < 1e-9


#: The PUMA 560's joint ranges (deg) in its standard DH convention: the qlim of Corke's Robotics Toolbox
#: (roboticstoolbox-python models/DH/Puma560.py, MATLAB mdl_puma560.m; limits from Wang & Chen, IEEE
#: Trans. RA 7(4) 1991), whose DH table exudyn's ManipulatorPuma560 repeats.
PUMA_QLIM_DEG = [(-160, 160), (-45, 225), (-225, 45), (-110, 170), (-100, 100), (-266, 266)]


def test_the_puma_file_holds_exudyns_puma_560() -> None:
    """The PUMA's rows in its model file are exudyn.robotics' DH table and link data, converted: the
    standard DH row [theta, d, a, alpha] is Rx(alpha), length a, final (0, d sin alpha, d cos alpha).
    Its joint ranges are the Robotics Toolbox's for the same DH table (exudyn's jointLimits are in
    another convention: its joint 2 down to -170 deg would put the upper arm through the pedestal)."""
    from exudyn.robotics.models import ManipulatorPuma560

    spec = models.get_model("puma560").spec
    for lk, ref, qlim in zip(spec.links, ManipulatorPuma560()["links"], PUMA_QLIM_DEG, strict=True):
        theta, dd, a, alpha = (float(v) for v in ref["stdDH"])
        final = np.array([0.0, dd * math.sin(alpha), dd * math.cos(alpha)])
        assert lk.rpy == (alpha, 0.0, 0.0) and lk.length == a
        assert np.allclose(lk.final, final, atol=1e-15)
        assert np.allclose(lk.com, np.asarray(ref["COM"], float) + np.array([a, 0, 0]) + final, atol=1e-15)
        assert np.allclose(lk.inertia, np.diag(np.asarray(ref["inertia"], float)))
        assert lk.mass == ref["mass"]
        assert [lk.joint_min, lk.joint_max] == pytest.approx([math.radians(v) for v in qlim], abs=1e-12)
    # the Toolbox's named postures are inside them: zero ('L'), ready (arm up), stretched
    for q in ([0.0] * 6, [0, math.pi / 2, -math.pi / 2, 0, 0, 0], [0, 0, -math.pi / 2, 0, 0, 0]):
        assert all(lk.joint_min <= v <= lk.joint_max for lk, v in zip(spec.links, q, strict=True))


# -- refusals --------------------------------------------------------------------------------------
ARM = """<?xml version="1.0"?>
<robot name="arm3">
  <link name="base"/>
  <link name="l1"><inertial><mass value="2"/><inertia ixx="0.02" iyy="0.02" izz="0.01"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.15 0 0"/><mass value="1.5"/>
    <inertia ixx="0.002" iyy="0.015" izz="0.015"/></inertial></link>
  <link name="l3"><inertial><mass value="0.5"/><inertia ixx="0.001" iyy="0.001" izz="0.001"/></inertial>
    <visual><geometry><cylinder radius="0.03" length="0.1"/></geometry></visual></link>
  <link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="40" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.1" rpy="1.5708 0 0"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="40" velocity="2"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="3"/></joint>
  <joint name="flange" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.1 0 0"/></joint>
</robot>
"""

BAD_URDFS = [
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>', 'joint "j3": axis [0, 0, 0] is not a unit vector'),
    (
        'name="j2" type="revolute"',
        'name="j2" type="prismatic"',
        'joint "j2": prismatic joints are not supported',
    ),
    ('<parent link="l2"/>', '<parent link="nope"/>', 'joint "j3": parent link "nope" is not defined'),
    ('<mass value="1.5"/>', '<mass value="-1.5"/>', 'link "l2": mass -1.5 kg is negative'),
    ('lower="-2" upper="2" effort="10"', 'lower="2" upper="-2" effort="10"', 'joint "j3": limit lower 2'),
    ('<origin xyz="0.3 0 0"/>', '<origin xyz="0.3 0"/>', "joint \"j3\": origin xyz '0.3 0' is not 3 numbers"),
    (
        "</robot>",
        '<joint name="loop" type="fixed"><parent link="l3"/><child link="l1"/></joint></robot>',
        "closed loops are not supported",
    ),
    (
        "</robot>",
        '<link name="l4"/><joint name="j4" type="revolute"><parent link="l1"/><child link="l4"/>'
        '<axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>',
        'link "l1": the chain branches here',
    ),
    (
        'iyy="0.015" izz="0.015"',
        'iyy="0.015" izz="0.1"',
        'link "l2": inertia violates the triangle inequality',
    ),
    ("</robot>", "</robt>", "not well-formed XML"),
]


def _model_dir(tmp_path: Path, urdf_text: str, extra: str = "") -> Path:
    (tmp_path / "arm3.urdf").write_text(urdf_text)
    (tmp_path / "assumptions.md").write_text("A three-joint test arm.\n")
    (tmp_path / "model.json5").write_text(
        '{format: 1, id: "arm3", name: "Arm 3", summary: "test arm", docs: {assumptions: "assumptions.md"},'
        f' urdf: {{file: "arm3.urdf"}}, {extra}}}'
    )
    return tmp_path


@pytest.mark.parametrize("old,new,message", BAD_URDFS)
def test_a_malformed_urdf_is_refused_naming_its_element(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    assert old in ARM
    directory = _model_dir(tmp_path, ARM.replace(old, new, 1))
    with pytest.raises(ModelFileError) as refused:
        load_model_dir(directory)
    assert message in str(refused.value) and "arm3.urdf" in str(refused.value)


def test_a_good_urdf_loads_and_its_chain_is_what_the_file_says(tmp_path: Path) -> None:
    spec = load_model_dir(_model_dir(tmp_path, ARM))
    assert [lk.source_joint for lk in spec.links] == ["j1", "j2", "j3"]
    assert spec.base_translation == (0.0, 0.0, 0.3)
    # joint 1 to joint 2 is 0.1 m across joint 2's axis: a length, like a DH row's a
    assert [round(lk.length, 9) for lk in spec.links] == [0.1, 0.3, 0.1]
    assert all(abs(lk.final[2]) < 1e-5 for lk in spec.links)  # rpy 1.5708 is not quite pi/2
    assert sum(lk.mass for lk in spec.links) == 4.0
    # joint 3 turns about l2's y axis: its frame's z is that axis
    pkg = models.ModelPackage(spec)
    frames = link_frames(pkg.describe(), pkg.describe().default_values(), [0.0, 0.0, 0.0])
    assert np.allclose(frames[-1][0], [0.4, 0.0, 0.4], atol=1e-4)  # the flange, 0.3 + 0.1 along l2's x
    with pytest.raises(UrdfError, match='locked_joints "j9": is not a joint'):
        from simecs.models.urdf_chain import serial_chain

        serial_chain(read_urdf(tmp_path / "arm3.urdf"), locked_joints={"j9": 0.0})


@pytest.mark.parametrize(
    "extra,message",
    [
        ("mas: 1", "model.json5: mas: unknown field"),
        ('joints: {j2: {drive: "big"}}', "joints.j2.drive: 'big' is not one of the drives"),
        ('joints: {j7: {drive: "auto"}}', "joints.j7: is not a movable joint"),
        ("home: [0, 0]", "home: 2 values for a 3-joint arm"),
        ("home: [0, 0, 2.5]", "home[2]: 2.5 rad is outside joint 3's range"),
        ("links: [], drives: {}", "give the chain as either `links` or `urdf`"),
        ('urdf: {file: "missing.urdf"}', "urdf.file: no such file"),
        ("payload: {mass: -1}", "payload.mass"),
    ],
)
def test_a_bad_model_file_is_refused_naming_its_field(tmp_path: Path, extra: str, message: str) -> None:
    directory = _model_dir(tmp_path, ARM, extra)
    if "urdf:" in extra:  # replace, not repeat, the urdf entry
        text = (directory / "model.json5").read_text().replace(' urdf: {file: "arm3.urdf"},', "")
        (directory / "model.json5").write_text(text)
    with pytest.raises(ModelFileError) as refused:
        load_model_dir(directory)
    assert message in str(refused.value)


def test_a_model_file_of_another_format_is_refused(tmp_path: Path) -> None:
    directory = _model_dir(tmp_path, ARM)
    (directory / "model.json5").write_text(
        (directory / "model.json5").read_text().replace("format: 1", "format: 2")
    )
    with pytest.raises(ModelFileError, match="format: 2 is not a format this simecs reads"):
        load_model_dir(directory)


# -- the command line ------------------------------------------------------------------------------
def simecs(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "simecs.nodes.tools.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_model_import_writes_a_model_that_checks_and_runs(tmp_path: Path) -> None:
    (tmp_path / "arm3.urdf").write_text(ARM)
    out = tmp_path / "arm3_model"
    done = simecs("model", "import", str(tmp_path / "arm3.urdf"), "--out", str(out), "--tool-link", "tool")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "standard move" in done.stdout and "ok" in done.stdout
    spec = load_model_dir(out)
    assert spec.id == "arm3" and [lk.drive for lk in spec.links] == ["j1_drive", "j2_drive", "j3_drive"]
    # the sized drives are written out in full, for the modeller to tune
    text = (out / "model.json5").read_text()
    assert '"ratio": 150.0' in text and '"auto"' not in text
    checked = simecs("model", "check", str(out), "--no-run")
    assert checked.returncode == 0 and "3 joints" in checked.stdout


def test_model_check_names_what_it_refuses(tmp_path: Path) -> None:
    directory = _model_dir(tmp_path, ARM.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>'))
    done = simecs("model", "check", str(directory))
    assert done.returncode == 1
    assert 'refused: arm3.urdf: joint "j3": axis [0, 0, 0] is not a unit vector' in done.stdout


def test_the_shipped_models_check(tmp_path: Path) -> None:
    done = simecs("model", "check", str(models.LIBRARY / "ur5"))
    assert done.returncode == 0, done.stdout
    assert "shoulder_pan" in done.stdout and "largest miss" in done.stdout


def test_rpy_round_trip() -> None:
    from simecs.mesh.rules.kinematics import rpy_of

    rng = np.random.default_rng(0)
    for rpy in [*rng.uniform(-3, 3, (50, 3)), (0.3, math.pi / 2, 0.2), (0.1, -math.pi / 2, 0.4)]:
        R = rot_rpy(rpy)
        assert np.abs(rot_rpy(rpy_of(R)) - R).max() < 1e-12


def test_the_proxy_serves_each_mesh_a_model_names(service: Service) -> None:
    client = service.client
    desc = client.describe("panda")
    names = desc.mesh_names()
    assert "link1.0" in names and "base.0" in names
    data = client.model_mesh("panda", "link4.0")
    assert data[:4] == b"glTF" and int.from_bytes(data[4:8], "little") == 2
    with pytest.raises(RemoteError) as missing:
        client.model_mesh("panda", "link9.0")
    assert missing.value.code == "not_found" and "link1.0" in str(missing.value)
    with pytest.raises(RemoteError) as unknown:
        client.model_mesh("nope", "link1.0")
    assert unknown.value.code == "not_found"
    assert client.describe("spider").mesh_names() == []
    # a name no mesh can have: refused naming the chunk, not an internal error
    for bad in ("a b", "x" * 65, "ü"):
        replies = list(client.z.get(f"simecs/library/panda/mesh/{bad}", timeout=5))
        assert len(replies) == 1 and replies[0].err is not None, bad
        error = codec.loads(m.Error, replies[0].err.payload.to_bytes())
        assert (error.code, error.field) == ("bad_request", "mesh") and "mesh name" in error.message, error


def test_a_hosts_own_model_joins_the_library_and_runs(mesh: Mesh, tmp_path: Path) -> None:
    """A simulator started with --models offers its model: the proxy fetches it (a bundle of the
    directory with its URDF), lists and describes it, keeps it over its restart, and runs go to the
    host; a broken model directory beside it is left out, and the host runs on."""
    own = tmp_path / "own"
    (own / "arm3").mkdir(parents=True)
    _model_dir(own / "arm3", ARM)
    broken = own / "broken"
    broken.mkdir()
    (broken / "model.json5").write_text("{format: 1, id: 'broken'")
    data = start_service(mesh, extra_simulator=("--models", str(own))).data_dir
    client = mesh.client()
    wait_until(lambda: "arm3" in [m.id for m in client.list_models()], timeout=60, what="arm3 in the library")
    desc = client.describe("arm3")
    assert [lk.joint for lk in desc.links] == ["joint1", "joint2", "joint3"] and desc.docs
    assert (data / "models" / "arm3" / "urdf" / "robot.urdf").is_file()
    assert "broken" in mesh.log("simulator") and "model left out" in mesh.log("simulator")
    s = client.create_session("ann", "arm3")
    target = [0.4, -0.3, 0.5]
    s.set_joint_path([(target, 100.0, 100.0)])
    s.set_settings(stop_time=2.5, output_interval=0.01, pacing="fast")
    run_id = s.run()
    state = s.wait_for(["finished", "failed"], 60, run_id)
    assert state.phase == "finished", state.reason
    columns, rows = s.results(run_id)
    q = [rows[-1, columns.index(f"joint{j}.q")] for j in (1, 2, 3)]
    assert np.max(np.abs(np.array(q) - target)) < 2e-3
    # the proxy keeps it: after a restart it describes it before any host says a word
    mesh.stop("simulator")
    mesh.stop("proxy")
    mesh.start("proxy", "--data-dir", str(data), "--max-running", "4")
    assert client.describe("arm3").id == "arm3"


def test_a_bundle_carries_a_urdf_model_whole_and_hostile_ones_are_refused(tmp_path: Path) -> None:
    import io
    import tarfile

    from simecs.models.bundle import bundle, unpack

    data = bundle(models.get_model("ur5").spec)
    directory = unpack(data, tmp_path / "in")
    spec = load_model_dir(directory)  # none of example-robot-data needed: its meshes came along
    assert spec.id == "ur5" and len(spec.visuals) == len(models.get_model("ur5").spec.visuals)
    assert all(v.near == directory / "urdf" for v in spec.visuals)
    assert 0 < len(spec.collisions) == len(models.get_model("ur5").spec.collisions)
    assert all((v.near / v.geometry.filename).is_file() for v in spec.collisions if v.geometry.kind == "mesh")
    assert models.ModelPackage(spec).mesh_store().glb("link2.0")[:4] == b"glTF"

    def tar_of(*members: tuple[str, bytes], link: str = "") -> bytes:
        out = io.BytesIO()
        with tarfile.open(fileobj=out, mode="w:gz") as tar:
            for name, body in members:
                info = tarfile.TarInfo(name)
                info.size = len(body)
                tar.addfile(info, io.BytesIO(body))
            if link:
                info = tarfile.TarInfo("m/evil")
                info.type, info.linkname = tarfile.SYMTYPE, link
                tar.addfile(info)
        return out.getvalue()

    for bad, why in [
        (b"not a tar at all", "not a gzip-compressed tar"),
        (tar_of(("m/../../escape", b"x")), "is not a plain file inside the model"),
        (tar_of(("/abs/model.json5", b"x")), "is not a plain file inside the model"),
        (tar_of(("m/model.json5", b"{}"), link="/etc/passwd"), "is not a plain file inside the model"),
        (tar_of(("a/model.json5", b"{}"), ("b/model.json5", b"{}")), "must hold one model directory"),
    ]:
        with pytest.raises(ModelFileError, match=why):
            unpack(bad, tmp_path / "bad")
    assert not (tmp_path.parent / "escape").exists()
