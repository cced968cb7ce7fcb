"""The one compiled real-time loop's own cost per tick: the local model's entry point
(`realtime.local_paced`, compiled without numba's reference counting: `paced.paced_entry`)
beside the same loop over the same kernels compiled with it, interleaved.

Both run the engine's ticks as fast as they compute (deadlines a nanosecond apart, dt
clamped to 1 ms), no update installed (the device held safe), so what differs between
them is the loop around the ticks: per tick, the work the loop records (its window, from
the tick's opening to the end of its burst) and the wall time per tick.

    python -m haptic_local_model.benchmarks.paced_overhead [--scene testbed god_crowd]
        [--device maglev twin_pantograph] [--ticks 20000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.mailbox import MAILBOX_DTYPE, N_CTL
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.paced import (
    RETURNED_DONE,
    RETURNED_NOISE,
    loop_record,
    paced_ticks,
)
from haptic_local_model.haptic_server.realtime import (
    local_asks,
    local_burst,
    local_paced,
    local_windows,
    local_world,
)
from haptic_local_model.shared.config import load_scene, load_user

NEVER = np.iinfo(np.int64).max
RING = 4096  # the ring's rows and the windows' slots


# the reference: the kind's kernels as they were (not inlined), in an entry point compiled
# with numba's reference counting; not cached, this benchmark's only
_counted_asks, _counted_burst = njit(local_asks.py_func), njit(local_burst.py_func)


@njit
def counted_paced(w, ring, loop, windows, ts):
    """local_paced as it was compiled before paced_entry: with NRT, its kernels called."""
    return paced_ticks(_counted_asks, _counted_burst, w, ring, loop, windows, ts)


ENTRIES = {"without NRT (local_paced)": local_paced, "with NRT": counted_paced}


def burst(scene: str, device: str, entry: Any, ticks: int) -> tuple[float, float, float]:
    """`ticks` ticks of a fresh engine through `entry`: (wall µs per tick, work p50, p99)."""
    engine = HapticEngine(load_scene(scene), load_device(device), load_user("swing"))
    loop = loop_record(1, (1e6, 1e6), 1)  # dt 1e6 periods: 1 ms
    lp = loop[0]
    lp["end_ns"] = lp["trip_at_ns"] = lp["return_at_ns"] = NEVER
    lp["stop_tick"] = 0
    ring_io = (
        np.zeros(RING, TICK_DTYPE), np.zeros(N_CTL, np.int64), np.zeros(4, MAILBOX_DTYPE),
        np.zeros(RING), np.zeros(RING), np.zeros(8), np.zeros(3), engine.row,
    )  # fmt: skip
    world, windows = local_world(engine, loop, ring_io), local_windows(ring_io)
    sim, ts = engine.sim_device, np.zeros(2, np.int64)
    assert sim is not None, f"{device}: not a simulated device"
    entry(world, ring_io[0], loop, windows, ts)  # stop_tick 0: done at once; compiled, primed
    lp["stop_tick"] = ticks
    start = time.perf_counter_ns()
    while (status := int(entry(world, ring_io[0], loop, windows, ts))) != RETURNED_DONE:
        if status != RETURNED_NOISE:
            raise SystemExit(f"{scene} on {device}: the loop returned {status} at {lp['tick']}")
        refill_noise(sim.noise, sim.records, float(lp["dt"]))
    wall_us = (time.perf_counter_ns() - start) / ticks / 1e3
    work = ring_io[4][: min(ticks, RING)]
    return wall_us, float(np.median(work)), float(np.percentile(work, 99))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scene", nargs="+", default=["testbed", "god_crowd"])
    ap.add_argument("--device", nargs="+", default=["maglev", "twin_pantograph"])
    ap.add_argument("--ticks", type=int, default=20_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    print("| scene | device | entry point | wall µs/tick | work p50 µs | work p99 µs |")
    print("|---|---|---|---|---|---|")
    for scene in args.scene:
        for device in args.device:
            for entry in ENTRIES.values():  # compiled (or loaded) before any is timed
                burst(scene, device, entry, 2_000)
            runs: dict[str, list[tuple[float, float, float]]] = {name: [] for name in ENTRIES}
            for _ in range(args.repeats):  # interleaved
                for name, entry in ENTRIES.items():
                    runs[name].append(burst(scene, device, entry, args.ticks))
            for name, figures in runs.items():
                wall, p50, p99 = np.median(np.array(figures), axis=0)
                print(f"| {scene} | {device} | {name} | {wall:.2f} | {p50:.2f} | {p99:.2f} |")


if __name__ == "__main__":
    main()
