"""The goal ghost (issue 32, as MoveIt users know it): the arm drawn translucent where the selected
node or action puts it, beside the arm itself, which stays where the run will start (or where a run
or a jog left it: what Teach records). The same geometry as the arm (`mesh.rules.shapes`), on its own
frames under `/ghost`; a mesh link is drawn as the box around it (viser draws glTF opaque).

The ghost also plays the planned motion (`CommandPlan.motion`: joint set points over time, from the
server) so the user sees the move before pressing Run: `play` poses it along the samples at their
own pace, on the tab's loop.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from simecs.mesh.protocol.model import ModelDescription
from simecs.mesh.rules import shapes
from simecs.mesh.rules.kinematics import link_poses

GHOST_ROOT = "/ghost"
GHOST_COLOR = (70, 150, 255)
GHOST_OPACITY = 0.35
FRAME_S = 1 / 25  # the planned motion is played at 25 poses a second


class GoalGhost:
    """A translucent copy of the arm's links (not its environment), shown at a pose or hidden."""

    def __init__(
        self,
        scene: Any,
        model: ModelDescription,
        values: Mapping[str, float],
        mesh_bounds: Mapping[str, tuple[np.ndarray, np.ndarray] | None] | None = None,
    ) -> None:
        self.scene = scene
        self.model = model
        self.values = dict(values)
        self.mesh_bounds = dict(mesh_bounds or {})
        self.frames: list[Any] = []
        self.solids: list[Any] = []
        self.q: list[float] | None = None  # the pose shown (None: hidden)
        self._play = 0  # bumped to stop a playing motion
        self._build()

    def _build(self) -> None:
        for link in self.model.links:
            self.frames.append(
                self.scene.add_frame(f"{GHOST_ROOT}/{link.name}", show_axes=False, visible=False)
            )
        for solid in shapes.solids(self.model, self.values):
            if solid.frame == shapes.WORLD or not solid.geometry.visible:
                continue
            name = f"{GHOST_ROOT}/{solid.frame}/s{solid.index}"
            self.solids.append(self._add(name, solid.geometry))

    def _add(self, name: str, geom: shapes.ShapeGeometry) -> Any:
        look = {"color": GHOST_COLOR, "opacity": GHOST_OPACITY, "cast_shadow": False, "receive_shadow": False}
        if geom.kind == "sphere":
            return self.scene.add_icosphere(name, radius=geom.radius, position=geom.position, **look)
        if geom.kind in ("cylinder", "pipe"):
            return self.scene.add_cylinder(
                name,
                radius=geom.radius,
                height=max(geom.length, 1e-6),
                wxyz=geom.wxyz,
                position=geom.position,
                **look,
            )
        if geom.kind == "box":
            return self.scene.add_box(
                name, dimensions=geom.dimensions, wxyz=geom.wxyz, position=geom.position, **look
            )
        corners = shapes.solid_corners(geom, self.mesh_bounds.get(geom.mesh))  # a mesh: its box
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        size = tuple(float(max(v, 1e-3)) for v in hi - lo)
        return self.scene.add_box(name, dimensions=size, position=tuple((lo + hi) / 2), **look)

    def set_values(self, values: Mapping[str, float]) -> None:
        """The arm's shapes changed (a link length): the ghost is drawn anew with them."""
        if all(self.values.get(n) == values.get(n) for n in shapes.appearance_parameters(self.model)):
            self.values = dict(values)
            return
        self.values = dict(values)
        q = self.q
        self.remove()
        self._build()
        if q is not None:
            self.show(q)

    def show(self, q: Sequence[float] | None) -> None:
        """The ghost at joint positions `q` (rad); None hides it."""
        self._play += 1  # a pose asked for ends a motion playing
        self._pose(q)

    def _pose(self, q: Sequence[float] | None) -> None:
        if q is None or len(q) != len(self.model.links):
            if self.q is not None:
                self.q = None
                for frame in self.frames:
                    frame.visible = False
            return
        self.q = [float(x) for x in q]
        for frame, row in zip(self.frames, link_poses(self.model, self.values, self.q), strict=False):
            frame.position = row[:3]
            frame.wxyz = row[3:7]
            if not frame.visible:
                frame.visible = True

    def play(
        self,
        t: Sequence[float],
        qs: Sequence[Sequence[float]],
        after: Callable[[float, Callable[[], None]], None],
        done: Callable[[], None] = lambda: None,
    ) -> float:
        """Pose the ghost along the planned motion (`t` s, `qs` rad) at its own pace, one pose every
        FRAME_S on the tab's loop (`after`); `done()` at its end. Returns the motion's length (s)."""
        self._play += 1
        mine = self._play
        times = np.asarray(t, dtype=float)
        poses = np.asarray(qs, dtype=float)
        if len(times) < 2 or poses.shape[0] != len(times):
            return 0.0
        span = float(times[-1] - times[0])
        steps = max(2, int(span / FRAME_S) + 1)

        def frame(k: int) -> None:
            if self._play != mine:
                return  # stopped, or another motion started
            at = times[0] + span * k / (steps - 1)
            self._pose([float(np.interp(at, times, poses[:, j])) for j in range(poses.shape[1])])
            if k + 1 < steps:
                after(FRAME_S, lambda: frame(k + 1))
            else:
                done()

        frame(0)
        return span

    def remove(self) -> None:
        self._play += 1
        for handle in [*self.solids, *self.frames]:
            try:
                handle.remove()
            except Exception:
                pass
        self.solids.clear()
        self.frames.clear()
