"""What the shared world's live view (`haptic-world --view`, haptic_server/port_view.py)
costs the world's loop: the router, the world and both stations on loopback
(stations.loopback_run), the world with and without --view, alternating, no browser.
Reports, per run, the world's ticks, stalls and overruns and its work per tick (p50, p99).

    python -m haptic_local_model.benchmarks.world_view [--scene grasp_vertical] [--seconds 20] [--repeat 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

from haptic_local_model.benchmarks.browser import free_ports
from haptic_local_model.benchmarks.stations import loopback_run


def world_figures(summary: dict[str, Any]) -> str:
    work = summary["work_us"]
    return (
        f"ticks {summary['ticks']}, stalls {summary['stalls']}, overruns "
        f"{summary.get('overruns', '?')}, work p50 {work['p50']:.1f} us p99 {work['p99']:.1f} us"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="grasp_vertical")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    for _ in range(args.repeat):
        for view in (True, False):
            web, grpc = free_ports(2)
            extra = ("--view", "--view-port", str(web), "--view-grpc-port", str(grpc))
            with tempfile.TemporaryDirectory() as folder:
                out = loopback_run(args.scene, args.seconds, Path(folder), extra if view else ())
            print(f"{'view ' if view else 'plain'}: {world_figures(out['world'])}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
