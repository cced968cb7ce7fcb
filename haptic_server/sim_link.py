"""The shared world's side of the sim that mirrors it (`sim-server --mirror`, docs/stations.md;
DESIGN-WAVE2 §6).

The world publishes its co-simulated bodies (WorldBodies, `<ns>/world/bodies`) every
BODIES_EVERY ticks; the sim tracks them with its mirror and steps the scene's `sim_bodies`,
which the mirror pushes, and publishes them every sim step (SimBodies, `<ns>/sim/bodies`).
Each world tick the sim's bodies are the newest SimBodies, carried on by their twists for the
time since it arrived (at most EXTRAPOLATE_S: an old sample is not carried into a guess);
a sim silent for `world_watchdog_ms` leaves them where they were, at rest. The SimBodies'
wrench on each co-simulated body (its mean over the sim's last step) is applied every tick
until the next arrives, for at most EXTRAPOLATE_S: with samples a sim step apart the
impulse the world applies is the sim's. A malformed
message is refused and counted by reason, never used; within the sim's epoch each must be
newer than the last taken, and another epoch (a restarted sim) is taken only once the
present one is silent.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import zenoh

from haptic_local_model.haptic_server.stages.cosim import carry_sim_bodies
from haptic_local_model.shared.net.stations import StationNetworkConfig, mirror_keys
from haptic_local_model.shared.net.transport import newest_payload
from haptic_local_model.shared.port_config import MAX_SIM_BODIES, PortSceneConfig
from haptic_local_model.shared.protocol.station import (
    SIM_BODIES_MAGIC,
    WORLD_BODIES_MAGIC,
    BodiesState,
    bodies_record,
    decode_bodies,
)
from haptic_local_model.shared.protocol.update import MessageError

BODIES_EVERY = 4  # world ticks a WorldBodies: 250 Hz at 1 kHz, four times a 60 Hz sim's rate
EXTRAPOLATE_S = 0.05  # three 60 Hz sim steps
SIM_RING = 16


class SimLink:
    """The world's bodies out, the sim's bodies in (module docstring)."""

    def __init__(
        self,
        scene: PortSceneConfig,
        network: StationNetworkConfig,
        model: np.ndarray,
        data: np.ndarray,
        epoch: int,
    ) -> None:
        self.network, self.model, self.data = network, model, data
        self.n_bodies = int(model[0]["n_bodies"])
        self.n_sim = len(scene.sim_bodies)
        self.record = bodies_record(WORLD_BODIES_MAGIC, self.n_bodies, epoch)
        self.sample = np.zeros((MAX_SIM_BODIES, 6))  # the sim's bodies at their start
        for j, spec in enumerate(scene.sim_body_specs):
            self.sample[j, :3] = (*spec.position, spec.angle)
        self.wrench = np.zeros((int(model[0]["n_bodies"]), 3))
        self.last: BodiesState | None = None
        self.rx_ns = 0
        self.received = self.rejected = self.sent = self.lost = 0
        self.reasons: dict[str, int] = {}
        # each SimBodies' age when taken: publish to take on the wall clocks (one host's)
        self.age_ms: list[float] = []
        self._pub: Any = None
        self._sub: Any = None

    def open(self, session: zenoh.Session) -> None:
        world_key, sim_key = mirror_keys(self.network.namespace)
        self._pub = session.declare_publisher(
            world_key, congestion_control=zenoh.CongestionControl.DROP, express=True
        )
        if self.n_sim:
            self._sub = session.declare_subscriber(sim_key, zenoh.handlers.RingChannel(SIM_RING))

    def _refuse(self, reason: str) -> None:
        self.rejected += 1
        self.reasons[reason] = self.reasons.get(reason, 0) + 1

    def _silent(self, now_ns: int) -> bool:
        return self.last is None or (now_ns - self.rx_ns) / 1e6 > self.network.world_watchdog_ms

    def take(self, now_ns: int) -> None:
        """The newest valid SimBodies (module docstring), then the sim's bodies this tick."""
        if self._sub is None:
            return
        for raw in newest_payload(self._sub):
            try:
                m = decode_bodies(raw, SIM_BODIES_MAGIC, self.n_sim)
            except MessageError as exc:
                self._refuse(exc.reason)
                continue
            last = self.last
            if last is not None and m.epoch == last.epoch and m.seq <= last.seq:
                self._refuse("stale")
                continue
            if last is not None and m.epoch != last.epoch and not self._silent(now_ns):
                self._refuse("other_epoch")
                continue
            self.last, self.rx_ns = m, now_ns
            self.received += 1
            self.sample[: self.n_sim] = m.array()
            self.wrench[:] = m.wrench[: self.n_bodies]
            if len(self.age_ms) < 100_000:
                self.age_ms.append((time.time_ns() - m.publish_time_ns) / 1e6)
        if self.last is not None and self._silent(now_ns):
            self.lost += 1
            self.sample[:, :3] += self.sample[:, 3:] * EXTRAPOLATE_S  # where it was carried
            self.sample[:, 3:] = 0.0  # held there, at rest
            self.last = None
        age = (now_ns - self.rx_ns) / 1e9 if self.last is not None else math.inf
        if age > EXTRAPOLATE_S:  # an old wrench is not applied on and on
            self.wrench[:] = 0.0
        self.data[0]["sim_wrench"][: self.n_bodies] = self.wrench
        carry_sim_bodies(self.model, self.data, self.sample, min(age, EXTRAPOLATE_S))

    def publish(self, seq: int) -> None:
        """Every BODIES_EVERY ticks: the co-simulated bodies (q's order) to the sim."""
        if seq % BODIES_EVERY:
            return
        d = self.data[0]
        r = self.record[0]
        n = self.n_bodies
        r["seq"] = seq
        r["publish_time_ns"] = time.time_ns()
        r["bodies"][:n, :3] = d["q"][: 3 * n].reshape(n, 3)
        r["bodies"][:n, 3:] = d["qd"][: 3 * n].reshape(n, 3)
        self._pub.put(self.record.tobytes())
        self.sent += 1

    def summary(self) -> dict[str, Any]:
        ages = np.array(self.age_ms) if self.age_ms else np.zeros(1)
        return {
            "world_bodies_sent": self.sent,
            "sim_bodies_received": self.received,
            "sim_bodies_rejected": self.rejected,
            "rejected_by_reason": dict(self.reasons),
            "sim_lost": self.lost,  # times the sim fell silent for world_watchdog_ms
            "sim_bodies_age_ms": {f"p{q}": float(np.percentile(ages, q)) for q in (50, 99)},
        }
