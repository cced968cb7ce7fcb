"""A user's space in their own units (pymunk's examples: pixels) rescaled to SI, in place.

The haptic side works in metres, kilograms and seconds. `scale_space(space, units)` rewrites
every length of a space (bodies' positions and velocities, shapes' geometry, joints' anchors
and lengths, gravity, the collision slop, the sleep speed) by `units.metres_per_unit` and
every mass by `units.kg_per_unit` (moments, stiffnesses and forces by their products), so the
space's motion is the same motion in SI: a trajectory in the rescaled space is the original's
times `metres_per_unit` (tests/test_space_units.py). Time is not rescaled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymunk


@dataclass(frozen=True)
class Units:
    """A space's units in SI: `metres_per_unit` (1e-3: a pixel is a millimetre) and
    `kg_per_unit` (a mass of 1 in the space weighs this many kilograms)."""

    metres_per_unit: float
    kg_per_unit: float = 1.0

    def __post_init__(self) -> None:
        for name in ("metres_per_unit", "kg_per_unit"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"Units.{name} = {value!r}: a finite number > 0")

    def to_user(self, pose_or_point: np.ndarray) -> np.ndarray:
        """SI points (..., 2) or poses (..., 3: x, y, theta) in the space's own units (the
        angle unchanged), e.g. a run's `device_pose` to draw over the user's window."""
        out = np.array(pose_or_point, dtype=np.float64, copy=True)
        out[..., :2] /= self.metres_per_unit
        return out


def _scale_shape(shape: pymunk.Shape, length: float) -> None:
    if isinstance(shape, pymunk.Circle):
        shape.unsafe_set_offset(shape.offset * length)
        shape.unsafe_set_radius(shape.radius * length)
    elif isinstance(shape, pymunk.Segment):
        shape.unsafe_set_endpoints(shape.a * length, shape.b * length)
        shape.unsafe_set_radius(shape.radius * length)
    elif isinstance(shape, pymunk.Poly):
        shape.unsafe_set_vertices([v * length for v in shape.get_vertices()])
        shape.unsafe_set_radius(shape.radius * length)
    else:
        raise ValueError(f"{type(shape).__name__}: a shape type scale_space cannot rescale")


_ROTARY = (
    pymunk.DampedRotarySpring, pymunk.RotaryLimitJoint, pymunk.RatchetJoint, pymunk.GearJoint,
    pymunk.SimpleMotor,
)  # fmt: skip


def _scale_constraint(c: pymunk.Constraint, length: float, mass: float) -> None:
    """Anchors and lengths by `length`; a spring's stiffness and damping and the joint's
    force limit by their units (a rotary joint's are torques: angles are not rescaled)."""
    if isinstance(c, _ROTARY):
        lever = mass * length * length
        if isinstance(c, pymunk.DampedRotarySpring):
            c.stiffness, c.damping = c.stiffness * lever, c.damping * lever
        if math.isfinite(c.max_force):
            c.max_force *= lever
        return
    c.anchor_a, c.anchor_b = c.anchor_a * length, c.anchor_b * length
    if isinstance(c, pymunk.PinJoint):
        c.distance *= length
    elif isinstance(c, pymunk.SlideJoint):
        c.min, c.max = c.min * length, c.max * length
    elif isinstance(c, pymunk.GrooveJoint):
        c.groove_a, c.groove_b = c.groove_a * length, c.groove_b * length
    elif isinstance(c, pymunk.DampedSpring):
        c.rest_length *= length
        c.stiffness, c.damping = c.stiffness * mass, c.damping * mass
    if math.isfinite(c.max_force):
        c.max_force *= mass * length
    if math.isfinite(c.max_bias):
        c.max_bias *= length


def scale_space(space: pymunk.Space, units: Units) -> None:
    """Rewrite `space` (in the units `units` names) in SI, in place: lengths times
    `units.metres_per_unit`, masses times `units.kg_per_unit`. Call it once, after the space
    is built and before it is touched; code that adds bodies later must add them in SI."""
    length, mass = units.metres_per_unit, units.kg_per_unit
    shape_mass = {s: s.mass for s in space.shapes}  # set by a shape's mass or density
    bodies = [b for b in space.bodies]
    held = {b: (b.mass, b.moment) for b in bodies if b.body_type == pymunk.Body.DYNAMIC}
    for shape in space.shapes:
        _scale_shape(shape, length)
    for shape, m in shape_mass.items():
        if m > 0.0:
            shape.mass = m * mass  # its body's mass and moment follow from its shapes
    for body in [*bodies, space.static_body]:
        body.position = body.position * length
        body.velocity = body.velocity * length
        if body in held and not any(shape_mass.get(s, 0.0) > 0.0 for s in body.shapes):
            m, moment = held[body]
            body.mass, body.moment = m * mass, moment * mass * length * length
            body.center_of_gravity = body.center_of_gravity * length
    for c in space.constraints:
        _scale_constraint(c, length, mass)
    space.gravity = space.gravity * length
    space.collision_slop *= length
    space.idle_speed_threshold *= length
    space.reindex_static()
    for body in bodies:
        space.reindex_shapes_for_body(body)


__all__ = ["Units", "scale_space"]
