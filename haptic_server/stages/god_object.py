"""The finite-sphere god-object in moving worlds (seed 003 §3; DESIGN-WAVE2 §3).

A massless disc proxy p of radius r follows the device point x_h as the local minimiser of
|p - x_h| outside the obstacles, reached by continuous motion from its last position
(Zilles & Salisbury 1995; Ruspini et al. 1997). Per tick, in sub-steps small enough that no
obstacle moves more than (r + rho)/2 relative to the proxy in one of them:

1. the shapes are placed by their exact twist maps (shared.shapes), and a stuck proxy is
   carried in its obstacle's frame (the static-contact carry, before depenetration);
2. depenetration: the smallest move that satisfies every plane phi_k + n_k . dp >= 0
   (at most two bind in 2D); when none exists (closing slabs) the proxy passes through the
   obstacle on the side the finger presses into: a logged pop, its force ramped;
3. goal: x_h projected onto the half-spaces of the touching obstacles, reached by a swept
   move that stops GAP short of any other obstacle (so a thin wall is never tunnelled);
4. friction: Coulomb's cone on the finger's offset, stick/slip with CHAI3D's 0.6 hysteresis.

The force on the user is F = K (p - x_h) + B (p' - x_h'); the force on the touched obstacles
is its opposite, split by the planes' multipliers (the seed's eq 3 names only the first),
sent to the sim with the proxy state. Every kernel is a pure function of its records.

When the topology under the proxy changes (a shape appears that touches it, or one it
touches comes in a new generation: a remesh, a cut), the new geometry may hold the proxy
somewhere else entirely. A two-proxy blend (DESIGN-WAVE2 §4) then runs proxy A on against a
copy of the old shapes and B, the god-object's own state, against the new ones, and renders
(1 - s) A + s B, s = smoothstep(t / T_b), T_b = min(blend_s, 0.8 T_avg): the force moves to
the new geometry's over T_b instead of in one tick.

A deformable surface (a membrane) arrives as NODAL segments at a low rate (10 Hz). Between
its updates the god-object runs against the rendered nodes (DESIGN-WAVE2 §4, F2): with
`node_foh`, at each new sample every node moves linearly from where it is rendered to the
predicted next surface y_new + (y_new - y_prev) over T_avg, the mean of the last three
sample intervals (sim time), so the surface moves smoothly and the proxy meets it as a
moving obstacle (the nodes' speed enters the sub-step bound). `linear` moves toward y_new
without the prediction (a lag of T_avg), `none` holds y_new (the zero-order hold). A segment
keeps its hold while its key and generation do; a new generation, or a segment entering the
neighbourhood, starts at rest at its new nodes.
"""

from __future__ import annotations

import enum
import math

import numpy as np
from numba import njit

from haptic_local_model.shared.avar import MAX_CARS
from haptic_local_model.shared.shapes import (
    MAX_SHAPES,
    SHAPE_DTYPE,
    Motion,
    carry_pose,
    carry_rate,
    signed_distance,
    sweep_distance,
    to_body,
    to_world,
    vertex_signed_distance,
    vertex_sweep_distance,
)

MAX_PLANES = 4  # touching obstacles kept per solve (2 bind in 2D; the rest are checked)
GAP_M = 1.0e-6  # a swept move stops this far outside a newly met obstacle
TOUCH_M = 2.0e-6  # an obstacle within this distance is a constraint plane
DEPENETRATION_ROUNDS = 3  # curved cores need more than one linearised solve
GOAL_ROUNDS = 4  # swept moves per sub-step (each may add a plane)
PARALLEL_SIN = 1.0e-6  # two planes closer than this in direction are merged
FEASIBLE_M = 1.0e-12  # slack of a satisfied plane
HYSTERESIS = 0.6  # slip returns to stick below 0.6 atan(mu_k) (CHAI3D's multiplier)
NEAR_SLACK_M = 1.0e-3  # prefilter margin beyond every motion bound
INTERVALS = 3  # sample intervals averaged into the node hold's horizon T_avg
MIN_HORIZON_S = 1.0e-3  # the shortest T_avg: a hostile clock cannot make a node's rate infinite
SAMPLE_DUE = 0.95  # an unchanged surface is a new sample this far into its period


class Contact(enum.IntEnum):
    """The proxy's contact state (logged)."""

    FREE = 0
    SLIDE = 1
    STICK = 2


class GeometryBlend(enum.IntEnum):
    """How NODAL segments are rendered between their updates (module docstring)."""

    NONE = 0  # zero-order hold: the newest nodes
    LINEAR = 1  # toward the newest nodes over T_avg (no prediction)
    NODE_FOH = 2  # toward the predicted next nodes over T_avg


#: When an install happens: the old and new updates' ages now (s) and the new one's sim time
#: (the clock of the node samples).
CLOCK_DTYPE = np.dtype([("old_tau", np.float64), ("new_tau", np.float64), ("new_time", np.float64)])


def install_clock(old_tau: float, new_tau: float, new_time: float) -> np.ndarray:
    """A CLOCK_DTYPE[1] record."""
    c = np.zeros(1, dtype=CLOCK_DTYPE)
    c[0] = (old_tau, new_tau, new_time)
    return c


#: Parameters of one god-object tool (static per scene).
GOD_PARAMS_DTYPE = np.dtype(
    [
        ("radius", np.float64),  # r, m
        ("stiffness", np.float64, (2,)),  # K_vc, N/m
        ("damping", np.float64, (2,)),  # B_vc, N s/m
        ("max_substeps", np.int64),
        ("pop_ramp_s", np.float64),  # T_pop: a pop's force change takes at least this long
        ("max_force", np.float64),  # N, |F| is clipped here (the device's limit)
        ("blend_s", np.float64),  # pose FOH of the extrapolation error at installs
        ("geometry_blend", np.int64),  # GeometryBlend of NODAL segments
        ("node_period_s", np.float64),  # the sim's sample period of NODAL segments (0: unknown)
    ]
)

#: The proxy's state and this tick's results (logged fields first).
GOD_DATA_DTYPE = np.dtype(
    [
        ("proxy", np.float64, (2,)),  # p, m, world
        ("contact", np.int64),  # Contact
        ("n_active", np.int64),  # touching obstacles after the tick
        ("force", np.float64, (2,)),  # rendered force on the user, N
        ("env_key", np.int64, (2,)),  # the touched obstacles' keys (-1: none) ...
        ("env_point", np.float64, (2, 2)),  # ... where the proxy touches them (world, m) ...
        ("env_arm", np.float64, (2, 2)),  # ... that point less the shape's centre (world axes)
        ("env_force", np.float64, (2, 2)),  # ... and the force on each (N): -F split
        ("pop", np.int64),  # 1 on the tick a pop happened
        ("pops", np.int64),  # pop events so far
        ("ramping", np.int64),  # the pop ramp is limiting the force
        ("substeps", np.int64),
        ("capped", np.int64),  # 1: the sub-steps needed exceeded max_substeps this tick
        ("popped_key", np.int64),  # key of the obstacle being passed through, -1 none
        ("stick_shape", np.int64),  # the obstacle the proxy sticks to or slides on (-1)
        ("stick_local", np.float64, (2,)),  # p in that obstacle's frame (it carries p)
        ("touch", np.float64, (2,)),  # where the last swept move met an obstacle
        ("touched", np.int64),
        ("fade_elapsed_s", np.float64),  # time since the last install's pose blend began
        ("node_elapsed_s", np.float64),  # time since the NODAL holds began (a new sample)
        ("node_sample_time", np.float64),  # the sim time of the newest node sample, s
        ("node_samples", np.int64),  # node samples installed so far
        ("finger", np.float64, (2,)),  # x_h of the current sub-step
        ("finger_prev", np.float64, (2,)),  # x_h at the last tick (the haptic tick's stage)
        ("finger_now", np.float64, (2,)),
        ("started", np.int64),  # finger_prev holds a reading
        ("proxy_start", np.float64, (2,)),  # p at the start of the tick
        ("sweep_dir", np.float64, (2,)),  # scratch of seek_goal
        ("n_near", np.int64),
        ("near", np.int64, (MAX_SHAPES,)),  # prefiltered shape indices
        ("poses", np.float64, (MAX_SHAPES, 3)),  # placed poses this sub-step
        ("pose_offset", np.float64, (MAX_SHAPES, 3)),  # install error being faded out
        ("pose_offset_rate", np.float64, (MAX_SHAPES, 3)),  # and its rate at the install
        ("install_scratch", np.float64, (MAX_SHAPES, 8)),
        ("old_pose", np.float64, (3,)),  # scratch of install_shapes
        ("old_rate", np.float64, (3,)),
        ("new_rate", np.float64, (3,)),
        ("n_planes", np.int64),
        ("plane_index", np.int64, (MAX_PLANES,)),
        ("plane_phi", np.float64, (MAX_PLANES,)),
        ("plane_normal", np.float64, (MAX_PLANES, 2)),
        ("node_start", np.float64, (MAX_SHAPES, 2, 2)),  # NODAL: rendered nodes at the install
        ("node_rate", np.float64, (MAX_SHAPES, 2, 2)),  # and their velocity until the horizon
        ("node_core", np.float64, (MAX_SHAPES, 2, 2)),  # placed segment about its midpoint
        ("node_bound", np.float64, (MAX_SHAPES,)),  # its largest half length over the hold
        ("node_speed", np.float64, (MAX_SHAPES,)),  # its fastest node, m/s
        ("node_horizon_s", np.float64),  # T_avg, the horizon of the next holds
        ("node_hold_s", np.float64),  # the horizon of the running holds
        ("intervals", np.float64, (INTERVALS,)),  # the last update intervals, s
        ("clock", CLOCK_DTYPE),  # the install's (filled by the caller)
        ("n_intervals", np.int64),
        # the cars of a train (Motion.TRACK shapes, by owner): their poses at this tick's
        # start and the twist that carries them to the train's predicted poses at its end
        # (haptic_server/stages/train.py writes them before the god-object's step)
        ("car_pose", np.float64, (MAX_CARS, 3)),
        ("car_twist", np.float64, (MAX_CARS, 3)),
        # J, this tick: the work the touched obstacles' own motion did on the finger (the
        # passivity observer's budget for a moving world: a wall driven into the hand)
        ("env_work", np.float64),
        ("work_pose", np.float64, (2, 3)),  # scratch of env_work: the shape's start, end
    ]
)


#: The two-proxy blend and what the god_object method renders (the blend's or B's alone).
BLEND_DTYPE = np.dtype(
    [
        ("active", np.int64),
        ("elapsed_s", np.float64),
        ("total_s", np.float64),  # T_b
        ("weight", np.float64),  # s, the new geometry's weight this tick (0: no blend)
        ("tau", np.float64),  # the age of A's shapes
        ("n_shapes", np.int64),
        ("shapes", SHAPE_DTYPE, (MAX_SHAPES,)),  # A's: the old update's, kept
        ("a", GOD_DATA_DTYPE),  # proxy A and its per-shape state
        ("offset_p", np.float64, (2,)),  # carried with A: what was rendered minus A, at a
        ("offset_f", np.float64, (2,)),  # restart (zero for a blend from rest)
        ("proxy", np.float64, (2,)),  # the rendered proxy
        ("force", np.float64, (2,)),  # the rendered force on the user, N
        ("env_key", np.int64, (2,)),  # the rendered forces on obstacles (as in GOD_DATA)
        ("env_point", np.float64, (2, 2)),
        ("env_arm", np.float64, (2, 2)),
        ("env_force", np.float64, (2, 2)),
    ]
)


def blend_data() -> np.ndarray:
    """No blend running (BLEND_DTYPE[1])."""
    return np.zeros(1, dtype=BLEND_DTYPE)


#: The god-object's parameters beyond the disc and its coupling, unless given.
GOD_DEFAULTS: dict[str, float] = {
    "max_substeps": 16,
    "pop_ramp_s": 5e-3,
    "max_force": 10.0,
    "blend_s": 8e-3,
    "geometry_blend": GeometryBlend.NODE_FOH,
    "node_period_s": 0.0,  # unknown: a deformable's samples are told by their change only
}


def god_params(
    radius: float, stiffness: tuple[float, float], damping: tuple[float, float], **fields: float
) -> np.ndarray:
    """One GOD_PARAMS_DTYPE record: the disc's radius, the coupling, and any other field by
    name (GOD_DEFAULTS otherwise; the scene loader checks the ranges)."""
    g = np.zeros(1, dtype=GOD_PARAMS_DTYPE)
    g[0]["radius"] = radius
    g[0]["stiffness"] = stiffness
    g[0]["damping"] = damping
    for name, value in {**GOD_DEFAULTS, **fields}.items():
        g[0][name] = value  # an unknown name is numpy's ValueError, naming it
    return g


def god_data(proxy: tuple[float, float]) -> np.ndarray:
    """A free proxy at the given point."""
    d = np.zeros(1, dtype=GOD_DATA_DTYPE)
    d[0]["proxy"] = proxy
    d[0]["popped_key"] = -1
    d[0]["stick_shape"] = -1
    d[0]["fade_elapsed_s"] = 1e300  # no install blend running
    return d


@njit(cache=True)
def pose_blend_weights(m, elapsed_s):
    """The cubic Hermite weights (h, g, h', g') that take an install's offset o and its rate
    v to zero over blend_s with zero rate: offset(t) = h o + g v, C1 at both ends, so
    neither the position nor the velocity of a shape jumps at an install (a linear fade
    steps the velocity, which the coupling's damping turns into a force step)."""
    if m.blend_s <= 0.0 or elapsed_s >= m.blend_s:
        return 0.0, 0.0, 0.0, 0.0
    big_t = m.blend_s
    s = max(0.0, elapsed_s) / big_t
    h = 2.0 * s**3 - 3.0 * s**2 + 1.0
    g = (s**3 - 2.0 * s**2 + s) * big_t
    hd = (6.0 * s**2 - 6.0 * s) / big_t
    gd = 3.0 * s**2 - 4.0 * s + 1.0
    return h, g, hd, gd


@njit(cache=True)
def place_shapes(m, d, shapes, tau, ahead_s):
    """Every near shape ahead_s into the tick (its update's age tau + ahead_s): its pose,
    plus what is left of its install offset; a NODAL segment's held nodes."""
    h, g, _, _ = pose_blend_weights(m, d.fade_elapsed_s + ahead_s)
    for i in range(d.n_near):
        k = d.near[i]
        s = shapes[k]
        if s.motion == Motion.NODAL:
            place_nodes(d, k, d.node_elapsed_s + ahead_s)
            continue
        carry_shape(d, s, tau, ahead_s, d.poses[k])
        if h != 0.0 or g != 0.0:
            for c in range(3):
                d.poses[k, c] += h * d.pose_offset[k, c] + g * d.pose_offset_rate[k, c]


@njit(cache=True, inline="always")
def carry_shape(d, s, tau, ahead_s, out):
    """Shape s's pose ahead_s into the tick that starts tau past its update: its twist map,
    or for a car of a train (TRACK) its pose on the train, from this tick's start whatever
    the update's age (the haptic side integrates the train)."""
    if s.motion == Motion.TRACK:
        carry_pose(d.car_pose[s.owner], d.car_twist[s.owner], Motion.BALLISTIC, ahead_s, out)
    else:
        carry_pose(s.pose, s.twist, s.motion, tau + ahead_s, out)


@njit(cache=True)
def place_nodes(d, k, elapsed_s):
    """A NODAL segment's nodes at elapsed_s after the install (held at the horizon), as a
    pose (the midpoint, the direction a -> b) and a core about it."""
    t = min(max(elapsed_s, 0.0), d.node_hold_s)
    ax = d.node_start[k, 0, 0] + t * d.node_rate[k, 0, 0]
    ay = d.node_start[k, 0, 1] + t * d.node_rate[k, 0, 1]
    bx = d.node_start[k, 1, 0] + t * d.node_rate[k, 1, 0]
    by = d.node_start[k, 1, 1] + t * d.node_rate[k, 1, 1]
    half = 0.5 * math.hypot(bx - ax, by - ay)
    d.poses[k, 0] = 0.5 * (ax + bx)
    d.poses[k, 1] = 0.5 * (ay + by)
    d.poses[k, 2] = math.atan2(by - ay, bx - ax)
    d.node_core[k, 0, 0] = -half
    d.node_core[k, 1, 0] = half
    d.node_core[k, 0, 1] = 0.0
    d.node_core[k, 1, 1] = 0.0


@njit(cache=True, inline="always")
def shape_distance(m, d, shapes, k, x, y):
    """phi and the world normal of the proxy at (x, y) against placed shape k."""
    s = shapes[k]
    if s.motion == Motion.NODAL:
        return vertex_signed_distance(d.node_core[k], 2, s.rounding, d.poses[k], x, y, m.radius)
    return signed_distance(s, d.poses[k], x, y, m.radius)


@njit(cache=True, inline="always")
def _point_speed(d, s, k):
    """The fastest a point of the shape's core moves: |v| + |omega| R (NODAL: its fastest
    node, as a point of a segment moves by the blend of its nodes' velocities)."""
    if s.motion == Motion.NODAL:
        return d.node_speed[k]
    if s.motion == Motion.TRACK:
        t = d.car_twist[s.owner]
        return math.hypot(t[0], t[1]) + abs(t[2]) * s.bound
    return math.hypot(s.twist[0], s.twist[1]) + abs(s.twist[2]) * s.bound


@njit(cache=True, inline="always")
def _bound(d, s, k):
    """The core's radius about its pose (NODAL: the largest half length over the hold)."""
    if s.motion == Motion.NODAL:
        return d.node_bound[k]
    return s.bound


@njit(cache=True)
def near_shapes(m, d, shapes, n_shapes, x0, x1, tau, dt):
    """The prefilter (a bounding-circle test per shape over the tick's motion) and the
    sub-step count n = ceil(2 max_k(|v_k| + |omega_k| R_k) dt / (r + rho_k)), capped at
    max_substeps (d.capped: a faster obstacle may pass through the proxy unnoticed).

    The proxy may move this tick by twice the finger's path (sliding round a curved
    obstacle), plus what the fastest obstacle carries or pushes it, plus the install blend's
    offsets: a shape farther than that and its own reach cannot touch it."""
    p = d.proxy
    r = m.radius
    finger = math.hypot(x0[0] - p[0], x0[1] - p[1]) + math.hypot(x1[0] - x0[0], x1[1] - x0[1])
    big_g = 4.0 * m.blend_s / 27.0  # |g| <= 4 T / 27 of the blend's rate term
    fastest = 0.0
    blend_reach = 0.0
    fading = d.fade_elapsed_s < m.blend_s
    for k in range(n_shapes):
        s = shapes[k]
        fastest = max(fastest, _point_speed(d, s, k))
        if fading:
            off = math.hypot(d.pose_offset[k, 0], d.pose_offset[k, 1])
            off += abs(d.pose_offset[k, 2]) * s.bound
            off += big_g * math.hypot(d.pose_offset_rate[k, 0], d.pose_offset_rate[k, 1])
            off += big_g * abs(d.pose_offset_rate[k, 2]) * s.bound
            blend_reach = max(blend_reach, off)
    reach = 2.0 * finger + (fastest * dt + blend_reach)
    d.n_near = 0
    steps = 1
    for k in range(n_shapes):
        s = shapes[k]
        speed = _point_speed(d, s, k)
        if s.motion == Motion.NODAL:
            place_nodes(d, k, d.node_elapsed_s)
        else:
            carry_shape(d, s, tau, 0.0, d.poses[k])
        dist = math.hypot(d.poses[k, 0] - p[0], d.poses[k, 1] - p[1])
        limit = _bound(d, s, k) + s.rounding + r + reach + speed * dt + blend_reach + NEAR_SLACK_M
        if dist > limit:
            continue
        d.near[d.n_near] = k
        d.n_near += 1
        need = math.ceil(2.0 * speed * dt / (r + s.rounding))
        steps = max(steps, need)
    d.capped = 1 if steps > m.max_substeps else 0
    d.substeps = min(max(steps, 1), m.max_substeps)


@njit(cache=True)
def collect_planes(m, d, shapes, below):
    """The constraint planes of the near shapes with phi < below (the most penetrated
    MAX_PLANES), at the current proxy; the popped obstacle is left out."""
    d.n_planes = 0
    for i in range(d.n_near):
        k = d.near[i]
        if shapes[k].key == d.popped_key:
            continue
        phi, nx, ny = shape_distance(m, d, shapes, k, d.proxy[0], d.proxy[1])
        if phi >= below:
            continue
        slot = d.n_planes
        if slot == MAX_PLANES:
            worst = 0
            for j in range(1, MAX_PLANES):
                if d.plane_phi[j] > d.plane_phi[worst]:
                    worst = j
            if phi >= d.plane_phi[worst]:
                continue
            slot = worst
        else:
            d.n_planes += 1
        d.plane_index[slot] = k
        d.plane_phi[slot] = phi
        d.plane_normal[slot, 0] = nx
        d.plane_normal[slot, 1] = ny


@njit(cache=True)
def _satisfies(d, x, y, skip_a, skip_b):
    p = d.proxy
    for j in range(d.n_planes):
        if j in (skip_a, skip_b):
            continue
        n = d.plane_normal[j]
        if d.plane_phi[j] + n[0] * (x - p[0]) + n[1] * (y - p[1]) < -FEASIBLE_M:
            return False
    return True


@njit(cache=True)
def project_onto_planes(d, gx, gy):
    """The point nearest g satisfying every plane phi_j + n_j . (x - p) >= 0, by the 2D
    closed form (Zilles & Salisbury): g itself, g moved onto one plane, or the corner of two;
    the nearest feasible candidate is the optimum. Returns (x, y, feasible)."""
    p = d.proxy
    if _satisfies(d, gx, gy, -1, -1):
        return gx, gy, True
    best = 1e300
    bx = gx
    by = gy
    for i in range(d.n_planes):
        n = d.plane_normal[i]
        viol = d.plane_phi[i] + n[0] * (gx - p[0]) + n[1] * (gy - p[1])
        if viol >= 0.0:
            continue
        x = gx - viol * n[0]
        y = gy - viol * n[1]
        if _satisfies(d, x, y, i, -1):
            dist = (x - gx) ** 2 + (y - gy) ** 2
            if dist < best:
                best = dist
                bx = x
                by = y
    for i in range(d.n_planes):
        for j in range(i + 1, d.n_planes):
            a = d.plane_normal[i]
            b = d.plane_normal[j]
            det = a[0] * b[1] - a[1] * b[0]
            if abs(det) < PARALLEL_SIN:
                continue
            # n_i . dx = -phi_i, n_j . dx = -phi_j
            ri = -d.plane_phi[i]
            rj = -d.plane_phi[j]
            dx = (ri * b[1] - a[1] * rj) / det
            dy = (a[0] * rj - ri * b[0]) / det
            x = p[0] + dx
            y = p[1] + dy
            if _satisfies(d, x, y, i, j):
                dist = (x - gx) ** 2 + (y - gy) ** 2
                if dist < best:
                    best = dist
                    bx = x
                    by = y
    return bx, by, best < 1e300


@njit(cache=True)
def depenetrate(m, d, shapes, xh):
    """Step 2: out of every obstacle that moved into the proxy, by the smallest move. When no
    move exists (the planes oppose and overlap), pass through the obstacle the finger presses
    into (the one its point violates most), once: a pop, counted and ramped."""
    for _ in range(DEPENETRATION_ROUNDS):
        collect_planes(m, d, shapes, TOUCH_M)
        deepest = 0.0
        for j in range(d.n_planes):
            deepest = min(deepest, d.plane_phi[j])
        if deepest >= -FEASIBLE_M:
            return
        x, y, ok = project_onto_planes(d, d.proxy[0], d.proxy[1])
        if not ok:
            worst = -1
            worst_v = 1e300
            p = d.proxy
            for j in range(d.n_planes):
                n = d.plane_normal[j]
                v = d.plane_phi[j] + n[0] * (xh[0] - p[0]) + n[1] * (xh[1] - p[1])
                if v < worst_v:
                    worst_v = v
                    worst = j
            d.popped_key = shapes[d.plane_index[worst]].key
            d.pop = 1
            d.pops += 1
            d.ramping = 1
            if d.contact == Contact.STICK:
                d.contact = Contact.SLIDE
            d.stick_shape = -1
            continue
        d.proxy[0] = x
        d.proxy[1] = y


@njit(cache=True, inline="always")
def _sweep(m, d, shapes, k, p, u, length):
    """How far the proxy moves from p along u (at most length) and stays GAP_M outside k."""
    s = shapes[k]
    if s.motion == Motion.NODAL:
        reach = s.rounding + m.radius + GAP_M
        return vertex_sweep_distance(d.node_core[k], 2, d.poses[k], p, u, length, reach)
    return sweep_distance(s, d.poses[k], p, u, length, m.radius, GAP_M)


@njit(cache=True)
def seek_goal(m, d, shapes, xh):
    """Step 3: toward x_h projected onto the touching planes, swept against the others."""
    d.touched = 0
    for _ in range(GOAL_ROUNDS):
        collect_planes(m, d, shapes, TOUCH_M)
        gx, gy, ok = project_onto_planes(d, xh[0], xh[1])
        if not ok:
            return
        p = d.proxy
        length = math.hypot(gx - p[0], gy - p[1])
        if length < 1e-12:
            return
        u = d.sweep_dir
        u[0] = (gx - p[0]) / length
        u[1] = (gy - p[1]) / length
        s = length
        for i in range(d.n_near):
            k = d.near[i]
            if shapes[k].key == d.popped_key:
                continue
            touching = False
            for j in range(d.n_planes):
                if d.plane_index[j] == k:
                    touching = True
            if touching:
                continue  # its linearised plane holds along the whole move (phi is convex)
            reach = _sweep(m, d, shapes, k, p, u, s)
            s = min(s, reach)
        p[0] += s * u[0]
        p[1] += s * u[1]
        if s >= length:
            return
        if d.touched == 0:
            d.touched = 1
            d.touch[0] = p[0]
            d.touch[1] = p[1]


@njit(cache=True)
def apply_friction(m, d, shapes, xh, hold_x, hold_y):
    """Step 4: Coulomb's cone on one touching obstacle. The stick candidate is where the proxy
    was held (carried) or, on a new contact, where it met the surface; it stays there while
    |d_t| <= mu d_n (mu_s from stick or a new contact, 0.6 atan(mu_k) back from slip), else
    slips along its frictionless move to where |d_t| = mu_k d_n."""
    collect_planes(m, d, shapes, TOUCH_M)
    prev = d.contact
    if d.n_planes == 0:
        d.contact = Contact.FREE
        d.stick_shape = -1
        return
    if d.n_planes > 1:
        d.contact = Contact.SLIDE  # wedged: the corner holds it
        d.stick_shape = -1
        return
    k = d.plane_index[0]
    s = shapes[k]
    nx = d.plane_normal[0, 0]
    ny = d.plane_normal[0, 1]
    if s.friction <= 0.0 and s.static_friction <= 0.0:
        d.contact = Contact.SLIDE
        d.stick_shape = -1
        return
    free_x = d.proxy[0]
    free_y = d.proxy[1]
    cx = hold_x
    cy = hold_y
    phi_hold, _, _ = shape_distance(m, d, shapes, k, cx, cy)
    if phi_hold >= TOUCH_M:
        if d.touched == 0:
            d.contact = Contact.SLIDE
            d.stick_shape = -1
            return
        cx = d.touch[0]
        cy = d.touch[1]
        phi_touch, _, _ = shape_distance(m, d, shapes, k, cx, cy)
        if phi_touch >= TOUCH_M:  # the sweep stopped short of this obstacle: no stick there
            d.contact = Contact.SLIDE
            d.stick_shape = -1
            return
    ex = xh[0] - cx
    ey = xh[1] - cy
    depth = -(nx * ex + ny * ey)  # d_n = n . (c - x_h)
    if depth <= 0.0:
        d.contact = Contact.SLIDE  # touching, not pressed
        d.stick_shape = -1
        return
    tx = ex + depth * nx  # tangential offset of the finger from the candidate
    ty = ey + depth * ny
    offset = math.hypot(tx, ty)
    if prev == Contact.SLIDE:
        limit = math.tan(HYSTERESIS * math.atan(s.friction)) * depth
    else:
        limit = s.static_friction * depth
    if offset <= limit:
        d.proxy[0] = cx
        d.proxy[1] = cy
        d.contact = Contact.STICK
        d.stick_shape = k
        lx, ly = to_body(d.poses[k], cx, cy)
        d.stick_local[0] = lx
        d.stick_local[1] = ly
        return
    # slip: the point of [c, p_free] nearest to x_h's projection + mu_k d_n back toward c
    keep = s.friction * depth / offset
    target_x = cx + tx * (1.0 - keep)
    target_y = cy + ty * (1.0 - keep)
    sx = free_x - cx
    sy = free_y - cy
    span = sx * sx + sy * sy
    t = 0.0 if span == 0.0 else ((target_x - cx) * sx + (target_y - cy) * sy) / span
    t = min(1.0, max(0.0, t))
    d.proxy[0] = cx + t * sx
    d.proxy[1] = cy + t * sy
    d.contact = Contact.SLIDE
    # the sliding proxy rides on the obstacle too: kinetic friction acts in its frame, so
    # on a moving surface the next substep's candidate is where the surface carried it
    d.stick_shape = k
    lx, ly = to_body(d.poses[k], d.proxy[0], d.proxy[1])
    d.stick_local[0] = lx
    d.stick_local[1] = ly


@njit(cache=True)
def share_force(m, d, shapes):
    """The force on the touched obstacles: the opposite of the rendered force F, split over
    the (at most two) touching planes as F = sum lambda_k n_k with lambda_k >= 0, at the point
    where the proxy touches each. An obstacle is only pushed, never pulled: a plane whose
    share would pull it (the finger withdrawing, the damping, a pop's ramp) takes none. One
    plane takes F whole (its tangential part is the friction) when F . n > 0."""
    collect_planes(m, d, shapes, TOUCH_M)
    fx = d.force[0]
    fy = d.force[1]
    d.n_active = min(d.n_planes, 2)
    for j in range(2):
        d.env_key[j] = -1
        for c in range(2):
            d.env_point[j, c] = 0.0
            d.env_arm[j, c] = 0.0
            d.env_force[j, c] = 0.0
    if d.n_active == 1:
        lam = fx * d.plane_normal[0, 0] + fy * d.plane_normal[0, 1]
        if lam > 0.0:
            _push(m, d, shapes, 0, -fx, -fy)
    elif d.n_active == 2:
        a = d.plane_normal[0]
        b = d.plane_normal[1]
        det = a[0] * b[1] - a[1] * b[0]
        if abs(det) < PARALLEL_SIN:
            la = max(0.0, fx * a[0] + fy * a[1])
            lb = 0.0
        else:
            la = max(0.0, (fx * b[1] - b[0] * fy) / det)
            lb = max(0.0, (a[0] * fy - fx * a[1]) / det)
        _push(m, d, shapes, 0, -la * a[0], -la * a[1])
        _push(m, d, shapes, 1, -lb * b[0], -lb * b[1])


@njit(cache=True)
def _push(m, d, shapes, j, fx, fy):
    """Plane j's obstacle takes force (fx, fy) where the proxy touches it."""
    k = d.plane_index[j]
    d.env_key[j] = shapes[k].key
    d.env_point[j, 0] = d.proxy[0] - m.radius * d.plane_normal[j, 0]
    d.env_point[j, 1] = d.proxy[1] - m.radius * d.plane_normal[j, 1]
    # the lever about the shape's centre as placed now (a held segment's: its midpoint): the
    # sim applies the force there on its own body, wherever that body has got to
    d.env_arm[j, 0] = d.env_point[j, 0] - d.poses[k, 0]
    d.env_arm[j, 1] = d.env_point[j, 1] - d.poses[k, 1]
    d.env_force[j, 0] = fx
    d.env_force[j, 1] = fy


@njit(cache=True)
def render_force(m, d, p0, x0, x1, dt):
    """F = K (p - x_h) + B (p' - x_h'), clipped at max_force; after a pop its change per tick
    is at most max_force dt / T_pop until it meets the target."""
    fx = m.stiffness[0] * (d.proxy[0] - x1[0])
    fy = m.stiffness[1] * (d.proxy[1] - x1[1])
    fx += m.damping[0] * ((d.proxy[0] - p0[0]) - (x1[0] - x0[0])) / dt
    fy += m.damping[1] * ((d.proxy[1] - p0[1]) - (x1[1] - x0[1])) / dt
    mag = math.hypot(fx, fy)
    if mag > m.max_force:
        fx *= m.max_force / mag
        fy *= m.max_force / mag
    if d.ramping == 0:
        d.force[0] = fx
        d.force[1] = fy
        return
    step = m.max_force * dt / m.pop_ramp_s
    ex = fx - d.force[0]
    ey = fy - d.force[1]
    gap = math.hypot(ex, ey)
    if gap <= step:
        d.force[0] = fx
        d.force[1] = fy
        d.ramping = 0
        return
    d.force[0] += ex * step / gap
    d.force[1] += ey * step / gap


@njit(cache=True)
def release_popped(m, d, shapes, n_shapes):
    """The popped obstacle constrains again once the proxy is out of it (or it is gone)."""
    if d.popped_key < 0:
        return
    for k in range(n_shapes):
        if shapes[k].key == d.popped_key:
            phi, _, _ = shape_distance(m, d, shapes, k, d.proxy[0], d.proxy[1])
            if phi < 0.0:
                return
    d.popped_key = -1


@njit(cache=True)
def god_object_tick(model, data, shapes, n_shapes, x0, x1, tau, dt):
    """god_object_step on GOD_PARAMS_DTYPE[1] and GOD_DATA_DTYPE[1] arrays (tests, benchmarks)."""
    god_object_step(model[0], data[0], shapes, n_shapes, x0, x1, tau, dt)


@njit(cache=True)
def god_object_step(m, d, shapes, n_shapes, x0, x1, tau, dt):
    """One tick: the device point moves x0 -> x1 while the shapes age from tau to tau + dt;
    the force on the user is left in d.force (a non-finite finger: zero, the proxy kept)."""
    d.pop = 0
    d.proxy_start[0] = d.proxy[0]
    d.proxy_start[1] = d.proxy[1]
    finite = True
    for c in range(2):
        if not (math.isfinite(x0[c]) and math.isfinite(x1[c])):
            finite = False
    if not finite:
        d.force[0] = 0.0
        d.force[1] = 0.0
        d.n_active = 0
        for j in range(2):
            d.env_key[j] = -1
            for c in range(2):
                d.env_force[j, c] = 0.0
        return
    near_shapes(m, d, shapes, n_shapes, x0, x1, tau, dt)
    n = d.substeps
    xh = d.finger
    for i in range(n):
        f = (i + 1) / n
        xh[0] = x0[0] + f * (x1[0] - x0[0])
        xh[1] = x0[1] + f * (x1[1] - x0[1])
        place_shapes(m, d, shapes, tau, f * dt)
        if d.contact != Contact.FREE and d.stick_shape >= 0:  # carried: stuck or sliding
            x, y = to_world(d.poses[d.stick_shape], d.stick_local[0], d.stick_local[1])
            d.proxy[0] = x
            d.proxy[1] = y
        depenetrate(m, d, shapes, xh)
        hold_x = d.proxy[0]
        hold_y = d.proxy[1]
        seek_goal(m, d, shapes, xh)
        apply_friction(m, d, shapes, xh, hold_x, hold_y)
    release_popped(m, d, shapes, n_shapes)
    d.fade_elapsed_s += dt
    d.node_elapsed_s += dt
    render_force(m, d, d.proxy_start, x0, x1, dt)
    share_force(m, d, shapes)
    env_work(d, shapes, tau, dt)


@njit(cache=True)
def env_work(d, shapes, tau, dt):
    """d.env_work: the work of the touched obstacles' motion on the finger over the tick,
    -sum F_j . (the touching point carried by its obstacle from the tick's start to its end);
    a NODAL segment (a membrane, not prescribed) counts none."""
    d.env_work = 0.0
    for j in range(d.n_active):
        if d.env_key[j] < 0:
            continue
        k = d.plane_index[j]
        s = shapes[k]
        if s.motion == Motion.NODAL:
            continue
        start = d.work_pose[0]
        end = d.work_pose[1]
        carry_shape(d, s, tau, 0.0, start)  # its own motion (an install's blend left out)
        carry_shape(d, s, tau, dt, end)
        lx, ly = to_body(end, d.env_point[j, 0], d.env_point[j, 1])
        x1, y1 = to_world(end, lx, ly)
        x0, y0 = to_world(start, lx, ly)
        d.env_work -= d.env_force[j, 0] * (x1 - x0) + d.env_force[j, 1] * (y1 - y0)


@njit(cache=True)
def _wrap(angle):
    """angle in [-pi, pi]."""
    return angle - 2.0 * math.pi * math.floor(angle / (2.0 * math.pi) + 0.5)


@njit(cache=True)
def install_shapes(model, data, old, n_old, new, n_new, clock):
    """install_shapes_step on GOD_PARAMS_DTYPE[1], GOD_DATA_DTYPE[1] and CLOCK_DTYPE[1]."""
    install_shapes_step(model[0], data[0], old, n_old, new, n_new, clock[0])


@njit(cache=True)
def install_shapes_step(m, d, old, n_old, new, n_new, clock):
    """A new set of shapes replaces the old at an install. A shape present in both (by key)
    keeps its rendered pose and velocity: the difference from the new extrapolation (the
    old one's error) and its rate fade out over blend_s by `pose_blend_weights` (DESIGN-WAVE2
    C2's pose FOH, made C1). The stick follows its shape by key (the pop keeps its key).
    The clock (CLOCK_DTYPE) holds the two updates' ages now and the new one's sim time."""
    old_tau = clock.old_tau
    new_tau = clock.new_tau
    new_time = clock.new_time
    h, g, hd, gd = pose_blend_weights(m, d.fade_elapsed_s)
    stick_key = old[d.stick_shape].key if 0 <= d.stick_shape < n_old else -1
    d.stick_shape = -1
    sample = new_node_sample(m, d, old, n_old, new, n_new, new_time)
    if sample:
        count_interval(m, d, new_time - d.node_sample_time)
    for k in range(n_new):
        s = new[k]
        if s.key == stick_key:
            d.stick_shape = k
        if s.motion == Motion.NODAL:
            hold_nodes(m, d, old, n_old, s, k, sample)
            continue
        for c in range(6):
            d.install_scratch[k, c] = 0.0
        if s.motion == Motion.TRACK:  # posed by the train, which no install moves
            carry_shape(d, s, new_tau, 0.0, d.poses[k])
            continue
        carry_pose(s.pose, s.twist, s.motion, new_tau, d.poses[k])
        carry_rate(s.twist, s.motion, new_tau, d.new_rate)
        found = -1
        for j in range(n_old):
            if old[j].key == s.key:
                found = j
                break
        if found >= 0 and m.blend_s > 0.0:
            o = old[found]
            carry_pose(o.pose, o.twist, o.motion, old_tau, d.old_pose)
            carry_rate(o.twist, o.motion, old_tau, d.old_rate)
            for c in range(3):
                off = d.pose_offset[found, c]
                rate = d.pose_offset_rate[found, c]
                d.old_pose[c] += h * off + g * rate
                d.old_rate[c] += hd * off + gd * rate
                d.install_scratch[k, c] = d.old_pose[c] - d.poses[k, c]
                d.install_scratch[k, 3 + c] = d.old_rate[c] - d.new_rate[c]
            d.install_scratch[k, 2] = _wrap(d.install_scratch[k, 2])
    for k in range(n_new):
        if new[k].motion == Motion.NODAL:
            start_nodes(d, k, sample)
            continue
        for c in range(3):
            d.pose_offset[k, c] = d.install_scratch[k, c]
            d.pose_offset_rate[k, c] = d.install_scratch[k, 3 + c]
    d.fade_elapsed_s = 0.0
    if sample:
        d.node_elapsed_s = 0.0
        d.node_sample_time = new_time
        d.node_samples += 1
        d.node_hold_s = d.node_horizon_s
    if d.stick_shape < 0 and d.contact == Contact.STICK:
        d.contact = Contact.SLIDE


@njit(cache=True)
def _old_match(old, n_old, s):
    """The index of the old NODAL segment of s's key and generation, -1 if none."""
    for j in range(n_old):
        o = old[j]
        if o.key == s.key and o.motion == Motion.NODAL and o.generation == s.generation:
            return j
    return -1


@njit(cache=True)
def new_node_sample(m, d, old, n_old, new, n_new, new_time):
    """Whether the new update brings a new sample of the deformable surface: a NODAL segment
    of the same key and generation whose nodes moved; or, the surface unchanged, a sample
    period (node_period_s) since the last. The sim may publish a surface at a lower rate
    than its updates, repeating the last sample in between: then the holds run on. (A
    surface at rest, or at the same place at two samples, is sampled all the same.) A
    segment without a match (one entering the neighbourhood, a new generation) is not a
    sample by itself, except the very first: it is held at its nodes (hold_nodes)."""
    period = m.node_period_s
    due = new_time - d.node_sample_time >= SAMPLE_DUE * period
    if period > 0.0 and d.node_samples > 0 and due:
        return True
    for k in range(n_new):
        s = new[k]
        if s.motion != Motion.NODAL:
            continue
        j = _old_match(old, n_old, s)
        if j < 0:
            if d.node_samples == 0:
                return True
            continue
        o = old[j]
        for c in range(2):
            if s.pose[c] != o.pose[c]:
                return True
        for i in range(2):
            for c in range(2):
                if s.vertices[i, c] != o.vertices[i, c]:
                    return True
    return False


@njit(cache=True)
def count_interval(m, d, interval):
    """The sim time between two node samples into the last INTERVALS, and the node hold's
    horizon T_avg, their mean (not before a second sample). An interval over twice the
    sample period (the surface was out of reach, or updates were lost) counts as one
    period."""
    if d.node_samples == 0 or not interval > 0.0:
        return
    period = m.node_period_s
    if period > 0.0 and interval < SAMPLE_DUE * period:
        return  # not a sample interval (the clock went wrong): T_avg keeps its history
    if period > 0.0 and interval > 2.0 * period:
        interval = period
    for i in range(INTERVALS - 1, 0, -1):
        d.intervals[i] = d.intervals[i - 1]
    d.intervals[0] = interval
    d.n_intervals = min(d.n_intervals + 1, INTERVALS)
    total = 0.0
    for i in range(d.n_intervals):
        total += d.intervals[i]
    d.node_horizon_s = max(total / d.n_intervals, MIN_HORIZON_S)


@njit(cache=True)
def hold_nodes(m, d, old, n_old, s, k, sample):
    """Where new NODAL segment k's nodes start (install_scratch[k, 0:4]) and their velocity
    (4:8). On a new sample: from where the old segment of the same key and generation is
    rendered now toward the newest nodes (LINEAR) or the predicted next ones (NODE_FOH) over
    T_avg, otherwise held at the newest nodes. Between samples: the old hold runs on (a
    segment without one: at rest at its nodes)."""
    sc = d.install_scratch[k]
    j = _old_match(old, n_old, s)
    if not sample and j >= 0:
        for i in range(2):
            for c in range(2):
                sc[2 * i + c] = d.node_start[j, i, c]
                sc[4 + 2 * i + c] = d.node_rate[j, i, c]
        return
    for i in range(2):
        x, y = to_world(s.pose, s.vertices[i, 0], s.vertices[i, 1])
        sc[2 * i] = x
        sc[2 * i + 1] = y
        sc[4 + 2 * i] = 0.0
        sc[5 + 2 * i] = 0.0
    if not sample or m.geometry_blend == GeometryBlend.NONE or d.node_horizon_s <= 0.0:
        return  # (a segment without a match between samples: at rest at its nodes)
    found = j
    if found < 0:
        return
    o = old[found]
    t = min(max(d.node_elapsed_s, 0.0), d.node_hold_s)
    for i in range(2):
        for c in range(2):
            now = d.node_start[found, i, c] + t * d.node_rate[found, i, c]
            target = sc[2 * i + c]
            if m.geometry_blend == GeometryBlend.NODE_FOH:
                prev = to_world(o.pose, o.vertices[i, 0], o.vertices[i, 1])[c]
                target += target - prev
            sc[2 * i + c] = now
            sc[4 + 2 * i + c] = (target - now) / d.node_horizon_s


@njit(cache=True)
def start_nodes(d, k, sample):
    """Install segment k's node hold from install_scratch, with the bounds the prefilter
    reads: the largest half length over the hold (at an end: |b - a| is convex in t) and
    the fastest node."""
    sc = d.install_scratch[k]
    for i in range(2):
        for c in range(2):
            d.node_start[k, i, c] = sc[2 * i + c]
            d.node_rate[k, i, c] = sc[4 + 2 * i + c]
    span = d.node_horizon_s if sample else d.node_hold_s
    dx0 = sc[2] - sc[0]
    dy0 = sc[3] - sc[1]
    dx1 = dx0 + span * (sc[6] - sc[4])
    dy1 = dy0 + span * (sc[7] - sc[5])
    d.node_bound[k] = 0.5 * max(math.hypot(dx0, dy0), math.hypot(dx1, dy1))
    d.node_speed[k] = max(math.hypot(sc[4], sc[5]), math.hypot(sc[6], sc[7]))
    d.pose_offset[k, :] = 0.0
    d.pose_offset_rate[k, :] = 0.0


@njit(cache=True)
def topology_changes(m, d, old, n_old, new, n_new, clock):
    """Whether the new shapes change the topology under the proxy: a shape that touches or
    overlaps it now and is new (its key not in the old update) or of a new generation, or one
    that touches it now and is gone from the new update (a pebble the sim's step flung out
    of the neighbourhood: without the blend the proxy would jump to the device in a tick)."""
    for j in range(n_old):
        o = old[j]
        gone = True
        for k in range(n_new):
            if new[k].key == o.key:
                gone = False
                break
        if gone and _touches_now(m, d, o, clock.old_tau):
            return True
    for k in range(n_new):
        s = new[k]
        changed = True
        for j in range(n_old):
            if old[j].key == s.key:
                changed = old[j].generation != s.generation
                break
        if changed and _touches_now(m, d, s, clock.new_tau):
            return True
    return False


@njit(cache=True, inline="always")
def _touches_now(m, d, s, tau):
    """Shape s, carried tau past its update (a nodal one at its sample, about a pose of zero
    angle), touches or overlaps the proxy."""
    if s.motion == Motion.NODAL:
        phi, _, _ = signed_distance(s, s.pose, d.proxy[0], d.proxy[1], m.radius)
    else:
        carry_shape(d, s, tau, 0.0, d.old_pose)
        phi, _, _ = signed_distance(s, d.old_pose, d.proxy[0], d.proxy[1], m.radius)
    return phi < TOUCH_M


@njit(cache=True)
def begin_blend(m, d, b, old, n_old, old_tau):
    """Start a two-proxy blend at an install, before the new shapes replace the old in d:
    A <- the god-object as it is, with the old shapes and their per-shape state. A blend
    already running restarts from what it renders: A <- B (on B's geometry, now the old one)
    plus a constant offset, what was rendered minus B, so the rendered proxy and force go on
    from where they were. (DESIGN-WAVE2 puts A at p_r and depenetrates it against B's
    geometry, a jump of up to (1 - s) |p_A - p_B|; the offset makes none.) No blend when T_b
    is zero."""
    total = blend_time(m, d)
    if total <= 0.0:
        return
    running = b.active == 1
    b.a = d
    for c in range(2):
        b.offset_p[c] = b.proxy[c] - d.proxy[c] if running else 0.0
        b.offset_f[c] = b.force[c] - d.force[c] if running else 0.0
    for k in range(n_old):
        b.shapes[k] = old[k]
    b.n_shapes = n_old
    b.tau = old_tau
    b.elapsed_s = 0.0
    b.total_s = total
    b.active = 1


@njit(cache=True)
def blend_time(m, d):
    """T_b = min(blend_s, 0.8 T_avg) (T_avg of a deformable's samples, once known)."""
    if d.n_intervals > 0:
        return min(m.blend_s, 0.8 * d.node_horizon_s)
    return m.blend_s


@njit(cache=True)
def install_blended_step(m, d, b, old, n_old, new, n_new, clock):
    """An install: a two-proxy blend begins if the topology under the proxy changes, then
    the new shapes replace the old (install_shapes_step); T_b counts this install's sample
    interval too."""
    began = topology_changes(m, d, old, n_old, new, n_new, clock)
    if began:
        begin_blend(m, d, b, old, n_old, clock.old_tau)
    install_shapes_step(m, d, old, n_old, new, n_new, clock)
    if began and b.active == 1:
        b.total_s = max(blend_time(m, d), 1e-9)


@njit(cache=True)
def install_blended(model, data, blend, old, n_old, new, n_new, clock):
    """install_blended_step on [1] arrays (tests, benchmarks)."""
    install_blended_step(model[0], data[0], blend[0], old, n_old, new, n_new, clock[0])


@njit(cache=True)
def blend_step(m, d, b, x0, x1, dt):
    """After the god-object's tick (B, in d): while a blend runs, A's tick against its old
    shapes; the rendered proxy, force and obstacle forces into b (B's alone otherwise), the
    force clipped at max_force again (A carries a restart's offset)."""
    s = 1.0
    blending = b.active == 1
    if blending:
        god_object_step(m, b.a, b.shapes, b.n_shapes, x0, x1, b.tau, dt)
        b.tau += dt
        b.elapsed_s += dt
        u = min(1.0, b.elapsed_s / b.total_s)
        s = u * u * (3.0 - 2.0 * u)
        if u >= 1.0:
            b.active = 0
    b.weight = s if blending else 0.0
    a = b.a
    for c in range(2):
        if s < 1.0:
            b.proxy[c] = (1.0 - s) * (a.proxy[c] + b.offset_p[c]) + s * d.proxy[c]
            b.force[c] = (1.0 - s) * (a.force[c] + b.offset_f[c]) + s * d.force[c]
        else:
            b.proxy[c] = d.proxy[c]
            b.force[c] = d.force[c]
    mag = math.hypot(b.force[0], b.force[1])
    if mag > m.max_force:
        b.force[0] *= m.max_force / mag
        b.force[1] *= m.max_force / mag
    for j in range(2):
        b.env_key[j] = d.env_key[j]
        for c in range(2):
            b.env_point[j, c] = d.env_point[j, c]
            b.env_arm[j, c] = d.env_arm[j, c]
            b.env_force[j, c] = s * d.env_force[j, c]
    if s < 1.0:
        for j in range(2):
            if a.env_key[j] >= 0:
                _add_env(b, a, j, 1.0 - s)


@njit(cache=True)
def _add_env(b, a, i, w):
    """A's share w of its force on its obstacle i: onto B's force on the same key, else into
    a free slot (B touches at most two obstacles; a third share is dropped)."""
    key = a.env_key[i]
    for j in range(2):
        if b.env_key[j] == key:
            b.env_force[j, 0] += w * a.env_force[i, 0]
            b.env_force[j, 1] += w * a.env_force[i, 1]
            return
    for j in range(2):
        if b.env_key[j] < 0:
            b.env_key[j] = key
            for c in range(2):
                b.env_point[j, c] = a.env_point[i, c]
                b.env_arm[j, c] = a.env_arm[i, c]
                b.env_force[j, c] = w * a.env_force[i, c]
            return


@njit(cache=True)
def blend_tick(model, data, blend, x0, x1, dt):
    """blend_step on [1] arrays (tests, benchmarks)."""
    blend_step(model[0], data[0], blend[0], x0, x1, dt)


@njit(cache=True)
def reset_proxy(d, x, y):
    """A free proxy at (x, y), nothing carried, popped, fading or owed (re-initialisation)."""
    d.proxy[0] = x
    d.proxy[1] = y
    d.contact = Contact.FREE
    d.stick_shape = -1
    d.popped_key = -1
    d.ramping = 0
    d.n_active = 0
    d.fade_elapsed_s = 1e300
    for c in range(2):
        d.force[c] = 0.0
    for k in range(MAX_SHAPES):
        for c in range(3):
            d.pose_offset[k, c] = 0.0
            d.pose_offset_rate[k, c] = 0.0
