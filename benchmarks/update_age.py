"""Update age (sim publish -> installed in the haptic loop) and where it goes, beside the floor.

Runs the default system as `make demo` does (haptic-run, testbed, ideal device, the MCAP log
on) `--repeat` times, and between them a Zenoh hop alone: two bare processes on the same
loopback network config, one publishing an update-sized message at the sim's rate, the
other stamping its arrival. From each run's log, every installed update's age is split into:

- transit: the sim's put -> the haptic server's sidecar has it in the mailbox (Zenoh's hop,
  the sidecar's callback), `age_ms` in the log;
- wait: mailbox -> the tick that installs it (`latency_s` - transit); the sim's phase lock
  (sim_server/pacing.py) aims each update at 0.2 ms before a tick.

The floor is one hop plus the wait for the next tick: the hop alone, measured here, plus
the wait a phase-locked update cannot avoid (the lock's margin). Targets: p50
<= 0.6 ms, p99 <= 1.5 ms; the figures are medians over the runs.

    python -m haptic_local_model.benchmarks.update_age [--seconds 10] [--repeat 3] [--network loopback]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic

TARGET_P50_MS, TARGET_P99_MS = 0.6, 1.5
PROBE_BYTES = 392  # the testbed's update
PROBE_HZ = 60.0
QUANTILES = (50, 90, 99)


def system_run(seconds: float, network: str, folder: Path) -> dict[str, np.ndarray]:
    """One default run with its log; every installed update's transit, wait and total (ms)."""
    log = folder / "run.mcap"
    subprocess.run(
        [
            sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--duration", str(seconds),
            "--network", network, "--log", str(log),
        ],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    updates = [u for u in read_json_topic(log, UPDATE_TOPIC) if u["installed"]]
    transit = np.array([u["age_ms"] for u in updates])
    total = np.array([u["latency_s"] * 1e3 for u in updates])
    return {"transit": transit, "wait": total - transit, "total": total}


def hop_run(seconds: float, network: str) -> np.ndarray:
    """One-way Zenoh latency (ms) of an update-sized message at the sim's rate, alone."""
    receiver = subprocess.Popen(
        [sys.executable, "-m", "haptic_local_model.benchmarks.update_age", "--probe", "receive", "--network",
         network, "--seconds", str(seconds)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    time.sleep(1.0)  # the listener first
    subprocess.run(
        [sys.executable, "-m", "haptic_local_model.benchmarks.update_age", "--probe", "send", "--network",
         network, "--seconds", str(seconds)],
        check=True,
    )  # fmt: skip
    out, _ = receiver.communicate(timeout=seconds + 60)
    return np.array(json.loads(out))


def _probe(role: str, network_name: str, seconds: float) -> None:
    """The hop's two ends, on the haptic and sim endpoints of the network config."""
    import zenoh

    from haptic_local_model.shared.net.config import load_network
    from haptic_local_model.shared.net.transport import open_session

    network = load_network(network_name)
    key = f"{network.namespace}/update_age_probe"
    if role == "receive":
        session = open_session(network.haptic, None, network.namespace)
        arrivals: list[float] = []

        def arrived(sample: Any) -> None:
            now = time.time_ns()
            sent = int.from_bytes(sample.payload.to_bytes()[:8], "little")
            arrivals.append((now - sent) / 1e6)

        session.declare_subscriber(key, arrived)
        end = time.monotonic() + seconds + 10.0
        while time.monotonic() < end and len(arrivals) < seconds * PROBE_HZ:
            time.sleep(0.05)
        session.close()
        print(json.dumps(arrivals[10:]))  # the first few ride on a fresh connection
        return
    session = open_session(network.sim, None, network.namespace)
    publisher = session.declare_publisher(
        key, congestion_control=zenoh.CongestionControl.DROP, express=True
    )
    time.sleep(3.0)  # a connecting peer finds the listener
    for _ in range(int(seconds * PROBE_HZ) + 10):
        publisher.put(time.time_ns().to_bytes(8, "little") + bytes(PROBE_BYTES - 8))
        time.sleep(1.0 / PROBE_HZ)
    session.close()


def _quantiles(v: np.ndarray) -> dict[str, float]:
    out = {f"p{q}": float(np.percentile(v, q)) for q in QUANTILES}
    out["max"] = float(v.max())
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--network", default="loopback")
    parser.add_argument("--probe", choices=["send", "receive"], help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.probe:
        _probe(args.probe, args.network, args.seconds)
        return 0
    runs: dict[str, list[dict[str, float]]] = {"transit": [], "wait": [], "total": [], "hop": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):  # interleaved: the system, then the hop alone
            for part, values in system_run(args.seconds, args.network, Path(tmp)).items():
                runs[part].append(_quantiles(values))
            runs["hop"].append(_quantiles(hop_run(args.seconds, args.network)))
    print(f"update age, ms (median over {args.repeat} runs of {args.seconds:g} s; the hop alone")
    print("measured between them):")
    print(f"{'':34}" + "".join(f"{k:>9}" for k in ("p50", "p90", "p99", "max")))
    labels = {
        "transit": "transit: put -> mailbox",
        "wait": "wait: mailbox -> installing tick",
        "total": "total: publish -> install",
        "hop": "a Zenoh hop alone (the floor)",
    }
    for part, label in labels.items():
        med = {k: float(np.median([r[k] for r in runs[part]])) for k in runs[part][0]}
        print(f"{label:34}" + "".join(f"{med[k]:9.3f}" for k in ("p50", "p90", "p99", "max")))
    p50 = float(np.median([r["p50"] for r in runs["total"]]))
    p99 = float(np.median([r["p99"] for r in runs["total"]]))
    ok = p50 <= TARGET_P50_MS and p99 <= TARGET_P99_MS
    print(
        f"\ntargets: p50 <= {TARGET_P50_MS} ms, p99 <= {TARGET_P99_MS} ms: "
        f"{'met' if ok else 'NOT met'} (p50 {p50:.3f}, p99 {p99:.3f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
