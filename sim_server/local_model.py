"""The local model the sim publishes each step (DESIGN §3; seed 000 §VII, seed 001 §3), in one
compiled call: D, G, C q̇, J_h and Λ⁻¹ at the tool's configuration, the directions its joints
resist (the left singular vectors of the scaled J_h whose singular value is below the rank
tolerance), and the neighbourhood's contacts, written into the record the haptic side parses
into (LOCAL_MODEL_DTYPE) and encoded from it (shared.protocol.update.encode_record).

The neighbourhood: each tool shape, inflated by the margin, is passed to Chipmunk's
`cpSpaceShapeQuery`, whose callback (`collect_hit`, a numba cfunc) copies each overlapping
shape's contact point set into a buffer; the tool point (link frame), the world point, the
outward normal and the world point's velocity are read from it, the rows sorted by gap
(stable) and the nearest MAX_CONTACTS kept. Only neighbours are visited: the query walks
Chipmunk's spatial index, not the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pymunk
from numba import carray, cfunc, from_dtype, njit, types

from haptic_local_model.shared.kinematics import (
    MAX_DOF,
    VELOCITY_TORQUE_STEP,
    mass_matrix_and_gravity,
    point_jacobian,
    point_on_link,
    scaled_gram,
    velocity_product_torque,
)
from haptic_local_model.shared.linalg import cholesky_inplace, cholesky_solve, symmetric_eigen
from haptic_local_model.shared.protocol.layout import LOCAL_MODEL_DTYPE, MAX_CONTACTS
from haptic_local_model.shared.protocol.update import encode_record
from haptic_local_model.sim_server import chipmunk as cp
from haptic_local_model.sim_server.tool import TOOL_LINKAGE, tool_state

if TYPE_CHECKING:  # annotations only
    from collections.abc import Sequence

    from haptic_local_model.shared.config import Material

TOUCH_TOLERANCE_M = 1.0e-4  # gap below which the tool counts as touching (FOH force gate)
TOOL_GROUP = 1  # pymunk shape-filter group: tool shapes never collide with each other
HITS_PER_QUERY = 1024  # shapes one tool shape's neighbourhood may overlap (more: counted)
MAX_CANDIDATES = 4096  # contact points before the nearest MAX_CONTACTS are kept

I8, F8 = np.int64, np.float64

#: Chipmunk's cpContactPointSet, as its C layout (count, padding, normal, 2 x (a, b, dist)).
CP_CONTACT_SET_DTYPE = np.dtype(
    [("count", np.int32), ("pad", np.int32), ("normal", F8, (2,)), ("points", F8, (2, 5))]
)
#: What collect_hit copies out of each query callback.
HITS_DTYPE = np.dtype(
    [
        ("count", I8),
        ("dropped", I8),  # hits beyond HITS_PER_QUERY
        ("hit_shape", I8, (HITS_PER_QUERY,)),  # the world shape hit (cpShape*)
        ("n_points", I8, (HITS_PER_QUERY,)),
        ("normal", F8, (HITS_PER_QUERY, 2)),  # from the tool to the world shape
        ("points", F8, (HITS_PER_QUERY, 2, 5)),  # point on the tool, on the world, distance
    ]
)
#: One tool shape's query: the inflated copy (on the tool's body), that body, its link.
QUERY_DTYPE = np.dtype([("query_shape", I8), ("body", I8), ("link", I8)])
#: A world shape the tool may touch, sorted by `shape`: its key and its material.
ENV_SHAPE_DTYPE = np.dtype(
    [
        ("ptr", I8),  # cpShape*
        ("key", I8),  # registration order: the contact key is key * 1024 + query index
        ("friction", F8),
        ("restitution", F8),
        ("stiffness", F8),
        ("damping", F8),
        ("tangential_stiffness", F8),
    ]
)
#: A contact point before the nearest are kept.
CANDIDATE_DTYPE = np.dtype(
    [
        ("gap", F8),
        ("link", I8),
        ("key", I8),
        ("tool", F8, (2,)),
        ("env", F8, (2,)),
        ("normal", F8, (2,)),
        ("env_velocity", F8, (2,)),
        ("share", F8),  # 1 / points of its manifold: its part of the pair's K, B, K_t
        ("env_index", I8),
    ]
)


@cfunc(
    types.void(
        types.int64,
        types.CPointer(from_dtype(CP_CONTACT_SET_DTYPE)),
        types.CPointer(from_dtype(HITS_DTYPE)),
    ),
    cache=True,
)
def collect_hit(shape, points, hits):  # pragma: no cover - called by Chipmunk
    """cpSpaceShapeQueryFunc: copy one overlapping shape's contact point set."""
    h = carray(hits, (1,))[0]
    ps = carray(points, (1,))[0]
    i = h.count
    if i >= HITS_PER_QUERY:
        h.dropped += 1
        return
    h.hit_shape[i] = shape
    h.n_points[i] = ps.count
    h.normal[i, 0] = ps.normal[0]
    h.normal[i, 1] = ps.normal[1]
    for p in range(ps.count):
        for c in range(5):
            h.points[i, p, c] = ps.points[p, c]
    h.count = i + 1


@dataclass
class StageStats:
    """Which optional stages the last local-model computation ran (leave out what is not needed)."""

    svd: bool = False
    gravity: bool = False
    contacts_sent: int = 0
    shapes_queried: int = 0
    hits_dropped: int = 0  # overlaps beyond HITS_PER_QUERY or MAX_CANDIDATES (0 expected)


class LocalModelKernel:
    """What build_local_model needs of a space, made once: the queries, the world shapes by
    pointer, the buffers.

    tool_shapes: (shape, link index) of the held tool; env_shapes: (shape, key, material) of
    every world shape the tool may touch (a shape in neither is not rendered); margin: the
    neighbourhood margin (m)."""

    def __init__(
        self,
        tool_shapes: Sequence[tuple[pymunk.Shape, int]],
        env_shapes: Sequence[tuple[pymunk.Shape, int, Material]],
        margin: float,
    ) -> None:
        # inflated copies ride on the tool's own bodies, outside the space
        self._inflated = [_inflated(shape, margin) for shape, _ in tool_shapes]
        self.queries = np.zeros(len(self._inflated), QUERY_DTYPE)
        for i, (q, (shape, link)) in enumerate(zip(self._inflated, tool_shapes, strict=True)):
            assert shape.body is not None
            self.queries[i] = (cp.shape_ptr(q), cp.body_ptr(shape.body), link)
        env = np.zeros(len(env_shapes), ENV_SHAPE_DTYPE)
        for i, (shape, key, m) in enumerate(env_shapes):
            env[i] = (
                cp.shape_ptr(shape), key, m.friction, m.restitution,
                m.stiffness_n_per_m, m.damping_ns_per_m, m.tangential_stiffness,
            )  # fmt: skip
        self.env = np.sort(env, order="ptr")
        self.hits = np.zeros(1, HITS_DTYPE)
        self.counts = np.zeros(2, I8)  # shapes queried, hits dropped
        #: what neighbourhood_contacts reads: the queries, the world shapes, collect_hit's
        #: address, its buffer, the candidates and their gaps, the counts
        self.query = (
            self.queries, self.env, collect_hit.address, self.hits,
            np.zeros(MAX_CANDIDATES, CANDIDATE_DTYPE), np.zeros(MAX_CANDIDATES), self.counts,
        )  # fmt: skip
        self.record = np.zeros(1, LOCAL_MODEL_DTYPE)
        self.work = (
            np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF), np.zeros((3, MAX_DOF)),
            np.zeros((MAX_DOF, MAX_DOF)), np.zeros((3, 3)), np.zeros(3), np.zeros(MAX_DOF),
        )  # fmt: skip


@njit(cache=True)
def build_local_model(tool, chain, query, work, out):
    """Fill `out` (LOCAL_MODEL_DTYPE[1]) with the local model at the tool's state (the
    fields the wire carries; epoch, seq, times are the caller's).

    tool: TOOL_DTYPE[1]; chain: CHAIN_DTYPE[1]; query, work: LocalModelKernel's."""
    t, m, c = tool[0], out[0], chain[0]
    d = t.dof
    frame_pos, frame_angle, jac, chol, scaled, sigma, col = work
    m.dof = d
    m.op_link = t.op_link
    m.base_angle = c.base_angle
    m.characteristic_length = t.characteristic_length
    for i in range(d):
        m.joint_types[i] = c.joint_types[i]
        m.lengths[i] = c.lengths[i]
        m.parents[i] = c.parents[i]
    m.n_chains = c.n_chains
    m.has_chains = 1 if c.n_chains > 1 else 0  # a tree or several chains need the trailer
    for i in range(d):
        if c.parents[i] != i - 1:
            m.has_chains = 1
    for k in range(c.n_chains):
        m.chain_first[k] = c.chain_first[k]
        m.chain_kind[k] = c.chain_kind[k]
        m.chain_port[k] = c.chain_port[k]
        for a in range(3):
            m.chain_base[k, a] = c.chain_base[k, a]
    for i in range(2):
        m.base[i] = c.base[i]
        m.op_point[i] = t.op_point[i]
    tool_state(tool, m.q, m.qd)
    # it leaves the link frames of q in frame_pos / frame_angle: J_h is taken from them
    mass_matrix_and_gravity(chain, t.gravity, m.q, (frame_pos, frame_angle, jac), m.mass, m.gravity)
    point_on_link(frame_pos, frame_angle, t.op_link, t.op_point, sigma)
    m.tool_pose[0], m.tool_pose[1] = sigma[0], sigma[1]
    m.tool_pose[2] = frame_angle[t.op_link]
    point_jacobian(c, frame_pos, d, t.op_link, sigma[0], sigma[1], jac)
    m.has_gravity = 1 if (t.gravity[0] != 0.0 or t.gravity[1] != 0.0) else 0
    _inverse_inertia(m, jac, chol, col)
    m.n_resisted = 0
    m.has_velocity_torque = 0
    if t.kind == TOOL_LINKAGE:  # a free body's J_h is full rank and its D constant
        _resisted_directions(m, jac, t.characteristic_length, t.rank_tolerance, scaled, sigma)
        velocity_product_torque(chain, m.q, m.qd, VELOCITY_TORQUE_STEP, m.velocity_torque)
        m.has_velocity_torque = 1
    neighbourhood_contacts(tool, query, m)


@njit(cache=True)
def _inverse_inertia(m, jac, chol, col):
    """Λ⁻¹ = J_h D⁻¹ J_hᵀ (seed 000 eq 6), D by its Cholesky factor."""
    d = m.dof
    cholesky_inplace(m.mass, d, chol)
    for r in range(3):
        for i in range(d):
            col[i] = jac[r, i]
        cholesky_solve(chol, d, col, col)  # D^-1 J_h^T's column r
        for a in range(3):
            s = 0.0
            for i in range(d):
                s += jac[a, i] * col[i]
            m.lambda_inv[a, r] = s


@njit(cache=True)
def _resisted_directions(m, jac, length, tolerance, scaled, sigma):
    """The left singular vectors of diag(1, 1, L) J_h (DESIGN §3; seed 000 eq 14, 22) whose
    singular value is below `tolerance` times the largest: the eigenvectors of the scaled
    J_h J_hᵀ, in descending order, so the resisted ones come last."""
    gram = np.empty((3, 3))
    scaled_gram(jac, m.dof, length, gram)
    symmetric_eigen(gram, 3, sigma, scaled)
    for k in range(3):
        sigma[k] = math.sqrt(max(sigma[k], 0.0))
    top = sigma[0]
    j = 0
    for k in range(3):
        if top <= 0.0 or sigma[k] < tolerance * top:
            for a in range(3):
                m.resisted[j, a] = scaled[a, k] if top > 0.0 else (1.0 if a == k else 0.0)
            j += 1
    m.n_resisted = j


@njit(cache=True)
def neighbourhood_contacts(tool, query, m):
    """The contacts of every tool shape with the world shapes within the margin into `m`
    (n_contacts, c_*, tool_touching); see the module docstring. query: LocalModelKernel's."""
    t = tool[0]
    queries, env, collect, hits, found, gaps, counts = query
    margin = t.margin
    n = 0
    counts[0] = 0
    counts[1] = 0
    for index in range(queries.shape[0]):
        qr = queries[index]
        hits[0].count = 0
        hits[0].dropped = 0
        cp.space_shape_query(t.space, qr.query_shape, collect, hits.ctypes.data)
        counts[0] += 1
        counts[1] += hits[0].dropped
        h = hits[0]
        for i in range(h.count):
            k = _env_index(env, h.hit_shape[i])
            if k < 0:  # a tool shape
                continue
            nx, ny = -h.normal[i, 0], -h.normal[i, 1]  # from the world to the tool
            n_norm = math.hypot(nx, ny)
            if n_norm < 0.5:
                continue
            nx, ny = nx / n_norm, ny / n_norm
            body = cp.shape_body(h.hit_shape[i])
            moving = cp.body_type(body) != cp.BODY_STATIC
            share = 1.0 / max(1, h.n_points[i])
            for p in range(h.n_points[i]):
                pt = h.points[i, p]
                tx, ty = pt[0] + margin * nx, pt[1] + margin * ny
                ex, ey = pt[2], pt[3]
                gap = nx * (tx - ex) + ny * (ty - ey)
                if gap > margin:
                    continue
                if n >= found.shape[0]:
                    counts[1] += 1
                    continue
                gaps[n] = gap
                r = found[n]
                r.gap, r.link, r.key = gap, qr.link, env[k].key * 1024 + index
                r.tool[0], r.tool[1] = cp.body_world_to_local(qr.body, tx, ty)
                r.env[0], r.env[1], r.normal[0], r.normal[1] = ex, ey, nx, ny
                r.env_velocity[0], r.env_velocity[1] = 0.0, 0.0
                if moving:
                    r.env_velocity[0], r.env_velocity[1] = cp.body_velocity_at_world_point(
                        body, ex, ey
                    )
                r.share, r.env_index = share, k
                n += 1
    _keep_nearest(found, gaps, n, env, m)


@njit(cache=True)
def _env_index(env, shape):
    """Where `shape` is in the world-shape table (sorted by pointer), or -1 (a tool shape)."""
    lo, hi = 0, env.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if env[mid].ptr < shape:
            lo = mid + 1
        else:
            hi = mid
    if lo < env.shape[0] and env[lo].ptr == shape:
        return lo
    return -1


@njit(cache=True)
def _keep_nearest(found, gaps, n, env, m):
    """The nearest MAX_CONTACTS of the `n` found (by gap, ties in the order found) into `m`."""
    order = np.argsort(gaps[:n], kind="mergesort")
    kept = min(n, MAX_CONTACTS)
    m.n_contacts = kept
    m.tool_touching = 1 if kept > 0 and found[order[0]].gap <= TOUCH_TOLERANCE_M else 0
    for i in range(kept):
        r = found[order[i]]
        e = env[r.env_index]
        m.c_link[i], m.c_key[i] = r.link, r.key
        for a in range(2):
            m.c_tool[i, a] = r.tool[a]
            m.c_env[i, a] = r.env[a]
            m.c_normal[i, a] = r.normal[a]
            m.c_env_velocity[i, a] = r.env_velocity[a]
        m.c_friction[i] = e.friction
        m.c_restitution[i] = e.restitution
        # a material's stiffness and damping belong to the shape pair: the points of one
        # contact manifold share them, so a face on a wall is as stiff as a corner
        m.c_stiffness[i] = r.share * e.stiffness
        m.c_damping[i] = r.share * e.damping
        m.c_tangential_stiffness[i] = r.share * e.tangential_stiffness


@njit(cache=True)
def encode_stamped(out, buf, epoch, seq, sim_time, publish_time_ns, state_lead_s):
    """The record's header fields the caller knows (epoch, seq, its times), then its bytes
    into `buf` (encode_record); returns their count."""
    m = out[0]
    m.epoch, m.seq, m.sim_time = epoch, seq, sim_time
    m.publish_time_ns, m.state_lead_s = publish_time_ns, state_lead_s
    return encode_record(out, buf)


def resisted_directions(jac: np.ndarray, length: float, tolerance: float) -> np.ndarray:
    """(j, 3) unit directions (scaled space) spanning N(J_hᵀ) at this rank tolerance: the
    kernel's answer for a 3 x d Jacobian (tools and tests)."""
    d = jac.shape[1]
    m = np.zeros(1, LOCAL_MODEL_DTYPE)
    m[0]["dof"] = d
    full = np.zeros((3, MAX_DOF))
    full[:, :d] = jac
    _resisted_directions(m[0], full, length, tolerance, np.zeros((3, 3)), np.zeros(3))
    return m[0]["resisted"][: int(m[0]["n_resisted"])].copy()


def _inflated(shape: pymunk.Shape, margin: float) -> pymunk.Shape:
    """A copy of a tool shape grown by `margin`, on the same body, for neighbourhood queries."""
    q: pymunk.Shape
    if isinstance(shape, pymunk.Poly):
        q = pymunk.Poly(shape.body, shape.get_vertices(), radius=shape.radius + margin)
    elif isinstance(shape, pymunk.Segment):
        q = pymunk.Segment(shape.body, shape.a, shape.b, shape.radius + margin)
    else:
        assert isinstance(shape, pymunk.Circle)
        q = pymunk.Circle(shape.body, shape.radius + margin, shape.offset)
    q.filter = pymunk.ShapeFilter(group=TOOL_GROUP)
    return q
