"""A scene's mechanism in the sim (DESIGN-WAVE2 §5): a train of cars on a track or a
slider-crank (shared/mechanism.py), as kinematic pymunk bodies.

The haptic loop integrates the mechanism's animation variable q (RK4 with the mass-weighted
projection) and is authoritative while its proxy states are fresh: each sim step starts from
the newest state it sent, carried over its age. The sim integrates the same equation itself
from there, substep by substep, without the finger's push (the haptic side renders it), and
moves each body so that it reaches its pose at every substep's end (velocities set toward
it: other dynamic bodies are pushed as by a moving car). With the haptic side silent the
sim's own integration carries the mechanism on; re-initialisation takes the sim's (q, q')
from the update's AVARS trailer.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pymunk
from numba import njit

from haptic_local_model.shared.avar import AVAR_DTYPE
from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.mechanism import (
    MAX_BODIES,
    MECHANISM_DTYPE,
    body_count,
    body_pose,
    initial_state,
    mechanism_record,
    step,
    turn_between,
)
from haptic_local_model.shared.protocol.proxy import TrainState
from haptic_local_model.shared.protocol.static import static_id
from haptic_local_model.sim_server import chipmunk as cp
from haptic_local_model.sim_server.chipmunk import body_ptr

CATCH_UP_STEP_S = 1e-3  # a followed state is carried over its age in steps of the haptic rate
MAX_CATCH_UP_S = 0.1  # ... at most (an older state is the watchdog's business)

#: What the compiled step reads of the mechanism (a zero record: none).
SIM_TRAIN_DTYPE = np.dtype(
    [
        ("enabled", np.int64),
        ("mech", MECHANISM_DTYPE),
        ("state", AVAR_DTYPE),
        ("body", np.int64, (MAX_BODIES,)),  # cpBody pointers of its bodies
    ]
)


def no_train() -> np.ndarray:
    return np.zeros(1, SIM_TRAIN_DTYPE)


@njit(cache=True)
def move_train(rec, h):
    """One substep of h: the mechanism by RK4 (no push), then each body's velocity set so
    that it reaches its new pose at the substep's end."""
    r = rec[0]
    if r.enabled == 0:
        return
    step(r.mech, r.state, 0.0, h)
    for k in range(body_count(r.mech)):
        x, y, angle = body_pose(r.mech, r.state.s, k)
        b = r.body[k]
        px, py = cp.body_position(b)
        cp.body_set_velocity(b, (x - px) / h, (y - py) / h)
        cp.body_set_angular_velocity(b, turn_between(cp.body_angle(b), angle) / h)


def _shapes(scene: SceneConfig, body: pymunk.Body, k: int) -> pymunk.Shape:
    """Body k's shape in its frame: a car's box about its track point; a crank's bar from
    its pivot, the rod from the crank's tip, the slider's box."""
    if scene.cars:
        return pymunk.Poly.create_box(body, scene.cars[0].size, radius=0.0)
    if scene.avar_tree is not None:
        a = scene.avar_tree
        return pymunk.Segment(body, (0.0, 0.0), (a.lengths[k], 0.0), a.width)
    c = scene.crank
    assert c is not None
    if k == 2:
        return pymunk.Poly.create_box(body, c.slider_size, radius=0.0)
    length = c.crank_length if k == 0 else c.rod_length
    return pymunk.Segment(body, (0.0, 0.0), (length, 0.0), c.width)


class SimTrain:
    """The scene's mechanism in the pymunk space: its bodies and shapes, and the record the
    compiled step moves them by."""

    def __init__(
        self, scene: SceneConfig, space: pymunk.Space, register: Callable[[pymunk.Shape, str], None]
    ) -> None:
        self.static_id = static_id(scene)
        self.record = no_train()
        r = self.record[0]
        r["enabled"] = 1
        r["mech"] = mechanism_record(scene)[0]
        r["state"]["s"], r["state"]["sd"] = initial_state(scene)
        self.n_cars = int(body_count(r["mech"]))
        owner = scene.cars[0] if scene.cars else scene.crank or scene.avar_tree
        assert owner is not None
        material = owner.material
        mat = scene.materials[material]
        self.owner: dict[pymunk.Shape, int] = {}  # the body of each of its shapes
        self.bodies: list[pymunk.Body] = []
        for k in range(self.n_cars):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            shape = _shapes(scene, body, k)
            shape.friction = mat.friction
            shape.elasticity = mat.restitution
            space.add(body, shape)
            register(shape, material)
            self.owner[shape] = k
            self.bodies.append(body)
            r["body"][k] = body_ptr(body)
        self.place()

    def place(self) -> None:
        """Every body at its pose (the start, a re-sync), at rest until the first substep
        sets its velocity."""
        r = self.record[0]
        for k, body in enumerate(self.bodies):
            x, y, angle = body_pose(r["mech"], r["state"]["s"], k)
            body.angle = angle  # before the position (Chipmunk keeps the COG)
            body.position = (x, y)

    def follow(self, train: TrainState | None, age_s: float) -> None:
        """The haptic side's state (a fresh proxy state's) carried on over its age by the
        sim's own integration: the next step starts from it. Another mechanism's (static id)
        is ignored."""
        if train is None or train.static_id != self.static_id:
            return
        r = self.record[0]
        st = r["state"]
        st["s"] = train.s
        st["sd"] = train.sd
        left = min(max(age_s, 0.0), MAX_CATCH_UP_S)
        while left > 0.0:
            h = min(left, CATCH_UP_STEP_S)
            step(r["mech"], st, 0.0, h)
            left -= h

    @property
    def state(self) -> tuple[float, float]:
        """(q, q') of the sim's mechanism."""
        st = self.record[0]["state"]
        return float(st["s"]), float(st["sd"])
