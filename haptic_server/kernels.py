"""The haptic tick: local model, joint penalties and device control as numba kernels.

`haptic_tick` is the per-tick entry point (DESIGN §4). It reads the installed local model
(two slots: the newest and the one it is cross-faded from), the gains, the proxy state, a
device reading and the measured hand wrench; it integrates the proxy, resolves colliding
contacts by impulses, and writes the wrench to command plus its parts into the log row.
Everything here is a pure function over preallocated arrays: no I/O, clocks or allocation.
"""

from __future__ import annotations

import math

from numba import njit

from device_models.world_map import (
    map_command_to_device,
    map_rate_step,
    map_sensors_to_world,
    map_wrench_to_world,
)
from haptic_server.layout import (
    FAULT_NONFINITE,
    METHOD_IMPEDANCE_ONLY,
    METHOD_LOCAL_MODEL,
    METHOD_VIRTUAL_COUPLING,
    METHOD_VIRTUAL_COUPLING_FOH,
)
from shared.kinematics import link_frames, point_jacobian, point_on_link
from shared.linalg import cholesky_inplace, cholesky_solve
from shared.wire import R_SIZE, REASONS, parse_update


@njit(cache=True)
def nnls(a, m, b, lam, passive, z, w, sys_m, rhs, chol):
    """Lawson-Hanson non-negative least squares: min |A lam - b|, lam >= 0 (m x m, m small).

    The inner least-squares problems are solved through the normal equations with a ridge
    of 1e-12 trace(A^T A) so rank-deficient contact sets (more contacts than DOFs) behave.
    """
    for i in range(m):
        lam[i] = 0.0
        passive[i] = 0
    ridge = 0.0
    for i in range(m):
        for k in range(m):
            ridge += a[k, i] * a[k, i]
    ridge = 1e-12 * ridge + 1e-300
    for _outer in range(3 * m + 3):
        # gradient w = A^T (b - A lam)
        for i in range(m):
            r = 0.0
            for k in range(m):
                res = b[k]
                for j in range(m):
                    res -= a[k, j] * lam[j]
                r += a[k, i] * res
            w[i] = r
        best = -1
        best_w = 1e-14
        for i in range(m):
            if passive[i] == 0 and w[i] > best_w:
                best_w = w[i]
                best = i
        if best < 0:
            return
        passive[best] = 1
        for _inner in range(3 * m + 3):
            # z = argmin over the passive set (others zero)
            for i in range(m):
                for j in range(m):
                    v = 0.0
                    if passive[i] == 1 and passive[j] == 1:
                        for k in range(m):
                            v += a[k, i] * a[k, j]
                    sys_m[i, j] = v
                sys_m[i, i] += ridge if passive[i] == 1 else 1.0
                v = 0.0
                if passive[i] == 1:
                    for k in range(m):
                        v += a[k, i] * b[k]
                rhs[i] = v
            cholesky_inplace(sys_m, m, chol)
            cholesky_solve(chol, m, rhs, z)
            ok = True
            for i in range(m):
                if passive[i] == 1 and z[i] <= 0.0:
                    ok = False
            if ok:
                for i in range(m):
                    lam[i] = z[i] if passive[i] == 1 else 0.0
                break
            alpha = 1.0
            for i in range(m):
                if passive[i] == 1 and z[i] <= 0.0:
                    denom = lam[i] - z[i]
                    if denom > 0.0:
                        alpha = min(alpha, lam[i] / denom)
            for i in range(m):
                lam[i] = lam[i] + alpha * (z[i] - lam[i]) if passive[i] == 1 else 0.0
                if passive[i] == 1 and lam[i] <= 1e-15:
                    passive[i] = 0
                    lam[i] = 0.0


# ---------------------------------------------------------------- stages


@njit(cache=True)
def contact_stage(slot, weight, newest, params, state, ws, dt):
    """Penalty + friction of continuous contacts (seed 001 eq 8) and collision detection.

    Accumulates weight * J_c^T F into ws.tau_contact and the contact stiffness and damping
    into ws.stiff_q / ws.damp_q (for the implicit proxy step). Colliding contacts of the
    newest slot are queued in ws.coll_* for the impulse stage. Returns the active count.
    """
    d = slot.dof
    active = 0
    for i in range(slot.n_contacts):
        link = slot.c_link[i]
        point_on_link(ws.frame_pos, ws.frame_angle, link, slot.c_tool[i], ws.point)
        px = ws.point[0]
        py = ws.point[1]
        point_jacobian(slot.joint_types, ws.frame_pos, d, link, px, py, ws.jac_point)
        nx = slot.c_normal[i, 0]
        ny = slot.c_normal[i, 1]
        tx = -ny
        ty = nx
        ex = slot.c_env[i, 0] + slot.c_env_velocity[i, 0] * slot.age_s
        ey = slot.c_env[i, 1] + slot.c_env_velocity[i, 1] * slot.age_s
        gap = nx * (px - ex) + ny * (py - ey)
        vx = -slot.c_env_velocity[i, 0]
        vy = -slot.c_env_velocity[i, 1]
        for j in range(d):
            vx += ws.jac_point[0, j] * state.qd[j]
            vy += ws.jac_point[1, j] * state.qd[j]
        vn = nx * vx + ny * vy
        vt = tx * vx + ty * vy
        if gap > 0.0:
            slot.c_in_contact[i] = 0
            slot.c_stick[i] = 0.0
            continue
        active += 1
        k_n = slot.c_stiffness[i]
        b_n = slot.c_damping[i]
        if (
            newest
            and slot.c_in_contact[i] == 0
            and params.impulses == 1
            and vn < -params.collision_speed
            and ws.n_colliding < ws.coll_target.shape[0]
        ):
            c = ws.n_colliding
            for j in range(d):
                ws.coll_rows[c, j] = nx * ws.jac_point[0, j] + ny * ws.jac_point[1, j]
            ws.coll_target[c] = -(1.0 + slot.c_restitution[i]) * vn
            ws.coll_index[c] = i
            ws.n_colliding = c + 1
        if slot.c_in_contact[i] == 0:
            slot.c_stick[i] = 0.0
        slot.c_in_contact[i] = 1
        f_n = k_n * (-gap) - b_n * vn
        if f_n < 0.0:
            f_n = 0.0
        k_t = params.friction_stiffness_ratio * k_n
        slot.c_stick[i] += vt * dt
        f_t = -k_t * slot.c_stick[i] - b_n * vt
        limit = slot.c_friction[i] * f_n
        sticking = True
        if abs(f_t) > limit:
            f_t = limit if f_t > 0.0 else -limit
            slot.c_stick[i] = -f_t / k_t if k_t > 0.0 else 0.0
            sticking = False
        fx = f_n * nx + f_t * tx
        fy = f_n * ny + f_t * ty
        ws.contact_force[0] += weight * fx
        ws.contact_force[1] += weight * fy
        kt_eff = k_t if sticking else 0.0
        for a in range(d):
            ja_n = nx * ws.jac_point[0, a] + ny * ws.jac_point[1, a]
            ja_t = tx * ws.jac_point[0, a] + ty * ws.jac_point[1, a]
            ws.tau_contact[a] += weight * (ws.jac_point[0, a] * fx + ws.jac_point[1, a] * fy)
            if f_n > 0.0:
                # stiffness times the relative velocity: the implicit step's correction
                ws.stiff_rel[a] += weight * (k_n * ja_n * vn + kt_eff * ja_t * vt)
                for b in range(d):
                    jb_n = nx * ws.jac_point[0, b] + ny * ws.jac_point[1, b]
                    jb_t = tx * ws.jac_point[0, b] + ty * ws.jac_point[1, b]
                    ws.stiff_q[a, b] += weight * (k_n * ja_n * jb_n + kt_eff * ja_t * jb_t)
                    ws.damp_q[a, b] += weight * b_n * (ja_n * jb_n + ja_t * jb_t)
    return active


@njit(cache=True)
def impulse_stage(d, state, ws):
    """All colliding contacts of a tick resolved together (DESIGN §4.1).

    lambda >= 0 is the least-squares solution of (J_n D^-1 J_n^T) lambda = v+ - v-;
    the proxy gets dqd = D^-1 J_n^T lambda at once and ws.impulse_q = J_n^T lambda = P_cs.
    """
    m = ws.n_colliding
    for a in range(d):
        ws.impulse_q[a] = 0.0
    if m == 0:
        return
    # rows of D^-1 J_n^T, one per colliding contact, via the Cholesky factor of D
    for c in range(m):
        for a in range(d):
            ws.vec_a[a] = ws.coll_rows[c, a]
        cholesky_solve(ws.chol, d, ws.vec_a, ws.vec_b)
        for r in range(m):
            v = 0.0
            for a in range(d):
                v += ws.coll_rows[r, a] * ws.vec_b[a]
            ws.nnls_a[r, c] = v
    nnls(
        ws.nnls_a, m, ws.coll_target, ws.nnls_lambda, ws.nnls_passive, ws.nnls_z, ws.nnls_w,
        ws.nnls_m, ws.nnls_rhs, ws.nnls_chol,
    )  # fmt: skip
    for a in range(d):
        v = 0.0
        for c in range(m):
            v += ws.coll_rows[c, a] * ws.nnls_lambda[c]
        ws.impulse_q[a] = v
    cholesky_solve(ws.chol, d, ws.impulse_q, ws.vec_b)
    for a in range(d):
        state.qd[a] += ws.vec_b[a]


@njit(cache=True)
def blend_mass_and_gravity(new, old, alpha, d, ws):
    """Cross-fade the frozen D^ and bias G^ + C^qd of the two slots into ws.mass and
    ws.tau_total (as -bias)."""
    for a in range(d):
        g = 0.0
        if new.has_gravity == 1:
            g += alpha * new.gravity[a]
        if new.has_velocity_torque == 1:
            g += alpha * new.velocity_torque[a]
        if old.valid == 1 and alpha < 1.0 and old.dof == d:
            if old.has_gravity == 1:
                g += (1.0 - alpha) * old.gravity[a]
            if old.has_velocity_torque == 1:
                g += (1.0 - alpha) * old.velocity_torque[a]
        ws.tau_total[a] = -g
        for b in range(d):
            v = new.mass[a, b]
            if old.valid == 1 and alpha < 1.0 and old.dof == d:
                v = alpha * v + (1.0 - alpha) * old.mass[a, b]
            ws.mass[a, b] = v


@njit(cache=True)
def _mat3_vec(m, v0, v1, v2, out, scale):
    for r in range(3):
        out[r] = scale * (m[r, 0] * v0 + m[r, 1] * v1 + m[r, 2] * v2)


@njit(cache=True)
def haptic_tick(slots, params, state, sensors, hand_measured, dt, ws, row):
    """One tick of the local model and device control (DESIGN §4; seed 000 eq 11, 17, 18, 21).

    slots: SLOT_DTYPE[2] (0 newest, 1 fading out); params: PARAMS_DTYPE[1];
    state: STATE_DTYPE[1]; sensors: device SENSOR_DTYPE[1] in world frame;
    hand_measured: (3,) measured hand wrench; ws: SCRATCH_DTYPE[1]; row: TICK_DTYPE[1].
    Writes the wrench to command into row.wrench_command.
    """
    new = slots[0]
    old = slots[1]
    p = params[0]
    st = state[0]
    sen = sensors[0]
    w = ws[0]
    r = row[0]
    d = new.dof
    method = p.method

    alpha = 1.0
    if old.valid == 1 and p.blend_s > 0.0 and st.blend < 1.0:
        alpha = st.blend
    st.blend = min(1.0, st.blend + (dt / p.blend_s if p.blend_s > 0.0 else 1.0))

    # kinematics at the proxy configuration
    link_frames(
        new.joint_types, new.lengths, new.base, new.base_angle, st.q, d, w.frame_pos, w.frame_angle
    )
    point_on_link(w.frame_pos, w.frame_angle, new.op_link, new.op_point, w.point)
    hx = w.point[0]
    hy = w.point[1]
    point_jacobian(new.joint_types, w.frame_pos, d, new.op_link, hx, hy, w.jac_hand)
    x_vm0 = hx
    x_vm1 = hy
    x_vm2 = w.frame_angle[new.op_link]
    xd_vm0 = 0.0
    xd_vm1 = 0.0
    xd_vm2 = 0.0
    for j in range(d):
        xd_vm0 += w.jac_hand[0, j] * st.qd[j]
        xd_vm1 += w.jac_hand[1, j] * st.qd[j]
        xd_vm2 += w.jac_hand[2, j] * st.qd[j]

    blend_mass_and_gravity(new, old, alpha, d, w)
    ok = cholesky_inplace(w.mass, d, w.chol)

    # contact stage: penalties, friction, and collisions of the newest geometry
    for a in range(d):
        w.tau_contact[a] = 0.0
        w.stiff_rel[a] = 0.0
        for b in range(d):
            w.stiff_q[a, b] = 0.0
            w.damp_q[a, b] = 0.0
    w.n_colliding = 0
    w.contact_force[0] = 0.0
    w.contact_force[1] = 0.0
    active = 0
    ran = 0
    if new.n_contacts > 0:
        active += contact_stage(new, alpha, True, p, st, w, dt)
        ran = 1
    if old.valid == 1 and alpha < 1.0 and old.n_contacts > 0 and old.dof == d:
        contact_stage(old, 1.0 - alpha, False, p, st, w, dt)  # fading out: not counted
        ran = 1
    new.age_s += dt
    old.age_s += dt
    if method == METHOD_VIRTUAL_COUPLING_FOH:
        w.n_colliding = 0
    impulse_stage(d, st, w)

    # D^-1 J_h^T (d x 3) and Lambda^-1 = J_h D^-1 J_h^T
    for c in range(3):
        for a in range(d):
            w.vec_a[a] = w.jac_hand[c, a]
        cholesky_solve(w.chol, d, w.vec_a, w.vec_b)
        for a in range(d):
            w.minv_jt[a, c] = w.vec_b[a]
    for rr in range(3):
        for c in range(3):
            v = 0.0
            for a in range(d):
                v += w.jac_hand[rr, a] * w.minv_jt[a, c]
            w.lambda_inv[rr, c] = v

    xh0 = sen.pose[0]
    xh1 = sen.pose[1]
    xh2 = sen.pose[2]
    vh0 = sen.twist[0]
    vh1 = sen.twist[1]
    vh2 = sen.twist[2]
    e0 = x_vm0 - xh0
    e1 = x_vm1 - xh1
    e2 = x_vm2 - xh2
    ed0 = xd_vm0 - vh0
    ed1 = xd_vm1 - vh1
    ed2 = xd_vm2 - vh2
    M = sen.inertia
    f_h0 = hand_measured[0]
    f_h1 = hand_measured[1]
    f_h2 = hand_measured[2]

    n_res = new.n_resisted
    if old.valid == 1 and alpha < 1.0 and old.n_resisted > n_res:
        n_res = old.n_resisted
    r.n_resisted = n_res
    for c in range(3):
        r.f_user[c] = 0.0
        r.f_contact[c] = 0.0
        r.f_impulse[c] = 0.0
        r.f_bias[c] = 0.0
        r.f_penalty[c] = 0.0
        r.f_coordination[c] = 0.0
        r.f_damping[c] = 0.0

    # generalized force on the proxy from the coupling (its stiffness goes into the implicit step)
    if method == METHOD_VIRTUAL_COUPLING:
        kc = p.vc_stiffness
        bc = p.vc_damping
    else:
        kc = p.coordination_stiffness
        bc = p.coordination_damping
    fc0 = kc[0] * e0 + bc[0] * ed0
    fc1 = kc[1] * e1 + bc[1] * ed1
    fc2 = kc[2] * e2 + bc[2] * ed2
    if method == METHOD_VIRTUAL_COUPLING:
        pull0, pull1, pull2 = -fc0, -fc1, -fc2
    else:
        pull0, pull1, pull2 = f_h0 - fc0, f_h1 - fc1, f_h2 - fc2

    if method == METHOD_VIRTUAL_COUPLING_FOH:
        # seed 002 §4: the device is servoed to a setpoint that follows the sim's tool by
        # first-order hold; force is off while the tool touches nothing. K_v damps the
        # handle's own motion: the world twist less the workspace's (rate control).
        moving = st.foh_steps_left > 0
        if moving:
            for c in range(3):
                st.foh_goal[c] += st.foh_step[c]
            st.foh_steps_left -= 1
        for c in range(3):
            r.vm_twist[c] = st.foh_step[c] / dt if moving else 0.0
        if new.tool_touching == 1:
            for c in range(3):
                r.f_coordination[c] = p.foh_stiffness[c] * (
                    st.foh_goal[c] - sen.pose[c]
                ) - p.foh_damping[c] * (sen.twist[c] - sen.frame_twist[c])
        for c in range(3):
            r.f_bias[c] = p.foh_gravity[c]  # f_g, always on
    elif method == METHOD_VIRTUAL_COUPLING:
        r.f_coordination[0] = fc0
        r.f_coordination[1] = fc1
        r.f_coordination[2] = fc2
    else:
        # seed 000 eq 11 / 18 with the four-channel coordination wrench
        li = w.lambda_inv
        # A = M_d Lambda^-1 (3x3)
        for rr in range(3):
            for c in range(3):
                w.system[rr, c] = M[rr, 0] * li[0, c] + M[rr, 1] * li[1, c] + M[rr, 2] * li[2, c]
        A = w.system
        _mat3_vec(A, f_h0, f_h1, f_h2, r.f_user, 1.0)
        r.f_user[0] -= f_h0
        r.f_user[1] -= f_h1
        r.f_user[2] -= f_h2
        _mat3_vec(A, fc0, fc1, fc2, r.f_coordination, 1.0)
        # accelerations at the hand due to configuration-space torques: J_h D^-1 tau
        acc_c0 = 0.0
        acc_c1 = 0.0
        acc_c2 = 0.0
        acc_g0 = 0.0
        acc_g1 = 0.0
        acc_g2 = 0.0
        acc_i0 = 0.0
        acc_i1 = 0.0
        acc_i2 = 0.0
        for a in range(d):
            acc_c0 += w.minv_jt[a, 0] * w.tau_contact[a]
            acc_c1 += w.minv_jt[a, 1] * w.tau_contact[a]
            acc_c2 += w.minv_jt[a, 2] * w.tau_contact[a]
            acc_g0 += w.minv_jt[a, 0] * w.tau_total[a]
            acc_g1 += w.minv_jt[a, 1] * w.tau_total[a]
            acc_g2 += w.minv_jt[a, 2] * w.tau_total[a]
            acc_i0 += w.minv_jt[a, 0] * w.impulse_q[a] / dt
            acc_i1 += w.minv_jt[a, 1] * w.impulse_q[a] / dt
            acc_i2 += w.minv_jt[a, 2] * w.impulse_q[a] / dt
        _mat3_vec(M, acc_c0, acc_c1, acc_c2, r.f_contact, 1.0)
        _mat3_vec(M, acc_g0, acc_g1, acc_g2, r.f_bias, 1.0)
        _mat3_vec(M, acc_i0, acc_i1, acc_i2, r.f_impulse, 1.0)
        # what the device limits kept back of earlier impulses is delivered now
        for c in range(3):
            r.f_impulse[c] += st.impulse_carry[c] / dt
            st.impulse_carry[c] = 0.0
        # (C_d - M_d L^-1 b_d) xd_h - M_d L^-1 k_d x_h
        bd = p.desired_damping
        kd = p.desired_stiffness
        _mat3_vec(
            A,
            bd[0] * vh0 + kd[0] * xh0,
            bd[1] * vh1 + kd[1] * xh1,
            bd[2] * vh2 + kd[2] * xh2,
            r.f_damping,
            -1.0,
        )
        C = sen.coriolis
        for rr in range(3):
            r.f_damping[rr] += C[rr, 0] * vh0 + C[rr, 1] * vh1 + C[rr, 2] * vh2
        # joint-constraint penalties along the resisted directions (seed 000 eq 17)
        if method == METHOD_LOCAL_MODEL and n_res > 0:
            kj = p.penalty_stiffness
            bj = p.penalty_damping
            s0 = kj * e0 + bj * ed0
            s1 = kj * e1 + bj * ed1
            s2 = kj * e2 + bj * ed2
            for rr in range(3):
                v = 0.0
                for c in range(3):
                    proj = alpha * new.penalty_projection[rr, c]
                    if old.valid == 1 and alpha < 1.0:
                        proj += (1.0 - alpha) * old.penalty_projection[rr, c]
                    s = s0 if c == 0 else (s1 if c == 1 else s2)
                    v += proj * s
                w.vec_a[rr] = v
            _mat3_vec(M, w.vec_a[0], w.vec_a[1], w.vec_a[2], r.f_penalty, 1.0)

    # proxy dynamics (seed 000 eq 21), linearly implicit in the contact springs (which move
    # with the environment) and in the coupling to the device (which moves with the device):
    # K, B are their configuration-space stiffness and damping. The device's velocity over
    # the step is predicted from its last acceleration, so a proxy and a device accelerating
    # together take identical steps (no lag between them), while stiff couplings on light
    # tools stay stable. (D + dt B + dt^2 K) dqd = dt (f - dt K v_rel + J^T (B_c + dt K_c) dt a_h)
    acc_h0 = (vh0 - st.prev_device_twist[0]) / dt
    acc_h1 = (vh1 - st.prev_device_twist[1]) / dt
    acc_h2 = (vh2 - st.prev_device_twist[2]) / dt
    st.prev_device_twist[0] = vh0
    st.prev_device_twist[1] = vh1
    st.prev_device_twist[2] = vh2
    if method != METHOD_VIRTUAL_COUPLING_FOH and ok:
        g0 = (bc[0] + dt * kc[0]) * dt * acc_h0 - dt * kc[0] * ed0
        g1 = (bc[1] + dt * kc[1]) * dt * acc_h1 - dt * kc[1] * ed1
        g2 = (bc[2] + dt * kc[2]) * dt * acc_h2 - dt * kc[2] * ed2
        for a in range(d):
            v = w.tau_contact[a] + w.tau_total[a] - dt * w.stiff_rel[a]
            v += (
                w.jac_hand[0, a] * (pull0 + g0)
                + w.jac_hand[1, a] * (pull1 + g1)
                + w.jac_hand[2, a] * (pull2 + g2)
            )
            w.vec_a[a] = dt * v
            for b in range(d):
                kq = 0.0
                for c in range(3):
                    kq += w.jac_hand[c, a] * (bc[c] + dt * kc[c]) * w.jac_hand[c, b]
                w.system[a, b] = (
                    w.mass[a, b] + dt * (w.damp_q[a, b] + kq) + dt * dt * w.stiff_q[a, b]
                )
        if cholesky_inplace(w.system, d, w.chol):
            cholesky_solve(w.chol, d, w.vec_a, w.vec_b)
            for a in range(d):
                st.qd[a] += w.vec_b[a]
                st.q[a] += dt * st.qd[a]

    # total, safe-state blend, limits, NaN guard
    step = dt / p.safe_ramp_s
    if st.safe < st.safe_target:
        st.safe = min(st.safe_target, st.safe + step)
    elif st.safe > st.safe_target:
        st.safe = max(st.safe_target, st.safe - step)
    finite = ok
    for c in range(3):
        u = (
            r.f_user[c] + r.f_contact[c] + r.f_impulse[c] + r.f_bias[c] + r.f_penalty[c]
            + r.f_coordination[c] + r.f_damping[c]
        )  # fmt: skip
        u_safe = -p.safe_damping[c] * (sen.twist[c] - sen.frame_twist[c])
        if not math.isfinite(u_safe):
            u_safe = 0.0
        if not math.isfinite(u):
            finite = False
        v = (1.0 - st.safe) * u + st.safe * u_safe
        lim = p.max_wrench[c]
        clipped = min(lim, max(-lim, v))
        # an impulse clipped at the device limit is not lost: the rest is carried to the next
        # ticks, so the device still receives the momentum change (seed 001 eq 7)
        f_imp = r.f_impulse[c]
        excess = v - clipped
        if st.safe == 0.0 and f_imp != 0.0 and excess * f_imp > 0.0:
            st.impulse_carry[c] = math.copysign(min(abs(excess), abs(f_imp)), f_imp) * dt
        r.wrench_command[c] = clipped
    for a in range(d):
        if not (math.isfinite(st.q[a]) and math.isfinite(st.qd[a])):
            finite = False
    if not finite:
        st.fault = FAULT_NONFINITE
        st.safe = 1.0
        st.safe_target = 1.0
        for c in range(3):
            u_safe = -p.safe_damping[c] * (sen.twist[c] - sen.frame_twist[c])
            if not math.isfinite(u_safe):
                u_safe = 0.0
            lim = p.max_wrench[c]
            r.wrench_command[c] = min(lim, max(-lim, u_safe))

    # log row (virtual_coupling_foh: the VM is the sim's tool, seen through the setpoint)
    if method == METHOD_VIRTUAL_COUPLING_FOH:
        for c in range(3):
            r.vm_pose[c] = st.foh_goal[c]
    else:
        r.vm_pose[0] = x_vm0
        r.vm_pose[1] = x_vm1
        r.vm_pose[2] = x_vm2
        r.vm_twist[0] = xd_vm0
        r.vm_twist[1] = xd_vm1
        r.vm_twist[2] = xd_vm2
    for c in range(3):
        r.device_pose[c] = sen.pose[c]
        r.device_twist[c] = sen.twist[c]
        r.hand_wrench_measured[c] = hand_measured[c]
    for a in range(d):
        r.proxy_q[a] = st.q[a]
        r.proxy_qd[a] = st.qd[a]
    r.contact_force_world[0] = w.contact_force[0]
    r.contact_force_world[1] = w.contact_force[1]
    r.n_contacts = new.n_contacts
    r.n_active = active
    r.n_colliding = w.n_colliding
    r.contact_stage = ran
    r.safe = st.safe
    r.fault = st.fault
    r.dt = dt


@njit(cache=True)
def begin_tick(sensors, world_map, hand, tick, t, world_sensors, hand_measured, row):
    """Device reading -> world frame through the device-to-world map; start the log row."""
    map_sensors_to_world(world_map, sensors, world_sensors)
    m = world_map[0]
    src = sensors[0]
    dst = world_sensors[0]
    r = row[0]
    for c in range(3):
        hand_measured[c] = dst.hand_wrench[c]
        r.hand_wrench[c] = hand[c] / (m.force_scale * m.scale[c])
        r.wrench_command[c] = 0.0
        r.world_offset[c] = m.offset[c]
    for k in range(r.device_aux.shape[0]):
        r.device_aux[k] = src.aux[k]
    r.tick = tick
    r.t = t
    r.device_fault = src.fault


@njit(cache=True)
def engine_step(
    sensors, world_map, hand, tick, t, world_sensors, hand_measured, slots, params, state, dt,
    ws, row, ready, lateness_us, work_us, update_seq, update_age_ms, device_limits,
    device_command,
):  # fmt: skip
    """One tick in one Python -> numba transition: the reading mapped to the world, the
    local model and control (haptic_tick), the command mapped back to the device frame and
    clipped at the device's limits, then the map's rate-control step (seed 002 §4)."""
    begin_tick(sensors, world_map, hand, tick, t, world_sensors, hand_measured, row)
    r = row[0]
    r.lateness_us = lateness_us
    r.work_us = work_us
    r.update_seq = update_seq
    r.update_age_ms = update_age_ms
    r.update_epoch = slots[0].epoch
    r.dof = slots[0].dof
    r.dt = dt
    if ready:
        haptic_tick(slots, params, state, world_sensors, hand_measured, dt, ws, row)
    map_command_to_device(world_map, r.wrench_command, device_limits, device_command)
    map_rate_step(world_map, sensors[0].pose, dt)


@njit(cache=True)
def store_applied(world_map, applied, row):
    """The wrench the device reports it applied (device frame), into the row (world frame)."""
    map_wrench_to_world(world_map, applied, row[0].wrench_applied)


# the engine's order record: the installed model's epoch and seq, whether one is installed,
# whether the last install began a new epoch, how many were installed, and whether every
# install needs the engine's Python side (after the watchdog fired, or for FOH setpoints)
ORDER_EPOCH, ORDER_SEQ, ORDER_READY, ORDER_NEW_EPOCH, ORDER_INSTALLED, ORDER_FOLLOW = range(6)
ORDER_SIZE = 6
R_STALE_EPOCH, R_SEQUENCE, R_DOF_CHANGE = 16, 17, 18
ORDER_REASONS = {R_STALE_EPOCH: "epoch", R_SEQUENCE: "sequence", R_DOF_CHANGE: "dof"}


def reason_of(code: int) -> str:
    """A verdict code (from parse_update or accept_update) as its reason tag."""
    return ORDER_REASONS.get(code) or (REASONS[code] if 0 <= code < len(REASONS) else "size")


@njit(cache=True)
def accept_update(
    buf, nbytes, limits, parsed, scratch, slots, state, order, match_radius, latency_s
):
    """Parse, validate, order-check and install an update: 0, or the reason code.

    order (ORDER_*): an older epoch or a repeated sequence number is rejected (DESIGN §3); a
    new epoch is installed without cross-fade. nbytes < 0 or beyond the buffer is a message
    too large for it (the I/O process's mailbox marks one so): rejected as R_SIZE.
    """
    if nbytes < 0 or nbytes > buf.shape[0]:
        return R_SIZE
    code = parse_update(buf, nbytes, limits, parsed, scratch)
    if code != 0:
        return code
    m = parsed[0]
    if m.epoch < order[ORDER_EPOCH]:
        return R_STALE_EPOCH
    new_epoch = m.epoch != order[ORDER_EPOCH]
    if not new_epoch and m.seq <= order[ORDER_SEQ]:
        return R_SEQUENCE
    if not new_epoch and order[ORDER_READY] == 1 and m.dof != slots[0].dof:
        return R_DOF_CHANGE
    m.age_s += latency_s  # it travelled this long: moving contacts have moved on
    install_update(parsed, slots, state, new_epoch, match_radius)
    order[ORDER_EPOCH] = m.epoch
    order[ORDER_SEQ] = m.seq
    order[ORDER_READY] = 1
    order[ORDER_NEW_EPOCH] = 1 if new_epoch else 0
    order[ORDER_INSTALLED] += 1
    return 0


@njit(cache=True)
def install_update(parsed, slots, state, new_epoch, match_radius):
    """Make a parsed model the newest slot; the previous one fades out over blend_s."""
    if new_epoch:
        slots[1].valid = 0
    else:
        slots[1] = slots[0]
    slots[0] = parsed[0]
    inherit_contact_state(slots[0], slots[1], match_radius)
    state[0].blend = 1.0 if slots[1].valid == 0 else 0.0


@njit(cache=True)
def store_row(rows, k, row):
    """rows[k] = row[0] (a numpy record copy costs 2 us from Python)."""
    rows[k] = row[0]


@njit(cache=True)
def inherit_contact_state(new, old, match_radius):
    """Carry contact state (in contact, stick displacement) from the previous model to the
    new one for contacts with the same key whose tool points lie within match_radius."""
    for i in range(new.n_contacts):
        new.c_in_contact[i] = 0
        new.c_stick[i] = 0.0
        if old.valid != 1:
            continue
        best = -1
        best_d = match_radius * match_radius
        for k in range(old.n_contacts):
            if old.c_key[k] != new.c_key[i] or old.c_link[k] != new.c_link[i]:
                continue
            dx = old.c_tool[k, 0] - new.c_tool[i, 0]
            dy = old.c_tool[k, 1] - new.c_tool[i, 1]
            dd = dx * dx + dy * dy
            if dd <= best_d:
                best_d = dd
                best = k
        if best >= 0:
            new.c_in_contact[i] = old.c_in_contact[best]
            new.c_stick[i] = old.c_stick[best]


__all__ = [
    "METHOD_IMPEDANCE_ONLY",
    "haptic_tick",
    "inherit_contact_state",
    "nnls",
]
