"""Stability: the sampled wall against Colgate's bound, the stiff cases, and the guards."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from haptic_local_model.benchmarks.stability import (
    COUPLED,
    LOCAL_MODEL,
    _push,
    _run,
    _wall_scene,
    classify,
    colgate_bound,
    engine_wall_boundary,
    god_object_map,
    many_contacts_case,
    proxy_kinetic,
    sampled_wall_boundary,
    wall_generates,
)
from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_local_model.shared.config import load_scene

BOUND_TOL = 0.20  # issue 7: the measured boundary within 20% of the passivity bound
PERIOD_S = 1.06e-3  # 1 kHz plus the measured p99.9 lateness
#: The engine's wall (docs/stability/report.md, "This engine's wall vs haptic rate"): the
#: issue's acceptance band, +-25% of the bound, and for the growth from 1 to 4 kHz. Measured
#: 0.94 and 0.98 of the bound at b = 5 N s/m: the engine's wall starts one tick late (the
#: contact is detected on the proxy a tick after it crossed), which costs O(omega T).
ENGINE_BOUND_TOL = 0.25
RATE_RATIO_TOL = 0.25
ENGINE_B = 5.0  # N s/m, the device's damping in the engine tests
#: semi-implicit Euler with explicit damping: relative error ~ t b^2 h / (2 m^2) = 1e-4 here
DAMPED_DEVICE_TOL = 1e-3


@pytest.mark.parametrize("b_device", [1.0, 5.0, 20.0])
def test_sampled_wall_boundary_matches_colgate(b_device: float) -> None:
    bound = colgate_bound(b_device, 0.0, PERIOD_S)
    measured = sampled_wall_boundary(b_device, 0.0, PERIOD_S, 0.25 * bound, 4 * bound, 16)
    assert abs(measured / bound - 1.0) < BOUND_TOL
    assert measured >= bound * 0.99  # the bound is sufficient: nothing below it generates


def test_virtual_damping_keeps_the_bound_conservative() -> None:
    bound = colgate_bound(5.0, 0.5, PERIOD_S)
    assert sampled_wall_boundary(5.0, 0.5, PERIOD_S, 0.25 * bound, 4 * bound, 16) >= bound


@pytest.mark.parametrize("stiffness", [1e2, 1e6])
def test_stiff_and_soft_walls_stay_stable_and_passive(stiffness: float) -> None:
    scene = _wall_scene(stiffness, 20.0)
    ticks = _run(scene, _push(2.0), 0.6)
    case = classify("K", str(stiffness), ticks, proxy_kinetic(ticks, scene))
    assert case.stable and case.finite and case.faults == 0, case


def test_god_object_coupling_gains_stay_stable_passive_and_finite() -> None:
    """The god-object's K_vc over three decades, B_vc from the loader's minimum up, the finger
    pressed into a floor (haptic-stability's "god-object coupling" axis, quick subset): every
    case finite, bounded, passive at the hand and without a fault."""
    cases = god_object_map(quick=True)
    assert len(cases) >= 5
    for case in cases:
        assert case.stable and case.finite and case.faults == 0, case


def test_many_simultaneous_contacts_stay_finite_and_still() -> None:
    ticks = many_contacts_case(48, 0.5)
    assert np.isfinite(ticks["wrench_command"]).all()
    assert np.abs(ticks["device_pose"][-1, :2]).max() < 1e-2


def test_guard_a_nan_never_reaches_the_device() -> None:
    """A NaN in the loop (here the hand's wrench) sends the device to the safe state: the
    command stays finite and within limits, and the fault is logged."""
    scene = load_scene("wall_push")
    device = IdealDevice(IdealDeviceConfig())
    from haptic_local_model.haptic_server.engine import HapticEngine
    from haptic_local_model.shared.config import UserConfig
    from haptic_local_model.shared.protocol.update import encode_update
    from haptic_local_model.sim_server.world import SimWorld

    engine = HapticEngine(
        scene, device, UserConfig(name="x", kind="constant_wrench", wrench=(1.0, 0.0, 0.0))
    )
    assert engine.receive(encode_update(SimWorld(scene).local_model(1, 0, 0))) == ""
    for _ in range(50):
        engine.tick(1e-3)
    engine.user[0]["wrench"] = np.nan
    rows = np.concatenate([engine.tick(1e-3).copy() for _ in range(50)])
    assert (rows["fault"] != 0).all()
    assert np.isfinite(rows["wrench_command"]).all()
    assert (np.abs(rows["wrench_command"]) <= np.array(device.limits().max_wrench)).all()
    assert (rows["safe"] == 1.0).all()


def test_user_force_beyond_what_the_device_can_resist_is_clipped_not_amplified() -> None:
    scene = dataclasses.replace(_wall_scene(15000.0, 20.0))
    ticks = _run(scene, _push(50.0), 0.5)
    limits = np.array(IdealDeviceConfig().max_wrench)
    assert (np.abs(ticks["wrench_applied"]) <= limits + 1e-12).all()
    assert np.isfinite(ticks["wrench_command"]).all()


def _engine_boundary(rate_hz: float) -> tuple[float, float]:
    bound = colgate_bound(ENGINE_B, 0.0, 1.0 / rate_hz)
    return engine_wall_boundary(COUPLED, rate_hz, ENGINE_B, 0.0, (bound / 8, bound * 8)), bound


def test_engine_wall_boundary_follows_colgate_at_1_and_4_khz() -> None:
    """The real engine's sampled wall (virtual coupling to a pinned tool, the ideal device
    with damping b): its passivity boundary is Colgate's 2 b / T and grows with the rate."""
    k1, bound1 = _engine_boundary(1000.0)
    k4, bound4 = _engine_boundary(4000.0)
    assert abs(k1 / bound1 - 1.0) < ENGINE_BOUND_TOL, (k1, bound1)
    assert abs(k4 / bound4 - 1.0) < ENGINE_BOUND_TOL, (k4, bound4)
    assert abs((k4 / k1) / 4.0 - 1.0) < RATE_RATIO_TOL, k4 / k1


def test_local_model_wall_is_not_a_sampled_wall_on_the_device() -> None:
    """With no device damping Colgate's bound allows no stiffness for a wall sampled at the
    device; the local model renders the contact on its implicit proxy and stays passive at
    ten times the bound of a 5 N s/m device (its limit scales with m / T^2, the report)."""
    stiffness = 10.0 * colgate_bound(ENGINE_B, 0.0, 1e-3)
    assert not wall_generates(LOCAL_MODEL, 1000.0, stiffness, 0.0, 0.0)
    assert wall_generates(COUPLED, 1000.0, stiffness, 0.0, 0.0)


def test_ideal_device_viscous_damping_decays_as_the_closed_form() -> None:
    """The ideal device's optional damping and substeps: m vd = -b v from v0 gives
    v = v0 exp(-b t / m) and x = v0 m / b (1 - exp(-b t / m)) (no command, no hand)."""
    mass, b, v0, dt, ticks = 0.5, ENGINE_B, 0.05, 1e-3, 100
    device = IdealDevice(
        IdealDeviceConfig(inertia=(mass, mass, 1e-3), viscous_damping=(b, b, 0.0), substeps=64)
    )
    device.state[0]["twist"][0] = v0
    for _ in range(ticks):
        device.advance(dt, np.zeros(3))
    decay = np.exp(-b * ticks * dt / mass)
    assert device.state[0]["twist"][0] == pytest.approx(v0 * decay, rel=DAMPED_DEVICE_TOL)
    x = v0 * mass / b * (1.0 - decay)
    assert device.state[0]["pose"][0] == pytest.approx(x, rel=DAMPED_DEVICE_TOL)
    assert IdealDeviceConfig().viscous_damping == (0.0, 0.0, 0.0)  # the default: undamped
    assert IdealDeviceConfig().substeps == 1  # and one step per tick, as before


@pytest.mark.parametrize("mass", [1e-3, 1e-2])
def test_a_tool_too_light_for_the_coordination_gains_is_softened_not_refused(mass: float) -> None:
    """The map's light tools get the coordination coupling a user's space would give them:
    each axis at 80 % of the bound K dt^2 + 2 B dt < 2 m (mass; moment on the third)."""
    scene = _wall_scene(15000.0, 20.0, mass=mass)
    held = next(b for b in scene.bodies if b.name == "rectangle")
    dt = 1.0 / scene.haptic_rate_hz
    r = scene.rendering
    for axis, m in enumerate((held.mass, held.mass, held.moment)):
        k, b = r.coordination_stiffness[axis], r.coordination_damping[axis]
        assert k * dt * dt + 2.0 * b * dt <= 0.8 * 2.0 * m * (1.0 + 1e-12)
    assert r.coordination_damping[0] < load_scene("wall_push").rendering.coordination_damping[0]
