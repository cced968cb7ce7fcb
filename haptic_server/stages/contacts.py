"""Contacts of the installed models (seed 001 §3.2): penalty and friction of continuous
contacts, detection of colliding ones, and their simultaneous resolution by impulses."""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.haptic_server.physics.contact_law import penalty_friction
from haptic_local_model.haptic_server.physics.implicit import clear_terms
from haptic_local_model.haptic_server.physics.impulses import lcp
from haptic_local_model.shared.kinematics import point_jacobian, point_on_link
from haptic_local_model.shared.linalg import cholesky_solve
from haptic_local_model.shared.protocol.codes import Method


@njit(cache=True)
def queue_collision(m, d, i, vn):
    """Queue contact i of the newest slot for the impulse stage if it collides: it starts
    penetrating this tick, approaching faster than collision_speed (DESIGN §4.1)."""
    ws = d.scratch
    if (
        d.contacts[0].in_contact[i] == 0
        and m.params.impulses == 1
        and vn < -m.params.collision_speed
        and ws.n_colliding < ws.coll_target.shape[0]
    ):
        slot = m.slots[0]
        c = ws.n_colliding
        for j in range(slot.dof):
            ws.coll_rows[c, j] = (
                slot.c_normal[i, 0] * ws.jac_point[0, j] + slot.c_normal[i, 1] * ws.jac_point[1, j]
            )
        ws.coll_target[c] = -(1.0 + slot.c_restitution[i]) * vn
        ws.coll_index[c] = i
        ws.n_colliding = c + 1


@njit(cache=True)
def contact_kinematics(m, d, k, i):
    """Contact i of slot k at the proxy: the point's Jacobian into scratch.jac_point; returns
    (gap, normal velocity, tangential velocity), the environment moved by its velocity times
    the model's age."""
    slot = m.slots[k]
    cs = d.contacts[k]
    ws = d.scratch
    n = slot.dof
    link = slot.c_link[i]
    point_on_link(ws.frame_pos, ws.frame_angle, link, slot.c_tool[i], ws.contact_point)
    px = ws.contact_point[0]
    py = ws.contact_point[1]
    point_jacobian(slot, ws.frame_pos, n, link, px, py, ws.jac_point)
    nx = slot.c_normal[i, 0]
    ny = slot.c_normal[i, 1]
    ex = slot.c_env[i, 0] + slot.c_env_velocity[i, 0] * cs.age_s
    ey = slot.c_env[i, 1] + slot.c_env_velocity[i, 1] * cs.age_s
    gap = nx * (px - ex) + ny * (py - ey)
    vx = -slot.c_env_velocity[i, 0]
    vy = -slot.c_env_velocity[i, 1]
    for j in range(n):
        vx += ws.jac_point[0, j] * d.state.qd[j]
        vy += ws.jac_point[1, j] * d.state.qd[j]
    return gap, nx * vx + ny * vy, -ny * vx + nx * vy


@njit(cache=True)
def collisions(m, d):
    """The newest slot's colliding contacts queued for the impulse stage (the contact forces
    come after the impulses, from the velocity they leave). A contact already in contact
    last tick cannot collide: its kinematics wait for the contact stage."""
    slot = m.slots[0]
    for i in range(slot.n_contacts):
        if d.contacts[0].in_contact[i] == 1:
            continue
        gap, vn, _vt = contact_kinematics(m, d, 0, i)
        if gap <= 0.0:
            queue_collision(m, d, i, vn)


@njit(cache=True)
def contact_stage(m, d, k, weight, detect):
    """Penalty + friction of slot k's continuous contacts (seed 001 eq 8), weighted by its
    cross-fade weight; with `detect`, the newest slot's colliding contacts are queued here
    (version 0.1's order: forces from the velocity before the impulses).

    Accumulates weight * J_c^T F into tau_contact and the contact stiffness and damping into
    contact_stiffness_q / contact_damping_q (for the implicit proxy step). Returns the
    number in penetration.
    """
    slot = m.slots[k]
    cs = d.contacts[k]
    ws = d.scratch
    dt = d.dt
    n = slot.dof
    active = 0
    for i in range(slot.n_contacts):
        gap, vn, vt = contact_kinematics(m, d, k, i)
        nx = slot.c_normal[i, 0]
        ny = slot.c_normal[i, 1]
        tx = -ny
        ty = nx
        if gap > 0.0:
            cs.in_contact[i] = 0
            cs.stick[i] = 0.0
            cs.offset[i] = 0.0
            continue
        cs.offset[i] = min(cs.offset[i], -gap)  # the depth not rendered (install.carried_in)
        active += 1
        if k == 0 and -gap > ws.penetration:
            ws.penetration = -gap
        k_n = slot.c_stiffness[i]
        b_n = slot.c_damping[i]
        if k == 0 and detect:
            queue_collision(m, d, i, vn)
        if cs.in_contact[i] == 0:
            cs.stick[i] = 0.0
        cs.in_contact[i] = 1
        k_t = slot.c_tangential_stiffness[i]
        f_n, f_t, cs.stick[i], sticking = penalty_friction(
            (k_n, b_n, slot.c_friction[i], k_t), -gap - cs.offset[i], vn, vt, cs.stick[i], dt
        )
        fx = f_n * nx + f_t * tx
        fy = f_n * ny + f_t * ty
        ws.contact_force[0] += weight * fx
        ws.contact_force[1] += weight * fy
        ws.env_work += (
            weight * dt * (fx * slot.c_env_velocity[i, 0] + fy * slot.c_env_velocity[i, 1])
        )
        kt_eff = k_t if sticking else 0.0
        for a in range(n):
            ja_n = nx * ws.jac_point[0, a] + ny * ws.jac_point[1, a]
            ja_t = tx * ws.jac_point[0, a] + ty * ws.jac_point[1, a]
            ws.tau_contact[a] += weight * (ws.jac_point[0, a] * fx + ws.jac_point[1, a] * fy)
            if f_n > 0.0:
                # stiffness times the relative velocity: the implicit step's correction
                ws.contact_stiff_vrel[a] += weight * (k_n * ja_n * vn + kt_eff * ja_t * vt)
                for b in range(n):
                    jb_n = nx * ws.jac_point[0, b] + ny * ws.jac_point[1, b]
                    jb_t = tx * ws.jac_point[0, b] + ty * ws.jac_point[1, b]
                    ws.contact_stiffness_q[a, b] += weight * (
                        k_n * ja_n * jb_n + kt_eff * ja_t * jb_t
                    )
                    ws.contact_damping_q[a, b] += weight * b_n * (ja_n * jb_n + ja_t * jb_t)
    return active


@njit(cache=True)
def contacts(m, d):
    """Collisions, their impulses, then the contact stage over both slots: the newest at
    weight alpha, the fading one at 1 - alpha (its contacts are not counted, nor queued for
    impulses); then both models' contact states age by dt. With impulse_law 1
    (version 0.1) the forces come first, from the velocity before the impulses."""
    w = d.scratch
    n = m.slots[0].dof
    clear_terms(n, w.tau_contact, w.contact_stiff_vrel, w.contact_stiffness_q, w.contact_damping_q)
    w.n_colliding = 0
    w.contact_force[0] = 0.0
    w.contact_force[1] = 0.0
    w.env_work = 0.0
    w.n_active = 0
    w.penetration = 0.0
    w.contact_ran = 0
    old = m.slots[1]
    after = m.params.impulse_law >= 2
    w.impact_eta = math.inf
    if after:
        if m.params.impulses == 1 and m.slots[0].n_contacts > 0:
            collisions(m, d)
        impulses(m, d)
        if m.params.impulse_law == 3 and w.n_colliding == 0 and w.mass_ok == 1 and paid_ahead(m):
            predict_impact(m, d)
    if m.slots[0].n_contacts > 0:
        w.n_active += contact_stage(m, d, 0, w.alpha, not after)
        w.contact_ran = 1
    if old.valid == 1 and w.alpha < 1.0 and old.n_contacts > 0 and old.dof == n:
        contact_stage(m, d, 1, 1.0 - w.alpha, False)
        w.contact_ran = 1
    if not after:
        impulses(m, d)
    d.contacts[0].age_s += d.dt
    d.contacts[1].age_s += d.dt


@njit(cache=True)
def resolve_rows(ws, n, k, out):
    """The impulses of the k contacts queued in ws.coll_rows / coll_target, resolved
    together: A = J_n D^-1 J_n^T (rows of D^-1 J_n^T via the Cholesky factor of D), lambda
    of the complementarity problem (physics.impulses), out = J_n^T lambda (P_cs)."""
    for c in range(k):
        for a in range(n):
            ws.coll_row[a] = ws.coll_rows[c, a]
        cholesky_solve(ws.mass_chol, n, ws.coll_row, ws.coll_minv_row)
        for r in range(k):
            v = 0.0
            for a in range(n):
                v += ws.coll_rows[r, a] * ws.coll_minv_row[a]
            ws.coll_a[r, c] = v
    lcp(ws.coll_a, ws.coll_target, ws.coll_lambda, k)
    for a in range(n):
        v = 0.0
        for c in range(k):
            v += ws.coll_rows[c, a] * ws.coll_lambda[c]
        out[a] = v


@njit(cache=True)
def impulses(m, d):
    """All colliding contacts of a tick resolved together (DESIGN §4.1; seed 001 eq 5-6):
    lambda >= 0 solves the complementarity problem of A = J_n D^-1 J_n^T and the targets
    v+ - v- (`physics.impulses`: a contact that would separate takes none, none is left
    approaching); the proxy gets dqd = D^-1 J_n^T lambda at once and impulse_q = J_n^T
    lambda = P_cs."""
    ws = d.scratch
    state = d.state
    n = m.slots[0].dof
    k = ws.n_colliding
    for a in range(n):
        ws.impulse_q[a] = 0.0
    if k == 0:
        return
    resolve_rows(ws, n, k, ws.impulse_q)
    slot = m.slots[0]
    for c in range(k):  # a moving shape's share: lambda n . v_env (the world's, not ours)
        i = ws.coll_index[c]
        ws.env_work += ws.coll_lambda[c] * (
            slot.c_normal[i, 0] * slot.c_env_velocity[i, 0]
            + slot.c_normal[i, 1] * slot.c_env_velocity[i, 1]
        )
    cholesky_solve(ws.mass_chol, n, ws.impulse_q, ws.impulse_dqd)
    for a in range(n):
        state.qd[a] += ws.impulse_dqd[a]


@njit(cache=True)
def paid_ahead(m):
    """impulse_law 3's prediction is needed: impulses on, and a law that gives the device
    its share of them (seed 000's, stages/control.py control_impedance_only)."""
    p = m.params
    law = p.method == Method.LOCAL_MODEL or p.method == Method.IMPEDANCE_ONLY
    return law and p.impulses == 1 and m.slots[0].n_contacts > 0


@njit(cache=True)
def approach_eta(m, d, i):
    """Contact i of the newest slot: the time until it collides (DESIGN §4.1) at today's
    relative velocity, inf if it is touching, not approaching faster than collision_speed,
    or at a point the tool's joints cannot move along its normal (no impulse could stop
    it); its kinematics are left in scratch (contact_kinematics)."""
    if d.contacts[0].in_contact[i] == 1:
        return math.inf
    gap, vn, _vt = contact_kinematics(m, d, 0, i)
    if not (gap > 0.0 and vn < -m.params.collision_speed):
        return math.inf
    slot = m.slots[0]
    jac = d.scratch.jac_point
    for j in range(slot.dof):  # the tool's joints must move the point along the normal
        if slot.c_normal[i, 0] * jac[0, j] + slot.c_normal[i, 1] * jac[1, j] != 0.0:
            return gap / -vn
    return math.inf


@njit(cache=True)
def predict_impact(m, d):
    """impulse_law 3: the newest slot's next collision, as if it were now (the contacts
    that reach their surface within a tick of the first, resolved together as `impulses`
    would): scratch.impact_eta, the time to it, and impulse_pred_q, its P_cs. The proxy's
    velocity is not changed: the control law pays the device's share ahead (impact_ledger).
    Runs on ticks without a collision; the coll_* scratch is free then."""
    ws = d.scratch
    slot = m.slots[0]
    n = slot.dof
    eta = math.inf
    for i in range(slot.n_contacts):
        ws.contact_eta[i] = approach_eta(m, d, i)
        eta = min(eta, ws.contact_eta[i])
    if eta == math.inf:
        return
    k = 0
    for i in range(slot.n_contacts):
        if k == ws.coll_target.shape[0] or ws.contact_eta[i] > eta + d.dt:
            continue
        _gap, vn, _vt = contact_kinematics(m, d, 0, i)
        for j in range(n):
            ws.coll_rows[k, j] = (
                slot.c_normal[i, 0] * ws.jac_point[0, j] + slot.c_normal[i, 1] * ws.jac_point[1, j]
            )
        ws.coll_target[k] = -(1.0 + slot.c_restitution[i]) * vn
        k += 1
    resolve_rows(ws, n, k, ws.impulse_pred_q)
    ws.impact_eta = eta
