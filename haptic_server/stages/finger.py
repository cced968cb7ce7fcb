"""The god_object method's stages of a haptic tick (seed 003 §3; docs/god-object.md).

The held tool is a disc; the device's point drives a god-object proxy against the newest
update's local shapes (haptic_server/stages/god_object.py), and the command is the proxy
coupling's force. The proxy is the tool's configuration (q = its centre, the angle kept), so
the guard, the NaN check, the log row and the proxy state the sim tracks work unchanged.
"""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.haptic_server.stages.control import clear_command_terms
from haptic_local_model.haptic_server.stages.god_object import (
    blend_step,
    god_object_step,
    install_blended_step,
    reset_proxy,
)


@njit(cache=True)
def finger(m, d):
    """The god-object's tick: the device point x_h from the last tick's to this one's, the
    shapes aged by the contact clock of slot 0; F into the coordination channel."""
    g = d.god
    b = d.god_blend
    st = d.state
    sen = d.sensors[0]
    r = d.row
    x1 = g.finger_now
    x0 = g.finger_prev
    x1[0] = sen.pose[0]
    x1[1] = sen.pose[1]
    if g.started == 0:
        x0[0] = x1[0]
        x0[1] = x1[1]
        g.started = 1
    slot = m.slots[0]
    god_object_step(m.god, g, slot.shapes, slot.n_shapes, x0, x1, d.contacts[0].age_s, d.dt)
    blend_step(m.god, g, b, x0, x1, d.dt)
    d.contacts[0].age_s += d.dt
    d.contacts[1].age_s += d.dt
    if math.isfinite(x1[0]) and math.isfinite(x1[1]):  # a bad reading is not the next start
        x0[0] = x1[0]
        x0[1] = x1[1]
    for c in range(2):
        st.qd[c] = (b.proxy[c] - st.q[c]) / d.dt
        st.q[c] = b.proxy[c]
    st.qd[2] = 0.0
    clear_command_terms(r)
    r.f_coordination[0] = b.force[0]
    r.f_coordination[1] = b.force[1]
    r.god_proxy[0] = b.proxy[0]
    r.god_proxy[1] = b.proxy[1]
    r.god_blend = b.weight
    r.god_contact = g.contact
    r.god_active = g.n_active
    r.god_pop = g.pop
    r.god_pops = g.pops
    r.god_substeps = g.substeps
    r.god_capped = g.capped
    r.n_shapes = slot.n_shapes
    for j in range(2):
        r.god_env_key[j] = b.env_key[j]
        for c in range(2):
            r.god_env_point[j, c] = b.env_point[j, c]
            r.god_env_arm[j, c] = b.env_arm[j, c]
            r.god_env_force[j, c] = b.env_force[j, c]


@njit(cache=True)
def install_finger_shapes(m, d, restart):
    """At an install: the new slot's shapes replace the old slot's (by key, blended; a
    change of topology under the proxy begins a two-proxy blend). On a restart (the engine
    re-initialises after this install) the old slot is stale: the shapes start afresh (a
    deformable's hold at rest at the new sample)."""
    old = m.slots[1]
    n_old = old.n_shapes if old.valid == 1 and not restart else 0
    new = m.slots[0]
    clock = d.god.clock
    clock.old_tau = d.contacts[1].age_s
    clock.new_tau = d.contacts[0].age_s
    clock.new_time = new.sim_time
    install_blended_step(
        m.god, d.god, d.god_blend, old.shapes, n_old, new.shapes, new.n_shapes, clock
    )


@njit(cache=True)
def restart_finger(d, x, y):
    """A re-initialised proxy at the sim's tool, the device point there too."""
    reset_proxy(d.god, x, y)
    d.god.started = 0
    d.god_blend.active = 0
    d.god_blend.weight = 0.0
