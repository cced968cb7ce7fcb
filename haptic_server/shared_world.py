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
- HELD: its station is silent (none yet, or none for `world_watchdog_ms`), or the world
  itself was (a tick more than the watchdog after the last: a stopped or starved process;
  its stations went safe meanwhile, and what it takes as it resumes was sent before). Its
  tool stays
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

The tick is compiled (haptic_server/stages/world_ports.py, and each engine's step): the
world's Python is its Zenoh calls, one compiled call a DeviceState received and one a tick.

Every tick's row (the engine's: PORT_ROW_DTYPE, or HAND_GRASP_ROW_DTYPE; the devices as
fed) stays in memory; `--log` writes them as a port world's log (haptic_server/world_runs.py), which
`haptic-replay` re-runs bit for bit.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import world_limits, world_map_of
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.log import rows_in_order
from haptic_local_model.haptic_server.port_scene import port_gains
from haptic_local_model.haptic_server.sim_link import SimLink
from haptic_local_model.haptic_server.stages.port_io import push_stretch
from haptic_local_model.haptic_server.stages.world_ports import (
    EVENT_DTYPE,
    MAX_EVENTS,
    STATE_NAMES,
    port_links,
    take_device,
    world_clock,
)
from haptic_local_model.haptic_server.world_engines import CosimWorld, world_engine
from haptic_local_model.shared.config import load_user
from haptic_local_model.shared.memory import FloodTrim
from haptic_local_model.shared.net.stations import (
    StateRoute,
    StationNetworkConfig,
    open_client,
    port_keys,
)
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig
from haptic_local_model.shared.protocol.station import (
    STALE,
    DeviceState,
    Vec3,
    encode_device,
    tool_record,
    vec3,
)
from haptic_local_model.shared.protocol.station_codec import reason_counts
from haptic_local_model.shared.timing import Pacer, SampleWindow, enter_loop

DEVICE_RING = 64
SPIN_NS = 100_000


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
            maps.append(world_map_of(dev).record[0])
            self.limits.append(vec3(world_limits(dev)))
        users = [load_user(port.user) for port in scene.ports]
        self.engine = world_engine(scene, self.limits, users)
        self.order = self.engine.names
        n = len(scene.ports)
        self.ports = port_links(n)  # PORT_LINK_DTYPE: each port's state, its last DeviceState
        self.clock = world_clock(n, self.engine.dt, network.world_watchdog_ms, network.safe_ramp_ms)
        self.clock[0]["object"] = self.engine.object_dof
        # a port scene's ports' passivity controllers (the hands' engine has none)
        tdpa = network.passivity == "tdpa" and isinstance(scene, PortSceneConfig)
        self.clock[0]["passivity"] = int(tdpa)
        self.events = np.zeros(MAX_EVENTS, EVENT_DTYPE)
        self.events.view(np.uint8)[:] = 0  # touched now (as the rows), not page by page in the loop
        self.epoch = time.time_ns()
        tools = []
        for p, user in enumerate(users):
            # the anchor squeezes as the scene's user pushes: the object is held at the start
            k, b = (np.array(v, np.float64) for v in port_gains(scene, p))
            stretch = push_stretch(user.wrench, maps[p], k)
            self.ports[p]["anchor"] = self.engine.tool(p)[0] + stretch
            rec = tool_record(p, self.epoch)
            rec["stiffness"] = k
            rec["damping"] = b
            tools.append(rec)
        self.tools = np.concatenate(tools)  # each port's ToolState, filled in place each tick
        self._tool_bytes = self.tools.view(np.uint8).reshape(n, -1)
        self.rows = np.zeros(max_rows, self.engine.rows_dtype)
        self.rows.view(np.uint8)[:] = 0  # every page touched now, not in the loop
        self.n_rows = 0
        self.start_q = self.engine.poses()
        self.work_us = SampleWindow(100_000)
        # with a sim: the ticks that took a SimBodies or published a WorldBodies, apart
        self.work_sim_us = SampleWindow(100_000)
        self.work_rest_us = SampleWindow(100_000)
        self.pacer = Pacer(round(self.engine.dt * 1e9), SPIN_NS, None)
        self._stop = False
        self.routes: list[StateRoute] = []  # each port's link routes, while it runs
        # the sim that mirrors the world: a port scene with sim bodies (a mirror refuses a
        # scene without), when the network has one
        self.sim: SimLink | None = None
        if isinstance(scene, PortSceneConfig) and scene.sim_bodies and network.sim.connect:
            assert isinstance(self.engine, CosimWorld)
            e = self.engine
            self.sim = SimLink(scene, network, e.model, e.data, self.epoch)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def receive(self, p: int, sub: Any, now_ns: int) -> None:
        """Every DeviceState waiting on port p's key, oldest first: each taken or refused and
        counted (world_ports.take_device)."""
        self.clock[0]["now_ns"] = now_ns
        while (sample := sub.try_recv()) is not None:
            take_device(self.ports, self.clock, p, sample.payload.to_bytes())

    def step(self, now_ns: int, t: float, seq: int) -> None:
        """One tick at `now_ns` (the loop's clock): every port's state and device, the
        engine's tick, every port's ToolState (in `tools`, seq `seq`) and the tick's row."""
        c = self.clock[0]
        c["now_ns"], c["wall_ns"], c["t"], c["seq"] = now_ns, time.time_ns(), t, seq
        c["k"] = self.n_rows % len(self.rows)
        self.engine.step(self.ports, self.clock, self.events, self.tools, self.rows)
        self.n_rows += 1

    def state(self, p: int) -> str:
        """Port p's state: held, indexing or coupled."""
        return STATE_NAMES[int(self.ports[p]["state"])]

    def reasons(self, p: int) -> dict[str, int]:
        """Port p's refused DeviceStates, by reason (those that happened)."""
        return reason_counts(self.ports[p]["reasons"])

    def run(self, duration_s: float | None, ready: Any = None) -> dict[str, Any]:
        session = open_client(self.network.world)
        routes = [
            StateRoute(session, port_keys(self.network.namespace, port.name), DEVICE_RING,
                       self.network.state_reliability)
            for port in self.scene.ports
        ]  # fmt: skip
        self.routes = routes
        if self.sim is not None:
            self.sim.open(session)
        pacer = Pacer(round(self.engine.dt * 1e9), SPIN_NS, duration_s)
        self.pacer = pacer
        enter_loop(self.warm, ready)
        dt, t = self.engine.dt, 0.0

        trim = FloodTrim()  # a flood's memory back to the system after it
        taken = [partial(self._taken, p) for p in range(len(routes))]  # for routes[p].check

        def tick(now: int, seq: int) -> None:
            nonlocal t
            for p in range(len(routes)):
                self.receive(p, routes[p].sub, now)
            sim_tick = self.sim is not None and self.sim.take(now)
            self.step(now, t, seq)
            t += dt
            for p in range(len(routes)):
                routes[p].pub.put(self._tool_bytes[p].tobytes())
            if self.sim is not None:
                sim_tick = self.sim.publish(seq) or sim_tick
            work = (time.perf_counter_ns() - now) / 1e3
            self.work_us.add(work)
            trim.after(now / 1e9, self._messages_received)
            for p in range(len(routes)):
                routes[p].check(now, taken[p])
            if self.sim is not None:
                (self.work_sim_us if sim_tick else self.work_rest_us).add(work)

        with session:  # closed however the loop ends
            pacer.run(tick, lambda: self._stop)
        return self.summary()

    def _taken(self, p: int) -> int:
        """Port p's DeviceStates taken or refused so far."""
        return int(self.ports[p]["received"] + self.ports[p]["rejected"])

    def _messages_received(self) -> int:
        """DeviceStates taken or refused, every port's."""
        return int(self.ports["received"].sum() + self.ports["rejected"].sum())

    def warm(self) -> None:
        """The tick's kernels compiled (or loaded from numba's cache) before the loop."""
        self.engine.warm()
        ports, clock = port_links(1), world_clock(1, 1e-3, 1.0, 1.0)
        take_device(ports, clock, 0, encode_device(DeviceState(0, 1, 1, 0, (0, 0, 0), (0, 0, 0))))

    def logged_rows(self) -> np.ndarray:
        return rows_in_order(self.rows, self.n_rows)

    def event_list(self) -> list[dict[str, Any]]:
        """The ports' state changes, in order: t, port, from, to."""
        names = [p.name for p in self.scene.ports]
        return [
            {"t": round(float(e["t"]), 6), "port": names[int(e["port"])],
             "from": STATE_NAMES[int(e["frm"])], "to": STATE_NAMES[int(e["to"])]}
            for e in self.events[: int(self.clock[0]["n_events"])]
        ]  # fmt: skip

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "ticks": self.n_rows,
            **self.pacer.figures(),
            "work_us": self.work_us.percentiles(50, 99, 99.9),
            "events": self.event_list(),
            "events_dropped": int(self.clock[0]["events_dropped"]),
            "stalls": int(self.clock[0]["stalls"]),  # ticks the world came late to, all held
            "epoch": self.epoch,
            "ports": {},
        }
        for p, port in enumerate(self.scene.ports):
            ps = self.ports[p]
            out["ports"][port.name] = {
                "state": self.state(p), "received": int(ps["received"]),
                "rejected": int(ps["rejected"]), "stale": int(ps["reasons"][STALE]),
                "rejected_by_reason": self.reasons(p),
                "routes_redeclared": dict(self.routes[p].redeclared) if self.routes else {},
            }  # fmt: skip
        end = self.engine.poses()
        for i, name in enumerate(self.order):  # over the whole run (not only the rows kept)
            out.setdefault("bodies", {})[name] = {
                "start": self.start_q[i].tolist(),
                "end": end[i].tolist(),
                "lowest_y": float(self.engine.lowest[i]),
            }  # fmt: skip
        out["steps_held"] = self.engine.steps_held()
        out["range_returns"] = self.engine.range_returns()
        if self.sim is not None:
            out["sim"] = self.sim.summary()
            # the world's work on the ticks that took or sent the sim's bodies, and the rest
            out["sim"]["work_us_sim_ticks"] = self.work_sim_us.percentiles(50, 99, 99.9)
            out["sim"]["work_us_other_ticks"] = self.work_rest_us.percentiles(50, 99, 99.9)
        return out
