"""The sim at scale: the `crowd` scene (1000 pebbles) beside the default testbed, real time.

Runs `haptic-run` on the crowd (user `plough`, which ploughs the tool through the pebbles)
and on the testbed (user `swing`), interleaved, `--repeat` times each, and reports from each
run's summary and log: the sim's step rate (steps started in each second: median and
least) and its work per step, the haptic loop's work per tick, the contacts the local model carried and the largest
update. Targets: the crowd's sim at >= 59 Hz (median), its haptic work per tick
within +-20% of the testbed's (p50 and p99, medians over the runs), and its update under the
size bound the wire allows a free tool (64 contacts), printed below.

    python -m haptic_local_model.benchmarks.crowd [--seconds 10] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.log import read_ticks
from haptic_local_model.shared.protocol.layout import MAX_CONTACTS, update_size

RUNS = {"crowd": "plough", "testbed": "swing"}
TARGET_SIM_HZ = 59.0
WORK_BAND = 0.20
#: a free tool's update (d = 3, no resisted directions) with every contact the wire allows
SIZE_BOUND_BYTES = update_size(3, 0, MAX_CONTACTS, 0xF)


def one_run(scene: str, user: str, seconds: float, folder: Path) -> dict[str, Any]:
    log, summary = folder / f"{scene}.mcap", folder / f"{scene}.json"
    subprocess.run(
        [
            sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--scene", scene, "--user", user,
            "--duration", str(seconds), "--log", str(log), "--summary-json", str(summary),
        ],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    s = json.loads(summary.read_text())
    ticks = read_ticks(log)
    return {
        "sim_hz": s["sim"]["step_rate_hz"]["p50"],  # steps in each second: median
        "sim_hz_min": s["sim"]["step_rate_hz"]["min"],  # and the fewest
        "sim_step_ms_p50": s["sim"]["step_ms"]["p50"],
        "sim_step_ms_p99": s["sim"]["step_ms"]["p99"],
        "work_us_p50": s["work_us"]["p50"],
        "work_us_p99": s["work_us"]["p99"],
        "contacts_mean": float(ticks["n_contacts"].mean()),
        "contacts_max": int(ticks["n_contacts"].max()),
        "update_bytes_max": s["sim"]["update_bytes_max"],
        "watchdog_trips": s["watchdog_trips"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    results: dict[str, list[dict[str, Any]]] = {scene: [] for scene in RUNS}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):  # interleaved
            for scene, user in RUNS.items():
                results[scene].append(one_run(scene, user, args.seconds, Path(tmp)))
    keys = list(results["crowd"][0])
    median = {
        s: {k: float(np.median([r[k] for r in rs])) for k in keys} for s, rs in results.items()
    }
    print(f"medians over {args.repeat} runs of {args.seconds:g} s each, interleaved")
    print(f"{'':20}" + "".join(f"{s:>12}" for s in RUNS))
    for k in keys:
        print(f"{k:20}" + "".join(f"{median[s][k]:12.2f}" for s in RUNS))
    crowd, testbed = median["crowd"], median["testbed"]
    ratios = {q: crowd[f"work_us_{q}"] / testbed[f"work_us_{q}"] for q in ("p50", "p99")}
    print(
        f"\ncrowd sim rate {crowd['sim_hz']:.1f} Hz (target >= {TARGET_SIM_HZ:g}); haptic work "
        f"crowd / testbed: p50 {ratios['p50']:.2f}, p99 {ratios['p99']:.2f} (target "
        f"{1 - WORK_BAND:.2f}-{1 + WORK_BAND:.2f}); largest update {crowd['update_bytes_max']:.0f}"
        f" bytes (bound: {SIZE_BOUND_BYTES} bytes, {MAX_CONTACTS} contacts)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
