"""Forged local models with the sim's own credentials, against the real processes.

Both servers run on the default network (this installation's credentials) on a free port,
the default scene (`testbed`) with the ideal device and the swinging hand. Once the sim's
updates flow, a peer presenting the sim's credentials follows the proxy states, builds the
sim's next update from the proxy's own state (so everything else in it is consistent and
plausible) and publishes one forgery of haptic_server/harness/forgeries.py in the sim's epoch. From
the haptic server's log, over the window after it:

- its verdict (refused, with the reason, or installed);
- how long the device was commanded at its limit on any axis (target: at most 50 ms);
- whether the loop's guard tripped, and if so how long after the sim's next good update
  rendering was normal again (not safe, no fault; target: within 200 ms);
- how many of the sim's own updates were refused (target: none, but one the forgery
  displaced: an installed forgery takes its sequence number).

    python -m haptic_local_model.benchmarks.model_attacks [--repeat 1] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from haptic_local_model.benchmarks.stranger import server_pair
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.forgeries import (
    EXPECTED,
    FORGERIES,
    LIMIT_MS,
    RESUME_MS,
    WINDOW_S,
    AttackResult,
    Forger,
    measure,
)
from haptic_local_model.shared.config import load_scene

SCENE, DEVICE, USER = "testbed", "ideal", "swing"
FLOW_S = 1.0  # the sim's updates flow this long before the forgery


def attack(forgery: str, workdir: Path, network: str = "loopback") -> AttackResult:
    """One run of both servers and one forged update; the servers are stopped by their pids."""
    scene = load_scene(SCENE)
    raw = b""
    extra = ["--device", DEVICE, "--user", USER]
    with server_pair(workdir, f"attack-{forgery}", SCENE, network, extra) as pair:
        forger = Forger(pair.net, scene, pair.epoch)
        try:
            time.sleep(FLOW_S)
            raw = forger.forge(forgery)
            time.sleep(WINDOW_S)
        finally:
            forger.close()
    log = pair.log
    result = measure(forgery, log, raw, load_device(DEVICE).limits().max_wrench)
    log.unlink(missing_ok=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--forgeries", nargs="*", default=sorted(FORGERIES))
    parser.add_argument("--out", type=Path, default=None, help="write model_attacks.md here")
    args = parser.parse_args(argv)
    results: list[AttackResult] = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):
            for name in args.forgeries:
                r = attack(name, Path(tmp))
                results.append(r)
                print(json.dumps(r.row()), flush=True)
    lines = [
        "# Forged local models against the real processes",
        "",
        f"`python -m haptic_local_model.benchmarks.model_attacks --repeat {args.repeat}`: one forgery per run, in"
        " the sim's epoch with the sim's credentials, default network, `testbed`, ideal device,"
        f" swinging hand; judged over {WINDOW_S:g} s after it. Targets: at most {LIMIT_MS:g} ms"
        f" at the device's limit, normal rendering within {RESUME_MS:g} ms of the sim's next"
        " good update after a guard trip, none of the sim's own updates refused.",
        "",
        "| forgery | expected | verdict | at limit (ms) | guard | resumed (ms) | sim's refused | meets |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        resumed = f"{r.resumed_ms:.0f}" if r.tripped else "-"
        lines.append(
            f"| {r.forgery} | {EXPECTED[r.forgery]} | {r.verdict} | {r.at_limit_ms:.0f} |"
            f" {r.tripped or '-'} | {resumed} | {r.own_refused} |"
            f" {'yes' if r.meets_targets() else 'NO'} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "model_attacks.md").write_text(text)
    return 0 if all(r.meets_targets() for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
