"""`sim-server`: the pymunk world at 30-60 Hz, publishing the local model over Zenoh."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from shared.cli import add_config_args, emit, run_main, seconds
from shared.config import load_scene
from shared.net.config import load_network


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sim-server", description=__doc__)
    add_config_args(parser, device=False, user=False)
    parser.add_argument(
        "--duration", type=seconds, default=None, help="stop after this many seconds"
    )
    parser.add_argument("--summary-json", type=Path, default=None)
    args = parser.parse_args(argv)

    def body() -> int:
        from sim_server.server import SimServer

        scene = load_scene(args.scene)
        network = load_network(args.network, roles=("sim",))
        server = SimServer(scene, network)
        signal.signal(signal.SIGTERM, server.request_stop)
        signal.signal(signal.SIGINT, server.request_stop)
        summary = server.run(
            args.duration, ready=lambda: emit("ready", process="sim", epoch=server.epoch)
        )
        if args.summary_json:
            args.summary_json.write_text(json.dumps(summary, indent=2))
        emit("stopped", process="sim", **summary)
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(main())
