"""What the sim steps, as the live view draws it (shared/protocol/world_view.py): every body's
shapes once (again on a change, and every SHAPES_PERIOD_S for a late view), then every
body's pose at the view's rate. Read from pymunk after a step's update is published, never
inside the step: the local model and its timing do not see it."""

from __future__ import annotations

import numpy as np
import pymunk

from haptic_local_model.shared.protocol.world_view import (
    BODY_DTYPE,
    MAX_VERTS,
    POSE_DTYPE,
    ROLE_DYNAMIC,
    ROLE_KINEMATIC,
    ROLE_STATIC,
    ROLE_TOOL,
    SHAPE_CIRCLE,
    SHAPE_DTYPE,
    SHAPE_POLY,
    SHAPE_SEGMENT,
    SHAPES_PERIOD_S,
    WorldPoses,
    WorldShapes,
    encode_poses,
    encode_shapes,
    layout_id,
)


class WorldViewSource:
    """The messages of one sim's world: `due(now_s)` says which are due, in order."""

    def __init__(self, space: pymunk.Space, names: dict[pymunk.Body, str],
                 tools: list[pymunk.Body], epoch: int, rate_hz: float) -> None:  # fmt: skip
        self.space, self.names, self.tools = space, names, tools
        self.epoch, self.period_s = epoch, 1.0 / rate_hz
        self._bodies: list[pymunk.Body] = []
        self._shapes: WorldShapes | None = None
        self._shapes_bytes = b""
        self._n_shapes = -1
        self._next_shapes_s = 0.0
        self._next_pose_s = 0.0

    def due(self, now_s: float, t: float) -> list[bytes]:
        """The messages due at `now_s` (a monotonic clock) for the world at sim time `t`:
        the shapes when the layout changed or SHAPES_PERIOD_S passed, then the poses once a
        view period has passed; none between."""
        if now_s < self._next_pose_s:
            return []
        out = []
        if len(self.space.shapes) != self._n_shapes or now_s >= self._next_shapes_s:
            self._layout(t)
            out.append(self._shapes_bytes)
            self._next_shapes_s = now_s + SHAPES_PERIOD_S
        out.append(encode_poses(self.poses(t)))
        self._next_pose_s = max(self._next_pose_s + self.period_s, now_s)
        return out

    def poses(self, t: float) -> WorldPoses:
        poses = np.zeros(len(self._bodies), POSE_DTYPE)
        for i, body in enumerate(self._bodies):
            x, y = body.position
            poses[i] = (x, y, body.angle)
        assert self._shapes is not None
        return WorldPoses(self.epoch, self._shapes.layout, t, poses)

    def _layout(self, t: float) -> None:
        shapes_list = self.space.shapes
        self._n_shapes = len(shapes_list)
        order: dict[pymunk.Body, int] = {}
        for shape in shapes_list:
            if shape.body is not None:
                order.setdefault(shape.body, len(order))
        bodies = np.zeros(len(order), BODY_DTYPE)
        for body, i in order.items():
            name = self.names.get(body, f"body{i}")
            bodies[i] = (name.encode()[:24], _role(body, self.tools), 0)
        shapes = np.zeros(len(shapes_list), SHAPE_DTYPE)
        for j, shape in enumerate(shapes_list):
            if shape.body is not None:
                shapes[j] = _shape_record(shape, order[shape.body])
        self._bodies = list(order)
        record = WorldShapes(self.epoch, layout_id(bodies, shapes), t, bodies, shapes)
        self._shapes, self._shapes_bytes = record, encode_shapes(record)


def _role(body: pymunk.Body, tools: list[pymunk.Body]) -> int:
    if body in tools:
        return ROLE_TOOL
    kind = body.body_type
    if kind == pymunk.Body.STATIC:
        return ROLE_STATIC
    return ROLE_KINEMATIC if kind == pymunk.Body.KINEMATIC else ROLE_DYNAMIC


def _shape_record(shape: pymunk.Shape, body: int) -> tuple[object, ...]:
    """A shape in its body's frame as a SHAPE_DTYPE row."""
    verts = np.zeros((MAX_VERTS, 2), np.float32)
    if isinstance(shape, pymunk.Circle):
        verts[0] = tuple(shape.offset)
        return (body, SHAPE_CIRCLE, 1, shape.radius, verts)
    if isinstance(shape, pymunk.Segment):
        verts[0], verts[1] = tuple(shape.a), tuple(shape.b)
        return (body, SHAPE_SEGMENT, 2, shape.radius, verts)
    assert isinstance(shape, pymunk.Poly)
    points = [tuple(v) for v in shape.get_vertices()]
    if len(points) > MAX_VERTS:  # drawn as its first MAX_VERTS (no scene has such a polygon)
        points = points[:MAX_VERTS]
    verts[: len(points)] = points
    return (body, SHAPE_POLY, len(points), shape.radius, verts)
