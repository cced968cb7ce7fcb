"""Forged local models with the sim's own credentials, against the real processes.

Both servers run on the default network (this installation's credentials) on a free port,
the default scene (`testbed`) with the ideal device and the swinging hand. Once the sim's
updates flow, a peer presenting the sim's credentials follows the proxy states, builds the
sim's next update from the proxy's own state (so everything else in it is consistent and
plausible) and publishes one forgery of benchmarks/forgeries.py in the sim's epoch. From
the haptic server's log, over the window after it:

- its verdict (refused, with the reason, or installed);
- how long the device was commanded at its limit on any axis (target: at most 50 ms);
- whether the loop's guard tripped, and if so how long after the sim's next good update
  rendering was normal again (not safe, no fault; target: within 200 ms);
- how many of the sim's own updates were refused (target: none, but one the forgery
  displaced: an installed forgery takes its sequence number).

    python -m benchmarks.model_attacks [--repeat 1] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.forgeries import EXPECTED, FORGERIES
from benchmarks.stranger import _Server
from device_models.registry import load_device
from haptic_server.log import UPDATE_TOPIC, read_json_topic, read_ticks
from shared.config import load_scene
from shared.net.config import EndpointSpec, free_loopback_port, load_network, on_port
from shared.net.transport import keys, open_session
from shared.protocol.proxy import ProxyState, decode_proxy
from shared.protocol.update import encode_update
from sim_server.world import SimWorld

SCENE, DEVICE, USER = "testbed", "ideal", "swing"
WINDOW_S = 0.6  # what the forgery did is judged over this long after it
FLOW_S = 1.0  # the sim's updates flow this long before the forgery
LIMIT_MS, RESUME_MS = 50.0, 200.0  # the targets


@dataclass
class AttackResult:
    forgery: str
    verdict: str  # "installed" or the reason it was refused
    at_limit_ms: float  # ticks at the device's limit in the window, as ms
    tripped: str  # the guard's fault ("" none)
    resumed_ms: float  # from the sim's first good update after the trip to normal rendering
    own_refused: int  # the sim's own updates refused in the window (but a displaced one)
    arrived: bool  # the forgery reached the haptic server at all

    def row(self) -> dict[str, Any]:
        return dict(self.__dict__)


class _Proxies:
    """The proxy states the haptic server publishes, as a sim sees them."""

    def __init__(self, session: Any, key: str) -> None:
        self.newest: ProxyState | None = None
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(key, self._receive)

    def _receive(self, sample: Any) -> None:
        proxy = decode_proxy(sample.payload.to_bytes())
        with self._cond:
            self.newest = proxy
            self._cond.notify_all()

    def next_rendering(self, epoch: int, timeout_s: float = 30.0) -> ProxyState:
        """The next proxy state published from now on that renders `epoch`."""
        end = time.monotonic() + timeout_s
        with self._cond:
            self.newest = None
            while True:
                p = self.newest
                if p is not None and p.epoch == epoch and p.valid and not p.safe_state:
                    self.newest = None
                    return p
                if not self._cond.wait(max(0.0, end - time.monotonic())):
                    raise RuntimeError("the haptic server does not render the sim's model")


def attack(forgery: str, workdir: Path, network: str = "loopback") -> AttackResult:
    """One run of both servers and one forged update; the servers are stopped by their pids."""
    scene = load_scene(SCENE)
    port = free_loopback_port()
    net = on_port(load_network(network), port)
    log = workdir / f"attack-{forgery}-{port}.mcap"
    common = ["--scene", SCENE, "--network", network, "--port", str(port)]
    py = sys.executable
    haptic = _Server([py, "-m", "haptic_server.cli", *common, "--device", DEVICE, "--user", USER,
                      "--log", str(log)])  # fmt: skip
    sim: _Server | None = None
    peer = None
    raw = b""
    try:
        haptic.wait_ready()
        sim = _Server([py, "-m", "sim_server.cli", *common])
        sim.wait_ready()
        epoch = int(sim.ready["epoch"])
        spec = EndpointSpec(
            connect=net.sim.connect, user="sim", password_file=net.sim.password_file
        )
        peer = open_session(spec)
        pub = peer.declare_publisher(keys(net.namespace).update)
        proxies = _Proxies(peer, keys(net.namespace).proxy)
        # made (and its kernels loaded) now: the forgery must go out within one sim period
        world = SimWorld(scene)
        world.local_model(epoch, 0, 0)
        time.sleep(FLOW_S)
        proxy = proxies.next_rendering(epoch)
        raw = encode_update(FORGERIES[forgery](_next_update(world, proxy, epoch), scene))
        pub.put(raw)
        time.sleep(WINDOW_S)
    finally:
        if peer is not None:
            peer.close()
        codes = [haptic.stop()] + ([sim.stop()] if sim is not None else [])
    if any(codes):
        raise RuntimeError(f"a server exited with {codes}")
    result = measure(forgery, log, raw, load_device(DEVICE).limits().max_wrench)
    log.unlink(missing_ok=True)
    return result


def _next_update(world: SimWorld, proxy: ProxyState, epoch: int) -> Any:
    """The update the sim would publish two after the one the haptic server rendered last,
    at the proxy's state (the sim's tool follows it closely): consistent and plausible."""
    world.set_tool_state(proxy.q, proxy.qd)
    seq = proxy.update_seq + 2
    world.time = seq * world.period
    return world.local_model(epoch, seq, time.time_ns())


def measure(
    forgery: str, log: Path, raw: bytes, max_wrench: tuple[float, float, float]
) -> AttackResult:
    """The forgery's verdict and what followed it, from the haptic server's log."""
    records = read_json_topic(log, UPDATE_TOPIC)
    forged = [r for r in records if base64.b64decode(r["raw_b64"]) == raw]
    ticks = read_ticks(log)
    if not forged:
        return AttackResult(forgery, "lost", 0.0, "", 0.0, 0, False)
    rec = forged[0]
    verdict = "installed" if rec["installed"] else rec["reason"]
    start = int(rec["tick"])
    dt = float(np.median(ticks["dt"]))
    window = ticks[(ticks["tick"] >= start) & (ticks["tick"] < start + round(WINDOW_S / dt))]
    limit = np.asarray(max_wrench) * (1 - 1e-9)
    at_limit = int((np.abs(window["wrench_command"]) >= limit).any(axis=1).sum())
    faults = np.flatnonzero(window["fault"] != 0)
    tripped, resumed_ms = "", 0.0
    own = [r for r in records if r is not rec and "seq" in r and r.get("epoch") == rec.get("epoch")]
    own_in_window = [r for r in own if start <= int(r["tick"]) < start + len(window)]
    if faults.size:
        trip_tick = int(window["tick"][faults[0]])
        tripped = {1: "nonfinite", 2: "runaway", 3: "passivity"}.get(
            int(window["fault"][faults[0]]), "?"
        )
        good = [int(r["tick"]) for r in own_in_window if r["installed"] and r["tick"] > trip_tick]
        if good:
            after = window[window["tick"] >= good[0]]
            normal = np.flatnonzero((after["safe"] == 0.0) & (after["fault"] == 0))
            resumed_ms = float(normal[0]) * dt * 1e3 if normal.size else float("inf")
        else:
            resumed_ms = float("inf")
    # an installed forgery takes its sequence number: the sim's updates up to it that arrive
    # after it are refused as out of order (displaced, not refused because of what it said)
    refused = [
        r for r in own_in_window
        if not r["installed"] and not (rec["installed"] and r["reason"] == "sequence"
                                       and r["seq"] <= rec["seq"])
    ]  # fmt: skip
    return AttackResult(
        forgery, verdict, at_limit * dt * 1e3, tripped, resumed_ms, len(refused), True
    )


def meets_targets(r: AttackResult) -> bool:
    expected = EXPECTED[r.forgery]
    verdict_ok = (
        r.verdict == "installed" if expected == "guard" else r.verdict not in ("installed", "lost")
    )
    return (
        r.arrived and verdict_ok and r.at_limit_ms <= LIMIT_MS and r.resumed_ms <= RESUME_MS
        and r.own_refused == 0
    )  # fmt: skip


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
        f"`python -m benchmarks.model_attacks --repeat {args.repeat}`: one forgery per run, in"
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
            f" {'yes' if meets_targets(r) else 'NO'} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "model_attacks.md").write_text(text)
    return 0 if all(meets_targets(r) for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
