"""A space in its own units (pymunk's examples: pixels) rescaled to SI in place
(sim_server/space_units.py, `api.scale_space`): the same motion, times the length scale."""

from __future__ import annotations

import numpy as np
import pymunk
import pytest

from haptic_local_model import api

L, KG = 1.0e-3, 0.01  # a pixel a millimetre, a mass of 1 ten grams


def _pixel_space() -> tuple[pymunk.Space, list[pymunk.Body]]:
    """Pixels: a ball and a box falling on a floor, a pendulum on a pivot, a damped spring
    and a pin between two discs, in gravity 900 px/s^2."""
    space = pymunk.Space()
    space.gravity = (0.0, -900.0)
    floor = pymunk.Segment(space.static_body, (0, 100), (600, 100), 1.0)
    floor.friction = 0.8
    space.add(floor)
    ball = pymunk.Body(10.0, pymunk.moment_for_circle(10.0, 0, 15))
    ball.position, ball.velocity = (100, 300), (40, 0)
    box = pymunk.Body()  # mass from its shape's density
    box.position, box.angle = (300, 250), 0.3  # tilted: a flat landing tips by round-off
    box_shape = pymunk.Poly.create_box(box, (20, 30), radius=1.0)
    box_shape.density, box_shape.friction = 0.02, 0.5
    space.add(ball, pymunk.Circle(ball, 15, (2, 0)), box, box_shape)
    bob = pymunk.Body(5.0, pymunk.moment_for_circle(5.0, 0, 10))
    bob.position = (500, 400)
    space.add(bob, pymunk.Circle(bob, 10), pymunk.PivotJoint(space.static_body, bob, (450, 450)))
    a, b = pymunk.Body(2.0, 50.0), pymunk.Body(2.0, 50.0)
    a.position, b.position = (150, 500), (220, 520)
    spring = pymunk.DampedSpring(a, b, (0, 0), (0, 0), 60.0, 300.0, 5.0)
    pin = pymunk.PinJoint(space.static_body, a, (150, 560), (0, 0))
    space.add(a, b, pymunk.Circle(a, 8), pymunk.Circle(b, 8), spring, pin)
    return space, [ball, box, bob, a, b]


def _trajectory(space: pymunk.Space, bodies: list[pymunk.Body], steps: int) -> np.ndarray:
    out = []
    for _ in range(steps):
        space.step(1.0 / 300.0)
        out.append([(*b.position, b.angle) for b in bodies])
    return np.array(out)


def test_a_rescaled_space_moves_as_the_original_times_the_scale() -> None:
    """Dynamics are invariant under a change of units: every body's path in the SI space is
    the pixel space's times L (angles equal), through contacts, a pivot, a pin and a spring."""
    pixels, bodies = _pixel_space()
    si, si_bodies = _pixel_space()
    api.scale_space(si, api.Units(metres_per_unit=L, kg_per_unit=KG))
    assert si.gravity == pytest.approx((0.0, -0.9))
    assert si_bodies[0].mass == pytest.approx(0.1) and si_bodies[1].mass == pytest.approx(
        bodies[1].mass * KG
    )
    assert si_bodies[0].moment == pytest.approx(bodies[0].moment * KG * L * L)
    expected = _trajectory(pixels, bodies, 300)
    got = _trajectory(si, si_bodies, 300)
    assert np.abs(expected[..., :2]).max() > 100.0  # they moved
    scaled = got.copy()
    scaled[..., :2] /= L
    np.testing.assert_allclose(scaled, expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_units_refuse_a_scale_that_is_not_positive_and_finite(bad: float) -> None:
    with pytest.raises(ValueError, match=r"Units\.metres_per_unit = .*: a finite number > 0"):
        api.Units(metres_per_unit=bad)
    with pytest.raises(ValueError, match=r"Units\.kg_per_unit = .*: a finite number > 0"):
        api.Units(metres_per_unit=1.0, kg_per_unit=bad)


def test_to_user_maps_si_poses_back_to_the_spaces_units() -> None:
    units = api.Units(metres_per_unit=L)
    pose = np.array([[0.3, 0.25, 0.5]])
    assert np.array_equal(units.to_user(pose), [[300.0, 250.0, 0.5]])
