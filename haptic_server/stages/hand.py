"""The mass-spring hand at 1 kHz (DESIGN-WAVE2 §7; seed 004 §4.2-4.4, Borst & Indugula).

The proxy hand is a tree chain (shared/kinematics.py): the palm (prismatic x, prismatic y,
revolute theta; the palm's frame at its centre, its link reaching the middle of its front
edge) and fingers of two revolute phalanges each (parent(phalanx 1) = palm, parent(phalanx
2) = phalanx 1), q of d = 3 + 2F. D(q), G(q) and C(q, qd) qd are computed every tick from the
hand's own table, so no frozen-D error. The tracked hand (the palm's pose from the port's
device, the finger angles from a glove) pulls the proxy by springs with the corrected signs:

    F = k_t (p_t - p_s) + b_t (v_t - v_s),   tau_theta = k_theta wrap(theta_t - theta_s) + ...,
    tau_j = k_j (alpha_t,j - alpha_s,j) + d_j (omega_t,j - omega_s,j)

(seed 004's eqs 4.2-4.3 have the spring terms reversed: they push the proxy away). With
`absolute` damping the damper acts on the proxy's own rates (-b v_s, seed 002's): a ramp is
then followed b v / k behind. Contacts of the palm box and the phalanx capsules with static
walls and posts are the co-simulation's (penalty, stick-spring friction), at the point on the
link (its Jacobian from the tree). Drives and contacts enter one linearly implicit
theta-step, with the tracked motion over the step (velocity v_t, acceleration a_t):

    (D + th dt B + th^2 dt^2 K) dqd = dt (tau - G - C qd - th dt K qd)
                                       + th dt^2 (K (v_t + dt a_t / 2) + B_rel a_t),
    q += dt (qd + th dqd),

so a 5 g phalanx on a k_j far above the explicit limit 4 I / dt^2 is stable. th = 0.6 (the
model's `theta`): th = 1 (Euler, the co-simulation's step) lags a tracked motion by O(dt),
and V5.1's separation, 1/64 of the motion it tracks, came out 5 % small at 1 kHz; th = 1/2
(the trapezoid, no numerical damping) blew up with the explicit C(q, qd) qd of fingers
driven at 100 times the explicit limit, and, with the sub-steps below, still lets their
energy rise by 0.28 J in one tick (benchmarks/hand.py, V5.3, reports th = 0.5 and 0.55
beside 0.6). At 0.6 V5.1 is 0.93 % small and no energy rises. The contacts' K and B are
taken at the step's end instead (their gains over th: dt K_c qd on the right, dt B_c +
th dt^2 K_c in the matrix): at th of the step a stiff mode's error turns over by
-(1 - th) / th per step, and a 4 g phalanx resting on a 15 kN/m post flipped out of contact
and back every tick (V5.2's fingertip press, benchmarks/hand.py).

Outputs: the palm's command (the reaction of the palm spring over the step, what the port's
device renders, clipped at its limits, zero if not finite) and the glove's joint torques,
-tau_j, gated for a unilateral (tendon) glove: applied only when they resist flexion
(the ungated torques are kept beside them).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.physics.contact_law import add_rows, penalty_friction
from haptic_local_model.haptic_server.physics.implicit import (
    clear_terms,
    implicit_advance,
    implicit_solve,
    implicit_system,
    subtract_stiffness_velocity,
)
from haptic_local_model.shared.kinematics import (
    MAX_DOF,
    PRISMATIC_X,
    PRISMATIC_Y,
    REVOLUTE,
    chain_record,
    mass_matrix_and_gravity,
    point_jacobian,
    point_velocity,
    velocity_product_torque_into,
)
from haptic_local_model.shared.port_config import HandSpec
from haptic_local_model.shared.shapes import MAX_VERTICES, vertex_signed_distance

F8 = np.float64
I8 = np.int64
MAX_WALLS = 4
PALM = 2  # the palm's link (after its prismatic x and y)
GLOVES = {"none": 0, "bilateral": 1, "unilateral": 2}
CORIOLIS_STEP = 1.0e-6
MAX_TURN = 0.05  # rad: the most a joint may turn in one sub-step
MAX_SUBSTEPS = 64

HAND_DTYPE = np.dtype(
    [
        ("dof", I8),
        ("palm_vertices", F8, (4, 2)),  # the palm box, palm frame
        ("radius", F8, (MAX_DOF,)),  # each phalanx's capsule radius
        ("spring", F8, (MAX_DOF,)),  # k per coordinate: palm k_t, k_t, k_theta; joints k_j
        ("damper", F8, (MAX_DOF,)),
        ("relative", I8),  # 1: b (v_t - v_s); 0: -b v_s
        ("glove", I8),  # GLOVES
        ("flexion", F8, (MAX_DOF,)),  # +-1: the sign of each joint's flexion
        ("n_walls", I8),
        ("wall_vertices", F8, (MAX_WALLS, MAX_VERTICES, 2)),
        ("wall_n_vert", I8, (MAX_WALLS,)),
        ("wall_rounding", F8, (MAX_WALLS,)),
        ("wall_pose", F8, (MAX_WALLS, 3)),
        ("stiffness", F8),
        ("damping", F8),
        ("friction", F8),
        ("tangential_stiffness", F8),
        ("gravity", F8, (2,)),
        ("max_wrench", F8, (3,)),
        ("theta", F8),  # the step's implicitness: 1/2 trapezoidal ... 1 Euler
        # 1: the palm's rates are a device's estimate (noisy): not differenced into an
        # acceleration (by 1 / dt it would carry the estimate's noise into the command)
        ("measured_palm", I8),
        ("glove_limit", F8),  # N m: the glove's torque is clipped here
    ]
)

HAND_DATA_DTYPE = np.dtype(
    [
        ("dt", F8),
        ("q", F8, (MAX_DOF,)),
        ("qd", F8, (MAX_DOF,)),
        ("target", F8, (MAX_DOF,)),  # input: tracked palm pose, glove angles
        ("target_rate", F8, (MAX_DOF,)),
        ("prev_target_rate", F8, (MAX_DOF,)),
        ("target_next", F8, (MAX_DOF, 2)),  # predicted over the step: position, rate
        ("drive_now", F8, (MAX_DOF,)),  # each drive's force at the step's start
        ("h", F8),  # the sub-step: dt / n_sub
        ("n_sub", I8),  # this tick's sub-steps
        ("substepped", I8),  # ticks that needed more than one
        ("target_acc", F8, (MAX_DOF,)),
        ("target_live", F8, (MAX_DOF,)),  # the tracked hand at the sub-step's start
        ("rate_live", F8, (MAX_DOF,)),
        ("cut", I8, (MAX_DOF,)),  # this tick's tracked value was not finite
        ("q_tick", F8, (MAX_DOF,)),  # the state at the tick's start (a retry restores it)
        ("qd_tick", F8, (MAX_DOF,)),
        ("stick_tick", F8, (MAX_DOF, MAX_WALLS, 2, MAX_VERTICES)),
        ("touching_tick", I8, (MAX_DOF, MAX_WALLS, 2, MAX_VERTICES)),
        ("command_sum", F8, (3,)),
        ("glove_sum", F8, (MAX_DOF,)),
        ("turn", F8),  # the largest joint turn of one sub-step, rad (inf: a step failed)
        ("singular_tick", I8),
        ("primed", I8, (MAX_DOF,)),
        ("stick", F8, (MAX_DOF, MAX_WALLS, 2, MAX_VERTICES)),
        ("touching", I8, (MAX_DOF, MAX_WALLS, 2, MAX_VERTICES)),
        ("command", F8, (3,)),  # output: the palm's device, world frame
        ("glove_torque", F8, (MAX_DOF,)),  # output: on the user's joints (gated)
        ("glove_ungated", F8, (MAX_DOF,)),
        ("contact_force", F8, (2,)),  # the walls' total force on the hand
        ("n_contacts", I8),
        ("penetration", F8),
        ("invalid", I8),
        ("singular", I8),
        # scratch
        ("mass", F8, (MAX_DOF, MAX_DOF)),
        ("gravity_q", F8, (MAX_DOF,)),
        ("coriolis", F8, (MAX_DOF,)),
        ("f", F8, (MAX_DOF,)),
        ("k", F8, (MAX_DOF, MAX_DOF)),
        ("b", F8, (MAX_DOF, MAX_DOF)),
        ("extra", F8, (MAX_DOF,)),
        ("system", F8, (MAX_DOF, MAX_DOF)),
        ("chol", F8, (MAX_DOF, MAX_DOF)),
        ("rhs", F8, (MAX_DOF,)),
        ("dqd", F8, (MAX_DOF,)),
        ("q_before", F8, (MAX_DOF,)),
        ("frame_pos", F8, (MAX_DOF, 2)),
        ("frame_angle", F8, (MAX_DOF,)),
        ("jac", F8, (3, MAX_DOF)),
        ("grav", F8, (MAX_DOF,)),
        ("d_plus", F8, (MAX_DOF, MAX_DOF)),
        ("d_minus", F8, (MAX_DOF, MAX_DOF)),
        ("qq", F8, (MAX_DOF,)),
        ("pose_w", F8, (3,)),
        ("pose_l", F8, (3,)),  # a link's pose (its frame), for its core
        ("core", F8, (MAX_VERTICES, 2)),
        ("cols", I8, (MAX_DOF,)),  # 0 .. dof - 1: a contact's columns (all of the hand's)
        ("jn", F8, (MAX_DOF,)),
        ("jt", F8, (MAX_DOF,)),
        ("hit", F8, (5,)),  # point x, y, depth, normal x, y (pushing the hand out)
    ]
)


def hand_chain(spec: HandSpec) -> np.ndarray:
    """The hand's tree as a CHAIN_DTYPE[1]: palm x, y, theta, then each finger's phalanges."""
    types = [PRISMATIC_X, PRISMATIC_Y, REVOLUTE]
    lengths = [0.0, 0.0, spec.palm_size[0] / 2]
    masses = [0.0, 0.0, spec.palm_mass]
    inertias = [0.0, 0.0, spec.palm_inertia]
    com = [(0.0, 0.0)] * 3
    parents = [-1, 0, 1]
    for finger in spec.fingers:
        for j in range(2):
            types.append(REVOLUTE)
            lengths.append(finger.lengths[j])
            masses.append(finger.masses[j])
            inertias.append(finger.inertias[j])
            com.append((finger.lengths[j] / 2, 0.0))
            parents.append(PALM if j == 0 else len(parents) - 1)
    return chain_record(
        np.array(types, I8),
        np.array(lengths),
        np.zeros(2),
        0.0,
        np.array(masses),
        np.array(inertias),
        np.array(com),
        np.array(parents, I8),
    )


def hand_records(
    spec: HandSpec,
    walls: list[tuple[np.ndarray, float, tuple[float, float, float]]],
    contact: tuple[float, float, float, float],
    palm_pose: tuple[float, float, float],
    max_wrench: tuple[float, float, float],
    dt: float,
    theta: float = 0.6,
    gravity: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(chain, model, data) of a hand at `palm_pose` with its fingers at their rest angles,
    the tracked hand there too. walls: (core vertices, rounding, pose) each; contact:
    (stiffness, damping, friction, tangential stiffness)."""
    chain = hand_chain(spec)
    model = np.zeros(1, HAND_DTYPE)
    data = np.zeros(1, HAND_DATA_DTYPE)
    m = model[0]
    d = data[0]
    n = spec.dof
    m["dof"] = n
    w, h = spec.palm_size
    m["palm_vertices"] = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    m["spring"][:3] = spec.palm_spring
    m["damper"][:3] = spec.palm_damping
    m["relative"] = 1 if spec.damping == "relative" else 0
    m["glove"] = GLOVES[spec.glove]
    rest = [a for f in spec.fingers for a in f.rest]
    for i, finger in enumerate(spec.fingers):
        for j in range(2):
            a = 3 + 2 * i + j
            m["radius"][a] = finger.radius
            m["spring"][a] = spec.joint_spring
            m["damper"][a] = spec.joint_damping
            m["flexion"][a] = finger.flexion
    if len(walls) > MAX_WALLS:
        raise ValueError(f"walls: at most {MAX_WALLS}")
    m["n_walls"] = len(walls)
    for k, (vertices, rounding, pose) in enumerate(walls):
        m["wall_vertices"][k, : len(vertices)] = vertices
        m["wall_n_vert"][k] = len(vertices)
        m["wall_rounding"][k] = rounding
        m["wall_pose"][k] = pose
    m["stiffness"], m["damping"], m["friction"], m["tangential_stiffness"] = contact
    m["max_wrench"] = max_wrench
    m["theta"] = theta
    m["glove_limit"] = spec.glove_max_torque
    m["gravity"] = gravity
    d["dt"] = dt
    d["cols"] = np.arange(MAX_DOF)
    d["q"][:n] = (*palm_pose, *rest)
    d["target"][:n] = d["q"][:n]
    return chain, model, data


@njit(cache=True, inline="always")
def hit_force(law, hit, vx, vy, touching, stick, key, h):
    """The force at the contact in `hit` (point, depth, normal) whose point moves at (vx,
    vy) against what it touches: penalty and stick-spring friction, law a record with the
    contacts' stiffness, damping, friction and tangential_stiffness. The stick spring at
    `key` starts over on a new contact. Returns (fx, fy, f_n, whether it sticks)."""
    depth = hit[2]
    nx = hit[3]
    ny = hit[4]
    tx = -ny
    ty = nx
    vn = nx * vx + ny * vy
    vt = tx * vx + ty * vy
    if touching[key] == 0:
        stick[key] = 0.0
    touching[key] = 1
    k_t = law.tangential_stiffness
    f_n, f_t, stick[key], sticking = penalty_friction(
        (law.stiffness, law.damping, law.friction, k_t), depth, vn, vt, stick[key], h
    )
    return f_n * nx + f_t * tx, f_n * ny + f_t * ty, f_n, sticking


@njit(cache=True, inline="always")
def hit_rows(jac, n, hit, fx, fy, f, jn, jt):
    """The force (fx, fy) at the contact in `hit` through the point's Jacobian (jac, n
    columns) into the generalised forces f, and the contact's normal and tangent rows."""
    nx = hit[3]
    ny = hit[4]
    tx = -ny
    ty = nx
    for a in range(n):
        f[a] += jac[0, a] * fx + jac[1, a] * fy
        jn[a] = nx * jac[0, a] + ny * jac[1, a]
        jt[a] = tx * jac[0, a] + ty * jac[1, a]


@njit(cache=True, inline="always")
def hit_stiffness(law, sticking, kmat, bmat, cols, jn, jt, count):
    """A pressing contact's rows (cols[:count]) into the implicit step's K and B: the
    tangent's spring and damper only while it sticks. At the step's end, not at theta of
    it (module docstring): the gains over theta."""
    kt = law.tangential_stiffness if sticking else 0.0
    bt = law.damping if sticking else 0.0
    s = 1.0 / law.theta
    add_rows(kmat, bmat, cols, jn, jt, count, (s * law.stiffness, s * kt, s * law.damping, s * bt))


@njit(cache=True)
def hand_contact(chain, m, d, link, wall, side, v):
    """The contact in d.hit on `link` (key: wall, side, vertex): penalty, stick-spring
    friction, its generalised force and its stiffness for the implicit step."""
    c = chain[0]
    n = m.dof
    px = d.hit[0]
    py = d.hit[1]
    depth = d.hit[2]
    vx, vy = point_velocity(c, d.frame_pos, link, px, py, d.qd)
    key = (link, wall, side, v)
    fx, fy, f_n, sticking = hit_force(m, d.hit, vx, vy, d.touching, d.stick, key, d.h)
    d.contact_force[0] += fx / d.n_sub  # the tick's mean over its sub-steps
    d.contact_force[1] += fy / d.n_sub
    d.n_contacts += 1
    if depth > d.penetration:
        d.penetration = depth
    point_jacobian(c, d.frame_pos, n, link, px, py, d.jac)
    hit_rows(d.jac, n, d.hit, fx, fy, d.f, d.jn, d.jt)
    if f_n > 0.0:
        hit_stiffness(m, sticking, d.k, d.b, d.cols, d.jn, d.jt, n)


@njit(cache=True)
def link_core(chain, m, d, link):
    """A shaped link's core into d.core (its frame): the palm's box or a phalanx's segment.
    Returns the vertex count and the rounding (a phalanx's capsule radius)."""
    if link == PALM:
        for v in range(4):
            d.core[v, 0] = m.palm_vertices[v, 0]
            d.core[v, 1] = m.palm_vertices[v, 1]
        return 4, 0.0
    d.core[0, 0] = 0.0
    d.core[0, 1] = 0.0
    d.core[1, 0] = chain[0].lengths[link]
    d.core[1, 1] = 0.0
    return 2, m.radius[link]


@njit(cache=True)
def link_vertex_hit(d, link, v, rounding, shape, n_shape, shape_rounding, pose):
    """Vertex v of the link's core (d.core, rounded by `rounding`) against a rounded shape
    at `pose`: whether it goes in; if so d.hit holds the point on the link, the depth and
    the normal pushing the link out."""
    ca = math.cos(d.frame_angle[link])
    sa = math.sin(d.frame_angle[link])
    wx = d.frame_pos[link, 0] + ca * d.core[v, 0] - sa * d.core[v, 1]
    wy = d.frame_pos[link, 1] + sa * d.core[v, 0] + ca * d.core[v, 1]
    phi, nx, ny = vertex_signed_distance(shape, n_shape, shape_rounding, pose, wx, wy, rounding)
    if phi >= 0.0:
        return False
    d.hit[0] = wx - rounding * nx
    d.hit[1] = wy - rounding * ny
    d.hit[2] = -phi
    d.hit[3] = nx
    d.hit[4] = ny
    return True


@njit(cache=True)
def shape_vertex_hit(d, link, n_core, rounding, shape, v, shape_rounding, pose):
    """Vertex v of a rounded shape at `pose` against the link's rounded core (d.core):
    whether it goes in; if so d.hit holds the point on the shape's surface, the depth and
    the normal pushing the link out."""
    cs = math.cos(pose[2])
    sn = math.sin(pose[2])
    wx = pose[0] + cs * shape[v, 0] - sn * shape[v, 1]
    wy = pose[1] + sn * shape[v, 0] + cs * shape[v, 1]
    d.pose_l[0] = d.frame_pos[link, 0]
    d.pose_l[1] = d.frame_pos[link, 1]
    d.pose_l[2] = d.frame_angle[link]
    phi, nx, ny = vertex_signed_distance(d.core, n_core, rounding, d.pose_l, wx, wy, shape_rounding)
    if phi >= 0.0:
        return False
    d.hit[0] = wx - shape_rounding * nx
    d.hit[1] = wy - shape_rounding * ny
    d.hit[2] = -phi
    d.hit[3] = -nx
    d.hit[4] = -ny
    return True


@njit(cache=True)
def link_wall_contacts(chain, m, d, link, wall, n_core, rounding):
    """Side 0: the link's core vertices in the wall; side 1: the wall's vertices in the
    link's rounded core."""
    for c in range(3):
        d.pose_w[c] = m.wall_pose[wall, c]
    shape = m.wall_vertices[wall]
    n_shape = m.wall_n_vert[wall]
    rw = m.wall_rounding[wall]
    for v in range(n_core):
        if link_vertex_hit(d, link, v, rounding, shape, n_shape, rw, d.pose_w):
            hand_contact(chain, m, d, link, wall, 0, v)
        else:
            d.touching[link, wall, 0, v] = 0
    for v in range(n_shape):
        if shape_vertex_hit(d, link, n_core, rounding, shape, v, rw, d.pose_w):
            hand_contact(chain, m, d, link, wall, 1, v)
        else:
            d.touching[link, wall, 1, v] = 0


@njit(cache=True)
def hand_contacts(chain, m, d):
    """Every shaped link (the palm, the phalanges) against every wall."""
    for link in range(PALM, m.dof):
        n_core, rounding = link_core(chain, m, d, link)
        for wall in range(m.n_walls):
            link_wall_contacts(chain, m, d, link, wall, n_core, rounding)


@njit(cache=True)
def tracked_inputs(m, d):
    """This tick's tracked hand: a value that is not finite cuts its drive for the tick
    (counted; the next finite one starts the prediction afresh); the tracked acceleration
    over the last tick."""
    dt = d.dt
    for a in range(m.dof):
        vt = d.target_rate[a]
        d.cut[a] = 0
        if not (math.isfinite(d.target[a]) and math.isfinite(vt)):
            d.invalid += 1
            d.cut[a] = 1
            d.prev_target_rate[a] = 0.0
            d.primed[a] = 0
            continue
        differenced = d.primed[a] == 1 and not (m.measured_palm == 1 and a < 3)
        d.target_acc[a] = (vt - d.prev_target_rate[a]) / dt if differenced else 0.0
        d.prev_target_rate[a] = vt
        d.primed[a] = 1


@njit(cache=True)
def drives(m, d):
    """The palm and joint springs toward the tracked hand at the sub-step's start, with its
    motion predicted over the sub-step (module docstring)."""
    h = d.h
    th = m.theta
    for a in range(m.dof):
        if d.cut[a] == 1:
            d.drive_now[a] = 0.0
            d.target_next[a, 0] = d.q[a]
            d.target_next[a, 1] = d.qd[a] if m.relative == 1 else 0.0
            continue
        k = m.spring[a]
        b = m.damper[a]
        vt = d.rate_live[a]
        acc = d.target_acc[a]
        err = d.target_live[a] - d.q[a]
        if a == PALM:
            err = math.atan2(math.sin(err), math.cos(err))
        rate = vt if m.relative == 1 else 0.0
        d.drive_now[a] = k * err + b * (rate - d.qd[a])
        d.f[a] += d.drive_now[a]
        d.k[a, a] += k
        d.b[a, a] += b
        # the step takes theta of the tracked motion's change in force over the step
        # the tracked hand moves h (v + h a / 2) over the sub-step (target_live's path)
        d.extra[a] += th * (
            k * h * (vt + 0.5 * h * acc) + (b * h * acc if m.relative == 1 else 0.0)
        )
        d.target_next[a, 0] = d.q[a] + err + h * (vt + 0.5 * h * acc)
        d.target_next[a, 1] = vt + h * acc


@njit(cache=True)
def hand_dynamics(chain, m, d):
    """D(q), G(q) and C(q, qd) qd of the hand at this tick's q."""
    scratch = (d.frame_pos, d.frame_angle, d.jac, d.grav, d.d_plus, d.d_minus, d.qq)
    velocity_product_torque_into(chain, d.q, d.qd, CORIOLIS_STEP, scratch, d.coriolis)
    # last: it leaves the link frames at q (the finite differences above moved them)
    work = (d.frame_pos, d.frame_angle, d.jac)
    mass_matrix_and_gravity(chain, m.gravity, d.q, work, d.mass, d.gravity_q)


@njit(cache=True)
def hand_step(m, d):
    """The linearly implicit step over d.h (module docstring); a step that is not finite
    holds the hand at rest where it was (counted)."""
    dt = d.h
    n = m.dof
    th = m.theta
    for a in range(n):
        d.f[a] = d.f[a] - d.gravity_q[a] - d.coriolis[a] + d.extra[a]
        d.q_before[a] = d.q[a]
    subtract_stiffness_velocity(d.f, d.k, d.qd, th * dt, n)
    implicit_system(d.system, d.mass, d.b, d.k, th * dt, n)
    ok = implicit_solve(d.system, d.chol, d.f, dt, d.rhs, d.dqd, n)
    if ok:
        ok = implicit_advance(d.q, d.qd, d.dqd, dt, th, n)
    if not ok:
        d.singular += 1
        for a in range(n):
            d.q[a] = d.q_before[a]
            d.qd[a] = 0.0
    return ok


@njit(cache=True)
def substep_outputs(m, d):
    """Add this sub-step's palm command (the reaction of the force the step took) and glove
    torques (likewise) to the tick's sums."""
    th = m.theta
    for a in range(m.dof):
        if d.cut[a] == 1:
            continue  # a cut drive renders nothing
        rate = d.target_next[a, 1] if m.relative == 1 else 0.0
        f = m.spring[a] * (d.target_next[a, 0] - d.q[a]) + m.damper[a] * (rate - d.qd[a])
        u = -((1.0 - th) * d.drive_now[a] + th * f)
        if a < 3:
            d.command_sum[a] += u
        else:
            d.glove_sum[a] += u


@njit(cache=True)
def hand_outputs(m, d):
    """The palm's command (the sub-steps' mean, clipped, zero if not finite) and the glove's
    torques on the user (likewise, gated for a unilateral glove)."""
    bad = False
    for a in range(3):
        u = d.command_sum[a] / d.n_sub
        if not math.isfinite(u):
            bad = True
        d.command[a] = min(m.max_wrench[a], max(-m.max_wrench[a], u))
    if bad:
        d.invalid += 1
        for a in range(3):
            d.command[a] = 0.0
    for a in range(3, m.dof):
        user = d.glove_sum[a] / d.n_sub
        if not math.isfinite(user):
            d.invalid += 1
            user = 0.0
        user = min(m.glove_limit, max(-m.glove_limit, user))
        d.glove_ungated[a] = user
        if m.glove == 0 or (m.glove == 2 and m.flexion[a] * user > 0.0):
            user = 0.0  # a tendon glove only holds a finger back from flexing
        d.glove_torque[a] = user


@njit(cache=True, inline="always")
def copy_state(n, src, dst):
    """The state a retried tick starts again from, src = (q, qd, stick, touching) into dst
    of the same: the first n of q and qd, every stick spring and touching flag. Inlined
    (with _live and _kept) where numba compiles its caller: called, the tuples' eight arrays
    were counted in and out (NRT) at each call, every tick (0.5 us a tick on hand_grasp,
    timed in compiled code)."""
    q, qd, stick, touching = src
    q_to, qd_to, stick_to, touching_to = dst
    for a in range(n):
        q_to[a] = q[a]
        qd_to[a] = qd[a]
    stick_to[:] = stick
    touching_to[:] = touching


@njit(cache=True, inline="always")
def _live(d):
    return d.q, d.qd, d.stick, d.touching


@njit(cache=True, inline="always")
def _kept(d):
    return d.q_tick, d.qd_tick, d.stick_tick, d.touching_tick


@njit(cache=True)
def save_tick(m, d):
    copy_state(m.dof, _live(d), _kept(d))
    d.singular_tick = d.singular


@njit(cache=True)
def restore_tick(m, d):
    copy_state(m.dof, _kept(d), _live(d))
    d.singular = d.singular_tick


@njit(cache=True)
def begin_substeps(m, d, n_sub):
    """The tick's sums and extremes start over for n_sub sub-steps of dt / n_sub."""
    d.h = d.dt / n_sub
    d.n_sub = n_sub
    d.turn = 0.0
    for a in range(3):
        d.command_sum[a] = 0.0
    for a in range(m.dof):
        d.glove_sum[a] = 0.0
    d.contact_force[0] = 0.0
    d.contact_force[1] = 0.0
    d.penetration = 0.0  # the deepest over the tick's sub-steps


@njit(cache=True)
def prepare_substep(chain, m, d, sub):
    """Sub-step `sub`'s forces on the hand: the tracked hand moved along its rate and
    acceleration to the sub-step's start, D, G, C qd, the walls' contacts, the drives."""
    n = m.dof
    tau = sub * d.h
    for a in range(n):
        d.target_live[a] = d.target[a] + tau * (d.target_rate[a] + 0.5 * tau * d.target_acc[a])
        d.rate_live[a] = d.target_rate[a] + tau * d.target_acc[a]
        d.q_before[a] = d.q[a]
    clear_terms(n, d.f, d.extra, d.k, d.b)
    d.n_contacts = 0
    hand_dynamics(chain, m, d)
    hand_contacts(chain, m, d)
    drives(m, d)


@njit(cache=True)
def finish_substep(m, d):
    """The sub-step's outputs into the tick's sums; its largest joint turn into d.turn."""
    substep_outputs(m, d)
    for a in range(PALM, m.dof):
        turn = abs(d.q[a] - d.q_before[a])
        if not turn <= d.turn:
            d.turn = turn


@njit(cache=True)
def substeps(chain, m, d, n_sub):
    """The tick as n_sub sub-steps of dt / n_sub; the largest joint turn of one sub-step
    into d.turn (inf if a step failed)."""
    begin_substeps(m, d, n_sub)
    for sub in range(n_sub):
        prepare_substep(chain, m, d, sub)
        ok = hand_step(m, d)
        finish_substep(m, d)
        if not ok:
            d.turn = math.inf  # a failed step asks for sub-steps too


@njit(cache=True)
def hand_tick(chain, model, data):
    """One tick of the hand: data.target / target_rate hold the tracked palm pose and the
    glove's angles (and their rates); data.command and data.glove_torque are left.

    A light phalanx struck by a stiff contact can turn by a radian in one 1 ms step, where
    the step's linearisation (of the contact normals, of D(q), of the explicit C(q, qd) qd)
    no longer holds and the finger whirls (V5.4 blew up so at 60 kN/m). A tick whose
    sub-step turns any joint by more than MAX_TURN is therefore run again from its start in
    4, then 16, then 64 sub-steps."""
    m = model[0]
    d = data[0]
    tracked_inputs(m, d)
    save_tick(m, d)
    n_sub = 1
    while True:
        substeps(chain, m, d, n_sub)
        if d.turn <= MAX_TURN or n_sub >= MAX_SUBSTEPS:
            break
        restore_tick(m, d)
        n_sub *= 4
    if n_sub > 1:
        d.substepped += 1
    hand_outputs(m, d)


def hand_energy(chain: np.ndarray, model: np.ndarray, data: np.ndarray) -> float:
    """The proxy hand's kinetic energy plus its drives' spring energy toward the targets
    (the palm's angle wrapped; no gravity: the V5 cases have none)."""
    m = model[0]
    d = data[0]
    n = int(m["dof"])
    mass = np.zeros((MAX_DOF, MAX_DOF))
    grav = np.zeros(MAX_DOF)
    work = (np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF), np.zeros((3, MAX_DOF)))
    mass_matrix_and_gravity(chain, np.zeros(2), d["q"], work, mass, grav)
    qd = d["qd"][:n]
    err = d["target"][:n] - d["q"][:n]
    err[PALM] = math.atan2(math.sin(err[PALM]), math.cos(err[PALM]))
    return float(0.5 * qd @ mass[:n, :n] @ qd + 0.5 * np.sum(m["spring"][:n] * err**2))


@njit(cache=True)
def run_tracked(chain, model, data, targets, rates, rows_q, rows_command, rows_contact):
    """Ticks k = 0 .. len(targets) - 1 with the tracked hand at targets[k] (its rates at
    rates[k]) at the step's start; after each, q, the palm's command and the walls' force
    on the hand into the rows."""
    d = data[0]
    n = model[0].dof
    for k in range(targets.shape[0]):
        for a in range(n):
            d.target[a] = targets[k, a]
            d.target_rate[a] = rates[k, a]
        hand_tick(chain, model, data)
        for a in range(n):
            rows_q[k, a] = d.q[a]
        for c in range(3):
            rows_command[k, c] = d.command[c]
        rows_contact[k, 0] = d.contact_force[0]
        rows_contact[k, 1] = d.contact_force[1]
        rows_contact[k, 2] = d.penetration


@njit(cache=True)
def glove_at(script, rows, t, n, out_angle, out_rate):
    """The glove's n angles at t from the script's first `rows` rows (t, a_1, ..., a_n):
    linear in between, held after the last (rate 0), the first before it."""
    if rows == 0:
        return
    if t < script[0, 0] or rows == 1:
        k = 0 if t < script[0, 0] else rows - 1
        for j in range(n):
            out_angle[j] = script[k, 1 + j]
            out_rate[j] = 0.0
        return
    for k in range(rows - 1):
        t0 = script[k, 0]
        t1 = script[k + 1, 0]
        if t0 <= t < t1:
            f = (t - t0) / (t1 - t0)
            for j in range(n):
                a0 = script[k, 1 + j]
                a1 = script[k + 1, 1 + j]
                out_angle[j] = a0 + f * (a1 - a0)
                out_rate[j] = (a1 - a0) / (t1 - t0)
            return
    for j in range(n):
        out_angle[j] = script[rows - 1, 1 + j]
        out_rate[j] = 0.0
