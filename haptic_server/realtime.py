"""The real-time loop's quiet ticks in one compiled call: wait, take updates, tick, log row.

`realtime_ticks` runs tick after tick of a simulated device without returning to Python:
it waits for each deadline (sleep, then spin, on the monotonic clock), validates and
installs what waits in the mailbox (haptic_server.mailbox.take_updates), re-arms the
watchdog on an install, runs the tick (haptic_server.simulated) and pushes its row and
timing into the sidecar's ring. It returns — with the tick it has opened (its start,
lateness and dt in the LOOP_DTYPE record, haptic_server.paced: the wait and the opening
are every compiled loop's) but not run — as soon as that tick needs the
supervisor's Python side: the run's end, a watchdog that may trip, an update that may start
a new epoch or needs the engine's follow-up (after a trip, FOH setpoints), the device's
noise block spent. It also returns, between two ticks, once `return_at_ns` has passed, so
the Python side sees stop requests and signals every RETURN_EVERY_NS (50 ms). The loop
(haptic_server.loop) runs an opened tick as before.
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
    RETURNED_NOISE,
    RETURNED_SUPERVISE,
    RETURNED_TO_PYTHON,
    loop_record,
    open_tick,
    open_tick_at,
)
from haptic_local_model.haptic_server.simulated import simulated_tick
from haptic_local_model.haptic_server.stages.install import EPOCH_LAW_LIVE
from haptic_local_model.shared.atomics import load_acquire
from haptic_local_model.shared.clock import monotonic_ns, realtime_ns, wait_until_ns
from haptic_local_model.shared.protocol.update import epoch_of


@njit(cache=True)
def _quiet_installs(lp, ring_io, recs, ts):
    """Take the waiting updates that need no Python; False if the tick needs the supervisor
    (the next one may start a new epoch, or the engine awaits a follow-up)."""
    ctl, mailbox, age_window = ring_io[1], ring_io[2], ring_io[5]
    model, data, clock, install = recs[0], recs[1], recs[4], recs[5]
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
            ctl, mailbox, lp.tick, realtime_ns(ts), 1, model, data, install
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


@njit(cache=True)
def realtime_ticks(recs, dev, user, ring_io, loop, ts):
    """Run ticks until one needs Python (see the module docstring); returns the status.

    recs: the engine's (model, data, io, world_map, clock, install); dev: the device's
    DeviceRecords; user: USER_DTYPE[1]; ring_io: (ring, ctl, mailbox, lateness window,
    work window, update-age window, peaks, the engine's row view); loop: LOOP_DTYPE[1];
    ts: int64[2] scratch."""
    lp = loop[0]
    ring, ctl, lateness_w, work_w = ring_io[0], ring_io[1], ring_io[3], ring_io[4]
    peaks, row = ring_io[6], ring_io[7]
    tick_recs = (recs[0], recs[1], recs[2], recs[3], recs[4])
    while True:
        open_tick_at(lp, wait_until_ns(ts, lp.deadline_ns, lp.spin_ns))
        now = lp.now_ns
        if now >= lp.end_ns or now > lp.trip_at_ns or not _quiet_installs(lp, ring_io, recs, ts):
            lp.status = RETURNED_SUPERVISE
            return lp.status
        lateness_us = lp.lateness_ns / 1e3
        if not simulated_tick(tick_recs, dev, user, lp.dt, lateness_us, lp.work_prev_us):
            lp.status = RETURNED_NOISE
            return lp.status
        push_row(ring, ctl, row, lateness_w, work_w, peaks)
        lp.tick += 1
        end = monotonic_ns(ts)
        lp.work_prev_us = (end - now) / 1e3
        lp.deadline_ns += lp.period_ns
        # between two ticks: no tick is left opened; a new fault is Python's to report
        if end >= lp.return_at_ns or recs[1][0].state.fault != lp.fault_reported:
            lp.status = RETURNED_TO_PYTHON
            return lp.status


def compile_realtime_kernels(engine: Any) -> None:
    """Compile (or load from the cache) realtime_ticks for `engine`'s records and device,
    before the loop starts: on copies, with the run's end already reached (it returns at
    the first tick, without waiting)."""
    sim = engine.sim_device
    loop = loop_record(1000, (0.25, 2.0), 1)
    open_tick(loop, 0)
    if sim is None:
        return
    copies = tuple(r.copy() for r in (*engine.recs, engine.install))
    dev = tuple(r.copy() for r in sim.records)
    ring_io = (
        np.zeros(2, TICK_DTYPE), np.zeros(N_CTL, np.int64), np.zeros(1, MAILBOX_DTYPE),
        np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), copies[1]["row"],
    )  # fmt: skip
    realtime_ticks(copies, dev, engine.user.copy(), ring_io, loop, np.zeros(2, np.int64))
