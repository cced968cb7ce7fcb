"""A network you can make bad: a user-space forwarder between two TUN devices that delays each
IP packet by D ± jitter, drops it with probability L and, if asked, lets a later packet
overtake an earlier one. This machine's kernel has no `netem` qdisc, so the impairment is a
process on the path instead.

Why between TUN devices and not a relay of Zenoh's TCP (or a Zenoh router in the middle):
a relay ends the TCP connection, so a packet it "drops" is never missing from the stream the
station reads and no retransmission ever stalls it; between TUN devices the packets are the
endpoints' own IP packets, TCP sees the loss and retransmits, and a UDP link sees it as a
lost datagram. The station's and the world's addresses stay those of the veth set-up
(`configs/network/stations_three_hosts`): the forwarder owns one TUN device in each
namespace and moves packets between them unchanged.

The forwarder opens both TUN devices in the namespace it runs in, says ready, and the
harness moves each device into its namespace (an open TUN descriptor stays attached to its
device when the device changes namespace). Each direction draws from its own seeded
generator, so a run is repeatable packet by packet for the same packet arrivals.

A pause stops the link for a window, as a stalled queue does: each SIGUSR1 the forwarder
takes holds every packet that arrives in the next `--pause-ms` (in one direction or both,
`--pause-dir`) until the window ends, then lets them on with their delays, in order (none
is lost: TCP sees a stall, not a loss).

    sudo .venv/bin/python -m haptic_local_model.benchmarks.impair --tun hw0 hs0 \
        --delay-ms 50 --jitter-ms 10 --loss 0.05 [--reorder] [--seed 1] \
        [--pause-ms 130 --pause-dir both]
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import heapq
import json
import os
import select
import signal
import struct
import sys
import time
from dataclasses import dataclass

import numpy as np

TUNSETIFF = 0x400454CA
IFF_TUN = 0x0001
IFF_NO_PI = 0x1000
MAX_PACKET = 65536
IP_PROTOCOLS = {6: "tcp", 17: "udp"}  # IPv4 header byte 9
IDLE_WAIT_S = 0.05  # how long the loop waits with nothing due (a stop is seen within this)
PAUSE_DIRS = ("both", "a_to_b", "b_to_a")


@dataclass(frozen=True)
class Impairment:
    """What a link does to each packet, each direction alike: a one-way delay drawn uniformly
    from [delay_s - jitter_s, delay_s + jitter_s], a loss with probability `loss`; unless
    `reorder`, a packet leaves no earlier than the one before it (jitter then bunches
    packets instead of swapping them, as a single queue does). A pause (Forwarder.pause, the
    forwarder's SIGUSR1) holds `pause_dir`'s packets for `pause_s` (module docstring)."""

    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    reorder: bool = False
    seed: int = 1
    pause_s: float = 0.0
    pause_dir: str = "both"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.delay_s) and self.delay_s >= 0.0):
            raise ValueError(f"impairment: delay_s must be >= 0, got {self.delay_s}")
        if not (np.isfinite(self.jitter_s) and 0.0 <= self.jitter_s <= self.delay_s):
            raise ValueError(
                f"impairment: jitter_s must be in [0, delay_s={self.delay_s}], got {self.jitter_s}"
            )
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"impairment: loss must be in [0, 1), got {self.loss}")
        if not (np.isfinite(self.pause_s) and self.pause_s >= 0.0):
            raise ValueError(f"impairment: pause_s must be >= 0, got {self.pause_s}")
        if self.pause_dir not in PAUSE_DIRS:
            raise ValueError(f"impairment: pause_dir must be one of {PAUSE_DIRS}")

    def argv(self) -> list[str]:
        """The forwarder's command-line flags for this impairment."""
        out = ["--delay-ms", f"{self.delay_s * 1e3:g}", "--jitter-ms", f"{self.jitter_s * 1e3:g}",
               "--loss", f"{self.loss:g}", "--seed", str(self.seed)]  # fmt: skip
        out += ["--pause-ms", f"{self.pause_s * 1e3:g}", "--pause-dir", self.pause_dir]
        return out + (["--reorder"] if self.reorder else [])


class Direction:
    """One direction of a link: when each packet that arrives leaves, or that it is lost."""

    def __init__(self, impairment: Impairment, stream: int) -> None:
        self.imp = impairment
        self.rng = np.random.default_rng([impairment.seed, stream])
        self.last_release = -np.inf
        self.passed = 0
        self.dropped = 0
        self.protocols = dict.fromkeys(IP_PROTOCOLS.values(), 0)  # IPv4 packets arrived
        self.paused_until = -np.inf  # a packet arriving before this enters the link then

    def release_at(self, now_s: float) -> float | None:
        """The time a packet arriving at now_s leaves, or None if it is lost."""
        imp = self.imp
        if imp.loss > 0.0 and self.rng.random() < imp.loss:
            self.dropped += 1
            return None
        t = (
            max(now_s, self.paused_until)
            + imp.delay_s
            + imp.jitter_s * (2.0 * self.rng.random() - 1.0)
        )
        if not imp.reorder:
            t = max(t, self.last_release)
        self.last_release = t
        self.passed += 1
        return t


class Forwarder:
    """Moves whole packets between two descriptors (TUN devices; in the tests datagram
    sockets), each direction through its own `Direction`; one thread, one heap of packets in
    flight ordered by when they leave."""

    def __init__(self, a: int, b: int, impairment: Impairment) -> None:
        self.fds = (a, b)
        self.directions = {a: Direction(impairment, 0), b: Direction(impairment, 1)}
        self.peer = {a: b, b: a}
        self.in_flight: list[tuple[float, int, int, bytes]] = []
        self.sent = 0
        self.stop = False

    def pause(self, now_s: float, seconds: float, which: str = "both") -> None:
        """Hold the packets arriving in [now_s, now_s + seconds) of `which` direction(s)
        (PAUSE_DIRS) until the window ends."""
        a, b = self.fds
        chosen = {"both": (a, b), "a_to_b": (a,), "b_to_a": (b,)}[which]
        for fd in chosen:
            d = self.directions[fd]
            d.paused_until = max(d.paused_until, now_s + seconds)

    def run(self, until_s: float = np.inf) -> None:
        """Forward until `stop` is set or the monotonic clock passes until_s."""
        while not self.stop and time.monotonic() < until_s:
            self.poll()

    def poll(self) -> None:
        """Wait for a packet or the next one due; take what arrived, send what is due."""
        now = time.monotonic()
        wait = IDLE_WAIT_S
        if self.in_flight:
            wait = min(wait, max(0.0, self.in_flight[0][0] - now))
        ready, _, _ = select.select(self.fds, [], [], wait)
        now = time.monotonic()
        for fd in ready:
            with contextlib.suppress(BlockingIOError, InterruptedError):
                self.take(fd, os.read(fd, MAX_PACKET), now)
        self.send_due(time.monotonic())

    def take(self, fd: int, packet: bytes, now_s: float) -> None:
        d = self.directions[fd]
        if len(packet) > 9 and packet[0] >> 4 == 4 and packet[9] in IP_PROTOCOLS:
            d.protocols[IP_PROTOCOLS[packet[9]]] += 1
        t = d.release_at(now_s)
        if t is not None:
            self.sent += 1  # a tie-breaker: equal release times leave in arrival order
            heapq.heappush(self.in_flight, (t, self.sent, self.peer[fd], packet))

    def send_due(self, now_s: float) -> None:
        while self.in_flight and self.in_flight[0][0] <= now_s:
            _, _, fd, packet = heapq.heappop(self.in_flight)
            with contextlib.suppress(OSError):  # a device gone down: the packet is lost
                os.write(fd, packet)

    def counts(self) -> dict[str, dict[str, int]]:
        a, b = self.fds
        return {
            name: {"passed": d.passed, "dropped": d.dropped, **d.protocols}
            for name, d in (("a_to_b", self.directions[a]), ("b_to_a", self.directions[b]))
        }


def open_tun(name: str) -> int:
    """A new TUN device `name` (no packet-information header), its descriptor."""
    if len(name.encode()) > 15:
        raise ValueError(f"impairment: TUN device name {name!r} is longer than 15 bytes")
    fd = os.open("/dev/net/tun", os.O_RDWR)
    try:
        fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TUN | IFF_NO_PI))
    except OSError:
        os.close(fd)
        raise
    return fd


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tun", nargs=2, required=True, metavar=("A", "B"), help="TUN device names")
    ap.add_argument("--delay-ms", type=float, default=0.0, help="one-way delay, each direction")
    ap.add_argument("--jitter-ms", type=float, default=0.0, help="± uniform about the delay")
    ap.add_argument("--loss", type=float, default=0.0, help="probability a packet is lost")
    ap.add_argument("--reorder", action="store_true", help="a later packet may overtake")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--pause-ms", type=float, default=0.0, help="each SIGUSR1: hold this long")
    ap.add_argument("--pause-dir", choices=PAUSE_DIRS, default="both")
    args = ap.parse_args(argv)
    imp = Impairment(args.delay_ms / 1e3, args.jitter_ms / 1e3, args.loss, args.reorder,
                     args.seed, args.pause_ms / 1e3, args.pause_dir)  # fmt: skip
    a, b = (open_tun(n) for n in args.tun)
    fwd = Forwarder(a, b, imp)

    def stop(*_: object) -> None:
        fwd.stop = True

    def pause(*_: object) -> None:
        fwd.pause(time.monotonic(), imp.pause_s, imp.pause_dir)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGUSR1, pause)
    print(json.dumps({"event": "ready", "tun": args.tun}), flush=True)
    fwd.run()
    print(json.dumps({"event": "summary", "counts": fwd.counts()}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
