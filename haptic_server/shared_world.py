"""The shared world of a port scene, served to haptic stations over a Zenoh router
(docs/stations.md): the co-simulated object and every port's tool (or two mass-spring hands
and the box they hold), at the haptic rate.

Each tick (wall-clock paced): take each port's newest DeviceState (a malformed one is
refused and counted), decide each port's state, feed the world's engine
(haptic_server/world_engines.py: the co-simulation, or the hands) each port's device, run
it, publish each port's ToolState. With a sim in the network (`sim-server --mirror`), a port
scene's world also takes the sim's bodies before the tick and publishes its co-simulated
bodies to the sim's mirror (haptic_server/sim_link.py).

A hand's port (`hand_grasp`) takes its station's glove angles as it takes its device's
pose: blended in from the fingers' angles over the coupling's ramp, held where they were
when the port leaves COUPLED; until a station sends its glove, the hand's fingers follow
the scene user's script.

A port is, in turn:
- HELD: its station is silent (none yet, or none for `world_watchdog_ms`). Its tool stays
  coupled to an anchor where its device was last, at rest: the tool keeps squeezing as it
  did, so the other ports keep the object. ToolStates say HELD, and the station ramps to
  its safe state.
- INDEXING: its station is back (or new) and says SAFE (it is not rendering the world's
  coupling). Every tick the world re-indexes it (offset = anchor - device), so the device,
  wherever its user left it, maps onto the anchor: the tool in the station's frame is then
  where the device is plus the coupling's stretch at the anchor, and the station ramps in
  the force it left with. Its tool stays on the anchor. A HELD port goes on only through
  INDEXING: a station that comes back still rendering (its SAFE never reached the world) is
  held until it says SAFE, so it is never re-indexed under its own force.
- COUPLED: the station renders the coupling (not SAFE). The offset is fixed; the fed pose
  blends from the anchor to the device over `safe_ramp_ms` (as the station's own ramp), and
  the anchor follows the fed pose. A device's pose is carried on by its twist for at most
  EXTRAPOLATE_S; when the port leaves COUPLED its anchor is where the device was last seen.
Messages: within a station's epoch each must be newer than the last; another epoch is taken
only once the present one is silent (a restarted station, not two on one port).
Offsets are added per axis (x, y and the angle): a rejoining device's turn about its own
origin is not composed with the anchor's (documented limit).

Every tick's row (the engine's: PORT_ROW_DTYPE, or HAND_GRASP_ROW_DTYPE; the devices as
fed) stays in memory; `--log` writes them as a `haptic-ports` log, which `haptic-ports
--replay` re-runs bit for bit.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.device_models.world_map import DeviceWorldMap
from haptic_local_model.haptic_server.sim_link import SimLink
from haptic_local_model.haptic_server.stages.port_io import push_stretch
from haptic_local_model.haptic_server.station import rows_in_order
from haptic_local_model.haptic_server.world_engines import (
    CosimWorld,
    port_gains,
    world_engine,
)
from haptic_local_model.shared.config import load_user
from haptic_local_model.shared.net.stations import (
    StationNetworkConfig,
    open_client,
    port_keys,
)
from haptic_local_model.shared.net.transport import newest_payload
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig
from haptic_local_model.shared.protocol.station import (
    HELD,
    DeviceState,
    Vec3,
    decode_device,
    order_refusal,
    tool_record,
    vec3,
)
from haptic_local_model.shared.protocol.update import MessageError
from haptic_local_model.shared.timing import Pacer, SampleWindow, enter_loop

DEVICE_RING = 64
SPIN_NS = 100_000
EXTRAPOLATE_S = 0.005  # as the station's (haptic_server/station.py)
MAX_EVENTS = 10_000  # port state changes kept for the summary and the log
HELD_STATE, INDEXING, COUPLED = "held", "indexing", "coupled"
ZERO3 = np.zeros(3)


@dataclass
class PortState:
    """What the world knows of one port's station."""

    state: str = HELD_STATE
    anchor: np.ndarray = field(default_factory=lambda: np.zeros(3))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    start: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the anchor at coupling
    blend: float = 0.0
    glove_start: np.ndarray | None = None  # a hand's glove when its port coupled
    last: DeviceState | None = None
    rx_ns: int = 0
    received: int = 0
    rejected: int = 0
    stale: int = 0  # older than the newest (another station's epoch, out of order)
    reasons: dict[str, int] = field(default_factory=dict)


class SharedWorld:
    """The world's records and ports, ready to run (module docstring)."""

    def __init__(
        self,
        scene: PortSceneConfig | HandSceneConfig,
        network: StationNetworkConfig,
        max_rows: int,
    ) -> None:
        self.scene, self.network = scene, network
        self.limits: list[Vec3] = []
        maps = []  # each scene device's map onto the world
        for port in scene.ports:  # the scene's devices' limits, in the world frame
            dev = load_simulated_device(port.device)
            wm = getattr(dev, "world_map", None) or DeviceWorldMap.identity()
            scale = wm.record[0]["scale"] * wm.record[0]["force_scale"]
            maps.append(wm.record[0])
            self.limits.append(vec3(np.array(dev.limits().max_wrench) / scale))
        users = [load_user(port.user) for port in scene.ports]
        self.engine = world_engine(scene, self.limits, users)
        self.order = self.engine.names
        self.ports = [PortState() for _ in scene.ports]
        self.epoch = time.time_ns()
        self._tool_records = []
        for p, user in enumerate(users):
            # the anchor squeezes as the scene's user pushes: the object is held at the start
            k, b = (np.array(v, np.float64) for v in port_gains(scene, p))
            stretch = push_stretch(user.wrench, maps[p], k)
            self.ports[p].anchor = self.engine.tool(p)[0] + stretch
            rec = tool_record(p, self.epoch)
            rec["stiffness"] = k
            rec["damping"] = b
            self._tool_records.append(rec)
        self.rows = np.zeros(max_rows, self.engine.rows_dtype)
        self.rows.view(np.uint8)[:] = 0  # every page touched now, not in the loop
        self.n_rows = 0
        self.start_q = self.engine.poses()
        self.events: list[dict[str, Any]] = []
        self.events_dropped = 0
        self.work_us = SampleWindow(100_000)
        self.pacer = Pacer(round(self.engine.dt * 1e9), SPIN_NS, None)
        self._stop = False
        # the sim that mirrors the world: a port scene with sim bodies (a mirror refuses a
        # scene without), when the network has one
        self.sim: SimLink | None = None
        if isinstance(scene, PortSceneConfig) and scene.sim_bodies and network.sim.connect:
            assert isinstance(self.engine, CosimWorld)
            e = self.engine
            self.sim = SimLink(scene, network, e.model, e.data, self.epoch)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def _refuse(self, ps: PortState, reason: str) -> None:
        ps.rejected += 1
        ps.reasons[reason] = ps.reasons.get(reason, 0) + 1

    def _take(self, p: int, sub: Any, now_ns: int) -> None:
        """Port p's newest valid DeviceState. Within the station's epoch a message must be
        newer than the last taken; another epoch (a restarted station, or a second one on
        the port) is taken only once the present one has been silent for the watchdog."""
        ps = self.ports[p]
        for raw in newest_payload(sub):
            try:
                m = decode_device(raw, p)
            except MessageError as exc:
                self._refuse(ps, exc.reason)
                continue
            why = order_refusal(ps.last, m.epoch, m.seq, self._silent(ps, now_ns))
            if why is not None:
                self._refuse(ps, why)
                continue
            ps.last, ps.rx_ns = m, now_ns
            ps.received += 1

    def _silent(self, ps: PortState, now_ns: int) -> bool:
        return ps.last is None or (now_ns - ps.rx_ns) / 1e6 > self.network.world_watchdog_ms

    def _live(self, ps: PortState, m: DeviceState, age_s: float) -> np.ndarray:
        """The station's device in the world: re-indexed, carried on by its twist for at
        most EXTRAPOLATE_S (an old reading is not carried on into a guess)."""
        return np.array(m.pose) + ps.offset + np.array(m.twist) * min(age_s, EXTRAPOLATE_S)

    def _port(self, p: int, now_ns: int, t: float) -> None:
        """Port p's state this tick and the device pose and twist it feeds (module docstring)."""
        ps = self.ports[p]
        m = ps.last
        if self._silent(ps, now_ns) or m is None or m.cut:
            new = HELD_STATE
        elif m.safe:
            new = INDEXING
        else:  # rendering: coupled, unless it comes from HELD (it must go safe first)
            new = HELD_STATE if ps.state == HELD_STATE else COUPLED
        if new != ps.state:
            if ps.state == COUPLED and m is not None:  # held where it was last seen
                ps.anchor = ps.start + ps.blend * (self._live(ps, m, 0.0) - ps.start)
            if len(self.events) < MAX_EVENTS:
                self.events.append({"t": round(t, 6), "port": self.scene.ports[p].name,
                                    "from": ps.state, "to": new})  # fmt: skip
            else:
                self.events_dropped += 1
            if new == COUPLED:
                ps.start = ps.anchor.copy()
                ps.blend = 0.0
                ps.glove_start = self.engine.glove(p)
            elif ps.state == COUPLED and m is not None and m.has_glove:
                held = self.engine.glove(p)  # a hand's fingers held where its station left them
                if held is not None:
                    self.engine.feed_glove(p, held, np.zeros_like(held))
            ps.state = new
        if new == COUPLED and m is not None:
            live = self._live(ps, m, (now_ns - ps.rx_ns) / 1e9)
            ps.blend = min(1.0, ps.blend + self.engine.dt / (self.network.safe_ramp_ms / 1e3))
            ps.anchor = ps.start + ps.blend * (live - ps.start)
            self.engine.feed(p, ps.anchor, ps.blend * np.array(m.twist))
            if m.has_glove and ps.glove_start is not None:
                # the station's glove, blended in from the fingers' as they were (as the pose)
                g0 = ps.glove_start
                n = len(g0)
                self.engine.feed_glove(
                    p, g0 + ps.blend * (np.array(m.glove[:n]) - g0),
                    ps.blend * np.array(m.glove_rate[:n]),
                )  # fmt: skip
            return
        if new == INDEXING and m is not None:
            ps.offset = ps.anchor - np.array(m.pose)
        self.engine.feed(p, ps.anchor, ZERO3)

    def _publish(self, p: int, pub: Any, seq: int) -> None:
        """Port p's ToolState: its record filled in place (shared/protocol/station.py)."""
        ps = self.ports[p]
        pose, twist = self.engine.tool(p)
        r = self._tool_records[p][0]
        r["seq"] = seq
        r["publish_time_ns"] = time.time_ns()
        r["pose"] = pose - ps.offset
        r["pose"][2] = math.atan2(math.sin(r["pose"][2]), math.cos(r["pose"][2]))
        r["twist"] = twist
        r["object_pose"] = self.engine.object_pose()
        r["flags"] = HELD if ps.state == HELD_STATE else 0
        pub.put(self._tool_records[p].tobytes())

    def run(self, duration_s: float | None, ready: Any = None) -> dict[str, Any]:
        session = open_client(self.network.world)
        subs, pubs = [], []
        for port in self.scene.ports:
            device_key, tool_key = port_keys(self.network.namespace, port.name)
            subs.append(
                session.declare_subscriber(device_key, zenoh.handlers.RingChannel(DEVICE_RING))
            )
            pubs.append(session.declare_publisher(
                tool_key, congestion_control=zenoh.CongestionControl.DROP, express=True
            ))  # fmt: skip
        if self.sim is not None:
            self.sim.open(session)
        pacer = Pacer(round(self.engine.dt * 1e9), SPIN_NS, duration_s)
        self.pacer = pacer
        enter_loop(self.warm, ready)
        pacer.start()
        seq = 0
        t = 0.0
        try:
            while not self._stop:
                now = pacer.wait()
                for p in range(len(self.ports)):
                    self._take(p, subs[p], now)
                    self._port(p, now, t)
                if self.sim is not None:
                    self.sim.take(now)
                self.engine.tick(t)
                for p in range(len(self.ports)):
                    self._publish(p, pubs[p], seq)
                if self.sim is not None:
                    self.sim.publish(seq)
                self.engine.row(self.rows, self.n_rows % len(self.rows), t)
                self.n_rows += 1
                self.work_us.add((time.perf_counter_ns() - now) / 1e3)
                seq += 1
                t += self.engine.dt
                if not pacer.next():
                    break
        finally:
            session.close()
        return self.summary()

    def warm(self) -> None:
        self.engine.warm()

    def logged_rows(self) -> np.ndarray:
        return rows_in_order(self.rows, self.n_rows)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "ticks": self.n_rows,
            **self.pacer.figures(),
            "work_us": self.work_us.percentiles(50, 99, 99.9),
            "events": self.events,
            "events_dropped": self.events_dropped,
            "epoch": self.epoch,
            "ports": {},
        }
        for p, port in enumerate(self.scene.ports):
            ps = self.ports[p]
            out["ports"][port.name] = {
                "state": ps.state, "received": ps.received, "rejected": ps.rejected,
                "stale": ps.stale, "rejected_by_reason": dict(ps.reasons),
            }  # fmt: skip
        end = self.engine.poses()
        for i, name in enumerate(self.order):  # over the whole run (not only the rows kept)
            out.setdefault("bodies", {})[name] = {
                "start": self.start_q[i].tolist(),
                "end": end[i].tolist(),
                "lowest_y": float(self.engine.lowest[i]),
            }  # fmt: skip
        out["steps_held"] = self.engine.steps_held()
        if self.sim is not None:
            out["sim"] = self.sim.summary()
        return out
