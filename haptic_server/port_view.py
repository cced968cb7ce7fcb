"""The live view of a port scene (`haptic-run --scene grasp_vertical --view`): the
co-simulated bodies (the object and the tools the devices hold) where the port engine has
them, and each device, drawn from the run's own rows. A hand scene (`--scene hand_grasp`,
`hand_press`) the same way: its box, each mass-spring hand (the palm's outline, each finger's
phalanges at their capsules' radius) and each device's measured position (the tracked palm).

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
from haptic_local_model.shared.config import BodySpec, load_config_text
from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.port_config import HandSceneConfig, HandSpec, PortSceneConfig
from haptic_local_model.shared.protocol.world_view import ROLE_DYNAMIC, ROLE_STATIC

TOOL_COLOR = (242, 89, 51)  # a port's tool (a pad): the proxy's orange of the single view
DEVICE_COLOR = (51, 115, 242)
FINGER_COLOR = (190, 60, 35)  # a hand's phalanges: darker than its palm's outline
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
    return rect_outline(body.size, x, y, angle)


def rect_outline(
    size: tuple[float, float], x: float, y: float, angle: float
) -> list[tuple[float, float]]:
    """A rectangle's outline (width, height `size`, centred on its pose), closed."""
    hx, hy = size[0] / 2, size[1] / 2
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


def hand_strips(
    hand: HandSpec, q: np.ndarray
) -> tuple[list[tuple[float, float]], list[list[tuple[float, float]]]]:
    """A hand at joint coordinates q (palm x, y, angle, then each finger's two phalanx
    angles; stages/hand.py `hand_chain`): its palm's outline, closed, and each finger's
    polyline from the middle of the palm's front edge through its two phalanges."""
    x, y, angle = float(q[0]), float(q[1]), float(q[2])
    w, h = hand.palm_size
    palm = rect_outline((w, h), x, y, angle)
    root = (x + w / 2 * np.cos(angle), y + w / 2 * np.sin(angle))
    fingers = []
    for i, finger in enumerate(hand.fingers):
        phi, points = angle, [root]
        for j in range(2):
            phi += float(q[3 + 2 * i + j])
            px, py = points[-1]
            points.append(
                (px + finger.lengths[j] * np.cos(phi), py + finger.lengths[j] * np.sin(phi))
            )
        fingers.append(points)
    return palm, fingers


class HandSceneView:
    """What is drawn of a hand run (one hand, or two on a box), from its rows."""

    def __init__(self, scene: HandSceneConfig, recording: Any) -> None:
        import rerun as rr

        self.rr, self.rec = rr, recording
        self.hands = [scene.hand_of(p) for p in range(len(scene.ports))]
        self.box = scene.box
        for body in scene.bodies:
            if body.shape != "box":
                raise ValueError(f"{scene.name}: body {body.name!r} is a {body.shape}; the "
                                 "hand view draws boxes")  # fmt: skip
        self._log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        walls = [box_outline(b, *b.position, b.angle) for b in scene.walls]
        if walls:
            self._log("world/static/walls", rr.LineStrips2D(
                walls, radii=LINE_M * 5, colors=[WALL_COLOR]), static=True)  # fmt: skip
        self.frames = 0

    def _log(self, path: str, archetype: Any, static: bool = False) -> None:
        self.rr.log(path, archetype, static=static, recording=self.rec)

    def frame(self, row: np.void) -> None:
        """One row: the box (a two-hand row's `box_q`), each hand at `q`, each device's
        tracked palm at `target`."""
        rr = self.rr
        rr.set_time("time", duration=float(row["t"]), recording=self.rec)
        n = len(self.hands)
        q = np.asarray(row["q"]).reshape(-1, MAX_DOF)[:n]
        target = np.asarray(row["target"]).reshape(-1, MAX_DOF)[:n]
        palms, fingers, finger_radii = [], [], []
        for hand, hand_q in zip(self.hands, q, strict=True):
            palm, hand_fingers = hand_strips(hand, hand_q)
            palms.append(palm)
            fingers += hand_fingers
            finger_radii += [f.radius for f in hand.fingers]
        self._log("world/bodies/tools", rr.LineStrips2D(
            palms, radii=LINE_M, colors=[TOOL_COLOR], draw_order=21,
        ))  # fmt: skip
        self._log("world/bodies/fingers", rr.LineStrips2D(
            fingers, radii=finger_radii, colors=[FINGER_COLOR], draw_order=19,
        ))  # fmt: skip
        if self.box is not None:
            bq = row["box_q"]
            outline = box_outline(self.box, float(bq[0]), float(bq[1]), float(bq[2]))
            self._log("world/bodies/objects", rr.LineStrips2D(
                [outline], radii=LINE_M, colors=[OBJECT_COLOR], draw_order=20,
            ))  # fmt: skip
        devices = [(float(p[0]), float(p[1])) for p in target]
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


def scene_view(topic: str, scene_text: str, recording: Any) -> PortSceneView | HandSceneView:
    """The view of a world kind (by its rows' topic) from its scene."""
    kind = viewed_kinds()[topic]
    scene = load_config_text(kind.scene, scene_text, f"the run's {kind.name} scene")
    if isinstance(scene, HandSceneConfig):
        return HandSceneView(scene, recording)
    return PortSceneView(scene, recording)


def viewed_kinds() -> dict[str, Any]:
    """The world kinds this view draws, by their rows' topic (world_runs.WORLD_KINDS's)."""
    from haptic_local_model.haptic_server.hand_grasp_ports import HAND_GRASP_KIND
    from haptic_local_model.haptic_server.hand_ports import HAND_KIND
    from haptic_local_model.haptic_server.ports import PORT_KIND

    return {kind.topic: kind for kind in (PORT_KIND, HAND_KIND, HAND_GRASP_KIND)}


def _live(config: dict[str, Any]) -> None:
    terminated = enter_view_process(config)
    topic = str(config["topic"])
    address = ViewAddress(config["bind"], int(config["web_port"]), int(config["grpc_port"]))
    rows = PortRows(int(config["n_rows"]), viewed_kinds()[topic].rows, name=config["shm_name"])
    server = RerunServer(address)
    try:
        rec = open_recording(address, "haptic-run")
        view = scene_view(topic, config["scene_text"], rec)
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
