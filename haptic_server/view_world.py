"""The live view's world layer: every body the sim steps, drawn from the sim's world messages
(`<ns>/view/world`, shared/protocol/world_view.py) under the haptic side's proxy, device,
contacts and forces, at the time of the frame they arrive with (one timeline).

A message is checked whole before it is drawn; one that is malformed, of another epoch than
the updates the loop installs, or of a layout the view has not been sent, is refused and
counted by reason (`refused`), never drawn and never raised.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from haptic_local_model.shared.protocol.update import MessageError
from haptic_local_model.shared.protocol.world_view import (
    ROLE_DYNAMIC,
    ROLE_KINEMATIC,
    ROLE_STATIC,
    ROLE_TOOL,
    SHAPE_CIRCLE,
    SHAPE_SEGMENT,
    WorldPoses,
    WorldShapes,
    decode_world,
)

#: a body's colour by role: the moving ones stand out from the walls and the held linkage
ROLE_COLORS = {
    ROLE_STATIC: (140, 145, 153),
    ROLE_KINEMATIC: (230, 160, 20),
    ROLE_DYNAMIC: (160, 60, 210),
    ROLE_TOOL: (200, 200, 205),  # the sim's tool, pale under the haptic side's proxy
}
MIN_LINE_M = 0.001  # a polygon's outline (pymunk's boxes have no rounding radius)

LogFn = Callable[..., None]


class WorldLayer:
    """The newest shapes and what the last poses drew."""

    def __init__(self, log: LogFn) -> None:
        self._log = log
        self.shapes: WorldShapes | None = None
        self.refused: dict[str, int] = {}
        self.drawn = 0  # poses messages drawn
        self.last_poses: WorldPoses | None = None
        self._static_layout = -1
        self.min_period_s = 0.0  # poses closer than this (sim time) to the last drawn: skipped
        self.thinned = 0  # poses skipped so (a degraded view: view_degrade.py)

    def take(self, raw: bytes, epoch: int) -> None:
        """A world message, drawn if it is the installed epoch's and its layout is known."""
        try:
            message = decode_world(raw)
        except MessageError as exc:
            self._refuse(exc.reason)
            return
        if message.epoch != epoch:
            self._refuse("epoch")  # another sim's, or before the loop installed any update
            return
        if isinstance(message, WorldShapes):
            self.shapes = message
            return
        if self.shapes is None or message.layout != self.shapes.layout:
            self._refuse("layout")
            return
        if len(message.poses) != len(self.shapes.bodies):
            self._refuse("size")
            return
        last = self.last_poses
        if last is not None and 0.0 <= message.t - last.t < self.min_period_s:
            self.thinned += 1
            return
        self._draw(self.shapes, message)

    def _refuse(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def _draw(self, shapes: WorldShapes, poses: WorldPoses) -> None:
        import rerun as rr

        roles = shapes.bodies["role"][shapes.shapes["body"]]
        world = world_vertices(shapes, poses)
        moving = roles != ROLE_STATIC
        groups = [("world/bodies/moving", moving)]
        if shapes.layout != self._static_layout:  # the walls do not move: once per layout
            groups.append(("world/bodies/static", ~moving))
            self._static_layout = shapes.layout
        for path, chosen in groups:
            strips, radii, colors, labels = _strips(shapes, world, chosen)
            if strips:
                self._log(path, rr.LineStrips2D(
                    strips, radii=radii, colors=colors, labels=labels, show_labels=False,
                    draw_order=20,
                ))  # fmt: skip
            centres, c_radii, c_colors = _discs(shapes, world, chosen)
            if centres:
                self._log(f"{path}/discs", rr.Points2D(centres, radii=c_radii, colors=c_colors))
        self.last_poses = poses
        self.drawn += 1


def world_vertices(shapes: WorldShapes, poses: WorldPoses) -> np.ndarray:
    """Every shape's vertices in the world (shapes x MAX_VERTS x 2): its body's pose applied."""
    pose = poses.poses[shapes.shapes["body"]]
    c = np.cos(pose["angle"].astype(float))[:, None]
    s = np.sin(pose["angle"].astype(float))[:, None]
    v = shapes.shapes["verts"].astype(float)
    x = pose["x"].astype(float)[:, None] + c * v[:, :, 0] - s * v[:, :, 1]
    y = pose["y"].astype(float)[:, None] + s * v[:, :, 0] + c * v[:, :, 1]
    return np.stack([x, y], axis=-1)


def _strips(
    shapes: WorldShapes, world: np.ndarray, chosen: np.ndarray
) -> tuple[list[Any], list[float], list[tuple[int, int, int]], list[str]]:
    strips, radii, colors, labels = [], [], [], []
    for j in np.flatnonzero(chosen):
        shape = shapes.shapes[j]
        kind, n = int(shape["kind"]), int(shape["n_verts"])
        if kind == SHAPE_CIRCLE:
            continue
        points = world[j, :n] if kind == SHAPE_SEGMENT else np.vstack([world[j, :n], world[j, :1]])
        body = shapes.bodies[int(shape["body"])]
        strips.append(points.tolist())
        radii.append(max(float(shape["radius"]), MIN_LINE_M) if kind == SHAPE_SEGMENT else
                     MIN_LINE_M)  # fmt: skip
        colors.append(ROLE_COLORS[int(body["role"])])
        labels.append(bytes(body["name"]).decode(errors="replace"))
    return strips, radii, colors, labels


def _discs(
    shapes: WorldShapes, world: np.ndarray, chosen: np.ndarray
) -> tuple[list[Any], list[float], list[tuple[int, int, int]]]:
    pick = chosen & (shapes.shapes["kind"] == SHAPE_CIRCLE)
    roles = shapes.bodies["role"][shapes.shapes["body"][pick]]
    return (
        world[pick, 0].tolist(),
        shapes.shapes["radius"][pick].astype(float).tolist(),
        [ROLE_COLORS[int(r)] for r in roles],
    )
