"""The last stages: the command's sum, the safe-state blend, the device limits, the
impulse carry, the NaN guard; then the log row."""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.shared.kinematics import REVOLUTE, link_spin
from haptic_local_model.shared.protocol.codes import Fault, Method


@njit(cache=True)
def safe_wrench(m, d, c):
    """The safe state's command on axis c: damping only, on the handle's own motion."""
    sen = d.sensors[0]
    u_safe = -m.params.safe_damping[c] * (sen.twist[c] - sen.frame_twist[c])
    return u_safe if math.isfinite(u_safe) else 0.0


@njit(cache=True)
def runaway_guard(m, d):
    """The last line against a model that drives the proxy or the device away (docs/security.md).

    - Runaway: the proxy's operational point faster than the scene allows, any of its links
      spinning faster, or its kinetic energy above the envelope's (Fault.RUNAWAY).
    - Passivity observer (after Hannaford and Ryu 2002) at the hand: the energy the device
      gives the hand is what its actuators put in, sum of u . v dt of last tick's command u
      and the twist it produced v (relative to the map's frame), less what went into the
      device's own kinetic energy 1/2 v^T M_d v (an inertia-compensating law drives the
      handle's mass, not the hand); forgotten over passivity_window_s. Above
      passivity_limit_j the rendering is generating energy (Fault.PASSIVITY). It omits
      the device's own friction losses, so it errs toward tripping. The work the touched
      obstacles' own motion did on the finger or the proxy (a wall driven into the hand, a
      belt dragging it: the god-object's env_work, the local model's contacts' and
      impulses' along the shapes' velocities) is the world's, not the rendering's: it is
      taken out.
    A trip sends the device to the safe state at once and stops the proxy; the next
    installed update re-initialises it from the sim (HapticEngine.installed)."""
    p = m.params
    st = d.state
    if p.guard == 0:
        return
    sen = d.sensors[0]
    work = 0.0
    kinetic = 0.0
    for c in range(3):
        v = sen.twist[c] - sen.frame_twist[c]
        work += st.last_command[c] * v * d.dt
        for k in range(3):
            kinetic += 0.5 * v * sen.inertia[c, k] * (sen.twist[k] - sen.frame_twist[k])
    if st.device_energy < 0.0:  # re-initialised: the device's energy so far is not the port's
        st.device_energy = kinetic
    given = work - (kinetic - st.device_energy)
    # a moving world's push is not the rendering's energy
    given -= d.god.env_work if p.method == Method.GOD_OBJECT else d.scratch.env_work
    st.device_energy = kinetic
    st.port_energy = st.port_energy * math.exp(-d.dt / p.passivity_window_s) + given
    if st.fault != Fault.NONE:
        return
    fault = Fault.NONE
    if p.integrate_proxy == 1 and d.scratch.mass_ok == 1:
        fault = _runaway(m, d)
    if fault == Fault.NONE and st.port_energy > p.passivity_limit_j:
        fault = Fault.PASSIVITY
    if fault != Fault.NONE:
        st.fault = fault
        st.safe = 1.0
        st.safe_target = 1.0
        for a in range(m.slots[0].dof):
            st.qd[a] = 0.0


@njit(cache=True)
def _runaway(m, d):
    """Fault.RUNAWAY if the proxy (after this tick's step) moves beyond the scene's envelope."""
    p = m.params
    st = d.state
    w = d.scratch
    slot = m.slots[0]
    n = slot.dof
    vx = 0.0
    vy = 0.0
    energy = 0.0
    for a in range(n):
        vx += w.jac_hand[0, a] * st.qd[a]
        vy += w.jac_hand[1, a] * st.qd[a]
        if slot.joint_types[a] == REVOLUTE:  # its link turns with it and its ancestors
            spin = link_spin(slot, st.qd, a)
            if abs(spin) > p.guard_max_angular_speed:
                return Fault.RUNAWAY
        for b in range(n):
            energy += 0.5 * st.qd[a] * w.mass[a, b] * st.qd[b]
    if p.method == Method.GOD_OBJECT:  # a disc: q = (x, y, angle), its centre held
        vx, vy = _away_from_hand(d, st.qd[0], st.qd[1])
        energy = 0.5 * (w.mass[0, 0] * vx * vx + w.mass[1, 1] * vy * vy)
    if math.hypot(vx, vy) > p.guard_max_speed or energy > p.guard_max_energy:
        return Fault.RUNAWAY
    return Fault.NONE


@njit(cache=True)
def _away_from_hand(d, vx, vy):
    """A god-object proxy's velocity as the guard counts it: only as fast as its distance
    from the device point opens. The massless proxy is the free point nearest the hand; when
    what held it moves on (a train's car sliding out from under a finger pressed 7 mm into
    it, a corner passed) it lands nearer the hand within the tick (4.9 m/s seen on
    coaster_clothoid), which lowers the coupling's force and is no runaway; a proxy that
    follows a fast hand keeps its distance. One carried off by an obstacle opens it, at the
    obstacle's speed, and is bounded as before."""
    x_h = d.god.finger_now
    x1 = d.state.q[0]
    y1 = d.state.q[1]
    x0 = x1 - vx * d.dt  # the proxy where the tick began
    y0 = y1 - vy * d.dt
    opening = (math.hypot(x1 - x_h[0], y1 - x_h[1]) - math.hypot(x0 - x_h[0], y0 - x_h[1])) / d.dt
    speed = math.hypot(vx, vy)
    if not (opening > 0.0 and speed > 0.0):
        return 0.0, 0.0
    return vx * opening / speed, vy * opening / speed


@njit(cache=True)
def safety_and_limits(m, d):
    """u = (1 - s) u_law + s u_safe, clipped at the device limits (world frame); an impulse
    clipped at the limit is carried to the next ticks (seed 001 eq 7). A non-finite command,
    proxy or D^ sends the device to the safe state at once (Fault.NONFINITE)."""
    p = m.params
    st = d.state
    r = d.row
    step = d.dt / p.safe_ramp_s
    if st.safe < st.safe_target:
        st.safe = min(st.safe_target, st.safe + step)
    elif st.safe > st.safe_target:
        st.safe = max(st.safe_target, st.safe - step)
    finite = d.scratch.mass_ok == 1
    for c in range(3):
        u = (
            r.f_user[c] + r.f_contact[c] + r.f_impulse[c] + r.f_bias[c] + r.f_penalty[c]
            + r.f_coordination[c] + r.f_damping[c]
        )  # fmt: skip
        if not math.isfinite(u):
            finite = False
        v = (1.0 - st.safe) * u + st.safe * safe_wrench(m, d, c)
        lim = p.max_wrench[c]
        clipped = min(lim, max(-lim, v))
        # an impulse clipped at the device limit is not lost: the rest is carried to the next
        # ticks, so the device still receives the momentum change (seed 001 eq 7)
        f_imp = r.f_impulse[c]
        excess = v - clipped
        if st.safe == 0.0 and f_imp != 0.0 and excess * f_imp > 0.0:
            if p.impulse_law == 2:
                # the impulse has the limit first: what the clipped command does not
                # deliver of it is carried (the coupling no longer brakes the same
                # momentum: see effective_device_twist)
                delivered = min(abs(f_imp), abs(clipped)) if clipped * f_imp > 0.0 else 0.0
                carried = abs(f_imp) - delivered
            else:
                # version 0.1, and law 3: all the excess, up to the impulse. Under law 3 the
                # carry is the momentum the device lacks against an unlimited one driven by
                # the whole law (control.impact_reference: the coupling sees it, and does
                # not brake it a second time)
                carried = min(abs(excess), abs(f_imp))
            st.impulse_carry[c] = math.copysign(carried, f_imp) * d.dt
        r.wrench_command[c] = clipped
        st.last_command[c] = clipped
    for a in range(m.slots[0].dof):
        if not (math.isfinite(st.q[a]) and math.isfinite(st.qd[a])):
            finite = False
    if not finite:
        st.fault = Fault.NONFINITE
        st.safe = 1.0
        st.safe_target = 1.0
        for c in range(3):
            lim = p.max_wrench[c]
            r.wrench_command[c] = min(lim, max(-lim, safe_wrench(m, d, c)))
            st.last_command[c] = r.wrench_command[c]


@njit(cache=True)
def fill_row(m, d):
    """The tick's state into the log row (FOH: the VM is the sim's tool, seen through the
    setpoint; its twist was written by the FOH law)."""
    st = d.state
    w = d.scratch
    sen = d.sensors[0]
    r = d.row
    if m.params.integrate_proxy == 0:
        for c in range(3):
            r.vm_pose[c] = st.foh_goal[c]
    else:
        for c in range(3):
            r.vm_pose[c] = w.x_vm[c]
            r.vm_twist[c] = w.xd_vm[c]
    for c in range(3):
        r.device_pose[c] = sen.pose[c]
        r.device_twist[c] = sen.twist[c]
        r.hand_wrench_measured[c] = d.hand_measured[c]
    for a in range(m.slots[0].dof):
        r.proxy_q[a] = st.q[a]
        r.proxy_qd[a] = st.qd[a]
    r.contact_force_world[0] = w.contact_force[0]
    r.contact_force_world[1] = w.contact_force[1]
    r.n_contacts = m.slots[0].n_contacts
    r.n_active = w.n_active
    r.penetration = w.penetration
    r.n_colliding = w.n_colliding
    r.contact_stage = w.contact_ran
    r.safe = st.safe
    r.fault = st.fault
    r.port_energy = st.port_energy
    r.dt = d.dt
