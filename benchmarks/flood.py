"""A flood on every key the haptic server subscribes to (issue 48): what it costs in memory,
whether its refusals are counted by reason, and whether a safety event is lost to it.

Both servers run as processes on the shipped default network (`loopback`) on a free port,
on a scene that subscribes to all three of the haptic server's keys: `coaster_loop` (a
train: its static description on `<ns>/static`) with the `pointer` user (`<ns>/input/pointer`),
besides the local model's `<ns>/local_model`. A peer with the sim's credentials (all the
access control lets publish there) sends, key after key, `--messages` messages that are each
refused: updates of a foreign magic, pointer inputs stamped 10 s ahead, static descriptions
with distinct foreign ids (each one a text the receiver has not seen); and proxy states of a
foreign magic toward the sim's own subscriber, which the access control drops at the haptic
server (only it may publish there). The sim is stopped
(SIGSTOP) from the flood's start to its end, so the haptic server's watchdog trips during it.

Then the shared world's station ports (`run_world`): through the router, each port's key
flooded with its own station's credentials, no station running.

Figures: each of the haptic server's processes' resident memory (VmRSS) before the flood and
after it (the flood's own growth), the refusals by reason from the server's summary, the
watchdog trips and the events the log lost (`lost`).

    python -m haptic_local_model.benchmarks.flood [--messages 30000] [--repeat 1]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from haptic_local_model.benchmarks.stranger import server_pair
from haptic_local_model.haptic_server.harness.soak import children, helper_name, rss_mb
from haptic_local_model.haptic_server.log import EVENT_TOPIC, read_json_topic
from haptic_local_model.haptic_server.shared_world import DEVICE_RING
from haptic_local_model.shared.net.config import EndpointSpec
from haptic_local_model.shared.net.transport import keys, open_session
from haptic_local_model.shared.protocol.pointer import encode_pointer
from haptic_local_model.shared.protocol.static import (
    STATIC_HEADER,
    STATIC_MAGIC,
    STATIC_VERSION,
    canonical,
    id_of,
)

SCENE = "coaster_loop"
USER = "pointer"
MESSAGES = 30_000
GROWTH_TARGET_MB = 1.0
SETTLE_S = 20.0  # after ready: the log writer's first growth (docs/bench soak) is done
AFTER_S = 5.0  # after the flood: its backlog taken, logged and trimmed before the reading
FUTURE_NS = 10_000_000_000  # a pointer stamp this far ahead of every receiver's clock


def junk_update(i: int) -> bytes:
    """An update of a foreign magic (refused by the parser; distinct each time)."""
    return struct.pack("<4sq", b"JUNK", i) + bytes(64)


def future_pointer(i: int) -> bytes:
    return encode_pointer(i + 1, time.time_ns() + FUTURE_NS, (0.01, 0.0, 0.0))


def foreign_static(i: int) -> bytes:
    desc = {"flood": i}
    return STATIC_HEADER.pack(STATIC_MAGIC, STATIC_VERSION, id_of(desc)) + canonical(desc)


#: a proxy state of a foreign magic, sent toward the sim: the access control lets only the
#: haptic server publish proxy states (a sim may only follow them), so none may reach it
junk_proxy = junk_update

FLOODS = {
    "update": junk_update,
    "pointer": future_pointer,
    "static": foreign_static,
    "proxy": junk_proxy,
}


@dataclass
class FloodResult:
    """What the flood cost and what the server said of it."""

    sent: dict[str, int] = field(default_factory=dict)
    rss_mb: list[dict[str, float]] = field(default_factory=list)  # before, after each round
    summary: dict[str, Any] = field(default_factory=dict)  # the haptic server's, at its stop
    sim_summary: dict[str, Any] = field(default_factory=dict)  # the sim's, at its stop
    watchdog_trips: int = 0
    events_lost: int = 0
    flood_s: float = 0.0

    def growth_mb(self, r: int) -> dict[str, float]:
        """Each process's growth over round r (0: the first)."""
        before, after = self.rss_mb[r], self.rss_mb[r + 1]
        return {p: after[p] - before[p] for p in before}

    def own_growth_mb(self, control: FloodResult, r: int) -> dict[str, float]:
        """The flood's own growth over round r: this run's less its control's (`run` with
        `control_s`), which grows by a few hundred kB in a round with no flood at all."""
        return {p: mb - control.growth_mb(r)[p] for p, mb in self.growth_mb(r).items()}


def _processes(haptic_pid: int) -> dict[str, int]:
    """The haptic server's processes by name: its loop's, its I/O's and its log writer's."""
    found = {"haptic": haptic_pid}
    for kid in children(haptic_pid):
        name = helper_name(kid)
        if name is not None:
            found[name] = kid
    return found


def _rss(pids: dict[str, int]) -> dict[str, float]:
    return {name: rss_mb(pid) or float("nan") for name, pid in pids.items()}


def _put_all(session: Any, key: str, messages: int, make: Callable[[int], bytes]) -> None:
    """make(i) for i < messages on `key`, each waiting for room (nothing dropped at the
    sender)."""
    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    for i in range(messages):
        pub.put(make(i))
    pub.undeclare()


def _rounds(
    result: FloodResult, rounds: int, pids: dict[str, int], flood_once: Callable[[], None]
) -> None:
    """`rounds` floods, each timed and followed by AFTER_S and a reading of `pids`' memory."""
    for _ in range(rounds):
        start = time.perf_counter()
        flood_once()
        result.flood_s = time.perf_counter() - start
        time.sleep(AFTER_S)
        result.rss_mb.append(_rss(pids))


def run(
    workdir: Path,
    messages: int = MESSAGES,
    rounds: int = 2,
    control_s: float | None = None,
    floods: tuple[str, ...] = tuple(FLOODS),
) -> FloodResult:
    """`rounds` floods of every key, one after another (with `control_s`: none, the same
    timeline with this long instead of each: what the processes grow by anyway); the
    servers are stopped by their pids whatever happens."""
    result = FloodResult()
    extra = ["--user", USER, "--device", "ideal"]
    with server_pair(workdir, "flood", SCENE, "loopback", extra) as pair:
        time.sleep(SETTLE_S)
        pids = _processes(pair.haptic_pid)
        result.rss_mb.append(_rss(pids))
        sim = pair.net.sim
        spec = EndpointSpec(connect=sim.connect, user=sim.user, password_file=sim.password_file)
        session = open_session(spec)
        k = keys(pair.net.namespace)
        os.kill(pair.sim_pid, signal.SIGSTOP)
        try:

            def flood_once() -> None:
                if control_s is not None:
                    time.sleep(control_s)
                for name in floods if control_s is None else ():
                    _put_all(session, getattr(k, name), messages, FLOODS[name])
                    result.sent[name] = result.sent.get(name, 0) + messages

            _rounds(result, rounds, pids, flood_once)
        finally:
            os.kill(pair.sim_pid, signal.SIGCONT)
            session.close()
        time.sleep(1.0)  # the sim's updates again: the server back out of its safe state
    stopped = [e for e in pair.events if e.get("event") == "stopped"]
    result.summary = stopped[-1] if stopped else {}
    sim_stopped = [e for e in pair.sim_events if e.get("event") == "stopped"]
    result.sim_summary = sim_stopped[-1] if sim_stopped else {}
    events = read_json_topic(pair.log, EVENT_TOPIC)
    result.watchdog_trips = sum(1 for e in events if e.get("kind") == "watchdog")
    result.events_lost = sum(1 for e in events if e.get("kind") == "lost")
    pair.log.unlink(missing_ok=True)
    return result


def run_world(workdir: Path, messages: int = MESSAGES, rounds: int = 2) -> FloodResult:
    """`rounds` floods of the shared world's station ports: through the router, each port's
    key flooded with its own station's credentials (all the router lets publish there) by
    DeviceStates of a foreign magic, no station running; the world's resident memory and its
    refusals by reason (in its summary, `ports`)."""
    from haptic_local_model.benchmarks.stations import CLI, Process, loopback_network
    from haptic_local_model.shared.net.stations import (
        load_station_network,
        open_client,
        port_keys,
    )

    result = FloodResult()
    net = loopback_network(workdir)
    network = load_station_network(net, "router")
    summary = workdir / "world.json"
    router = Process([*CLI, "router", "--network", net])
    world: Process | None = None
    try:
        router.wait_ready()
        world = Process([*CLI, "world", "--network", net, "--scene", "grasp_vertical",
                         "--json", str(summary)])  # fmt: skip
        world.wait_ready()
        time.sleep(SETTLE_S)
        pids = {"world": world.proc.pid}
        result.rss_mb.append(_rss(pids))
        sessions = {p: open_client(network.station(p)) for p in ("left", "right")}
        try:

            def flood_once() -> None:
                for port, session in sessions.items():
                    _put_all(session, port_keys(network.namespace, port)[0], messages, junk_update)
                    result.sent[port] = result.sent.get(port, 0) + messages

            _rounds(result, rounds, pids, flood_once)
        finally:
            for session in sessions.values():
                session.close()
    finally:
        for proc in (world, router):
            if proc is not None:
                proc.stop()
    if summary.is_file():
        result.summary = json.loads(summary.read_text())
    return result


def report(result: FloodResult) -> list[str]:
    s = result.summary
    what = ", ".join(f"{n} {k}" for k, n in result.sent.items()) or "none: the control"
    lines = [f"flood: {sum(result.sent.values())} messages ({what}), a round in {result.flood_s:.2f} s, "
             "the sim stopped throughout"]  # fmt: skip
    for proc, start in result.rss_mb[0].items():
        rounds = ", ".join(
            f"{g[proc]:+.2f}" for g in map(result.growth_mb, range(len(result.rss_mb) - 1))
        )
        lines.append(f"  {proc:10s} resident {start:7.1f} MB, grew by round: {rounds} MB")
    lines.append(f"  updates refused by reason: {s.get('rejected_by_reason')}, not taken "
                 f"(the mailbox full, counted): {s.get('updates_lost')}")  # fmt: skip
    lines.append(f"  pointer inputs refused by reason: {s.get('pointer_rejected_by_reason')}")
    lines.append(f"  static messages refused by reason: {s.get('static_refused_by_reason')}")
    sim = result.sim_summary
    lines.append(f"  proxy states that reached the sim, refused by reason: "
                 f"{sim.get('proxies_rejected_by_reason')} (the access control drops them)")  # fmt: skip
    lines.append(f"  watchdog trips in the log: {result.watchdog_trips}; events lost: "
                 f"{result.events_lost}")  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flood", description=__doc__.split("\n\n")[0])
    parser.add_argument("--messages", type=int, default=MESSAGES, help="per key")
    parser.add_argument("--rounds", type=int, default=2, help="floods in one run, in turn")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--keys", nargs="+", choices=tuple(FLOODS), default=list(FLOODS))
    args = parser.parse_args(argv)
    worst = 0.0
    with tempfile.TemporaryDirectory(prefix="flood-") as tmp:
        for _ in range(args.repeat):  # interleaved: a flood, then its control
            flood = run(Path(tmp), args.messages, args.rounds, None, tuple(args.keys))
            print("\n".join(report(flood)))
            control = run(Path(tmp), args.messages, args.rounds, flood.flood_s)
            print("\n".join(report(control)))
            for r in range(args.rounds):
                own = flood.own_growth_mb(control, r)
                print(f"  round {r + 1}, the flood's own growth (flood - control): "
                      + ", ".join(f"{p} {mb:+.2f} MB" for p, mb in own.items()))  # fmt: skip
                worst = max(worst, *own.values())
        for _ in range(args.repeat):  # the shared world's station ports, the same way
            world = run_world(Path(tmp), args.messages, args.rounds)
            rounds = ", ".join(f"{world.growth_mb(r)['world']:+.2f}" for r in range(args.rounds))
            refused = {p: v["rejected_by_reason"] for p, v in world.summary["ports"].items()}
            print(f"world: {sum(world.sent.values())} DeviceStates ({world.sent}), resident "
                  f"{world.rss_mb[0]['world']:.1f} MB, grew by round: {rounds} MB; refused by "
                  f"reason {refused} (the rest dropped by its ring of {DEVICE_RING})")  # fmt: skip
    print(f"largest growth of the haptic server's processes {worst:+.2f} MB (target <= "
          f"{GROWTH_TARGET_MB:g} MB)")  # fmt: skip
    return 0 if worst <= GROWTH_TARGET_MB else 1


if __name__ == "__main__":
    sys.exit(main())
