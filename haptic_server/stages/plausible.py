"""Is a valid update also plausible for this scene? Defence in depth against a buggy or
compromised sim that holds valid credentials (docs/security.md).

The validating parser (shared/protocol/update.py) checks that an update is well formed and
within the protocol's global bounds. The haptic server also knows the scene, so it checks
what the update says against it (ENVELOPE_DTYPE, packed by `envelope_record`):

- **consistency** (Reason.INCONSISTENT): the chain is the scene's tool; D, G, C(q, qd) qd,
  Lambda^-1 = J_h D^-1 J_h^T and the tool pose equal what that chain gives at the update's own
  q (recomputed here with the sim's kernels, so they agree to rounding); a resisted direction
  is one J_h does not move. A forged D = 1e-6 I, a gravity torque of 1e4 or a Lambda^-1 of the
  wrong sign cannot agree with the chain.
- **the scene's envelope** (Reason.IMPLAUSIBLE): the operational point's speed, every link's
  angular speed and the tool's kinetic energy within the scene's [safety] bounds; a
  contact's stiffness, damping, friction and restitution within the scene's materials, its
  environment point's speed within what the scene can move, its tool point on the tool, and
  its depth at the sim's own tool state within max_penetration_m.
- **rate** (Reason.JUMP): while the sim's updates flow, the tool moves from one to the next
  no farther than its speed bound allows in the time between them, and the sequence number
  advances no faster than the sim's rate.
"""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.shared.kinematics import (
    REVOLUTE,
    VELOCITY_TORQUE_STEP,
    link_spin,
    mass_matrix_and_gravity,
    point_jacobian,
    point_on_link,
    scaled_gram,
    velocity_product_torque_into,
)
from haptic_local_model.shared.linalg import cholesky_inplace, cholesky_solve, symmetric_eigen
from haptic_local_model.shared.protocol.codes import Reason

#: geometry the sim and the haptic side compute from the same numbers agrees to rounding;
#: beyond these it is another tool (m, rad)
GEOMETRY_TOLERANCE = 1.0e-9
#: a tool point may lie this far outside its link's outline (m): pymunk's contact points lie
#: on the shape, up to its collision slop (1e-4 m)
OUTLINE_SLACK_M = 1.0e-3
#: C qd by central differences: the same code on the same numbers, but its rounding is that
#: of a difference quotient (relative)
VELOCITY_TORQUE_TOLERANCE = 1.0e-5
#: the tool may move this much more between two updates than its speed bound allows (m, rad)
JUMP_SLACK = 1.0e-3

#: ENVELOPE_DTYPE.ratios: each checked figure of the last update over its bound
RATIO_MASS = 0  # largest |D - D(q)| over its tolerance
RATIO_SPEED = 1  # the operational point's speed
RATIO_SPIN = 2  # the fastest link's spin
RATIO_ENERGY = 3  # the kinetic energy
RATIO_DEPTH = 4  # the deepest contact at the sim's tool state
RATIO_ENV_SPEED = 5  # the fastest environment point
RATIO_JUMP = 6  # the tool's move since the previous update (linear or angular)
RATIO_NAMES = ("mass", "speed", "spin", "energy", "depth", "env_speed", "jump")


@njit(cache=True)
def check_plausible(u, prev, live, env):
    """0 if the parsed update `u` is plausible for the scene, else the Reason. `prev` is the
    installed model the update follows; `live`: the sim's updates flow (same epoch, no
    watchdog trip since), so the rate checks apply. env: ENVELOPE_DTYPE record."""
    for k in range(env.ratios.shape[0]):
        env.ratios[k] = 0.0
    code = _check_chain(u, env)
    if code == 0:
        code = _check_dynamics(u, env)
    if code == 0:
        code = _check_motion(u, env)
    if code == 0:
        code = _check_contacts(u, env)
    if code == 0 and env.linkage == 1:
        code = _check_velocity_torque(u, env)  # last: it moves the frames of q
    if code == 0 and live:
        code = _check_jump(u, prev, env)
    return code


@njit(cache=True, inline="always")
def _differs(a, b, tolerance):
    return not abs(a - b) <= tolerance


@njit(cache=True)
def _check_chain(u, env):
    """The update's chain, operational point and sections are the scene's tool."""
    c = env.chain[0]
    d = c.dof
    if u.dof != d or u.op_link != env.op_link:
        return Reason.INCONSISTENT
    for i in range(d):
        if u.joint_types[i] != c.joint_types[i] or u.parents[i] != c.parents[i]:
            return Reason.INCONSISTENT
        if _differs(u.lengths[i], c.lengths[i], GEOMETRY_TOLERANCE):
            return Reason.INCONSISTENT
    for k in range(2):
        if _differs(u.base[k], c.base[k], GEOMETRY_TOLERANCE):
            return Reason.INCONSISTENT
        if _differs(u.op_point[k], env.op_point[k], GEOMETRY_TOLERANCE):
            return Reason.INCONSISTENT
    if _differs(u.base_angle, c.base_angle, GEOMETRY_TOLERANCE):
        return Reason.INCONSISTENT
    if u.n_chains != c.n_chains:
        return Reason.INCONSISTENT
    for k in range(1, c.n_chains):
        if u.chain_first[k] != c.chain_first[k] or u.chain_kind[k] != c.chain_kind[k]:
            return Reason.INCONSISTENT
        if u.chain_port[k] != c.chain_port[k]:
            return Reason.INCONSISTENT
        for a in range(3):
            if _differs(u.chain_base[k, a], c.chain_base[k, a], GEOMETRY_TOLERANCE):
                return Reason.INCONSISTENT
    length = env.characteristic_length
    if _differs(u.characteristic_length, length, GEOMETRY_TOLERANCE * length):
        return Reason.INCONSISTENT
    has_gravity = 1 if (env.gravity[0] != 0.0 or env.gravity[1] != 0.0) else 0
    if u.has_gravity != has_gravity or u.has_velocity_torque != env.linkage:
        return Reason.INCONSISTENT
    if env.linkage == 0 and u.n_resisted != 0:
        return Reason.INCONSISTENT
    return 0


@njit(cache=True)
def _check_dynamics(u, env):
    """D, G, the tool pose, Lambda^-1 and the resisted directions as the chain gives them at
    u.q. Leaves the link frames of u.q and J_h in the envelope's scratch."""
    c = env.chain[0]
    d = c.dof
    tol = env.tolerance
    mass, grav, jac = env.mass, env.gravity_q, env.jac
    mass_matrix_and_gravity(
        env.chain, env.gravity, u.q, (env.frame_pos, env.frame_angle, jac), mass, grav
    )
    scale = 0.0
    for a in range(d):
        for b in range(d):
            scale = max(scale, abs(mass[a, b]))
    worst = 0.0
    for a in range(d):
        for b in range(d):
            worst = max(worst, abs(u.mass[a, b] - mass[a, b]) / (tol * scale + 1e-300))
            if _differs(u.mass[a, b], mass[a, b], tol * scale):
                return Reason.INCONSISTENT
    env.ratios[RATIO_MASS] = worst
    if u.has_gravity == 1:
        # a floor for the scale: the weight of the tool on a 1 mm lever
        g_scale = 1e-3 * math.hypot(env.gravity[0], env.gravity[1])
        for i in range(d):
            g_scale += 1e-3 * c.masses[i] * math.hypot(env.gravity[0], env.gravity[1])
        for a in range(d):
            g_scale = max(g_scale, abs(grav[a]))
        for a in range(d):
            if _differs(u.gravity[a], grav[a], tol * g_scale):
                return Reason.INCONSISTENT
    point = env.point
    point_on_link(env.frame_pos, env.frame_angle, env.op_link, env.op_point, point)
    reach = 1.0 + abs(point[0]) + abs(point[1])
    if _differs(u.tool_pose[0], point[0], tol * reach) or _differs(
        u.tool_pose[1], point[1], tol * reach
    ):
        return Reason.INCONSISTENT
    angle = env.frame_angle[env.op_link]
    if _differs(u.tool_pose[2], angle, tol * (1.0 + abs(angle))):
        return Reason.INCONSISTENT
    point_jacobian(c, env.frame_pos, d, env.op_link, point[0], point[1], jac)
    if not cholesky_inplace(mass, d, env.chol):
        return Reason.INCONSISTENT
    lam = env.gram  # J_h D^-1 J_h^T, as the sim computes it
    col = env.column
    lam_scale = 0.0
    for r in range(3):
        for i in range(d):
            col[i] = jac[r, i]
        cholesky_solve(env.chol, d, col, col)
        for a in range(3):
            s = 0.0
            for i in range(d):
                s += jac[a, i] * col[i]
            lam[a, r] = s
            lam_scale = max(lam_scale, abs(s))
    for a in range(3):
        for b in range(3):
            if _differs(u.lambda_inv[a, b], lam[a, b], tol * lam_scale):
                return Reason.INCONSISTENT
    if u.n_resisted > 0:
        return _check_resisted(u, env)
    return 0


@njit(cache=True)
def _check_resisted(u, env):
    """Each resisted direction n (scaled space) is one the scaled J_h barely moves:
    n^T (S J_h J_h^T S) n below the rank tolerance squared times the largest eigenvalue."""
    gram = env.gram
    scaled_gram(env.jac, env.chain[0].dof, env.characteristic_length, gram)
    values = env.eigenvalues
    symmetric_eigen(gram, 3, values, env.eigenvectors)
    top = max(values[0], max(values[1], values[2]))
    bound = env.rank_tolerance * env.rank_tolerance * top * (1.0 + 1e-6) + 1e-300
    for r in range(u.n_resisted):
        s = 0.0
        for a in range(3):
            for b in range(3):
                s += u.resisted[r, a] * gram[a, b] * u.resisted[r, b]
        if s > bound:
            return Reason.INCONSISTENT
    return 0


@njit(cache=True)
def _check_motion(u, env):
    """The operational point's speed, every link's spin and the kinetic energy within the
    scene's bounds (J_h and D^ of u.q in the scratch)."""
    c = env.chain[0]
    d = c.dof
    jac = env.jac
    vx = 0.0
    vy = 0.0
    for i in range(d):
        vx += jac[0, i] * u.qd[i]
        vy += jac[1, i] * u.qd[i]
    env.ratios[RATIO_SPEED] = math.hypot(vx, vy) / env.max_speed
    if math.hypot(vx, vy) > env.max_speed:
        return Reason.IMPLAUSIBLE
    for i in range(d):
        if c.joint_types[i] == REVOLUTE:
            spin = link_spin(c, u.qd, i)
            env.ratios[RATIO_SPIN] = max(env.ratios[RATIO_SPIN], abs(spin) / env.max_angular_speed)
            if abs(spin) > env.max_angular_speed:
                return Reason.IMPLAUSIBLE
    energy = 0.0
    for a in range(d):
        for b in range(d):
            energy += 0.5 * u.qd[a] * u.mass[a, b] * u.qd[b]
    env.ratios[RATIO_ENERGY] = energy / env.max_energy
    if energy > env.max_energy:
        return Reason.IMPLAUSIBLE
    return 0


@njit(cache=True)
def _check_contacts(u, env):
    """Every contact's material within the scene's, its environment point's speed within what
    the scene moves, its tool point on its link, its depth at u.q within the bound."""
    point = env.point
    for i in range(u.n_contacts):
        if (
            u.c_stiffness[i] > env.max_stiffness
            or u.c_tangential_stiffness[i] > env.max_tangential_stiffness
            or u.c_damping[i] > env.max_damping
            or u.c_friction[i] > env.max_friction
            or u.c_restitution[i] > env.max_restitution
        ):
            return Reason.IMPLAUSIBLE
        env_speed = math.hypot(u.c_env_velocity[i, 0], u.c_env_velocity[i, 1])
        env.ratios[RATIO_ENV_SPEED] = max(
            env.ratios[RATIO_ENV_SPEED], env_speed / env.max_env_speed
        )
        if env_speed > env.max_env_speed:
            return Reason.IMPLAUSIBLE
        link = u.c_link[i]
        if _outline_distance(env, link, u.c_tool[i, 0], u.c_tool[i, 1]) > OUTLINE_SLACK_M:
            return Reason.IMPLAUSIBLE
        point_on_link(env.frame_pos, env.frame_angle, link, u.c_tool[i], point)
        gap = u.c_normal[i, 0] * (point[0] - u.c_env[i, 0])
        gap += u.c_normal[i, 1] * (point[1] - u.c_env[i, 1])
        env.ratios[RATIO_DEPTH] = max(env.ratios[RATIO_DEPTH], -gap / env.max_penetration)
        if gap < -env.max_penetration:
            return Reason.IMPLAUSIBLE
    return 0


@njit(cache=True)
def _outline_distance(env, link, px, py):
    """How far a point of the link's frame lies outside the capsule around its shape."""
    ax, ay = env.outline_a[link, 0], env.outline_a[link, 1]
    bx, by = env.outline_b[link, 0], env.outline_b[link, 1]
    ex, ey = bx - ax, by - ay
    ee = ex * ex + ey * ey
    s = 0.0 if ee <= 0.0 else min(1.0, max(0.0, ((px - ax) * ex + (py - ay) * ey) / ee))
    return math.hypot(px - ax - s * ex, py - ay - s * ey) - env.outline_radius[link]


@njit(cache=True)
def _check_velocity_torque(u, env):
    """C(q, qd) qd as the sim computes it (the same central differences)."""
    d = env.chain[0].dof
    c_own = env.velocity_torque
    work = (
        env.frame_pos, env.frame_angle, env.jac, env.gravity_step, env.mass_plus, env.mass_minus,
        env.q_step,
    )  # fmt: skip
    velocity_product_torque_into(env.chain, u.q, u.qd, VELOCITY_TORQUE_STEP, work, c_own)
    # its scale: its own largest entry, or D's largest entry times the largest rate squared
    scale = 0.0
    qd_max = 0.0
    mass_max = 0.0
    for a in range(d):
        scale = max(scale, abs(c_own[a]))
        qd_max = max(qd_max, abs(u.qd[a]))
        for b in range(d):
            mass_max = max(mass_max, abs(env.mass[a, b]))
    scale = max(scale, mass_max * qd_max * qd_max) + 1e-12
    for a in range(d):
        if _differs(u.velocity_torque[a], c_own[a], VELOCITY_TORQUE_TOLERANCE * scale):
            return Reason.INCONSISTENT
    return 0


@njit(cache=True)
def _check_jump(u, prev, env):
    """While updates flow: the tool moved no farther than its speed bound allows since the
    previous update, and the sequence advanced no faster than the sim's rate."""
    period = env.sim_period_s
    sim_dt = u.sim_time - prev.sim_time
    if not sim_dt > 0.0:
        return Reason.JUMP
    published_dt = max(0.0, (u.publish_time_ns - prev.publish_time_ns) / 1e9)
    dt = min(sim_dt, published_dt + period) + period
    moved = math.hypot(u.tool_pose[0] - prev.tool_pose[0], u.tool_pose[1] - prev.tool_pose[1])
    turned = abs(u.tool_pose[2] - prev.tool_pose[2])
    linear = moved / (env.max_speed * dt + JUMP_SLACK)
    angular = turned / (env.max_angular_speed * dt + JUMP_SLACK)
    env.ratios[RATIO_JUMP] = max(linear, angular)
    if linear > 1.0 or angular > 1.0:
        return Reason.JUMP
    if u.seq - prev.seq > dt / period + 1.0:
        return Reason.JUMP
    return 0
