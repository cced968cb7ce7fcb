"""The local shapes a god-object tool is rendered against (DESIGN-WAVE2 C2, C4).

Each pymunk shape of the world becomes one SHAPE_DTYPE row: its convex core in its body's
frame about the body's centre of gravity (a circle's centre, a segment's ends, a polygon's
vertices counter-clockwise) with pymunk's radius as the rounding, computed once; at each
update the rows of the shapes near the tool get their body's pose (the centre of gravity's
position and the angle) and twist (pymunk's body velocity is the centre of gravity's).
Bodies move ballistically between updates as far as the haptic side knows (Motion.BALLISTIC:
a free body's centre moves straight; a kinematic body here turns about its centre too).

A twist beyond the protocol's limits (DEFAULT_LIMITS: 100 m/s, 1000 rad/s) is published at the
limit, and counted (`LocalShapes.twists_clamped`): the parser refuses the whole update for one
shape beyond them. A small pebble reaches them legitimately: in god_crowd, 2 N of friction at
the rim of a 5 g, 4 mm pebble for one 60 Hz step spins it at 3000 rad/s, and a CI run lost
updates that way ('shape'). Over an update's life the haptic side's extrapolation of such a
spin (more than 16 rad a step) means nothing; the pose it starts from is exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymunk

from haptic_local_model.shared.config import Material
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS
from haptic_local_model.shared.shapes import (
    MAX_SHAPES,
    MIN_EDGE_M,
    Motion,
    ShapeKind,
    polygon_problem,
    set_core,
    shape_array,
    vertex_distance,
)
from haptic_local_model.sim_server.membrane import Membrane

_Segment = tuple[Membrane, int, np.ndarray, np.ndarray]  # a string's segment: its nodes
SAFE_SHARE = 1.0 - 1e-9  # of a limit: a clamped twist is published this far inside it


@dataclass(frozen=True)
class _Entry:
    body: pymunk.Body
    row: np.ndarray  # SHAPE_DTYPE[1]: the core and materials; pose and twist per update


class LocalShapes:
    """The world's shapes as local-shape rows, and the query that picks the near ones."""

    def __init__(
        self,
        shapes: dict[pymunk.Shape, tuple[int, Material]],
        tool_shapes: list[pymunk.Shape],
        margin_m: float,
        membranes: list[Membrane] | None = None,
        cars: dict[pymunk.Shape, int] | None = None,
    ) -> None:
        self._entries = {
            s: _Entry(_body(s), _core_row(s, key, mat)) for s, (key, mat) in shapes.items()
        }
        for shape, k in (cars or {}).items():  # posed by the haptic side's train
            row = self._entries[shape].row
            row["motion"] = int(Motion.TRACK)
            row["owner"] = k
        self._tool = tool_shapes
        self._membranes = membranes or []
        self.margin_m = margin_m
        self.dropped = 0  # shapes within the margin beyond MAX_SHAPES (the farthest go)
        self.twists_clamped = 0  # published twists brought within the protocol's limits

    def fill(
        self, space: pymunk.Space, record: np.void, proxy: tuple[float, float, float] | None = None
    ) -> int:
        """The shapes within margin_m of the tool's shapes into record["shapes"], nearest
        first, at most MAX_SHAPES; returns how many. Given the haptic side's proxy (x, y and
        its radius), the query is about the proxy instead: the sim's finger follows it
        centimetres behind when it moves fast, and a shape the proxy touches must never fall
        out of the nearest MAX_SHAPES (the proxy would jump off it)."""
        tool = self._tool
        bb = tool[0].bb
        for s in tool[1:]:
            bb = bb.merge(s.bb)
        if proxy is not None:
            x, y, r = proxy
            bb = pymunk.BB(x - r, y - r, x + r, y + r)
        bb = pymunk.BB(
            bb.left - self.margin_m, bb.bottom - self.margin_m,
            bb.right + self.margin_m, bb.top + self.margin_m,
        )  # fmt: skip
        centre = bb.center()
        found: list[tuple[float, int, _Entry | _Segment]] = []
        for shape in space.bb_query(bb, pymunk.ShapeFilter()):
            entry = self._entries.get(shape)
            if entry is None or shape in tool:
                continue
            gap = shape.point_query(centre).distance
            found.append((gap, id(shape), entry))
        for mem in self._membranes:
            nodes = mem.published
            for i in range(len(nodes) - 1):
                a, b = nodes[i], nodes[i + 1]
                if np.hypot(*(b - a)) <= 1e3 * MIN_EDGE_M:
                    continue  # a segment the parser would refuse (nodes crushed together)
                lo, hi = np.minimum(a, b) - mem.spec.radius, np.maximum(a, b) + mem.spec.radius
                if lo[0] > bb.right or hi[0] < bb.left or lo[1] > bb.top or hi[1] < bb.bottom:
                    continue
                gap = vertex_distance(np.array([a, b]), 2, centre.x, centre.y)[0] - mem.spec.radius
                found.append((gap, mem.first_key + i, (mem, i, a, b)))
        found.sort(key=lambda f: (f[0], f[1]))
        self.dropped += max(0, len(found) - MAX_SHAPES)
        rows = record["shapes"]
        for k, (_, _, near) in enumerate(found[:MAX_SHAPES]):
            if isinstance(near, tuple):
                mem, i, a, b = near
                mem.fill_row(rows[k], i, a, b)
                continue
            rows[k] = near.row[0]
            body = near.body
            cog = body.local_to_world(body.center_of_gravity)
            rows[k]["pose"] = (cog.x, cog.y, math.remainder(body.angle, 2.0 * math.pi))
            rows[k]["twist"] = self._twist(body)
        n = min(len(found), MAX_SHAPES)
        record["n_shapes"] = n
        return n

    def _twist(self, body: pymunk.Body) -> tuple[float, float, float]:
        """The body's twist, within the protocol's limits (a little inside, so that the
        parser's test of the speed's hypot cannot round it out)."""
        v, w = body.velocity, body.angular_velocity
        speed, top = math.hypot(v.x, v.y), SAFE_SHARE * DEFAULT_LIMITS.max_abs_velocity
        spin = SAFE_SHARE * DEFAULT_LIMITS.max_abs_angular_velocity
        if speed <= top and abs(w) <= spin:
            return v.x, v.y, w
        self.twists_clamped += 1
        scale = 1.0 if speed <= top else top / speed
        return v.x * scale, v.y * scale, math.copysign(min(abs(w), spin), w)


def _body(shape: pymunk.Shape) -> pymunk.Body:
    body = shape.body
    if body is None:
        raise ValueError("a shape of the world has no body")
    return body


def _core_row(shape: pymunk.Shape, key: int, material: Material) -> np.ndarray:
    """A shape's core about its body's centre of gravity, its rounding and its friction."""
    rows = shape_array(1)
    row = rows[0]
    cog = np.array(_body(shape).center_of_gravity)
    if isinstance(shape, pymunk.Circle):
        set_core(row, ShapeKind.CIRCLE, [np.array(shape.offset) - cog], shape.radius)
    elif isinstance(shape, pymunk.Segment):
        ends = [np.array(shape.a) - cog, np.array(shape.b) - cog]
        set_core(row, ShapeKind.SEGMENT, ends, shape.radius)
    else:
        assert isinstance(shape, pymunk.Poly)
        verts = np.array([tuple(v) for v in shape.get_vertices()]) - cog
        if "clockwise" in polygon_problem(verts):
            verts = verts[::-1]
        problem = polygon_problem(verts)
        if problem:
            raise ValueError(f"shape {key}: {problem}")
        set_core(row, ShapeKind.POLYGON, verts, shape.radius)
    row["key"] = key
    row["motion"] = int(Motion.BALLISTIC)
    row["static_friction"] = material.static_coefficient
    row["friction"] = material.friction
    return rows
