"""The compiled sim step (sim_server/drive.py) against pymunk driven through its Python API.

The reference below is the drive the sim had before it was compiled, written with pymunk's
own Python calls (forces, torques, its Python velocity callback for the table drag, its
`Space.step`): an independent route to the same C library. A free tool must match it bit for
bit; a linkage's computed torque sums D(q) acc in another order than numpy's BLAS, so it
matches within a few ulps that the contacts of a 2 s run do not grow past REL_TOL.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pymunk
import pytest

from haptic_local_model.shared.config import load_scene
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

STEPS = 120  # 2 s at 60 Hz
REL_TOL = 1e-9  # linkage: ulps of the torque sum's order, grown over the run


def _reference_step(world: SimWorld, target: ToolTarget | None) -> None:
    """One sim period the way pymunk's Python API does it."""
    scene = world.scene
    h = world.period / world.substeps
    q, _ = world.tool_state()
    mass, grav, _ = world.dynamics_terms(q)
    w = 2.0 * math.pi * scene.tool.tracking_bandwidth_hz
    for k in range(world.substeps):
        t = world.time + k * h
        for body, spec in world._kinematic:  # the oscillating obstacles
            if spec.oscillation_period_s > 0.0:
                om = 2.0 * math.pi / spec.oscillation_period_s
                mean = (math.sin(om * (t + h)) - math.sin(om * t)) / h  # the law's, over [t, t + h]
                body.velocity = (
                    spec.velocity[0] + spec.oscillation_amplitude[0] * mean,
                    spec.velocity[1] + spec.oscillation_amplitude[1] * mean,
                )
        t_ahead = k * h
        if scene.tool.kind == "body":
            b = world.tool_bodies[0]
            (px, py), (vx, vy) = b.position, b.velocity
            th, om_b = b.angle, b.angular_velocity
            if target is None:
                ax, ay, al = -2.0 * w * vx, -2.0 * w * vy, -2.0 * w * om_b
            else:
                gq, gv = target.q, target.qd
                ax = w * w * (gq[0] + gv[0] * t_ahead - px) + 2.0 * w * (gv[0] - vx)
                ay = w * w * (gq[1] + gv[1] * t_ahead - py) + 2.0 * w * (gv[1] - vy)
                al = w * w * (gq[2] + gv[2] * t_ahead - th) + 2.0 * w * (gv[2] - om_b)
            m = b.mass
            f = (m * ax - m * scene.gravity[0], m * ay - m * scene.gravity[1])
            b.apply_force_at_world_point(f, b.local_to_world(b.center_of_gravity))
            b.torque += b.moment * al
        else:
            q, qd = world.tool_state()
            if target is None:
                acc = -2.0 * w * qd
            else:
                acc = w * w * (target.q + target.qd * t_ahead - q) + 2.0 * w * (target.qd - qd)
            tau = mass @ acc + grav
            for i, b in enumerate(world.tool_bodies):
                b.torque += float(tau[i])
                if i > 0:
                    world.tool_bodies[i - 1].torque -= float(tau[i])
        world.space.step(h)
    world.time += world.period
    for body, spec in world._kinematic:  # published: the law's own velocity at the step's end
        if spec.oscillation_period_s > 0.0:
            om = 2.0 * math.pi / spec.oscillation_period_s
            rate = om * math.cos(om * world.time)
            body.velocity = (
                spec.velocity[0] + spec.oscillation_amplitude[0] * rate,
                spec.velocity[1] + spec.oscillation_amplitude[1] * rate,
            )


def _python_drag(rate_per_s: float):  # type: ignore[no-untyped-def]
    def update(body: pymunk.Body, gravity: object, damping: float, dt: float) -> None:
        pymunk.Body.update_velocity(body, gravity, damping * math.exp(-rate_per_s * dt), dt)

    return update


def _state(world: SimWorld) -> np.ndarray:
    return np.array(
        [[*b.position, b.angle, *b.velocity, b.angular_velocity] for b in world.space.bodies]
    )


@pytest.mark.parametrize(
    ("scene", "exact"), [("testbed_free_tool", True), ("wall_slide", True), ("testbed", False)]
)
def test_compiled_step_is_pymunks_python_step(scene: str, exact: bool) -> None:
    config = load_scene(scene)
    compiled, reference = SimWorld(config), SimWorld(config)
    for body, spec in zip(reference.space.bodies, config.bodies, strict=False):
        if spec.kind == "dynamic" and spec.linear_damping_per_s > 0.0:
            body.velocity_func = _python_drag(spec.linear_damping_per_s)  # pymunk's callback
    rng = np.random.default_rng(5)
    q0, _ = compiled.tool_state()
    for k in range(STEPS):
        target = None
        if k % 40 < 30:  # follow a wandering proxy, then rest
            q = q0 + 0.02 * np.sin(0.05 * k + np.arange(len(q0)))
            target = ToolTarget(
                q, rng.normal(0, 0.05, len(q0)), np.zeros(3), np.zeros(3), False, True
            )
        compiled.step(target)
        _reference_step(reference, target)
    a, b = _state(compiled), _state(reference)
    if exact:
        np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_allclose(a, b, rtol=REL_TOL, atol=REL_TOL)
    assert np.abs(a[:, :2]).max() < 0.2  # positions (m): the run stayed in the enclosure


def test_a_crowd_sleeps_and_only_the_neighbourhood_is_published() -> None:
    """The crowd scene: resting pebbles fall asleep, the local model carries only contacts
    within the margin of the tool (however many bodies the world has), and none of the
    query's overlaps are dropped."""
    from haptic_local_model.shared.protocol.update import decode_update

    world = SimWorld(load_scene("crowd"))
    margin = world.scene.tool.neighbourhood_margin_m
    for _ in range(60):  # 1 s: past the 0.3 s sleep time
        world.step(None)
    asleep = sum(b.is_sleeping for b in world.space.bodies)
    assert asleep >= 0.95 * len(world.space.bodies)
    q, _ = world.tool_state()
    target = ToolTarget(
        q + np.array([0.0, -0.03, 0.0]), np.zeros(3), np.zeros(3), np.zeros(3), False, True
    )
    for _ in range(30):  # push the plough into the pebbles
        world.step(target)
    update = decode_update(world.local_model_bytes(1, 1, 0))
    assert update.contacts.count > 0 and world.stats.hits_dropped == 0
    rows = update.contacts.rows
    assert (update.contacts.floats[:, 0:2] ** 2).sum(axis=1).max() < 0.03**2  # on the plough
    gaps = ((rows["env"] - _tool_points_world(world, rows["tool"])) * rows["normal"]).sum(axis=1)
    assert (gaps <= margin + 1e-9).all()


def _tool_points_world(world: SimWorld, local: np.ndarray) -> np.ndarray:
    body = world.tool_bodies[0]
    return np.array([list(body.local_to_world(tuple(p))) for p in local])


@pytest.mark.parametrize("rate_hz", [30.0, 60.0])
def test_an_oscillating_body_is_on_its_law_at_every_step(rate_hz: float) -> None:
    """The testbed's shuttle against its closed form x(t) = x0 + v t + A sin(w t) at every
    period's end (each substep moves it by the law's mean velocity over the substep), and the
    twist the update publishes is the law's own at that time. With the law's velocity at the
    substep's end instead, the shuttle was (h / 2)(v(t) - v(0)) off: 105 um for a 5 mm,
    1 Hz platform at 30 Hz."""
    config = load_scene("testbed")
    config = dataclasses.replace(config, sim_rate_hz=rate_hz)
    world = SimWorld(config)
    (body, spec), *_ = [(b, s) for b, s in world._kinematic if s.oscillation_period_s > 0.0]
    x0 = np.array(body.position)
    om = 2.0 * math.pi / spec.oscillation_period_s
    amp, vel = np.array(spec.oscillation_amplitude), np.array(spec.velocity)
    worst = 0.0
    for _ in range(int(2 * rate_hz)):
        world.step(None)
        t = world.time
        law = x0 + vel * t + amp * math.sin(om * t)
        worst = max(worst, float(np.abs(np.array(body.position) - law).max()))
        np.testing.assert_allclose(body.velocity, vel + amp * om * math.cos(om * t), atol=1e-12)
    assert worst < 1e-12, f"{worst * 1e6:.3f} um off the law"
