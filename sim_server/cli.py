"""`sim-server`: the pymunk world at 30-60 Hz, publishing the local model over Zenoh; or,
with `--mirror PORT_SCENE`, the sim of a shared world's port scene: it mirrors the world's
co-simulated bodies and steps the scene's sim_bodies (sim_server/mirror.py,
docs/stations.md)."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import Any

from haptic_local_model.shared.cli import (
    EXIT_FAILED,
    add_config_args,
    done_with_signals,
    emit,
    run_main,
    seconds,
    write_summary,
)
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.net.config import load_network, on_port
from haptic_local_model.shared.timing import try_raise_priority


def clock_jump(text: str) -> Any:
    """AT_S,BY_MS,FOR_S: the sim's clock stepped by BY_MS from AT_S into the run, for FOR_S."""
    from haptic_local_model.sim_server.server import ClockJump

    try:
        at_s, by_ms, for_s = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected AT_S,BY_MS,FOR_S, got {text!r}") from None
    return ClockJump(at_s, by_ms, for_s)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sim-server", description=__doc__)
    add_config_args(parser, device=False, user=False)
    parser.add_argument(
        "--duration", type=seconds, default=None, help="stop after this many seconds"
    )
    parser.add_argument("--summary-json", type=Path, default=None)
    parser.add_argument(
        "--mirror",
        default=None,
        metavar="PORT_SCENE",
        help="mirror a shared world's port scene (configs/ports) and step its sim_bodies; "
        "--network is then a station network (default stations_loopback)",
    )
    parser.add_argument(
        "--rate", type=float, default=60.0, metavar="HZ", help="--mirror: the sim's rate"
    )
    parser.add_argument(
        "--inject-clock-jump", type=clock_jump, default=None, help=argparse.SUPPRESS
    )
    args = parser.parse_args(argv)
    try_raise_priority()  # before Zenoh starts its threads: they inherit it

    def body() -> int:
        if args.mirror is not None:
            return _mirror(args)
        from haptic_local_model.sim_server.server import SimServer

        scene = load_scene(args.scene)
        network = load_network(args.network, roles=("sim",))
        if args.port is not None:
            network = on_port(network, args.port)
        server = SimServer(scene, network, clock_jump=args.inject_clock_jump)
        signal.signal(signal.SIGTERM, server.request_stop)
        signal.signal(signal.SIGINT, server.request_stop)
        summary = server.run(
            args.duration, ready=lambda: emit("ready", process="sim", epoch=server.epoch)
        )
        emit("stopped", process="sim", **summary)
        if not write_summary(args.summary_json, summary, "sim-server"):
            return EXIT_FAILED
        return 0

    return done_with_signals(run_main(body), argv)


def _mirror(args: argparse.Namespace) -> int:
    from haptic_local_model.shared.config import ConfigError
    from haptic_local_model.shared.net.stations import load_station_network
    from haptic_local_model.shared.port_config import load_port_scene
    from haptic_local_model.sim_server.mirror import Mirror

    if not 30.0 <= args.rate <= 1000.0:  # the world carries a sample for at most 50 ms
        raise ConfigError("--rate", "rate", f"{args.rate:g} Hz: the mirror runs at 30 to 1000 Hz")
    # the single-device default network is not a station network: the stations' is
    network = load_station_network(
        "stations_loopback" if args.network == "loopback" else args.network, "sim"
    )
    scene = load_port_scene(args.mirror)
    if not scene.sim_bodies:
        raise ConfigError(args.mirror, "sim_bodies", "empty: the sim has no body to step")
    mirror = Mirror(scene, network, args.rate)
    signal.signal(signal.SIGTERM, mirror.request_stop)
    signal.signal(signal.SIGINT, mirror.request_stop)
    try:
        summary = mirror.run(
            args.duration, ready=lambda: emit("ready", process="sim", epoch=mirror.epoch)
        )
    except ConnectionError as exc:
        print(f"sim-server: {exc}", file=sys.stderr)
        return EXIT_FAILED
    emit("stopped", process="sim", **summary)
    if not write_summary(args.summary_json, summary, "sim-server"):
        return EXIT_FAILED
    return 0


if __name__ == "__main__":
    sys.exit(main())
