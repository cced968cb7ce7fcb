"""Stages at the proxy configuration: cross-fade weights, frames and J_h, the blended D^ and
bias, and the operational-space terms D^-1 J_h^T and Lambda^-1 (seed 000 eq 6, 23)."""

from __future__ import annotations

from numba import njit

from haptic_local_model.shared.kinematics import link_frames, point_jacobian, point_on_link
from haptic_local_model.shared.linalg import cholesky_inplace, cholesky_solve


@njit(cache=True)
def fading(m, d):
    """The older slot still contributes this tick (DESIGN §4.4: geometry is cross-faded)."""
    return m.slots[1].valid == 1 and d.scratch.alpha < 1.0


@njit(cache=True)
def blend_weights(m, d):
    """alpha, the newest slot's weight this tick, then advance the blend over blend_s."""
    p = m.params
    st = d.state
    alpha = 1.0
    if m.slots[1].valid == 1 and p.blend_s > 0.0 and st.blend < 1.0:
        alpha = st.blend
    st.blend = min(1.0, st.blend + (d.dt / p.blend_s if p.blend_s > 0.0 else 1.0))
    d.scratch.alpha = alpha


@njit(cache=True)
def proxy_kinematics(m, d):
    """Link frames, the operational point, J_h, x_VM and xd_VM = J_h qd at the proxy."""
    new = m.slots[0]
    st = d.state
    w = d.scratch
    n = new.dof
    link_frames(new, st.q, n, w.frame_pos, w.frame_angle)
    point_on_link(w.frame_pos, w.frame_angle, new.op_link, new.op_point, w.op_point)
    hx = w.op_point[0]
    hy = w.op_point[1]
    point_jacobian(new, w.frame_pos, n, new.op_link, hx, hy, w.jac_hand)
    w.x_vm[0] = hx
    w.x_vm[1] = hy
    w.x_vm[2] = w.frame_angle[new.op_link]
    for c in range(3):
        w.xd_vm[c] = 0.0
    for j in range(n):
        for c in range(3):
            w.xd_vm[c] += w.jac_hand[c, j] * st.qd[j]


@njit(cache=True)
def blend_model(m, d):
    """Cross-fade the frozen D^ and bias G^ + C^ qd of the two slots into scratch.mass and
    scratch.tau_bias (as -bias), and factor D^."""
    new = m.slots[0]
    old = m.slots[1]
    w = d.scratch
    alpha = w.alpha
    n = new.dof
    both = old.valid == 1 and alpha < 1.0 and old.dof == n
    for a in range(n):
        g = 0.0
        if new.has_gravity == 1:
            g += alpha * new.gravity[a]
        if new.has_velocity_torque == 1:
            g += alpha * new.velocity_torque[a]
        if both:
            if old.has_gravity == 1:
                g += (1.0 - alpha) * old.gravity[a]
            if old.has_velocity_torque == 1:
                g += (1.0 - alpha) * old.velocity_torque[a]
        w.tau_bias[a] = -g
        for b in range(n):
            v = new.mass[a, b]
            if both:
                v = alpha * v + (1.0 - alpha) * old.mass[a, b]
            w.mass[a, b] = v
    w.mass_ok = 1 if cholesky_inplace(w.mass, n, w.mass_chol) else 0


@njit(cache=True)
def operational_terms(m, d):
    """D^-1 J_h^T (d x 3) and Lambda^-1 = J_h D^-1 J_h^T (seed 000 eq 6)."""
    w = d.scratch
    n = m.slots[0].dof
    for c in range(3):
        for a in range(n):
            w.jac_row[a] = w.jac_hand[c, a]
        cholesky_solve(w.mass_chol, n, w.jac_row, w.minv_jac_row)
        for a in range(n):
            w.minv_jt[a, c] = w.minv_jac_row[a]
    for r in range(3):
        for c in range(3):
            v = 0.0
            for a in range(n):
                v += w.jac_hand[r, a] * w.minv_jt[a, c]
            w.lambda_inv[r, c] = v
