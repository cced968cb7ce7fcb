"""A tree linkage driven by one animation variable through gears (seed 003 §4; DESIGN-WAVE2
§5 "general trees with avars": the windmill, the carousel).

The links of a planar tree of revolute joints (shared/kinematics.py: joint i on the tip of
link parents[i], -1 the base) turn with one avar q: theta_i = offset_i + gear_i q, linear
gearing, so theta' = g q' and J = g in joint space (seed 003's restriction kept: one avar per
joint). In the world coordinates of each link (its centre of mass c_i and its angle phi_i),
J_i = (J_c,i g, sum of the ancestors' g) and Jd_i q'^2 = (the point's bias acceleration at
joint rates g) q'^2, and eq 5.1 (shared/avar.py `mass_weighted_rate`) gives q''. M_q is then
g^T D(theta) g, with D the tree's joint-space mass matrix: tests/test_avar.py checks it, and
the motion, against the tree RNEA of shared/reference.py.

Every kernel works on TREE_DTYPE, whose scratch holds the frames and the per-link rows.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.shared.avar import mass_weighted_rate, rk4_flagged
from haptic_local_model.shared.kinematics import (
    CHAIN_DTYPE,
    MAX_DOF,
    REVOLUTE,
    chain_record,
    link_frames,
    point_bias_acceleration,
    point_jacobian,
    point_on_link,
)

N_ROWS = 3 * MAX_DOF  # (x, y, angle) of each link
FLOOR_FRACTION = 1e-6  # M_q's regularisation, of its median over a turn of the avar
SAMPLES = 721

TREE_DTYPE = np.dtype(
    [
        ("chain", CHAIN_DTYPE),  # the links (revolute joints), base, masses, inertias, COMs
        ("gear", np.float64, (MAX_DOF,)),  # theta_i = offset_i + gear_i q
        ("offset", np.float64, (MAX_DOF,)),
        ("gravity", np.float64, (2,)),
        ("floor", np.float64),
        ("terms_q", np.float64),  # the q the rows below are of (NaN: none yet)
        ("terms_mass", np.float64),  # and their M_q
        ("theta", np.float64, (MAX_DOF,)),  # scratch from here on
        ("frame_pos", np.float64, (MAX_DOF, 2)),
        ("frame_angle", np.float64, (MAX_DOF,)),
        ("jac", np.float64, (3, MAX_DOF)),
        ("point", np.float64, (2,)),
        ("bias3", np.float64, (3,)),
        ("rows", np.float64, (N_ROWS,)),  # J
        ("bias", np.float64, (N_ROWS,)),  # Jd
        ("bias_rate", np.float64, (N_ROWS,)),  # Jd q'^2
        ("mass", np.float64, (N_ROWS,)),
        ("force", np.float64, (N_ROWS,)),
    ]
)


def tree_record(
    base: tuple[float, float],
    lengths: tuple[float, ...],
    masses: tuple[float, ...],
    inertias: tuple[float, ...],
    com_offsets: tuple[tuple[float, float], ...],
    parents: tuple[int, ...],
    gears: tuple[float, ...],
    offsets: tuple[float, ...],
) -> np.ndarray:
    """TREE_DTYPE[1] (gravity 0; `with_gravity` sets it), its regularisation floor from a
    sweep of M_q over a turn of the avar."""
    n = len(lengths)
    rec = np.zeros(1, TREE_DTYPE)
    r = rec[0]
    r["chain"] = chain_record(
        np.full(n, REVOLUTE), np.array(lengths), np.array(base), 0.0, np.array(masses),
        np.array(inertias), np.array(com_offsets, dtype=float).reshape(n, 2), np.array(parents),
    )[0]  # fmt: skip
    r["gear"][:n] = gears
    r["offset"][:n] = offsets
    r["terms_q"] = np.nan
    sweep = np.array([tree_mass(r, q) for q in np.linspace(0.0, 2.0 * math.pi, SAMPLES)])
    r["floor"] = FLOOR_FRACTION * float(np.median(sweep))
    return rec


def conditioning(rec: np.ndarray) -> float:
    """min M_q / max M_q over a turn of the avar (0: it moves no mass somewhere)."""
    sweep = np.array([tree_mass(rec[0], q) for q in np.linspace(0.0, 2.0 * math.pi, SAMPLES)])
    return float(sweep.min() / sweep.max()) if sweep.max() > 0.0 else 0.0


@njit(cache=True)
def tree_terms(t, q):
    """The links' frames at q, and J, Jd, diag M and M g over each link's (x, y, angle) of
    its centre of mass into t's rows; returns M_q (unregularised). Kept for the next call at
    the same q (a tick asks for every link's pose at two q's, and Q's rows at one)."""
    if q == t.terms_q:
        return t.terms_mass
    c = t.chain
    n = c.dof
    for i in range(n):
        t.theta[i] = t.offset[i] + t.gear[i] * q
    link_frames(c, t.theta, n, t.frame_pos, t.frame_angle)
    m_q = 0.0
    for i in range(n):
        point_on_link(t.frame_pos, t.frame_angle, i, c.com_offsets[i], t.point)
        point_jacobian(c, t.frame_pos, n, i, t.point[0], t.point[1], t.jac)
        point_bias_acceleration(c, t.frame_pos, n, i, t.point[0], t.point[1], t.gear, t.bias3)
        vx = 0.0
        vy = 0.0
        w = 0.0
        for j in range(n):
            vx += t.jac[0, j] * t.gear[j]
            vy += t.jac[1, j] * t.gear[j]
            w += t.jac[2, j] * t.gear[j]
        m = c.masses[i]
        inertia = c.inertias[i]
        t.rows[3 * i] = vx
        t.rows[3 * i + 1] = vy
        t.rows[3 * i + 2] = w
        t.bias[3 * i] = t.bias3[0]
        t.bias[3 * i + 1] = t.bias3[1]
        t.bias[3 * i + 2] = 0.0  # the angle is linear in q: no bias
        t.mass[3 * i] = m
        t.mass[3 * i + 1] = m
        t.mass[3 * i + 2] = inertia
        t.force[3 * i] = m * t.gravity[0]
        t.force[3 * i + 1] = m * t.gravity[1]
        t.force[3 * i + 2] = 0.0
        m_q += m * (vx * vx + vy * vy) + inertia * w * w
    t.terms_q = q
    t.terms_mass = m_q
    return m_q


@njit(cache=True)
def tree_mass(t, q):
    """M_q = g^T D(theta) g at q (as regularised in the step)."""
    m_q = tree_terms(t, q)
    return m_q + t.floor if m_q < t.floor else m_q


@njit(cache=True)
def tree_rate(t, q, qd, q_ext):
    """q'' (eq 5.1) under gravity and the generalised force q_ext: (q'', singular)."""
    tree_terms(t, q)
    n = 3 * t.chain.dof
    for i in range(n):
        t.bias_rate[i] = t.bias[i] * qd * qd
    qdd, m_q, singular = mass_weighted_rate(t.rows, t.bias_rate, t.mass, t.force, n, t.floor)
    return qdd + q_ext / m_q, singular


_tree_rk4 = rk4_flagged(tree_rate)


@njit(cache=True)
def tree_step(t, st, q_ext, dt):
    """One RK4 step of dt with q_ext held; the avar kept on [0, 2 pi) (its gears are whole
    numbers: a turn of q brings every link back); a flagged step counts once."""
    st.s, st.sd, flagged = _tree_rk4(t, st.s, st.sd, q_ext, dt)
    if flagged:
        st.singular += 1
    st.s = st.s % (2.0 * math.pi)


@njit(cache=True)
def tree_body_pose(t, q, k):
    """Link k's frame at q: its joint and its absolute angle."""
    tree_terms(t, q)
    return t.frame_pos[k, 0], t.frame_pos[k, 1], t.frame_angle[k]


@njit(cache=True)
def tree_point_rate(t, q, k, px, py):
    """The velocity of the world point (px, py) on link k per unit q'."""
    tree_terms(t, q)
    c = t.chain
    point_jacobian(c, t.frame_pos, c.dof, k, px, py, t.jac)  # the rows keep theirs
    vx = 0.0
    vy = 0.0
    for j in range(c.dof):
        vx += t.jac[0, j] * t.gear[j]
        vy += t.jac[1, j] * t.gear[j]
    return vx, vy


@njit(cache=True)
def tree_energy(t, q, qd):
    """1/2 M_q q'^2 - sum m g . c (J)."""
    m_q = tree_terms(t, q)
    c = t.chain
    e = 0.5 * m_q * qd * qd
    for i in range(c.dof):
        point_on_link(t.frame_pos, t.frame_angle, i, c.com_offsets[i], t.point)
        e -= c.masses[i] * (t.gravity[0] * t.point[0] + t.gravity[1] * t.point[1])
    return e
