"""The sim's mirror of a shared world (`sim-server --mirror SCENE`; DESIGN-WAVE2 §6,
docs/stations.md).

A port scene's box and tools are co-simulated at 1 kHz by `haptic-world`; the sim holds the
rest of the world. It mirrors the co-simulated bodies and steps the scene's `sim_bodies`
(dynamic pymunk bodies) among them and the static walls, at its own rate:

- each step it takes the newest WorldBodies (`<ns>/world/bodies`; a malformed one is refused
  and counted by reason) and drives each mirrored body, a kinematic pymunk body, to the
  pose the world's sample predicts for the step's end (its pose carried on by its twist for
  the sample's age, at most EXTRAPOLATE_S): the mirror pushes the sim's bodies with the
  world's motion, and is never pushed back (the world's bodies have their own dynamics at
  1 kHz: a mirror the sim's bodies could push would count their contact twice);
- it publishes the sim's bodies (SimBodies, `<ns>/sim/bodies`), the world whose samples
  its mirror follows, and the running impulse the sim's bodies have put on each mirrored
  body (the contact impulses pymunk applied, each arbiter's at its contacts' mean point).
  The world applies what is new of it to its body (`sim_contact = "wrench"`: momentum kept,
  at the sim's rate).

With `sim_contact = "shape"` the world meets the sim's bodies as moving shapes of infinite
mass at 1 kHz instead (haptic_server/sim_link.py), and the mirror does not touch them: they
are obstacles that move on their own (one-way). Both at once, the mirror pushing them and
they the world's bodies, is a loop that drives itself: a ball resting on the box presses it
by pymunk's allowed overlap times the world's contact stiffness, the box moves, the mirror
follows, the ball with it, and the press stays (a 20 g ball drove the held box out of its
grasp and through the floor).

The mirror's lag: at each step, how far the mirror stands from where the newest sample puts
the body now (its prediction's error over the last step), the largest over the bodies.
With no sample for `world_watchdog_ms` the mirror stops where it is.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pymunk
import zenoh

from haptic_local_model.shared.config import BodySpec
from haptic_local_model.shared.net.stations import (
    StationNetworkConfig,
    mirror_keys,
    open_client,
)
from haptic_local_model.shared.net.transport import newest_payload
from haptic_local_model.shared.port_config import PortSceneConfig
from haptic_local_model.shared.protocol.station import (
    SIM_BODIES_MAGIC,
    WORLD_BODIES_MAGIC,
    BodiesReceiver,
    bodies_record,
)
from haptic_local_model.shared.timing import Pacer, SampleWindow, enter_loop
from haptic_local_model.sim_server.world import body_shape

SUBSTEPS = 10  # pymunk steps a sim step: a 60 Hz step in 1.7 ms ones
EXTRAPOLATE_S = 0.05
SLOP_M = 1e-4  # pymunk's allowed overlap (its default, 0.1, is for pixels)
WORLD_RING = 16
SPIN_NS = 200_000
MIRROR_CATEGORY = 0b10  # the mirror's shapes (a "shape" scene's sim bodies pass through)


def _shape(body: pymunk.Body, spec: BodySpec, scene: PortSceneConfig) -> pymunk.Shape:
    shape = body_shape(body, spec)
    shape.friction = scene.contact.friction  # every contact takes the scene's [contact]
    shape.elasticity = scene.contact.restitution
    return shape


class Mirror(BodiesReceiver):
    """The sim's world of a port scene (module docstring), ready to run."""

    def __init__(
        self, scene: PortSceneConfig, network: StationNetworkConfig, rate_hz: float
    ) -> None:
        if not scene.sim_bodies:
            raise ValueError(f"{scene.name}: sim_bodies is empty: the sim has nothing to step")
        self.scene, self.network, self.rate_hz = scene, network, rate_hz
        self.h = 1.0 / rate_hz
        space = pymunk.Space()
        space.gravity = scene.gravity
        space.collision_slop = SLOP_M
        space.iterations = 20
        self.space = space
        for spec in scene.bodies:
            if spec.kind == "static":
                body = pymunk.Body(body_type=pymunk.Body.STATIC)
                self._add(body, spec)
        self.order = scene.cosim_order()
        self.mirrored = [
            self._add(pymunk.Body(body_type=pymunk.Body.KINEMATIC), scene.body(name))
            for name in self.order
        ]
        self.sims = [
            self._add(pymunk.Body(spec.mass, spec.moment), spec) for spec in scene.sim_body_specs
        ]
        for b in self.mirrored:
            for s in b.shapes:
                s.filter = pymunk.ShapeFilter(categories=MIRROR_CATEGORY)
        if scene.sim_contact == "shape":  # one-way: the sim's bodies move on their own
            for b in self.sims:
                for s in b.shapes:
                    s.filter = pymunk.ShapeFilter(
                        mask=pymunk.ShapeFilter.ALL_MASKS() ^ MIRROR_CATEGORY
                    )
        for b, spec in zip(self.sims, scene.sim_body_specs, strict=True):
            b.velocity = spec.velocity
            b.angular_velocity = spec.angular_velocity
        self.epoch = time.time_ns()
        self.record = bodies_record(SIM_BODIES_MAGIC, len(self.sims), self.epoch, self.h)
        self.init_receiver(WORLD_BODIES_MAGIC, len(self.mirrored), network.world_watchdog_ms)
        self.steps = 0
        self.lag_mm = SampleWindow(1_000_000)
        self.touching = [0] * len(self.sims)  # steps each sim body touched a mirrored one
        self._sim_set = set(self.sims)
        self._mirror_set = set(self.mirrored)
        self.wrench = np.zeros((len(self.mirrored), 3))  # on each mirrored body, this step
        self.impulse = np.zeros((len(self.mirrored), 3))  # on each, since the start (N s)
        self.pacer = Pacer(round(self.h * 1e9), SPIN_NS, None)
        self._stop = False

    def _add(self, body: pymunk.Body, spec: BodySpec) -> pymunk.Body:
        body.position = spec.position
        body.angle = spec.angle
        self.space.add(body, _shape(body, spec, self.scene))
        return body

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def take(self, sub: Any, now_ns: int) -> None:
        """The newest valid WorldBodies: within the world's epoch newer than the last taken;
        another epoch (a restarted world) only once the present one is silent."""
        for raw in newest_payload(sub):
            m = self.accept(raw, now_ns)
            if m is not None:
                self.taken(m, now_ns)

    def step(self, now_ns: int) -> None:
        """One sim step: the mirror driven to the world's predicted poses, the space stepped."""
        m = self.last
        if m is not None and self.silent(now_ns):
            self.lose()
            m = None
        if m is None:
            for b in self.mirrored:  # no world: the mirror stops where it is
                b.velocity, b.angular_velocity = (0.0, 0.0), 0.0
        else:
            age = min((now_ns - self.rx_ns) / 1e9, EXTRAPOLATE_S)
            lag = 0.0
            for b, s in zip(self.mirrored, m.bodies, strict=True):
                x, y = s[0] + s[3] * age, s[1] + s[4] * age
                lag = max(lag, math.hypot(b.position.x - x, b.position.y - y))
                end = min(age + self.h, EXTRAPOLATE_S)
                tx, ty, ta = s[0] + s[3] * end, s[1] + s[4] * end, s[2] + s[5] * end
                turn = math.remainder(ta - b.angle, 2.0 * math.pi)
                b.velocity = ((tx - b.position.x) / self.h, (ty - b.position.y) / self.h)
                b.angular_velocity = turn / self.h
            self.lag_mm.add(lag * 1e3)
        self.wrench[:] = 0.0
        for _ in range(SUBSTEPS):
            self.space.step(self.h / SUBSTEPS)
            self._impulses()
        self.impulse += self.wrench
        self.wrench /= self.h
        for j, b in enumerate(self.sims):
            hits: list[bool] = []
            b.each_arbiter(self._touches, hits)
            self.touching[j] += any(hits)
        self.steps += 1

    def _impulses(self) -> None:
        """The substep's contact impulses of the sim's bodies on each mirrored body (about
        its centre) into self.wrench, taken within pymunk's arbiter callback (an arbiter
        must not be kept past it). pymunk gives an arbiter's total impulse on its first
        shape's body."""
        for i, b in enumerate(self.mirrored):
            b.each_arbiter(self._impulse, b, i)

    def _touches(self, a: pymunk.Arbiter, hits: list[bool]) -> None:
        hits.append(any(s.body in self._mirror_set for s in a.shapes))

    def _impulse(self, a: pymunk.Arbiter, b: pymunk.Body, i: int) -> None:
        first, second = a.shapes
        mine = first.body is b
        if (second.body if mine else first.body) not in self._sim_set:
            return
        j = a.total_impulse if mine else -a.total_impulse
        points = a.contact_point_set.points
        if not points:
            return
        px = sum(p.point_a.x + p.point_b.x for p in points) / (2 * len(points))
        py = sum(p.point_a.y + p.point_b.y for p in points) / (2 * len(points))
        rx, ry = px - b.position.x, py - b.position.y
        self.wrench[i] += (j.x, j.y, rx * j.y - ry * j.x)

    def publish(self, pub: Any, seq: int) -> None:
        r = self.record[0]
        r["seq"] = seq
        r["publish_time_ns"] = time.time_ns()
        for j, b in enumerate(self.sims):
            r["bodies"][j] = (b.position.x, b.position.y, b.angle,
                              b.velocity.x, b.velocity.y, b.angular_velocity)  # fmt: skip
        r["impulse"][: len(self.mirrored)] = self.impulse
        r["follows"] = self.last.epoch if self.last is not None else 0
        pub.put(self.record.tobytes())

    def run(self, duration_s: float | None, ready: Any = None) -> dict[str, Any]:
        session = open_client(self.network.sim)
        world_key, sim_key = mirror_keys(self.network.namespace)
        sub = session.declare_subscriber(world_key, zenoh.handlers.RingChannel(WORLD_RING))
        pub = session.declare_publisher(
            sim_key, congestion_control=zenoh.CongestionControl.DROP, express=True
        )
        pacer = Pacer(round(self.h * 1e9), SPIN_NS, duration_s)
        self.pacer = pacer
        enter_loop(lambda: None, ready)
        published = 0

        def tick(now: int, _seq: int) -> None:
            nonlocal published
            self.take(sub, now)
            self.step(now)
            if self.last is not None:  # following a world: a sim of none says nothing
                self.publish(pub, published)
                published += 1

        with session:  # closed however the loop ends
            pacer.run(tick, lambda: self._stop)
        return self.summary()

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "steps": self.steps,
            **self.pacer.figures(),
            "epoch": self.epoch,
            "world_bodies_received": self.received,
            "world_bodies_rejected": self.rejected,
            "rejected_by_reason": dict(self.reasons),
            "world_lost": self.lost,
            "lag_mm": self.lag_mm.percentiles(50, 99),
            "mirror": {
                name: [b.position.x, b.position.y, b.angle]
                for name, b in zip(self.order, self.mirrored, strict=True)
            },
            "sim_bodies": {},
        }
        for j, (name, b) in enumerate(zip(self.scene.sim_bodies, self.sims, strict=True)):
            out["sim_bodies"][name] = {
                "end": [b.position.x, b.position.y, b.angle],
                "velocity": [b.velocity.x, b.velocity.y, b.angular_velocity],
                "steps_touching_mirror": self.touching[j],
            }
        return out
