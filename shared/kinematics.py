"""Planar serial-chain kinematics and dynamics terms shared by the sim and the haptic kernels.

A tool is a chain of joints (DESIGN §2). A free rigid body is the chain
(prismatic x, prismatic y, revolute) with zero lengths, so one set of kernels serves both.
Link i's frame sits at joint i with absolute angle phi_i; points on a link are given in that
frame. All functions are numba kernels over preallocated arrays (no allocation inside).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

REVOLUTE = 0
PRISMATIC_X = 1  # slides along the world x axis (used before any revolute joint)
PRISMATIC_Y = 2

MAX_DOF = 12
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
) -> np.ndarray:
    """A CHAIN_DTYPE[1] record of a chain of len(joint_types) joints."""
    d = len(joint_types)
    if d > MAX_DOF:
        raise ValueError(f"tool has {d} DOF; at most {MAX_DOF} supported")
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
    return rec


@njit(cache=True)
def link_frames(joint_types, lengths, base, base_angle, q, dof, frame_pos, frame_angle):
    """Origin (joint position) and absolute angle of every link frame at configuration q."""
    px = base[0]
    py = base[1]
    phi = base_angle
    for i in range(dof):
        jt = joint_types[i]
        if jt == REVOLUTE:
            phi += q[i]
        elif jt == PRISMATIC_X:
            px += q[i]
        else:
            py += q[i]
        frame_pos[i, 0] = px
        frame_pos[i, 1] = py
        frame_angle[i] = phi
        px += lengths[i] * math.cos(phi)
        py += lengths[i] * math.sin(phi)


@njit(cache=True)
def point_on_link(frame_pos, frame_angle, link, local_point, out):
    """World position of `local_point` given in the frame of `link`."""
    c = math.cos(frame_angle[link])
    s = math.sin(frame_angle[link])
    out[0] = frame_pos[link, 0] + c * local_point[0] - s * local_point[1]
    out[1] = frame_pos[link, 1] + s * local_point[0] + c * local_point[1]


@njit(cache=True)
def point_jacobian(joint_types, frame_pos, dof, link, px, py, jac):
    """3 x dof Jacobian of (P_x, P_y, phi_link) for world point P on `link` (DESIGN §2)."""
    for j in range(dof):
        if j > link:
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
def point_velocity(joint_types, frame_pos, count, px, py, qd):
    """World velocity (vx, vy) that joints 0 .. count - 1 give point P at rates qd."""
    vx = 0.0
    vy = 0.0
    for j in range(count):
        jt = joint_types[j]
        if jt == REVOLUTE:
            vx -= qd[j] * (py - frame_pos[j, 1])
            vy += qd[j] * (px - frame_pos[j, 0])
        elif jt == PRISMATIC_X:
            vx += qd[j]
        else:
            vy += qd[j]
    return vx, vy


@njit(cache=True)
def point_bias_acceleration(joint_types, frame_pos, dof, link, px, py, qd, out):
    """J_dot qd of world point P on `link`: its acceleration when qdd = 0 (DESIGN §4.3).

    A revolute joint j moves P at qd_j e_z x (P - o_j), so its column changes at
    qd_j e_z x (v_P - v_oj), with v_oj the velocity of joint j's own origin (which the
    joints before it, and a prismatic joint j itself, move). Prismatic columns are constant
    and the angular row is a sum of revolute rates: both contribute nothing.
    """
    vpx, vpy = point_velocity(joint_types, frame_pos, min(link + 1, dof), px, py, qd)
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for j in range(min(link + 1, dof)):
        if joint_types[j] != REVOLUTE:
            continue
        vox, voy = point_velocity(joint_types, frame_pos, j, frame_pos[j, 0], frame_pos[j, 1], qd)
        out[0] -= qd[j] * (vpy - voy)
        out[1] += qd[j] * (vpx - vox)


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
    joint_types = c.joint_types
    masses = c.masses
    inertias = c.inertias
    com_offsets = c.com_offsets
    frame_pos, frame_angle, jac = work
    link_frames(joint_types, c.lengths, c.base, c.base_angle, q, dof, frame_pos, frame_angle)
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
        point_jacobian(joint_types, frame_pos, dof, i, com_x, com_y, jac)
        for a in range(dof):
            gravity_out[a] -= masses[i] * (jac[0, a] * gravity[0] + jac[1, a] * gravity[1])
            for b in range(dof):
                mass_out[a, b] += masses[i] * (jac[0, a] * jac[0, b] + jac[1, a] * jac[1, b])
                mass_out[a, b] += inertias[i] * jac[2, a] * jac[2, b]


def fastest_spin(joint_types: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """The fastest link's angular speed |omega| (rad/s) of a chain moving at qd: a link turns
    with every revolute joint before it. qd's last axis is the joints (several states at
    once: one figure per state); joint_types those joints' types."""
    omega = np.cumsum(np.where(joint_types == REVOLUTE, qd, 0.0), axis=-1)
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
