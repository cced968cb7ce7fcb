"""A haptic station's side of the link to its shared world, compiled (haptic_server/station.py
runs it; docs/stations.md):

- `take_tool`: one ToolState received on the port's key, checked
  (shared/protocol/station_codec.tool_refusal) and ordered, its tool, gains and object into
  the station's record, or refused and counted by reason. Within the world's epoch a
  message must be newer than the last taken; another epoch (a world restarted, or a second
  one) is taken only once the present one has been silent for the station's watchdog (the
  links' one order rule, shared/protocol/station.py's `order_code`);
- `station_step`: the tool's age, the station's tick (stages/station.py) and the tick's
  DeviceState (DEVICE_RECORD, filled in place: the device's pose and twist in the world
  unless its reading was not finite, SAFE while not rendering the coupling, CUT, a hand's
  glove from its user's script);
- `station_log`: the tick's row.

So a station's Python is its Zenoh calls and the device's noise refills: one compiled call a
ToolState received, two a tick.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.physics.passivity import carry_budget
from haptic_local_model.haptic_server.stages.hand import glove_at
from haptic_local_model.haptic_server.stages.station import station_row, station_tick
from haptic_local_model.shared.protocol.station import (
    CUT,
    GLOVE,
    HELD,
    INDEXED,
    REASONS,
    SAFE,
)
from haptic_local_model.shared.protocol.station_codec import (
    TOOL_FLOATS,
    admit,
    message_flags,
    message_floats,
    tool_refusal,
)

I8 = np.int64
TOOL_ENERGY = TOOL_FLOATS - 3  # a ToolState's energy: its last three numbers
STATION_LINK_DTYPE = np.dtype([
    ("has_last", I8), ("epoch", np.uint64), ("seq", np.uint64),  # the last ToolState taken
    ("tool_ns", I8),  # when it was taken (the loop's clock)
    ("received", I8), ("rejected", I8), ("reasons", I8, len(REASONS)),
    ("t0_ns", I8),  # the loop's first tick: a hand's glove script's clock
    ("n_glove", I8),  # rows of a hand's glove script (0: not a hand's station)
    ("safe_entries", I8), ("was_safe", I8),  # times the ramp reached the safe state
    # the world's end's energy (its ToolStates') minus this, the station's budget: set on each
    # world's first ToolState so the budget carries on across worlds (station._passivity)
    ("energy_base", np.float64, 3),
])  # fmt: skip


def station_link() -> np.ndarray:
    link = np.zeros(1, STATION_LINK_DTYPE)
    link[0]["was_safe"] = 1  # a station starts safe: its first coupling is no safe entry
    link[0]["t0_ns"] = -1
    return link


@njit(cache=True)
def take_tool(station, link, p, now_ns, raw):
    """Port p's ToolState `raw` (bytes) at now_ns, taken or refused and counted (module
    docstring)."""
    s, c = station[0], link[0]
    silent = now_ns - c.tool_ns >= s.watchdog_s * 1e9  # the station's own watchdog
    taken, epoch, seq, first = admit(c, raw, tool_refusal(raw, p), silent)
    if not taken:
        return
    f = message_floats(raw, TOOL_FLOATS)
    # a world's first: its count starts anew, the budget carries on
    carry_budget(c.energy_base, s.budget, f, TOOL_ENERGY, first)
    c.epoch, c.seq, c.has_last, c.tool_ns = epoch, seq, 1, now_ns
    c.received += 1
    for a in range(3):
        s.tool_pose[a] = f[a]
        s.tool_twist[a] = f[3 + a]
        s.stiffness[a] = f[6 + a]
        s.damping[a] = f[9 + a]
        s.object_pose[a] = f[12 + a]
        s.object_twist[a] = f[15 + a]
        s.device_echo[a] = f[18 + a]
    s.have_tool = 1
    flags = message_flags(raw)
    s.held = 1 if flags & HELD else 0
    s.indexed = 1 if flags & INDEXED else 0


@njit(cache=True)
def station_step(station, dev, link, msg, glove, now_ns, wall_ns, seq):
    """One tick at now_ns: the tool's age, the station's tick, and the tick's DeviceState in
    msg (seq, publish time wall_ns; a hand's glove from `glove`, its script, on the loop's
    clock from its first tick)."""
    s, c, r = station[0], link[0], msg[0]
    if c.t0_ns < 0:
        c.t0_ns = now_ns
    if s.have_tool == 1:
        s.tool_age = (now_ns - c.tool_ns) / 1e9
    station_tick(station, dev)
    w = s.world[0]
    r.seq = seq
    r.publish_time_ns = wall_ns
    for a in range(3):
        r.pose[a] = 0.0 if s.cut == 1 else w.pose[a]
        r.twist[a] = 0.0 if s.cut == 1 else w.twist[a]
        r.energy[a] = s.energy[a]
    flags = (SAFE if s.fresh == 0 or s.braking == 1 else 0) | (CUT if s.cut == 1 else 0)
    if c.n_glove > 0:
        n = min(glove.shape[1] - 1, len(r.glove))  # a script wider than the message: cut
        glove_at(glove, c.n_glove, (now_ns - c.t0_ns) / 1e9, n, r.glove[:n], r.glove_rate[:n])
        flags |= GLOVE
    r.flags = flags
    safe = 1 if s.gain == 0.0 else 0
    if safe == 1 and c.was_safe == 0:
        c.safe_entries += 1
    c.was_safe = safe


@njit(cache=True)
def station_log(station, link, rows, k, now_ns, late_ns, work_ns):
    """The tick into rows[k], with the loop's figures and the counters."""
    station_row(station, rows, k, station[0].sensors[0].fault)
    row = rows[k]
    row.wall_ns = now_ns
    row.late_us = late_ns / 1e3
    row.work_us = work_ns / 1e3
    row.received = link[0].received
    row.rejected = link[0].rejected
