"""A user's own pymunk space, touched live (`haptic_local_model.api.touch`, `run_live`).

The haptic server is the same process as `haptic-run`'s (`haptic_server/cli.py`): started
here with the scene the user's space is rendered with (`sim_server/user_space.py`), on the
default authenticated loopback network (`configs/network/loopback.toml`, on a free port of
this run's), or one the user already runs (`haptic-server --scene FILE`, FILE from
`api.scene_file`, with any device, a real one included) reached over `network`. The user's
space is stepped and its local model published from this process by the sim's own server
(`sim_server/server.py` `SimServer`, its world the user's space), one step each time the
user's loop calls `LiveSpace.step`: one network path, the sim's.
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

#: UserSpaceWorld's rate, substeps, contact, margin and after_step
WorldOptions = tuple[float, int, Material, float, Callable[[float], None] | None]


class LiveSpace:
    """The user's space held live, their loop stepping it: `open` starts the haptic server
    on `device` (moved by the simulated `user`; `start_haptic`) or reaches the one running
    on `network`, and connects the sim's server; each `step` waits for the step's deadline
    (the scene's rate), steps the space over the coming period with the held body driven
    toward the haptic proxy, and publishes its local model; `close` disconnects, stops the
    haptic server it started (by its pid) and returns the summaries."""

    def __init__(self, space: pymunk.Space, tool: pymunk.Body, world_options: WorldOptions,
                 device: str, user: str, log: Path | str | None, network: str,
                 start_haptic: bool) -> None:  # fmt: skip
        self.world = UserSpaceWorld(space, tool, *world_options)
        self.device, self.user, self.log = device, user, log
        self.network, self.start_haptic = network, start_haptic
        self._folder = Path(tempfile.mkdtemp(prefix="touch-live-"))
        self._haptic: Child | None = None
        self._sim: SimServer | None = None

    def open(self) -> None:
        net = load_network(self.network, roles=("haptic", "sim"))
        port = free_loopback_port() if self.start_haptic and on_loopback(net) else None
        if port is not None:
            net = on_port(net, port)
        if self.start_haptic:
            self._haptic = self._start_haptic(port)
        sim = SimServer(self.world.scene, net, world=self.world)
        sim.connect()
        self._sim = sim

    def _start_haptic(self, port: int | None) -> Child:
        scene_path = self._folder / "user_space.toml"
        scene_path.write_text(self.world.text)
        argv = [
            sys.executable, "-m", "haptic_local_model.haptic_server.cli",
            "--scene", str(scene_path), "--device", self.device, "--user", self.user,
            "--network", str(resolve("network", self.network)),
            "--summary-json", str(self._folder / "haptic-summary.json"),
        ]  # fmt: skip
        if port is not None:
            argv += ["--port", str(port)]
        if self.log is not None:
            argv += ["--log", str(Path(self.log).resolve())]
        haptic = Child("haptic", argv)
        if not haptic.wait_ready(READY_TIMEOUT_S):
            code = haptic.stop()
            raise RuntimeError(f"the haptic server did not become ready (exit {code})")
        return haptic

    def step(self) -> float:
        """One step of the user's space at its deadline, published: the space's time (s)."""
        if self._sim is None:
            raise RuntimeError("step() outside the session: use `with api.touch(...) as hand`")
        self._sim.step()
        return float(self.world.time)

    def close(self) -> dict[str, Any]:
        """Disconnected, the haptic server this session started stopped: its summary
        (haptic-run's: ticks, tick rate, update age, faults; empty for a server the user
        runs) with the sim's under "sim"."""
        summary: dict[str, Any] = {}
        try:
            if self._sim is not None:
                self._sim.close()
                summary["sim"] = self._sim.summary()
        finally:
            if self._haptic is not None:
                summary["haptic_exit"] = self._haptic.stop()
                path = self._folder / "haptic-summary.json"
                if path.is_file():
                    summary = {**json.loads(path.read_text()), **summary}
            shutil.rmtree(self._folder, ignore_errors=True)
        return summary


__all__ = ["LiveSpace", "WorldOptions"]
