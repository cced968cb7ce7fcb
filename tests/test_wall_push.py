"""Seed 001 §5: a rectangle pushed into a stiff wall by 2 N, penalty only vs with impulses."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from haptic_local_model.benchmarks.wall_push import (
    PUSH_N,
    SETTLE_BAND,
    WallPushMetrics,
    impact,
    measure,
    sweep_case,
)

PENETRATION_TOL = 0.05  # issue 3: steady penetration within 5% of F/K
RUN_S = 2.0


@pytest.fixture(scope="module")
def metrics() -> dict[str, WallPushMetrics]:
    return {scene: measure(scene, RUN_S)[0] for scene in ("wall_push", "wall_push_penalty")}


def test_steady_penetration_is_force_over_stiffness(metrics: dict[str, WallPushMetrics]) -> None:
    for m in metrics.values():
        assert m.penetration_error < PENETRATION_TOL, m
        assert abs(m.steady_force_n - PUSH_N) < SETTLE_BAND * PUSH_N, m


def test_impulses_stop_the_bouncing(metrics: dict[str, WallPushMetrics]) -> None:
    with_impulses, penalty = metrics["wall_push"], metrics["wall_push_penalty"]
    assert with_impulses.contact_losses <= 1
    assert with_impulses.settling_s < RUN_S / 2  # settled within the band, and stays there
    # the seed's difference: penalty alone bounces more and settles later
    assert penalty.contact_losses > with_impulses.contact_losses
    assert penalty.settling_s > with_impulses.settling_s


#: Stiffness x push corners of `benchmarks.wall_push --sweep` (the shipped 50 N limit: the
#: 1 kg device needs 280-660 N to stop in one tick, so every impulse is carried).
SWEEP_CASES = [(5000.0, 1.0), (50000.0, 2.0), (50000.0, 5.0)]


@pytest.mark.parametrize("law", ["0.2", "0.13"])
@pytest.mark.parametrize(("stiffness", "push"), SWEEP_CASES)
def test_impulses_under_the_device_limit_neither_bounce_nor_push_out(stiffness, push, law) -> None:
    """An impulse the device delivers over several ticks: at most one contact loss, the VM
    not pushed out by a zero-restitution impact beyond the spring-back of the depth at which
    it was detected (sqrt(K/m) (depth - F/K), undamped, from rest), its penetration F/K
    within 5%, and no energy put into the hand's port."""
    r = sweep_case(stiffness, push, law, RUN_S)
    assert r["contact_losses"] <= 1, r
    assert r["push_out"] <= r["spring_back_bound"], r
    assert abs(r["vm_penetration_ratio"] - 1.0) < PENETRATION_TOL, r
    assert r["port_energy_j"] <= 0.0, r
    assert r["peak_command_n"] <= 50.0, r


def test_version_01_impulses_bounce_at_the_device_limit() -> None:
    """The same wall under version 0.1's law (kept for its logs): the carried impulse and
    the coupling both brake the device, and the forces of the impact tick push the VM out."""
    r = sweep_case(50000.0, 5.0, "0.1", RUN_S)
    assert r["contact_losses"] > 1, r
    assert r["push_out"] > 3.0 * r["spring_back_bound"], r


#: long enough for the device to settle: its overshoot after a carried impulse returns with the
#: coordination coupling's slow pole (tau = 0.68 s for the scene's K_pc = 100 N/m, B_pc = 70 N
#: s/m on a 1 kg device); from a few mm to within 5% of F/K (tens of um) takes about 8 tau
SETTLE_RUN_S = 8.0
SETTLE_TAUS = 10.0


@pytest.mark.parametrize("law", ["0.2", "0.13"])
@pytest.mark.parametrize(("stiffness", "push"), SWEEP_CASES)
def test_the_device_settles_at_force_over_stiffness(stiffness, push, law) -> None:
    """Not only the VM: the device's own penetration settles within 5% of F/K, and stays,
    within ten of the coupling's slow time constants after the impact."""
    r = sweep_case(stiffness, push, law, SETTLE_RUN_S)
    assert r["device_settle_s"] <= SETTLE_TAUS * r["coupling_time_constant_s"], r
    assert abs(r["device_penetration_ratio"] - 1.0) < PENETRATION_TOL, r
    assert abs(r["vm_penetration_ratio"] - 1.0) < PENETRATION_TOL, r


#: Law 0.13's device peak at the sweep's corners, in F/K (0.2: 4.6, 42.8 and 42.6: the 1 kg
#: device's stopping distance at 50 N past the proxy; 0.13 measured 1.6, 1.0 and 3.4, the
#: proxy's own depth at detection, 1.5-4.3 F/K at 50 kN/m, and under a tick of the plan)
PEAK_013_FK = 4.0


@pytest.mark.parametrize(("stiffness", "push"), SWEEP_CASES)
def test_law_013_stops_the_device_where_the_proxy_stops(stiffness, push) -> None:
    """Half the device's share of a predicted impact paid ahead: it comes to rest near the
    proxy's stop instead of its stopping distance past it, within the device limit, and
    passive at the port."""
    new, old = sweep_case(stiffness, push, "0.13", RUN_S), sweep_case(stiffness, push, "0.2", RUN_S)
    assert new["device_peak_ratio"] <= PEAK_013_FK, new
    assert new["device_peak_ratio"] <= old["device_peak_ratio"], (new, old)
    assert new["peak_command_n"] <= 50.0, new
    assert new["port_energy_j"] <= 0.0, new


@pytest.mark.slow
def test_the_fronts_wall_settles_within_half_a_second() -> None:
    """The front's wall row (benchmarks/front.py: wall_push, 2 N, the ideal device started
    on the proxy), graded against the closed form F/K: the device's peak within 3 F/K and
    inside 5 % of F/K within 0.5 s of the impact and to the end (0.2: 12.6 F/K and 3.8 s on
    the coupling's slow pole), no contact loss, passive at the port."""
    from haptic_local_model.benchmarks.front import wall_transient

    for law in ("0.13", "0.2"):
        scene, ticks = _front_wall(law, 2.0)
        e = wall_transient(scene, ticks)
        if law == "0.2":  # the weakness it replaces, as measured
            assert e["peak_over_fk"] > 10.0 and e["settle_s"] > 1.5, e
            continue
        assert e["peak_over_fk"] <= 3.0, e
        assert e["settle_s"] <= 0.5, e
        assert e["contact_losses"] == 0, e
        assert e["port_energy_j"] <= 0.0, e


def _front_wall(law: str, seconds: float) -> tuple[Any, np.ndarray]:
    from haptic_local_model.benchmarks.front import configure, device_for
    from haptic_local_model.haptic_server.harness.virtual import run_virtual
    from haptic_local_model.shared.config import load_scene, load_user

    scene = configure(load_scene("wall_push"), "local_model", 60.0)
    rendering = dataclasses.replace(scene.rendering, impulse_law=law)  # type: ignore[arg-type]
    scene = dataclasses.replace(scene, rendering=rendering)
    device = device_for("ideal", "local_model")
    return scene, run_virtual(scene, device, load_user("push_2n"), seconds).ticks


def test_no_force_before_contact_beyond_the_bounded_payment_ahead() -> None:
    """Before the first contact the law 0.13 device is commanded exactly what law 0.2's is
    (the free-space law, bit for bit), except in the payment window just before the
    predicted impact: there its extra force is braking only (against the approach), within
    the 50 N limit, lasts at most T = M v / (F_max - F_push) (the time the limit needs for
    the whole momentum change), and totals at most PREPAY_SHARE of M v. This bounds what
    the hand feels before it touches the wall (measured: 4 ticks, 0.196 N s of 0.40, from
    1.4 mm off the surface)."""
    from haptic_local_model.haptic_server.stages.control import PREPAY_SHARE

    _, new = _front_wall("0.13", 0.3)
    _, old = _front_wall("0.2", 0.3)
    first_new, _ = impact(new)
    first_old, _ = impact(old)
    assert first_new == first_old  # the proxy meets the wall on the same tick
    mass = 1.0  # configs/devices/ideal.toml inertia
    v = float(old["device_twist"][first_old, 0])  # the approach speed the payment answers
    window_ticks = int(np.ceil(mass * v / (50.0 - PUSH_N) / 1e-3))
    extra = new["f_impulse"][:first_new, 0]
    paying = np.flatnonzero(extra != 0.0)
    assert paying.size > 0  # the payment exists (else the peak could not be 1 F/K)
    start = int(paying[0])
    assert first_new - start <= window_ticks, (start, first_new, window_ticks)
    before = slice(0, start)  # the free-space law, untouched
    assert np.array_equal(new["wrench_command"][before], old["wrench_command"][before])
    assert np.all(extra[paying] < 0.0)  # braking, against the approach along +x
    assert np.all(np.abs(new["wrench_command"][:first_new]) <= 50.0)
    paid = -float(extra.sum()) * 1e-3
    assert paid <= PREPAY_SHARE * mass * v, (paid, v)
