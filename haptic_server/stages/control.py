"""The control law: one function per rendering method, chosen once per tick by `control`.

Each writes the wrench's parts into the log row (f_user, f_contact, f_impulse, f_bias,
f_penalty, f_coordination, f_damping: their sum is the command before the safety stage)
and scratch.pull, the task-space force the proxy step applies to the proxy.
"""

from __future__ import annotations

from numba import njit

from haptic_local_model.haptic_server.stages.kinematics import fading
from haptic_local_model.shared.kinematics import point_bias_acceleration
from haptic_local_model.shared.linalg import cholesky_inplace, cholesky_solve
from haptic_local_model.shared.protocol.codes import Method


@njit(cache=True)
def mat3_vec(a, v, out, scale):
    """out = scale * (a v) for a 3x3 a (the sum in the order of the original unrolled form)."""
    for r in range(3):
        out[r] = scale * (a[r, 0] * v[0] + a[r, 1] * v[1] + a[r, 2] * v[2])


@njit(cache=True)
def effective_device_twist(m, d):
    """The device's twist as if the impulse it still owes were delivered:
    xd_h + M_d^-1 impulse_carry (impulse_law 2). A device that cannot stop in one tick is
    moving faster than the VM it follows only by that carry, which the next ticks deliver;
    the coordination coupling sees the effective twist, so it neither brakes the device a
    second time nor drags the VM back into the surface it was stopped at."""
    w = d.scratch
    sen = d.sensors[0]
    carry = d.state.impulse_carry
    for c in range(3):
        w.device_twist_eff[c] = sen.twist[c]
    if m.params.impulse_law != 2 or (carry[0] == 0.0 and carry[1] == 0.0 and carry[2] == 0.0):
        return
    if not cholesky_inplace(sen.inertia, 3, w.inertia_chol):
        return
    cholesky_solve(w.inertia_chol, 3, carry, w.carry_velocity)
    for c in range(3):
        w.device_twist_eff[c] += w.carry_velocity[c]


@njit(cache=True)
def coupling_errors(m, d):
    """e = x_VM - x_h, ed = xd_VM - xd_h (the device's effective twist), the device-proxy
    coupling force K e + B ed, the resisted directions in force this tick; the row's force
    parts start at zero."""
    p = m.params
    w = d.scratch
    sen = d.sensors[0]
    r = d.row
    effective_device_twist(m, d)
    for c in range(3):
        w.e[c] = w.x_vm[c] - sen.pose[c]
        w.ed[c] = w.xd_vm[c] - w.device_twist_eff[c]
        w.f_coupling[c] = p.coupling_stiffness[c] * w.e[c] + p.coupling_damping[c] * w.ed[c]
    n_res = m.slots[0].n_resisted
    old = m.slots[1]
    if fading(m, d) and old.n_resisted > n_res:
        n_res = old.n_resisted
    w.n_resisted = n_res
    r.n_resisted = n_res
    clear_command_terms(r)


@njit(cache=True)
def clear_command_terms(r):
    """The row's command terms to zero: a law sets those it has (safety_and_limits sums them)."""
    for c in range(3):
        r.f_user[c] = 0.0
        r.f_contact[c] = 0.0
        r.f_impulse[c] = 0.0
        r.f_bias[c] = 0.0
        r.f_penalty[c] = 0.0
        r.f_coordination[c] = 0.0
        r.f_damping[c] = 0.0


@njit(cache=True)
def control(m, d):
    """The method's control law (the one dispatch on the method in a tick)."""
    method = m.params.method
    if method == Method.LOCAL_MODEL:
        control_local_model(m, d)
    elif method == Method.IMPEDANCE_ONLY:
        control_impedance_only(m, d)
    elif method == Method.VIRTUAL_COUPLING:
        control_virtual_coupling(m, d)
    else:
        control_foh(m, d)


@njit(cache=True)
def control_impedance_only(m, d):
    """Seed 000 eq 11 / 18 with the four-channel coordination wrench (DESIGN §4.3):
    u = (M_d L^-1 - I) F_h + M_d J_h D^-1 (tau + P_cs/dt) + M_d J_h_dot qd + M_d L^-1 F_c
        + (C_d - M_d L^-1 b_d) xd_h - M_d L^-1 k_d x_h.
    The M_d J_h_dot qd term (params.jdot_qd) is in f_bias with the torques' part."""
    w = d.scratch
    st = d.state
    sen = d.sensors[0]
    r = d.row
    dt = d.dt
    n = m.slots[0].dof
    M = sen.inertia
    li = w.lambda_inv
    f_h = d.hand_measured
    for c in range(3):
        w.pull[c] = f_h[c] - w.f_coupling[c]
    for rr in range(3):  # A = M_d Lambda^-1
        for c in range(3):
            w.a_task[rr, c] = M[rr, 0] * li[0, c] + M[rr, 1] * li[1, c] + M[rr, 2] * li[2, c]
    mat3_vec(w.a_task, f_h, r.f_user, 1.0)
    for c in range(3):
        r.f_user[c] -= f_h[c]
    mat3_vec(w.a_task, w.f_coupling, r.f_coordination, 1.0)
    # accelerations at the hand due to configuration-space torques: J_h D^-1 tau
    for c in range(3):
        w.acc_contact[c] = 0.0
        w.acc_bias[c] = 0.0
        w.acc_impulse[c] = 0.0
    for a in range(n):
        for c in range(3):
            w.acc_contact[c] += w.minv_jt[a, c] * w.tau_contact[a]
            w.acc_bias[c] += w.minv_jt[a, c] * w.tau_bias[a]
            w.acc_impulse[c] += w.minv_jt[a, c] * w.impulse_q[a] / dt
    if m.params.jdot_qd == 1:
        slot = m.slots[0]
        point_bias_acceleration(
            slot, w.frame_pos, n, slot.op_link, w.op_point[0], w.op_point[1], st.qd, w.jdot_qd
        )
        for c in range(3):
            w.acc_bias[c] += w.jdot_qd[c]
    mat3_vec(M, w.acc_contact, r.f_contact, 1.0)
    mat3_vec(M, w.acc_bias, r.f_bias, 1.0)
    mat3_vec(M, w.acc_impulse, r.f_impulse, 1.0)
    # what the device limits kept back of earlier impulses is delivered now
    for c in range(3):
        r.f_impulse[c] += st.impulse_carry[c] / dt
        st.impulse_carry[c] = 0.0
    # (C_d - M_d L^-1 b_d) xd_h - M_d L^-1 k_d x_h
    bd = m.params.desired_damping
    kd = m.params.desired_stiffness
    for c in range(3):
        w.damping_task[c] = bd[c] * sen.twist[c] + kd[c] * sen.pose[c]
    mat3_vec(w.a_task, w.damping_task, r.f_damping, -1.0)
    C = sen.coriolis
    vh = sen.twist
    for rr in range(3):
        r.f_damping[rr] += C[rr, 0] * vh[0] + C[rr, 1] * vh[1] + C[rr, 2] * vh[2]


@njit(cache=True)
def control_local_model(m, d):
    """Seed 000's law plus the joint-constraint penalties along the resisted directions
    (seed 000 eq 17): M_d sum_i (k_j n_i^T e + b_j n_i^T ed) n_i, cross-faded."""
    control_impedance_only(m, d)
    w = d.scratch
    if w.n_resisted == 0:
        return
    p = m.params
    new = m.slots[0]
    old = m.slots[1]
    alpha = w.alpha
    both = old.valid == 1 and alpha < 1.0
    s0 = p.penalty_stiffness * w.e[0] + p.penalty_damping * w.ed[0]
    s1 = p.penalty_stiffness * w.e[1] + p.penalty_damping * w.ed[1]
    s2 = p.penalty_stiffness * w.e[2] + p.penalty_damping * w.ed[2]
    for rr in range(3):
        v = 0.0
        for c in range(3):
            proj = alpha * new.penalty_projection[rr, c]
            if both:
                proj += (1.0 - alpha) * old.penalty_projection[rr, c]
            s = s0 if c == 0 else (s1 if c == 1 else s2)
            v += proj * s
        w.penalty_task[rr] = v
    mat3_vec(d.sensors[0].inertia, w.penalty_task, d.row.f_penalty, 1.0)


@njit(cache=True)
def control_virtual_coupling(m, d):
    """A spring-damper between device and proxy (DESIGN §4, the seed 000 §VI comparison):
    the device feels F_c, the proxy -F_c."""
    w = d.scratch
    for c in range(3):
        d.row.f_coordination[c] = w.f_coupling[c]
        w.pull[c] = -w.f_coupling[c]


@njit(cache=True)
def control_foh(m, d):
    """Seed 002 §4: the device is servoed to a setpoint that follows the sim's tool by
    first-order hold; force is off while the tool touches nothing (unless
    foh_free_space_force). K_v damps the handle's own motion: the world twist less the
    workspace's (rate control). f_g is always on."""
    p = m.params
    st = d.state
    sen = d.sensors[0]
    r = d.row
    moving = st.foh_steps_left > 0
    if moving:
        for c in range(3):
            st.foh_goal[c] += st.foh_step[c]
        st.foh_steps_left -= 1
    for c in range(3):
        r.vm_twist[c] = st.foh_step[c] / d.dt if moving else 0.0
    if m.slots[0].tool_touching == 1 or p.foh_free_space == 1:
        for c in range(3):
            r.f_coordination[c] = p.foh_stiffness[c] * (
                st.foh_goal[c] - sen.pose[c]
            ) - p.foh_damping[c] * (sen.twist[c] - sen.frame_twist[c])
    for c in range(3):
        r.f_bias[c] = p.foh_gravity[c]
