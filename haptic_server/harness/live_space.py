"""A user's own pymunk space, touched live (`haptic_local_model.api.run_live`).

The haptic server is the same process as `haptic-run`'s (`haptic_server/cli.py`, started
here with the scene the user's space is rendered with, `sim_server/user_space.py`), on the
default authenticated loopback network (`configs/network/loopback.toml`, on a free port of
this run's); the user's space is stepped, paced at the scene's rate, and its local model
published from this process by the sim's own server (`sim_server/server.py` `SimServer`, its
world the user's space): one network path, the sim's.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pymunk

from haptic_local_model.haptic_server.harness.run import READY_TIMEOUT_S, Child
from haptic_local_model.shared.config import Material, resolve
from haptic_local_model.shared.net.config import (
    free_loopback_port,
    load_network,
    on_loopback,
    on_port,
)
from haptic_local_model.sim_server.server import SimServer
from haptic_local_model.sim_server.user_space import UserSpaceWorld


def run_live(
    space: pymunk.Space,
    tool: pymunk.Body,
    seconds: float,
    device: str,
    user: str,
    log: Path | str | None,
    world_options: tuple[float, int, Material, float, Callable[[float], None] | None],
    network: str = "loopback",
) -> dict[str, Any]:
    """Start the haptic server on `device` (moved by the simulated `user`), then step and
    publish the user's space in real time for `seconds`; stop the server (by its pid) and
    return its summary (haptic-run's: ticks, tick rate, update age, faults) with the sim's
    under "sim". `world_options`: UserSpaceWorld's rate, substeps, contact, margin and
    after_step."""
    world = UserSpaceWorld(space, tool, *world_options)
    folder = Path(tempfile.mkdtemp(prefix="touch-live-"))
    try:
        scene_path = folder / "user_space.toml"
        scene_path.write_text(world.text)
        net = load_network(network, roles=("haptic", "sim"))
        port = free_loopback_port() if on_loopback(net) else None
        if port is not None:
            net = on_port(net, port)
        summary_path = folder / "haptic-summary.json"
        argv = [
            sys.executable, "-m", "haptic_local_model.haptic_server.cli",
            "--scene", str(scene_path),
            "--device", device, "--user", user, "--network", str(resolve("network", network)),
            "--duration", repr(seconds + 30.0), "--summary-json", str(summary_path),
        ]  # fmt: skip
        if port is not None:
            argv += ["--port", str(port)]
        if log is not None:
            argv += ["--log", str(Path(log).resolve())]
        haptic = Child("haptic", argv)
        try:
            if not haptic.wait_ready(READY_TIMEOUT_S):
                raise RuntimeError(
                    f"the haptic server did not become ready (exit {haptic.proc.poll()})"
                )
            sim = SimServer(world.scene, net, world=world).run(seconds)
        finally:
            code = haptic.stop()
        summary: dict[str, Any] = (
            json.loads(summary_path.read_text()) if summary_path.is_file() else {}
        )
        summary["sim"] = sim
        summary["haptic_exit"] = code
        return summary
    finally:
        shutil.rmtree(folder, ignore_errors=True)


__all__ = ["run_live"]
