"""Held linkages against independent references (DESIGN §4.3, the J_h_dot qd term).

- J_h_dot qd of the kernels against closed forms: the second time derivative of the
  reference's point pose along q + qd s, and a spinning free body's centripetal acceleration.
- The pinned-rigid-body reference against the recursive Newton-Euler one (two formulations
  that share nothing).
- The continuous closed loop with today's law follows the linkage driven by the hand alone
  exactly (e = x_VM - x_h obeys a homogeneous stable equation from e(0) = 0), and without
  J_h_dot qd it does not: the law's own error, with no sampling in it.
- The project, on a subset of `benchmarks.holds`' family, against the linkage alone: within
  the goal of 0.5 mm RMS over 5 s at 60 Hz away from singularities, where seed 000's law as
  printed is off by more than the goal, and by what the continuous law alone predicts.
- Held at the singularity: the local model's drift <= 0.1 mm, impedance control's >= 100x.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from haptic_local_model.benchmarks.holds import (
    SEED_OFFSET,
    TARGET_RMS_MM,
    HoldCase,
    case_scene,
    distance_mm,
    family,
    measure_case,
    rms,
    run_case,
    steady_drift_mm,
)
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.kinematics import (
    PRISMATIC_X,
    PRISMATIC_Y,
    REVOLUTE,
    chain_record,
    link_frames,
    point_bias_acceleration,
    point_on_link,
)
from haptic_local_model.shared.reference import ChainSpec, Hold, point_pose, simulate
from haptic_local_model.shared.reference_bodies import simulate_bodies
from haptic_local_model.shared.reference_loop import LoopGains, simulate_loop

SPEC = ChainSpec(
    base=(0.0, 0.0), lengths=(0.042, 0.042, 0.03), masses=(3.0, 3.0, 1.0),
    inertias=(0.015, 0.015, 0.005), com_offsets=((0.021, 0.0), (0.021, 0.0), (0.015, 0.0)),
)  # fmt: skip
Q0 = np.array([np.pi / 2, -np.pi / 2, -np.pi / 2])


def kernel_jdot_qd(types, lengths, q, qd, link, r):
    n = len(q)
    frame_pos = np.zeros((n, 2))
    frame_angle = np.zeros(n)
    chain = chain_record(
        np.array(types), np.array(lengths), np.zeros(2), 0.0, np.zeros(n), np.zeros(n),
        np.zeros((n, 2)),
    )[0]  # fmt: skip
    link_frames(chain, q, n, frame_pos, frame_angle)
    p = np.zeros(2)
    point_on_link(frame_pos, frame_angle, link, np.array(r), p)
    out = np.zeros(3)
    point_bias_acceleration(chain, frame_pos, n, link, p[0], p[1], qd, out)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_jdot_qd_is_the_points_acceleration_at_zero_qdd(seed: int) -> None:
    """d^2/ds^2 pose(q + qd s) at s = 0 (the reference's forward kinematics, fourth-order
    central differences) for random revolute chains, holds and rates."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 5))
    lengths = tuple(rng.uniform(0.02, 0.1, n))
    spec = ChainSpec(
        base=(0.0, 0.0), lengths=lengths, masses=(1.0,) * n, inertias=(0.01,) * n,
        com_offsets=((0.0, 0.0),) * n,
    )  # fmt: skip
    q = rng.uniform(-np.pi, np.pi, n)
    qd = rng.uniform(-5.0, 5.0, n)
    link = int(rng.integers(0, n))
    r = rng.uniform(-0.05, 0.05, 2)
    h = 1e-3
    pose = [point_pose(spec, q + k * h * qd, link, r) for k in (-2, -1, 0, 1, 2)]
    expected = (-pose[0] + 16 * pose[1] - 30 * pose[2] + 16 * pose[3] - pose[4]) / (12 * h * h)
    got = kernel_jdot_qd([REVOLUTE] * n, lengths, q, qd, link, r)
    scale = float(np.abs(expected[:2]).max())
    np.testing.assert_allclose(got[:2], expected[:2], rtol=0, atol=1e-6 * scale)
    assert got[2] == 0.0


def test_jdot_qd_of_a_spinning_free_body_is_centripetal() -> None:
    """A free body (x, y, theta) translating and spinning at w: a point r off its frame
    accelerates at -w^2 R(theta) r, whatever the translation rate."""
    types = [PRISMATIC_X, PRISMATIC_Y, REVOLUTE]
    theta, w = 0.7, 3.0
    r = np.array([0.04, -0.01])
    q = np.array([0.1, -0.2, theta])
    qd = np.array([0.5, -0.3, w])
    got = kernel_jdot_qd(types, [0.0, 0.0, 0.0], q, qd, 2, r)
    c, s = np.cos(theta), np.sin(theta)
    expected = -(w**2) * np.array([c * r[0] - s * r[1], s * r[0] + c * r[1]])
    np.testing.assert_allclose(got[:2], expected, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize(
    ("link", "point", "wrench"),
    [
        (2, (0.015, 0.0), (0.4, 0.0, 0.0)),
        (1, (0.03, 0.01), (0.0, 0.4, 0.002)),
        (0, (0.042, 0.0), (0.3, 0.3, 0.0)),
    ],
)
def test_pinned_bodies_agree_with_newton_euler(link, point, wrench) -> None:
    t = np.linspace(0.0, 3.0, 301)
    a = simulate(SPEC, Q0, np.zeros(3), Hold(np.array(wrench), link, np.array(point)), 3.0, t)
    b = simulate_bodies(SPEC, Q0, np.zeros(3), Hold(wrench, link, point), 3.0, t)
    assert float(distance_mm(a.pose, a.pose[:1].repeat(len(t), 0)).max()) > 5.0  # it moved
    assert float(distance_mm(a.pose, b.pose).max()) < 1e-5
    assert float(np.abs(a.pose[:, 2] - b.pose[:, 2]).max()) < 1e-8
    assert b.constraint_error < 1e-9


GAINS = LoopGains(
    coordination_stiffness=(100.0, 100.0, 0.5), coordination_damping=(70.0, 70.0, 0.375)
)


@pytest.mark.slow
def test_the_continuous_law_follows_the_hand_driven_linkage_only_with_jdot_qd() -> None:
    """Distal hold pushed diagonally: with J_h_dot qd the closed loop is the linkage alone
    to solver tolerance; without, it is off by millimetres."""
    t = np.linspace(0.0, 5.0, 501)
    link, point, wrench = 2, (0.015, 0.01), (-0.28, 0.28, 0.0)
    hold = Hold(np.array(wrench), link, np.array(point))
    alone = simulate(SPEC, Q0, np.zeros(3), hold, 5.0, t)
    exact = simulate_loop(SPEC, Q0, hold, GAINS, 5.0, t)
    printed = simulate_loop(SPEC, Q0, hold, dataclasses.replace(GAINS, jdot_qd=False), 5.0, t)
    assert float(distance_mm(exact.vm_pose, alone.pose).max()) < 1e-5
    assert float(distance_mm(exact.device_pose, alone.pose).max()) < 1e-5
    assert rms(distance_mm(printed.vm_pose, alone.pose)) > 1.0


@pytest.fixture(scope="module")
def quick_family() -> list[dict]:
    scene = load_scene("linkage_distal")
    return [measure_case(scene, case, 5.0, (60.0,)) for case in family(scene, quick=True)]


@pytest.mark.slow
def test_holds_away_from_singularities_are_within_the_goal(quick_family) -> None:
    away = [r for r in quick_family if not r["singular"]]
    assert len(away) >= 5, [r["case"] for r in quick_family]
    for row in away:
        assert row["rms_mm"]["60"] <= TARGET_RMS_MM, row
        assert row["travel_mm"] > 5.0, row  # the hold moved: the error is over a real path


@pytest.mark.slow
def test_every_hold_follows_the_hand_driven_linkage(quick_family) -> None:
    """Also the holds that pass near rank loss (the distal ones, pushed toward a straight
    arm): within the same goal."""
    for row in quick_family:
        assert row["rms_mm"]["60"] <= TARGET_RMS_MM, row


@pytest.mark.slow
def test_the_printed_law_misses_where_the_continuous_law_says_it_must(quick_family) -> None:
    """Seed 000's law as printed is off by more than the goal on several holds, and by
    what the same law with exact dynamics and no sampling gives (within 15%): the error is
    the law's, not the sim rate's or the frozen model's."""
    missed = [r for r in quick_family if r["rms_old_mm"] > TARGET_RMS_MM]
    assert len(missed) >= 3, quick_family
    for row in missed:
        assert row["rms_old_mm"] == pytest.approx(row["law_old_mm"], rel=0.15), row
        assert row["law_mm"] < 1e-5, row


@pytest.mark.parametrize("pull_deg", [0.0, 10.0])
def test_a_hold_at_the_singularity_drifts_under_impedance_control_only(pull_deg: float) -> None:
    """The arm started straight and pulled along itself at its distal COM stays at the
    singularity; the device starts 5 mm, 3 mm off. The resisted direction's offset is pulled
    back by the joint penalties (local model) and by nothing under impedance control."""
    scene = load_scene("linkage_distal")
    lk = scene.tool_linkage
    a = lk.initial_angles[0] + np.radians(pull_deg)
    case = HoldCase(
        2, "com", tuple(lk.com_offsets[2]), "pull", (0.4 * np.cos(a), 0.4 * np.sin(a), 0.0)
    )
    straight = (lk.initial_angles[0], 0.0, 0.0)
    drift = {}
    for method in ("local_model", "impedance_only"):
        s = case_scene(
            scene, case, 60.0, method=method, offset=SEED_OFFSET, initial_angles=straight
        )
        ticks = run_case(s, case, 5.0)
        assert (ticks["n_resisted"][-1000:] > 0).all()  # held at the singularity throughout
        drift[method] = steady_drift_mm(ticks)
    assert drift["local_model"] <= 0.1, drift
    assert drift["impedance_only"] >= 100.0 * drift["local_model"], drift
