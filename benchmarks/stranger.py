"""A stranger on the default network: can it install an update or slow the sim's?

Both servers run as processes on the shipped default network (`loopback`: this
installation's credentials, access control, Zenoh's message size limit) on a free port. A
peer without credentials connects to the haptic server's endpoint and, phase by phase,
publishes valid-looking local models of a newer epoch, then 1, 10 and 100 MB messages, then
a 10 kHz flood of small ones. From the haptic server's log: how many of its messages arrived
(none may), how many were installed (none may), and the age (publish -> installed) of the
sim's updates in each phase, against a quiet phase before and after, interleaved.

    python -m haptic_local_model.benchmarks.stranger [--phase-s 2] [--repeat 3] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import base64
import struct
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from haptic_local_model.haptic_server.harness.run import Child
from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.net.config import (
    EndpointSpec,
    NetworkConfig,
    free_loopback_port,
    load_network,
    on_port,
)
from haptic_local_model.shared.net.transport import keys, open_session
from haptic_local_model.shared.protocol.layout import PUBLISH_TIME_AT
from haptic_local_model.shared.protocol.update import encode_update
from haptic_local_model.sim_server.world import SimWorld

SCENE = "free_box"
PHASES = ("quiet", "updates", "1MB", "10MB", "100MB", "flood_10kHz", "quiet_after")
FLOOD_HZ = 10_000.0
READY_TIMEOUT_S = 300.0


@dataclass
class StrangerResult:
    """The sim's update ages by phase (ms), and what of the stranger's arrived."""

    ages_ms: dict[str, list[float]] = field(default_factory=dict)
    stranger_sent: int = 0
    stranger_arrived: int = 0  # records in the haptic log not from the sim
    installed_epochs: set[int] = field(default_factory=set)
    sim_epoch: int = 0

    def percentile(self, phase: str, q: float) -> float:
        ages = self.ages_ms.get(phase, [])
        return float(np.percentile(ages, q)) if ages else float("nan")


@dataclass(frozen=True)
class ServerPair:
    """Both servers of a run on a free loopback port: the network they meet on, the haptic
    server's log, the sim's epoch."""

    net: NetworkConfig
    log: Path
    epoch: int
    sim_pid: int = 0
    haptic_pid: int = 0
    #: the haptic server's JSON events as they come (its `stopped` summary last)
    events: list[dict[str, Any]] = field(default_factory=list)
    #: the sim's, the same
    sim_events: list[dict[str, Any]] = field(default_factory=list)


@contextmanager
def server_pair(
    workdir: Path, stem: str, scene: str, network: str, haptic_extra: list[str]
) -> Iterator[ServerPair]:
    """Start the haptic server (logging to workdir/<stem>-<port>.mcap) and then the sim on
    `scene`, wait until both are ready; on leaving, stop both by their pids whatever happened,
    and raise if either exited with an error."""
    port = free_loopback_port()
    net = on_port(load_network(network), port)
    log = workdir / f"{stem}-{port}.mcap"
    common = ["--scene", scene, "--network", network, "--port", str(port)]
    py = sys.executable
    haptic = Child("haptic", [py, "-m", "haptic_local_model.haptic_server.cli", *common,
                              *haptic_extra, "--log", str(log)])  # fmt: skip
    sim: Child | None = None
    try:
        _ready(haptic)
        sim = Child("sim", [py, "-m", "haptic_local_model.sim_server.cli", *common])
        epoch = int(_ready(sim)["epoch"])
        yield ServerPair(net, log, epoch, sim.proc.pid, haptic.proc.pid, haptic.events, sim.events)
    finally:
        codes = [haptic.stop()] + ([sim.stop()] if sim is not None else [])
    if any(codes):
        raise RuntimeError(f"a server exited with {codes}")


def run(phase_s: float, workdir: Path, network: str = "loopback") -> StrangerResult:
    """One run of every phase; the servers are stopped by their pids whatever happens."""
    bounds: dict[str, tuple[int, int]] = {}
    result = StrangerResult()
    with server_pair(workdir, "stranger", SCENE, network, ["--user", "constant_push"]) as pair:
        result.sim_epoch = pair.epoch
        time.sleep(1.0)  # the sim's updates flowing
        stranger = open_session(EndpointSpec(connect=pair.net.haptic.listen))  # no credentials
        try:
            pub = stranger.declare_publisher(
                keys(pair.net.namespace).update, congestion_control=zenoh.CongestionControl.DROP
            )
            world = SimWorld(load_scene(SCENE))
            for phase in PHASES:
                start = time.time_ns()
                result.stranger_sent += _attack(phase, pub, world, phase_s)
                bounds[phase] = (start, time.time_ns())
        finally:
            stranger.close()
    log = pair.log
    for rec in read_json_topic(log, UPDATE_TOPIC):
        if rec.get("epoch") != result.sim_epoch:
            result.stranger_arrived += 1
            continue
        if rec["installed"]:
            result.installed_epochs.add(int(rec["epoch"]))
            raw = base64.b64decode(rec["raw_b64"])
            published = struct.unpack_from("<q", raw, PUBLISH_TIME_AT)[0]
            for phase, (a, b) in bounds.items():
                if a <= published < b:
                    result.ages_ms.setdefault(phase, []).append(1e3 * rec["latency_s"])
    log.unlink(missing_ok=True)
    return result


def _ready(child: Child) -> dict[str, Any]:
    """Wait until the server says it is ready; its ready event."""
    if not child.wait_ready(READY_TIMEOUT_S):
        raise RuntimeError(f"the {child.name} server did not become ready")
    return next(e for e in child.events if e.get("event") == "ready")


def _attack(phase: str, pub: Any, world: SimWorld, seconds: float) -> int:
    """The stranger's messages of one phase; returns how many it sent."""
    end = time.monotonic() + seconds
    sent = 0
    if phase.startswith("quiet"):
        time.sleep(seconds)
    elif phase == "updates":  # a newer epoch than the sim's: it would take over
        epoch = time.time_ns()
        while time.monotonic() < end:
            pub.put(encode_update(world.local_model(epoch, sent, time.time_ns())))
            sent += 1
            time.sleep(1 / 60)
    elif phase.endswith("MB"):
        payload = bytes(int(phase[:-2]) * 1024 * 1024)
        while time.monotonic() < end:
            pub.put(payload)
            sent += 1
            time.sleep(0.1)
    else:
        # at FLOOD_HZ on average, a batch every millisecond: a stranger that spun a CPU
        # would measure the 2-core host's contention, not the network's
        small = encode_update(world.local_model(time.time_ns(), 0, time.time_ns()))
        batch = round(FLOOD_HZ / 1000)
        next_t = time.monotonic()
        while time.monotonic() < end:
            for _ in range(batch):
                pub.put(small)
            sent += batch
            next_t += 1e-3
            time.sleep(max(0.0, next_t - time.monotonic()))
    return sent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--phase-s", type=float, default=2.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None, help="write stranger.md here")
    args = parser.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):
            runs.append(run(args.phase_s, Path(tmp)))
    lines = [
        "# A stranger on the default network",
        "",
        f"`python -m haptic_local_model.benchmarks.stranger --phase-s {args.phase_s:g} --repeat {args.repeat}`:"
        " the sim's update age (publish -> installed) p50 / p99 in ms per phase, each run in"
        " one row; the stranger's messages sent, arrived at the haptic server, installed.",
        "",
        "| run | " + " | ".join(PHASES) + " | sent | arrived | installed |",
        "|---|" + "---|" * (len(PHASES) + 3),
    ]
    for i, r in enumerate(runs):
        cells = []
        for phase in PHASES:
            ages = r.ages_ms.get(phase, [])
            cells.append(
                f"{np.percentile(ages, 50):.2f} / {np.percentile(ages, 99):.2f}" if ages else "-"
            )
        others = len(r.installed_epochs - {r.sim_epoch})
        lines.append(
            f"| {i + 1} | " + " | ".join(cells)
            + f" | {r.stranger_sent} | {r.stranger_arrived} | {others} |"
        )  # fmt: skip
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "stranger.md").write_text(text)
    return 0 if all(r.stranger_arrived == 0 for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
