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

The shared world (`haptic-world --view`) and a station (`haptic-station --view`) are drawn the
same way from the rows their loops keep (a ring: `rows_viewed`): the world's are a port
world's or a two-hands world's rows (its bodies, every station's tool and device as fed);
a station's are its own (`StationView`: its device, and its tool where the last ToolState it
took puts it, both in the station's frame). The view calls no compiled kernel.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from collections.abc import Iterator
from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.live_view import (
    VIEW_HZ,
    RerunServer,
    enter_view_process,
    open_recording,
    view_main,
)
from haptic_local_model.haptic_server.logger import BlockChild
from haptic_local_model.haptic_server.view_address import ViewAddress
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
        """The newest finished row (-1: none yet): the row before the latest (a written row's
        time is after 0, and later than the row's before it in the ring; the latest may be
        being written). The rows may be a ring (the shared world's, a station's)."""
        t = self.rows["t"]
        latest = int(np.argmax(t))
        if t[latest] <= 0.0 or (latest == 0 and t[-1] <= 0.0):
            return -1
        return (latest - 1) % len(t)

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


class StationView:
    """What is drawn of a station, from its rows (STATION_ROW_DTYPE): its device's pose and
    its tool (a pad's outline, or a palm's) where the last ToolState it took puts it, with
    the coupling's stretch between them; the tool is cleared while it has none."""

    def __init__(self, scene: PortSceneConfig | HandSceneConfig, port: str, recording: Any) -> None:
        import rerun as rr

        self.rr, self.rec = rr, recording
        index = [p.name for p in scene.ports].index(port)
        if isinstance(scene, HandSceneConfig):
            self.tool_size = scene.hand_of(index).palm_size
        else:
            tool = scene.body(scene.ports[index].tool)
            if tool.shape != "box":
                raise ValueError(f"{scene.name}: tool {tool.name!r} is a {tool.shape}; the "
                                 "station view draws boxes")  # fmt: skip
            self.tool_size = tool.size
        self._log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        self.frames = 0
        self._tool_shown = False

    def _log(self, path: str, archetype: Any, static: bool = False) -> None:
        self.rr.log(path, archetype, static=static, recording=self.rec)

    def frame(self, row: np.void) -> None:
        rr = self.rr
        rr.set_time("time", duration=float(row["t"]), recording=self.rec)
        device = (float(row["pose"][0]), float(row["pose"][1]))
        self._log("world/devices", rr.Points2D([device], radii=DEVICE_M, colors=[DEVICE_COLOR]))
        if int(row["have_tool"]):
            x, y, angle = (float(v) for v in row["tool_pose"])
            self._log("world/bodies/tools", rr.LineStrips2D(
                [rect_outline(self.tool_size, x, y, angle), [device, (x, y)]],
                radii=LINE_M, colors=[TOOL_COLOR, DEVICE_COLOR], draw_order=21,
            ))  # fmt: skip
            self._tool_shown = True
        elif self._tool_shown:
            self._log("world/bodies/tools", rr.Clear(recursive=False))
            self._tool_shown = False
        self.frames += 1


@contextlib.contextmanager
def rows_viewed(
    loop: Any, view: ViewAddress | None, scene_text: str, topic: str, port: str = ""
) -> Iterator[None]:
    """With a `view`: the loop's rows (`loop.rows`, a ring it fills) moved into shared memory
    and the port view drawing them until the block ends, when the rows are copied back out
    (the summary and the log read them after). Without: nothing."""
    from haptic_local_model.shared.timing import loop_cpu

    if view is None:
        yield
        return
    shared = PortRows(len(loop.rows), loop.rows.dtype)
    shared.rows.view(np.uint8)[:] = 0  # every page touched now, not in the loop
    loop.rows = shared.rows
    child = PortViewProcess(shared, {
        "bind": view.bind, "web_port": view.web_port, "grpc_port": view.grpc_port,
        "scene_text": scene_text, "topic": topic, "port": port, "loop_cpu": loop_cpu(),
    })  # fmt: skip
    try:
        yield
    finally:
        loop.rows = shared.rows.copy()
        child.stop()
        shared.close(unlink=True)


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


def scene_view(
    topic: str, scene_text: str, recording: Any, port: str = ""
) -> PortSceneView | HandSceneView | StationView:
    """The view of a world kind or of a station (by its rows' topic) from its scene."""
    from haptic_local_model.haptic_server.station_records import STATION_TOPIC
    from haptic_local_model.shared.config import parse_toml_text
    from haptic_local_model.shared.port_config import is_hand_scene

    if topic == STATION_TOPIC:
        hands = is_hand_scene(parse_toml_text(scene_text, "the station's scene"))
        scene_type = HandSceneConfig if hands else PortSceneConfig
        station_scene = load_config_text(scene_type, scene_text, "the station's scene")
        return StationView(station_scene, port, recording)
    kind = viewed_kinds()[topic]
    scene = load_config_text(kind.scene, scene_text, f"the run's {kind.name} scene")
    if isinstance(scene, HandSceneConfig):
        return HandSceneView(scene, recording)
    return PortSceneView(scene, recording)


def row_dtype(topic: str) -> np.dtype:
    """The rows of a world kind or of a station, by their topic."""
    from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE
    from haptic_local_model.haptic_server.station_records import STATION_TOPIC

    return STATION_ROW_DTYPE if topic == STATION_TOPIC else viewed_kinds()[topic].rows


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
    rows = PortRows(int(config["n_rows"]), row_dtype(topic), name=config["shm_name"])
    server = RerunServer(address)
    try:
        rec = open_recording(address, "haptic-run")
        view = scene_view(topic, config["scene_text"], rec, str(config.get("port", "")))
        print(f"live view: {address.url}", file=sys.stderr, flush=True)
        parent, seen_t, wall0 = int(config["parent_pid"]), 0.0, time.monotonic()
        while os.getppid() == parent and not terminated.is_set():
            newest = rows.newest()
            if newest >= 0:
                row = rows.rows[newest].copy()
                if float(row["t"]) > seen_t:  # a later row (the rows may be a ring)
                    view.frame(row)
                    seen_t = float(row["t"])
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
