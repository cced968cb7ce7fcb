"""Installing an update (DESIGN §3): validate, order-check, make it the newest slot.

`accept_update` is the one route: the real-time loop's mailbox kernel, `HapticEngine.receive`
(virtual clock, replay) and the tests all go through it. Verdicts are
`shared.protocol.codes.Reason` codes.
"""

from __future__ import annotations

from numba import njit

from haptic_local_model.haptic_server.stages.finger import install_finger_shapes
from haptic_local_model.haptic_server.stages.plausible import check_plausible
from haptic_local_model.shared.mechanism import body_count
from haptic_local_model.shared.protocol.codes import Reason
from haptic_local_model.shared.protocol.layout import (
    DEFAULT_CLOCK_SKEW_MS,
    DEFAULT_MAX_UPDATE_AGE_MS,
)
from haptic_local_model.shared.protocol.update import parse_update

#: How epochs and times are admitted (install.epoch_law). Releases before 0.3 switched to
#: any higher epoch at once, never back to a lower one, and took any publish time: a single
#: forged epoch of 2^63 - 1 took the device over and locked the real sim out.
EPOCH_LAW_HIGHER = 0
#: Since 0.3: while a sim's updates flow (a model installed, the watchdog quiet) only its
#: epoch installs; any other, higher or lower, waits for the watchdog, as a restarted sim's
#: first update always does. An update must be fresh (age within [-max_skew_s, max_age_s]),
#: so an update older than an outage never ends it. The epoch's value means nothing but
#: "another sim": its order is never used, so no epoch can run ahead of another (0.3 also
#: refused an epoch, the sim's start time, after the update's own publish time; a clock
#: stepped back under a running sim then locked it out, and 0.4 dropped that check).
EPOCH_LAW_LIVE = 1
#: the contacts' extrapolation age at install is the update's age, clamped to [0, this]
MAX_LATENCY_S = 1.0
DEFAULT_MAX_AGE_S = DEFAULT_MAX_UPDATE_AGE_MS / 1e3
DEFAULT_MAX_SKEW_S = DEFAULT_CLOCK_SKEW_MS / 1e3


@njit(cache=True)
def accept_update(buf, nbytes, age_s, model, data, install, god):
    """Parse, validate, order-check and install the update in buf[:nbytes]: 0 or the reason.

    age_s is the receiver's clock minus the update's publish time, as it was taken (negative
    if the sim's clock runs ahead): its moving contacts have moved on by that much. The
    epoch and time checks follow install.epoch_law (above). nbytes < 0 or beyond the buffer
    is a message too large for it (the mailbox marks one so): rejected as SIZE. `god` is
    the engine's method marker (stages.tick.method_marker): an install compiled for the
    local model has no god-object's shapes to install.
    """
    ins = install[0]
    if nbytes < 0 or nbytes > buf.shape[0]:
        return Reason.SIZE
    code = parse_update(buf, nbytes, ins.limits, ins.parsed, ins.parse_scratch)
    if code != 0:
        return code
    u = ins.parsed[0]
    if ins.epoch_law == EPOCH_LAW_LIVE:
        code = admit_live(u, age_s, ins)
    elif u.epoch < ins.epoch:
        code = Reason.STALE_EPOCH
    if code != 0:
        return code
    new_epoch = u.epoch != ins.epoch
    env = ins.envelope[0]
    # after the watchdog (or a guard's trip) the sim's sequence is followed afresh: an
    # update that pushed it ahead cannot lock the sim's own updates out
    resync = env.enabled == 1 and (ins.stale == 1 or data[0].state.fault != 0)
    if not new_epoch and u.seq <= ins.seq and not resync:
        return Reason.SEQUENCE
    if not new_epoch and ins.ready == 1 and u.dof != model[0].slots[0].dof:
        return Reason.DOF_CHANGE
    tm = model[0].train
    if u.has_avars != tm.enabled or (
        tm.enabled == 1 and (u.avar_static_id != tm.static_id or u.avar_cars != body_count(tm.mech))
    ):
        return Reason.STATIC  # another mechanism, or one where the scene has none
    if env.enabled == 1:
        live = ins.ready == 1 and not new_epoch and not resync and model[0].slots[0].valid == 1
        code = check_plausible(u, model[0].slots[0], live, env)
        if code != 0:
            return code
    latency_s = min(max(age_s, 0.0), MAX_LATENCY_S)
    install_update(model[0], data[0], ins, new_epoch, latency_s, god)
    ins.epoch = u.epoch
    ins.seq = u.seq
    ins.ready = 1
    ins.new_epoch = 1 if new_epoch else 0
    ins.installed += 1
    return 0


@njit(cache=True)
def admit_live(u, age_s, ins):
    """EPOCH_LAW_LIVE's checks of a parsed update: 0 or the reason it may not install."""
    if age_s > ins.max_age_s:
        return Reason.LATE
    if age_s < -ins.max_skew_s:
        return Reason.FUTURE
    if u.epoch != ins.epoch and ins.ready == 1 and ins.stale == 0:
        return Reason.STALE_EPOCH
    if ins.bound == 1 and u.epoch != ins.owner:  # the live sim's session holds another epoch
        return Reason.UNBOUND
    return 0


@njit(cache=True)
def install_update(m, d, ins, new_epoch, latency_s, god):
    """Make the parsed model the newest slot; the previous one fades out over blend_s (a new
    epoch drops it). The new model's contacts inherit their state by key."""
    if new_epoch:
        m.slots[1].valid = 0
    else:
        m.slots[1] = m.slots[0]
        d.contacts[1] = d.contacts[0]
    m.slots[0] = ins.parsed[0]
    cs = d.contacts[0]
    cs.age_s = -m.slots[0].state_lead_s  # contacts move from the time the state holds
    cs.age_s += latency_s
    inherit_contact_state(m.slots[0], cs, m.slots[1], d.contacts[1], ins.match_radius_m)
    d.state.blend = 1.0 if m.slots[1].valid == 0 else 0.0
    if god is not None:  # the god-object's (method_marker)
        # a re-initialisation follows (new epoch, watchdog, fault): no stale shapes to blend
        restart = new_epoch or ins.stale == 1 or d.state.fault != 0
        install_finger_shapes(m, d, restart)


@njit(cache=True)
def inherit_contact_state(new, new_state, old, old_state, match_radius):
    """Carry contact state (in contact, stick displacement) from the previous model to the
    new one for contacts with the same key whose tool points lie within match_radius
    (and the depth not rendered, `offset`). A contact not in contact before gets as its
    offset how far the carry back drew it toward the tool (carried_in); the contact stage
    keeps it no deeper than the contact is."""
    for i in range(new.n_contacts):
        new_state.in_contact[i] = 0
        new_state.stick[i] = 0.0
        new_state.offset[i] = carried_in(new, i, new_state.age_s)
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
            new_state.in_contact[i] = old_state.in_contact[best]
            new_state.stick[i] = old_state.stick[best]
            if new_state.in_contact[i] == 1:
                new_state.offset[i] = old_state.offset[best]


@njit(cache=True)
def carried_in(slot, i, age_s):
    """How far the install drew contact i toward the tool (m, >= 0): the depth a contact not
    in contact before is not rendered at (CONTACT_STATE_DTYPE's `offset`; the contact stage
    keeps it no deeper than the contact, and 0 once it opens, so no depth it gives is energy
    the proxy never put in).

    The install carries a contact's environment back from the time its state holds (age
    < 0, docs/god-object.md "One clock"): along a velocity leaving the tool (n . v < 0) that
    brings it nearer by n . v age. Right for a shape that moved so over the sim's step; not
    for one the sim's tool struck in it (pymunk's bouncing_balls: a ball hit by the hand
    leaves it at 1.24 m/s, carried back 14 ms it lands 14 mm inside the proxy, and its
    spring gave 0.5 J the passivity observer saw). The previous model, which did not have
    it touching, is trusted about the past."""
    carry = (
        slot.c_normal[i, 0] * slot.c_env_velocity[i, 0]
        + slot.c_normal[i, 1] * slot.c_env_velocity[i, 1]
    ) * age_s
    return max(carry, 0.0)
