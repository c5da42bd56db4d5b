"""What a user keeps on the server besides sessions: named parameter sets (paper §2.2 step 2) and
saved programs (actions, tasks and missions), both per model. The proxy's handlers for their
commands; each checks what it loads against the model as it is now."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from simecs.mesh.process.runtime import RequestError
from simecs.mesh.protocol import codec
from simecs.mesh.protocol import messages as m

from .library import ModelLibrary
from .paramsets import ParamSetStore
from .programs import ProgramStore
from .quotas import QuotaCheck
from .sessions import SessionRecord, SessionStore


class UserLibrary:
    def __init__(
        self, data: Path, models: Callable[[], ModelLibrary], store: SessionStore, quota: QuotaCheck
    ) -> None:
        self.paramsets = ParamSetStore(data / "paramsets")
        self.programs = ProgramStore(data / "programs")
        self.models = models
        self.store = store
        self.quota = quota

    def handlers(self) -> dict[type, Callable[[SessionRecord, Any], Any]]:
        return {
            m.SaveParamSet: self.save_param_set,
            m.LoadParamSet: self.load_param_set,
            m.DeleteParamSet: self.delete_param_set,
            m.ListParamSets: self.list_param_sets,
            m.SaveProgram: self.save_program,
            m.LoadProgram: self.load_program,
            m.DeleteProgram: self.delete_program,
            m.ListPrograms: self.list_programs,
        }

    # -- parameter sets ----------------------------------------------------------------------------
    def save_param_set(self, rec: SessionRecord, cmd: m.SaveParamSet) -> str:
        replacing = self.paramsets.exists(rec.user, rec.model_id, cmd.name)
        self.quota.new_param_set(rec.user, self.paramsets.count(rec.user), replacing)
        self.paramsets.save(rec.user, rec.model_id, cmd.name, rec.values)
        return cmd.name

    def load_param_set(self, rec: SessionRecord, cmd: m.LoadParamSet) -> dict[str, float]:
        stored = self.paramsets.load(rec.user, rec.model_id, cmd.name)
        known = self.models().describe(rec.model_id).default_values()
        # Parameters added to the model since the set was saved keep their current values.
        kept = {k: v for k, v in stored.items() if k in known}
        try:
            rec.values = self.models().check(rec.model_id, kept, rec.values)
        except (RequestError, codec.DecodeError) as exc:
            raise RequestError(
                "bad_request", f"parameter set {cmd.name!r} is unusable: {exc}", "name"
            ) from None
        self.store.publish_params(rec, sorted(kept))
        self.store.edited(rec)
        return rec.values

    def delete_param_set(self, rec: SessionRecord, cmd: m.DeleteParamSet) -> str:
        self.paramsets.delete(rec.user, rec.model_id, cmd.name)
        return cmd.name

    def list_param_sets(self, rec: SessionRecord, cmd: m.ListParamSets) -> list[str]:
        return self.paramsets.names(rec.user, rec.model_id)

    # -- programs ----------------------------------------------------------------------------------
    def save_program(self, rec: SessionRecord, cmd: m.SaveProgram) -> str:
        self.models().check_program(rec.model_id, rec.values, cmd.program, "program")
        replacing = self.programs.exists(rec.user, rec.model_id, cmd.program.kind, cmd.name)
        self.quota.new_program(rec.user, self.programs.count(rec.user), replacing)
        self.programs.save(rec.user, rec.model_id, cmd.name, cmd.program)
        return cmd.name

    def load_program(self, rec: SessionRecord, cmd: m.LoadProgram) -> m.Program:
        program = self.programs.load(rec.user, rec.model_id, cmd.kind, cmd.name)
        try:
            self.models().check_program(rec.model_id, rec.values, program, "program")
        except RequestError as exc:
            raise RequestError(
                "bad_request",
                f"{cmd.kind} {cmd.name!r} no longer fits the model: {exc.field}: {exc.message}",
                "name",
            ) from None
        return program

    def delete_program(self, rec: SessionRecord, cmd: m.DeleteProgram) -> str:
        self.programs.delete(rec.user, rec.model_id, cmd.kind, cmd.name)
        return cmd.name

    def list_programs(self, rec: SessionRecord, cmd: m.ListPrograms) -> list[m.ProgramEntry]:
        return self.programs.entries(rec.user, rec.model_id, cmd.kind)
