"""Robot models: physics built in Exudyn and their descriptions as data.

from simecs.models import list_models, get_model
pkg = get_model("spider"); sim = pkg.build({}); sim.set_initial([0]*7)
sim.set_joint_path([([0.5]*7, 100, 100)]); sim.start(5.0, 0.01); rows = sim.advance(0.02) ...

The modules, from the data a model author writes to the running simulation (docs/MODELS.md):
model_file (a model directory: model.json5, read into an ArmSpec), urdf and urdf_chain (a URDF's
serial chain), library/ (the shipped model directories), spec (ArmSpec), drives_catalog (drive size
classes and the sizing rule), description (what clients see), docs (its hypertext pages), mechanics
(arrays and initial states), chain_dynamics and drive (numba kernels: the rigid chain, the drive
train), exudyn_chain (the Exudyn system), simulation (one run), package (ModelPackage).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.model import ModelSummary

from .errors import CommandError, ParameterError, SimulationError
from .model_file import MODEL_FILE, ModelFileError, load_model_dir
from .package import ModelPackage
from .simulation import Simulation

__all__ = [
    "list_models",
    "get_model",
    "ModelPackage",
    "Simulation",
    "CommandError",
    "ParameterError",
    "SimulationError",
    "ModelFileError",
    "load_model_dir",
    "warmup",
    "costs",
    "forget_library",
]

_REGISTRY: dict[str, ModelPackage] = {}

#: The shipped models, one directory each (model_file.py reads them; docs/MODELS.md says how to write one).
LIBRARY = Path(__file__).parent / "library"


#: Where a host's own models are: model directories, or folders of them, separated by os.pathsep.
EXTRA_ENV = "SIMECS_MODELS"
_PROBLEMS: list[str] = []


def library_dirs() -> list[Path]:
    """The model directories of the shipped library, in the order clients list them."""
    order = ["spider", "puma560", "panda", "ur5", "jaco2"]
    found = sorted(p for p in LIBRARY.iterdir() if (p / MODEL_FILE).is_file())
    return sorted(found, key=lambda p: (order.index(p.name) if p.name in order else len(order), p.name))


def extra_dirs() -> list[Path]:
    """The model directories named by SIMECS_MODELS (a host's own models, offered on the mesh)."""
    out = []
    for entry in os.environ.get(EXTRA_ENV, "").split(os.pathsep):
        if not entry:
            continue
        path = Path(entry)
        if (path / MODEL_FILE).is_file():
            out.append(path)
        elif path.is_dir():
            out.extend(sorted(p for p in path.iterdir() if (p / MODEL_FILE).is_file()))
        else:
            _PROBLEMS.append(f"{EXTRA_ENV}: {entry} is neither a model directory nor a folder of them")
    return out


def _load() -> dict[str, ModelPackage]:
    if not _REGISTRY:
        for directory in library_dirs():
            spec = load_model_dir(directory)
            _REGISTRY[spec.id] = ModelPackage(spec)
        for directory in extra_dirs():  # a bad one is reported and left out: the host runs on
            try:
                spec = load_model_dir(directory)
            except ModelFileError as exc:
                _PROBLEMS.append(str(exc))
                continue
            if spec.id in _REGISTRY:
                _PROBLEMS.append(f"{directory}: model id {spec.id!r} is already in the library")
                continue
            _REGISTRY[spec.id] = ModelPackage(spec)
    return _REGISTRY


def add_model(directory: Path) -> ModelPackage:
    """Load a model directory into this process's library (the proxy, for a host's own model);
    ModelFileError if it is refused. A model of the same id is replaced."""
    spec = load_model_dir(directory)
    _load()[spec.id] = package = ModelPackage(spec)
    return package


def forget_library() -> None:
    """Forget the models read so far (the compiled kernels stay): a process forked from a warm one
    reads the library again, with its own SIMECS_MODELS (mesh/process/forks.py)."""
    _REGISTRY.clear()
    _PROBLEMS.clear()


def load_problems() -> list[str]:
    """Why model directories of SIMECS_MODELS were left out."""
    _load()
    return list(_PROBLEMS)


def list_models() -> list[ModelSummary]:
    """One summary per model of the library, in registration order."""
    return [p.describe().summary_entry() for p in _load().values()]


def get_model(model_id: str) -> ModelPackage:
    """The model `model_id`; KeyError naming the known ids otherwise."""
    reg = _load()
    if model_id not in reg:
        raise KeyError(f"unknown model {model_id!r}; known: {', '.join(sorted(reg))}")
    return reg[model_id]


def costs(seconds: float = 0.25) -> dict[str, float]:
    """CPU s per simulated s of each model (default values, a joint move, the default step): the
    simulator's first estimate of what a run costs, until its runs measure it (mesh/rules/load.py)."""
    import time

    out = {}
    for model_id, package in _load().items():
        sim = package.build({})
        try:
            home = package.home()
            sim.set_initial(list(home))
            sim.set_joint_path([(list(package.spec.standard_target), 100.0, 100.0)])
            sim.start(seconds, 0.002)
            t0 = time.process_time()
            sim.advance(seconds)
            out[model_id] = (time.process_time() - t0) / seconds
        finally:
            sim.close()
    return out


def warmup(alongside: bool = False) -> float:
    """Compile (or load from the numba cache) the drive kernels; returns the seconds it took.
    `alongside`: the planner's kernels compile in a second process meanwhile, on another core (`make
    warm` on a fresh clone: a cold compile is about 45 s for the drives and 17 s for the planner)."""
    import subprocess
    import sys
    import time

    t0 = time.perf_counter()
    helper = None
    if alongside:
        code = "from simecs.models.planner import warmup; warmup()"
        helper = subprocess.Popen([sys.executable, "-c", code])
    sim = get_model("spider").build({})
    sim.set_initial([0.0] * sim.n)
    sim.set_joint_path([([0.01] * sim.n, 100.0, 100.0)])
    sim.start(0.004, 0.002)
    sim.advance(0.002)
    sim.sensors(np.empty(1 + 9 * sim.n))  # the external controller's sensor kernel
    sim.advance(0.004)
    sim.set_control("opspace_motion", 0.002)  # the operational-space controller's kernel
    sim.start(0.004, 0.002)
    sim.advance(0.004)
    sim.set_points.set_forces(np.array([[0.0, 0.0, 0.0, -1.0, 1.0]]))  # the hybrid one reads the tool's force
    sim.set_control("opspace_hybrid", 0.002)
    sim.start(0.004, 0.002)
    sim.advance(0.004)
    sim.close()
    # contact with the drives off (a new simulation: values set during a run wait for their time)
    sim = get_model("spider").build({"drives.enabled": 0.0})
    sim.set_obstacles([Obstacle(name="warmup", kind="box", position=[2.0, 2.0, 2.0])])
    sim.start(0.004, 0.002)
    sim.advance(0.004)
    sim.close()
    from .planner import warmup as warm_planner

    if helper is not None and helper.wait() != 0:
        print("the planner's compile alongside failed: compiled here", file=sys.stderr)
    warm_planner()  # from the cache the helper filled, or compiled here
    return time.perf_counter() - t0
