"""The model library as the proxy serves it: descriptions, documentation pages, and the check of
parameter values against a model (its bounds, then the model's own cross-checks)."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import DocPage, ModelDescription, check_values

log = logging.getLogger("simecs.proxy")


class ModelLibrary:
    def __init__(self, hosted_dir: Path | None = None) -> None:
        # The models installed with this server, and those simulator hosts brought (kept in
        # `hosted_dir` over restarts): the proxy uses their descriptions, value checks and planners;
        # simulations run in simulator nodes, reached over the mesh.
        from simecs import models
        from simecs.models.planner import warmup

        self._packages: dict[str, Any] = {s.id: models.get_model(s.id) for s in models.list_models()}
        self.hosted_dir = hosted_dir
        if hosted_dir is not None and hosted_dir.is_dir():
            for directory in sorted(hosted_dir.iterdir()):
                if directory.name in self._packages or directory.name.startswith("."):
                    continue  # a shipped model is never replaced; staging folders are leftovers
                try:
                    package = models.add_model(directory)
                except ValueError as exc:
                    log.warning("a host's model kept in %s is left out: %s", directory, exc)
                    continue
                self._packages[package.id] = package
        warmup()  # the kinematics kernels, so the first command is planned at once
        self.descriptions: dict[str, ModelDescription] = {
            model_id: pkg.describe() for model_id, pkg in self._packages.items()
        }

    def knows(self, model_id: str) -> bool:
        return model_id in self.descriptions

    def add_bundle(self, data: bytes) -> ModelDescription:
        """A host's model, from its bundle: unpacked into `hosted_dir` and added to the library.
        ValueError (models.ModelFileError) says what was refused; a known model is not replaced."""
        import shutil
        import tempfile

        from simecs import models
        from simecs.models.bundle import unpack

        assert self.hosted_dir is not None, "the proxy keeps hosts' models in its data folder"
        self.hosted_dir.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".incoming-", dir=self.hosted_dir))
        try:
            directory = unpack(data, staging)
            spec = models.load_model_dir(directory)
            if self.knows(spec.id):
                return self.descriptions[spec.id]
            final = self.hosted_dir / spec.id
            shutil.rmtree(final, ignore_errors=True)
            directory.rename(final)
            package = models.add_model(final)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        self._packages[package.id] = package
        self.descriptions[package.id] = package.describe()
        return self.descriptions[package.id]

    def summaries(self) -> m.ModelList:
        return m.ModelList(models=[d.summary_entry() for d in self.descriptions.values()])

    def describe(self, model_id: str) -> ModelDescription:
        desc = self.descriptions.get(model_id)
        if desc is None:
            raise RequestError(
                "not_found", f"no model {model_id!r} (models: {', '.join(self.descriptions)})", "model_id"
            )
        return desc

    def mesh(self, model_id: str, name: str) -> bytes:
        """The binary glTF of a mesh shape of the model (made on the first ask, then kept)."""
        from simecs.models.meshes import MeshError

        self.describe(model_id)
        store = self._packages[model_id].mesh_store()
        try:
            return bytes(store.glb(name))
        except KeyError:
            known = ", ".join(store.names()) or "none"
            raise RequestError(
                "not_found", f"model {model_id} has no mesh {name!r} (meshes: {known})", "mesh"
            ) from None
        except MeshError as exc:
            raise RequestError("internal", str(exc), "mesh") from None

    def doc(self, model_id: str, page: str) -> DocPage:
        desc = self.describe(model_id)
        for doc in desc.docs:
            if doc.id == page:
                return doc
        raise RequestError("not_found", f"model {desc.id} has no documentation page {page!r}", "page")

    def check(self, model_id: str, changes: Mapping[str, Any], base: Mapping[str, float]) -> dict[str, float]:
        """`base` with `changes` applied, if the model accepts every value; nothing partially."""
        values = check_values(self.describe(model_id), changes, base)
        try:
            return dict(self._packages[model_id].check_values(values))
        except ValueError as exc:  # the model's cross-checks (models.ParameterError)
            name = getattr(exc, "name", "")
            raise RequestError("bad_request", str(exc), f"values.{name}" if name else "values") from None

    def plan(
        self,
        model_id: str,
        values: Mapping[str, float],
        initial: Sequence[float],
        command: m.RobotCommand,
        stop_time: float,
        obstacles: Sequence[m.Obstacle] = (),
        collisions: bool = False,
    ) -> Any:
        """The command expanded for this model, values and initial pose (models.plan.Plan) among
        `obstacles` (what grasps take), or a refusal naming the field inside `command` (a level the
        model does not accept: unsupported). A path whose drives cannot hold the arm against gravity is
        refused, and with `collisions` one that makes the arm touch an obstacle or itself (naming the
        step)."""
        planner = self._planner(model_id, command.kind, "command", values, initial, stop_time, obstacles)
        with _refused_as("command"):
            plan = planner.plan(command)
        problem = planner.checks.holding_problem(plan)
        if problem is None and collisions:
            problem = planner.checks.collision(plan) or planner.checks.self_touch(plan)
        if problem is not None:
            raise RequestError("bad_request", problem[1], problem[0])
        return plan

    def check_hold(self, model_id: str, values: Mapping[str, float], initial: Sequence[float]) -> None:
        """Refuse a run without a command whose arm its drives cannot hold at the initial pose."""
        kind = self.describe(model_id).command_levels[0]  # any: the planner is only asked about q0
        problem = self._planner(model_id, kind, "initial", values, initial).checks.holding_problem(None)
        if problem is not None:
            raise RequestError("bad_request", problem[1], problem[0])

    def check_program(
        self, model_id: str, values: Mapping[str, float], program: m.Program, where: str
    ) -> None:
        """What a saved program must satisfy whatever pose it starts from: its arguments against their
        primitives, joint targets within range (a reach needs a start pose: checked at set_command)."""
        planner = self._planner(model_id, program.kind, where, values)
        with _refused_as(where):
            planner.check_arguments(program)

    def _planner(
        self,
        model_id: str,
        kind: str,
        where: str,
        values: Mapping[str, float],
        initial: Sequence[float] | None = None,
        stop_time: float = 1.0,
        obstacles: Sequence[m.Obstacle] = (),
    ) -> Any:
        """A planner of the model, once it is known to accept commands of `kind`."""
        from simecs.models.planner import Planner

        desc = self.describe(model_id)
        if kind not in desc.command_levels:
            raise RequestError(
                "unsupported",
                f"model {desc.id} accepts {', '.join(desc.command_levels)} commands, not {kind}",
                f"{where}.kind",
            )
        start = initial if initial is not None else [0.0] * len(desc.links)
        return Planner(self._packages[model_id], values, start, stop_time, obstacles=obstacles)


@contextmanager
def _refused_as(where: str) -> Iterator[None]:
    """A command the model cannot carry out, as the refusal naming its field under `where`."""
    from simecs.models import CommandError

    try:
        yield
    except CommandError as exc:
        raise RequestError("bad_request", exc.reason, _join(where, exc.field)) from None


def _join(prefix: str, field: str) -> str:
    return f"{prefix}.{field}" if field else prefix
