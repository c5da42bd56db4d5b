"""The 3D virtual prototype (paper §2.2, §5.1): solid shapes on link frames, in an environment.

Everything comes from the `ModelDescription` the server sends, and every solid's geometry from
`simecs.mesh.rules.shapes` (the same geometry the recordings' Foxglove /scene gets): link frames follow
the paper's Link convention and are posed either by the kinematic simulation of the sliders
(`mesh.rules.kinematics`) or by the pose columns of the live stream; parameter values reshape the solids
(link lengths, `scales_with`, `anchor`), so an edited length reshapes the arm at once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from simecs.mesh.protocol.environment import Obstacle
from simecs.mesh.protocol.model import ModelDescription, Shape
from simecs.mesh.rules import shapes
from simecs.mesh.rules.kinematics import link_poses, matrix_from_quat
from simecs.mesh.rules.shapes import ShapeGeometry

TOOL_PATH_COLOR = (255, 150, 0)


class ArmScene:
    """One tab's 3D prototype: environment, link frames with their solids, and their poses."""

    def __init__(
        self,
        scene: Any,
        model: ModelDescription,
        values: Mapping[str, float],
        root: str = "/arm",
        shadows: bool = False,
        meshes: Mapping[str, bytes] | None = None,
    ):
        self.scene = scene
        self.meshes = dict(meshes or {})  # GLB of each mesh shape (a missing one is not drawn)
        self.model = model
        self.root = root
        self.shadows = shadows
        self.values = dict(values)
        self.appearance = shapes.appearance_parameters(model)
        self.frames: list[Any] = []
        self.solids: dict[int, tuple[Any, str]] = {}  # index in model.shapes -> (handle, kind)
        self._pipe_meshes: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._env: list[Any] = []
        self._obstacles: list[Any] = []
        self._contacts: Any = None  # the contact forces' arrows, when any
        self._arrows = np.zeros((0, 2, 3))
        self._path_line: Any = None  # the planned tool path, when there is one
        self._tool_path = np.zeros((0, 3), dtype=np.float32)
        self._listed: list[Obstacle] = []  # the obstacles drawn, where their list puts them
        self._moved: dict[int, np.ndarray] = {}  # where a run's grasps put some (as last sent)
        self.q: list[float] = [0.0] * len(model.links)
        self.poses: np.ndarray | None = None  # the link poses last shown (`corners`)
        self._mesh_bounds: dict[str, tuple[np.ndarray, np.ndarray] | None] | None = None

    # -- building ------------------------------------------------------------------------------
    def build(self) -> None:
        """Add the environment, then one frame per link with its solids (all in one batch)."""
        # Shadows cost a shadow-map pass per frame: several times the frame time on a machine
        # without a GPU (software WebGL), where they would stall the whole page.
        self.scene.configure_default_lights(enabled=True, cast_shadow=self.shadows)
        if not self.shadows:  # an environment map costs as much again; plain lights instead
            self.scene.configure_environment_map(None)
            self._env.append(
                self.scene.add_light_hemisphere(
                    "/env/sky", sky_color=(255, 255, 255), ground_color=(160, 160, 170), intensity=2.0
                )
            )
        for link in self.model.links:
            frame = self.scene.add_frame(
                f"{self.root}/{link.name}", show_axes=False, axes_length=0.1, axes_radius=0.004
            )
            self.frames.append(frame)
        bottoms = []
        for n, solid in enumerate(shapes.solids(self.model, self.values)):
            if solid.frame == shapes.WORLD:
                self._env.append(self._add_solid(f"/env/s{n}", solid.shape, solid.geometry)[0])
                bottoms.append(shapes.shape_bottom(solid.geometry))
            else:
                name = f"{self.root}/{solid.frame}/s{solid.index}"
                self.solids[solid.index] = self._add_solid(name, solid.shape, solid.geometry)
        floor_z = min(bottoms) - 1e-3 if bottoms else 0.0
        reach = sum(abs(self.values.get(link.length_param, 0.0)) for link in self.model.links)
        size = max(4.0, 2.5 * reach)
        self._env.append(
            self.scene.add_grid(
                "/env/floor",
                width=size,
                height=size,
                cell_size=0.25,
                section_size=1.0,
                position=(0.0, 0.0, floor_z),
                plane_color=(236, 238, 242),
                plane_opacity=1.0,
                shadow_opacity=0.2 if self.shadows else 0.0,
            )
        )
        self.show_q(self.q)

    def _add_solid(self, name: str, shape: Shape, geom: ShapeGeometry) -> tuple[Any, str]:
        color = tuple(int(c) for c in shape.color[:3])
        light = {"cast_shadow": self.shadows, "receive_shadow": self.shadows}
        if geom.kind == "mesh":
            data = self.meshes.get(geom.mesh)
            if data is None:  # the server did not give it: an empty node keeps the indices whole
                return self.scene.add_frame(name, show_axes=False, position=geom.position), "mesh"
            h = self.scene.add_glb(
                name, data, scale=geom.dimensions, wxyz=geom.wxyz, position=geom.position, **light
            )
        elif geom.kind == "box":
            h = self.scene.add_box(
                name,
                color=color,
                dimensions=geom.dimensions,
                wxyz=geom.wxyz,
                position=geom.position,
                **light,
            )
        elif geom.kind == "sphere":
            h = self.scene.add_icosphere(
                name, radius=geom.radius, color=color, position=geom.position, **light
            )
        elif geom.kind == "pipe":
            verts, faces = self._pipe(geom.inner_ratio)
            h = self.scene.add_mesh_simple(
                name,
                verts,
                faces,
                color=color,
                scale=(geom.radius, geom.radius, max(geom.length, 1e-6)),
                wxyz=geom.wxyz,
                position=geom.position,
                flat_shading=False,
                **light,
            )
        else:
            h = self.scene.add_cylinder(
                name,
                radius=geom.radius,
                height=max(geom.length, 1e-6),
                color=color,
                wxyz=geom.wxyz,
                position=geom.position,
                **light,
            )
        h.visible = geom.visible
        return h, geom.kind

    def _pipe(self, ratio: float) -> tuple[np.ndarray, np.ndarray]:
        key = round(ratio, 4)
        if key not in self._pipe_meshes:
            self._pipe_meshes[key] = shapes.pipe_mesh(key)
        return self._pipe_meshes[key]

    # -- updating --------------------------------------------------------------------------------
    def set_values(self, values: Mapping[str, float]) -> bool:
        """Take new parameter values; reshape the solids they change and re-pose the arm.

        Returns whether anything in the 3D prototype changed.
        """
        changed = any(self.values.get(n) != values.get(n) for n in self.appearance)
        self.values = dict(values)
        if not changed:
            return False
        for solid in shapes.solids(self.model, self.values):
            found = self.solids.get(solid.index) if solid.frame != shapes.WORLD else None
            if found is None:
                continue
            handle, kind = found
            geom = solid.geometry
            length = max(geom.length, 1e-6)
            if kind == "pipe":
                handle.scale = (geom.radius, geom.radius, length)
            elif kind == "cylinder":
                handle.radius = geom.radius
                handle.height = length
            elif kind == "box":
                handle.dimensions = geom.dimensions
            elif kind == "sphere":
                handle.radius = geom.radius
            handle.position = geom.position
            handle.visible = geom.visible
        self.show_q(self.q)
        return True

    def show_q(self, q: Sequence[float]) -> None:
        """Kinematic simulation: pose every link frame for joint positions `q` (rad)."""
        self.q = [float(x) for x in q]
        self.apply_poses(link_poses(self.model, self.values, self.q))

    def apply_poses(self, poses: np.ndarray) -> None:
        """Set link frame poses from rows in `columns.POSE_FIELDS` order (x, y, z, qw, qx, qy, qz)."""
        self.poses = np.array(poses[: len(self.model.links)], dtype=float)  # what `corners` frames
        for frame, row in zip(self.frames, poses, strict=False):
            frame.position = row[:3]
            frame.wxyz = row[3:7]

    def corners(self) -> np.ndarray:
        """World corners (n x 3) of boxes around the arm's solids as last posed (the links' and the
        base's, not the environment's): what the View presets frame."""
        poses = self.poses
        if poses is None or len(poses) < len(self.model.links):
            poses = link_poses(self.model, self.values, self.q)
        if self._mesh_bounds is None:
            self._mesh_bounds = {name: shapes.glb_bounds(data) for name, data in self.meshes.items()}
        names = {link.name: i for i, link in enumerate(self.model.links)}
        out = [np.zeros((0, 3))]
        for n, solid in enumerate(shapes.solids(self.model, self.values)):
            if n < len(self.model.environment) or not solid.geometry.visible:  # the environment comes first
                continue
            box = shapes.solid_corners(solid.geometry, self._mesh_bounds.get(solid.geometry.mesh))
            if solid.frame != shapes.WORLD:
                row = poses[names[solid.frame]]
                box = box @ matrix_from_quat(row[3:7]).T + row[:3]
            out.append(box)
        return np.concatenate(out)

    def extent(self) -> float:
        """About how far the arm reaches from the origin (the Cartesian gizmo's size; the View
        presets frame `corners`)."""
        poses = link_poses(self.model, self.values, [0.0] * len(self.model.links))
        far = float(np.max(np.linalg.norm(poses[:, :3], axis=1))) if len(poses) else 0.0
        biggest = max([max(s.length, 2 * s.radius, s.width, s.height) for s in self.model.shapes] or [0.0])
        return max(far + biggest, 0.5)

    def show_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        """Draw what the arm can touch (the session's obstacles, or a run's), each where it is listed,
        in place of what was drawn before; no contact arrows."""
        for handle in self._obstacles:
            handle.remove()
        self._listed, self._moved = list(obstacles), {}
        self._obstacles = [
            self._add_solid(f"/env/obstacles/{solid.index}", solid.shape, solid.geometry)[0]
            for solid in shapes.obstacle_solids(obstacles)
        ]
        self.show_contacts(np.zeros((0, 2, 3)))

    def move_obstacles(self, moved: Mapping[int, np.ndarray]) -> None:
        """Put obstacles where a run's grasps took them (index -> x, y, z, qw, qx, qy, qz); a pose
        already shown is not sent again (a released object stays put for many frames)."""
        for index, pose in moved.items():
            shown = self._moved.get(index)
            if 0 <= index < len(self._obstacles) and (shown is None or not np.array_equal(shown, pose)):
                self._moved[index] = np.array(pose, dtype=float)
                handle = self._obstacles[index]
                handle.position = tuple(float(v) for v in pose[:3])
                handle.wxyz = tuple(float(v) for v in pose[3:7])

    def settle_world(self) -> None:
        """The obstacles back where their list puts them and no arrows (the user poses the arm: what a
        run showed is over)."""
        if self._moved:
            self.show_obstacles(self._listed)
        self.show_contacts(np.zeros((0, 2, 3)))

    def show_contacts(self, arrows: np.ndarray) -> None:
        """The contact forces as red arrows ((k, 2, 3): from where a link is pushed, along the force;
        mesh/rules/scene_state.py); sent only when they change."""
        if arrows.shape == self._arrows.shape and np.array_equal(arrows, self._arrows):
            return
        self._arrows = arrows.copy()
        if self._contacts is not None:
            self._contacts.remove()
            self._contacts = None
        if arrows.shape[0]:
            self._contacts = self.scene.add_arrows(
                "/env/contacts",
                points=arrows.astype(np.float32),
                colors=(220, 30, 30),
                shaft_radius=0.004,
                head_radius=0.012,
                head_length=0.025,
            )

    def show_tool_path(self, points: Sequence[Sequence[float]]) -> None:
        """The tool's path as the server planned the session's command (a polyline; [] hides it);
        sent only when it changes."""
        path = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        if path.shape == self._tool_path.shape and np.array_equal(path, self._tool_path):
            return
        self._tool_path = path
        if self._path_line is not None:
            self._path_line.remove()
            self._path_line = None
        if path.shape[0] >= 2:
            segments = np.stack([path[:-1], path[1:]], axis=1)
            self._path_line = self.scene.add_line_segments(
                "/env/tool_path", segments, colors=TOOL_PATH_COLOR, thickness=2.0, thickness_units="screen"
            )

    def remove(self) -> None:
        if self._path_line is not None:
            self._env.append(self._path_line)
            self._path_line = None
        if self._contacts is not None:
            self._env.append(self._contacts)
            self._contacts = None
        for handle in [*self._env, *self._obstacles, *self.frames]:
            try:
                handle.remove()
            except Exception:
                pass
        self._env.clear()
        self._obstacles.clear()
        self.frames.clear()
        self.solids.clear()
