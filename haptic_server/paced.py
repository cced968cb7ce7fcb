"""The one compiled real-time loop, `paced_ticks`: it serves every world that runs in this
process, the local model's (haptic_server.realtime, driven by the supervisor of
haptic_server.loop) and every port world's (driven by haptic_server.world.run_paced).

`LOOP_DTYPE` is a real-time loop's timing state, shared by its Python side and its compiled
part; `open_tick_at` is the one rule of a tick's start (lateness, dt, an overrun's resync).
`paced_ticks` runs a world kind's compiled ticks one a period without returning to Python:
it waits for each deadline (sleep, then spin, on the monotonic clock), opens the tick, asks
the kind whether the opened tick needs the Python side (`asks`: the local model's end,
watchdog and installs that need the engine's Python side; a port world's never does), runs
it through the kind's kernel (`burst`: its rows into a rows array, or the local model's into
the sidecar's ring) and keeps each tick's lateness, interval and work. The kind's functions
are arguments: the loop is inlined into a cached entry point of each kind's own, `*_paced`,
where they are direct calls. It returns only when Python is needed: the opened tick needs
the supervisor (it is left opened: the Python side runs it), a device's noise block is spent
(the tick is left opened: refill, then call again and it runs without waiting),
`return_at_ns` has passed after a tick (signals, stop requests, the next noise block drawn
in the slack; a kind's burst sets it to 0 to be back after its tick: the local model's new
fault, for Python to report), or `stop_tick` ticks are run.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.shared.clock import monotonic_ns, wait_until_ns
from haptic_local_model.shared.timing import spin_for

I8, F8 = np.int64, np.float64

#: Why a compiled loop returned (LOOP_DTYPE.status).
RETURNED_TO_PYTHON = 0  # return_at_ns passed, between two ticks: signals, stop requests
RETURNED_SUPERVISE = 1  # the opened tick needs the supervisor (end, watchdog, epoch, follow)
RETURNED_NOISE = 2  # a device's noise block is spent: refill, then run the opened tick
RETURNED_DONE = 3  # stop_tick ticks are run (a port world's rows)

#: A real-time loop's timing state, shared by its Python side and its compiled part. Every
#: field down to stop_tick, and now_ns..status, are paced_ticks' (every world's); end_ns
#: to age_max and fault_reported are the local model's kind's (its hook, its burst and its
#: supervisor: haptic_server.realtime, haptic_server.loop); a port world's leaves them.
LOOP_DTYPE = np.dtype(
    [
        ("period_ns", I8),
        ("spin_ns", I8),  # the wait spins this long before a deadline (shared.timing.spin_for)
        ("deadline_ns", I8),  # of the next tick
        ("last_start_ns", I8),  # start of the last tick opened
        ("dt_min", F8),  # measured dt is clamped to [dt_min, dt_max] s
        ("dt_max", F8),
        ("tick", I8),  # ticks run
        ("overruns", I8),
        ("skipped", I8),  # whole periods the overruns spanned: ticks never run
        ("late_over_1ms", I8),
        ("work_prev_us", F8),  # work of the last tick run (the local model's next row)
        ("return_at_ns", I8),  # hand the loop back to Python at the first tick from here
        ("stop_tick", I8),  # the run's ticks: returns RETURNED_DONE at it (a port world's rows)
        ("end_ns", I8),  # the supervisor's: the run ends
        ("trip_at_ns", I8),  # the supervisor's: the watchdog may trip after this
        ("watchdog_ns", I8),
        ("last_valid_ns", I8),  # the newest install (monotonic)
        ("budget", I8),  # updates taken per tick at most
        ("received", I8),  # updates taken from the mailbox by the kernel
        ("installed", I8),  # of which installed
        ("newest_seq", I8),
        ("newest_age_ms", F8),
        ("age_count", I8),  # samples written into the update-age window
        ("age_max", F8),
        ("now_ns", I8),  # the opened tick: its start, lateness and dt
        ("lateness_ns", I8),
        ("dt", F8),
        ("status", I8),
        ("fault_reported", I8),  # the state's fault the Python side has logged
    ]
)

#: paced_ticks' peaks (float64[3]): the latest tick's lateness (µs), the longest work (µs),
#: the latest tick's index
PEAK_LATE, PEAK_WORK, PEAK_LATE_TICK = 0, 1, 2


def loop_record(period_ns: int, dt_clamp: tuple[float, float], watchdog_ns: int) -> np.ndarray:
    rec = np.zeros(1, LOOP_DTYPE)
    lp = rec[0]
    lp["period_ns"] = period_ns
    lp["spin_ns"] = spin_for(period_ns)
    lp["dt_min"] = dt_clamp[0] * period_ns / 1e9
    lp["dt_max"] = dt_clamp[1] * period_ns / 1e9
    lp["watchdog_ns"] = watchdog_ns
    lp["stop_tick"] = np.iinfo(np.int64).max  # no end of its own (a port run sets its rows')
    lp["newest_seq"] = -1
    lp["newest_age_ms"] = np.nan
    return rec


@njit(cache=True)
def open_tick(loop, now):
    """open_tick_at, callable from Python (the loop's ticks that run there)."""
    open_tick_at(loop[0], now)


@njit(cache=True)
def open_tick_at(lp, now):
    """The tick starting at `now`: lateness, dt (measured, clamped), overrun resync (the
    whole periods it spanned counted as skipped)."""
    lateness = now - lp.deadline_ns
    dt_ns = now - lp.last_start_ns if lp.tick > 0 else lp.period_ns
    lp.last_start_ns = now
    if lateness > lp.period_ns:
        lp.overruns += 1
        lp.skipped += lateness // lp.period_ns
        lp.deadline_ns = now  # resynchronise: no burst of catch-up ticks
    if lateness > 1_000_000:
        lp.late_over_1ms += 1
    lp.now_ns = now
    lp.lateness_ns = lateness
    lp.dt = min(max(dt_ns / 1e9, lp.dt_min), lp.dt_max)


@njit(cache=True)
def _opened(lp, previous, late_w, interval_w, peaks):
    """The opened tick's lateness (µs, at its index) and its interval from the tick before
    (ms, at the index before: a first tick has none) into their windows."""
    late_us = lp.lateness_ns / 1e3
    late_w[lp.tick % late_w.shape[0]] = late_us
    if late_us > peaks[PEAK_LATE]:
        peaks[PEAK_LATE] = late_us
        peaks[PEAK_LATE_TICK] = lp.tick
    if lp.tick > 0:
        interval_w[(lp.tick - 1) % interval_w.shape[0]] = (lp.now_ns - previous) / 1e6


#: The decorator of a kind's two kernels (its hook and its burst): inlined (numba's IR) into
#: the kind's entry point (PacedEntry), where they run without reference counting too; a
#: runner that calls the burst from Python (the virtual clock's) gets it compiled on its own.
kind_kernel = njit(cache=True, inline="always")


@kind_kernel
def never_asks(world, lp, ts):
    """A port world's kind hook: its opened tick never needs the Python side."""
    return False


_WITHOUT_NRT: dict[str, Any] = {"_nrt": False}  # numba's flag; its type stubs do not name it


class PacedEntry:
    """A kind's cached entry point over paced_ticks (`*_paced`, decorated `paced_entry`),
    compiled without numba's reference counting (NRT).

    Every numba function increfs each array it is passed on entry and decrefs it on return:
    calling the kind's two kernels with the world every tick cost the local model's loop 80
    pairs of atomic operations a tick, 0.82 against 0.44 µs of work on the testbed in a
    burst without waits (`benchmarks/paced_overhead.py`). Without NRT the entry point itself
    counts nothing: it allocates nothing and keeps no array past its return, and its
    caller's references keep the world alive through the call.

    The kind's two kernels (`kind_kernel`) are inlined into it and count nothing either;
    what they call keeps its NRT. A function compiled from inside the entry point would be
    compiled in its context, without NRT too (numba's nested target context), and one that
    allocates (the install path's eigen-solver) would fail to compile. So on a world not seen
    before, the kind's kernels are compiled (or loaded from the cache) first on their own,
    with NRT, and with them everything they call: the entry point then only calls those."""

    def __init__(self, fn: Any, asks: Any, burst: Any, cache: bool = True) -> None:
        self.dispatcher = njit(cache=cache, **_WITHOUT_NRT)(fn)
        self.asks, self.burst = asks, burst
        self._world: Any = None  # the last world it was called with (kept)
        self._layouts: set[Any] = set()  # the arguments' layouts its kernels are compiled for
        self.__doc__ = fn.__doc__

    def __call__(self, world: Any, rows: Any, loop: Any, windows: Any, ts: Any) -> Any:
        if world is not self._world:  # a run's first call: its world, built once a run
            self._compile_kernels(world, rows, loop, ts)
            self._world = world
        return self.dispatcher(world, rows, loop, windows, ts)

    def _compile_kernels(self, world: Any, rows: Any, loop: Any, ts: Any) -> None:
        """The kind's kernels compiled (or loaded) for these arguments' types, unless they
        are for their layout already: numba's typeof of a world is ~10 ms (its record
        dtypes), and a run's first call, already opened, would wait for it (the warm-up
        compiled them on copies of the same layout)."""
        layout = _layout((world, rows, loop, ts))
        if layout in self._layouts:
            return
        from numba import typeof, types

        self.asks.compile((typeof(world), typeof(loop[0]), typeof(ts)))
        self.burst.compile((typeof(world), typeof(rows), types.int64, types.int64))
        self._layouts.add(layout)


def _layout(value: Any) -> Any:
    """What numba's type of `value` depends on, cheaply: an array's dtype, dimensions and
    flags, a tuple's members' (a record's or a scalar's Python type otherwise)."""
    if isinstance(value, tuple):
        return tuple(_layout(v) for v in value)
    if isinstance(value, np.ndarray):
        f = value.flags
        return (value.dtype, value.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned)
    return type(value)


def paced_entry(asks: Any, burst: Any) -> Any:
    """The decorator of a kind's entry point over paced_ticks with its kernels (PacedEntry)."""
    return lambda fn: PacedEntry(fn, asks, burst)


# Inlined (numba's IR) into each kind's cached entry point, where `asks` and `burst` are
# then direct calls of the kind's kernels: a kernel passed as a value keys numba's cache by
# the object (another process never finds it again) and lowers as an address that stops
# the caching.
@njit(inline="always")
def paced_ticks(asks, burst, world, rows, loop, windows, ts):
    """A world's ticks, one a period, until Python is needed (the module docstring); the
    status. asks(world, lp, ts): whether the opened tick (lp: loop[0]) needs the Python side
    (it returns RETURNED_SUPERVISE, the tick left opened); burst(world, rows, start, stop):
    the kind's compiled ticks (the first tick not run: stop, or start when a device's noise
    block needs a refill); world: the records they take; rows: where the ticks' rows go (a
    port world's one per tick, tick k into rows[k]; the local model's sidecar ring);
    loop: LOOP_DTYPE[1]; windows: (lateness µs, work µs, interval ms, peaks float64[3]),
    each tick's at its index; ts: int64[2] scratch."""
    lp = loop[0]
    late_w, work_w, interval_w, peaks = windows
    while True:
        if lp.status != RETURNED_NOISE:  # an opened tick runs without waiting again
            if lp.tick >= lp.stop_tick:
                lp.status = RETURNED_DONE
                return lp.status
            previous = lp.last_start_ns
            open_tick_at(lp, wait_until_ns(ts, lp.deadline_ns, lp.spin_ns))
            _opened(lp, previous, late_w, interval_w, peaks)
            if asks(world, lp, ts):
                lp.status = RETURNED_SUPERVISE
                return lp.status
        if burst(world, rows, lp.tick, lp.tick + 1) == lp.tick:
            lp.status = RETURNED_NOISE
            return lp.status
        end = monotonic_ns(ts)
        work_us = (end - lp.now_ns) / 1e3
        work_w[lp.tick % work_w.shape[0]] = work_us
        peaks[PEAK_WORK] = max(peaks[PEAK_WORK], work_us)
        lp.work_prev_us = work_us
        lp.tick += 1
        lp.deadline_ns += lp.period_ns
        lp.status = RETURNED_TO_PYTHON
        if end >= lp.return_at_ns:
            return lp.status
