"""An imported model checked against yourdfpy, an independent reading of the same URDF.

The tests (tests/test_model_files.py) and `simecs bench model` (fk_vs_reference_m) both use it: tool
poses on random configurations, and the mass, centre of mass and inertia of the moving arm.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from simecs import models
from simecs.mesh.process.files import parse_json5
from simecs.mesh.rules.kinematics import link_frames
from simecs.models.urdf import resolve_uri


def urdf_models() -> list[str]:
    """The ids of the library's models whose chain comes from a URDF."""
    return [p.name for p in models.library_dirs() if models.get_model(p.name).spec.links[0].source_joint]


class UrdfReference:
    """One library model and yourdfpy's reading of its URDF, posed alike."""

    def __init__(self, model_id: str) -> None:
        import yourdfpy

        self.package = models.get_model(model_id)
        source_dir = self.package.spec.source
        assert source_dir is not None
        self.source: dict[str, Any] = parse_json5((source_dir / "model.json5").read_text())["urdf"]
        path = resolve_uri(self.source["file"], source_dir)
        self.urdf = yourdfpy.URDF.load(
            str(path), load_meshes=False, build_scene_graph=True, load_collision_meshes=False
        )
        self.base = self.source.get("base_link") or self.urdf.base_link
        self.names = [lk.source_joint for lk in self.package.spec.links]
        self.description = self.package.describe()
        self.values = self.description.default_values()

    def random_q(self, rng: np.random.Generator) -> list[float]:
        return [float(rng.uniform(lk.joint_min, lk.joint_max)) for lk in self.package.spec.links]

    def pose(self, q: list[float]) -> None:
        self.urdf.update_cfg(
            {**dict(zip(self.names, q, strict=True)), **self.source.get("locked_joints", {})}
        )

    def tool_error(self, q: list[float]) -> float:
        """Largest difference of the tool frame's position (m) and rotation matrix entries."""
        self.pose(q)
        T = self.urdf.get_transform(self.source["tool_link"], self.base)
        p, R = link_frames(self.description, self.values, q)[-1]
        return max(float(np.abs(p - T[:3, 3]).max()), float(np.abs(R - T[:3, :3]).max()))

    def mass_properties(self, q: list[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(mass, first moment, inertia about the world origin) of the moving arm: yourdfpy's, ours."""
        self.pose(q)
        ref_m, ref_c, ref_I = 0.0, np.zeros(3), np.zeros((3, 3))
        todo = [self.urdf.joint_map[self.names[0]].child]
        while todo:
            link = todo.pop()
            todo.extend(j.child for j in self.urdf.robot.joints if j.parent == link)
            inertial = self.urdf.link_map[link].inertial
            if inertial is None or inertial.mass == 0:
                continue
            origin = inertial.origin if inertial.origin is not None else np.eye(4)
            T = self.urdf.get_transform(link, self.base) @ origin
            c = T[:3, 3]
            ref_m += inertial.mass
            ref_c += inertial.mass * c
            ref_I += T[:3, :3] @ inertial.inertia @ T[:3, :3].T + inertial.mass * (
                c @ c * np.eye(3) - np.outer(c, c)
            )
        m, c_sum, inertia = 0.0, np.zeros(3), np.zeros((3, 3))
        for lk, (p, R) in zip(
            self.package.spec.links, link_frames(self.description, self.values, q)[:-1], strict=True
        ):
            c = p + R @ np.array(lk.com)
            m += lk.mass
            c_sum += lk.mass * c
            inertia += R @ np.array(lk.inertia_matrix()) @ R.T + lk.mass * (
                c @ c * np.eye(3) - np.outer(c, c)
            )
        return (ref_m, *ref_c, *ref_I.ravel()), (m, *c_sum, *inertia.ravel())
