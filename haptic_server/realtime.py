"""The local model as a kind of the one compiled real-time loop (haptic_server.paced).

`local_paced` is paced_ticks over the local model's kind, a cached entry point as each port
world kind's: it runs tick after tick of a simulated device without returning to Python.
The kind's hook (`local_asks`, after each tick's opening) validates and installs what waits
in the mailbox (haptic_server.mailbox.take_updates) and re-arms the watchdog on an install;
it hands the opened tick (its start, lateness and dt in the LOOP_DTYPE record) to the
supervisor's Python side (RETURNED_SUPERVISE) as soon as that tick needs it: the run's end,
a watchdog that may trip, an update that may start a new epoch or needs the engine's
follow-up (after a trip, FOH setpoints). The kind's burst (`local_burst`) runs the tick
(haptic_server.simulated) and pushes its row and timing into the sidecar's ring; after a
tick that brought a new fault it asks to be back in Python (return_at_ns = 0) for the
report. paced_ticks returns for a spent noise block (refill, call again), and between two
ticks once `return_at_ns` has passed, so the Python side sees stop requests and signals
every RETURN_EVERY_NS (50 ms). The loop (haptic_server.loop) runs an opened tick that
needs the supervisor as before.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.mailbox import (
    C_UPD_HEAD,
    C_UPD_READ,
    MAILBOX_DTYPE,
    N_CTL,
    push_row,
    take_updates,
)
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.paced import (
    kind_kernel,
    loop_record,
    open_tick,
    paced_entry,
    paced_ticks,
)
from haptic_local_model.haptic_server.simulated import simulated_tick
from haptic_local_model.haptic_server.stages.install import EPOCH_LAW_LIVE
from haptic_local_model.shared.atomics import load_acquire
from haptic_local_model.shared.clock import realtime_ns
from haptic_local_model.shared.protocol.update import epoch_of


@njit(cache=True)
def _quiet_installs(lp, ring_io, recs, ts):
    """Take the waiting updates that need no Python; False if the tick needs the supervisor
    (the next one may start a new epoch, or the engine awaits a follow-up)."""
    ctl, mailbox, age_window = ring_io[1], ring_io[2], ring_io[5]
    data, clock, install = recs[1], recs[4], recs[6]
    ins = install[0]
    taken = 0
    while taken < lp.budget:
        read = load_acquire(ctl, C_UPD_READ)
        if read >= load_acquire(ctl, C_UPD_HEAD):  # afresh: the sidecar writes it
            break
        slot = mailbox[read % mailbox.shape[0]]
        if clock[0].ready == 0 or ins.follow == 1 or data[0].state.fault != 0:
            return False  # the install needs the engine's Python side (re-initialisation)
        if ins.epoch_law != EPOCH_LAW_LIVE and epoch_of(slot.raw, slot.length) != ins.epoch:
            return False  # the update may begin an epoch (live, another is only rejected)
        n, installed, follow, seq, latency = take_updates(
            ctl, mailbox, lp.tick, realtime_ns(ts), 1, recs
        )
        taken += n
        lp.received += n
        if installed:
            lp.installed += installed
            lp.last_valid_ns = lp.now_ns
            lp.trip_at_ns = lp.now_ns + lp.watchdog_ns
            lp.newest_seq = seq
            lp.newest_age_ms = latency * 1e3
            age_window[lp.age_count % age_window.shape[0]] = lp.newest_age_ms
            lp.age_count += 1
            lp.age_max = max(lp.age_max, lp.newest_age_ms)
            clock[0].update_seq = seq
            clock[0].update_age_ms = lp.newest_age_ms
        if follow:  # cannot happen after the checks above; the supervisor sorts it out
            return False
    return True


@kind_kernel
def local_asks(w, lp, ts):
    """The local model's kind hook, after a tick's opening: the quiet installs taken; whether
    the opened tick needs the supervisor (the run's end, a watchdog that may trip, an
    install that needs the engine's Python side). w: local_burst's."""
    now = lp.now_ns
    return now >= lp.end_ns or now > lp.trip_at_ns or not _quiet_installs(lp, w[4], w[0], ts)


@kind_kernel
def local_burst(w, ring, start, stop):
    """Ticks start..stop-1 of the simulated device (paced_ticks runs one: the opened tick's
    dt, lateness and the work of the tick before, from the loop record), each row pushed
    into the sidecar's `ring` with its timing; the first tick not run (stop, or start when
    the device's noise block needs a refill). After a tick that brought a new fault, the
    loop is to be back in Python (return_at_ns = 0). w: (the engine's records (model, data,
    io, world_map, clock, method marker, install), the device's DeviceRecords,
    USER_DTYPE[1], the loop record, (ring, ctl, mailbox, lateness window, work window,
    update-age window, peaks, the engine's row view))."""
    recs, dev, user, lp, ring_io = w[0], w[1], w[2], w[3][0], w[4]
    tick_recs = (recs[0], recs[1], recs[2], recs[3], recs[4], recs[5])
    for k in range(start, stop):
        if not simulated_tick(tick_recs, dev, user, lp.dt, lp.lateness_ns / 1e3, lp.work_prev_us):
            return k
        push_row(ring, ring_io[1], ring_io[7], ring_io[3], ring_io[4], ring_io[6])
        if recs[1][0].state.fault != lp.fault_reported:
            lp.return_at_ns = 0  # Python is to report it, after this tick
    return stop


@paced_entry(local_asks, local_burst)
def local_paced(w, ring, loop, windows, ts):
    """The local model's real-time loop: paced_ticks over local_asks and local_burst."""
    return paced_ticks(local_asks, local_burst, w, ring, loop, windows, ts)


def local_windows(ring_io: tuple[Any, ...]) -> tuple[np.ndarray, ...]:
    """paced_ticks' windows for the local model: its lateness and work windows and peaks
    (float64[3]), which its rows' push keeps too (a tick the supervisor runs in Python
    writes them there only), and a one-slot scratch for the intervals it does not keep."""
    return ring_io[3], ring_io[4], np.zeros(1), ring_io[6]


def local_world(engine: Any, loop: np.ndarray, ring_io: tuple[Any, ...]) -> tuple[Any, ...]:
    """local_paced's world: the engine's records, its simulated device's, the user, the
    loop record, the ring's I/O (local_burst)."""
    return engine.loop_recs, engine.sim_device.records, engine.user, loop, ring_io


def compile_realtime_kernels(engine: Any) -> None:
    """Compile (or load from the cache) local_paced for `engine`'s records and device, before
    the loop starts: on copies, with the run's end already reached (it returns at the first
    tick, without waiting)."""
    sim = engine.sim_device
    loop = loop_record(1000, (0.25, 2.0), 1)
    open_tick(loop, 0)
    if sim is None:
        return
    copies = engine.loop_recs_copy()
    dev = tuple(r.copy() for r in sim.records)
    ring_io = (
        np.zeros(2, TICK_DTYPE), np.zeros(N_CTL, np.int64), np.zeros(1, MAILBOX_DTYPE),
        np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(3), copies[1]["row"],
    )  # fmt: skip
    w = (copies, dev, engine.user.copy(), loop, ring_io)
    local_paced(w, ring_io[0], loop, local_windows(ring_io), np.zeros(2, np.int64))
