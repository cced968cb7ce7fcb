"""Loop timing: a sleep-then-spin wait, and bounded-memory statistics of lateness and work.

STACK-NOTES: sleeping to ~0.5 ms before a deadline and spinning the rest on
perf_counter_ns gives p50 lateness < 1 us on these VMs, where a plain sleep gives ~75 us.
"""

from __future__ import annotations

import contextlib
import gc
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

SPIN_NS = 500_000


def spin_for(period_ns: int) -> int:
    """How long a wait spins before each deadline: SPIN_NS, but at most half the period, so
    the loop sleeps half of every period at high rates. A SCHED_FIFO thread that never
    sleeps is stopped by the kernel's real-time throttling (sched_rt_runtime_us: 50 ms in
    every second here); sleeping ~50% of a 10 kHz period keeps it well clear of that."""
    return min(SPIN_NS, period_ns // 2)


def wait_until(deadline_ns: int, spin_ns: int = SPIN_NS) -> int:
    """Sleep until spin_ns before the deadline, then spin; returns perf_counter_ns() at exit."""
    now = time.perf_counter_ns()
    remaining = deadline_ns - now - spin_ns
    if remaining > 0:
        time.sleep(remaining / 1e9)
    now = time.perf_counter_ns()
    while now < deadline_ns:
        now = time.perf_counter_ns()
    return now


def wall_clock_at(mono_ns: int, reads: int = 5) -> int:
    """The wall clock (time.time_ns) at a reading of time.perf_counter_ns: their offset from
    the tightest of a few bracketed reads (to within a microsecond unless every read was
    preempted). NTP slews both clocks alike; only a step of the wall clock moves them apart."""
    width, offset = None, 0
    for _ in range(reads):
        before = time.perf_counter_ns()
        wall = time.time_ns()
        after = time.perf_counter_ns()
        if width is None or after - before < width:
            width, offset = after - before, wall - (before + after) // 2
    return mono_ns + offset


REALTIME_PRIORITY = 10
# CPython hands the GIL to a waiting thread after this long (default 5 ms): a thread that must
# run every millisecond (a Zenoh receiver, a device's servo callback) must not wait that long
GIL_SWITCH_INTERVAL_S = 1e-4


def try_realtime_priority(priority: int = REALTIME_PRIORITY) -> bool:
    """Best effort: SCHED_FIFO for the calling thread, so a loop that sleeps most of each
    period preempts ordinary processes when it wakes (measured here: lateness p99.9 from
    ~1.3 ms to ~60 us). Falls back quietly where not permitted. Threads it starts later
    inherit it; children inherit it too: call it after starting any helper process."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (OSError, AttributeError):
        return False


SIM_PRIORITY = 1  # SCHED_RR, below the loop (REALTIME_PRIORITY) and its I/O process
SIM_NICENESS = -5  # where real-time priority is not permitted


def try_raise_priority(priority: int = SIM_PRIORITY, niceness: int = SIM_NICENESS) -> str:
    """Best effort, for the sim, which needs little CPU (~6 % of one on the testbed) but
    needs it each step: a browser drawing the live view on the CPU the loop leaves free kept
    it waiting (docs/live-view.md). SCHED_RR at `priority` (ahead of every ordinary process,
    behind the loop and its I/O), else `niceness`; threads started later inherit it.
    Returns what it got: "rr", "nice" or "" (neither permitted: it runs as before)."""
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority))
        return "rr"
    except (OSError, AttributeError):
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, 0, niceness)
        return "nice"
    except (OSError, AttributeError):
        return ""


def loop_cpu() -> int | None:
    """The CPU a real-time loop keeps to itself: the last one this process may run on, when
    there are at least two (None on one CPU: nothing to keep apart)."""
    cpus = sorted(os.sched_getaffinity(0))
    return cpus[-1] if len(cpus) > 1 else None


def keep_to_cpu(cpu: int | None) -> bool:
    """Run the calling thread on `cpu` only (best effort; False where not permitted). A
    SCHED_FIFO loop that spins before each deadline holds its CPU for that time, and any
    ordinary thread the kernel queued on it waits until the loop sleeps (measured: updates
    received in the spin waited for the next tick, receive -> install p50 0.82 ms at 1 kHz)."""
    if cpu is None:
        return False
    try:
        os.sched_setaffinity(0, {cpu})
        return True
    except OSError:
        return False


def avoid_cpu(cpu: int | None) -> None:
    """Keep the calling thread, and the threads it starts from now on, off `cpu` (the loop's):
    for the loop's I/O process, before it opens its Zenoh session."""
    allowed = os.sched_getaffinity(0) - {cpu}
    if cpu is not None and allowed:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, allowed)


class SampleWindow:
    """The newest `capacity` samples of a quantity (preallocated), plus exact totals."""

    def __init__(self, capacity: int) -> None:
        self._buf = np.zeros(capacity, dtype=np.float64)
        self._buf.fill(0.0)  # touch every page now: memory stays flat while the loop runs
        self.count = 0
        self.maximum = 0.0

    def add(self, value: float) -> None:
        self._buf[self.count % self._buf.shape[0]] = value
        self.count += 1
        if value > self.maximum:
            self.maximum = value

    @property
    def buffer(self) -> np.ndarray:
        """The preallocated samples; a kernel may write them (index count % capacity), and
        then say how many with `filled`."""
        return self._buf

    def filled(self, count: int, maximum: float) -> None:
        """`count` samples in all have been written into `buffer`, the largest `maximum`."""
        self.count = count
        self.maximum = max(self.maximum, maximum)

    def values(self) -> np.ndarray:
        return self._buf[: min(self.count, self._buf.shape[0])]

    def percentiles(self, *qs: float) -> dict[str, float]:
        v = self.values()
        if v.size == 0:
            return {f"p{_q_name(q)}": float("nan") for q in qs} | {"max": float("nan")}
        out = {f"p{_q_name(q)}": float(np.percentile(v, q)) for q in qs}
        out["max"] = float(self.maximum)
        return out


def _q_name(q: float) -> str:
    return str(q).replace(".", "_").removesuffix("_0")


@dataclass
class LoopCounters:
    """Exact counts over the whole run."""

    ticks: int = 0
    late_over_1ms: int = 0
    overruns: int = 0  # ticks that started more than one period late (resynchronised)
    skipped: int = 0  # whole periods those overruns spanned: ticks never run


def rate_per_second(intervals_ms: np.ndarray) -> dict[str, float]:
    """Steps (or ticks) started in each whole second of a run, from the intervals between
    their starts (ms): median and least. Rates from counts, not from mean intervals: the sim's
    phase lock moves single steps by up to a haptic period (16 / 17 ms at 60 Hz)."""
    if intervals_ms.size == 0:
        return {"p50": 0.0, "min": 0.0}
    counts = np.bincount((np.cumsum(intervals_ms) // 1000.0).astype(np.int64))[:-1]
    if counts.size == 0:  # less than a second
        return {"p50": 1e3 * intervals_ms.size / float(intervals_ms.sum()), "min": 0.0}
    return {"p50": float(np.median(counts)), "min": float(counts.min())}


class Pacer:
    """A loop paced by the wall clock (the shared world's and a station's): `wait` sleeps to
    the next deadline, then spins its last spin_ns; a tick later than a whole period starts
    the deadlines afresh from now (counted as an overrun, and the whole periods it spanned as
    skipped ticks). It keeps the tick intervals (for rate_per_second) and the lateness.

    Every period of the run is a tick or a skipped one: over a run of T, ticks + skipped
    lies in [T/P - overruns, T/P + 1]. A restart spaces the deadlines it counts by less than
    two periods (the last skipped deadline, then a period after the late start), so each may
    lose one; the +1 is the tick that starts at or after the end and ends the run."""

    def __init__(self, period_ns: int, spin_ns: int, duration_s: float | None) -> None:
        self.period_ns, self.spin_ns, self.duration_s = period_ns, spin_ns, duration_s
        self.intervals_ms = SampleWindow(1_000_000)
        self.late_us = SampleWindow(100_000)
        self.overruns = 0
        self.skipped = 0  # whole periods an overrun spanned: ticks never run
        self.ticks = 0
        self.late_ns = 0
        self.worst = (0, 0)  # the latest tick: ns late, its index
        self.started_ns = 0  # the clock at the first deadline (0 before start)

    def start(self) -> None:
        self.deadline = self.last = self.started_ns = time.perf_counter_ns()
        self.end = self.deadline + int(self.duration_s * 1e9) if self.duration_s else None

    def wait(self) -> int:
        """Until this tick's deadline; the clock then."""
        now = wait_until(self.deadline, self.spin_ns)
        self.late_ns = now - self.deadline
        if self.late_ns > self.period_ns:
            self.overruns += 1
            self.skipped += self._spanned(self.late_ns)
            self.deadline = now
        if self.ticks:
            self.intervals_ms.add((now - self.last) / 1e6)
        self.last = now
        self.late_us.add(self.late_ns / 1e3)
        if self.late_ns > self.worst[0]:
            self.worst = (self.late_ns, self.ticks)
        return now

    def _spanned(self, late_ns: int) -> int:
        """The deadlines after this tick's that passed before it started (those before the
        run's end): the ticks an overrun skips."""
        n = late_ns // self.period_ns
        if self.end is not None:
            n = min(n, max(0, -(-(self.end - self.deadline) // self.period_ns) - 1))
        return n

    def next(self) -> bool:
        """The tick is done: whether the loop goes on (its duration not yet over)."""
        self.ticks += 1
        self.deadline += self.period_ns
        return self.end is None or self.last < self.end

    def run(self, tick: Callable[[int, int], None], stopped: Callable[[], bool]) -> int:
        """The paced loop, written once for every loop on the wall clock that is not
        compiled (the shared world, a station, the sim's mirror; the local model's and a
        local port world's are, haptic_server.paced): start the clock, then until the
        duration is over or `stopped()`, wait for each deadline and run tick(now_ns, seq)
        (seq counts the ticks from 0). Returns the ticks run."""
        self.start()
        seq = 0
        while not stopped():
            now = self.wait()
            tick(now, seq)
            seq += 1
            if not self.next():
                break
        return seq

    def figures(self) -> dict[str, Any]:
        latest = (self.worst[0] / 1e6, self.worst[1])
        return paced_figures(self.intervals_ms, self.late_us, self.overruns, self.skipped,
                             latest, self.started_ns)  # fmt: skip


def paced_figures(
    intervals_ms: SampleWindow,
    late_us: SampleWindow,
    overruns: int,
    skipped: int,
    latest: tuple[float, int],
    started_ns: int,
) -> dict[str, Any]:
    """A paced loop's figures (a Pacer's, or a compiled loop's that kept the same): the tick
    rate, the lateness, the overruns and the periods they skipped, the latest tick (ms late,
    its index), and the clock at the first deadline."""
    return {
        "tick_rate_hz": rate_per_second(intervals_ms.values()),
        "late_us": late_us.percentiles(50, 99, 99.9),
        "overruns": overruns,
        "ticks_skipped": skipped,
        "latest_tick": {"late_ms": latest[0], "tick": latest[1]},
        # the loop's clock (perf_counter: CLOCK_MONOTONIC, one for every process on the
        # host) at its first deadline: another process's rows are matched in time on it
        "started_ns": started_ns,
    }


def enter_loop(warm: Callable[[], None], ready: Callable[[], None] | None) -> None:
    """Before a real-time loop's first tick: compile (or load) its kernels, collect and
    freeze what lives as long as the process (a full collection then no longer stalls a
    tick), take SCHED_FIFO after the warm-up (a loop compiling at it starved the others for
    seconds), then say ready."""
    warm()
    gc.collect()
    gc.freeze()
    try_realtime_priority()
    if ready is not None:
        ready()
