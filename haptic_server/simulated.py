"""A tick with a simulated hand and device in one compiled call, and a burst of such ticks.

The hand (haptic_server.users) holds the simulated device (device_models.kernels, picked by
the device's record types at compile time) and the engine step (haptic_server.stages.tick)
runs between the device's reading and its command: the order of the engine's Python tick,
in one Python -> numba transition instead of eight. `run_ticks` runs a span of ticks at a
fixed dt (the virtual clock's ticks between two sim steps), each row into a caller's array.
"""

from __future__ import annotations

from numba import njit

from haptic_local_model.device_models.kernels import (
    device_advance,
    device_applied,
    device_command,
    device_noise_ready,
    device_read,
    device_sense_hand,
    device_true_state,
)
from haptic_local_model.haptic_server.stages.tick import engine_step, store_applied
from haptic_local_model.haptic_server.users import hand_wrench


@njit(cache=True)
def simulated_tick(recs, dev, user, dt, lateness_us, work_us):
    """One tick: the hand on the device's true state -> the device's reading -> the engine
    step -> the command held by the device -> the device's physics over dt.

    recs is the engine's (model, data, io, world_map, clock, method marker), dev the device's
    DeviceRecords, user a USER_DTYPE[1] (kind USER_GIVEN: the hand is already in io.hand).
    Returns False, having done nothing, if the device's noise block does not cover dt: the
    caller refills it (NoiseBuffer.refill) and calls again."""
    if not device_noise_ready(dev, dt):
        return False
    io, world_map, clock = recs[2], recs[3], recs[4]
    u = user[0]
    hand = io[0].hand
    device_true_state(dev, u.device_pose, u.device_twist)
    hand_wrench(user, clock[0].t - u.start_s, u.device_pose, u.device_twist, hand)
    device_sense_hand(dev, hand)
    device_read(dev, io[0].sensors)
    engine_step(recs, dt, lateness_us, work_us)
    device_command(dev, io[0].command)
    store_applied(world_map, device_applied(dev), recs[1])
    device_advance(dev, dt, hand)
    return True


@njit(cache=True)
def run_ticks(recs, dev, user, dt, rows, start, stop):
    """Ticks start..stop-1 at a fixed dt, row k into rows[k]. Returns the first tick not run:
    stop, or earlier when the device's noise block needs a refill (the caller refills it and
    calls again)."""
    data = recs[1]
    for k in range(start, stop):
        if not simulated_tick(recs, dev, user, dt, 0.0, 0.0):
            return k
        rows[k] = data[0].row
    return stop
