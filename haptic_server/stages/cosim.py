"""The 1 kHz co-simulation of several tools and a grasped object (DESIGN-WAVE2 §2 C3, §6).

The extended configuration q = (q_tool_0, q_tool_1, q_object, ...) holds free rigid bodies
(x, y, theta each), so D^ = blkdiag(m, m, I, ...) is exact and constant. Each tick:

1. Contacts from the shapes, at 1 kHz (seed 001 eq 8): every vertex of a body's core
   against every other body's or static wall's rounded core (`vertex_signed_distance`).
   A contact pushes along the penetrated shape's outward normal with k delta - b v_n >= 0
   and a stick spring k_t capped at mu f_n along the tangent, its deflection kept per
   (vertex owner, penetrated shape, vertex). Normals rotate with the bodies. Tool-object
   contacts have both sides in q: their rows are n^T (J_o - J_t). The sim's bodies
   (`sim_bodies`) are walls that move: their poses and twists are inputs each tick (from
   the sim, `carry_sim_bodies`). With `sim_contact = "shape"` they take part in the
   contacts: a contact's velocity takes a wall's point velocity, and a wall's mass is
   infinite (one-way: they move on their own, the sim's mirror does not touch them). With
   "wrench" they meet nothing here: the impulses they put on the sim's mirror of each body
   come in as a force a tick (`sim_wrench`, an input; `drain_impulse`).
1b. First touch (seed 001 eq 5-6, DESIGN-WAVE2 §6): a contact that starts penetrating this
   tick while approaching faster than collision_speed collides. All of a tick's colliding
   contacts are resolved together, R their rows, A = R D^-1 R^T: the impulses lambda solve
   the complementarity problem A lambda - b = w >= 0, lambda >= 0, lambda . w = 0 with
   b = -(1 + e) v_n (a contact that would separate takes none; projected Gauss-Seidel),
   and q-dot takes D^-1 R^T lambda at once. The depth a colliding contact reached within
   its tick is projected out the same way (A mu >= depth: q takes D^-1 R^T mu, which moves
   no momentum), so no spring is left loaded by the collision to push the bodies apart.
   Two pads that meet the box in one tick stop as one body (e = 0), whatever their masses
   and speeds. The contact forces (step 1) are then taken at the velocity the impulses
   leave: the tick's contacts are found first (`all_contacts`), the impulses applied, then
   each contact's penalty and friction (`contact_forces`); a colliding contact's from the
   next tick.
2. Each port's virtual coupling between its device (pose and twist in the world frame) and
   its tool: K_c (x_h - x_t) + B_c (xd_h - xd_t) on the tool, the opposite on the device
   (K_c here is the coupling's stiffness; the contacts' is k). A port whose reading is not
   finite couples nothing that tick and commands zero; the other port goes on.
3. One linearly implicit step over the whole of q in the contact and coupling springs
   (seed 000 eq 21 as `stages/proxy.py` takes it):
   (D + dt B + dt^2 K) dqd = dt (f - dt K qd + dt K_c xd_h + (B_c + dt K_c) dt a_h),
   where a_h is the device's acceleration over the last tick (its motion predicted over the
   step). Contact stiffness between the tools and the object enters the same matrix, so a
   light object squeezed by stiff pads is stable at any K_c m_O ratio (V4.4).
4. Each port's command: the reaction of the coupling force the tool took over the step,
   NaN replaced by zero (counted), clipped at the port's limits.
5. The scene's range (`range_m`): an object (a dynamic body that is not a tool) that left
   it, |x| or |y| beyond range_m (it fell out of the grip of a world with no floor), is put
   back at its start pose, at rest, its contacts forgotten (`resets`), once no other
   co-simulated body's bounding circle reaches it there; until then it is held at rest
   where it left, clamped to the range (`parked`, ticks). So every pose the world sends
   stays within what a station takes (shared/protocol/station.py's POSE_LIMIT_M).

All functions are numba kernels over COSIM_DTYPE (the model) and COSIM_DATA_DTYPE (state,
the per-port device inputs and commands, and scratch); nothing allocates.
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
from haptic_local_model.haptic_server.physics.impulses import lcp
from haptic_local_model.shared.kinematics import wrap_angle
from haptic_local_model.shared.port_config import (
    MAX_COSIM_BODIES,
    MAX_PORTS,
    MAX_SIM_BODIES,
    MAX_STATIC_BODIES,
    PortSceneConfig,
)
from haptic_local_model.shared.shapes import MAX_VERTICES, vertex_signed_distance

F8 = np.float64
I8 = np.int64
N_ELEMENTS = MAX_COSIM_BODIES + MAX_STATIC_BODIES  # bodies first, then the walls
MAX_COSIM_DOF = 3 * MAX_COSIM_BODIES
MAX_COLLISIONS = 16  # colliding contacts resolved in one tick; more: penalty alone
# every penetrating vertex of a tick: each ordered pair with a body, MAX_VERTICES each
MAX_HITS = (
    MAX_COSIM_BODIES * (N_ELEMENTS - 1) + MAX_STATIC_BODIES * MAX_COSIM_BODIES
) * MAX_VERTICES

COSIM_DTYPE = np.dtype(
    [
        ("n_bodies", I8),
        ("n_static", I8),  # walls: the static bodies, then the sim's bodies
        ("n_sim", I8),  # the last n_sim walls are the sim's bodies (their poses move)
        ("sim_shapes", I8),  # 1: the sim's bodies are contact shapes (sim_contact "shape")
        ("n_ports", I8),
        ("mass", F8, (MAX_COSIM_BODIES,)),
        ("inertia", F8, (MAX_COSIM_BODIES,)),
        ("mass_q", F8, (MAX_COSIM_DOF, MAX_COSIM_DOF)),  # D = blkdiag(m, m, I, ...)
        ("n_vert", I8, (N_ELEMENTS,)),
        ("vertices", F8, (N_ELEMENTS, MAX_VERTICES, 2)),  # core, body frame about the COM
        ("rounding", F8, (N_ELEMENTS,)),
        ("bound", F8, (N_ELEMENTS,)),  # max |vertex|
        ("gravity", F8, (2,)),
        ("stiffness", F8),
        ("damping", F8),
        ("friction", F8),
        ("tangential_stiffness", F8),
        ("impulses", I8),  # 1: colliding contacts resolved by simultaneous impulses
        ("restitution", F8),  # e
        ("collision_speed", F8),  # m/s: a new contact approaching faster collides
        ("port_tool", I8, (MAX_PORTS,)),
        ("coupling_stiffness", F8, (MAX_PORTS, 3)),
        ("coupling_damping", F8, (MAX_PORTS, 3)),
        ("max_wrench", F8, (MAX_PORTS, 3)),  # world frame: the device's limits
        ("range_m", F8),  # an object beyond it returns to its start (step 5)
        ("start_q", F8, (MAX_COSIM_DOF,)),  # the bodies' start poses
    ]
)

COSIM_DATA_DTYPE = np.dtype(
    [
        ("q", F8, (MAX_COSIM_DOF,)),
        ("qd", F8, (MAX_COSIM_DOF,)),
        ("stick", F8, (N_ELEMENTS, N_ELEMENTS, MAX_VERTICES)),  # tangential deflection, m
        ("touching", I8, (N_ELEMENTS, N_ELEMENTS, MAX_VERTICES)),
        ("wall_pose", F8, (MAX_STATIC_BODIES, 3)),  # a sim body's: an input each tick
        ("wall_twist", F8, (MAX_STATIC_BODIES, 3)),  # zero for a static wall
        ("sim_wrench", F8, (MAX_COSIM_BODIES, 3)),  # input: the sim's bodies' on each body
        ("device_pose", F8, (MAX_PORTS, 3)),  # inputs: world frame
        ("device_twist", F8, (MAX_PORTS, 3)),
        ("prev_device_twist", F8, (MAX_PORTS, 3)),
        ("device_next", F8, (MAX_PORTS, 6)),  # pose, twist predicted over the step
        ("port_cut", I8, (MAX_PORTS,)),  # this tick's reading was not finite: no coupling
        ("q_before", F8, (MAX_COSIM_DOF,)),
        ("qd_before", F8, (MAX_COSIM_DOF,)),
        ("primed", I8, (MAX_PORTS,)),  # prev_device_twist holds a reading
        ("command", F8, (MAX_PORTS, 3)),  # output: world frame, clipped
        ("body_force", F8, (MAX_COSIM_BODIES, 3)),  # contact wrench on each body (about COM)
        ("n_contacts", I8),
        ("penetration", F8),  # the deepest this tick, m
        ("invalid", I8),  # commands that were not finite (zero force sent instead)
        ("singular", I8),  # steps whose system did not factor (the bodies held)
        ("resets", I8),  # objects put back at their start after leaving the range
        ("parked", I8),  # ticks an object out of range waited for its start to be clear
        ("collisions", I8),  # colliding contacts since the start (each solved for; a
        # separating one takes a zero impulse)
        ("dt", F8),
        # scratch
        ("f", F8, (MAX_COSIM_DOF,)),
        ("k", F8, (MAX_COSIM_DOF, MAX_COSIM_DOF)),
        ("b", F8, (MAX_COSIM_DOF, MAX_COSIM_DOF)),
        ("extra", F8, (MAX_COSIM_DOF,)),
        ("system", F8, (MAX_COSIM_DOF, MAX_COSIM_DOF)),
        ("chol", F8, (MAX_COSIM_DOF, MAX_COSIM_DOF)),
        ("rhs", F8, (MAX_COSIM_DOF,)),
        ("dqd", F8, (MAX_COSIM_DOF,)),
        ("pose_o", F8, (3,)),
        ("pose_t", F8, (3,)),
        ("hit", F8, (5,)),  # the contact being met: point x, y, depth, normal x, y
        ("cols", I8, (6,)),
        ("jn", F8, (6,)),
        ("jt", F8, (6,)),
        ("n_hits", I8),
        ("hits", F8, (MAX_HITS, 5)),  # point x, y, depth, normal x, y
        ("hit_of", I8, (MAX_HITS, 4)),  # o, t, v, colliding
        ("n_colliding", I8),
        ("coll_rows", F8, (MAX_COLLISIONS, MAX_COSIM_DOF)),  # n^T (J_o - J_t) over q
        ("coll_target", F8, (MAX_COLLISIONS,)),  # -(1 + e) v_n
        ("coll_depth", F8, (MAX_COLLISIONS,)),
        ("coll_a", F8, (MAX_COLLISIONS, MAX_COLLISIONS)),  # R D^-1 R^T
        ("coll_lambda", F8, (MAX_COLLISIONS,)),  # the impulses, N s
        ("coll_mu", F8, (MAX_COLLISIONS,)),  # the depths' projection: A mu >= depth, mu >= 0
    ]
)


def body_core(body: object) -> tuple[np.ndarray, float]:
    """A body's core vertices (counter-clockwise, about its origin) and rounding."""
    shape = body.shape  # type: ignore[attr-defined]
    if shape == "box":
        w, h = body.size  # type: ignore[attr-defined]
        v = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
        return np.array(v, F8), 0.0
    if shape == "circle":
        return np.zeros((1, 2), F8), float(body.radius)  # type: ignore[attr-defined]
    return np.array([body.a, body.b], F8), float(body.radius)  # type: ignore[attr-defined]


def cosim_records(
    scene: PortSceneConfig, max_wrench: list[tuple[float, float, float]]
) -> tuple[np.ndarray, np.ndarray]:
    """The model and data records of a port scene: the ports' tools first (in port order),
    then the other dynamic bodies, then the static ones and the sim's (at their start, at
    rest until the sim moves them); q at the bodies' initial poses and velocities.
    `max_wrench` is each port's device limit in the world frame."""
    model = np.zeros(1, COSIM_DTYPE)
    data = np.zeros(1, COSIM_DATA_DTYPE)
    m = model[0]
    d = data[0]
    order = cosim_order(scene)
    m["n_bodies"] = len(order)
    statics = scene.static_bodies
    m["n_static"] = len(statics)
    m["n_sim"] = len(scene.sim_bodies)
    m["sim_shapes"] = int(scene.sim_contact == "shape")
    m["n_ports"] = len(scene.ports)
    for i, name in enumerate(order):
        b = scene.body(name)
        m["mass"][i] = b.mass
        m["inertia"][i] = b.moment
        m["mass_q"][3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = np.diag([b.mass, b.mass, b.moment])
        _set_core(m, i, b)
        d["q"][3 * i : 3 * i + 3] = (b.position[0], b.position[1], b.angle)
        d["qd"][3 * i : 3 * i + 3] = (b.velocity[0], b.velocity[1], b.angular_velocity)
    m["start_q"] = d["q"]
    m["range_m"] = scene.range_m
    for j, b in enumerate(statics):
        _set_core(m, MAX_COSIM_BODIES + j, b)
        d["wall_pose"][j] = (b.position[0], b.position[1], b.angle)
    m["gravity"] = scene.gravity
    c = scene.contact
    m["stiffness"] = c.stiffness_n_per_m
    m["damping"] = c.damping_ns_per_m
    m["friction"] = c.friction
    m["tangential_stiffness"] = c.friction_stiffness_ratio * c.stiffness_n_per_m
    m["impulses"] = int(c.impulses)
    m["restitution"] = c.restitution
    m["collision_speed"] = c.collision_speed_m_per_s
    for p, port in enumerate(scene.ports):
        m["port_tool"][p] = order.index(port.tool)
        m["coupling_stiffness"][p] = port.coupling_stiffness
        m["coupling_damping"][p] = port.coupling_damping
        m["max_wrench"][p] = max_wrench[p]
    d["dt"] = scene.period_s
    return model, data


def cosim_order(scene: PortSceneConfig) -> list[str]:
    """The co-simulated bodies in q's order: the tools in port order, then the objects."""
    return scene.cosim_order()


def _set_core(m: np.void, e: int, body: object) -> None:
    v, rounding = body_core(body)
    m["n_vert"][e] = len(v)
    m["vertices"][e, : len(v)] = v
    m["rounding"][e] = rounding
    m["bound"][e] = float(np.max(np.hypot(v[:, 0], v[:, 1])))


@njit(cache=True)
def _pose(m, d, e, out):
    """Element e's pose: a body's from q, a wall's from wall_pose."""
    if e < MAX_COSIM_BODIES:
        for c in range(3):
            out[c] = d.q[3 * e + c]
    else:
        for c in range(3):
            out[c] = d.wall_pose[e - MAX_COSIM_BODIES, c]


@njit(cache=True)
def _present(m, e):
    if e < MAX_COSIM_BODIES:
        return e < m.n_bodies
    j = e - MAX_COSIM_BODIES
    return j < m.n_static - m.n_sim or (j < m.n_static and m.sim_shapes == 1)


@njit(cache=True)
def _point_velocity(d, e, px, py):
    """The velocity of the point (px, py) carried by element e (a static wall's is zero)."""
    if e >= MAX_COSIM_BODIES:
        j = e - MAX_COSIM_BODIES
        w = d.wall_twist[j, 2]
        return (
            d.wall_twist[j, 0] - w * (py - d.wall_pose[j, 1]),
            d.wall_twist[j, 1] + w * (px - d.wall_pose[j, 0]),
        )
    a = 3 * e
    w = d.qd[a + 2]
    return d.qd[a] - w * (py - d.q[a + 1]), d.qd[a + 1] + w * (px - d.q[a])


@njit(cache=True)
def _apply(d, e, px, py, fx, fy):
    """A force at (px, py) on element e: into f and the body's contact wrench."""
    if e >= MAX_COSIM_BODIES:
        return
    a = 3 * e
    torque = (px - d.q[a]) * fy - (py - d.q[a + 1]) * fx
    d.f[a] += fx
    d.f[a + 1] += fy
    d.f[a + 2] += torque
    d.body_force[e, 0] += fx
    d.body_force[e, 1] += fy
    d.body_force[e, 2] += torque


@njit(cache=True)
def _rows(d, o, t, px, py, nx, ny):
    """The contact's normal and tangent rows n^T (J_o - J_t), t^T (J_o - J_t) over the at
    most six columns of the two bodies (d.cols; -1 for a wall's)."""
    tx = -ny
    ty = nx
    for side in range(2):
        e = o if side == 0 else t
        sign = 1.0 if side == 0 else -1.0
        for c in range(3):
            d.cols[3 * side + c] = 3 * e + c if e < MAX_COSIM_BODIES else -1
        if e >= MAX_COSIM_BODIES:
            continue
        rx = px - d.q[3 * e]
        ry = py - d.q[3 * e + 1]
        d.jn[3 * side] = sign * nx
        d.jn[3 * side + 1] = sign * ny
        d.jn[3 * side + 2] = sign * (rx * ny - ry * nx)
        d.jt[3 * side] = sign * tx
        d.jt[3 * side + 1] = sign * ty
        d.jt[3 * side + 2] = sign * (rx * ty - ry * tx)


@njit(cache=True)
def _relative_velocity(d, o, t, px, py, nx, ny):
    """(v_n, v_t) of o's point (px, py) against t's, along the normal and its tangent."""
    vox, voy = _point_velocity(d, o, px, py)
    vtx, vty = _point_velocity(d, t, px, py)
    rvx = vox - vtx
    rvy = voy - vty
    return nx * rvx + ny * rvy, -ny * rvx + nx * rvy


@njit(cache=True)
def _hit(m, d, o, t, v):
    """A penetrating vertex v of element o in element t (its point, depth and normal in
    d.hit), kept for `contact_forces`; a new one approaching faster than collision_speed is
    queued for `collide` instead."""
    h = d.n_hits  # < MAX_HITS: every ordered pair's vertices at most
    for c in range(5):
        d.hits[h, c] = d.hit[c]
    d.hit_of[h, 0] = o
    d.hit_of[h, 1] = t
    d.hit_of[h, 2] = v
    d.hit_of[h, 3] = 0
    d.n_hits = h + 1
    d.n_contacts += 1
    if d.hit[2] > d.penetration:
        d.penetration = d.hit[2]
    if d.touching[o, t, v] == 1:
        return
    d.stick[o, t, v] = 0.0
    d.touching[o, t, v] = 1
    if m.impulses == 1 and d.n_colliding < MAX_COLLISIONS:
        vn, _vt = _relative_velocity(d, o, t, d.hit[0], d.hit[1], d.hit[3], d.hit[4])
        if vn < -m.collision_speed:  # colliding: its impulse this tick, its penalty the next
            _queue_collision(m, d, o, t, vn)
            d.hit_of[h, 3] = 1


@njit(cache=True)
def contact(m, d, h):
    """Hit h at the present velocity: penalty, stick-spring friction, the force on both,
    and their stiffness for the implicit step."""
    o = d.hit_of[h, 0]
    t = d.hit_of[h, 1]
    v = d.hit_of[h, 2]
    px = d.hits[h, 0]
    py = d.hits[h, 1]
    depth = d.hits[h, 2]
    nx = d.hits[h, 3]
    ny = d.hits[h, 4]
    tx = -ny
    ty = nx
    vn, vt = _relative_velocity(d, o, t, px, py, nx, ny)
    k_t = m.tangential_stiffness
    f_n, f_t, d.stick[o, t, v], sticking = penalty_friction(
        (m.stiffness, m.damping, m.friction, k_t), depth, vn, vt, d.stick[o, t, v], d.dt
    )
    fx = f_n * nx + f_t * tx
    fy = f_n * ny + f_t * ty
    _apply(d, o, px, py, fx, fy)
    _apply(d, t, px, py, -fx, -fy)
    if f_n > 0.0:
        _rows(d, o, t, px, py, nx, ny)
        # a sliding contact's friction is mu f_n whatever the tangential speed: neither its
        # stick spring nor its damping is in the implicit step (they would brake the slide)
        if sticking:
            add_rows(d.k, d.b, d.cols, d.jn, d.jt, 6, (m.stiffness, k_t, m.damping, m.damping))
        else:
            k_t = 0.0
            add_rows(d.k, d.b, d.cols, d.jn, d.jt, 6, (m.stiffness, 0.0, m.damping, 0.0))
        if m.n_sim > 0:
            _wall_motion(d, h, m.stiffness, k_t)


@njit(cache=True)
def _wall_motion(d, h, kn, kt):
    """A moving wall's side of a contact's springs in the implicit step: the step's
    -dt K q-dot takes the bodies' velocities only (q holds no wall), so a wall moving at
    v_w adds -dt (kn jn (n . v_w) + kt jt (t . v_w)) with the wall's side's sign (the
    springs it loads as it moves; as a device's motion in the coupling, `couple_ports`).
    Without it a box riding a belt is pulled back each tick and rides it in a limit cycle.
    h: the hit (its rows in d.jn, d.jt, d.cols)."""
    o = d.hit_of[h, 0]
    t = d.hit_of[h, 1]
    nx = d.hits[h, 3]
    ny = d.hits[h, 4]
    side = 0 if o >= MAX_COSIM_BODIES else 1
    e = o if side == 0 else t
    if e < MAX_COSIM_BODIES:
        return
    sign = 1.0 if side == 0 else -1.0
    vx, vy = _point_velocity(d, e, d.hits[h, 0], d.hits[h, 1])
    wn = sign * (nx * vx + ny * vy)
    wt = sign * (-ny * vx + nx * vy)
    for i in range(6):
        a = d.cols[i]
        if a >= 0:
            d.extra[a] -= d.dt * (kn * d.jn[i] * wn + kt * d.jt[i] * wt)


@njit(cache=True)
def contact_forces(m, d):
    """Every hit's force but a colliding one's (module docstring, step 1)."""
    for h in range(d.n_hits):
        if d.hit_of[h, 3] == 0:
            contact(m, d, h)


@njit(cache=True)
def _queue_collision(m, d, o, t, vn):
    """A contact that starts penetrating while approaching (its point and normal in d.hit):
    its row n^T (J_o - J_t) over q and its target normal velocity change, for `collide`."""
    c = d.n_colliding
    _rows(d, o, t, d.hit[0], d.hit[1], d.hit[3], d.hit[4])
    for a in range(3 * m.n_bodies):
        d.coll_rows[c, a] = 0.0
    for i in range(6):
        if d.cols[i] >= 0:
            d.coll_rows[c, d.cols[i]] += d.jn[i]
    d.coll_target[c] = -(1.0 + m.restitution) * vn
    d.coll_depth[c] = d.hit[2]
    d.n_colliding = c + 1


@njit(cache=True)
def collide(m, d):
    """The tick's colliding contacts resolved together (module docstring, step 1b): the
    impulses into q-dot, the depths they reached projected out of q."""
    n = 3 * m.n_bodies
    k = d.n_colliding
    if k == 0:
        return
    for r in range(k):  # R D^-1 R^T (D diagonal)
        for c in range(k):
            v = 0.0
            for a in range(n):
                i = a // 3
                inv = 1.0 / (m.inertia[i] if a % 3 == 2 else m.mass[i])
                v += d.coll_rows[r, a] * inv * d.coll_rows[c, a]
            d.coll_a[r, c] = v
    lcp(d.coll_a, d.coll_target, d.coll_lambda, k)
    lcp(d.coll_a, d.coll_depth, d.coll_mu, k)
    for a in range(n):
        i = a // 3
        inv = 1.0 / (m.inertia[i] if a % 3 == 2 else m.mass[i])
        p = 0.0
        s = 0.0
        for c in range(k):
            p += d.coll_rows[c, a] * d.coll_lambda[c]
            s += d.coll_rows[c, a] * d.coll_mu[c]
        d.qd[a] += p * inv
        d.q[a] += s * inv
    d.collisions += k


@njit(cache=True)
def _release(d, o, t):
    for v in range(MAX_VERTICES):
        d.touching[o, t, v] = 0
        d.stick[o, t, v] = 0.0


@njit(cache=True)
def contacts_of(m, d, o, t):
    """Every vertex of o's core against t's rounded core (a bounding-circle test first)."""
    _pose(m, d, o, d.pose_o)
    _pose(m, d, t, d.pose_t)
    reach = m.bound[o] + m.bound[t] + m.rounding[o] + m.rounding[t]
    if math.hypot(d.pose_o[0] - d.pose_t[0], d.pose_o[1] - d.pose_t[1]) > reach:
        _release(d, o, t)
        return
    cs = math.cos(d.pose_o[2])
    sn = math.sin(d.pose_o[2])
    ro = m.rounding[o]
    for v in range(m.n_vert[o]):
        bx = m.vertices[o, v, 0]
        by = m.vertices[o, v, 1]
        wx = d.pose_o[0] + cs * bx - sn * by
        wy = d.pose_o[1] + sn * bx + cs * by
        phi, nx, ny = vertex_signed_distance(
            m.vertices[t], m.n_vert[t], m.rounding[t], d.pose_t, wx, wy, ro
        )
        if phi >= 0.0:
            d.touching[o, t, v] = 0
            d.stick[o, t, v] = 0.0
            continue
        d.hit[0] = wx - ro * nx
        d.hit[1] = wy - ro * ny
        d.hit[2] = -phi
        d.hit[3] = nx
        d.hit[4] = ny
        _hit(m, d, o, t, v)


@njit(cache=True)
def all_contacts(m, d):
    """The tick's contacts found (`_hit`) for every ordered pair of present elements, not
    both walls."""
    for o in range(N_ELEMENTS):
        if not _present(m, o):
            continue
        for t in range(N_ELEMENTS):
            if t == o or not _present(m, t):
                continue
            if o >= MAX_COSIM_BODIES and t >= MAX_COSIM_BODIES:
                continue
            if t < o and m.n_vert[o] == 1 and m.n_vert[t] == 1:
                continue  # two discs meet once: their centres, either way round
            contacts_of(m, d, o, t)


@njit(cache=True)
def couple_ports(m, d):
    """Each port's coupling on its tool: the force, its stiffness and damping, and the
    device's predicted motion over the step (into d.extra)."""
    dt = d.dt
    for p in range(m.n_ports):
        a0 = 3 * m.port_tool[p]
        d.port_cut[p] = 0
        for c in range(3):
            if not (math.isfinite(d.device_pose[p, c]) and math.isfinite(d.device_twist[p, c])):
                d.port_cut[p] = 1
        if d.port_cut[p] == 1:
            # a reading that is not finite couples nothing this tick (the other port and the
            # bodies go on); the next finite reading starts the prediction afresh
            d.invalid += 1
            d.primed[p] = 0
            for c in range(3):
                d.prev_device_twist[p, c] = 0.0
                d.device_next[p, c] = d.q[a0 + c]
                d.device_next[p, c + 3] = d.qd[a0 + c]
            continue
        for c in range(3):
            a = a0 + c
            kc = m.coupling_stiffness[p, c]
            bc = m.coupling_damping[p, c]
            vh = d.device_twist[p, c]
            acc = (vh - d.prev_device_twist[p, c]) / dt if d.primed[p] == 1 else 0.0
            d.prev_device_twist[p, c] = vh
            pose = d.device_pose[p, c]
            if c == 2:  # the device's angle on the turn nearest the tool's: no 2 pi step
                pose = d.q[a] + wrap_angle(pose - d.q[a])
            d.f[a] += kc * (pose - d.q[a]) + bc * (vh - d.qd[a])
            d.k[a, a] += kc
            d.b[a, a] += bc
            d.extra[a] += dt * kc * vh + (bc + dt * kc) * dt * acc
            d.device_next[p, c + 3] = vh + dt * acc
            d.device_next[p, c] = pose + dt * (vh + dt * acc)
        d.primed[p] = 1


@njit(cache=True)
def _clear(m, d):
    clear_terms(3 * m.n_bodies, d.f, d.extra, d.k, d.b)
    for e in range(MAX_COSIM_BODIES):
        for c in range(3):
            d.body_force[e, c] = 0.0
    d.n_contacts = 0
    d.penetration = 0.0
    d.n_colliding = 0
    d.n_hits = 0


@njit(cache=True)
def step_bodies(m, d):
    """The linearly implicit step of q (module docstring, step 3). A system that does not
    factor, or a step that is not finite, holds the bodies where they were, at rest, and is
    counted (`singular`): a bad state never stays in q."""
    dt = d.dt
    n = 3 * m.n_bodies
    for i in range(m.n_bodies):
        d.f[3 * i] += m.mass[i] * m.gravity[0]
        d.f[3 * i + 1] += m.mass[i] * m.gravity[1]
        if m.n_sim > 0:
            for c in range(3):
                d.f[3 * i + c] += d.sim_wrench[i, c]
    for a in range(n):
        d.f[a] += d.extra[a]
        d.q_before[a] = d.q[a]
        d.qd_before[a] = d.qd[a]
    subtract_stiffness_velocity(d.f, d.k, d.qd, dt, n)
    implicit_system(d.system, m.mass_q, d.b, d.k, dt, n)
    ok = implicit_solve(d.system, d.chol, d.f, dt, d.rhs, d.dqd, n)
    if ok:
        ok = implicit_advance(d.q, d.qd, d.dqd, dt, 1.0, n)
    if not ok:
        d.singular += 1
        for a in range(n):
            d.q[a] = d.q_before[a]
            d.qd[a] = 0.0


@njit(cache=True)
def _start_clear(m, d, i):
    """No other co-simulated body's bounding circle reaches body i's at its start pose."""
    a = 3 * i
    reach_i = m.bound[i] + m.rounding[i]
    for j in range(m.n_bodies):
        if j == i:
            continue
        gap = math.hypot(d.q[3 * j] - m.start_q[a], d.q[3 * j + 1] - m.start_q[a + 1])
        if gap <= reach_i + m.bound[j] + m.rounding[j]:
            return False
    return True


@njit(cache=True)
def keep_in_range(m, d):
    """Step 5 of the module docstring: each object beyond the scene's range back at its
    start pose at rest when its start is clear, else held at rest clamped to the range."""
    r = m.range_m
    for i in range(m.n_ports, m.n_bodies):  # the tools come first
        a = 3 * i
        if abs(d.q[a]) <= r and abs(d.q[a + 1]) <= r:
            continue
        if _start_clear(m, d, i):
            for c in range(3):
                d.q[a + c] = m.start_q[a + c]
            for e in range(N_ELEMENTS):  # its contacts start afresh
                for v in range(MAX_VERTICES):
                    d.stick[i, e, v] = d.stick[e, i, v] = 0.0
                    d.touching[i, e, v] = d.touching[e, i, v] = 0
            d.resets += 1
        else:
            d.q[a] = min(r, max(-r, d.q[a]))
            d.q[a + 1] = min(r, max(-r, d.q[a + 1]))
            d.parked += 1
        for c in range(3):
            d.qd[a + c] = 0.0


@njit(cache=True)
def coupling_reaction(m, d, p, c):
    """Port p's coupling on axis c over the step, as its device takes it: the reaction of
    the force on the tool, K (q - x_dev) + B (qd - v_dev) at the new tool state and the
    device's predicted one (minus the force on the tool, bit for bit)."""
    a = 3 * m.port_tool[p] + c
    u = m.coupling_stiffness[p, c] * (d.q[a] - d.device_next[p, c])
    u += m.coupling_damping[p, c] * (d.qd[a] - d.device_next[p, c + 3])
    return u


@njit(cache=True)
def port_commands(m, d):
    """Each device's command: the reaction of the force its tool took over the step (the
    coupling at the new tool state and the device's predicted one: the pair the implicit
    step linearised), finite and within the port's limits. Against the device's present
    pose instead, a tool moving at v would leave K v dt out of the command (0.12 N in a
    60 mm/s lift at 2 kN/m)."""
    for p in range(m.n_ports):
        bad = d.port_cut[p] == 1
        for c in range(3):
            u = coupling_reaction(m, d, p, c)
            if not math.isfinite(u):
                bad = True
            lim = m.max_wrench[p, c]
            d.command[p, c] = min(lim, max(-lim, u))
        if bad:
            if d.port_cut[p] == 0:
                d.invalid += 1
            for c in range(3):
                d.command[p, c] = 0.0


@njit(cache=True)
def carry_sim_bodies(model, data, sample, age):
    """The sim's bodies at this tick: sample[j] = (pose, twist) of sim body j (the sim's
    newest), carried on by its twist for `age` seconds (the caller's bound)."""
    m = model[0]
    d = data[0]
    first = m.n_static - m.n_sim
    for j in range(m.n_sim):
        for c in range(3):
            pose = sample[j, c]  # as it is at age 0 (a replay's: bit for bit, -0.0 too)
            d.wall_pose[first + j, c] = pose + age * sample[j, 3 + c] if age > 0.0 else pose
            d.wall_twist[first + j, c] = sample[j, 3 + c]


@njit(cache=True)
def drain_impulse(model, data, pending, rate):
    """The sim's impulse on the co-simulated bodies into this tick's sim_wrench: each
    body's `rate` (N, N m), but no more than what is `pending` (N s, N m s; taken off it):
    every impulse the sim reports is applied once, over about one sim step."""
    m = model[0]
    d = data[0]
    for i in range(m.n_bodies):
        for c in range(3):
            f = rate[i, c]
            left = pending[i, c]
            if f * left <= 0.0 or abs(f) * d.dt > abs(left):
                f = left / d.dt
            d.sim_wrench[i, c] = f
            pending[i, c] = left - f * d.dt


@njit(cache=True)
def sim_bodies_of(m, d, out):
    """The sim's bodies as this tick met them (m, d: the records): out[j] = (pose, twist),
    a row's inputs (zeros past n_sim)."""
    first = m.n_static - m.n_sim
    for j in range(MAX_SIM_BODIES):
        for c in range(6):
            out[j, c] = 0.0
    for j in range(m.n_sim):
        for c in range(3):
            out[j, c] = d.wall_pose[first + j, c]
            out[j, 3 + c] = d.wall_twist[first + j, c]


@njit(cache=True)
def cosim_tick(model, data):
    """One tick of the co-simulation (module docstring): the devices' world poses and
    twists are in data.device_pose / device_twist; the commands are left in data.command."""
    m = model[0]
    d = data[0]
    _clear(m, d)
    all_contacts(m, d)
    collide(m, d)
    contact_forces(m, d)
    couple_ports(m, d)
    step_bodies(m, d)
    port_commands(m, d)
    keep_in_range(m, d)


def kinetic_energy(model: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """The co-simulated bodies' kinetic energy for rows of qd (n x MAX_COSIM_DOF)."""
    m = model[0]
    e = np.zeros(len(qd))
    for i in range(int(m["n_bodies"])):
        v = qd[:, 3 * i : 3 * i + 3]
        e += (
            0.5 * m["mass"][i] * (v[:, 0] ** 2 + v[:, 1] ** 2)
            + 0.5 * m["inertia"][i] * v[:, 2] ** 2
        )
    return e
