"""A shared world's ports, compiled (haptic_server/shared_world.py runs them; docs/stations.md):

- `take_device`: one DeviceState received on a port's key, checked
  (shared/protocol/station_codec.device_refusal) and ordered by the links' one order rule
  (shared/protocol/station.py's `order_code`; tests/test_world_ports.py checks the compiled
  take against the reference decoder and the rule run as Python, `order_refusal`), its
  fields taken, or refused and counted by reason;
- `step_ports`: each port's state this tick (HELD, INDEXING, COUPLED: shared_world's
  docstring) and the device pose and twist it feeds its tool;
- `fill_tool`: a port's ToolState, its TOOL_RECORD filled in place.

The world's engines (haptic_server/world_engines.py) wrap `step_ports`, their tick and
`fill_tool` in one compiled call a tick, so the world's Python is its Zenoh calls: one
compiled call a message received and one a tick (the same tick in Python took about four
times the co-simulation's own work).

Records, not objects: a port's state is a PORT_LINK_DTYPE record (its last DeviceState's
fields in it), the tick's inputs and settings a WORLD_CLOCK_DTYPE record, the state changes
an EVENT_DTYPE array the summary reads.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.physics.passivity import (
    PC_MAX_OVER_B,
    carry_budget,
    pc_damping,
)
from haptic_local_model.shared.protocol.station import (
    CUT,
    GLOVE,
    HELD,
    INDEXED,
    MAX_GLOVE_JOINTS,
    REASONS,
    SAFE,
    tool_record,
)
from haptic_local_model.shared.protocol.station_codec import (
    DEVICE_FLOATS,
    admit,
    device_refusal,
    message_flags,
    message_floats,
)

HELD_STATE, INDEXING, COUPLED = 0, 1, 2
STATE_NAMES = ("held", "indexing", "coupled")
#: What an engine does with a hand's glove this tick (a tool has none).
GLOVE_AS_BEFORE, GLOVE_TAKE_START, GLOVE_HOLD = 0, 1, 2
DEVICE_ENERGY = DEVICE_FLOATS - 3  # a DeviceState's energy: its last three numbers
EXTRAPOLATE_S = 0.005  # a device's pose carried on by its twist at most this (as a station's)
MAX_EVENTS = 10_000  # port state changes kept for the summary and the log
J = MAX_GLOVE_JOINTS

F8, I8 = np.float64, np.int64
PORT_LINK_DTYPE = np.dtype([
    ("state", I8), ("anchor", F8, 3), ("offset", F8, 3), ("start", F8, 3), ("blend", F8),
    # the last DeviceState taken
    ("has_last", I8), ("epoch", np.uint64), ("seq", np.uint64), ("pose", F8, 3),
    ("twist", F8, 3), ("flags", I8), ("glove", F8, J), ("glove_rate", F8, J), ("rx_ns", I8),
    ("received", I8), ("rejected", I8), ("reasons", I8, len(REASONS)),
    # what this tick feeds the port's tool: the device's pose and twist, the glove's action
    ("fed_pose", F8, 3), ("fed_twist", F8, 3), ("glove_act", I8), ("glove_start", F8, J),
    # the passivity observer and controller at the port's tool (port_passivity): the
    # station's end's energy less energy_base (set on each station's first DeviceState, so
    # the budget carries on across stations), the tool's net work on the coupling while
    # coupled, and the controller's damping this tick
    ("budget", F8, 3), ("energy_base", F8, 3), ("energy", F8, 3), ("pc_damping", F8, 3),
])  # fmt: skip
WORLD_CLOCK_DTYPE = np.dtype([
    ("now_ns", I8),  # the tick's monotonic time (the loop's): ages and silence
    ("wall_ns", I8),  # the ToolStates' publish time
    ("t", F8), ("k", I8), ("seq", I8),  # the tick's time, its row's index, its ToolStates' seq
    ("n_ports", I8), ("dt", F8), ("watchdog_ms", F8), ("ramp_ms", F8),
    ("object", I8),  # a co-simulation's first dof of the body each ToolState carries
    ("n_events", I8), ("events_dropped", I8),
    ("last_tick_ns", I8),  # the previous tick's now_ns (0 before the first)
    ("stalls", I8),  # ticks that came more than the watchdog after the one before
    ("held_until_ns", I8),  # after a stall every port is held until then
    ("passivity", I8),  # 1: the ports' passivity controllers act; 0: observers only
])  # fmt: skip
EVENT_DTYPE = np.dtype([("t", F8), ("port", I8), ("frm", I8), ("to", I8)])


def port_links(n_ports: int) -> np.ndarray:
    """Every port's record, HELD with nothing taken."""
    return np.zeros(n_ports, PORT_LINK_DTYPE)


def world_clock(n_ports: int, dt: float, watchdog_ms: float, ramp_ms: float) -> np.ndarray:
    clock = np.zeros(1, WORLD_CLOCK_DTYPE)
    c = clock[0]
    c["n_ports"], c["dt"], c["watchdog_ms"], c["ramp_ms"] = n_ports, dt, watchdog_ms, ramp_ms
    return clock


@njit(cache=True)
def silent(ps, c):
    """Nothing taken from port ps's station, or nothing for the watchdog."""
    return ps.has_last == 0 or (c.now_ns - ps.rx_ns) / 1e6 > c.watchdog_ms


@njit(cache=True)
def take_device(ports, clock, p, raw):
    """Port p's DeviceState `raw` (bytes), taken or refused and counted (module docstring).
    Within a station's epoch a message must be newer than the last taken; another epoch (a
    restarted station, or a second one on the port) only once the present one is silent."""
    c = clock[0]
    ps = ports[p]
    taken, epoch, seq, first = admit(ps, raw, device_refusal(raw, p), silent(ps, c))
    if not taken:
        return
    f = message_floats(raw, DEVICE_FLOATS)
    # a station's first: its count starts anew, the budget carries on
    carry_budget(ps.energy_base, ps.budget, f, DEVICE_ENERGY, first)
    ps.epoch, ps.seq = epoch, seq
    for a in range(3):
        ps.pose[a] = f[a]
        ps.twist[a] = f[3 + a]
    for j in range(J):
        ps.glove[j] = f[6 + j]
        ps.glove_rate[j] = f[6 + J + j]
    ps.flags = message_flags(raw)
    ps.has_last = 1
    ps.rx_ns = c.now_ns
    ps.received += 1


@njit(cache=True)
def _live(ps, age_s, a):
    """The station's device in the world, axis a: re-indexed, carried on by its twist for at
    most EXTRAPOLATE_S (an old reading is not carried on into a guess)."""
    return ps.pose[a] + ps.offset[a] + ps.twist[a] * min(age_s, EXTRAPOLATE_S)


@njit(cache=True)
def _event(c, events, p, frm, to):
    if c.n_events < len(events):
        e = events[c.n_events]
        e.t, e.port, e.frm, e.to = c.t, p, frm, to
        c.n_events += 1
    else:
        c.events_dropped += 1


@njit(cache=True)
def stalled(c):
    """Whether this tick comes more than the watchdog after the last (the world's process
    stopped or starved): its stations went safe meanwhile, and what it takes now was sent
    before. Notes the tick's time for the next."""
    gap = c.last_tick_ns > 0 and (c.now_ns - c.last_tick_ns) / 1e6 > c.watchdog_ms
    c.last_tick_ns = c.now_ns
    if gap:
        c.stalls += 1
        c.held_until_ns = c.now_ns + int(c.watchdog_ms * 1e6)
    return gap


@njit(cache=True)
def step_ports(ports, clock, events):
    """Each port's state this tick and the device pose and twist it feeds (shared_world's
    docstring), into its fed_pose, fed_twist and glove_act. After a stall of the world's own
    longer than the watchdog every port is held, as if its station had been silent for it,
    for a watchdog period more: what the world takes as it resumes was sent during the stall
    (the backlog drained in about 20 ms on loopback), and a re-index onto a device pose from
    it would put the tool where the device is no longer. Then coupled again only through
    SAFE and a re-index, never into the stretch it left."""
    c = clock[0]
    gap = stalled(c)
    for p in range(c.n_ports):
        ps = ports[p]
        if gap or c.now_ns < c.held_until_ns or silent(ps, c) or ps.flags & CUT:
            new = HELD_STATE
        elif ps.flags & SAFE:
            new = INDEXING
        else:  # rendering: coupled, unless it comes from HELD (it must go safe first)
            new = HELD_STATE if ps.state == HELD_STATE else COUPLED
        ps.glove_act = GLOVE_AS_BEFORE
        if new != ps.state:
            # held where it was last seen; after a stall, where the last tick before it fed
            # (what the stall's backlog says is where the device drifted while safe)
            if ps.state == COUPLED and not gap:
                for a in range(3):
                    ps.anchor[a] = ps.start[a] + ps.blend * (_live(ps, 0.0, a) - ps.start[a])
            _event(c, events, p, ps.state, new)
            if new == COUPLED:
                for a in range(3):
                    ps.start[a] = ps.anchor[a]
                ps.blend = 0.0
                ps.glove_act = GLOVE_TAKE_START
            elif ps.state == COUPLED and ps.flags & GLOVE:
                ps.glove_act = GLOVE_HOLD  # a hand's fingers held where its station left them
            ps.state = new
        if new == COUPLED:
            age_s = (c.now_ns - ps.rx_ns) / 1e9
            ps.blend = min(1.0, ps.blend + c.dt / (c.ramp_ms / 1e3))
            for a in range(3):
                ps.anchor[a] = ps.start[a] + ps.blend * (_live(ps, age_s, a) - ps.start[a])
                ps.fed_pose[a] = ps.anchor[a]
                ps.fed_twist[a] = ps.blend * ps.twist[a]
            continue
        for a in range(3):
            if new == INDEXING:
                ps.offset[a] = ps.anchor[a] - ps.pose[a]
            ps.fed_pose[a] = ps.anchor[a]
            ps.fed_twist[a] = 0.0


@njit(cache=True)
def fill_tool(tools, p, ps, c, q, qd, obj, obj_twist):
    """Port p's ToolState in tools[p]: its tool (pose q[:3], twist qd[:3], world frame) in its
    station's frame, and the object's (pose `obj`, twist `obj_twist`, world frame) likewise,
    for the station's local model. While the port is re-indexed every tick (INDEXING) the
    tool moves with the device in the station's frame: its twist there is its own plus the
    device's (the object's is its own: the station's local model is off until it couples),
    and the ToolState says INDEXED with the device pose it re-indexed on, so that the station
    can tell the coupling's stretch from its device's motion over the round trip."""
    r = tools[p]
    r.seq = c.seq
    r.publish_time_ns = c.wall_ns
    for a in range(3):
        r.pose[a] = q[a] - ps.offset[a]
        r.twist[a] = qd[a] + (ps.twist[a] if ps.state == INDEXING else 0.0)
        r.object_pose[a] = obj[a] - ps.offset[a]
        r.object_twist[a] = obj_twist[a]
        r.device_pose[a] = ps.pose[a]
        r.energy[a] = ps.energy[a]
    r.pose[2] = math.atan2(math.sin(r.pose[2]), math.cos(r.pose[2]))
    r.object_pose[2] = math.atan2(math.sin(r.object_pose[2]), math.cos(r.object_pose[2]))
    r.flags = HELD if ps.state == HELD_STATE else (INDEXED if ps.state == INDEXING else 0)


@njit(cache=True)
def port_passivity(ps, c, k, b, q, qd):
    """The world's end of port ps's passivity observer and controller, before the tick
    (docs/stations.md, "Passivity"): per axis, the power the coupling at the pose and twist
    fed would give the tool (pose q, twist qd), K (x_fed - x) + B (v_fed - v) times v. If
    it would leave the link with less than none (the tool's net work on it, `energy`, plus
    the station's end's, `budget`, a one-way delay old), the tool gets the damping
    alpha = deficit / (v^2 dt) (at most PC_MAX_OVER_B B) through the coupling: this tick's
    pose fed moves by -alpha v / K. For this tick only (the next is fed from the device
    again), so the controller's action is a force, never a drift of the pose fed from the
    device's. Acts only if the clock's `passivity`."""
    for a in range(3):
        ps.pc_damping[a] = 0.0
    if ps.state != COUPLED or c.passivity == 0:
        return
    for a in range(3):
        if k[a] <= 0.0:
            continue
        v = qd[a]
        force = k[a] * (ps.fed_pose[a] - q[a]) + b[a] * (ps.fed_twist[a] - v)
        out = force * v * c.dt
        held = ps.energy[a] + ps.budget[a] - out
        alpha = pc_damping(held, out, v * v * c.dt, PC_MAX_OVER_B * b[a])
        if alpha > 0.0:
            ps.pc_damping[a] = alpha
            ps.fed_pose[a] -= alpha * v / k[a]


@njit(cache=True)
def observe_axis(ps, a, force, v, dt):
    """The world's passivity observer on port ps's axis a after the tick: the coupling's
    `force` on the tool moving at `v`, while coupled: the tool's work on the coupling,
    -force v dt, into `energy` (sent to the station)."""
    if ps.state == COUPLED:
        ps.energy[a] -= force * v * dt


def warm_records(n_ports: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fresh ports, clock, events and ToolStates to compile a world's step with (its own
    would be stepped)."""
    tools = np.concatenate([tool_record(p, 0) for p in range(n_ports)])
    clock = world_clock(n_ports, 1e-3, 50.0, 100.0)
    return port_links(n_ports), clock, np.zeros(1, EVENT_DTYPE), tools
