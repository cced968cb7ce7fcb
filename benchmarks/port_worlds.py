"""Every shipped port scene in real time in one haptic process (`haptic-run --scene NAME`,
docs/grasp.md "Port worlds in real time"): for each scene and device, `--repeat` runs of
`--seconds` each, as a user starts them (a fresh process: its kernels load from numba's
cache, its loop is the real-time runner), then `haptic-replay` of each log. Reports per
scene and device the medians over the repeats of: ticks delivered (the ticks run over the
periods that passed), overruns, work p50/p99/p99.9 (a tick's compiled call, µs) and whether
every log replayed bit for bit. Runs are interleaved (scene by scene, repeat by repeat) so a
noisy neighbour spreads over all of them.

    python -m haptic_local_model.benchmarks.port_worlds [--seconds 10] [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from haptic_local_model.shared.config import shipped

DEVICES = ("maglev", "twin_pantograph")
RUN = [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run"]
REPLAY = [sys.executable, "-m", "haptic_local_model.haptic_server.harness.replay"]


def one_run(scene: str, device: str, seconds: float, out: Path) -> dict[str, Any]:
    """One real-time run and the replay of its log: the run's figures, `replayed`."""
    log, summary = out / f"{scene}-{device}.mcap", out / f"{scene}-{device}.json"
    cmd = [*RUN, "--scene", scene, "--device", device, "--duration", str(seconds),
           "--log", str(log), "--summary-json", str(summary)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600 + 2 * seconds)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {proc.stderr.strip()}")
    figures: dict[str, Any] = json.loads(summary.read_text())
    replay = subprocess.run([*REPLAY, str(log)], capture_output=True, text=True, timeout=600)
    figures["replayed"] = replay.returncode == 0 and "bit-exact" in replay.stdout
    log.unlink()
    return figures


def medians(runs: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "runs": len(runs),
        "ticks_delivered": statistics.median(r["ticks_delivered"] for r in runs),
        "ticks_delivered_least": min(r["ticks_delivered"] for r in runs),
        "overruns": statistics.median(r["overruns"] for r in runs),
        "work_us": {
            q: statistics.median(r["work_us"][q] for r in runs) for q in ("p50", "p99", "p99_9")
        },
        "work_us_p99_worst": max(r["work_us"]["p99"] for r in runs),
        "replayed_bit_exact": all(r["replayed"] for r in runs),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--scene", action="append", help="only these scenes (default: all)")
    parser.add_argument("--device", action="append", help=f"default: {', '.join(DEVICES)}")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    scenes = args.scene or sorted(shipped("ports"))
    devices = args.device or list(DEVICES)
    runs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            for scene in scenes:
                for device in devices:
                    print(f"run {k + 1}/{args.repeat}: {scene} on {device}", file=sys.stderr)
                    r = one_run(scene, device, args.seconds, Path(tmp))
                    runs.setdefault((scene, device), []).append(r)
    table = {f"{s}/{d}": medians(v) for (s, d), v in runs.items()}
    print(f"{args.seconds:g} s a run, medians of {args.repeat} runs\n")
    print("| scene | device | ticks delivered (least) | overruns | work p50 / p99 / p99.9 µs "
          "(worst p99) | replay |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for name, m in table.items():
        scene, device = name.split("/")
        w = m["work_us"]
        print(
            f"| {scene} | {device} | {100 * m['ticks_delivered']:.2f} % "
            f"({100 * m['ticks_delivered_least']:.2f} %) | {m['overruns']:g} | "
            f"{w['p50']:.0f} / {w['p99']:.0f} / {w['p99_9']:.0f} ({m['work_us_p99_worst']:.0f}) | "
            f"{'bit-exact' if m['replayed_bit_exact'] else 'DIFFERS'} |"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"seconds": args.seconds, "repeat": args.repeat,
                                         "results": table}, indent=2))  # fmt: skip
    return 0 if all(m["replayed_bit_exact"] for m in table.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
