"""A scene's train of cars in the sim (DESIGN-WAVE2 §5): kinematic pymunk bodies on a track.

The haptic loop integrates the train (its animation variable s, RK4 with the mass-weighted
projection, shared/avar.py) and is authoritative while its proxy states are fresh: each sim
step starts from the newest train state it sent. The sim integrates the same equation itself
from there, substep by substep, without the finger's push (the haptic side renders it), and
moves each car's KINEMATIC body so that it reaches its pose on the track at every substep's
end (velocities set toward it: other dynamic bodies are pushed as by a moving car). With the
haptic side silent the sim's own integration carries the train on; re-initialisation takes
the sim's (s, s') from the update's AVARS trailer.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pymunk
from numba import njit

from haptic_local_model.shared.avar import (
    AVAR_DTYPE,
    MAX_CARS,
    TRAIN_DTYPE,
    train_record,
    train_step,
)
from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.protocol.proxy import TrainState
from haptic_local_model.shared.protocol.static import static_id
from haptic_local_model.shared.track import TRACK_DTYPE, tabulate, track_point
from haptic_local_model.sim_server import chipmunk as cp
from haptic_local_model.sim_server.chipmunk import body_ptr

#: What the compiled step reads of the train (a zero record: no train).
SIM_TRAIN_DTYPE = np.dtype(
    [
        ("enabled", np.int64),
        ("track", TRACK_DTYPE),
        ("train", TRAIN_DTYPE),
        ("state", AVAR_DTYPE),
        ("body", np.int64, (MAX_CARS,)),  # cpBody pointers of the cars
    ]
)


CATCH_UP_STEP_S = 1e-3  # a followed state is carried over its age in steps of the haptic rate
MAX_CATCH_UP_S = 0.1  # ... at most (an older state is the watchdog's business)


def no_train() -> np.ndarray:
    return np.zeros(1, SIM_TRAIN_DTYPE)


@njit(cache=True)
def move_train(rec, h):
    """One substep of h: the train by RK4 (no push), then each car's velocity set so that
    its body reaches the car's new pose at the substep's end."""
    r = rec[0]
    if r.enabled == 0:
        return
    train_step(r.track, r.train, r.state, 0.0, h)
    for k in range(r.train.n_cars):
        x, y, psi, _, _ = track_point(r.track, r.state.s - k * r.train.spacing)
        b = r.body[k]
        px, py = cp.body_position(b)
        turn = psi - cp.body_angle(b)
        turn -= 2.0 * math.pi * round(turn / (2.0 * math.pi))  # the short way round
        cp.body_set_velocity(b, (x - px) / h, (y - py) / h)
        cp.body_set_angular_velocity(b, turn / h)


class SimTrain:
    """The scene's train in the pymunk space: the cars' bodies and shapes, and the record
    the compiled step moves them by."""

    def __init__(
        self, scene: SceneConfig, space: pymunk.Space, register: Callable[[pymunk.Shape, str], None]
    ) -> None:
        cars = scene.cars[0]
        self.static_id = static_id(scene)
        self.record = no_train()
        r = self.record[0]
        r["enabled"] = 1
        r["track"] = tabulate(scene.track_spec)[0]
        r["train"] = train_record(
            cars.count, cars.spacing_m, cars.mass, cars.inertia, scene.gravity, cars.restitution
        )[0]
        r["state"]["s"] = cars.initial_s
        r["state"]["sd"] = cars.initial_speed
        self.n_cars = cars.count
        self.owner: dict[pymunk.Shape, int] = {}  # the car of each car shape
        self.bodies: list[pymunk.Body] = []
        mat = scene.materials[cars.material]
        for k in range(cars.count):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            shape = pymunk.Poly.create_box(body, cars.size, radius=0.0)
            shape.friction = mat.friction
            shape.elasticity = mat.restitution
            space.add(body, shape)
            register(shape, cars.material)
            self.owner[shape] = k
            self.bodies.append(body)
            r["body"][k] = body_ptr(body)
        self.place()

    def place(self) -> None:
        """Every car at its pose and velocity on the track (the start, a re-sync)."""
        r = self.record[0]
        st, tr, train = r["state"], r["track"], r["train"]
        for k, body in enumerate(self.bodies):
            x, y, psi, kappa, _ = track_point(tr, st["s"] - k * train["spacing"])
            body.angle = psi  # before the position (Chipmunk keeps the COG)
            body.position = (x, y)
            body.velocity = (math.cos(psi) * st["sd"], math.sin(psi) * st["sd"])
            body.angular_velocity = kappa * st["sd"]

    def follow(self, train: TrainState | None, age_s: float) -> None:
        """The haptic side's train state (a fresh proxy state's) carried on over its age by
        the sim's own integration: the next step starts from it. A train of another track
        (static id) is ignored."""
        if train is None or train.static_id != self.static_id:
            return
        r = self.record[0]
        st = r["state"]
        st["s"] = train.s
        st["sd"] = train.sd
        left = min(max(age_s, 0.0), MAX_CATCH_UP_S)
        while left > 0.0:
            h = min(left, CATCH_UP_STEP_S)
            train_step(r["track"], r["train"], st, 0.0, h)
            left -= h

    @property
    def state(self) -> tuple[float, float]:
        """(s, s') of the sim's train."""
        st = self.record[0]["state"]
        return float(st["s"]), float(st["sd"])
