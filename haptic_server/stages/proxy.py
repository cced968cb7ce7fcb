"""The proxy step (seed 000 eq 21), linearly implicit in the contact springs and the
device coupling."""

from __future__ import annotations

from numba import njit

from haptic_local_model.haptic_server.physics.implicit import (
    implicit_advance,
    implicit_solve,
    implicit_system,
)


@njit(cache=True)
def proxy_step(m, d):
    """D^ qdd = tau_c - G^ - C^ qd + J_h^T pull, integrated over dt.

    Linearly implicit in the contact springs (which move with the environment) and in the
    coupling to the device (which moves with the device): K, B are their configuration-space
    stiffness and damping. The device's velocity over the step is predicted from its last
    acceleration, so a proxy and a device accelerating together take identical steps (no lag
    between them), while stiff couplings on light tools stay stable:
    (D + dt B + dt^2 K) dqd = dt (f - dt K v_rel + J^T (B_c + dt K_c) dt a_h).
    """
    p = m.params
    st = d.state
    w = d.scratch
    vh = w.device_twist_eff  # the sensors' twist plus the velocity change the carry owes
    dt = d.dt
    for c in range(3):
        w.hand_acc[c] = (vh[c] - st.prev_device_twist[c]) / dt
        st.prev_device_twist[c] = vh[c]
    if p.impulse_law >= 2:
        # this tick's new impulse is a step, not an acceleration to extrapolate: the next
        # tick's estimate starts from the twist it leaves (J_h D^-1 P_cs)
        for c in range(3):
            st.prev_device_twist[c] += w.acc_impulse[c] * dt
    if p.integrate_proxy == 0 or w.mass_ok == 0:
        return
    n = m.slots[0].dof
    kc = p.coupling_stiffness
    bc = p.coupling_damping
    g0 = (bc[0] + dt * kc[0]) * dt * w.hand_acc[0] - dt * kc[0] * w.ed[0]
    g1 = (bc[1] + dt * kc[1]) * dt * w.hand_acc[1] - dt * kc[1] * w.ed[1]
    g2 = (bc[2] + dt * kc[2]) * dt * w.hand_acc[2] - dt * kc[2] * w.ed[2]
    jh = w.jac_hand
    for a in range(n):
        v = w.tau_contact[a] + w.tau_bias[a] - dt * w.contact_stiff_vrel[a]
        v += jh[0, a] * (w.pull[0] + g0) + jh[1, a] * (w.pull[1] + g1) + jh[2, a] * (w.pull[2] + g2)
        w.proxy_rhs[a] = v  # f; implicit_solve makes it h f in place
        for b in range(n):
            kq = 0.0
            for c in range(3):
                kq += jh[c, a] * (bc[c] + dt * kc[c]) * jh[c, b]
            w.proxy_damping[a, b] = w.contact_damping_q[a, b] + kq
    implicit_system(w.proxy_system, w.mass, w.proxy_damping, w.contact_stiffness_q, dt, n)
    if implicit_solve(w.proxy_system, w.proxy_chol, w.proxy_rhs, dt, w.proxy_rhs, w.proxy_dqd, n):
        implicit_advance(st.q, st.qd, w.proxy_dqd, dt, 1.0, n)
