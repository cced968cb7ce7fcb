"""The shared world's side of the sim that mirrors it (`sim-server --mirror`, docs/stations.md;
DESIGN-WAVE2 §6).

The world publishes its co-simulated bodies (WorldBodies, `<ns>/world/bodies`) every
BODIES_EVERY ticks; the sim tracks them with its mirror and steps the scene's `sim_bodies`,
which the mirror pushes, and publishes them every sim step (SimBodies, `<ns>/sim/bodies`).
Each world tick the sim's bodies are the newest SimBodies, carried on by their twists for the
time since it arrived; past EXTRAPOLATE_S (an old sample is not carried into a guess), or
with the sim silent for `world_watchdog_ms`, they are held where they were carried, at rest.
A SimBodies carries the running impulse the sim's bodies have put on each mirrored body; the
world applies what is new since the last one taken, spread over one sim step
(`drain_impulse`): every impulse once, none lost with a dropped message, none doubled by
two taken in one tick; no body is pushed harder than FORCE_OVER_WEIGHT times the sim's
bodies' weight (beyond it the impulse is not applied, and counted). The force a tick follows
the arrivals: with 60 Hz samples on 1 kHz ticks, m g for 16 ticks and two thirds of it on
the 17th; two samples in one tick make twice it for a step, then nothing until the next.
A lost sim's impulse not yet applied is dropped. A SimBodies whose mirror follows another
world (or none yet) is refused (`other_world`). A malformed message is refused and counted
by reason, never used; within the sim's epoch each must be newer than the last taken, and
another epoch (a restarted sim) is taken only once the present one is silent.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import zenoh

from haptic_local_model.haptic_server.stages.cosim import (
    MAX_COSIM_BODIES,
    carry_sim_bodies,
    drain_impulse,
)
from haptic_local_model.shared.net.stations import StationNetworkConfig, mirror_keys
from haptic_local_model.shared.net.transport import newest_payload
from haptic_local_model.shared.port_config import MAX_SIM_BODIES, PortSceneConfig
from haptic_local_model.shared.protocol.station import (
    SIM_BODIES_MAGIC,
    WORLD_BODIES_MAGIC,
    BodiesReceiver,
    BodiesState,
    bodies_record,
)

BODIES_EVERY = 4  # world ticks a WorldBodies: 250 Hz at 1 kHz, four times a 60 Hz sim's rate
EXTRAPOLATE_S = 0.05  # three 60 Hz sim steps
# the most force the sim's bodies may put on a body, over their weight: a body falling
# 0.5 m onto it (3.1 m/s) stopped within a 60 Hz step is 19 times its weight
FORCE_OVER_WEIGHT = 100.0
SIM_RING = 16


class SimLink(BodiesReceiver):
    """The world's bodies out, the sim's bodies in (module docstring)."""

    def __init__(
        self,
        scene: PortSceneConfig,
        network: StationNetworkConfig,
        model: np.ndarray,
        data: np.ndarray,
        epoch: int,
    ) -> None:
        self.network, self.model, self.data, self.epoch = network, model, data, epoch
        self.n_bodies = int(model[0]["n_bodies"])
        self.n_sim = len(scene.sim_bodies)
        period = BODIES_EVERY * float(data[0]["dt"])
        self.record = bodies_record(WORLD_BODIES_MAGIC, self.n_bodies, epoch, period)
        self.sample = np.zeros((MAX_SIM_BODIES, 6))  # the sim's bodies at their start
        for j, spec in enumerate(scene.sim_body_specs):
            self.sample[j, :3] = (*spec.position, spec.angle)
        self.held = True  # the sample is held (at rest), not carried on by its twist
        g = float(np.hypot(*scene.gravity)) or 9.81
        self.max_force = FORCE_OVER_WEIGHT * g * sum(b.mass for b in scene.sim_body_specs)
        self.clipped = 0  # SimBodies whose impulse would have pushed beyond max_force
        self.impulse_taken: np.ndarray | None = None  # the sim's running impulse as last taken
        self.pending = np.zeros((MAX_COSIM_BODIES, 3))  # received, not yet applied (N s)
        self.rate = np.zeros((MAX_COSIM_BODIES, 3))  # applied per second (N, N m)
        self.init_receiver(SIM_BODIES_MAGIC, self.n_sim, network.world_watchdog_ms)
        self.sent = 0
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

    def _install(self, m: BodiesState, now_ns: int) -> None:
        """A SimBodies taken: its bodies, and the impulse since the last one taken (the first
        of a sim, or the first after a loss, is the baseline: nothing applied from it)."""
        impulse = np.array(m.impulse)[: self.n_bodies]
        if self.impulse_taken is not None and self.last is not None and m.epoch == self.last.epoch:
            self.pending[: self.n_bodies] += impulse - self.impulse_taken
        self.impulse_taken = impulse
        # the rest over about one sim step, each body's force and torque (about its centre:
        # times a metre) within max_force; what is beyond is not applied (counted)
        limit = self.max_force * m.period_s
        if np.any(np.abs(self.pending) > limit):
            self.clipped += 1
            np.clip(self.pending, -limit, limit, out=self.pending)
        self.rate[:] = self.pending / m.period_s
        self.taken(m, now_ns)
        self.sample[: self.n_sim] = m.array()
        self.held = False
        if len(self.age_ms) < 100_000:
            self.age_ms.append((time.time_ns() - m.publish_time_ns) / 1e6)

    def _hold(self, age_s: float) -> None:
        """The sim's bodies held where they were carried to, at rest."""
        if not self.held:
            self.sample[:, :3] += self.sample[:, 3:] * min(age_s, EXTRAPOLATE_S)
            self.sample[:, 3:] = 0.0
            self.held = True

    def _other_world(self, m: BodiesState) -> str | None:
        """A SimBodies whose mirror follows no world, or another one."""
        return "other_world" if m.follows != self.epoch else None

    def take(self, now_ns: int) -> bool:
        """The newest valid SimBodies (module docstring), then the sim's bodies this tick;
        whether a SimBodies came (taken or refused)."""
        if self._sub is None:
            return False
        came = False
        for raw in newest_payload(self._sub):
            came = True
            m = self.accept(raw, now_ns, self._other_world)
            if m is not None:
                self._install(m, now_ns)
        age = (now_ns - self.rx_ns) / 1e9
        if self.last is not None and age > EXTRAPOLATE_S:
            self._hold(age)  # an old sample is not carried on into a guess
        if self.last is not None and self.silent(now_ns):
            self._hold(age)
            self.lose()
            self.impulse_taken = None  # a sim heard again starts a new baseline
            self.pending[:] = 0.0  # and nothing of a lost sim is applied on
            self.rate[:] = 0.0
        drain_impulse(self.model, self.data, self.pending, self.rate)
        carry_sim_bodies(self.model, self.data, self.sample, 0.0 if self.held else age)
        return came

    def publish(self, seq: int) -> bool:
        """Every BODIES_EVERY ticks: the co-simulated bodies (q's order) to the sim; whether
        it did this tick."""
        if seq % BODIES_EVERY:
            return False
        d = self.data[0]
        r = self.record[0]
        n = self.n_bodies
        r["seq"] = seq
        r["publish_time_ns"] = time.time_ns()
        r["bodies"][:n, :3] = d["q"][: 3 * n].reshape(n, 3)
        r["bodies"][:n, 3:] = d["qd"][: 3 * n].reshape(n, 3)
        self._pub.put(self.record.tobytes())
        self.sent += 1
        return True

    def summary(self) -> dict[str, Any]:
        ages = np.array(self.age_ms) if self.age_ms else np.zeros(1)
        return {
            "world_bodies_sent": self.sent,
            "sim_bodies_received": self.received,
            "sim_bodies_rejected": self.rejected,
            "rejected_by_reason": dict(self.reasons),
            "sim_lost": self.lost,  # times the sim fell silent for world_watchdog_ms
            "impulse_clipped": self.clipped,
            "sim_bodies_age_ms": {f"p{q}": float(np.percentile(ages, q)) for q in (50, 99)},
        }
