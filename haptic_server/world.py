"""The World protocol, and the one runner per clock of the worlds that run in this process
with their devices (docs/architecture.md, "World kinds and runners").

A world is what a device touches: two devices on a co-simulated box (`ports`), a
mass-spring hand that a device drives (`hand_ports`), two hands holding a box
(`hand_grasp_ports`). Each is built from its scene, owns its records and its simulated
devices, and runs its ticks in one compiled call (`burst`): the devices read, the world's
stages, the commands clipped at the devices' limits and the devices' physics, one row a
tick. What a world kind's log is and how it replays is its `WorldKind`.

The runners are written once for every world:
- `run_ticks`: ticks start..stop-1, each device's noise block refilled when a burst says so;
- `run_virtual`: the virtual clock, as fast as the ticks compute, with what reaches the world
  between its ticks (a `Feed`: a sim's updates) if it has any;
- `run_real_time`: the wall clock, one tick a period in one compiled loop (paced_ticks of
  haptic_server.paced, the one real-time loop: the local model's runs on it too), which
  returns to Python only for a spent noise block, the next one drawn ahead, or every
  RETURN_EVERY_NS for signals and stop requests; after the kernels are compiled on a spare
  world.

The single-device engine (a local model, a god-object, from a sim's updates; engine.py) is a
world too on the virtual clock, its sim's steps and updates its feed (harness.virtual); on
the wall clock its supervisor (haptic_server.loop) runs the same paced_ticks over the
local model's kind (haptic_server.realtime: its hook hands a tick that needs the supervisor
back to Python, its burst writes its rows into the sidecar's ring) through the same Python
side, `drive_paced`.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.haptic_server.paced import (
    PEAK_LATE,
    PEAK_LATE_TICK,
    PEAK_WORK,
    RETURNED_NOISE,
    RETURNED_TO_PYTHON,
    loop_record,
)
from haptic_local_model.shared.timing import SampleWindow, enter_loop, paced_figures

#: Replay a kind's rows: (scene, each port's world-frame limits, rows) -> (ticks compared,
#: the first tick whose outputs differ in any bit, or None).
Replay = Callable[[Any, list[tuple[float, float, float]], np.ndarray], tuple[int, int | None]]

SPIN_NS = 100_000  # the real-time runner spins this long before each deadline
# the compiled paced loop hands back to Python this often (signals, stop requests): each return
# costs Python work between two ticks, which at 10 kHz eats into a 100 us period (haptic-run
# --haptic-rate 10000, 5 interleaved pairs: overruns median 183 every 10 ms, 113 every 50 ms)
RETURN_EVERY_NS = 50_000_000


class Compiled(NamedTuple):
    """A port world kind's compiled ticks as the runners call them, and its records."""

    #: burst(records, rows, start, stop) -> the first tick not run (stop, or earlier when
    #: a device's noise block needs a refill)
    burst: Any
    #: paced(records, rows, loop, windows, ts): haptic_server.paced.paced_ticks over
    #: paced.never_asks (a port world's opened tick never needs Python) and burst, a cached
    #: entry point of the kind's own
    paced: Any
    records: tuple[Any, ...]


@dataclass(frozen=True)
class WorldKind:
    """What a world kind's log is and how it replays (one per kind, beside its records)."""

    name: str
    topic: str  # the log's row topic
    schema: str  # its ros1msg schema's name
    rows: np.dtype  # one tick's row
    scene: type  # the scene's config class (PortSceneConfig, HandSceneConfig)
    ports: int | None  # the ports it has (None: as many as its scene declares)
    replay: Replay | None  # None: its rows alone do not replay (a sim's updates feed its ticks)


class World(Protocol):
    """A world with its devices, as the runners, the log and the replay see it."""

    @property
    def kind(self) -> WorldKind: ...

    @property
    def devices(self) -> Sequence[SimulatedDevice]: ...

    @property
    def period_s(self) -> float: ...

    def burst(self, rows: np.ndarray, start: int, stop: int) -> int:
        """Ticks start..stop-1 in one compiled call, row k into rows[k]; the first tick not
        run: stop, or earlier when a device's noise block needs a refill."""
        ...

    def limits(self) -> list[list[float]]:
        """Each port's device limits in the world frame (the log keeps them for replay)."""
        ...

    def summary_lines(self, rows: np.ndarray, wall_s: float) -> list[str]:
        """What a run of `rows` did, for people."""
        ...


def run_ticks(world: World, rows: np.ndarray, start: int, stop: int) -> int:
    """Ticks start..stop-1 into rows, refilling each device's noise as the bursts need."""
    k = start
    while k < stop:
        k = world.burst(rows, k, stop)
        if k < stop:
            for dev in world.devices:
                refill_noise(dev.noise, dev.records, world.period_s)
    return stop


class Feed(Protocol):
    """What reaches a world between its ticks on the virtual clock: for a single device on a
    sim, the sim steps and its update is installed (harness/virtual.py)."""

    def __call__(self, k: int, rows: np.ndarray) -> int:
        """Before tick k (rows[:k] are the ticks run): what arrives by then, taken in. The
        next tick before which something arrives (> k; len(rows) or more: nothing more)."""
        ...


def run_virtual(
    world: World, duration_s: float, feed: Feed | None = None
) -> tuple[np.ndarray, float]:
    """`duration_s` of virtual time as fast as it computes: (every tick's row, wall s). With
    a `feed`, the ticks run in bursts between its arrivals."""
    rows = np.zeros(round(duration_s / world.period_s), world.kind.rows)
    rows.fill(0)  # the pages mapped now, before the clock starts (np.zeros maps them lazily)
    entered = time.perf_counter()
    k = 0
    while k < len(rows):
        stop = len(rows) if feed is None else min(len(rows), feed(k, rows))
        k = run_ticks(world, rows, k, stop)
    return rows, time.perf_counter() - entered


def draw_ahead(world: World) -> bool:
    """Between two ticks, in the period's slack: the next noise block of the first device
    that has none waiting (one a tick: a block of normals takes 0.3-1 ms on these machines,
    and the devices of one world spend theirs at the same pace, so drawn at need they all
    draw in one tick and overrun it). The refill at need copies it in: the normals read are
    the same, and a real-time run's rows are the virtual clock's. Whether one was drawn."""
    return any(dev.noise.prefetch() for dev in world.devices)


class PortWorld(World, Protocol):
    """A world whose ticks the real-time runner paces in compiled code (the port worlds)."""

    @property
    def compiled(self) -> Compiled:
        """Its compiled ticks and the records they take (Compiled)."""
        ...


def compiled_burst(world: PortWorld, rows: np.ndarray, start: int, stop: int) -> int:
    """The World protocol's `burst` of a port world: its compiled ticks on its records."""
    kernels = world.compiled
    return int(kernels.burst(kernels.records, rows, start, stop))


@dataclass
class PacedTimes:
    """What the compiled paced loop keeps of each tick (preallocated): its lateness, its
    work and its interval from the tick before, and their peaks (haptic_server.paced)."""

    late_us: SampleWindow
    work_us: SampleWindow
    intervals_ms: SampleWindow
    peaks: np.ndarray

    @classmethod
    def of(cls, ticks: int) -> PacedTimes:
        return cls(SampleWindow(100_000), SampleWindow(max(ticks, 1)),
                   SampleWindow(1_000_000), np.zeros(3))  # fmt: skip

    @property
    def windows(self) -> tuple[np.ndarray, ...]:
        """What paced_ticks writes: (lateness, work, intervals, peaks)."""
        return self.late_us.buffer, self.work_us.buffer, self.intervals_ms.buffer, self.peaks

    def ran(self, ticks: int) -> None:
        """`ticks` ticks have been run and written."""
        self.late_us.filled(ticks, float(self.peaks[PEAK_LATE]))
        self.work_us.filled(ticks, float(self.peaks[PEAK_WORK]))
        self.intervals_ms.filled(max(ticks - 1, 0), 0.0)


def paced_loop(period_ns: int) -> np.ndarray:
    """A port world's LOOP_DTYPE record: its period, the wait's spin (SPIN_NS), the clock
    not started."""
    loop = loop_record(period_ns, (1.0, 1.0), 0)
    loop[0]["spin_ns"] = SPIN_NS
    return loop


def drive_paced(
    entry: Callable[[], int], refill: Callable[[], None], between: Callable[[], bool]
) -> int:
    """The one Python side of the compiled paced loop (paced_ticks), for every world that
    runs in this process, the local model's included: `entry()` enters a kind's entry point
    on its arguments. A spent noise block (RETURNED_NOISE) is refilled by `refill()` for the
    opened tick, and the loop entered again; between two ticks (RETURNED_TO_PYTHON)
    `between()` does what waits there and says whether to go on (it sets `return_at_ns`,
    when the loop is next back). Returns the status that ended it: RETURNED_DONE,
    RETURNED_SUPERVISE (the opened tick is the caller's), or RETURNED_TO_PYTHON when
    `between()` said stop."""
    while True:
        status = int(entry())
        if status == RETURNED_NOISE:
            refill()
        elif status != RETURNED_TO_PYTHON or not between():
            return status


def run_paced(
    world: PortWorld,
    rows: np.ndarray,
    loop: np.ndarray,
    times: PacedTimes,
    stopped: Callable[[], bool],
) -> int:
    """A port world's rows run by the compiled paced loop (drive_paced) from `loop`'s
    deadline (its first tick's) until every row is run or `stopped()` (asked between two
    ticks, at least every RETURN_EVERY_NS): a device's spent noise block refilled for the
    tick it stopped at, the next blocks drawn ahead in the slack after a tick (draw_ahead).
    The blocks drawn ahead."""
    lp = loop[0]
    lp["stop_tick"] = rows.shape[0]
    kernels = world.compiled
    windows, ts = times.windows, np.zeros(2, np.int64)
    drawn = [0]

    def refill() -> None:
        for dev in world.devices:
            refill_noise(dev.noise, dev.records, world.period_s)
        lp["return_at_ns"] = 0  # back after that tick: the next blocks drawn in its slack

    def between() -> bool:
        if stopped():
            return False
        ahead = draw_ahead(world)
        drawn[0] += ahead
        lp["return_at_ns"] = 0 if ahead else time.perf_counter_ns() + RETURN_EVERY_NS
        return True

    if between():
        drive_paced(lambda: kernels.paced(kernels.records, rows, loop, windows, ts), refill,
                    between)  # fmt: skip
    times.ran(int(lp["tick"]))
    return drawn[0]


def compile_paced(world: PortWorld) -> None:
    """The world's paced loop compiled (or loaded from numba's cache) for its kind and its
    devices, and run for no tick."""
    run_paced(world, np.zeros(0, world.kind.rows), paced_loop(1), PacedTimes.of(0),
              lambda: False)  # fmt: skip


def _warm(spare: PortWorld, world: PortWorld) -> None:
    """The world's kernels and its paced loop compiled (or loaded from numba's cache) on a
    spare world, then the loop called on the world's own records for no tick (the first
    call on new arrays costs milliseconds: it overran the first tick); each device's next
    noise block drawn before the clock starts."""
    run_ticks(spare, np.zeros(2, spare.kind.rows), 0, 2)
    for dev in spare.devices:  # the refill's check loaded (at a tick, loading it took 140 ms)
        refill_noise(dev.noise, dev.records, spare.period_s)
    compile_paced(spare)
    compile_paced(world)
    while draw_ahead(world):
        pass


def run_real_time(
    world: PortWorld,
    spare: PortWorld,
    duration_s: float,
    stopped: Callable[[], bool] = lambda: False,
    rows: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """`duration_s` on the wall clock, one tick a period in compiled code (run_paced; a
    SIGINT or SIGTERM, or `stopped()`, ends it early): (the rows of the ticks run, the
    loop's figures). The kernels are compiled (or loaded) on `spare`, a world built as
    `world` is, first. The rows go into `rows` if given (zeroed, one per tick: shared memory
    a live view reads).

    Ticks delivered is the ticks run over the periods that passed between the first tick
    and the last (a tick later than a whole period starts the deadlines afresh: the
    periods it skipped are lost, not caught up)."""
    n = round(duration_s / world.period_s)
    if rows is None:
        rows = np.zeros(n, world.kind.rows)
    if rows.shape != (n,) or rows.dtype != world.kind.rows:
        raise ValueError(f"rows: {rows.shape} of {rows.dtype}, not ({n},) of the world's rows")
    rows.view(np.uint8)[:] = 0  # every page touched now, not in the loop
    period_ns = round(world.period_s * 1e9)
    loop, times = paced_loop(period_ns), PacedTimes.of(n)
    asked, first = [False], 0

    def stop(*_: object) -> None:
        asked[0] = True

    previous = [signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)]
    try:
        enter_loop(lambda: _warm(spare, world), None)
        first = loop[0]["deadline_ns"] = time.perf_counter_ns()  # the periods count from it
        run_paced(world, rows, loop, times, lambda: asked[0] or stopped())
    finally:
        for s, handler in zip((signal.SIGINT, signal.SIGTERM), previous, strict=True):
            signal.signal(s, handler)
    return rows[: times.work_us.count], loop_figures(loop[0], times, first, n)


def loop_figures(lp: np.void, times: PacedTimes, first: int, n: int) -> dict[str, Any]:
    """A paced run's figures (Pacer.figures' and the work's, the ticks delivered) from its
    loop record, its tick times and its first deadline."""
    ran, period_ns = int(lp["tick"]), int(lp["period_ns"])
    last = int(lp["last_start_ns"])
    periods = (last - first) // period_ns + 1 if ran else 0
    late_ms, tick = float(times.peaks[PEAK_LATE]) / 1e3, int(times.peaks[PEAK_LATE_TICK])
    return {
        "ticks": ran,
        "ticks_delivered": ran / periods if periods else 0.0,
        "wall_s": (last - first) / 1e9 if ran else 0.0,
        **paced_figures(times.intervals_ms, times.late_us, int(lp["overruns"]),
                        int(lp["skipped"]), (late_ms, tick), first),
        "work_us": times.work_us.percentiles(50, 99, 99.9),
        "stopped_early": ran < n,
    }  # fmt: skip
