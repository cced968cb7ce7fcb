"""Local shapes and the 2D narrow phase of the haptic loop (DESIGN-WAVE2 C2).

A shape is a convex core (a point, a segment, or a convex polygon of at most 8 vertices,
counter-clockwise, in its body's frame about the body's centre of mass) swept by a rounding
radius rho, as pymunk's circle, segment and poly radius. Its world pose is the body's pose
at the update (COM position and angle) carried forward by the body's twist over the update's
age tau, by one of two exact maps:

- BALLISTIC (a free body): the COM moves in a straight line at v and the body spins at
  omega about it, c(tau) = c_u + v tau, theta(tau) = theta_u + omega tau;
- SCREW (a prescribed motion, a constant spatial twist): the body turns about its fixed
  instantaneous centre, c(tau) = c_u + sin(w tau)/w v + (1 - cos(w tau))/w perp(v);

or, for a segment of a deformable surface (a membrane's polyline), NODAL: its two nodes
move each on its own, by the haptic side's node first-order hold (DESIGN-WAVE2 §4; the
update carries the nodes only, about a pose with zero angle and zero twist).

For the finite-sphere proxy of radius r, an obstacle is the configuration-space set
core + B(rho + r); its signed distance phi = dist(p, core) - rho - r is convex in p (the
distance to a convex set is convex), which the swept test (`sweep_distance`) relies on.
All functions are numba kernels over records and preallocated arrays.
"""

from __future__ import annotations

import enum
import math

import numpy as np
import numpy.typing as npt
from numba import njit

MAX_SHAPES = 64
MAX_VERTICES = 8


class ShapeKind(enum.IntEnum):
    """The core of a shape (the wire's `kind`; its vertex count follows from it)."""

    CIRCLE = 0  # one vertex, the centre; rho is the radius
    SEGMENT = 1  # two vertices; rho is the half thickness
    POLYGON = 2  # 3..8 vertices, convex, counter-clockwise


class Motion(enum.IntEnum):
    """How a shape's pose is carried forward from its update (module docstring)."""

    BALLISTIC = 0
    SCREW = 1
    NODAL = 2  # segments only: the nodes are held by the haptic side (module docstring)
    TRACK = 3  # a car of a train: posed by the haptic side's avar (shared/avar.py), by `owner`


#: One local shape as the haptic loop holds it: what the sim sent, plus `bound` (the core's
#: radius about the COM, computed at install; it bounds how far a point of the core moves).
SHAPE_DTYPE = np.dtype(
    [
        ("key", np.int64),  # stable identity of the shape (pymunk shape id)
        ("kind", np.int64),  # ShapeKind
        ("n_vert", np.int64),
        ("generation", np.int64),  # topology generation (deformables)
        ("motion", np.int64),  # Motion
        ("vertices", np.float64, (MAX_VERTICES, 2)),  # m, body frame about the COM
        ("rounding", np.float64),  # rho, m
        ("pose", np.float64, (3,)),  # COM x, y (m) and angle (rad) at the update
        ("twist", np.float64, (3,)),  # COM velocity (m/s) and angular velocity (rad/s)
        ("static_friction", np.float64),  # mu_s
        ("friction", np.float64),  # mu_k
        ("bound", np.float64),  # m, max |vertex| (derived)
        ("owner", np.int64),  # -1 the world; k: car k of the train (motion TRACK)
    ]
)

SERIES_BELOW = 1.0e-4  # |omega tau| under which the screw map uses its Taylor series
MIN_EDGE_M = 1.0e-12  # a segment or polygon edge shorter than this is degenerate


def shape_array(n: int) -> np.ndarray:
    """n zeroed shape records of the world (owner -1)."""
    rows = np.zeros(n, dtype=SHAPE_DTYPE)
    rows["owner"] = -1
    return rows


def polygon_problem(vertices: npt.ArrayLike) -> str:
    """Why a polygon core is not acceptable ("" if it is): 3..8 finite vertices, strictly
    convex and counter-clockwise (every vertex strictly left of every edge it is not on: a
    left turn at each vertex alone would pass a star), no repeated vertex."""
    v = np.asarray(vertices, dtype=float)
    n = len(v)
    if not 3 <= n <= MAX_VERTICES:
        return f"a polygon needs 3..{MAX_VERTICES} vertices, got {n}"
    if not np.all(np.isfinite(v)):
        return "a vertex is not finite"
    edges = np.roll(v, -1, axis=0) - v
    if np.any(np.hypot(edges[:, 0], edges[:, 1]) <= MIN_EDGE_M):
        return "two consecutive vertices coincide"
    nxt = np.roll(edges, -1, axis=0)
    turns = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]
    if np.all(turns < 0.0):
        return "the vertices run clockwise (counter-clockwise expected)"
    for i in range(n):
        rel = v - v[i]
        side = edges[i, 0] * rel[:, 1] - edges[i, 1] * rel[:, 0]
        others = np.ones(n, dtype=bool)
        others[[i, (i + 1) % n]] = False
        if not np.all(side[others] > 0.0):
            return "the polygon is not convex"
    return ""


def set_core(shape: np.void, kind: ShapeKind, vertices: npt.ArrayLike, rounding: float) -> None:
    """Fill a shape record's core (kind, vertices, rho, bound) from body-frame vertices."""
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    shape["kind"] = int(kind)
    shape["n_vert"] = len(v)
    shape["vertices"][:] = 0.0
    shape["vertices"][: len(v)] = v
    shape["rounding"] = rounding
    shape["bound"] = float(np.max(np.hypot(v[:, 0], v[:, 1])))


@njit(cache=True)
def carry_pose(pose, twist, motion, tau, out):
    """out = the pose carried forward tau seconds by the twist (module docstring)."""
    w = twist[2]
    a = w * tau
    out[2] = pose[2] + a
    if motion == 0 or a == 0.0:
        out[0] = pose[0] + twist[0] * tau
        out[1] = pose[1] + twist[1] * tau
        return
    if abs(a) < SERIES_BELOW:
        s = tau * (1.0 - a * a / 6.0)  # sin(a) / w
        c = tau * (0.5 * a - a * a * a / 24.0)  # (1 - cos a) / w
    else:
        s = math.sin(a) / w
        c = (1.0 - math.cos(a)) / w
    out[0] = pose[0] + s * twist[0] - c * twist[1]
    out[1] = pose[1] + s * twist[1] + c * twist[0]


@njit(cache=True)
def carry_rate(twist, motion, tau, out):
    """out = d/dtau of carry_pose: the COM velocity (turned by omega tau for a screw) and
    omega."""
    out[2] = twist[2]
    if motion == 0:
        out[0] = twist[0]
        out[1] = twist[1]
        return
    a = twist[2] * tau
    cs = math.cos(a)
    sn = math.sin(a)
    out[0] = cs * twist[0] - sn * twist[1]
    out[1] = sn * twist[0] + cs * twist[1]


@njit(cache=True)
def to_body(pose, x, y):
    """World point -> the body frame of a pose (about its COM)."""
    cs = math.cos(pose[2])
    sn = math.sin(pose[2])
    dx = x - pose[0]
    dy = y - pose[1]
    return cs * dx + sn * dy, -sn * dx + cs * dy


@njit(cache=True)
def to_world(pose, x, y):
    """Body-frame point -> world."""
    cs = math.cos(pose[2])
    sn = math.sin(pose[2])
    return pose[0] + cs * x - sn * y, pose[1] + sn * x + cs * y


@njit(cache=True)
def core_distance(shape, qx, qy):
    """Signed distance from a body-frame point to the shape's core, and the outward unit
    normal (body frame): `vertex_distance` of its vertices."""
    return vertex_distance(shape.vertices, shape.n_vert, qx, qy)


@njit(cache=True)
def vertex_distance(v, n, qx, qy):
    """Signed distance from a point to the core of the first n vertices of v (a point, a
    segment, or a convex counter-clockwise polygon) and the outward unit normal: positive
    outside, minus the depth to the nearest edge inside a polygon. A point on a point or
    segment core gets the segment's left normal (no direction)."""
    if n == 1:
        dx = qx - v[0, 0]
        dy = qy - v[0, 1]
        d = math.hypot(dx, dy)
        if d == 0.0:
            return 0.0, 0.0, 1.0
        return d, dx / d, dy / d
    best = 1e300
    bx = 0.0
    by = 0.0
    inside = n >= 3
    deepest = -1e300
    ex_n = 0.0
    ey_n = 0.0
    edges = n if n >= 3 else 1
    for i in range(edges):
        ax = v[i, 0]
        ay = v[i, 1]
        j = i + 1 if i + 1 < n else 0
        ex = v[j, 0] - ax
        ey = v[j, 1] - ay
        length2 = ex * ex + ey * ey
        t = ((qx - ax) * ex + (qy - ay) * ey) / length2 if length2 > 0.0 else 0.0
        t = min(1.0, max(0.0, t))
        cx = ax + t * ex
        cy = ay + t * ey
        d = math.hypot(qx - cx, qy - cy)
        if d < best:
            best = d
            bx = cx
            by = cy
        if n >= 3 and length2 > 0.0:
            length = math.sqrt(length2)
            nx = ey / length
            ny = -ex / length
            s = nx * (qx - ax) + ny * (qy - ay)
            if s > 0.0:
                inside = False
            if s > deepest:
                deepest = s
                ex_n = nx
                ey_n = ny
    if inside:
        return deepest, ex_n, ey_n
    if best == 0.0:
        if n >= 3:
            return 0.0, ex_n, ey_n
        ex = v[1, 0] - v[0, 0]
        ey = v[1, 1] - v[0, 1]
        length = math.hypot(ex, ey)
        if length == 0.0:
            return 0.0, 0.0, 1.0
        return 0.0, -ey / length, ex / length
    return best, (qx - bx) / best, (qy - by) / best


@njit(cache=True)
def signed_distance(shape, pose, px, py, radius):
    """phi and the world normal of a disc of the given radius at (px, py) against the shape
    at pose: phi = dist(p, core) - rho - radius (convex in p)."""
    return vertex_signed_distance(
        shape.vertices, shape.n_vert, shape.rounding, pose, px, py, radius
    )


@njit(cache=True)
def vertex_signed_distance(v, n, rounding, pose, px, py, radius):
    """signed_distance of the core of v[:n] (body frame of pose) rounded by rho."""
    qx, qy = to_body(pose, px, py)
    d, nx, ny = vertex_distance(v, n, qx, qy)
    cs = math.cos(pose[2])
    sn = math.sin(pose[2])
    return d - rounding - radius, cs * nx - sn * ny, sn * nx + cs * ny


SWEEP_ITERATIONS = 8
SWEEP_TOLERANCE_M = 1.0e-9


@njit(cache=True)
def sweep_distance(shape, pose, p, u, length, radius, gap):
    """`vertex_sweep_distance` of the shape's core, for a disc of the given radius that must
    stay `gap` outside it."""
    reach = shape.rounding + radius + gap
    return vertex_sweep_distance(shape.vertices, shape.n_vert, pose, p, u, length, reach)


@njit(cache=True)
def vertex_sweep_distance(v, n, pose, p, u, length, reach):
    """How far a point can move from p along the unit direction u (at most `length`) and
    stay `reach` (the core's rounding, the disc's radius and a gap) outside the core of
    v[:n]: Newton's iteration on the convex psi = dist - reach along the ray, which
    approaches its root from below and never steps past it (a convex function lies above its
    tangents). Returns `length` when the shape is not reached; stops short (never through)
    if the iteration cap is met."""
    s = 0.0
    for _ in range(SWEEP_ITERATIONS):
        x = p[0] + s * u[0]
        y = p[1] + s * u[1]
        psi, nx, ny = vertex_signed_distance(v, n, reach, pose, x, y, 0.0)
        if psi <= SWEEP_TOLERANCE_M:
            return s
        slope = nx * u[0] + ny * u[1]
        if slope >= -1e-12:
            return length  # phi does not decrease along the rest of the ray
        s += psi / -slope
        if s >= length:
            return length
    return s
