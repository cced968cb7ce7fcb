"""How much faster than real time the virtual clock runs each scene (issue 2: >= 50x).

Each scene runs `--seconds` of simulated time `--repeats` times, without a log and with the
MCAP log written; prints the median speed-up (simulated s / wall s) and its spread. The
first run of each scene loads the numba cache and is not counted.

    python -m benchmarks.virtual_clock [--seconds 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from haptic_server.harness.virtual import run_virtual_named

SCENES = (("free_box", "waypoints"), ("wall_push", "push_2n"), ("testbed_free_tool", "push_block"))
TARGET = 50.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    head = f"{'no log: median':>16}{'min':>8}{'max':>8}{'MCAP log: median':>18}{'min':>8}{'max':>8}"
    print(f"{'scene':<20}{head}")
    with tempfile.TemporaryDirectory() as tmp:
        for scene, user in SCENES:
            run_virtual_named(scene, "ideal", user, 0.5)
            plain = [
                run_virtual_named(scene, "ideal", user, args.seconds).speedup
                for _ in range(args.repeats)
            ]
            logged = [
                run_virtual_named(scene, "ideal", user, args.seconds, Path(tmp) / "x.mcap").speedup
                for _ in range(args.repeats)
            ]
            print(
                f"{scene:<20}{np.median(plain):>15.1f}x{min(plain):>7.1f}x{max(plain):>7.1f}x"
                f"{np.median(logged):>17.1f}x{min(logged):>7.1f}x{max(logged):>7.1f}x"
            )
    print(f"\ntarget: >= {TARGET:.0f}x real time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
