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
- `run_real_time`: the wall clock, one tick a period (shared.timing.Pacer, the paced loop of
  the network's processes too), after the kernels are compiled on a spare world.

The single-device engine (a local model, a god-object, from a sim's updates; engine.py) is a
world too on the virtual clock, its sim's steps and updates its feed (harness.virtual); it
keeps its own real-time loop (haptic_server.loop, the compiled burst with the supervisor).
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.kernels import noise_ready
from haptic_local_model.shared.timing import Pacer, SampleWindow, enter_loop

#: Replay a kind's rows: (scene, each port's world-frame limits, rows) -> (ticks compared,
#: the first tick whose outputs differ in any bit, or None).
Replay = Callable[[Any, list[tuple[float, float, float]], np.ndarray], tuple[int, int | None]]

SPIN_NS = 100_000  # the real-time runner spins this long before each deadline
REFILL_AHEAD = 16  # ticks: the real-time runner refills a noise block this long before need


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


def refill_ahead(world: World) -> bool:
    """After a tick, in the period's slack: draw the next noise block of the first device
    whose block will not last REFILL_AHEAD more ticks (one a tick: a block of normals takes
    0.3-1 ms on these machines, and the devices of one world spend theirs at the same pace,
    so drawn at need they all draw in one tick and overrun it). The refill at need copies
    it in: the normals read are the same, and a real-time run's rows are the virtual
    clock's. Whether one was drawn."""
    ahead = REFILL_AHEAD * world.period_s
    for dev in world.devices:
        if not noise_ready(dev.records, ahead) and dev.noise.prefetch():
            return True
    return False


def _warm(spare: World, world: World, rows: np.ndarray) -> None:
    """The world's kernels compiled (or loaded from numba's cache) on a spare world, then
    called on the world's own records for no tick (the first call on new arrays costs
    milliseconds: it overran the first tick)."""
    run_ticks(spare, np.zeros(2, spare.kind.rows), 0, 2)
    refill_ahead(spare)
    world.burst(rows, 0, 0)


def run_real_time(
    world: World,
    spare: World,
    duration_s: float,
    stopped: Callable[[], bool] = lambda: False,
    rows: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """`duration_s` on the wall clock, one tick a period (a SIGINT or SIGTERM, or
    `stopped()`, ends it early): (the rows of the ticks run, the loop's figures). The
    kernels are compiled (or loaded) on `spare`, a world built as `world` is, first. The
    rows go into `rows` if given (zeroed, one per tick: shared memory a live view reads).

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
    work = SampleWindow(n)
    pacer = Pacer(period_ns, SPIN_NS, None)
    first = [0]
    asked = [False]

    def tick(now: int, seq: int) -> None:
        if seq == 0:
            first[0] = pacer.deadline  # the first tick's: the periods are counted from it
        run_ticks(world, rows, seq, seq + 1)
        work.add((time.perf_counter_ns() - now) / 1e3)
        refill_ahead(world)

    def stop(*_: object) -> None:
        asked[0] = True

    previous = [signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)]
    try:
        enter_loop(lambda: _warm(spare, world, rows), None)
        ran = pacer.run(tick, lambda: asked[0] or stopped() or pacer.ticks >= n)
    finally:
        for s, handler in zip((signal.SIGINT, signal.SIGTERM), previous, strict=True):
            signal.signal(s, handler)
    periods = (pacer.last - first[0]) // period_ns + 1 if ran else 0
    figures = {
        "ticks": ran,
        "ticks_delivered": ran / periods if periods else 0.0,
        "wall_s": (pacer.last - first[0]) / 1e9 if ran else 0.0,
        **pacer.figures(),
        "work_us": work.percentiles(50, 99, 99.9),
        "stopped_early": ran < n,
    }
    return rows[:ran], figures
