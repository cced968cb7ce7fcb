"""Planar tree kinematics and dynamics terms shared by the sim and the haptic kernels.

A tool is a tree of joints (DESIGN §2, DESIGN-WAVE2 C1). A free rigid body is the chain
(prismatic x, prismatic y, revolute) with zero lengths, so one set of kernels serves both.
Link i's frame sits at joint i with absolute angle phi_i; points on a link are given in that
frame. Joint i hangs from the tip of link parents[i] (at lengths[parents[i]] along it), or,
with parent -1, from the base of its chain: joints are numbered so that a parent comes
before its children (parents[i] < i), and chain k covers the joints chain_first[k] ..
chain_first[k + 1] - 1 (the extended configuration: the held tool is chain 0, at base and
base_angle; further chains at chain_base[k]). A serial chain has parents[i] = i - 1 and one
chain: the kernels then do the same operations in the same order as the serial ones did.
All functions are numba kernels over records and preallocated arrays (no allocation inside).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

REVOLUTE = 0
PRISMATIC_X = 1  # slides along the world x axis (used before any revolute joint)
PRISMATIC_Y = 2

MAX_DOF = 12  # a joint set is an int64 bit mask (`ancestry`): at most 63
MAX_CHAINS = 4
MAX_PORTS = 2  # devices on one world (DESIGN-WAVE2 C3)
# the kind of each chain of the extended configuration (DESIGN-WAVE2 C4)
CHAIN_TOOL = 0
CHAIN_OBJECT = 1
CHAIN_HAND = 2
CHAIN_AVAR = 3
VELOCITY_TORQUE_STEP = 1.0e-6  # rad, central differences of D(q) for C(q, qd) qd
NO_GRAVITY = np.zeros(2)  # a constant of the kernels (numba freezes global arrays)

#: One tool chain as a record (MJX's jnt_* / body_* columns of one tool): the kernels take
#: it whole, so a new column is a field here, not a new argument at every call site.
CHAIN_DTYPE = np.dtype(
    [
        ("dof", np.int64),
        ("joint_types", np.int64, (MAX_DOF,)),
        ("lengths", np.float64, (MAX_DOF,)),  # m
        ("base", np.float64, (2,)),  # m, world
        ("base_angle", np.float64),  # rad
        ("masses", np.float64, (MAX_DOF,)),  # kg
        ("inertias", np.float64, (MAX_DOF,)),  # kg m^2 about the link's COM
        ("com_offsets", np.float64, (MAX_DOF, 2)),  # m, in the link's frame
        # the tree: joint i hangs from the tip of link parents[i] (-1: its chain's base)
        ("parents", np.int64, (MAX_DOF,)),
        ("n_chains", np.int64),
        ("chain_first", np.int64, (MAX_CHAINS,)),  # first joint of each chain
        ("chain_kind", np.int64, (MAX_CHAINS,)),  # CHAIN_TOOL, ...
        ("chain_port", np.int64, (MAX_CHAINS,)),  # the device port, -1 none
        ("chain_base", np.float64, (MAX_CHAINS, 3)),  # x, y, angle of chains 1.. (0: base)
    ]
)


def chain_record(
    joint_types: np.ndarray,
    lengths: np.ndarray,
    base: np.ndarray,
    base_angle: float,
    masses: np.ndarray,
    inertias: np.ndarray,
    com_offsets: np.ndarray,
    parents: np.ndarray | None = None,
) -> np.ndarray:
    """A CHAIN_DTYPE[1] record of one chain of len(joint_types) joints: serial (each joint
    on the one before) unless `parents` says otherwise."""
    d = len(joint_types)
    if d > MAX_DOF:
        raise ValueError(f"tool has {d} DOF; at most {MAX_DOF} supported")
    tree = np.arange(d) - 1 if parents is None else np.asarray(parents, dtype=np.int64)
    bad = [i for i in range(d) if not -1 <= tree[i] < i] if len(tree) == d else [len(tree)]
    if bad:
        raise ValueError(f"parents: joint {bad[0]} must hang from -1 or an earlier joint")
    rec = np.zeros(1, CHAIN_DTYPE)
    c = rec[0]
    c["dof"] = d
    c["joint_types"][:d] = joint_types
    c["lengths"][:d] = lengths
    c["base"] = base
    c["base_angle"] = base_angle
    c["masses"][:d] = masses
    c["inertias"][:d] = inertias
    c["com_offsets"][:d] = com_offsets
    c["parents"][:d] = tree
    c["n_chains"] = 1
    c["chain_port"][0] = 0
    return rec


@njit(cache=True)
def wrap_angle(angle):
    """angle on (-pi, pi]: a difference of two angles taken the short way round."""
    return math.atan2(math.sin(angle), math.cos(angle))


@njit(cache=True, inline="always")
def ancestry(parents, link):
    """The joints that move `link` (it and its ancestors) as a bit mask; -1: none. A parent
    that does not come before its child ends the walk there (the parser refuses such trees;
    a zeroed record cannot loop)."""
    mask = np.int64(0)
    k = link
    while k >= 0:
        mask |= np.int64(1) << k
        up = parents[k]
        if up >= k:
            break
        k = up
    return mask


@njit(cache=True, inline="always")
def moves(mask, j):
    """Joint j is in the set `mask` (from `ancestry`)."""
    return (mask >> j) & 1 == 1


@njit(cache=True, inline="always")
def root_pose(c, i):
    """Position and angle of the base that root joint i (parent -1) hangs from: chain 0's is
    the record's base and base_angle, a further chain's its row of chain_base."""
    chain = 0
    for k in range(1, c.n_chains):
        if c.chain_first[k] <= i:
            chain = k
    if chain == 0:
        return c.base[0], c.base[1], c.base_angle
    return c.chain_base[chain, 0], c.chain_base[chain, 1], c.chain_base[chain, 2]


@njit(cache=True)
def link_frames(c, q, dof, frame_pos, frame_angle):
    """Origin (joint position) and absolute angle of every link frame at configuration q.

    c: a record with the chain's joint_types, parents, lengths, base, base_angle and chains
    (CHAIN_DTYPE, or the parsed update)."""
    for i in range(dof):
        up = c.parents[i]
        if up < 0 or up >= i:
            px, py, phi = root_pose(c, i)
        else:
            phi = frame_angle[up]
            px = frame_pos[up, 0] + c.lengths[up] * math.cos(phi)
            py = frame_pos[up, 1] + c.lengths[up] * math.sin(phi)
        jt = c.joint_types[i]
        if jt == REVOLUTE:
            phi += q[i]
        elif jt == PRISMATIC_X:
            px += q[i]
        else:
            py += q[i]
        frame_pos[i, 0] = px
        frame_pos[i, 1] = py
        frame_angle[i] = phi


@njit(cache=True)
def point_on_link(frame_pos, frame_angle, link, local_point, out):
    """World position of `local_point` given in the frame of `link`."""
    c = math.cos(frame_angle[link])
    s = math.sin(frame_angle[link])
    out[0] = frame_pos[link, 0] + c * local_point[0] - s * local_point[1]
    out[1] = frame_pos[link, 1] + s * local_point[0] + c * local_point[1]


@njit(cache=True)
def point_jacobian(c, frame_pos, dof, link, px, py, jac):
    """3 x dof Jacobian of (P_x, P_y, phi_link) for world point P on `link` (DESIGN §2):
    column j is zero unless joint j moves the link (c: joint_types and parents)."""
    joint_types = c.joint_types
    mask = ancestry(c.parents, link)
    for j in range(dof):
        if not moves(mask, j):
            jac[0, j] = 0.0
            jac[1, j] = 0.0
            jac[2, j] = 0.0
        elif joint_types[j] == REVOLUTE:
            jac[0, j] = -(py - frame_pos[j, 1])
            jac[1, j] = px - frame_pos[j, 0]
            jac[2, j] = 1.0
        elif joint_types[j] == PRISMATIC_X:
            jac[0, j] = 1.0
            jac[1, j] = 0.0
            jac[2, j] = 0.0
        else:
            jac[0, j] = 0.0
            jac[1, j] = 1.0
            jac[2, j] = 0.0


@njit(cache=True)
def point_velocity(c, frame_pos, link, px, py, qd):
    """World velocity (vx, vy) of point P moving with `link` at rates qd (-1: the ground)."""
    vx = 0.0
    vy = 0.0
    mask = ancestry(c.parents, link)
    for j in range(link + 1):
        if not moves(mask, j):
            continue
        jt = c.joint_types[j]
        if jt == REVOLUTE:
            vx -= qd[j] * (py - frame_pos[j, 1])
            vy += qd[j] * (px - frame_pos[j, 0])
        elif jt == PRISMATIC_X:
            vx += qd[j]
        else:
            vy += qd[j]
    return vx, vy


@njit(cache=True)
def point_bias_acceleration(c, frame_pos, dof, link, px, py, qd, out):
    """J_dot qd of world point P on `link`: its acceleration when qdd = 0 (DESIGN §4.3).

    A revolute joint j moves P at qd_j e_z x (P - o_j), so its column changes at
    qd_j e_z x (v_P - v_oj), with v_oj the velocity of joint j's own origin (which its
    ancestors move). Prismatic columns are constant
    and the angular row is a sum of revolute rates: both contribute nothing.
    """
    top = min(link, dof - 1)
    vpx, vpy = point_velocity(c, frame_pos, top, px, py, qd)
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    mask = ancestry(c.parents, top)
    for j in range(top + 1):
        if not moves(mask, j) or c.joint_types[j] != REVOLUTE:
            continue
        up = c.parents[j] if c.parents[j] < j else -1
        vox, voy = point_velocity(c, frame_pos, up, frame_pos[j, 0], frame_pos[j, 1], qd)
        out[0] -= qd[j] * (vpy - voy)
        out[1] += qd[j] * (vpx - vox)


@njit(cache=True)
def link_spin(c, qd, link):
    """Link `link`'s angular velocity: the rates of the revolute joints that move it."""
    mask = ancestry(c.parents, link)
    spin = 0.0
    for j in range(link + 1):
        if moves(mask, j) and c.joint_types[j] == REVOLUTE:
            spin += qd[j]
    return spin


@njit(cache=True)
def scaled_gram(jac, dof, length, out):
    """S J J^T S with S = diag(1, 1, length) (3 x 3 into out): the Gram matrix of J_h with its
    angular row scaled by the characteristic length (DESIGN §3), whose eigenvectors are
    J_h's left singular vectors in the scaled space."""
    for a in range(3):
        sa = length if a == 2 else 1.0
        for b in range(3):
            sb = length if b == 2 else 1.0
            s = 0.0
            for i in range(dof):
                s += (sa * jac[a, i]) * (sb * jac[b, i])
            out[a, b] = s


@njit(cache=True)
def mass_matrix_and_gravity(chain, gravity, q, work, mass_out, gravity_out):
    """D(q) = sum m J_v^T J_v + I J_w^T J_w and G(q) = -sum m J_v^T g (DESIGN §2).

    chain: CHAIN_DTYPE[1]; work: (frame_pos (d, 2), frame_angle (d,), jac (3, d)) scratch."""
    c = chain[0]
    dof = c.dof
    masses = c.masses
    inertias = c.inertias
    com_offsets = c.com_offsets
    frame_pos, frame_angle, jac = work
    link_frames(c, q, dof, frame_pos, frame_angle)
    for a in range(dof):
        gravity_out[a] = 0.0
        for b in range(dof):
            mass_out[a, b] = 0.0
    for i in range(dof):
        if masses[i] == 0.0 and inertias[i] == 0.0:
            continue
        # the COM in the world: point_on_link's sums, without its output array (no
        # allocation: the haptic side checks every update with this at install)
        cos_i = math.cos(frame_angle[i])
        sin_i = math.sin(frame_angle[i])
        com_x = frame_pos[i, 0] + cos_i * com_offsets[i, 0] - sin_i * com_offsets[i, 1]
        com_y = frame_pos[i, 1] + sin_i * com_offsets[i, 0] + cos_i * com_offsets[i, 1]
        point_jacobian(c, frame_pos, dof, i, com_x, com_y, jac)
        for a in range(dof):
            gravity_out[a] -= masses[i] * (jac[0, a] * gravity[0] + jac[1, a] * gravity[1])
            for b in range(dof):
                mass_out[a, b] += masses[i] * (jac[0, a] * jac[0, b] + jac[1, a] * jac[1, b])
                mass_out[a, b] += inertias[i] * jac[2, a] * jac[2, b]


def fastest_spin(joint_types: np.ndarray, parents: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """The fastest link's angular speed |omega| (rad/s) of a tree moving at qd: a link turns
    with every revolute joint that moves it. qd's last axis is the joints (several states at
    once: one figure per state); joint_types and parents those joints'."""
    rates = np.where(joint_types == REVOLUTE, qd, 0.0)
    omega = np.zeros_like(rates)
    for i in range(rates.shape[-1]):
        up = int(parents[i])
        omega[..., i] = (omega[..., up] if 0 <= up < i else 0.0) + rates[..., i]
    return np.abs(omega).max(axis=-1, initial=0.0)


def free_body_chain() -> tuple[np.ndarray, np.ndarray]:
    """Joint types and lengths of a free rigid body: q = (x, y, theta) of its frame."""
    return (
        np.array([PRISMATIC_X, PRISMATIC_Y, REVOLUTE], dtype=np.int64),
        np.zeros(3),
    )


@njit(cache=True)
def velocity_product_torque(chain, q, qd, step, out):
    """C(q, qd) qd = Ddot qd - 1/2 grad_q(qd^T D qd): Coriolis and centripetal torques.

    dD/dq_k by central differences of `mass_matrix_and_gravity` (step ~1e-6 rad gives
    ~1e-12 relative error); the sim sends the result with each update. Allocates its
    scratch: `velocity_product_torque_into` is the same sum on the caller's."""
    dof = chain[0].dof
    work = (
        np.zeros((dof, 2)), np.zeros(dof), np.zeros((3, dof)), np.zeros(dof),
        np.zeros((dof, dof)), np.zeros((dof, dof)), q.copy(),
    )  # fmt: skip
    velocity_product_torque_into(chain, q, qd, step, work, out)


@njit(cache=True)
def velocity_product_torque_into(chain, q, qd, step, work, out):
    """velocity_product_torque on preallocated scratch: work = (frame_pos (>= d, 2),
    frame_angle (>= d), jac (3, >= d), gravity (>= d), D+ (>= d, >= d), D- (>= d, >= d),
    q copy (>= d)); the same operations in the same order, so the same bits."""
    dof = chain[0].dof
    frame_pos, frame_angle, jac, grav, d_plus, d_minus, qq = work
    zero_g = NO_GRAVITY
    for i in range(dof):
        qq[i] = q[i]
        out[i] = 0.0
    for k in range(dof):
        qq[k] = q[k] + step
        mass_matrix_and_gravity(chain, zero_g, qq, (frame_pos, frame_angle, jac), d_plus, grav)
        qq[k] = q[k] - step
        mass_matrix_and_gravity(chain, zero_g, qq, (frame_pos, frame_angle, jac), d_minus, grav)
        qq[k] = q[k]
        # dD/dq_k contributes (dD/dq_k qd_k) qd to Ddot qd and -1/2 qd^T dD/dq_k qd to row k
        quad = 0.0
        for i in range(dof):
            row = 0.0
            for j in range(dof):
                dd = (d_plus[i, j] - d_minus[i, j]) / (2.0 * step)
                row += dd * qd[j]
                quad += qd[i] * dd * qd[j]
            out[i] += row * qd[k]
        out[k] -= 0.5 * quad
