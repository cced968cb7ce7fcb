"""The console scripts of a shared world served to haptic stations (docs/stations.md):

    haptic-router  --network stations_loopback
    haptic-world   --network stations_loopback --scene grasp_vertical [--log world.mcap]
    haptic-station --network stations_loopback --scene grasp_vertical --port left \\
                   [--device maglev] [--user squeeze_left_2n] [--log left.mcap]

Each runs until SIGTERM or SIGINT (or --duration), then writes its log (a temporary file
renamed when whole) and its summary (--json), and prints one JSON line per event on stdout
(`ready`, `done`; a station's `softened` and `restored`: docs/stations.md, "Passivity"). The
world's log is a port world's log and a station's holds the tool states it rendered
against: `haptic-replay LOG` re-runs either bit for bit.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import zenoh

from haptic_local_model.device_models.registry import device_config, load_simulated_device
from haptic_local_model.haptic_server.hand_grasp_ports import HAND_GRASP_KIND
from haptic_local_model.haptic_server.log import write_rows_log
from haptic_local_model.haptic_server.port_scene import load_glove_users
from haptic_local_model.haptic_server.port_view import rows_viewed
from haptic_local_model.haptic_server.ports import PORT_KIND
from haptic_local_model.haptic_server.shared_world import SharedWorld
from haptic_local_model.haptic_server.station import MAX_LOG_S, RING_S, Station
from haptic_local_model.haptic_server.station_records import STATION_TOPIC
from haptic_local_model.haptic_server.view_address import add_view_args, view_address
from haptic_local_model.shared import __version__
from haptic_local_model.shared.cli import (
    add_version,
    emit,
    log_file,
    run_main,
    seconds,
    write_summary,
)
from haptic_local_model.shared.config import (
    ConfigError,
    load_config_text,
    load_user,
    parse_toml_text,
    resolve,
)
from haptic_local_model.shared.net.stations import (
    PASSIVITY,
    StationNetworkConfig,
    load_station_network,
    router_config,
)
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig, is_hand_scene


def _passivity(network: StationNetworkConfig, passivity: str | None) -> StationNetworkConfig:
    """The network, its `passivity` overridden by --passivity if given."""
    return network if passivity is None else replace(network, passivity=passivity)


def _local_model(network: StationNetworkConfig, local: str | None) -> StationNetworkConfig:
    """The network, its `local_model` overridden by --local-model (on, off) if given."""
    return network if local is None else replace(network, local_model=local == "on")


def _common(parser: argparse.ArgumentParser, scene: bool = True) -> None:
    add_version(parser)
    parser.add_argument(
        "--network", default="stations_loopback", help="station network in configs/network"
    )
    if scene:
        parser.add_argument(
            "--passivity", choices=PASSIVITY, default=None,
            help="the port links' passivity controllers (default: the network's)",
        )  # fmt: skip
        parser.add_argument(
            "--scene", default="grasp_vertical", help="port scene in configs/ports or a path"
        )
        parser.add_argument(
            "--duration", type=seconds, default=None, help="seconds (default: until stopped)"
        )
        parser.add_argument(
            "--log",
            type=log_file,
            default=None,
            metavar="OUT.mcap",
            help=f"every tick's row (needs --duration <= {MAX_LOG_S:g})",
        )
        parser.add_argument("--json", type=Path, default=None, help="write the summary here")


def _scene(name: str) -> tuple[PortSceneConfig | HandSceneConfig, str]:
    """A port scene, or a hand scene of two hands on a box (`hand_grasp`)."""
    path = resolve("ports", name)
    if not path.is_file():
        raise ConfigError(str(path), "scene", "no such file")
    text = path.read_text()
    if is_hand_scene(parse_toml_text(text, str(path))):
        hands = load_config_text(HandSceneConfig, text, str(path))
        if len(hands.ports) != 2:
            raise ConfigError(str(path), "ports", "one hand has no stations: run it with "
                              "haptic-run (two hands on a box have: hand_grasp)")  # fmt: skip
        load_glove_users(hands, [p.user for p in hands.ports])  # the world's gloves
        for i, hand in enumerate(hands.hands):
            if hand.damping != "relative":  # a station renders B (v_palm - v_device)
                raise ConfigError(str(path), f"hands[{i}].damping", "at stations a palm's "
                                  "damping is relative (the station's coupling law)")  # fmt: skip
        return hands, text
    return load_config_text(PortSceneConfig, text, str(path)), text


def _rows_for(args: argparse.Namespace, rate_hz: float) -> int:
    """Rows for the whole run when logged, else a ring of the last RING_S seconds."""
    if args.log is not None and (args.duration is None or args.duration > MAX_LOG_S):
        raise ConfigError("--log", "--duration", f"a logged run needs --duration <= {MAX_LOG_S:g}")
    span = args.duration if args.log is not None else min(args.duration or RING_S, RING_S)
    return round((span + 1.0) * rate_hz)


def _run_loop(prog: str, loop: Any, duration_s: float | None) -> dict[str, Any] | None:
    """Run the world's or a station's loop until SIGTERM, SIGINT or its duration; its
    summary, or None (said in one line) if the router cannot be reached."""
    signal.signal(signal.SIGTERM, loop.request_stop)
    signal.signal(signal.SIGINT, loop.request_stop)
    try:
        summary: dict[str, Any] = loop.run(duration_s, ready=lambda: emit("ready", prog=prog))
    except ConnectionError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None
    return summary


def _finish(prog: str, summary: dict[str, Any], path: Path | None) -> None:
    write_summary(path, summary, prog)
    emit("done", prog=prog, summary=summary)


def router_main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-router", description="The stations' Zenoh router")
    _common(parser, scene=False)
    args = parser.parse_args(argv)

    def body() -> int:
        network = load_station_network(args.network, "router")
        try:
            session = zenoh.open(router_config(network))
        except zenoh.ZError as exc:  # e.g. the address is taken
            print(f"haptic-router: cannot listen on {list(network.router.listen)}: {exc}",
                  file=sys.stderr)  # fmt: skip
            return 1
        done = threading.Event()
        signal.signal(signal.SIGTERM, lambda *_: done.set())
        signal.signal(signal.SIGINT, lambda *_: done.set())
        emit("ready", prog="haptic-router", listen=list(network.router.listen))
        try:
            while not done.wait(0.5):
                pass
        finally:
            session.close()
        emit("done", prog="haptic-router")
        return 0

    return run_main(body)


def world_main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-world", description="The stations' shared world")
    _common(parser)
    add_view_args(parser, "the world's bodies and every station's tool and device")
    args = parser.parse_args(argv)

    def body() -> int:
        network = _passivity(load_station_network(args.network, "world"), args.passivity)
        scene, text = _scene(args.scene)
        world = SharedWorld(scene, network, _rows_for(args, scene.haptic_rate_hz))
        kind = HAND_GRASP_KIND if isinstance(scene, HandSceneConfig) else PORT_KIND
        with rows_viewed(world, view_address(args), text, kind.topic):
            summary = _run_loop("haptic-world", world, args.duration)
        if summary is None:
            return 1
        if args.log is not None:
            rows = world.logged_rows()
            write_rows_log(args.log, rows, kind.topic, kind.schema, {
                "configs": {"ports": text,
                            "devices": json.dumps([p.device for p in scene.ports]),
                            "users": json.dumps([p.user for p in scene.ports])},
                "limits": {"max_wrench": json.dumps([list(v) for v in world.limits])},
                "run": {"version": __version__, "ticks": str(len(rows)), "kind": "haptic-world",
                        "events": json.dumps(world.event_list())},
            })  # fmt: skip
        _finish("haptic-world", summary, args.json)
        return 0

    return run_main(body)


def station_main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-station", description="A port's haptic station")
    _common(parser)
    parser.add_argument("--port", required=True, help="the scene's port this station drives")
    parser.add_argument("--device", default=None, help="a simulated device (default: the port's)")
    parser.add_argument("--user", default=None, help="a simulated user (default: the port's)")
    parser.add_argument(
        "--local-model", choices=("on", "off"), default=None,
        help="render the pad's contact with the object here (default: the network's)",
    )  # fmt: skip
    add_view_args(parser, "this station's device and its tool as the world last sent it")
    args = parser.parse_args(argv)

    def body() -> int:
        network = _passivity(load_station_network(args.network, args.port), args.passivity)
        network = _local_model(network, args.local_model)
        scene, text = _scene(args.scene)
        spec = next((p for p in scene.ports if p.name == args.port), None)
        if spec is None:
            names = ", ".join(p.name for p in scene.ports)
            raise ConfigError(args.scene, "--port", f"{args.port!r} is not a port ({names})")
        device_name, user_name = args.device or spec.device, args.user or spec.user
        device, user = load_simulated_device(device_name), load_user(user_name)
        rows = _rows_for(args, scene.haptic_rate_hz)
        station = Station(scene, network, args.port, device, user, rows)
        station.on_event = lambda e: emit(
            e["event"], prog="haptic-station", **{k: v for k, v in e.items() if k != "event"}
        )
        with rows_viewed(station, view_address(args), text, STATION_TOPIC, args.port):
            summary = _run_loop("haptic-station", station, args.duration)
        if summary is None:
            return 1
        if args.log is not None:
            station.write_log(args.log, {
                "ports": text, "device": device_config(device_name).read_text(),
                "user": resolve("users", user_name).read_text(),
            })  # fmt: skip
        _finish("haptic-station", summary, args.json)
        return 0

    return run_main(body)


ROLES = {"router": router_main, "world": world_main, "station": station_main}


def main(argv: list[str] | None = None) -> int:
    """`python -m haptic_local_model.haptic_server.stations_cli ROLE ...` (the tests)."""
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] not in ROLES:
        print(f"usage: stations_cli {{{','.join(ROLES)}}} ...", file=sys.stderr)
        return 2
    return ROLES[args[0]](args[1:])


if __name__ == "__main__":
    sys.exit(main())
