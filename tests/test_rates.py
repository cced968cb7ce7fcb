"""What depends on the haptic period is stated in time, and holds at 1, 4 and 10 kHz.

The safe-state ramp and the geometry cross-fade are configured in ms and must take that long
at any rate (to within a tick); a pushed box settles on a stiff wall where the closed form
puts it (F / K) at every rate; seed 002's first-order hold interpolates the sim's setpoints
over the sim's own interval whatever the number of ticks in it, so the device's goal follows
the same path at every rate.
"""

from __future__ import annotations

import numpy as np
import pytest

from haptic_local_model.device_models.registry import load_device, load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.net.config import load_network
from haptic_local_model.sim_server.world import SimWorld

RATES = (1000.0, 4000.0, 10000.0)
RAMP_S = load_network("loopback").safe_ramp_ms / 1000.0
#: the steady push of push_2n on the wall of wall_push: F = 2 N on K = 15000 N/m, shared by
#: the box's two contact points
PUSH_N, WALL_K = 2.0, 15000.0
DEPTH_TOL = 1e-4  # relative to F / K once settled (measured: 4e-6 at 1 kHz, 2e-7 at 10 kHz)
FORCE_TOL_N = 1e-3  # the wall's reaction against the push, settled (measured: 8e-6 N)
#: the FOH goal's path at 4 and 10 kHz against 1 kHz; the scoop's goal moves 8 mm along x
#: (measured: 9 um apart: the same sim steps, interpolated over more ticks)
FOH_PATH_TOL_M = 5e-5


def _engine(rate: float) -> tuple[HapticEngine, SimWorld]:
    scene = load_scene("wall_push", rate)
    engine = HapticEngine(scene, load_device("ideal"), load_user("push_2n"), RAMP_S)
    world = SimWorld(scene)
    assert engine.receive(world.local_model_bytes(1, 0, 0)) == ""
    return engine, world


@pytest.mark.parametrize("rate", RATES)
def test_the_safe_ramp_and_the_cross_fade_last_their_time(rate: float) -> None:
    engine, world = _engine(rate)
    dt = 1.0 / rate
    blend_s = engine.scene.rendering.blend_ms / 1000.0
    for _ in range(round(0.05 / dt)):
        engine.tick(dt)
    world.step(None)  # the sim's next step (an update of the same sim time is refused as a jump)
    assert engine.receive(world.local_model_bytes(1, 1, 0)) == ""  # a new model: cross-fade
    ticks_to_blend = 0
    while engine.state[0]["blend"] < 1.0:
        engine.tick(dt)
        ticks_to_blend += 1
    assert abs(ticks_to_blend * dt - blend_s) <= dt + 1e-12
    engine.set_safe(True)
    ticks_to_safe = 0
    while engine.state[0]["safe"] < 1.0:
        engine.tick(dt)
        ticks_to_safe += 1
    assert abs(ticks_to_safe * dt - RAMP_S) <= dt + 1e-12


@pytest.mark.parametrize("rate", RATES)
def test_a_box_pushed_on_a_wall_settles_at_the_closed_form_depth(rate: float) -> None:
    scene = load_scene("wall_push", rate)
    ticks = run_virtual(scene, load_simulated_device("ideal"), load_user("push_2n"), 2.5).ticks
    settled = ticks[-round(0.3 * rate) :]  # the last 0.3 s
    force = -settled["contact_force_world"][:, 0]  # the wall pushes back along -x
    assert np.abs(force - PUSH_N).max() <= FORCE_TOL_N
    box, wall = scene.bodies[0], scene.bodies[1]
    face = settled["proxy_q"][:, 0] + box.size[0] / 2  # the box's leading face (x)
    depth = face - (wall.a[0] - wall.radius)
    assert np.abs(depth / (PUSH_N / WALL_K) - 1.0).max() <= DEPTH_TOL, depth.max()


def test_the_first_order_hold_follows_the_same_path_at_every_rate() -> None:
    """maglev_scoop (virtual_coupling_foh, seed 002 §4) with the ideal device: the device's
    goal x_goal (the logged vm_pose) at 4 and 10 kHz against 1 kHz, sampled at 1 kHz."""
    paths = {}
    for rate in RATES:
        scene = load_scene("maglev_scoop", rate)
        ticks = run_virtual(scene, load_simulated_device("ideal"), load_user("scoop"), 2.0).ticks
        every = round(rate / RATES[0])
        paths[rate] = ticks["vm_pose"][::every, :2]
    n = min(len(p) for p in paths.values())
    assert np.ptp(paths[RATES[0]][:n, 0]) > 5e-3  # the goal does move
    for rate in RATES[1:]:
        gap = np.abs(paths[rate][:n] - paths[RATES[0]][:n]).max()
        assert gap <= FOH_PATH_TOL_M, (rate, gap)
