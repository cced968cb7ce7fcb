"""The live view: the visual loop beside the haptic and physics loops, in a browser.

A process of its own (`python -m haptic_local_model.haptic_server.live_view CONFIG.json`)
reads the shared block that the loop and its I/O sidecar fill (`haptic_server.mailbox`): the
newest tick row, the updates the loop has given a verdict on, the events. At VIEW_HZ it
draws them with Rerun (https://rerun.io): the scene's static bodies, the held linkage, the
tool's proxy and the device, the contacts with their normals, the force arrows, and plots of
the forces and the penetration. The Rerun server (its gRPC proxy and its web viewer, both
shipped in the `rerun-sdk` wheel, so the view works offline) is a child of this process,
bound to loopback unless asked otherwise. The loop never waits on any of it: the view only
reads, and it stops drawing (never the run) if it fails.

`haptic-replay LOG --view` draws a log the same way (`view_log`).
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_local_model.haptic_server.foxglove_view import WARNING_EVENTS
from haptic_local_model.haptic_server.logger import BlockChild
from haptic_local_model.haptic_server.mailbox import (
    C_CLOSED,
    C_EVT_HEAD,
    C_TICK_HEAD,
    C_UPD_READ,
    EVENT_SLOTS,
    MAILBOX_SLOTS,
    RING_TICKS,
    SharedBlock,
)
from haptic_local_model.haptic_server.view_address import ViewAddress
from haptic_local_model.haptic_server.view_board import ViewBoard
from haptic_local_model.haptic_server.view_degrade import DegradePolicy, InstallGap
from haptic_local_model.haptic_server.view_world import WorldLayer
from haptic_local_model.shared.config import BodySpec, static_bodies
from haptic_local_model.shared.protocol.layout import MAX_DOF

if TYPE_CHECKING:
    from haptic_local_model.haptic_server.log import LogContents

VIEW_HZ = 60.0  # frames a second (of wall time live, of log time in a replay)
SERVER_MEMORY = "256MiB"  # what the Rerun server keeps for a browser that connects late
START_TIMEOUT_S = 20.0
FORCE_M_PER_N = 0.01  # force arrows: 1 cm per newton (as in the Foxglove channels)
NORMAL_M = 0.02  # contact normals drawn this long

_STATIC = (140, 145, 153)
_DEVICE = (51, 115, 242)
_PROXY = (242, 89, 51)
_LINKAGE = (90, 90, 90)
_CONTACT = (26, 191, 77)


def _rr() -> Any:
    import rerun as rr

    return rr


class RerunServer:
    """`rerun --serve-web`: the gRPC proxy the view logs to and the web viewer that reads it,
    a child process (the SDK's in-process servers listen on every interface)."""

    def __init__(self, address: ViewAddress) -> None:
        for port in (address.grpc_port, address.web_port):
            if _listening(address.host, port):
                raise RuntimeError(
                    f"the live view's port {port} on {address.bind} is in use (--view-port)"
                )
        import rerun_cli

        binary = Path(rerun_cli.__file__).parent / "rerun"
        self._proc = subprocess.Popen(
            [str(binary), "--serve-web", "--bind", address.bind,
             "--port", str(address.grpc_port), "--web-viewer-port", str(address.web_port),
             "--server-memory-limit", SERVER_MEMORY],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        end = time.monotonic() + START_TIMEOUT_S
        while not all(_listening(address.host, p) for p in (address.grpc_port, address.web_port)):
            if self._proc.poll() is not None or time.monotonic() > end:
                self.stop()
                raise RuntimeError(
                    f"the Rerun server did not start on {address.bind} ports "
                    f"{address.grpc_port} and {address.web_port}"
                )
            time.sleep(0.05)

    def cpu_s(self) -> float:
        """The server's CPU time so far (user + system), s."""
        try:
            fields = Path(f"/proc/{self._proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return 0.0
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        if self._proc.poll() is None:
            self._proc.terminate()
        try:
            self._proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(5.0)


def _listening(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex((host, port)) == 0


def blueprint() -> Any:
    """The layout: the scene seen from above on the left; on the right the forces, the
    penetration and the run's events."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            # the view's origin is the root, not `world`: a view does not apply its own
            # origin's transform, which would leave the world's mirror (y up) undone
            rrb.Spatial2DView(origin="/", contents="/world/**", name="scene (y up)"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="plots/force", name="forces (N)"),
                rrb.TimeSeriesView(origin="plots/penetration", name="penetration (mm)"),
                rrb.TextLogView(origin="events", name="events"),
            ),
            column_shares=[2, 1],
        ),
        collapse_panels=True,
    )


def _outline(body: BodySpec) -> tuple[list[tuple[float, float]], float]:
    """A static box or segment as a line strip in the world and its half-width."""
    if body.shape == "box":
        hx, hy = body.size[0] / 2, body.size[1] / 2
        corners = ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy))
        return [body.to_world(px, py) for px, py in corners], 0.001
    return [body.to_world(*body.a), body.to_world(*body.b)], max(body.radius, 0.001)


class SceneView:
    """What is drawn, from tick rows, installed updates and events: one Rerun recording.

    The scene's y axis points up: the world entity is mirrored once (Rerun's 2D views point
    y down, as images do), and every entity under it is in the world's own coordinates.
    """

    def __init__(self, scene_text: str | None, recording: Any) -> None:
        rr = _rr()
        self.rec = recording
        self._log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        force_names = ["device command x", "device command y", "contact on proxy x",
                       "contact on proxy y"]  # fmt: skip
        series = (
            ("penetration", [_PROXY], ["deepest"]),
            ("force", [_DEVICE, (30, 60, 140), _PROXY, (140, 50, 30)], force_names),
        )
        for path, colors, names in series:
            self._log(f"plots/{path}", rr.SeriesLines(colors=colors, names=names), static=True)
        self._static(scene_text)
        self._chain: tuple[np.void, int] | None = None
        self._frame_pos = np.zeros((MAX_DOF, 2))
        self._frame_angle = np.zeros(MAX_DOF)
        self._contacts: list[tuple[float, float, float, float]] | None = None
        self._parser: Any = None
        self.frames = 0
        self.epoch = -1  # of the newest installed update: the sim whose world is drawn
        self.world_layer = WorldLayer(self._log)

    def _log(self, path: str, archetype: Any, static: bool = False) -> None:
        _rr().log(path, archetype, static=static, recording=self.rec)

    def _static(self, scene_text: str | None) -> None:
        rr = _rr()
        bodies = static_bodies(scene_text)
        discs = [body for body in bodies if body.shape == "circle"]
        strips, widths = [], []
        for body in bodies:
            if body.shape != "circle":
                strip, width = _outline(body)
                strips.append(strip)
                widths.append(width)
        centres = [body.position for body in discs]
        radii = [body.radius for body in discs]
        if strips:
            walls = rr.LineStrips2D(strips, radii=widths, colors=[_STATIC])
            self._log("world/static/walls", walls, static=True)
        if centres:
            discs = rr.Points2D(centres, radii=radii, colors=[_STATIC])
            self._log("world/static/discs", discs, static=True)

    def set_time(self, t_s: float) -> None:
        _rr().set_time("time", duration=t_s, recording=self.rec)

    def update(self, raw: bytes, contacts: bool = True) -> None:
        """An installed update: its linkage (joint types, lengths, base) and its contacts
        (unless a degraded view dropped them: `contacts`; they are then cleared once)."""
        rr = _rr()
        if self._parser is None:
            from haptic_local_model.shared.protocol.update import UpdateParser

            self._parser = UpdateParser()
        if self._parser.parse(raw) != 0:
            return
        out = self._parser.out[0]
        dof = int(out["dof"])
        self._chain = (out.copy(), dof)  # the parsed record: its tree and bases
        if not contacts:
            if self._contacts is not None:
                self._log("world/contacts", rr.Clear(recursive=True))
                self._contacts = None
            return
        n = int(out["n_contacts"])
        found = [
            (float(e[0]), float(e[1]), float(k[0]), float(k[1]))
            for e, k in zip(out["c_env"][:n], out["c_normal"][:n], strict=True)
        ]
        if found == self._contacts:
            return
        self._contacts = found
        points = [(x, y) for x, y, _nx, _ny in found]
        normals = [(nx * NORMAL_M, ny * NORMAL_M) for _x, _y, nx, ny in found]
        self._log("world/contacts", rr.Points2D(points, radii=0.003, colors=[_CONTACT]))
        arrows = rr.Arrows2D(origins=points, vectors=normals, colors=[_CONTACT])
        self._log("world/contacts/normals", arrows)

    def frame(self, row: np.void, forces: bool = True) -> None:
        """One frame from a tick row: the device, the proxy, the linkage, the forces (unless
        a degraded view dropped them: `forces`), the penetration."""
        from haptic_local_model.shared.kinematics import link_frames

        rr = _rr()
        self.set_time(float(row["t"]))
        if "update_epoch" in (row.dtype.names or ()):
            self.epoch = int(row["update_epoch"])
        dev, vm = row["device_pose"], row["vm_pose"]
        dev_xy = (float(dev[0]), float(dev[1]))
        vm_xy = (float(vm[0]), float(vm[1]))
        command, contact = row["wrench_command"], row["contact_force_world"]
        cx, cy, fx, fy = float(command[0]), float(command[1]), float(contact[0]), float(contact[1])
        # one call per entity (a call costs ~0.3 ms of Python here): the proxy over the device
        # (where they coincide, both show), the two force arrows from them
        self._log("world/tool", rr.Points2D(
            [dev_xy, vm_xy], radii=[0.006, 0.004], colors=[_DEVICE, _PROXY],
            labels=["device", "proxy"], show_labels=False, draw_order=40,
        ))  # fmt: skip
        k = FORCE_M_PER_N
        if forces:
            self._log("world/forces", rr.Arrows2D(
                origins=[dev_xy, vm_xy], vectors=[(cx * k, cy * k), (fx * k, fy * k)],
                colors=[_DEVICE, _PROXY],
            ))  # fmt: skip
        if self._chain is not None:
            model, dof = self._chain
            if 0 < dof == int(row["dof"]):
                link_frames(model, row["proxy_q"], dof, self._frame_pos, self._frame_angle)
                self._log("world/linkage", rr.LineStrips2D(
                    _link_strips(model, self._frame_pos, self._frame_angle, dof),
                    radii=0.003, colors=[_LINKAGE],
                ))  # fmt: skip
        if forces:
            self._log("plots/force", rr.Scalars([cx, cy, fx, fy]))
        if "penetration" in (row.dtype.names or ()):
            self._log("plots/penetration", rr.Scalars([float(row["penetration"]) * 1e3]))
        self.frames += 1

    def world(self, raw: bytes) -> None:
        """A message of the sim's world (its bodies, or their poses), drawn at the time of the
        newest frame if it is the installed epoch's (view_world.py)."""
        self.world_layer.take(raw, self.epoch)

    def event(self, tick: int, kind: str, detail: str, t_s: float | None = None) -> None:
        rr = _rr()
        if t_s is not None:
            self.set_time(t_s)
        warn = any(w in kind for w in WARNING_EVENTS)
        text = f"tick {tick}: {kind} {detail}".rstrip()
        self._log("events", rr.TextLog(text, level="WARN" if warn else "INFO"))


def _link_strips(
    model: np.void, frame_pos: np.ndarray, frame_angle: np.ndarray, dof: int
) -> list[list[tuple[float, float]]]:
    """Each link of the tool's tree as a line from its joint to its tip."""
    lengths = model["lengths"]
    return [
        [
            (float(frame_pos[i, 0]), float(frame_pos[i, 1])),
            (
                float(frame_pos[i, 0] + lengths[i] * np.cos(frame_angle[i])),
                float(frame_pos[i, 1] + lengths[i] * np.sin(frame_angle[i])),
            ),
        ]
        for i in range(dof)
    ]


def open_recording(address: ViewAddress, app: str) -> Any:
    """A recording stream connected to the Rerun server at `address`, with the layout."""
    rr = _rr()
    rec = rr.RecordingStream(app, make_default=False, make_thread_default=False)
    rec.connect_grpc(address.grpc_url, default_blueprint=blueprint())
    return rec


# -- live: a process beside the loop ------------------------------------------------------


class ViewProcess(BlockChild):
    """Starts the view (`python -m haptic_local_model.haptic_server.live_view`) on the loop's
    shared block. It does not wait for it: the view says where it is on stderr once it serves."""

    def __init__(self, shm_name: str, config: dict[str, Any]) -> None:
        super().__init__("haptic_local_model.haptic_server.live_view", shm_name, config)


def main(argv: list[str] | None = None) -> int:
    """`python -m haptic_local_model.haptic_server.live_view CONFIG.json` (ViewProcess)."""
    return view_main(argv, _live)


def view_main(argv: list[str] | None, live: Callable[[dict[str, Any]], None]) -> int:
    """A view process's entry (this one's, port_view's): its CONFIG.json read, SIGINT left
    to the run, `live(config)` run; an error is said and ends the view, never the run."""
    args = sys.argv[1:] if argv is None else argv
    config = json.loads(Path(args[0]).read_text())
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run decides when the view ends
    try:
        live(config)
    except Exception as exc:  # the view never stops the run: say why, and go
        print(f"live view stopped: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    return 0


def enter_view_process(config: dict[str, Any]) -> threading.Event:
    """A view process off the loop's way: niced below the sim and the sidecar, off the
    loop's CPU; the event is set on SIGTERM (the run ending it)."""
    from haptic_local_model.shared.timing import avoid_cpu

    terminated = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: terminated.set())
    with contextlib.suppress(OSError):
        os.nice(10)
    avoid_cpu(config.get("loop_cpu"))
    return terminated


def _live(config: dict[str, Any]) -> None:
    terminated = enter_view_process(config)
    address = ViewAddress(config["bind"], int(config["web_port"]), int(config["grpc_port"]))
    block = SharedBlock.attach(config["shm_name"])
    shm = block.shm
    server = RerunServer(address)
    try:
        rec = open_recording(address, "haptic-run")
        view = SceneView(config.get("scene_text"), rec)
        cpu0, server_cpu0, wall0 = time.process_time(), server.cpu_s(), time.monotonic()
        print(f"live view: {address.url}", file=sys.stderr, flush=True)
        board = ViewBoard.attach(config["view_board"]) if config.get("view_board") else None
        feed = BlockFeed(block, view, board, float(config.get("watchdog_ms", 100.0)))
        parent = int(config["parent_pid"])
        next_frame = time.monotonic()
        while block.ctl[C_CLOSED] == 0 and os.getppid() == parent and not terminated.is_set():
            feed.poll()
            period = 1.0 / min(VIEW_HZ, feed.policy.level.frame_hz)
            next_frame += period
            time.sleep(max(0.0, next_frame - time.monotonic()))
            next_frame = max(next_frame, time.monotonic() - period)
        feed.poll()
        rec.flush(timeout_sec=5.0)
        rec.disconnect()  # before its server goes
        cpu_s, server_cpu_s = time.process_time() - cpu0, server.cpu_s() - server_cpu0
        frames = max(view.frames, 1)
        if board is not None:
            board.close()
        print(
            f"live view: {view.world_layer.drawn} world frames; refused {view.world_layer.refused}",
            file=sys.stderr, flush=True,
        )  # fmt: skip
        print(
            f"live view: {len(feed.changes)} level changes, ended at "
            f"'{feed.policy.level.name}'", file=sys.stderr, flush=True,
        )  # fmt: skip
        print(
            f"live view: {view.frames} frames in {time.monotonic() - wall0:.1f} s; CPU per "
            f"frame {1e3 * cpu_s / frames:.2f} ms here, {1e3 * server_cpu_s / frames:.2f} ms "
            "in the Rerun server",
            file=sys.stderr, flush=True,
        )  # fmt: skip
    finally:
        server.stop()
        block.release()
        shm.close()


class BlockFeed:
    """The shared block's newest tick row, the loop's new verdicts and its new events, read
    without taking anything from the log writer or the sidecar."""

    def __init__(
        self, block: SharedBlock, view: SceneView, board: ViewBoard | None, watchdog_ms: float
    ) -> None:
        from haptic_local_model.haptic_server.model import TICK_DTYPE

        self.block, self.view = block, view
        self.row = np.zeros(1, TICK_DTYPE)
        self.last_tick_head = 0
        self.upd_seen = 0
        self.evt_seen = 0
        self.board = board
        self.world_seen = 0
        self.policy = DegradePolicy(watchdog_ms)
        self.gap = InstallGap()
        self.changes: list[str] = []  # the level changes said

    def poll(self) -> None:
        b, ctl, view = self.block, self.block.ctl, self.view
        read = int(ctl[C_UPD_READ])
        for i in range(max(self.upd_seen, read - MAILBOX_SLOTS + 1), read):
            slot = i % MAILBOX_SLOTS
            n = int(b.update_len[slot])
            if int(b.update_verdict[slot]) != 0 or n <= 0:
                continue
            raw = b.updates[slot, :n].tobytes()
            if int(ctl[C_UPD_READ]) - i < MAILBOX_SLOTS:  # not reused while copied
                view.update(raw, contacts=self.policy.level.forces)
        self.upd_seen = read
        evt_head = int(ctl[C_EVT_HEAD])
        for i in range(max(self.evt_seen, evt_head - EVENT_SLOTS + 1), evt_head):
            view.event(*b.event_at(i))
        self.evt_seen = evt_head
        head = int(ctl[C_TICK_HEAD])
        level = self.policy.level
        if head > self.last_tick_head:
            self.row[0] = b.ticks[(head - 1) % RING_TICKS]
            if int(ctl[C_TICK_HEAD]) - (head - 1) < RING_TICKS:  # not overwritten meanwhile
                view.frame(self.row[0], forces=level.forces)
                self._judge(self.row[0])
            self.last_tick_head = head
        if self.board is not None:  # the sim's world, at the newest frame's time
            messages, self.world_seen = self.board.read_since(self.world_seen)
            if level.world_hz > 0:  # read all the same: a restored view starts at the newest
                view.world_layer.min_period_s = 1.0 / level.world_hz
                for _tick, raw in messages:
                    view.world(raw)

    def _judge(self, row: np.void) -> None:
        """The install gap into the degrade policy; a change of level said in the events
        panel and on stderr."""
        t = float(row["t"])
        said = self.policy.observe(t, self.gap.gap_s(t, int(row["update_seq"])))
        if said is not None:
            kind = "view_degraded" if "degraded" in said else "view_restored"
            self.view.event(int(row["tick"]), kind, said)
            self.changes.append(said)
            print(f"live view: {said}", file=sys.stderr, flush=True)


# -- replay: a log drawn the same way -----------------------------------------------------


class EmptyLogError(ValueError):
    """A log without tick rows."""


def log_frames(
    log: LogContents,
) -> Iterator[tuple[np.void, list[bytes], list[tuple[int, str, str, float]], list[bytes]]]:
    """A log as the view draws it: a tick row every 1 / VIEW_HZ of log time, with the
    installed updates (bytes), the events (tick, kind, detail, time) and the sim's world
    messages since the frame before."""
    updates = sorted(
        ((int(u["tick"]), base64.b64decode(str(u["raw_b64"]))) for u in log.updates
         if u.get("installed")),
        key=lambda u: u[0],
    )  # fmt: skip
    events = sorted(log.events, key=lambda e: int(e["tick"]))
    world = sorted(log.world, key=lambda w: w[0])
    u = e = w = 0
    next_t = -1.0
    new_updates: list[bytes] = []
    new_events: list[tuple[int, str, str, float]] = []
    new_world: list[bytes] = []
    for row in log.ticks:
        tick, t = int(row["tick"]), float(row["t"])
        while w < len(world) and world[w][0] <= tick:
            new_world.append(world[w][1])
            w += 1
        while u < len(updates) and updates[u][0] <= tick:
            new_updates.append(updates[u][1])
            u += 1
        while e < len(events) and int(events[e]["tick"]) <= tick:
            ev = events[e]
            new_events.append((int(ev["tick"]), str(ev["kind"]), str(ev.get("detail", "")), t))
            e += 1
        if t >= next_t:
            yield row, new_updates, new_events, new_world
            new_updates, new_events, new_world = [], [], []
            next_t = t + 1.0 / VIEW_HZ


def view_log(path: Path, address: ViewAddress, stop: threading.Event, speed: float = 0.0) -> int:
    """Draw a log: every update, every event and the ticks at VIEW_HZ of log time, as fast
    as they go (speed 0) or at `speed` x log time from the first installed update (what
    comes before it, at once). Returns the frames drawn. The server
    keeps serving until `stop` is set."""
    from haptic_local_model.haptic_server.log import read_log

    log = read_log(path)
    if len(log.ticks) == 0:
        raise EmptyLogError(f"{path}: no tick rows to draw (not a haptic log, or an empty one)")
    server = RerunServer(address)
    try:
        rec = open_recording(address, "haptic-replay")
        view = SceneView(log.metadata.get("configs", {}).get("scene"), rec)
        print(f"live view: {address.url}", file=sys.stderr, flush=True)
        # paced from the first installed update: the seconds before the sim's first one
        # (its start, its kernels loading) have no model to draw, and are drawn at once
        wall0, t0 = time.monotonic(), None
        for row, updates, events, world in log_frames(log):
            for raw in updates:
                view.update(raw)
            for event in events:
                view.event(*event)
            view.frame(row)
            for raw in world:  # at this frame's time, as live
                view.world(raw)
            if t0 is None and updates:
                wall0, t0 = time.monotonic(), float(row["t"])
                print(f"live view: the log's first {t0:.2f} s, before the sim's first update, "
                      f"drawn at once", file=sys.stderr, flush=True)  # fmt: skip
            if speed > 0 and t0 is not None:
                time.sleep(max(0.0, wall0 + (float(row["t"]) - t0) / speed - time.monotonic()))
            if stop.is_set():
                break
        layer = view.world_layer
        print(f"live view: {layer.drawn} world frames; refused {layer.refused}", file=sys.stderr,
              flush=True)  # fmt: skip
        rec.flush(timeout_sec=5.0)
        rec.disconnect()  # before its server goes
        stop.wait()
        return view.frames
    finally:
        server.stop()


if __name__ == "__main__":
    sys.exit(main())
