"""The world's view messages (sim -> live view, key `<ns>/view/world`, docs/live-view.md):
what the sim steps, for drawing, off the haptic path.

Two kinds, both of one epoch (the sim's) and one layout (which bodies and shapes):
- **shapes**: every body (its name and role) and every shape in its body's frame; sent when
  the layout changes and re-sent every SHAPES_PERIOD_S for a view that joins late;
- **poses**: every body's pose (x, y, angle) at the sim's time `t`, in the layout's body
  order, at the view's rate (`NetworkConfig.view_publish_hz`).

Bytes: the header (magic `HLMV`, uint16 version, uint16 kind, uint64 epoch, uint32 layout
id, uint32 bodies, uint32 shapes, float64 t), then for shapes `bodies` BODY records and
`shapes` SHAPE records, for poses `bodies` POSE records; little-endian, nothing else. A
message is checked whole (`decode_world`): sizes, kinds, indices, finite values, bounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haptic_local_model.shared.protocol.update import MessageError

WORLD_MAGIC = b"HLMV"
WORLD_VERSION = 1
KIND_SHAPES, KIND_POSES = 1, 2
SHAPES_PERIOD_S = 1.0  # a view that joins late draws the bodies within this
MAX_BODIES = 1024
MAX_SHAPES = 2048
MAX_VERTS = 16  # a polygon's vertices (a box has 4)
MAX_COORD_M = 1.0e3  # anything farther out than this is not a body of a desk-top scene
MAX_RADIUS_M = 10.0

HEADER_DTYPE = np.dtype(
    [("magic", "S4"), ("version", "<u2"), ("kind", "<u2"), ("epoch", "<u8"),
     ("layout", "<u4"), ("bodies", "<u4"), ("shapes", "<u4"), ("t", "<f8")]
)  # fmt: skip
# a body's role: how the view colours it
ROLE_STATIC, ROLE_KINEMATIC, ROLE_DYNAMIC, ROLE_TOOL = 0, 1, 2, 3
ROLES = ("static", "kinematic", "dynamic", "tool")
BODY_DTYPE = np.dtype([("name", "S24"), ("role", "u1"), ("pad", "u1", 3)])
# a shape in its body's frame: a circle (verts[0] its centre), a segment (verts[0..1] its
# ends, radius its half-thickness) or a polygon (verts[:n_verts], rounded by radius)
SHAPE_CIRCLE, SHAPE_SEGMENT, SHAPE_POLY = 0, 1, 2
SHAPE_DTYPE = np.dtype(
    [("body", "<u2"), ("kind", "u1"), ("n_verts", "u1"), ("radius", "<f4"),
     ("verts", "<f4", (MAX_VERTS, 2))]
)  # fmt: skip
POSE_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("angle", "<f4")])


@dataclass(frozen=True)
class WorldShapes:
    epoch: int
    layout: int
    t: float
    bodies: np.ndarray  # BODY_DTYPE
    shapes: np.ndarray  # SHAPE_DTYPE


@dataclass(frozen=True)
class WorldPoses:
    epoch: int
    layout: int
    t: float
    poses: np.ndarray  # POSE_DTYPE, one per body of the layout


def _header(kind: int, epoch: int, layout: int, t: float, bodies: int, shapes: int) -> bytes:
    head = np.zeros(1, HEADER_DTYPE)
    head[0] = (WORLD_MAGIC, WORLD_VERSION, kind, epoch, layout, bodies, shapes, t)
    return head.tobytes()


def encode_shapes(shapes: WorldShapes) -> bytes:
    head = _header(KIND_SHAPES, shapes.epoch, shapes.layout, shapes.t, len(shapes.bodies),
                   len(shapes.shapes))  # fmt: skip
    return head + shapes.bodies.tobytes() + shapes.shapes.tobytes()


def encode_poses(poses: WorldPoses) -> bytes:
    head = _header(KIND_POSES, poses.epoch, poses.layout, poses.t, len(poses.poses), 0)
    return head + poses.poses.tobytes()


def layout_id(bodies: np.ndarray, shapes: np.ndarray) -> int:
    """The layout's name: a CRC of its bodies and shapes (a change makes a new one)."""
    import zlib

    return zlib.crc32(bodies.tobytes() + shapes.tobytes())


def decode_world(raw: bytes) -> WorldShapes | WorldPoses:
    """A world view message checked whole; MessageError (reason, detail) otherwise."""
    n = HEADER_DTYPE.itemsize
    if len(raw) < n:
        raise MessageError("size", f"{len(raw)} bytes is shorter than the {n}-byte header")
    head = np.frombuffer(raw, HEADER_DTYPE, 1)[0]
    if bytes(head["magic"]) != WORLD_MAGIC:
        raise MessageError("magic", f"{bytes(head['magic'])!r} is not {WORLD_MAGIC!r}")
    if int(head["version"]) != WORLD_VERSION:
        raise MessageError("version", f"version {int(head['version'])}, not {WORLD_VERSION}")
    kind, bodies, count = int(head["kind"]), int(head["bodies"]), int(head["shapes"])
    if kind not in (KIND_SHAPES, KIND_POSES):
        raise MessageError("kind", f"kind {kind} is neither shapes nor poses")
    if not (0 < bodies <= MAX_BODIES and 0 <= count <= MAX_SHAPES):
        raise MessageError("bounds", f"{bodies} bodies, {count} shapes")
    t = float(head["t"])
    if not np.isfinite(t):
        raise MessageError("finite", "the time is not finite")
    epoch, layout = int(head["epoch"]), int(head["layout"])
    if kind == KIND_POSES:
        _size(raw, n + bodies * POSE_DTYPE.itemsize, "poses")
        poses = np.frombuffer(raw, POSE_DTYPE, bodies, n).copy()
        _finite_within(poses.view(("<f4", 3)), MAX_COORD_M, "a pose")
        return WorldPoses(epoch, layout, t, poses)
    _size(raw, n + bodies * BODY_DTYPE.itemsize + count * SHAPE_DTYPE.itemsize, "shapes")
    body = np.frombuffer(raw, BODY_DTYPE, bodies, n).copy()
    shape = np.frombuffer(raw, SHAPE_DTYPE, count, n + bodies * BODY_DTYPE.itemsize).copy()
    if np.any(body["role"] >= len(ROLES)):
        raise MessageError("role", f"a body's role is not one of {ROLES}")
    if np.any(shape["body"] >= bodies) or np.any(shape["kind"] > SHAPE_POLY):
        raise MessageError("index", "a shape names a body or a kind that does not exist")
    if np.any(shape["n_verts"] > MAX_VERTS) or np.any(shape["radius"] < 0):
        raise MessageError("bounds", f"a polygon of more than {MAX_VERTS} vertices, or a "
                                     "negative radius")  # fmt: skip
    _finite_within(shape["verts"], MAX_COORD_M, "a shape's vertex")
    _finite_within(shape["radius"], MAX_RADIUS_M, "a shape's radius")
    if layout != layout_id(body, shape):
        raise MessageError("layout", f"layout id {layout} is not its bodies' and shapes'")
    return WorldShapes(epoch, layout, t, body, shape)


def _size(raw: bytes, expected: int, what: str) -> None:
    if len(raw) != expected:
        raise MessageError("size", f"{len(raw)} bytes, a {what} message of its counts is "
                                   f"{expected}")  # fmt: skip


def _finite_within(values: np.ndarray, bound: float, what: str) -> None:
    if not np.all(np.isfinite(values)) or np.any(np.abs(values) > bound):
        raise MessageError("finite", f"{what} is not finite or beyond {bound:g}")
