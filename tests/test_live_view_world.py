"""The live view draws the bodies the sim steps where the sim has them: headless Chromium
(Debian's, driven by Playwright) watches `haptic-run --view --log` on the testbed; when the
run ends the viewer keeps its last frame, and the block's and the shuttle's outlines in that
screenshot are compared with the last poses the sim sent (read back from the run's log, which
files every world message the view was given).

World to pixels is measured, not assumed: the walls' outer extent in the sim's shapes message
against the extent of the walls' colour in the screenshot gives the view's scale and offset
(Rerun fits its 2D camera to what is drawn). Skipped without a browser unless
HAPTIC_REQUIRE_BROWSER is set (CI)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_live_view import ARTIFACTS, SCENE, SETTLE_S, Proc, _browser, procs  # noqa: F401

from haptic_local_model.benchmarks.browser import free_ports, open_page, open_pages, pixels
from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.haptic_server.port_view import DEVICE_COLOR, TOOL_COLOR
from haptic_local_model.haptic_server.view_world import ROLE_COLORS, world_vertices
from haptic_local_model.shared.protocol.world_view import (
    ROLE_DYNAMIC,
    ROLE_KINEMATIC,
    ROLE_STATIC,
    WorldPoses,
    WorldShapes,
    decode_world,
)

RUN_S = 20  # the viewer loads (SETTLE_S) and draws the run live before it ends (stopped once shot)
PIXEL_TOL = 4.0  # px: the outline's anti-aliasing and line width, at ~2 px per mm here
COLOUR_TOL = 10  # per channel: the outlines' anti-aliased edges
REPLAY_CATCH_UP_S = 4.0  # the viewer takes the log and draws
SCALE_AGREEMENT = 0.03  # x and y scales of the measured map agree (Rerun keeps the aspect)
SEEN_TIMEOUT_S = 30.0  # a shot waits this long for the viewer's layout (_walls_all_round)
SEEN_POLL_S = 0.5


_MASKS: dict[tuple[int, tuple[int, int, int]], tuple[np.ndarray, np.ndarray]] = {}


def _mask(img: np.ndarray, rgb: tuple[int, int, int]) -> np.ndarray:
    """The pixels of colour rgb (read only), kept for the image: a shot is compared with
    hundreds of rows, each of which asks for the same masks (the cache holds the image, so
    its id cannot be reused while it is in it)."""
    hit = _MASKS.get((id(img), rgb))
    if hit is not None and hit[0] is img:
        return hit[1]
    diff = np.abs(img.astype(np.int16) - np.array(rgb, np.int16)).max(axis=-1)
    mask = diff <= COLOUR_TOL
    mask.flags.writeable = False
    if len(_MASKS) > 16:
        _MASKS.clear()
    _MASKS[(id(img), rgb)] = (img, mask)
    return mask


def _extent(mask: np.ndarray) -> tuple[float, float, float, float]:
    """(x min, x max, y min, y max) of the pixels set, in pixel centres."""
    ys, xs = np.nonzero(mask)
    assert len(xs) > 0
    return float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max())


def _world(log_path: Path) -> tuple[WorldShapes, list[WorldPoses]]:
    """The run's shapes and every poses message of their layout, as logged."""
    messages = [decode_world(raw) for _tick, raw in read_log(log_path).world]
    shapes = [m for m in messages if isinstance(m, WorldShapes)]
    assert shapes, f"{log_path}: no world shapes logged"
    poses = [m for m in messages if isinstance(m, WorldPoses) and m.layout == shapes[-1].layout]
    assert poses, f"{log_path}: no world poses logged"
    return shapes[-1], poses


def _walls(shapes: WorldShapes, poses: WorldPoses) -> tuple[float, float, float, float]:
    """The inside of the walls in the world (x0, x1, y0, y1): the static segments' centre
    lines, less their half-thickness (the testbed's walls enclose it, all of one thickness)."""
    static = shapes.bodies["role"][shapes.shapes["body"]] == ROLE_STATIC
    verts = world_vertices(shapes, poses)[static][:, :2]
    r = float(shapes.shapes["radius"][static].max())
    return (
        float(verts[..., 0].min()) + r, float(verts[..., 0].max()) - r,
        float(verts[..., 1].min()) + r, float(verts[..., 1].max()) - r,
    )  # fmt: skip


def _inside(mask: np.ndarray) -> tuple[float, float, float, float] | None:
    """The inside of the walls on screen (left, right, top, bottom; pixel edges): along every
    row and column through the middle 80 % of the walls' colour, its innermost pixels on each
    side, and the median over those lines. A body resting on a wall covers the wall's inner
    edge with its outline where it rests (a block on the floor moved the floor's edge 4 px
    when the median was over 41 lines about the middle): over the whole wall it is a minority
    of the lines (the view may also cut the walls' outer edges off). None when a line has
    no wall on one side: the walls are not all on screen (_walls_all_round)."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    cy, cx = (int(ys.min()) + int(ys.max())) // 2, (int(xs.min()) + int(xs.max())) // 2
    hy, hx = (int(ys.max()) - int(ys.min())) * 2 // 5, (int(xs.max()) - int(xs.min())) * 2 // 5
    edges = []
    for lines, centre in (
        (mask[cy - hy : cy + hy + 1], cx),
        (mask[:, cx - hx : cx + hx + 1].T, cy),
    ):
        if not (lines[:, :centre].any(axis=1).all() and lines[:, centre:].any(axis=1).all()):
            return None
        first = [int(np.flatnonzero(line[:centre]).max()) + 1 for line in lines]
        last = [centre + int(np.flatnonzero(line[centre:]).min()) for line in lines]
        edges += [float(np.median(first)), float(np.median(last))]
    return edges[0], edges[1], edges[2], edges[3]


def _walls_all_round(img: np.ndarray) -> bool:
    """The shot shows the scene's walls on all four sides of the middle. A shot taken before
    the viewer applied the run's layout (its blueprint comes over the same connection as the
    data, late on a busy machine) has the scene's view across the whole page, and SCENE's
    crop cuts its right wall off (a clean-clone CI failed so: a row of the middle with no
    wall right of the centre)."""
    return _inside(_mask(img, ROLE_COLORS[ROLE_STATIC])) is not None


def _centre(shapes: WorldShapes, poses: WorldPoses, name: str) -> tuple[float, float, int]:
    names = [bytes(b["name"]).decode() for b in shapes.bodies]
    i = names.index(name)
    return float(poses.poses[i]["x"]), float(poses.poses[i]["y"]), int(shapes.bodies[i]["role"])


def _on_screen(img: np.ndarray) -> dict[str, Any]:
    """What the screenshot shows, measured once for every poses message it is compared
    with: the walls' inside (left, right, top, bottom) and the block's and the shuttle's
    outlines' middles (pixels)."""
    walls = _inside(_mask(img, ROLE_COLORS[ROLE_STATIC]))
    assert walls is not None, "the walls are not on screen all round (see _walls_all_round)"
    drawn: dict[str, Any] = {"walls": walls}
    for name, role in (("block", ROLE_DYNAMIC), ("shuttle", ROLE_KINEMATIC)):
        mx0, mx1, my0, my1 = _extent(_mask(img, ROLE_COLORS[role]))
        drawn[name] = ((mx0 + mx1 + 1) / 2, (my0 + my1 + 1) / 2)  # pixel edges, as the walls'
    return drawn


def _drawn_centres(drawn: dict[str, Any], shapes: WorldShapes, poses: WorldPoses) -> dict[str, Any]:
    """For the block and the shuttle: where the screenshot has its outline's middle
    (_on_screen), and where the sim's pose puts it through the walls' measured map (pixels)."""
    wx0, wx1, wy0, wy1 = _walls(shapes, poses)
    left, right, top, bottom = drawn["walls"]
    sx, sy = (right - left) / (wx1 - wx0), (bottom - top) / (wy1 - wy0)
    assert abs(sx - sy) < SCALE_AGREEMENT * sx, f"scales {sx:.1f} and {sy:.1f} px/m"
    found = {}
    for name, role in (("block", ROLE_DYNAMIC), ("shuttle", ROLE_KINEMATIC)):
        x, y, sent_role = _centre(shapes, poses, name)
        assert sent_role == role
        found[name] = (drawn[name], (left + sx * (x - wx0), bottom - sy * (y - wy0)))  # y up
    return found


def _error_px(found: dict[str, Any]) -> float:
    return max(float(np.hypot(d[0] - e[0], d[1] - e[1])) for d, e in found.values())


def _assert_drawn_as_sent(
    img: np.ndarray, shapes: WorldShapes, all_poses: list[WorldPoses], what: str
) -> None:
    """The block and the shuttle both where one poses message of the sim has them: the viewer
    may show any moment of the run (it lags on a busy machine), so the message is the one
    nearest the drawing, and both bodies must agree with it within PIXEL_TOL."""
    drawn = _on_screen(img)
    errors = [_error_px(_drawn_centres(drawn, shapes, p)) for p in all_poses]
    best = int(np.argmin(errors))
    found = _drawn_centres(drawn, shapes, all_poses[best])
    print(f"{what}: poses message {best} of {len(all_poses)}, {errors[best]:.1f} px: {found}")
    assert errors[best] < PIXEL_TOL, f"{what}: no poses message within {PIXEL_TOL} px: {found}"
    # the check can tell: the shuttle moves 5 cm over its period, far more than PIXEL_TOL
    assert max(errors) > 10 * PIXEL_TOL, f"{what}: every poses message fits: {max(errors)} px"


def _shot(url: str, browser: str, wait: Any, seen: Any = None) -> bytes:
    """A screenshot of the viewer on `url` once it loaded and `wait()` returned; with `seen`
    (a test on the scene's pixels), the first shot that passes it, shot again every
    SEEN_POLL_S for SEEN_TIMEOUT_S, else the last one (its test then fails and says why)."""
    with open_page(url, browser) as page:
        time.sleep(SETTLE_S)
        wait()
        png = page.screenshot()
        end = time.monotonic() + SEEN_TIMEOUT_S
        while seen is not None and not seen(pixels(png)[SCENE]) and time.monotonic() < end:
            time.sleep(SEEN_POLL_S)
            png = page.screenshot()
        return png


@pytest.mark.processes
def test_the_block_and_the_shuttle_are_drawn_where_the_sim_has_them(
    tmp_path: Path,
    procs: list[Proc],  # noqa: F811
) -> None:
    """Live, and replayed from the run's log: the block and the shuttle where one of the
    sim's poses messages has them both."""
    browser = _browser()
    web, grpc = free_ports(2)
    run = Proc(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--duration",
         str(RUN_S), "--log", "run.mcap", "--view", "--view-port", str(web), "--view-grpc-port",
         str(grpc)],
        tmp_path,
    )  # fmt: skip
    procs.append(run)
    url = run.url()
    live_png = _shot(url, browser, lambda: time.sleep(4.0), _walls_all_round)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    (ARTIFACTS / "world-live.png").write_bytes(live_png)
    assert run.stop() == 0, run.lines  # shot: the rest of the run adds nothing
    drawn = [line for line in run.lines if "world frames" in line]
    assert drawn and int(drawn[0].split("live view: ")[1].split()[0]) > 0, drawn
    shapes, all_poses = _world(tmp_path / "run.mcap")
    _assert_drawn_as_sent(pixels(live_png)[SCENE], shapes, all_poses, "live")
    web, grpc = free_ports(2)
    replay = Proc(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.replay", "run.mcap",
         "--view", "--view-port", str(web), "--view-grpc-port", str(grpc), "--view-seconds",
         "120"],
        tmp_path,
    )  # fmt: skip
    procs.append(replay)
    replay_png = _shot(
        replay.url(), browser, lambda: time.sleep(REPLAY_CATCH_UP_S), _walls_all_round
    )
    (ARTIFACTS / "world-replay.png").write_bytes(replay_png)
    assert replay.stop() == 0, replay.lines
    _assert_drawn_as_sent(pixels(replay_png)[SCENE], shapes, all_poses, "replay")


# -- a port scene: the port engine's own state, no sim ----------------------------------

PORT_SCENE = "grasp_vertical"
PORT_RUN_S = 20


def _port_centres(img: np.ndarray, scene: Any, row: np.void) -> dict[str, Any]:
    """The pads' centres against the box's, on screen and as the row's poses put them, in
    px: the scale from the box's drawn height (its outline's outer edges: the box's height
    and the line's; its sides may lie under the pads'), Rerun's fit of the camera being
    unknown, one scale for x and y (Rerun keeps the aspect); y points up in the world."""
    from haptic_local_model.haptic_server.port_view import LINE_M, OBJECT_COLOR, TOOL_COLOR

    order = scene.cosim_order()
    box = scene.body("box")
    bx0, bx1, by0, by1 = _extent(_mask(img, OBJECT_COLOR))
    sx = sy = (by1 - by0 + 1) / (box.size[1] + 2 * LINE_M)
    box_px = ((bx0 + bx1 + 1) / 2, (by0 + by1 + 1) / 2)
    tools = _mask(img, TOOL_COLOR)
    q = row["q"]
    i_box = order.index("box")
    found = {}
    for name, side in (("pad_left", slice(0, int(box_px[0]))),
                       ("pad_right", slice(int(box_px[0]), None))):  # fmt: skip
        half = np.zeros_like(tools)
        half[:, side] = tools[:, side]
        x0, x1, y0, y1 = _extent(half)
        drawn = ((x0 + x1 + 1) / 2 - box_px[0], (y0 + y1 + 1) / 2 - box_px[1])
        i = order.index(name)
        dx, dy = float(q[3 * i] - q[3 * i_box]), float(q[3 * i + 1] - q[3 * i_box + 1])
        found[name] = (drawn, (sx * dx, -sy * dy))
    return found


def _viewed_run(scene_name: str, artifact: str, tmp_path: Path, started: list[Proc]) -> Any:
    """`haptic-run --scene NAME --log run.mcap --view` shot by Chromium 4 s in: (the scene's
    pixels, the log's path, the port scene's config); the shot kept in ARTIFACTS."""
    from haptic_local_model.haptic_server.world_runs import port_scene

    browser = _browser()
    web, grpc = free_ports(2)
    run = Proc(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--scene",
         scene_name, "--duration", str(PORT_RUN_S), "--log", "run.mcap", "--view",
         "--view-port", str(web), "--view-grpc-port", str(grpc)],
        tmp_path,
    )  # fmt: skip
    started.append(run)
    png = _shot(run.url(), browser, lambda: time.sleep(4.0))
    assert run.stop() == 0, run.lines  # shot: the rest of the run adds nothing
    frames = [line for line in run.lines if "live view:" in line and " frames in " in line]
    assert frames and int(frames[0].split("live view: ")[1].split()[0]) > 0, run.lines
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    (ARTIFACTS / artifact).write_bytes(png)
    return pixels(png)[SCENE], tmp_path / "run.mcap", port_scene(scene_name, None, None).config


def _best_row(img: np.ndarray, scene: Any, rows: np.ndarray, centres: Any) -> tuple[float, Any]:
    """The row of the run (one every 0.1 s) the drawing matches best: (its error in px, the
    drawn centres against it)."""
    picks = rows[:: max(1, len(rows) // 200)]
    errors = [_error_px(centres(img, scene, row)) for row in picks]
    best = int(np.argmin(errors))
    return errors[best], centres(img, scene, picks[best])


@pytest.mark.processes
def test_a_port_scenes_box_and_pads_are_drawn_where_the_engine_has_them(
    tmp_path: Path,
    procs: list[Proc],  # noqa: F811
) -> None:
    """`haptic-run --scene grasp_vertical --view`: the box (object colour) and the two pads
    (tool colour) drawn where one row of the run's log has them, relative to each other."""
    from haptic_local_model.haptic_server.world_runs import read_port_log

    img, log, scene = _viewed_run(PORT_SCENE, "port-live.png", tmp_path, procs)
    best, found = _best_row(img, scene, read_port_log(log)[0], _port_centres)
    print(f"port: {best:.1f} px: {found}")
    assert best < PIXEL_TOL, f"no row within {PIXEL_TOL} px: {found}"
    # the check can tell: the pads sit a box's half-width and more from its centre
    gap_px = min(abs(d[0]) for d, _e in found.values())
    assert gap_px > 10 * PIXEL_TOL, f"the pads drawn {gap_px:.0f} px from the box's centre"


# -- a hand scene: two mass-spring hands on a box, no sim ------------------------------

HAND_SCENE = "hand_grasp"


def _hand_centres(img: np.ndarray, scene: Any, row: np.void) -> dict[str, Any]:
    """Each palm's, each device's and each hand's fingers' drawn centre against the box's, on
    screen and as the row puts them (px), the scale from the box's drawn height as in the
    port case; the left hand's left of the box's centre, the right's right of it. The
    fingers by their x only: Rerun's camera fits the outlines and cuts the fingers' capsules
    off at the top and the bottom of the view."""
    from haptic_local_model.haptic_server.port_view import (
        DEVICE_COLOR,
        FINGER_COLOR,
        LINE_M,
        OBJECT_COLOR,
        TOOL_COLOR,
        hand_strips,
    )

    box = scene.box
    bx0, bx1, by0, by1 = _extent(_mask(img, OBJECT_COLOR))
    s = (by1 - by0 + 1) / (box.size[1] + 2 * LINE_M)
    box_px = ((bx0 + bx1 + 1) / 2, (by0 + by1 + 1) / 2)
    bq = row["box_q"]
    found = {}
    for p, side in enumerate((slice(0, int(box_px[0])), slice(int(box_px[0]), None))):
        hand = scene.hand_of(p)
        palm, fingers = hand_strips(hand, row["q"][p])
        finger_x = [x + sign * f.radius for strip, f in zip(fingers, hand.fingers, strict=True)
                    for x, _y in strip for sign in (-1, 1)]  # fmt: skip
        expected = {
            "palm": np.mean(palm[:4], axis=0),
            "device": row["target"][p, :2],
            "fingers": ((min(finger_x) + max(finger_x)) / 2, None),
        }
        for what, colour in (("palm", TOOL_COLOR), ("device", DEVICE_COLOR),
                             ("fingers", FINGER_COLOR)):  # fmt: skip
            mask = _mask(img, colour)
            half = np.zeros_like(mask)
            half[:, side] = mask[:, side]
            x0, x1, y0, y1 = _extent(half)
            ex, ey = expected[what]
            drawn_y = 0.0 if ey is None else (y0 + y1 + 1) / 2 - box_px[1]
            wanted_y = 0.0 if ey is None else -s * (float(ey) - float(bq[1]))
            drawn = ((x0 + x1 + 1) / 2 - box_px[0], drawn_y)
            found[f"{scene.ports[p].name} {what}"] = (drawn, (s * (float(ex) - bq[0]), wanted_y))
    return found


@pytest.mark.processes
def test_a_hand_scenes_box_hands_and_devices_are_drawn_where_the_rows_have_them(
    tmp_path: Path,
    procs: list[Proc],  # noqa: F811
) -> None:
    """`haptic-run --scene hand_grasp --view`: the box (object colour), both hands (palm,
    tool colour; fingers, finger colour) and both devices' tracked palms (device colour)
    drawn where one row of the run's log has them, relative to the box."""
    from haptic_local_model.haptic_server.hand_grasp_ports import HAND_GRASP_KIND
    from haptic_local_model.haptic_server.world_runs import read_port_log

    img, log, scene = _viewed_run(HAND_SCENE, "hand-live.png", tmp_path, procs)
    rows, _meta = read_port_log(log, HAND_GRASP_KIND.topic, HAND_GRASP_KIND.rows)
    best, found = _best_row(img, scene, rows, _hand_centres)
    print(f"hands: {best:.1f} px: {found}")
    assert best < PIXEL_TOL, f"no row within {PIXEL_TOL} px: {found}"
    # the check can tell: the hands and devices sit a box's half-width and more off its centre
    gap_px = min(abs(d[0]) for d, _e in found.values())
    assert gap_px > 10 * PIXEL_TOL, f"drawn {gap_px:.0f} px from the box's centre"


# -- a shared world and its stations: each drawn from its own process's rows --------------

STATIONS_RUN_S = 30  # the stations' run (two views loaded in turn); the world runs past it
STATION_DRAWN_WITHIN_S = 14.0  # after SETTLE_S: shot by then, inside the stations' run


def _wait_event(proc: Proc, event: str, timeout_s: float = 120.0) -> None:
    """Until `proc` printed its JSON `event` line on stdout (stations_cli's `ready`)."""
    end = time.monotonic() + timeout_s
    while not any(f'"event": "{event}"' in line for line in proc.out):
        assert proc.proc.poll() is None, f"exited {proc.proc.returncode}: {proc.lines}"
        assert time.monotonic() < end, f"no {event} in {timeout_s} s: {proc.lines}"
        time.sleep(0.1)


def _frames(proc: Proc) -> int:
    said = [line for line in proc.lines if "live view:" in line and " frames in " in line]
    assert said, proc.lines
    return int(said[0].split("live view: ")[1].split()[0])


@pytest.mark.processes
def test_a_shared_worlds_box_and_pads_are_drawn_from_the_worlds_process(
    tmp_path: Path,
    procs: list[Proc],  # noqa: F811
) -> None:
    """`haptic-world --view` on loopback with both stations (the left one with `--view`
    too): the world's view draws the box and both stations' pads where one row of the
    world's log has them (as the port case); the station's view draws its device and its
    tool, and both views count their frames."""
    from haptic_local_model.benchmarks.stations import loopback_network
    from haptic_local_model.haptic_server.world_runs import port_scene, read_port_log

    browser = _browser()
    cli = [sys.executable, "-m", "haptic_local_model.haptic_server.stations_cli"]
    net = ["--network", loopback_network(tmp_path)]
    router = Proc([*cli, "router", *net], tmp_path)
    procs.append(router)
    _wait_event(router, "ready")
    web, grpc, s_web, s_grpc = free_ports(4)
    world = Proc(
        [*cli, "world", *net, "--duration", str(STATIONS_RUN_S + 6), "--log", "world.mcap",
         "--view", "--view-port", str(web), "--view-grpc-port", str(grpc)],
        tmp_path,
    )  # fmt: skip
    procs.append(world)
    _wait_event(world, "ready")
    stations = [
        Proc(
            [*cli, "station", *net, "--port", port, "--duration", str(STATIONS_RUN_S), *extra],
            tmp_path,
        )
        for port, extra in (
            ("left", ["--view", "--view-port", str(s_web), "--view-grpc-port", str(s_grpc)]),
            ("right", []),
        )
    ]
    procs.extend(stations)
    with open_pages([world.url(), stations[0].url()], browser) as pages:
        time.sleep(SETTLE_S)  # both at once: each view lives as long as its run
        # shot once the station draws its device and the tool the world sends it (a loaded
        # host may take longer to couple it), within its run
        end = time.monotonic() + STATION_DRAWN_WITHIN_S
        while True:
            png, station_png = (page.screenshot() for page in pages)
            if _station_drawn(station_png) or time.monotonic() > end:
                break
            time.sleep(0.5)
    for proc in (*stations, world):  # shot: the rest of the run adds nothing
        assert proc.stop() == 0, proc.lines
    assert _frames(world) > 0 and _frames(stations[0]) > 0
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    (ARTIFACTS / "world-stations-live.png").write_bytes(png)
    (ARTIFACTS / "station-live.png").write_bytes(station_png)
    img = pixels(png)[SCENE]
    rows, _meta = read_port_log(tmp_path / "world.mcap")
    scene = port_scene("grasp_vertical", None, None).config
    picks = rows[:: max(1, len(rows) // 200)]
    errors = [_error_px(_port_centres(img, scene, row)) for row in picks]
    best = int(np.argmin(errors))
    found = _port_centres(img, scene, picks[best])
    print(f"world: row {best} of {len(picks)}, {errors[best]:.1f} px: {found}")
    assert errors[best] < PIXEL_TOL, f"no row within {PIXEL_TOL} px: {found}"
    gap_px = min(abs(d[0]) for d, _e in found.values())
    assert gap_px > 10 * PIXEL_TOL, f"the pads drawn {gap_px:.0f} px from the box's centre"
    station_img = pixels(station_png)[SCENE]
    for name, colour in (("tool", TOOL_COLOR), ("device", DEVICE_COLOR)):
        assert _mask(station_img, colour).sum() > 50, f"the station's {name} is not drawn"


def _station_drawn(png: bytes) -> bool:
    """The station's view shows its device and its tool."""
    img = pixels(png)[SCENE]
    return all(_mask(img, c).sum() > 50 for c in (TOOL_COLOR, DEVICE_COLOR))
