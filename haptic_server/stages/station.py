"""One haptic station's tick (docs/stations.md): its device coupled to its tool in a shared
world that another process co-simulates.

The world sends the port's tool (pose and twist in this station's frame) and the coupling's
gains (each at most the station's own scene's: a world cannot make a station stiffer than
its own file says); every tick the station renders the coupling against its own device at
once, the tool carried on by its twist since it arrived, for at most `extrapolate_s` (an old
tool state is not carried on into a guess):

    F = K (x_tool + v_tool min(age, extrapolate_s) - x_dev) + B (v_tool - v_dev)   (world)

mapped to the device, clipped at its limits. Without a fresh tool state (none for the
watchdog's period, or the world says it holds the port) the command ramps over `ramp_s` to
the safe state, a hold: the scene's coupling to a fixed anchor, where the device first read
before the join, where the coupling last put it on every later entry (_hold); it ramps back
the same way when tool states return (into about the squeeze it left with: _rejoins).
With the local model on, the pad's contact with the object the world last sent (low-passed:
_see_object) is rendered here, and the coupling only along its tangent (_local_contact). A
reading that is not finite renders zero for the tick; a coupling or a command that is not
finite is zeroed and counted. No I/O: the loop (haptic_server/station.py) feeds the tool
state and its age and publishes the device state this leaves in `world`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.device_models.base import SENSOR_DTYPE
from haptic_local_model.device_models.kernels import (
    device_advance,
    device_command,
)
from haptic_local_model.device_models.world_map import (
    MAP_DTYPE,
    map_command_to_device,
    map_rate_step,
)
from haptic_local_model.haptic_server.physics.passivity import pc_damping
from haptic_local_model.haptic_server.stages.port_io import read_device
from haptic_local_model.haptic_server.users import USER_DTYPE
from haptic_local_model.shared.kinematics import wrap_angle

F8 = np.float64
I8 = np.int64

STATION_DTYPE = np.dtype(
    [
        ("dt", F8),
        ("t", F8),
        ("watchdog_s", F8),
        ("ramp_s", F8),
        ("extrapolate_s", F8),  # the tool is carried on by its twist for at most this long
        ("max_stiffness", F8, (3,)),  # the station's own scene's coupling: received gains
        ("max_damping", F8, (3,)),  # are clamped to these
        ("limits", F8, (3,)),  # the device's max_wrench, device frame
        # the newest tool state: set by the loop
        ("have_tool", I8),
        ("held", I8),  # the world holds this port (it lost us, or re-indexes us)
        ("indexed", I8),  # the world re-indexes this port (we say SAFE): the tool is at
        ("device_echo", F8, (3,)),  # the device pose it took, plus the coupling's stretch
        ("tool_age", F8),  # s since it arrived
        ("tool_pose", F8, (3,)),
        ("tool_twist", F8, (3,)),
        ("stiffness", F8, (3,)),
        ("damping", F8, (3,)),
        # the tick's state and outputs
        ("fresh", I8),
        ("gain", F8),  # 0: the safe state, 1: the coupling
        ("coupling", F8, (3,)),  # world frame, before the ramp
        # its stiffness part as rendered: K (x_tool - x_dev), on a return the squeeze it left
        # with blended into it (_rejoin_coupling)
        ("spring", F8, (3,)),
        ("out", F8, (3,)),  # device frame: what the device is commanded
        ("cut", I8),  # this tick's reading was not finite
        ("invalid", I8),  # commands that were not finite (zeroed), all told
        ("sensors", SENSOR_DTYPE, (1,)),
        ("world", SENSOR_DTYPE, (1,)),
        ("hand", F8, (3,)),
        ("user", USER_DTYPE, (1,)),
        ("map", MAP_DTYPE, (1,)),
        ("scratch", F8, (3,)),
        # rejoining (_rejoins): the spring it rendered last while fully coupled, and the wait
        ("left_spring", F8, (3,)),
        ("has_left", I8),
        ("rejoin_wait_s", F8),  # waited so far for a tool state near the squeeze it left
        ("rejoin_waits", I8),  # ticks it waited so, all told
        # braking (_brakes): back from its safe state, the device slowed before it couples
        ("braking", I8),  # 1 from the safe state until the device is slow enough
        ("brake_s", F8),  # braked so far on this return
        ("rejoin_brakes", I8),  # ticks it braked so, all told
        ("damping_gain", F8),  # 0 braking, 1 coupled: the live spring and damping blended in
        # the passivity observer and controller (_passivity; docs/stations.md, "Passivity")
        ("passivity", I8),  # 1: the controller acts; 0: the observer only
        ("pc_max", F8, (3,)),  # the controller's largest damping, N s/m (world frame)
        ("budget", F8, (3,)),  # set by the loop: the world's end's energy, J (its ToolStates')
        ("energy", F8, (3,)),  # the device's net work on the coupling, J, since the start
        ("pc_damping", F8, (3,)),  # the controller's damping this tick, N s/m
        # the local model (_local_contact; docs/stations.md, "The local model at the station")
        ("local_model", I8),  # 1: the pad's contact with the object rendered here
        ("pad_half", F8, (2,)),  # the tool's (pad's) half extents, m
        ("object_half", F8, (2,)),  # the object's (box's) half extents, m
        ("contact_stiffness", F8),  # the world's contact on a pad's face (its points'), N/m
        ("fade_s", F8),  # the blend between the coupling's normal and the local contact
        ("object_pose", F8, (3,)),  # set by the loop: the newest ToolState's object
        ("object_twist", F8, (3,)),
        ("contact_w", F8),  # 0: the coupling whole, 1: its tangent and the local contact
        ("normal", F8, (2,)),  # the contact's normal, from the object to the pad
        ("depth", F8),  # the device's pad into the object, m (0: apart)
        ("local_force", F8, (3,)),  # the local contact's force, world frame, before the blend
        ("object_tau", F8),  # the low-pass on the object as rendered (s; <= dt: none)
        ("has_seen", I8),  # object_seen is set (0: taken as it is on the next contact tick)
        ("object_seen", F8, (3,)),  # the object as the local contact renders it: low-passed
        ("object_seen_twist", F8, (3,)),
        # the hold (_hold; docs/stations.md, "The join"): the safe state, on every entry
        ("has_hold", I8),  # hold_pose is set (this safe episode's first finite reading)
        ("hold_pose", F8, (3,)),  # world frame: where the device is held (it slips past the cap)
        ("hold_force", F8, (3,)),  # world frame: K (x_hold - x) - B v, clipped
        ("hold_out", F8, (3,)),  # device frame: the hold mapped to the device
    ]
)

#: One station tick as logged (world frame unless said).
STATION_ROW_DTYPE = np.dtype(
    [
        ("t", F8),
        ("wall_ns", I8),  # the loop's clock at the tick's start
        ("late_us", F8),  # after its deadline
        ("work_us", F8),  # the compiled tick, the decode and the publish
        ("pose", F8, (3,)),
        ("twist", F8, (3,)),
        ("hand", F8, (3,)),  # the user's wrench on the device, device frame
        ("coupling", F8, (3,)),
        ("spring", F8, (3,)),
        ("out", F8, (3,)),  # device frame
        # the tool state the tick rendered against, as the loop set it (the replay's input)
        ("tool_pose", F8, (3,)),
        ("tool_twist", F8, (3,)),
        ("stiffness", F8, (3,)),  # the gains the world sent (before the station's clamp)
        ("damping", F8, (3,)),
        ("tool_age", F8),
        ("have_tool", I8),
        ("held", I8),
        ("indexed", I8),
        ("device_echo", F8, (3,)),
        ("gain", F8),
        ("fresh", I8),
        ("cut", I8),
        ("invalid", I8),
        ("received", I8),  # tool states taken, all told
        ("rejected", I8),  # tool states refused (malformed, stale, another world's), all told
        ("fault", I8),  # the device's fault bits
        ("budget", F8, (3,)),  # the world's end's energy, as the loop set it (an input)
        ("energy", F8, (3,)),
        ("pc_damping", F8, (3,)),
        ("object_pose", F8, (3,)),  # the ToolState's object, as the loop set it (an input)
        ("object_twist", F8, (3,)),
        ("contact_w", F8),
        ("depth", F8),
        ("local_force", F8, (3,)),
        ("hold_force", F8, (3,)),  # the hold (before the ramp's blend; 0 at the full coupling)
    ]
)


@njit(cache=True)
def _rejoins(s, fresh):
    """Whether a fresh tool state is rendered: a station that was coupled and is safe again
    ramps back in only into about the squeeze it left with. A tool state whose spring
    differs from it, on x or y, by more than that squeeze (or a tenth of the device's limit,
    if more) is waited out, the station safe and saying so, for at most the watchdog's
    period: a world that re-indexed on a device state of a stall's backlog re-indexes on the
    next within a few ticks; a stretch the world changed meanwhile is then ramped in as it
    is, the ramp bounding each tick's step."""
    if fresh == 0 or s.gain > 0.0 or s.has_left == 0:
        s.rejoin_wait_s = 0.0
        return fresh
    if s.rejoin_wait_s >= s.watchdog_s:
        return fresh
    floor = 0.0  # a tenth of the device's limit on x or y, whichever is more
    for c in range(2):
        floor = max(floor, 0.1 * s.limits[c])
    for c in range(2):
        if abs(s.spring[c] - s.left_spring[c]) > max(abs(s.left_spring[c]), floor):
            s.rejoin_wait_s += s.dt
            s.rejoin_waits += 1
            return 0
    return fresh


#: Back from the safe state, the station brakes its device with at most this share of the
#: squeeze it left with
BRAKE_SHARE = 0.05
#: until the brake no longer saturates, within this share of the device's limit (the
#: maglev's twist noise through 40 N s/m is 0.09 N rms: 0.1 N)
BRAKE_FLOOR = 0.002
#: or at the latest this long after the fresh tool state came back
BRAKE_MAX_S = 0.5


#: The squeeze a station leaves with is averaged over its fully coupled ticks whose tool
#: state is at most this old (a stalled world's last one, carried on, is not the squeeze)
LEFT_AGE_S = 0.01


@njit(cache=True)
def _note_squeeze(s):
    """The spring the station renders fully coupled on a tool state younger than LEFT_AGE_S,
    averaged over `ramp_s` (the device's noise is not the squeeze): what it comes back into
    after its safe state (_rejoins, _brakes)."""
    if s.fresh == 0 or s.gain < 1.0 or s.damping_gain < 1.0 or s.tool_age > LEFT_AGE_S:
        return
    a = 1.0 if s.has_left == 0 else min(1.0, s.dt / s.ramp_s)
    s.has_left = 1
    for c in range(3):
        s.left_spring[c] += a * (s.spring[c] - s.left_spring[c])


@njit(cache=True, inline="always")
def _damping(s, c):
    """The coupling's damping on axis c: the world's, clamped to the station's own scene's."""
    return min(s.damping[c], s.max_damping[c])


@njit(cache=True, inline="always")
def _left(s, c):
    """The spring the station comes back into on axis c: the one it left with (once it has
    been fully coupled), else the live one."""
    return s.left_spring[c] if s.has_left == 1 else s.spring[c]


@njit(cache=True)
def _brakes(s):
    """Whether the station, rendering a fresh tool state again after its safe state (or at
    its first), still brakes its device before it couples: the user pushed the device while
    it was safe and it may still be moving (about 50 mm/s after a stall), which the
    coupling's damping would arrest with twice the squeeze. While braking the station says
    SAFE, so the world keeps re-indexing it (the tool moves with the device in the station's
    frame); it couples once the coupling's damping on the device's motion would be within
    the brake's cap (and BRAKE_FLOOR of its limit), or after BRAKE_MAX_S."""
    if s.fresh == 0:
        s.braking = 1
        s.brake_s = 0.0
        return 0
    if s.braking == 0 or s.cut == 1:
        return s.braking
    if s.brake_s < BRAKE_MAX_S:
        for c in range(3):
            if (
                _damping(s, c) * abs(s.world[0].twist[c])
                > BRAKE_SHARE * abs(_left(s, c)) + BRAKE_FLOOR * s.limits[c]
            ):
                s.brake_s += s.dt
                s.rejoin_brakes += 1
                return 1
    s.braking = 0
    return 0


@njit(cache=True)
def _rejoin_coupling(s):
    """The coupling on a return (_brakes): while braking, the squeeze it left with and the
    device's own motion damped with at most BRAKE_SHARE of it; once coupled, blended into
    the live spring and the whole damping over `ramp_s` (then the coupling as before, bit
    for bit). The live spring's lag behind a moving device (the round trip at 50 mm/s:
    0.2 N on the maglev's 2 kN/m) is not rendered."""
    braking = _brakes(s)
    if braking == 1 or s.fresh == 0:
        s.damping_gain = 0.0
    else:
        s.damping_gain = min(1.0, s.damping_gain + s.dt / s.ramp_s)
    if s.fresh == 0 or s.cut == 1 or s.damping_gain == 1.0:
        return  # going safe, or a reading not finite (zero), as before
    g = s.damping_gain
    for c in range(3):
        base = _left(s, c)
        spring = base + g * (s.spring[c] - base)
        cap = BRAKE_SHARE * abs(base)
        damp = s.coupling[c] - s.spring[c]
        if braking == 1:
            damp = -_damping(s, c) * s.world[0].twist[c]
        held = min(cap, max(-cap, damp))
        s.coupling[c] = spring + held + g * (damp - held)
        s.spring[c] = spring  # as rendered (the log's), the live one was _rejoins' to judge


@njit(cache=True)
def _passivity(s):
    """The station's end of the port link's passivity observer and controller
    (docs/stations.md, "Passivity"; Ryu and Hannaford's PO/PC on the whole link, each end's
    energy exchanged in the messages). Per axis, the net work the device has done on the
    rendered coupling, -f v dt summed (world frame), is this end's `energy` (sent to the
    world); with the world's end's (`budget`, a one-way delay old) it is the energy the link
    holds. A tick whose output f v dt would leave the link with less than none gets the
    damping alpha = deficit / (v^2 dt) (at most pc_max) against the device's motion, so
    the link gives out no more than it holds. Observed always; the controller acts if
    `passivity`."""
    w = s.world[0]
    for c in range(3):
        s.pc_damping[c] = 0.0
    if s.cut == 1 or s.gain == 0.0:
        return
    for c in range(3):
        v = w.twist[c]
        out = s.gain * s.coupling[c] * v * s.dt
        held = s.energy[c] + s.budget[c] - out
        alpha = 0.0
        if s.passivity == 1:
            alpha = pc_damping(held, out, s.gain * v * v * s.dt, s.pc_max[c])
        if alpha > 0.0:
            s.pc_damping[c] = alpha
            s.coupling[c] -= alpha * v
            out = s.gain * s.coupling[c] * v * s.dt
        s.energy[c] -= out


@njit(cache=True, inline="always")
def _radius(half, angle, ax, ay):
    """A rectangle's half extent (half-sizes `half`, turned by `angle`) along the axis (ax, ay)."""
    c, s = math.cos(angle), math.sin(angle)
    return half[0] * abs(c * ax + s * ay) + half[1] * abs(-s * ax + c * ay)


@njit(cache=True)
def pad_depth(s, x, y, angle, ahead):
    """How deep the pad at (x, y, angle) is in the object, carried on by its twist for
    `ahead` s (m; 0 if apart), by the separating axes of the two rectangles: the least
    overlap over the four edge normals, its normal (from the object to the pad) in
    s.normal. Kept as it was when apart (the fade out renders along the last one)."""
    ox = s.object_pose[0] + s.object_twist[0] * ahead
    oy = s.object_pose[1] + s.object_twist[1] * ahead
    oa = s.object_pose[2] + s.object_twist[2] * ahead
    return depth_at(s, x, y, angle, ox, oy, oa)


@njit(cache=True)
def depth_at(s, x, y, angle, ox, oy, oa):
    """pad_depth against the object at (ox, oy, oa)."""
    dx, dy = x - ox, y - oy
    best, nx, ny = math.inf, 0.0, 0.0
    for k in range(4):
        turn = angle if k < 2 else oa
        ax, ay = (
            (math.cos(turn), math.sin(turn)) if k % 2 == 0 else (-math.sin(turn), math.cos(turn))
        )
        d = dx * ax + dy * ay
        overlap = _radius(s.pad_half, angle, ax, ay) + _radius(s.object_half, oa, ax, ay) - abs(d)
        if overlap <= 0.0:
            return 0.0
        if overlap < best:
            sign = 1.0 if d >= 0.0 else -1.0
            best, nx, ny = overlap, sign * ax, sign * ay
    s.normal[0], s.normal[1] = nx, ny
    return best


@njit(cache=True)
def _see_object(s, ahead):
    """The object as the local contact renders it (docs/stations.md, "The local model at the
    station"): where the world last sent it, carried on by its twist for `ahead`, low-passed
    with time constant `object_tau` (pose and twist alike): the object's reported motion is
    the devices' own common motion a round trip late, and a spring about it rendered as it
    comes closes a delayed loop through both stations that rings at the device's own
    frequency on k_s (8.5 Hz on the maglev at 150 ms one way). Taken as it is on the first
    tick of contact (has_seen 0)."""
    a = 1.0 if s.has_seen == 0 or s.object_tau <= s.dt else s.dt / s.object_tau
    s.has_seen = 1
    for c in range(3):
        target = s.object_pose[c] + s.object_twist[c] * ahead
        err = target - s.object_seen[c]
        if c == 2:
            err = wrap_angle(err)
        s.object_seen[c] += a * err
        s.object_seen_twist[c] += a * (s.object_twist[c] - s.object_seen_twist[c])


@njit(cache=True)
def _local_contact(s, ahead):
    """The local model (docs/stations.md, "The local model at the station"): the device's pad
    against the object where the world last sent it (carried on by its twist for `ahead`,
    low-passed: _see_object), rendered here at once with the coupling in series with the
    world's contact, k_s = K_n k_c / (K_n + k_c), along the contact's normal n: F_loc = k_s
    depth n (it only pushes). Where it is active the coupling keeps only its tangent: f <- f
    - w (f.n) n + w F_loc, w fading over `fade_s` towards 1 in contact (fresh, coupled, no
    brake) and 0 out of it. The world's tool stays coupled to the device: it squeezes the
    object as at 0 ms. The coupling's damping along n comes with it, B_n (v_object - v_dev)
    . n, the sum clipped at zero (it only pushes). Before the ramp and the passivity
    controller, which see it as the coupling."""
    for c in range(3):
        s.local_force[c] = 0.0
    s.depth = 0.0
    on = s.local_model == 1 and s.cut == 0 and s.fresh == 1 and s.damping_gain == 1.0
    on = on and s.indexed == 0  # re-indexed, the object is where the device was, not is
    if not on:
        s.contact_w = 0.0  # going safe, braking or cut: the coupling as before, bit for bit
        s.has_seen = 0  # the object taken as it is when the contact comes back
        return
    w = s.world[0]
    _see_object(s, ahead)
    o = s.object_seen
    s.depth = depth_at(s, w.pose[0], w.pose[1], w.pose[2], o[0], o[1], o[2])
    target = 1.0 if s.depth > 0.0 else 0.0
    step = s.dt / s.fade_s
    s.contact_w += min(step, max(-step, target - s.contact_w))
    if abs(target - s.contact_w) < 0.5 * step:  # the sum's rounding: the end exactly
        s.contact_w = target
    if s.contact_w == 0.0:
        return
    nx, ny = s.normal[0], s.normal[1]
    kn = (
        min(s.stiffness[0], s.max_stiffness[0]) * nx * nx
        + min(s.stiffness[1], s.max_stiffness[1]) * ny * ny
    )
    k_s = kn * s.contact_stiffness / (kn + s.contact_stiffness) if kn > 0.0 else 0.0
    # the coupling's damping along n goes with it: B_n times the rate of the depth
    bn = _damping(s, 0) * nx * nx + _damping(s, 1) * ny * ny
    v = s.object_seen_twist
    rate = nx * (v[0] - w.twist[0]) + ny * (v[1] - w.twist[1])
    push = max(0.0, k_s * s.depth + bn * rate)  # it only pushes
    s.local_force[0], s.local_force[1] = push * nx, push * ny
    along = s.coupling[0] * nx + s.coupling[1] * ny
    g = s.contact_w
    s.coupling[0] += g * (s.local_force[0] - along * nx)
    s.coupling[1] += g * (s.local_force[1] - along * ny)


#: The hold's spring slips past this share of the device's limit (its anchor follows the
#: device), so a user who pushes on with no world meets a bounded force: the maglev's 5 N,
#: over twice the grasp's 2 N squeeze
HOLD_SHARE = 0.1


@njit(cache=True)
def _hold(s):
    """The station's safe state (docs/stations.md, "The join"), acting whenever its ramp's
    gain is below 1: its device held by its own scene's coupling (the spring K and damper B
    of `max_stiffness`, `max_damping`, world frame) to a fixed anchor, F = K (x_h - x) - B v,
    so that its user's push does not carry it off while it has no world: it comes back to
    the coupling at rest and where the world re-indexes its tool. The anchor is taken on the
    first finite reading of each safe episode (the start, or the tick the gain leaves 1):
    where the coupling last put the device, x_h = x + spring / K (the spring the tick
    renders: none before the first tool state, so the device's pose then), so the force
    its user meets goes on as it was and a constant push does not move it. The episode ends
    when the gain is back at 1. The spring is clipped at HOLD_SHARE of the device's limit,
    its anchor slipping with the device past it (a friction element: what it stores is at
    most cap^2 / 2K). A spring to a fixed anchor and a damper are passive. Into hold_force
    (world frame) and hold_out (device frame); zero on a cut. At the full coupling only
    hold_force is zeroed (the log's): hold_out is read with the weight 1 - gain."""
    w = s.world[0]
    for c in range(3):
        s.hold_force[c] = 0.0
    if s.gain == 1.0:
        s.has_hold = 0  # coupled: the next safe entry takes its own anchor
        return
    if s.cut == 0:
        if s.has_hold == 0:
            s.has_hold = 1
            for c in range(3):
                k = s.max_stiffness[c]
                s.hold_pose[c] = w.pose[c] + (s.spring[c] / k if k > 0.0 else 0.0)
        for c in range(3):
            k = s.max_stiffness[c]
            err = s.hold_pose[c] - w.pose[c]
            if c == 2:
                err = wrap_angle(err)
            cap = HOLD_SHARE * s.limits[c]
            if k * abs(err) > cap:  # slip: the anchor follows to the cap's stretch
                err = math.copysign(cap / k, err)
                s.hold_pose[c] = w.pose[c] + err
            s.hold_force[c] = k * err - s.max_damping[c] * w.twist[c]
    map_command_to_device(s.map, s.hold_force, s.limits, s.hold_out)


@njit(cache=True)
def station_tick(station, dev):
    """One tick (module docstring)."""
    s = station[0]
    read_device(s.user, s.t, dev, s.hand, s.sensors, s.map, s.world)
    w = s.world[0]
    sen = s.sensors[0]
    s.cut = 0
    for c in range(3):
        if not (math.isfinite(w.pose[c]) and math.isfinite(w.twist[c])):
            s.cut = 1
    fresh = 1 if s.have_tool == 1 and s.held == 0 and s.tool_age < s.watchdog_s else 0
    ahead = min(s.tool_age, s.extrapolate_s)
    bad = False
    for c in range(3):
        s.coupling[c] = 0.0
        s.spring[c] = 0.0
        if s.cut == 0 and s.have_tool == 1:
            k = min(s.stiffness[c], s.max_stiffness[c])
            b = _damping(s, c)
            err = s.tool_pose[c] + s.tool_twist[c] * ahead - w.pose[c]
            if s.indexed == 1:  # the stretch, not the device's motion over the round trip
                err = s.tool_pose[c] - s.device_echo[c]
            if c == 2:
                err = wrap_angle(err)
            s.spring[c] = k * err
            s.coupling[c] = s.spring[c] + b * (s.tool_twist[c] - w.twist[c])
            if not math.isfinite(s.coupling[c]):
                bad = True
    s.fresh = _rejoins(s, fresh)
    _rejoin_coupling(s)
    _local_contact(s, ahead)
    step = s.dt / s.ramp_s
    s.gain = min(1.0, s.gain + step) if s.fresh == 1 else max(0.0, s.gain - step)
    _note_squeeze(s)
    _passivity(s)
    _hold(s)
    map_command_to_device(s.map, s.coupling, s.limits, s.scratch)
    for c in range(3):
        v = s.gain * s.scratch[c] + (1.0 - s.gain) * s.hold_out[c]  # the hold: 0 on a cut
        if not math.isfinite(v):
            bad = True
            v = 0.0
        s.out[c] = min(s.limits[c], max(-s.limits[c], v))
    if bad:
        s.invalid += 1
        for c in range(3):
            s.out[c] = 0.0
    device_command(dev, s.out)
    device_advance(dev, s.dt, s.hand)
    map_rate_step(s.map, sen.pose, s.dt)
    s.t += s.dt


@njit(cache=True)
def station_row(station, rows, k, fault):
    """The tick into rows[k] (arrays and an index: a call with records costs more)."""
    s = station[0]
    row = rows[k]
    w = s.world[0]
    row.t = s.t - s.dt
    for c in range(3):
        row.pose[c] = w.pose[c]
        row.twist[c] = w.twist[c]
        row.hand[c] = s.hand[c]
        row.coupling[c] = s.coupling[c]
        row.spring[c] = s.spring[c]
        row.out[c] = s.out[c]
        row.tool_pose[c] = s.tool_pose[c]
        row.tool_twist[c] = s.tool_twist[c]
        row.stiffness[c] = s.stiffness[c]
        row.damping[c] = s.damping[c]
        row.budget[c] = s.budget[c]
        row.energy[c] = s.energy[c]
        row.pc_damping[c] = s.pc_damping[c]
        row.object_pose[c] = s.object_pose[c]
        row.object_twist[c] = s.object_twist[c]
        row.device_echo[c] = s.device_echo[c]
        row.local_force[c] = s.local_force[c]
        row.hold_force[c] = s.hold_force[c]
    row.tool_age = s.tool_age
    row.have_tool = s.have_tool
    row.gain = s.gain
    row.fresh = s.fresh
    row.held = s.held
    row.indexed = s.indexed
    row.cut = s.cut
    row.invalid = s.invalid
    row.fault = fault
    row.contact_w = s.contact_w
    row.depth = s.depth
