"""The control law: one function per rendering method, chosen once per tick by `control`.

Each writes the wrench's parts into the log row (f_user, f_contact, f_impulse, f_bias,
f_penalty, f_coordination, f_damping: their sum is the command before the safety stage)
and scratch.pull, the task-space force the proxy step applies to the proxy.
"""

from __future__ import annotations

import math

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
        w.device_pose_eff[c] = sen.pose[c]
    if m.params.impulse_law == 3:
        impact_reference(m, d)
        return
    if m.params.impulse_law != 2 or (carry[0] == 0.0 and carry[1] == 0.0 and carry[2] == 0.0):
        return
    if not cholesky_inplace(sen.inertia, 3, w.inertia_chol):
        return
    cholesky_solve(w.inertia_chol, 3, carry, w.carry_velocity)
    for c in range(3):
        w.device_twist_eff[c] += w.carry_velocity[c]


#: impulse_law 3 (impact_ledger). The share of an impact's momentum change the device gets
#: before the impact: a device stopped at a uniform rate over a window centred on the
#: impact comes to rest where the proxy stopped (half the velocity step before, half after:
#: it lags the proxy by v T / 8 at the impact, T the window, and overshoots it by nothing).
PREPAY_SHARE = 0.5
#: The part of each axis's device limit the payment ahead may take: all of what the law's
#: other terms this tick leave of it in its direction (PREPAY_HEADROOM of it), so the
#: command is not clipped and the device brakes as planned.
PREPAY_HEADROOM = 1.0
#: ... but never less than this part of the limit (what the clip then keeps back of the
#: payment is carried: the ledger stays exact, the window a little off).
PREPAY_ROOM_FLOOR = 0.2
#: A payment begun stays on while the impact is predicted within this many times the time
#: ahead it would begin at (a user slowing down shortens it; no chattering at its edge).
PREPAY_HOLD = 2.0
#: The rate (1/s) at which the device's impact offset returns, critically damped, by
#: feedforward: from the 1.7 mm a 1 kg device at 0.4 m/s overshoots at 50 N to within
#: 5 % of F/K (7 um) in 0.2 s. Its force M_d (w^2 D + 2 w V) is 2.4 N for that overshoot.
RETURN_RATE = 40.0
#: An offset smaller than this (m, rad; and its rate in m/s, rad/s) is returned: zero.
RETURN_FLOOR = 1e-12


@njit(cache=True)
def impact_reference(m, d):
    """impulse_law 3: the device as an unlimited one would be (impact_ledger). Its velocity
    differs from that one's by V = M_d^-1 (prepaid - carry) + impact_offset_rate (what was
    paid ahead of an impact, less what the limits still owe of one, plus what the return
    has not yet removed), and its pose by the offset D, which integrates V. The coupling
    sees pose - D and twist - V (device_pose_eff, device_twist_eff): it neither brakes the
    device's impact nor drags the VM after the displacement the device limits caused."""
    w = d.scratch
    sen = d.sensors[0]
    st = d.state
    owed = False
    for c in range(3):
        w.prepay_task[c] = st.impulse_prepaid[c] - st.impulse_carry[c]
        w.offset_velocity[c] = 0.0
        owed = owed or w.prepay_task[c] != 0.0
    if owed and cholesky_inplace(sen.inertia, 3, w.inertia_chol):
        cholesky_solve(w.inertia_chol, 3, w.prepay_task, w.offset_velocity)
    for c in range(3):
        v = w.offset_velocity[c] + st.impact_offset_rate[c]
        w.offset_velocity[c] = v
        st.impact_offset[c] += v * d.dt
        w.device_twist_eff[c] = sen.twist[c] - v
        w.device_pose_eff[c] = sen.pose[c] - st.impact_offset[c]


@njit(cache=True)
def impact_ledger(m, d, carried):
    """impulse_law 3: the device's share of an impulse it cannot take in one tick.

    The impact predicted (contacts.predict_impact), the device is paid PREPAY_SHARE of its
    momentum change ahead, at a rate that leaves it at the impact (prepay); the impact's
    tick nets what was paid against the impulse (the rest is carried at the limit, as in
    law 2). A prediction that lapses leaves the velocity paid to the return. With nothing
    owed (no carry, nothing paid ahead), the offset D returns by feedforward (return_offset).
    All of it is in f_impulse and clipped and carried with it (stages/safety.py)."""
    w = d.scratch
    st = d.state
    r = d.row
    if w.n_colliding > 0:
        for c in range(3):
            r.f_impulse[c] -= st.impulse_prepaid[c] / d.dt
            st.impulse_prepaid[c] = 0.0
        return
    if prepay(m, d):
        return
    paid = st.impulse_prepaid
    if paid[0] != 0.0 or paid[1] != 0.0 or paid[2] != 0.0:
        # no impact came: the velocity paid is the offset's now, for the return to take back
        if cholesky_inplace(d.sensors[0].inertia, 3, w.inertia_chol):
            cholesky_solve(w.inertia_chol, 3, paid, w.prepay_task)
            for c in range(3):
                st.impact_offset_rate[c] += w.prepay_task[c]
        for c in range(3):
            paid[c] = 0.0
        return
    if not carried:
        return_offset(m, d)


@njit(cache=True)
def prepay_room(m, d, c):
    """What axis c's device limit leaves to a payment in the direction of the predicted
    impulse (scratch.prepay_task) after the law's terms already in the row (the user's,
    contacts', bias and coordination forces): PREPAY_HEADROOM of the limit, less those terms'
    part along the payment (a term against it leaves the whole limit), at least
    PREPAY_ROOM_FLOOR of the limit."""
    r = d.row
    other = r.f_user[c] + r.f_contact[c] + r.f_bias[c] + r.f_coordination[c]
    along = other if d.scratch.prepay_task[c] * other > 0.0 else 0.0
    lim = m.params.max_wrench[c]
    return max(PREPAY_HEADROOM * lim - abs(along), PREPAY_ROOM_FLOOR * lim)


@njit(cache=True)
def lead_time(m, d):
    """How far ahead of the VM (s) the device runs toward the predicted impact: its lead
    along the approach (the coupling's error, -e, taken along the direction of the
    predicted velocity step J_h D^-1 P_pred in scratch.damping_task) over the VM's speed
    along it. 0 without a translational step or an approach."""
    w = d.scratch
    dvx = w.damping_task[0]
    dvy = w.damping_task[1]
    size = math.hypot(dvx, dvy)
    if size == 0.0:
        return 0.0
    ux = -dvx / size  # the direction of the approach
    uy = -dvy / size
    speed = w.xd_vm[0] * ux + w.xd_vm[1] * uy
    if speed <= 0.0:
        return 0.0
    return -(w.e[0] * ux + w.e[1] * uy) / speed


@njit(cache=True)
def braking_only(d):
    """The payment ahead (scratch.prepay_task) cut to what brakes the device's own motion:
    at most the momentum it had along the payment before it (M_d xd_h less what was paid).
    A device at rest, or moving away, that a shape approaches is paid nothing: no force
    from nothing before the contact, and no work into the hand. False when nothing is left."""
    w = d.scratch
    st = d.state
    mat3_vec(d.sensors[0].inertia, d.sensors[0].twist, w.carry_velocity, 1.0)
    size = 0.0
    own = 0.0
    for c in range(3):
        size += w.prepay_task[c] * w.prepay_task[c]
        own -= w.prepay_task[c] * (w.carry_velocity[c] - st.impulse_prepaid[c])
    size = math.sqrt(size)
    if size == 0.0 or own <= 0.0:
        return False
    own /= size  # the momentum the payment opposes, N s
    if own < size:
        for c in range(3):
            w.prepay_task[c] *= own / size
    return True


@njit(cache=True)
def prepay(m, d):
    """The device's share of the predicted impulse, M_d J_h D^-1 P_pred (N s), paid ahead.
    T is the window that pays all of it at PREPAY_HEADROOM of the limits; paying from
    tau = PREPAY_SHARE T before the collision's tick, at that rate, the device comes to
    rest where the VM does. A device running ahead of the VM by lead_time starts that much
    earlier (tau within [0, T]). Each tick pays what leaves tau / T of it paid at the
    collision's tick, its direction kept, within PREPAY_HEADROOM of each limit. Nothing is
    paid when T is a tick or less (the impact's own tick delivers it all): a device that can
    stop within a tick feels no force before the contact. Before it, the device is given at
    most tau / T (PREPAY_SHARE, more by the lead) of the predicted momentum change, within
    the limits, over at most T. Returns whether it paid."""
    w = d.scratch
    st = d.state
    eta = w.impact_eta
    if eta == math.inf or w.mass_ok == 0 or st.safe != 0.0:
        return False  # nothing predicted, or the law not wholly in command
    n = m.slots[0].dof
    for c in range(3):
        v = 0.0
        for a in range(n):
            v += w.minv_jt[a, c] * w.impulse_pred_q[a]
        w.damping_task[c] = v  # J_h D^-1 P_pred (damping_task is free until f_damping)
    mat3_vec(d.sensors[0].inertia, w.damping_task, w.prepay_task, 1.0)
    if not braking_only(d):
        return False
    window = 0.0
    for c in range(3):
        room = prepay_room(m, d, c)
        if room > 0.0:
            window = max(window, abs(w.prepay_task[c]) / room)
    if window <= d.dt:
        return False  # the impact's own tick can deliver it all: nothing is paid before it
    ahead = min(window, max(0.0, PREPAY_SHARE * window + lead_time(m, d)))
    paying = st.impulse_prepaid[0] != 0.0 or st.impulse_prepaid[1] != 0.0
    paying = paying or st.impulse_prepaid[2] != 0.0
    # the window opens on the tick nearest its start (eta is checked once a tick)
    if eta > ahead + 0.5 * d.dt and not (paying and eta <= PREPAY_HOLD * ahead + d.dt):
        return False
    share = ahead / window
    span = max(math.ceil(eta / d.dt), 1.0) * d.dt  # the ticks before the collision's
    scale = 1.0
    for c in range(3):
        f = (share * w.prepay_task[c] - st.impulse_prepaid[c]) / span
        w.prepay_task[c] = f
        room = prepay_room(m, d, c)
        if abs(f) > room:
            scale = min(scale, room / abs(f))
    for c in range(3):
        f = scale * w.prepay_task[c]
        d.row.f_impulse[c] += f
        st.impulse_prepaid[c] += f * d.dt
    return True


@njit(cache=True)
def return_offset(m, d):
    """The impact offset D back to zero, critically damped at RETURN_RATE: the device is
    given M_d A, A = -w^2 D - 2 w V_r, and its offset rate V_r takes A (feedforward: the
    coupling, which sees pose - D, closes the loop on whatever the device did not follow)."""
    st = d.state
    w = d.scratch
    off = st.impact_offset
    rate = st.impact_offset_rate
    big = 0.0
    for c in range(3):
        big = max(big, abs(off[c]), abs(rate[c]))
    if big == 0.0:
        return
    if big < RETURN_FLOOR:
        for c in range(3):
            off[c] = 0.0
            rate[c] = 0.0
        return
    k = RETURN_RATE * RETURN_RATE
    b = 2.0 * RETURN_RATE
    for c in range(3):
        w.damping_task[c] = -k * off[c] - b * rate[c]
        rate[c] += w.damping_task[c] * d.dt
    mat3_vec(d.sensors[0].inertia, w.damping_task, w.prepay_task, 1.0)
    for c in range(3):
        d.row.f_impulse[c] += w.prepay_task[c]


@njit(cache=True)
def coupling_errors(m, d):
    """e = x_VM - x_h, ed = xd_VM - xd_h (the device's effective twist), the device-proxy
    coupling force K e + B ed, the resisted directions in force this tick; the row's force
    parts start at zero."""
    p = m.params
    w = d.scratch
    r = d.row
    effective_device_twist(m, d)
    for c in range(3):
        w.e[c] = w.x_vm[c] - w.device_pose_eff[c]
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
    carried = False
    for c in range(3):
        carried = carried or st.impulse_carry[c] != 0.0
        r.f_impulse[c] += st.impulse_carry[c] / dt
        st.impulse_carry[c] = 0.0
    if m.params.impulse_law == 3:
        impact_ledger(m, d, carried)
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
