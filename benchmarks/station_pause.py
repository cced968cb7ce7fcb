"""A station's link stopped mid-press (issue 46): the three-namespace set-up of
benchmarks/stations.py, each station's link through the impairment forwarder
(benchmarks/impair.py) at `--delay-ms` one way, the users pressing (station_links'
PRESS_USERS, maglevs); at `--pause-at` s of the right station's run its link is paused both
ways for `--pause-ms` (the forwarder's SIGUSR1: every packet held until the window ends).
From the processes' own logs, per run:

- `into_box_mm`: how far the right station's device went into the box (along -x, its press)
  from the pause until `STEP_WINDOW` ticks after its first fresh tool state after it;
- `rejoin_step_n`: the largest tick-to-tick change of its command (x) from its first fresh
  tool state after the pause over `STEP_WINDOW` ticks, beside `steady_step_n` and
  `steady_step_max_n`, the same's 99th percentile and largest over the `STEADY` ticks
  before the pause;
- `registration_mm`: where the world has the right station's device less where it is
  (station_links.registration: the two logs matched on the host's monotonic clock), x-y,
  over the station's `BEFORE` s before the pause and `AFTER` s after it, both in the
  press's hold (the users' targets still), and how far the second is from the first: how far
  the station's device and its tool walked apart.

Needs root; everything it creates is removed and every process it starts stopped by its pid.

    sudo .venv/bin/python -m haptic_local_model.benchmarks.station_pause \
        [--runs 3] [--delay-ms 0] [--pause-ms 130] [--pause-at 8.3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.impair import Impairment
from haptic_local_model.benchmarks.station_links import PRESS_USERS, registration
from haptic_local_model.benchmarks.stations import (
    CLI,
    PORTS,
    STOP_S,
    ThreeHosts,
    after,
    netns_unavailable,
    station_rows,
)
from haptic_local_model.haptic_server.world_runs import read_port_log

NETWORK = "stations_three_hosts"
SECONDS = 10.0
STEP_WINDOW = 200
STEADY = 300
BEFORE = (0.4, 0.02)  # s of the station's clock before the pause: from, to
AFTER = (0.35, 0.65)  # and after it: in the press's hold (press_*_ramp: 8 to 9 s)
WORLD_SPARE_S = 60.0  # the world's run beyond the stations' (it is stopped after them)


def figures(
    right: np.ndarray, world: np.ndarray, world_start_ns: int, pause_ns: int, port: int
) -> dict[str, Any]:
    p = after(right, pause_ns)
    t = float(right["t"][p])
    x0 = float(right["pose"][p, 0])
    back = p + int(np.argmax(right["fresh"][p:] == 0))  # the watchdog (or p if none)
    back += int(np.argmax(right["fresh"][back:] == 1))
    full = back + int(np.argmax(right["gain"][back:] == 1.0))
    into = float((x0 - right["pose"][p : back + STEP_WINDOW, 0]).max())
    out = right["out"][:, 0]
    step = np.abs(np.diff(out[back - 1 : back + STEP_WINDOW]))
    steady = np.abs(np.diff(out[p - STEADY : p]))
    before = registration(right, world, world_start_ns, port, (t - BEFORE[0], t - BEFORE[1]))
    later = registration(right, world, world_start_ns, port, (t + AFTER[0], t + AFTER[1]))
    return {
        "into_box_mm": into * 1e3,
        "went_safe": bool(right["gain"][p:full].min() < 1.0),
        "least_gain": float(right["gain"][p : full + 1].min()),
        "rejoin_step_n": float(step.max()),
        "steady_step_n": float(np.percentile(steady, 99)),
        "steady_step_max_n": float(steady.max()),
        "registration_mm": {
            "before": before[:2].tolist(),
            "after": later[:2].tolist(),
            "change": float(np.hypot(*(later - before)[:2])),
        },
    }


def run(folder: Path, delay_ms: float, pause_ms: float, pause_at_s: float) -> dict[str, Any]:
    imp = Impairment(delay_ms / 1e3, pause_s=pause_ms / 1e3)
    with ThreeHosts(impair=dict.fromkeys(PORTS, imp)) as h:
        net = ["--network", NETWORK]
        h.start(h.world_ns, [*CLI, "router", *net]).wait_ready()
        # the world outlives the stations however long they take to start (it is stopped
        # after them)
        world = h.start(h.world_ns, [*CLI, "world", *net,
                                     "--duration", str(SECONDS + WORLD_SPARE_S),
                                     "--log", str(folder / "world.mcap"),
                                     "--json", str(folder / "world.json")])  # fmt: skip
        world.wait_ready()
        stations = {}
        for p in PORTS:
            args = ["--port", p, "--duration", str(SECONDS), "--log", str(folder / f"{p}.mcap"),
                    "--device", "maglev", "--user", PRESS_USERS[p]]  # fmt: skip
            stations[p] = h.start(h.station_ns[p], [*CLI, "station", *net, *args])
        for s in stations.values():
            s.wait_ready()
        # at pause_at_s of the right station's own clock (its loop starts as it says ready):
        # timed from both ready, a right station that started first (up to 2 s on a loaded
        # 2-core machine) was paused past its press's hold, its window after the pause past
        # its run's end (a registration of NaNs, in a run here and in a clean-clone run)
        time.sleep(max(0.0, stations["right"].ready_at + pause_at_s - time.monotonic()))
        pause_ns = time.perf_counter_ns()
        os.kill(h.forwarders["right"].proc.pid, signal.SIGUSR1)
        codes = {p: s.proc.wait(SECONDS + STOP_S) for p, s in stations.items()}
        world.stop()
        codes["world"] = world.proc.wait(STOP_S)
    started_ns = json.loads((folder / "world.json").read_text())["started_ns"]
    out = figures(station_rows(folder / "right.mcap"), read_port_log(folder / "world.mcap")[0],
                  started_ns, pause_ns, PORTS.index("right"))  # fmt: skip
    out["exit_codes"] = codes
    out["left_over"] = h.leftovers()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--delay-ms", type=float, default=0.0)
    ap.add_argument("--pause-ms", type=float, default=130.0)
    ap.add_argument("--pause-at", type=float, default=8.3, help="s after the stations are ready")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--keep", type=Path, help="keep each run's logs in KEEP/run<i>")
    args = ap.parse_args(argv)
    why = netns_unavailable()
    if why:
        print(why, file=sys.stderr)
        return 2
    results = []
    for i in range(args.runs):
        with tempfile.TemporaryDirectory() as d:
            folder = Path(d) if args.keep is None else args.keep / f"run{i}"
            folder.mkdir(parents=True, exist_ok=True)
            results.append(run(folder, args.delay_ms, args.pause_ms, args.pause_at))
        print(json.dumps(results[-1]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
