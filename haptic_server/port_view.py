"""The live view of a port scene (`haptic-run --scene grasp_vertical --view`): the
co-simulated bodies (the object and the tools the devices hold) where the port engine has
them, and each device, drawn from the run's own rows.

A port scene runs its world in the haptic-run process (haptic_server.world_runs), so there is
no sim and no world message: the rows the loop fills are the state. With --view they live in
shared memory (`PortRows`), and a process of its own (`python -m
haptic_local_model.haptic_server.port_view CONFIG.json`, niced, off the loop's CPU) reads the
newest finished row at VIEW_HZ and draws it with Rerun, as live_view.py does for a single
device. The loop never waits on it: it only writes the rows it always wrote.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.live_view import (
    VIEW_HZ,
    RerunServer,
    ViewAddress,
    enter_view_process,
    open_recording,
    view_main,
)
from haptic_local_model.haptic_server.logger import BlockChild
from haptic_local_model.haptic_server.view_world import ROLE_COLORS
from haptic_local_model.shared.config import BodySpec
from haptic_local_model.shared.port_config import PortSceneConfig
from haptic_local_model.shared.protocol.world_view import ROLE_DYNAMIC, ROLE_STATIC

TOOL_COLOR = (242, 89, 51)  # a port's tool (a pad): the proxy's orange of the single view
DEVICE_COLOR = (51, 115, 242)
OBJECT_COLOR = ROLE_COLORS[ROLE_DYNAMIC]
WALL_COLOR = ROLE_COLORS[ROLE_STATIC]
LINE_M = 0.0002  # outline half-width: thin, the pads' and the box's sides touch
DEVICE_M = 0.001  # a device's dot: inside its pad's outline (a pad is 6 mm wide)


class PortRows:
    """A port run's rows in shared memory (the loop writes them as it always does)."""

    def __init__(self, n: int, dtype: np.dtype, name: str | None = None) -> None:
        size = max(n * dtype.itemsize, 1)
        self.shm = shared_memory.SharedMemory(name=name, create=name is None, size=size)
        if name is not None:  # attached: the creator unlinks it (mailbox.SharedBlock.attach)
            resource_tracker.unregister(self.shm._name, "shared_memory")  # type: ignore[attr-defined]
        self.rows: np.ndarray = np.ndarray((n,), dtype, buffer=self.shm.buf)

    def newest(self) -> int:
        """The newest finished row (-1: none yet): the row before the last one written (a
        written row's time is after 0; the last may be being written)."""
        written = np.flatnonzero(self.rows["t"] > 0.0)
        return int(written[-1]) - 1 if len(written) else -1

    def close(self, unlink: bool) -> None:
        del self.rows
        self.shm.close()
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self.shm.unlink()


def box_outline(body: BodySpec, x: float, y: float, angle: float) -> list[tuple[float, float]]:
    """A box body's outline at pose (x, y, angle), closed."""
    hx, hy = body.size[0] / 2, body.size[1] / 2
    c, s = np.cos(angle), np.sin(angle)
    corners = ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy))
    return [(x + c * px - s * py, y + s * px + c * py) for px, py in corners]


class PortSceneView:
    """What is drawn of a port run, from its rows: one Rerun recording."""

    def __init__(self, scene: PortSceneConfig, recording: Any) -> None:
        import rerun as rr

        self.rr, self.rec = rr, recording
        self.order = scene.cosim_order()
        self.bodies = [scene.body(name) for name in self.order]
        self.tools = {p.tool for p in scene.ports}
        self.ports = len(scene.ports)
        for body in self.bodies:
            if body.shape != "box":
                raise ValueError(f"{scene.name}: body {body.name!r} is a {body.shape}; the "
                                 "port view draws boxes")  # fmt: skip
        self._log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        self.frames = 0

    def _log(self, path: str, archetype: Any, static: bool = False) -> None:
        self.rr.log(path, archetype, static=static, recording=self.rec)

    def frame(self, row: np.void) -> None:
        rr = self.rr
        rr.set_time("time", duration=float(row["t"]), recording=self.rec)
        q = row["q"]
        for kind, color, order in (("tools", TOOL_COLOR, 21), ("objects", OBJECT_COLOR, 20)):
            strips = [
                box_outline(body, float(q[3 * i]), float(q[3 * i + 1]), float(q[3 * i + 2]))
                for i, body in enumerate(self.bodies)
                if (body.name in self.tools) == (kind == "tools")
            ]
            if strips:
                self._log(f"world/bodies/{kind}", rr.LineStrips2D(
                    strips, radii=LINE_M, colors=[color], draw_order=order,
                ))  # fmt: skip
        devices = [(float(p[0]), float(p[1])) for p in row["device_pose"][: self.ports]]
        self._log("world/devices", rr.Points2D(devices, radii=DEVICE_M, colors=[DEVICE_COLOR]))
        self.frames += 1


class PortViewProcess(BlockChild):
    """Starts the port view on the rows' shared memory; it says where it serves on stderr."""

    def __init__(self, rows: PortRows, config: dict[str, Any]) -> None:
        super().__init__(
            "haptic_local_model.haptic_server.port_view", rows.shm.name,
            {**config, "n_rows": len(rows.rows)},
        )  # fmt: skip

    def stop(self) -> None:
        if self.alive:
            self._proc.send_signal(signal.SIGTERM)
        self.join(10.0)


def main(argv: list[str] | None = None) -> int:
    """`python -m haptic_local_model.haptic_server.port_view CONFIG.json` (PortViewProcess)."""
    return view_main(argv, _live)


def _live(config: dict[str, Any]) -> None:
    from haptic_local_model.haptic_server.ports import PORT_ROW_DTYPE
    from haptic_local_model.shared.config import load_config_text

    terminated = enter_view_process(config)
    scene = load_config_text(PortSceneConfig, config["scene_text"], "the run's port scene")
    address = ViewAddress(config["bind"], int(config["web_port"]), int(config["grpc_port"]))
    rows = PortRows(int(config["n_rows"]), PORT_ROW_DTYPE, name=config["shm_name"])
    server = RerunServer(address)
    try:
        rec = open_recording(address, "haptic-run")
        view = PortSceneView(scene, rec)
        print(f"live view: {address.url}", file=sys.stderr, flush=True)
        parent, seen, wall0 = int(config["parent_pid"]), -1, time.monotonic()
        while os.getppid() == parent and not terminated.is_set():
            newest = rows.newest()
            if newest > seen:
                view.frame(rows.rows[newest].copy())
                seen = newest
            time.sleep(1.0 / VIEW_HZ)
        rec.flush(timeout_sec=5.0)
        rec.disconnect()
        print(f"live view: {view.frames} frames in {time.monotonic() - wall0:.1f} s",
              file=sys.stderr, flush=True)  # fmt: skip
    finally:
        server.stop()
        rows.close(unlink=False)


if __name__ == "__main__":
    sys.exit(main())
