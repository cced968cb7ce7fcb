"""How much faster than real time the virtual clock runs every shipped scene.

Every scene in configs/scenes (the default `testbed` and the heaviest, `maglev_scoop`,
included) runs `--seconds` of simulated time `--repeats` times, without a log and with the
MCAP log written, interleaved; prints the median speed-up (simulated s / wall s), its
spread, and where the time goes (ms of wall time per simulated second: the sim's step, its
local model with its encoding, the install, the haptic ticks). The first run of each scene loads
the numba cache and is not counted. What a run pays once, before its clock starts, is printed
beside its rate: loading the kernels (from numba's cache), and making the world, the engine
and (with a log) the writer process. Targets: >= 200x without a log, >= 100x with it.

    python -m haptic_local_model.benchmarks.virtual_clock [--seconds 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.shared.config import CONFIG_ROOT

#: The user each scene is driven by (a scene not listed here runs with `swing`).
USERS = {
    "free_box": "waypoints",
    "maglev_scoop": "scoop",
    "testbed_free_tool": "push_block",
    "wall_push": "push_2n",
    "wall_push_penalty": "push_2n",
    "wall_slide": "slide",
}
TARGET_NO_LOG, TARGET_LOG = 200.0, 100.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    scenes = sorted(p.stem for p in (CONFIG_ROOT / "scenes").glob("*.toml"))
    head = f"{'no log: median':>16}{'min':>8}{'max':>8}{'MCAP log: median':>18}{'min':>8}{'max':>8}"
    print(
        f"{'scene':<20}{head}   ms per simulated s: sim/local model/install/ticks"
        "   start-up s: load/made/made with log"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for scene in scenes:
            user = USERS.get(scene, "swing")
            first = run_virtual_named(scene, "ideal", user, 0.5)
            plain, logged, stages, starts = [], [], [], []
            for _ in range(args.repeats):
                r = run_virtual_named(scene, "ideal", user, args.seconds)
                plain.append(r.speedup)
                stages.append([v / 1e6 / args.seconds for v in r.stage_ns.values()])
                path = Path(tmp) / "x.mcap"
                r_log = run_virtual_named(scene, "ideal", user, args.seconds, path)
                logged.append(r_log.speedup)
                starts.append([r.load_s, r.setup_s, r_log.setup_s])
            split = "/".join(f"{v:.1f}" for v in np.median(np.array(stages), axis=0))
            start = "/".join(f"{v:.2f}" for v in np.median(np.array(starts), axis=0))
            print(
                f"{scene:<20}{np.median(plain):>15.1f}x{min(plain):>7.1f}x{max(plain):>7.1f}x"
                f"{np.median(logged):>17.1f}x{min(logged):>7.1f}x{max(logged):>7.1f}x   "
                f"{split:<31}{start}   (first load {first.load_s:.2f})"
            )
    print(f"\ntargets: >= {TARGET_NO_LOG:.0f}x without a log, >= {TARGET_LOG:.0f}x with it")
    return 0


if __name__ == "__main__":
    sys.exit(main())
