"""Loop timing on this machine, measured in one run (issue 2, 6):

1. a bare loop that only waits for each 1 ms deadline (sleep, then spin) with the sim
   server running beside it: the limit of the machine;
2. the two-process system (haptic-run, real time) with logging on;
3. the same with logging off.

Reports lateness p50/p99/p99.9/max, late ticks over 1 ms and work per tick for each, and
writes the figures as JSON. Machines are shared and noisy: compare within one run.

    python -m benchmarks.loop_timing [--seconds 20] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from shared.config import REPO_ROOT
from shared.timing import try_realtime_priority, wait_until


def bare_loop(seconds: float, period_ns: int = 1_000_000) -> dict[str, Any]:
    """Only wait for deadlines; lateness is all there is."""
    n = int(seconds * 1e9 / period_ns)
    lateness = np.zeros(n)
    deadline = time.perf_counter_ns() + period_ns
    for i in range(n):
        now = wait_until(deadline)
        lateness[i] = (now - deadline) / 1e3
        if now - deadline > period_ns:
            deadline = now
        deadline += period_ns
    return {
        "ticks": n,
        "lateness_us": _pct(lateness),
        "late_ticks_over_1ms": int((lateness > 1000).sum()),
    }


def _pct(v: np.ndarray) -> dict[str, float]:
    return {
        "p50": float(np.percentile(v, 50)),
        "p99": float(np.percentile(v, 99)),
        "p99_9": float(np.percentile(v, 99.9)),
        "max": float(v.max()),
    }


def with_sim_beside(seconds: float, network: str) -> dict[str, Any]:
    """The bare loop (its own process, with the loop's real-time priority) while a sim server
    runs as another process: the same load and privileges as the system."""
    sim = subprocess.Popen(
        [sys.executable, "-m", "sim_server.cli", "--network", network],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        sim.stdout.readline()  # the "ready" line
        argv = ["-m", "benchmarks.loop_timing", "--bare-only", "--seconds", str(seconds)]
        out = subprocess.run(
            [sys.executable, *argv], cwd=REPO_ROOT, check=True, capture_output=True, text=True
        )
        return json.loads(out.stdout)  # type: ignore[no-any-return]
    finally:
        os.kill(sim.pid, signal.SIGTERM)
        sim.wait(30)


def system(seconds: float, log: bool, network: str, scene: str, device: str) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        summary = Path(tmp) / "summary.json"
        argv = [
            sys.executable, "-m", "haptic_server.run", "--duration", str(seconds),
            "--network", network, "--scene", scene, "--device", device,
            "--summary-json", str(summary),
        ]  # fmt: skip
        argv += ["--log", str(Path(tmp) / "run.mcap")] if log else ["--no-log"]
        subprocess.run(argv, cwd=REPO_ROOT, check=True, stdout=subprocess.DEVNULL)
        return json.loads(summary.read_text())  # type: ignore[no-any-return]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--network", default="loopback")
    parser.add_argument("--scene", default="testbed")
    parser.add_argument("--device", default="ideal")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--bare-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.bare_only:
        realtime = try_realtime_priority()
        print(json.dumps({**bare_loop(args.seconds), "realtime_priority": realtime}))
        return 0
    results = {
        "bare_loop_with_sim": with_sim_beside(args.seconds, args.network),
        "system_log_on": system(args.seconds, True, args.network, args.scene, args.device),
        "system_log_off": system(args.seconds, False, args.network, args.scene, args.device),
    }
    columns = ("ticks", "lat p50", "p99", "p99.9", "max", "late>1ms", "work p50", "p99", "max")
    print(f"{'run':<22}" + "".join(f"{c:>9}" for c in columns) + "  realtime")
    for name, r in results.items():
        lat = r["lateness_us"]
        work = r.get("work_us", {"p50": float("nan"), "p99": float("nan"), "max": float("nan")})
        values = (
            r["ticks"], lat["p50"], lat["p99"], lat["p99_9"], lat["max"], r["late_ticks_over_1ms"],
            work["p50"], work["p99"], work["max"],
        )  # fmt: skip
        print(f"{name:<22}" + "".join(f"{v:>9.1f}" for v in values) + f"  {r['realtime_priority']}")
    bare = results["bare_loop_with_sim"]
    on = results["system_log_on"]
    ratio = on["lateness_us"]["p99_9"] / max(bare["lateness_us"]["p99_9"], 1e-9)
    print(f"\nlateness p99.9, log on / bare loop: {ratio:.2f} (target <= 2)")
    print(
        f"late ticks > 1 ms: log on {on['late_ticks_over_1ms']}, bare {bare['late_ticks_over_1ms']}"
    )
    print(f"work p99 with logging: {on['work_us']['p99']:.1f} us (target <= 100 us)")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
