"""Deformable surfaces sampled at a low rate (DESIGN-WAVE2 §4, F2): the node hold of NODAL
segments in the god-object kernel against closed forms (V2.1), the pymunk string against
F L / (4 T), the membrane_10hz scene pressed through the whole system in the virtual clock
(V2.3), and the loop-gain check that keeps a scene from limit-cycling."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from haptic_local_model.benchmarks import node_hold
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.stages.god_object import (
    GeometryBlend,
    blend_data,
    blend_tick,
    god_data,
    god_object_tick,
    god_params,
    install_blended,
    install_clock,
    install_shapes,
)
from haptic_local_model.haptic_server.world import run_ticks
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.protocol.proxy import ShapeImpulses
from haptic_local_model.shared.shapes import Motion, ShapeKind, set_core, shape_array
from haptic_local_model.sim_server.membrane import Membrane
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

DT = 1e-3
R = 0.002


def nodal(
    shapes: np.ndarray, k: int, a: tuple[float, float], b: tuple[float, float], **f: object
) -> None:
    """shapes[k] = a NODAL segment a -> b (world), rounded by 0.5 mm."""
    mid = np.add(a, b) / 2
    set_core(shapes[k], ShapeKind.SEGMENT, [np.subtract(a, mid), np.subtract(b, mid)], 5e-4)
    shapes[k]["key"] = f.pop("key", 1)
    shapes[k]["motion"] = int(Motion.NODAL)
    shapes[k]["pose"] = (*mid, 0.0)
    for name, value in f.items():
        shapes[k][name] = value


@pytest.mark.parametrize("rate_hz", [10.0, 30.0, 60.0])
def test_v2_1_the_node_hold_moves_a_sampled_wall_without_steps(rate_hz: float) -> None:
    """V2.1: y = 5 mm sin(2 pi t) sampled at rate_hz, the finger fixed in it, K = 1000 N/m:
    the per-tick force step at updates <= 0.1 N and <= 2x the largest elsewhere, and the RMS
    error against the wall as it is at every tick <= 1.1x the zero-order hold's. The
    zero-order hold steps by the sampled sine's increments (2 A sin(pi f / f_u) cos(...) K),
    and the hold without prediction lags by T_u (larger RMS): both checked as they are."""
    runs = {b: node_hold.moving_wall(rate_hz, b) for b in GeometryBlend}
    foh, zoh, lin = (
        runs[GeometryBlend.NODE_FOH],
        runs[GeometryBlend.NONE],
        runs[GeometryBlend.LINEAR],
    )
    assert foh.update_max_n <= node_hold.STEP_TARGET_N
    assert foh.update_max_n <= node_hold.STEP_RATIO * foh.other_max_n
    assert foh.rms_n <= node_hold.RMS_RATIO * zoh.rms_n
    step = 2 * node_hold.AMPLITUDE * math.sin(math.pi / rate_hz) * node_hold.K
    # (the installs fall on the 1 ms grid: a sample interval may be a tick longer)
    assert step * math.cos(math.pi / rate_hz) * 0.99 <= zoh.update_max_n <= step * 1.03
    assert zoh.other_max_n == 0.0
    assert lin.rms_n > foh.rms_n


def test_v2_1_with_the_coupling_damping_the_update_steps_stay_small() -> None:
    """The scenes' B = 2 N s/m turns the hold's change of velocity at an update into a force
    step B dv: still <= 0.1 N and <= 2x elsewhere at 10 Hz (the zero-order hold: 8.8 N)."""
    w = node_hold.moving_wall(10.0, GeometryBlend.NODE_FOH, damping=2.0)
    assert w.update_max_n <= node_hold.STEP_TARGET_N
    assert w.update_max_n <= node_hold.STEP_RATIO * w.other_max_n


def run_wall(install_every_s: float, sample_every_s: float, ticks: int = 1200) -> np.ndarray:
    """The V2.1 wall sampled every sample_every_s but installed every install_every_s (the
    sim's updates repeating its last sample in between): the force per tick."""
    m = god_params(
        R, (1000.0, 1000.0), (0.0, 0.0), max_force=1e3, node_period_s=sample_every_s
    )  # fmt: skip
    old, new = shape_array(1), shape_array(1)
    node_hold._sample(new, 0.0)
    d = god_data((0.0, R))
    install_shapes(m, d, old, 0, new, 1, install_clock(0.0, 0.0, 0.0))
    x = np.array([0.0, node_hold.FINGER_Y])
    sample_t, last, k_install = 0.0, 0.0, 1
    out = np.zeros(ticks)
    for i in range(ticks):
        t = i * DT
        if t >= k_install * install_every_s - 1e-12:
            if t >= sample_t + sample_every_s - 1e-9:
                sample_t = round(t / sample_every_s) * sample_every_s
            old[:] = new
            node_hold._sample(new, sample_t)
            install_shapes(m, d, old, 1, new, 1, install_clock(t - last, 0.0, t))
            last = t
            k_install += 1
        god_object_tick(m, d, new, 1, x, x, t - last, DT)
        out[i] = d[0]["force"][1]
    return out


def test_updates_that_repeat_a_sample_leave_the_hold_running() -> None:
    """A surface published at 10 Hz in updates at 50 Hz: the four repeats between samples
    change nothing; the force is the one of 10 Hz updates alone."""
    alone = run_wall(0.1, 0.1)
    repeated = run_wall(0.02, 0.1)
    assert np.max(np.abs(alone - repeated)) < 1e-9
    assert np.ptp(alone[200:]) > 5.0  # the wall moves: the figure is not of a still surface


def test_a_segment_entering_between_samples_leaves_the_holds_running() -> None:
    """The sim sends the segments near the finger: one may enter between two samples. It is
    held at rest at its nodes; the others' holds, the horizon and the force under the
    finger are as if it had not come."""
    runs = []
    for extra in (False, True):
        m = god_params(R, (1000.0, 1000.0), (0.0, 0.0), max_force=1e3, node_period_s=0.1)
        d = god_data((0.0, R))
        old, new = shape_array(2), shape_array(2)
        x = np.array([0.0, -0.01])
        forces, n_new, n_old = [], 1, 0
        for i in range(1000):
            t = i * DT
            if i % 20 == 0:  # updates at 50 Hz, samples at 10 Hz
                old[:] = new
                n_old = n_new
                y = 0.005 * math.sin(2 * math.pi * (i // 100) * 0.1)
                nodal(new, 0, (-0.05, y), (0.05, y), key=1)
                n_new = 2 if extra and i >= 530 else 1
                if n_new == 2:
                    nodal(new, 1, (0.05, y), (0.1, y), key=2)
                install_shapes(m, d, old, n_old, new, n_new, install_clock(0.02, 0.0, t))
            god_object_tick(m, d, new, n_new, x, x, 0.0, DT)
            forces.append(d[0]["force"][1])
        runs.append((np.array(forces), d[0]["node_horizon_s"]))
    (alone, horizon), (joined, horizon_joined) = runs
    assert np.array_equal(alone, joined)
    assert horizon == horizon_joined == pytest.approx(0.1)
    assert np.ptp(alone[300:]) > 1.0  # the surface moves under the finger


def straight_string() -> tuple[np.ndarray, ...]:
    """(params, data, old, new, finger): one NODAL segment along y = 0 sampled every 100 ms,
    installed; the finger 10 mm above it, free."""
    m = god_params(R, (1000.0, 1000.0), (2.0, 2.0), node_period_s=0.1)
    old, new = shape_array(1), shape_array(1)
    nodal(new, 0, (-0.05, 0.0), (0.05, 0.0))
    d = god_data((0.0, 0.01))
    install_shapes(m, d, old, 0, new, 1, install_clock(0.0, 0.0, 0.0))
    return m, d, old, new, np.array([0.0, 0.01])


def test_a_still_surface_is_sampled_all_the_same() -> None:
    """Samples that repeat the surface bit for bit (a string at rest) still count once per
    period, so the hold's horizon is the sample period when the surface starts to move."""
    m, d, old, new, x = straight_string()
    for i in range(1, 1000):
        if i % 20 == 0:  # updates at 50 Hz, the surface unchanged
            old[:] = new
            install_shapes(m, d, old, 1, new, 1, install_clock(0.02, 0.0, i * DT))
        god_object_tick(m, d, new, 1, x, x, 0.0, DT)
    assert d[0]["node_samples"] == 10  # t = 0, 0.1, ..., 0.9 s
    assert d[0]["node_horizon_s"] == pytest.approx(0.1, abs=2e-3)


def test_a_new_generation_starts_from_its_own_nodes() -> None:
    """A segment whose generation changes (a remesh) is not held toward a prediction from the
    old geometry: its nodes are the new ones, at rest, from the install on."""
    m, d, old, new, x = straight_string()
    for step, generation in ((1, 0), (2, 1)):
        old[:] = new
        nodal(new, 0, (-0.05, 0.002 * step), (0.05, 0.002 * step), generation=generation)
        install_shapes(m, d, old, 1, new, 1, install_clock(0.1, 0.0, 0.1 * step))
        god_object_tick(m, d, new, 1, x, x, 0.0, DT)
    np.testing.assert_allclose(d[0]["node_start"][0], [[-0.05, 0.004], [0.05, 0.004]])
    assert not d[0]["node_rate"][0].any()


def test_a_fast_held_surface_is_substepped_and_never_passes_the_proxy() -> None:
    """A thin segment (rho 0.5 mm) held from 20 mm below the finger to 40 mm above it in one
    20 ms sample period (3 m/s, 3 mm per tick against (r + rho) / 2 = 1.25 mm): the node
    speed sets the sub-steps, and the surface carries the proxy up instead of passing it."""
    m = god_params(R, (1000.0, 1000.0), (2.0, 2.0), max_force=1e3, node_period_s=0.02)
    old, new = shape_array(1), shape_array(1)
    d = god_data((0.0, 0.0))
    x = np.array([0.0, 0.0])
    for i, y in enumerate((-0.05, -0.04, -0.03)):  # two samples so far; predicted: -0.02 ...
        old[:] = new
        nodal(new, 0, (-0.05, y), (0.05, y))
        install_shapes(m, d, old, min(i, 1), new, 1, install_clock(0.02, 0.0, 0.02 * i))
        for _ in range(20):
            god_object_tick(m, d, new, 1, x, x, 0.0, DT)
    old[:] = new
    nodal(new, 0, (-0.05, 0.005), (0.05, 0.005))  # predicts +0.04: it sweeps past the finger
    install_shapes(m, d, old, 1, new, 1, install_clock(0.02, 0.0, 0.06))
    substeps = []
    for _ in range(20):
        god_object_tick(m, d, new, 1, x, x, 0.0, DT)
        substeps.append(d[0]["substeps"])
    assert max(substeps) >= 3  # ceil(2 x 3 mm / 2.5 mm)
    assert d[0]["proxy"][1] == pytest.approx(0.04 + 5e-4 + R, abs=1e-6)  # on top of it
    assert d[0]["pops"] == 0


def test_the_pymunk_string_deflects_by_the_closed_form() -> None:
    """1 N on the mid-span node of membrane_10hz's string: F L / (4 T) = 10 mm per newton at
    rest (the zero-rest-length springs make it exact; the dashpots exert nothing at rest)."""
    world = SimWorld(load_scene("membrane_10hz"))
    mem = world.membranes[0]
    q, qd = world.tool_state()
    target = ToolTarget(
        q=q, qd=qd, device_pose=np.zeros(3), device_twist=np.zeros(3), coupled_to_device=False,
        fresh=True, impulses=ShapeImpulses(  # 1 N over each step, past segment 10's first
            np.array([mem.first_key + 10]), np.array([[-0.01, 0.0]]),  # end: all on node 10
            np.array([[0.0, -1.0]]) * world.period,
        ),
    )  # fmt: skip
    for _ in range(600):  # 10 s: tau = 0.6 s
        world.step(target)
    spec = mem.spec
    closed = 1.0 * spec.length / (4 * spec.tension_n)
    assert -mem.nodes()[10, 1] == pytest.approx(closed, rel=1e-4)
    assert np.abs(mem.nodes()[:, 0] - np.linspace(-0.05, 0.05, 21)).max() < 1e-6


def test_a_segment_force_is_shared_by_its_nodes_and_the_pins_take_theirs() -> None:
    world = SimWorld(load_scene("membrane_10hz"))
    mem = world.membranes[0]
    nodes = mem.nodes()
    point = 0.75 * nodes[5] + 0.25 * nodes[6]
    pushes = mem.pushes(mem.first_key + 5, point, np.array([0.0, -2.0]))
    assert [b for b, _, _ in pushes] == [mem.bodies[4], mem.bodies[5]]
    np.testing.assert_allclose([f[1] for _, _, f in pushes], [-1.5, -0.5])
    end = mem.pushes(mem.first_key, nodes[0], np.array([0.0, -1.0]))
    assert end == []  # on the pinned end: the wall takes it


def test_an_unstable_string_is_refused_with_the_substep_it_needs() -> None:
    scene = load_scene("membrane_10hz")
    light = dataclasses.replace(scene.deformables[0], mass=0.001)
    world = SimWorld(scene)
    with pytest.raises(ValueError, match=r"deformables.membrane: .* sim substep under"):
        Membrane(world.space, light, scene.materials["skin"], 100, 1e-3)


def test_the_scene_refuses_a_coupling_that_would_limit_cycle_through_the_string() -> None:
    """K = 1000 N/m with node_foh: a gain of 1.7 per sample (measured: 4 N peak to peak);
    the zero-order hold halves it (0.83): accepted."""
    scene = load_scene("membrane_10hz")
    stiff = dataclasses.replace(scene.rendering, god_object_stiffness=(1000.0, 1000.0))
    with pytest.raises(ValueError, match=r"deformables\[0\]: .* gain of 1.67"):
        dataclasses.replace(scene, rendering=stiff)
    held = dataclasses.replace(stiff, geometry_blend="none")
    assert dataclasses.replace(scene, rendering=held).deformables[0].loop_gain(1000.0, False) < 1


def test_the_scene_refuses_a_string_it_cannot_sample_or_step() -> None:
    """The loader, before any process starts: a sample rate that does not divide the sim's
    (the sim would sample at another rate than the haptic side expects), two strings at
    different rates, and a string pymunk's explicit spring cannot step (named with the
    substep it needs)."""
    scene = load_scene("membrane_10hz")
    string = scene.deformables[0]
    with pytest.raises(ValueError, match=r"deformables\[0\].publish_hz: 35 Hz must divide"):
        dataclasses.replace(scene, deformables=(dataclasses.replace(string, publish_hz=35.0),))
    light = dataclasses.replace(string, mass=0.001)
    with pytest.raises(ValueError, match=r"sim_substeps: deformables\[0\]: .* substep under"):
        dataclasses.replace(scene, deformables=(light,))
    other = dataclasses.replace(string, name="other", a=(-0.05, 0.05), b=(0.05, 0.05))
    two = (string, dataclasses.replace(other, publish_hz=20.0))
    with pytest.raises(ValueError, match=r"deformables\[1\].publish_hz: every deformable"):
        dataclasses.replace(scene, deformables=two)


@pytest.mark.slow
def test_v2_3_the_membrane_pressed_through_the_system_at_10_hz() -> None:
    """V2.3 in the virtual clock (the real sim and haptic engine): at rest the string's
    deflection, read from the proxy, is F L / (4 T) within 5 % of the force the hand feels,
    the force's peak to peak <= 0.02 N, no fault; the zero-order hold's ripple is larger."""
    foh = node_hold.membrane_press("node_foh", 10.0)
    zoh = node_hold.membrane_press("none", 10.0)
    assert foh.force_n == pytest.approx(1.1, abs=0.1)  # the hand's 1 N, give or take its spring
    assert abs(foh.error) <= node_hold.DEFLECTION_TOLERANCE
    assert foh.node_deflection_m == pytest.approx(foh.deflection_m, abs=1e-4)  # sim and proxy
    assert foh.peak_to_peak_n <= node_hold.PEAK_TO_PEAK_N
    assert foh.faults == 0 and zoh.faults == 0
    assert zoh.peak_to_peak_n > foh.peak_to_peak_n


# --- V2.2: a change of topology under the proxy (the two-proxy blend) ----------------------


def test_v2_2_a_bump_appearing_under_the_finger_is_blended_in_over_t_b() -> None:
    """V2.2: a 3 mm bump appears under a finger pressing 2 mm: the force rises from 2 N to
    5 N over T_b = 25 ms (+- 1 tick), no per-tick step above the smoothstep's steepest,
    1.5 dF dt / T_b (+ 1 %); without the blend it steps at once (the damping kicks too)."""
    f = node_hold.bump_forces(0.025, [(200, [(2, 0.003)])])
    assert f[199] == pytest.approx(2.0, abs=1e-9)
    done = 200 + int(np.flatnonzero(np.abs(f[200:] - 5.0) < 1e-9)[0])
    assert abs((done - 199) - 25) <= 1  # the blend's last tick is its 25th
    steps = np.abs(np.diff(f[195:300]))
    assert steps.max() <= 1.5 * 3.0 * DT / 0.025 * 1.01
    jump = node_hold.bump_forces(0.0, [(200, [(2, 0.003)])])
    assert np.abs(np.diff(jump[195:300])).max() > 3.0


def test_v2_2_a_second_change_mid_blend_restarts_from_what_is_rendered() -> None:
    """The bump grows to 5 mm 10 ticks into the blend: A restarts from the rendered proxy,
    so the force neither jumps nor runs back; it reaches K 7 mm over a new T_b."""
    f = node_hold.bump_forces(0.025, [(200, [(2, 0.003)]), (210, [(2, 0.003), (3, 0.005)])])
    steps = np.abs(np.diff(f[195:320]))
    assert steps.max() <= 1.5 * (7.0 - f[209]) * DT / 0.025 * 1.01
    assert (np.diff(f[200:260]) >= -1e-9).all()  # rises only
    assert f[-1] == pytest.approx(7.0, abs=1e-9)


def test_a_shape_gone_from_under_the_finger_is_blended_out_over_t_b() -> None:
    """The bump the finger presses on is gone from the next update (the sim flung it out of
    the neighbourhood: god_crowd, 0.7): the force falls from 5 N to 2 N over T_b with no step
    above 1.5 dF dt / T_b, where before the proxy fell onto the floor in one tick (a 3 mm
    jump the runaway guard took for a fault)."""
    f = node_hold.bump_forces(0.025, [(200, [(2, 0.003)]), (300, [])])
    assert f[299] == pytest.approx(5.0, abs=1e-9) and f[-1] == pytest.approx(2.0, abs=1e-9)
    assert np.abs(np.diff(f[295:])).max() <= 1.5 * 3.0 * DT / 0.025 * 1.01
    assert 20 <= np.count_nonzero(np.abs(f[300:] - 2.0) > 1e-9) <= 26  # over T_b = 25 ms
    jump = node_hold.bump_forces(0.0, [(200, [(2, 0.003)]), (300, [])])
    assert np.abs(np.diff(jump[295:])).max() > 3.0


def test_a_new_generation_of_a_held_surface_is_blended_in() -> None:
    """A membrane's segment under the finger comes in a new generation 1 mm higher (a remesh):
    the two-proxy blend runs over min(blend_s, 0.8 T_avg) = 80 ms (blend_s 100 ms, samples
    every 100 ms) and the force rises without a step; the weight of the new geometry is
    logged (god_blend) while it runs."""
    m = god_params(R, (1000.0, 1000.0), (2.0, 2.0), max_force=20.0, blend_s=0.1, node_period_s=0.1)
    d, b = god_data((0.0, 5e-4 + R)), blend_data()
    old, new = shape_array(1), shape_array(1)
    x = np.array([0.0, 5e-4 + R - 0.002])
    forces, weights = [], []
    for i in range(400):
        if i % 100 == 0:
            old[:] = new
            y, gen = (0.001, 1) if i == 300 else (0.0, 0)
            nodal(new, 0, (-0.05, y), (0.05, y), generation=gen)
            install_blended(m, d, b, old, min(i, 1), new, 1, install_clock(0.1, 0.0, i * DT))
        god_object_tick(m, d, new, 1, x, x, 0.0, DT)
        blend_tick(m, d, b, x, x, DT)
        forces.append(b[0]["force"][1])
        weights.append(b[0]["weight"])
    f, w = np.array(forces), np.array(weights)
    assert f[299] == pytest.approx(2.0, abs=1e-6) and f[-1] == pytest.approx(3.0, abs=1e-6)
    assert np.count_nonzero(w[300:] > 0) == 80  # T_b = min(100 ms, 0.8 x 100 ms)
    assert np.abs(np.diff(f[290:])).max() <= 1.5 * 1.0 * DT / 0.08 * 1.01


def test_a_reinitialisation_starts_the_string_hold_at_the_new_sample() -> None:
    """After the watchdog, the next update re-initialises: the string's hold must start at
    that update's sample, at rest, not predict from the stale sample before the outage (the
    pressed string relaxes while the haptic side is away: 2 y_new - y_stale would be off by
    what it relaxed)."""
    scene = load_scene("membrane_10hz")
    world = SimWorld(scene)
    engine = HapticEngine(scene, load_simulated_device("ideal"), load_user("press_1n"))
    mem = world.membranes[0]
    q, qd = world.tool_state()
    press = ToolTarget(
        q=q, qd=qd, device_pose=np.zeros(3), device_twist=np.zeros(3), coupled_to_device=False,
        fresh=True, impulses=ShapeImpulses(
            np.array([mem.first_key + 10]), np.array([[-0.01, 0.0]]),
            np.array([[0.0, -1.0]]) * world.period,
        ),
    )  # fmt: skip
    seq = 0
    for target in [press] * 60 + [None] * 9:  # 1 s pressed, then 150 ms of outage
        world.step(target)
        raw = world.local_model_bytes(1, seq, seq * 16_666_667)
        seq += 1
        if target is None:
            continue
        assert engine.receive(raw) == ""
        run_ticks(engine, np.zeros(16, TICK_DTYPE), 0, 16)
    stale = engine.data[0]["god"]["node_start"].copy()
    engine.set_stale()
    assert engine.receive(raw) == ""  # the first update after the outage: a new sample
    god = engine.data[0]["god"]
    n = int(engine.slots[0]["n_shapes"])
    assert n > 0 and not god["node_rate"][:n].any()  # at rest at the new sample
    shapes = engine.slots[0]["shapes"][:n]
    mid = shapes["pose"][:, None, :2] + shapes["vertices"][:, :2]
    np.testing.assert_allclose(god["node_start"][:n], mid)
    assert np.abs(god["node_start"][:n] - stale[:n]).max() > 5e-4  # it did relax
