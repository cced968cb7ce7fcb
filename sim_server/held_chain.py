"""A held chain in a user's pymunk space: the bodies from the ground to the held one, joined by
PivotJoints, read as the linkage our scenes describe (DESIGN §2; docs/scenes.md `[[linkages]]`).

A link's frame is its body's: its origin at the pivot to its parent (the ground for the
first), its x axis toward the pivot of its child, the child's pivot at x = its length. That
is how our own linkages are built (sim_server/world.py), so the sim's kernels read the
joint angles from the bodies' angles (sim_server/tool.py). A chain built otherwise is refused
with the body and what is off; a serial chain only (no tree, no loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pymunk

#: a pivot this far (m) from where a link's frame puts it is refused
PIVOT_TOLERANCE_M = 1.0e-6
#: the shortest link a scene accepts (shared/config.py LINK_LENGTH_RANGE_M)
MIN_LINK_M = 1.0e-4


class ChainError(ValueError):
    """A held chain that cannot be read as a linkage: names the body or joint."""


@dataclass(frozen=True)
class HeldChain:
    """A serial chain of pivoted bodies, root first, as a `[[linkages]]` table holds it."""

    bodies: tuple[pymunk.Body, ...]
    joints: tuple[pymunk.PivotJoint, ...]
    held: int  # the held body's index
    base: tuple[float, float]
    lengths: tuple[float, ...]
    radius: float  # the capsule about each link's segment that holds its shapes

    def toml(self, name: str, material: str) -> str:
        """The linkage as a scene's `[[linkages]]` table."""

        def vec(v: tuple[float, ...]) -> str:
            return "[" + ", ".join(repr(float(x)) for x in v) + "]"

        bs = self.bodies
        angles = [bs[0].angle] + [bs[i].angle - bs[i - 1].angle for i in range(1, len(bs))]
        return (
            f'[[linkages]]\nname = "{name}"\nmaterial = "{material}"\n'
            f"base = {vec(self.base)}\nlengths = {vec(self.lengths)}\n"
            f"masses = {vec(tuple(b.mass for b in bs))}\n"
            f"inertias = {vec(tuple(b.moment for b in bs))}\n"
            "com_offsets = [" + ", ".join(vec(tuple(b.center_of_gravity)) for b in bs) + "]\n"
            f"initial_angles = {vec(tuple(angles))}\nradius = {self.radius!r}\n"
        )


def _pivots(space: pymunk.Space) -> dict[pymunk.Body, list[pymunk.PivotJoint]]:
    by_body: dict[pymunk.Body, list[pymunk.PivotJoint]] = {}
    for c in space.constraints:
        if isinstance(c, pymunk.PivotJoint):
            by_body.setdefault(c.a, []).append(c)
            by_body.setdefault(c.b, []).append(c)
    return by_body


def _other(joint: pymunk.PivotJoint, body: pymunk.Body) -> pymunk.Body:
    return joint.b if joint.a is body else joint.a


def _anchor(joint: pymunk.PivotJoint, body: pymunk.Body) -> tuple[float, float]:
    """The joint's anchor in `body`'s frame."""
    a = joint.anchor_a if joint.a is body else joint.anchor_b
    return float(a[0]), float(a[1])


Path = list[tuple[pymunk.PivotJoint, pymunk.Body]]


def _walk(by_body: dict[pymunk.Body, list[pymunk.PivotJoint]], tool: pymunk.Body) -> list[Path]:
    """From the held body along each of its pivots: (joint, the body past it), ... to the
    ground (a static or kinematic body) or the chain's free end."""
    seen = {tool}
    ends: list[Path] = []
    for start in by_body.get(tool, []):
        path: Path = []
        body, joint = tool, start
        while True:
            nxt = _other(joint, body)
            path.append((joint, nxt))
            if nxt.body_type != pymunk.Body.DYNAMIC or nxt in seen:
                break
            seen.add(nxt)
            onward = [j for j in by_body.get(nxt, []) if j is not joint]
            if not onward:  # the chain's free end
                break
            if len(onward) > 1:
                raise ChainError(
                    f"body at {tuple(nxt.position)} of the held chain has {len(onward) + 1} "
                    "pivot joints: a held chain must be serial (two joints a link at most)"
                )
            body, joint = nxt, onward[0]
        ends.append(path)
    return ends


def find_held_chain(space: pymunk.Space, tool: pymunk.Body) -> HeldChain | None:
    """The serial chain of PivotJoints from a static body to `tool` (and on past it to its
    free end, if it is held in the middle); None when no PivotJoint holds `tool`."""
    by_body = _pivots(space)
    if tool not in by_body:
        return None
    paths = _walk(by_body, tool)
    if len(paths) > 2:
        raise ChainError(
            f"the held body has {len(paths)} pivot joints: a held chain must be serial"
        )
    grounded = [p for p in paths if p[-1][1].body_type != pymunk.Body.DYNAMIC]
    free = [p for p in paths if p[-1][1].body_type == pymunk.Body.DYNAMIC]
    if len(grounded) != 1:
        raise ChainError(
            f"the held chain reaches the ground through {len(grounded)} pivots: exactly one "
            "(a serial chain from a static or kinematic body) is rendered"
        )
    if grounded[0][-1][1].body_type != pymunk.Body.STATIC:
        raise ChainError("the held chain hangs from a kinematic body: only a static base")
    # root first: the ground path reversed, the held body, then its free side
    up = grounded[0]
    bodies = [b for _, b in reversed(up[:-1])] + [tool]
    joints = [j for j, _ in reversed(up)]
    for path in free:
        for joint, body in path:
            bodies.append(body)
            joints.append(joint)
    return _as_linkage(bodies, joints, len(up) - 1)


def _as_linkage(bodies: list[pymunk.Body], joints: list[pymunk.PivotJoint], held: int) -> HeldChain:
    """Lengths from each child's pivot on its parent's x axis; the radius of the capsules."""
    for body, joint in zip(bodies, joints, strict=True):
        ax, ay = _anchor(joint, body)
        if math.hypot(ax, ay) > PIVOT_TOLERANCE_M:
            raise ChainError(
                f"link body at {tuple(body.position)}: its pivot to its parent is at "
                f"({ax:g}, {ay:g}) in its frame; a link's origin must be its pivot"
            )
    lengths = []
    for i, body in enumerate(bodies):
        if i + 1 < len(bodies):
            x, y = _anchor(joints[i + 1], body)
            if abs(y) > PIVOT_TOLERANCE_M or x < MIN_LINK_M:
                raise ChainError(
                    f"link body at {tuple(body.position)}: its child's pivot is at ({x:g}, "
                    f"{y:g}) in its frame; it must lie on the link's x axis, at x > 0"
                )
            lengths.append(x)
        else:
            lengths.append(max(MIN_LINK_M, max(_reach_x(s) for s in body.shapes)))
    radius = max(
        max((_off_axis(s, length) for s in b.shapes), default=0.0)
        for b, length in zip(bodies, lengths, strict=True)
    )
    root = joints[0]
    static = root.a if root.a is not bodies[0] else root.b
    base = static.local_to_world(_anchor(root, static))
    return HeldChain(
        tuple(bodies), tuple(joints), held, (float(base[0]), float(base[1])), tuple(lengths),
        max(radius, 1.0e-6),
    )  # fmt: skip


def _points(shape: pymunk.Shape) -> tuple[list[tuple[float, float]], float]:
    """A shape's defining points in its body's frame and the radius about them."""
    if isinstance(shape, pymunk.Circle):
        pts = [shape.offset]
    elif isinstance(shape, pymunk.Segment):
        pts = [shape.a, shape.b]
    else:
        assert isinstance(shape, pymunk.Poly)
        pts = shape.get_vertices()
    return [(float(p[0]), float(p[1])) for p in pts], shape.radius


def _reach_x(shape: pymunk.Shape) -> float:
    """How far along its link's x axis a shape's defining points reach (a free end link's
    length: its capsule radius covers the rest)."""
    pts, _ = _points(shape)
    return max(p[0] for p in pts)


def _off_axis(shape: pymunk.Shape, length: float) -> float:
    """How far the shape reaches from the link's segment (0, 0)-(length, 0)."""
    pts, r = _points(shape)
    return max(math.hypot(p[0] - min(max(p[0], 0.0), length), p[1]) for p in pts) + r
