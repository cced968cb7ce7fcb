"""A haptic station: one port's device and user, coupled to its tool in a shared world that
`haptic-world` co-simulates, over a Zenoh router (docs/stations.md).

Each tick (wall-clock paced at the scene's haptic rate): take the newest ToolState (a
malformed one is refused and counted), run the compiled tick (haptic_server/stages/station.py:
the device, its user, the coupling rendered against the tool carried on by its twist, the
watchdog's ramp to the safe state), publish the device's state. The rows stay in memory and
are written to MCAP when the run ends (`--log`: a temporary file renamed when whole).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.kernels import noise_ready
from haptic_local_model.device_models.world_map import DeviceWorldMap
from haptic_local_model.haptic_server.hand_ports import glove_at, glove_script
from haptic_local_model.haptic_server.stages.station import (
    STATION_DTYPE,
    STATION_ROW_DTYPE,
    station_row,
    station_tick,
)
from haptic_local_model.haptic_server.users import user_record
from haptic_local_model.haptic_server.world_engines import port_gains, tool_start
from haptic_local_model.shared.config import UserConfig
from haptic_local_model.shared.net.stations import (
    StationNetworkConfig,
    open_client,
    port_keys,
)
from haptic_local_model.shared.net.transport import newest_payload
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig
from haptic_local_model.shared.protocol.station import (
    CUT,
    GLOVE,
    SAFE,
    DeviceState,
    ToolState,
    decode_tool,
    encode_device,
    vec3,
)
from haptic_local_model.shared.protocol.update import MessageError
from haptic_local_model.shared.timing import Pacer, SampleWindow, enter_loop

TOOL_RING = 64  # tool states kept between two ticks: a stalled tick's worth and more
SPIN_NS = 100_000  # the wait's last 0.1 ms spins (several loops share two cores)
MAX_LOG_S = 600.0  # the rows of at most this long stay in memory (--log: --duration <= this)
RING_S = 60.0  # without --log: the last this long (the summary's figures)
#: the tool is carried on by its twist for at most this long: a few of the world's periods
#: and a network hop; an older tool state is rendered where it was (DeviceState likewise)
EXTRAPOLATE_S = 0.005


def rows_in_order(rows: np.ndarray, written: int) -> np.ndarray:
    """A ring of rows, `written` of them written in turn: those kept, oldest first (the
    last len(rows) if more were written). The station's and the shared world's logs."""
    cap = len(rows)
    if written <= cap:
        return rows[:written].copy()
    k = written % cap
    return np.concatenate([rows[k:], rows[:k]])


@dataclass
class StationCounters:
    received: int = 0
    rejected: int = 0
    refills: int = 0
    safe_entries: int = 0  # times the ramp reached the safe state
    reasons: dict[str, int] = field(default_factory=dict)


class Station:
    """One station's records, ready to run (module docstring)."""

    def __init__(
        self,
        scene: PortSceneConfig | HandSceneConfig,
        network: StationNetworkConfig,
        port: str,
        device: SimulatedDevice,
        user: UserConfig,
        max_rows: int,
    ) -> None:
        names = [p.name for p in scene.ports]
        if port not in names:
            raise ValueError(f"port: {port!r} is not one of the scene's ({', '.join(names)})")
        self.scene, self.network, self.port, self.device = scene, network, port, device
        self.index = names.index(port)
        self.user = user
        spec = scene.ports[self.index]
        stiffness, damping = port_gains(scene, self.index)
        st = np.zeros(1, STATION_DTYPE)
        s = st[0]
        s["dt"] = scene.period_s
        s["watchdog_s"] = network.watchdog_ms / 1e3
        s["ramp_s"] = network.safe_ramp_ms / 1e3
        s["limits"] = device.limits().max_wrench
        s["safe_damping"] = device.rendering.safe_damping
        s["stiffness"] = stiffness
        s["damping"] = damping
        s["max_stiffness"] = stiffness
        s["max_damping"] = damping
        s["extrapolate_s"] = EXTRAPOLATE_S
        wm = getattr(device, "world_map", None) or DeviceWorldMap.identity()
        s["map"][0] = wm.record[0]
        self.station = st
        self._place(spec.device_start)
        self.rows = np.zeros(max_rows, STATION_ROW_DTYPE)
        self.rows.view(np.uint8)[:] = 0  # every page touched now, not in the loop
        self.n_rows = 0
        self._tool_ns = 0
        self._last_tool: ToolState | None = None
        self.counters = StationCounters()
        self.work_us = SampleWindow(100_000)
        self.pacer = Pacer(round(scene.period_s * 1e9), SPIN_NS, None)
        self.epoch = time.time_ns()
        self._stop = False
        # a hand's station sends its user's glove (finger_angles on its own clock)
        self._glove = np.zeros((0, 1))
        if isinstance(scene, HandSceneConfig):
            rest = [a for f in scene.hand_of(self.index).fingers for a in f.rest]
            self._glove = glove_script(user, rest)
        joints = self._glove.shape[1] - 1
        self._glove_angle, self._glove_rate = np.zeros(joints), np.zeros(joints)

    def _place(self, start: tuple[float, float, float]) -> None:
        """The device at rest at its start, mapped onto its tool (the world re-indexes it
        when it joins, so this only makes the log's frame the world's at the start)."""
        dev = self.device
        dev.reset(np.array(start, np.float64))
        pose, twist = np.zeros(3), np.zeros(3)
        dev.true_state(pose, twist)
        s = self.station[0]
        u = user_record(self.user)[0]
        u["start_pose"] = pose
        s["user"][0] = u
        tool = tool_start(self.scene, self.index)
        wm = s["map"][0]
        wm["offset"] = tool - wm["scale"] * pose
        s["map"][0] = wm
        s["tool_pose"] = tool

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def _refuse(self, reason: str) -> None:
        self.counters.rejected += 1
        self.counters.reasons[reason] = self.counters.reasons.get(reason, 0) + 1

    def _take_tools(self, sub: Any, now_ns: int) -> None:
        """The newest valid ToolState waiting, into the record; the rest counted. Within the
        world's epoch a message must be newer than the last taken; another epoch (a world
        restarted, or a second one) is taken only once the present one's are stale."""
        newest = None
        s = self.station[0]
        for raw in newest_payload(sub):
            try:
                m = decode_tool(raw, self.index)
            except MessageError as exc:
                self._refuse(exc.reason)
                continue
            last = newest or self._last_tool
            if last is not None:
                if m.epoch == last.epoch and m.seq <= last.seq:
                    self._refuse("stale")
                    continue
                current = now_ns - self._tool_ns < s["watchdog_s"] * 1e9
                if m.epoch != last.epoch and current and newest is None:
                    self._refuse("other_epoch")
                    continue
            newest = m
            self.counters.received += 1
        if newest is not None:
            self._last_tool = newest
            s["have_tool"] = 1
            s["held"] = 1 if newest.held else 0
            s["tool_pose"] = newest.pose
            s["tool_twist"] = newest.twist
            s["stiffness"] = newest.stiffness
            s["damping"] = newest.damping
            self._tool_ns = now_ns
        if s["have_tool"] == 1:
            s["tool_age"] = (now_ns - self._tool_ns) / 1e9

    def run(self, duration_s: float | None, ready: Any = None) -> dict[str, Any]:
        device_key, tool_key = port_keys(self.network.namespace, self.port)
        session = open_client(self.network.station(self.port))
        sub = session.declare_subscriber(tool_key, zenoh.handlers.RingChannel(TOOL_RING))
        pub = session.declare_publisher(
            device_key, congestion_control=zenoh.CongestionControl.DROP, express=True
        )
        st, dev = self.station, self.device.records
        dt = float(st[0]["dt"])
        pacer = Pacer(round(dt * 1e9), SPIN_NS, duration_s)
        self.pacer = pacer
        enter_loop(self.warm, ready)
        pacer.start()
        t0 = -1
        seq = 0
        was_safe = True
        try:
            while not self._stop:
                now = pacer.wait()
                t0 = now if t0 < 0 else t0
                if not noise_ready(dev, dt):
                    refill_noise(self.device.noise, dev, dt)
                    self.counters.refills += 1
                self._take_tools(sub, now)
                station_tick(st, dev)
                s = st[0]
                w = s["world"][0]
                flags = (SAFE if s["fresh"] == 0 else 0) | (CUT if s["cut"] == 1 else 0)
                pose = (0.0, 0.0, 0.0) if s["cut"] else vec3(w["pose"])
                twist = (0.0, 0.0, 0.0) if s["cut"] else vec3(w["twist"])
                glove, rate = self._glove_at((now - t0) / 1e9)
                pub.put(encode_device(DeviceState(
                    self.index, self.epoch, seq, time.time_ns(), pose, twist,
                    flags | (GLOVE if glove else 0), glove, rate,
                )))  # fmt: skip
                safe = s["gain"] == 0.0
                if safe and not was_safe:
                    self.counters.safe_entries += 1
                was_safe = safe
                self._row(now, pacer.late_ns, time.perf_counter_ns() - now)
                seq += 1
                if not pacer.next():
                    break
        finally:
            session.close()
        return self.summary()

    def _glove_at(self, t: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """A hand's station: its glove's angles and rates at t (its own clock); else ()."""
        if len(self._glove) == 0:
            return (), ()
        glove_at(self._glove, len(self._glove), t, len(self._glove_angle), self._glove_angle,
                 self._glove_rate)  # fmt: skip
        return tuple(self._glove_angle.tolist()), tuple(self._glove_rate.tolist())

    def _row(self, now_ns: int, late_ns: int, work_ns: int) -> None:
        self.work_us.add(work_ns / 1e3)
        k = self.n_rows % len(self.rows)
        station_row(self.station, self.rows, k, self.station[0]["sensors"][0]["fault"])
        row = self.rows[k]
        row["wall_ns"] = now_ns
        row["late_us"] = late_ns / 1e3
        row["work_us"] = work_ns / 1e3
        row["received"] = self.counters.received
        row["rejected"] = self.counters.rejected
        self.n_rows += 1

    def warm(self) -> None:
        """Compile (or load) the tick on spare records before the loop."""
        spare = self.station.copy()
        self.device.noise.refill()
        records = self.device.records
        station_tick(spare, records)
        station_row(spare, np.zeros(1, STATION_ROW_DTYPE), 0, 0)
        if len(self._glove):  # a hand's glove, called from the loop: compiled (or loaded) now
            self._glove_at(0.0)
        self._place(self.scene.ports[self.index].device_start)

    def logged_rows(self) -> np.ndarray:
        return rows_in_order(self.rows, self.n_rows)

    def summary(self) -> dict[str, Any]:
        rows = self.logged_rows()
        c = self.counters
        return {
            "port": self.port,
            "device": self.device.name,
            "user": self.user.name,
            "ticks": self.n_rows,
            **self.pacer.figures(),
            "work_us": self.work_us.percentiles(50, 99, 99.9),
            "noise_refills": c.refills,
            "tool_states_received": c.received,
            "tool_states_rejected": c.rejected,
            "rejected_by_reason": dict(c.reasons),
            "safe_entries": c.safe_entries,
            "commands_invalid": int(self.station[0]["invalid"]),
            "mean_command_last_s": (
                rows["out"][-min(len(rows), 1000) :].mean(axis=0).tolist() if len(rows) else []
            ),
            "epoch": self.epoch,
        }
