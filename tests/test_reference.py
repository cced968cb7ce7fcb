"""Checks of the independent planar-chain reference against closed forms and conservation laws."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import simpson
from scipy.optimize import brentq

from haptic_local_model.shared.reference import (
    ChainSpec,
    Hold,
    bias_forces,
    forward_dynamics,
    inverse_dynamics,
    mass_matrix,
    point_jacobian,
    point_pose,
    simulate,
)

GRAVITY = (0.0, -9.81)

# Machine-precision algebra on O(1e-2) matrix entries: a few ulps of accumulated round-off.
ALGEBRA_RTOL = 1e-12
ALGEBRA_ATOL = 1e-14
# Conservation over 2 s with rtol=1e-10 DOP853: the brief's budget, about 100x the integrator error.
ENERGY_RTOL = 1e-8
# Work by Simpson quadrature of F.v_P over 4001 samples: observed ~1e-11, O(h^4) plus solver error.
WORK_RTOL = 1e-9
# Central differences with step 1e-6 rad: truncation O(h^2) ~ 1e-13 m, round-off ~ 1e-11 m.
FD_STEP = 1e-6
FD_ATOL = 1e-8
# Brief's budget for the small-angle period; amplitude 0.01 rad shifts the period by ~6e-6.
PERIOD_RTOL = 1e-3
PENDULUM_AMPLITUDE = 0.01
# Closed-form trajectories sampled from a rtol=1e-10 integration.
TRAJECTORY_RTOL = 1e-8


def haptic_chain(gravity: tuple[float, float] = (0.0, 0.0)) -> ChainSpec:
    """The 3-link haptic device from the brief: COMs at mid-link."""
    lengths = (0.042, 0.042, 0.030)
    return ChainSpec(
        base=(0.01, -0.02),
        lengths=lengths,
        masses=(3.0, 3.0, 1.0),
        inertias=(0.015, 0.015, 0.005),
        com_offsets=tuple((0.5 * length, 0.0) for length in lengths),
        gravity=gravity,
    )


def skewed_chain(gravity: tuple[float, float] = (0.0, 0.0)) -> ChainSpec:
    """A 3-link chain with off-axis COMs and a rotated base, exercising every geometry term."""
    return ChainSpec(
        base=(0.1, 0.2),
        lengths=(0.3, 0.2, 0.15),
        masses=(1.5, 1.0, 0.6),
        inertias=(0.012, 0.006, 0.002),
        com_offsets=((0.12, 0.02), (0.09, -0.015), (0.05, 0.03)),
        gravity=gravity,
        base_angle=0.4,
    )


def single_link(gravity: tuple[float, float] = (0.0, 0.0), base_angle: float = 0.0) -> ChainSpec:
    """One link of the haptic device: m = 3 kg, I = 0.015 kg m^2, COM at mid-link."""
    return ChainSpec(
        base=(0.0, 0.0),
        lengths=(0.042,),
        masses=(3.0,),
        inertias=(0.015,),
        com_offsets=((0.021, 0.0),),
        gravity=gravity,
        base_angle=base_angle,
    )


def pivot_inertia(spec: ChainSpec) -> float:
    """Inertia of a single link about its pivot (parallel-axis theorem)."""
    com = np.asarray(spec.com_offsets[0])
    return spec.inertias[0] + spec.masses[0] * float(com @ com)


def kinetic_energy(spec: ChainSpec, q: np.ndarray, qd: np.ndarray) -> float:
    """Kinetic energy 0.5 qd^T D(q) qd."""
    return 0.5 * float(qd @ mass_matrix(spec, q) @ qd)


def potential_energy(spec: ChainSpec, q: np.ndarray) -> float:
    """Gravitational potential -sum m_i g . c_i, COM positions from point_pose (not RNEA)."""
    g = np.asarray(spec.gravity)
    return -sum(
        m * float(g @ point_pose(spec, q, i, c)[:2])
        for i, (m, c) in enumerate(zip(spec.masses, spec.com_offsets, strict=True))
    )


@pytest.mark.parametrize("spec", [haptic_chain(), skewed_chain()], ids=["haptic", "skewed"])
def test_mass_matrix_is_symmetric_positive_definite(spec: ChainSpec) -> None:
    rng = np.random.default_rng(1234)
    for q in rng.uniform(-np.pi, np.pi, size=(50, spec.n)):
        d = mass_matrix(spec, q)
        np.testing.assert_allclose(d, d.T, rtol=ALGEBRA_RTOL, atol=ALGEBRA_ATOL)
        assert np.linalg.eigvalsh(d).min() > 0.0


TWO_LINK = dict(l1=0.3, lc1=0.12, m1=2.0, i1=0.02, l2=0.25, lc2=0.1, m2=1.2, i2=0.01)


def two_link_spec(gravity: tuple[float, float]) -> ChainSpec:
    """Two-link arm with COMs on the link axes, matching the textbook closed forms."""
    p = TWO_LINK
    return ChainSpec(
        base=(0.0, 0.0),
        lengths=(p["l1"], p["l2"]),
        masses=(p["m1"], p["m2"]),
        inertias=(p["i1"], p["i2"]),
        com_offsets=((p["lc1"], 0.0), (p["lc2"], 0.0)),
        gravity=gravity,
    )


def test_mass_matrix_matches_two_link_closed_form() -> None:
    p = TWO_LINK
    spec = two_link_spec((0.0, 0.0))
    rng = np.random.default_rng(7)
    for q in rng.uniform(-np.pi, np.pi, size=(20, 2)):
        c2 = np.cos(q[1])
        d11 = (
            p["m1"] * p["lc1"] ** 2
            + p["m2"] * (p["l1"] ** 2 + p["lc2"] ** 2 + 2 * p["l1"] * p["lc2"] * c2)
            + p["i1"]
            + p["i2"]
        )
        d12 = p["m2"] * (p["lc2"] ** 2 + p["l1"] * p["lc2"] * c2) + p["i2"]
        d22 = p["m2"] * p["lc2"] ** 2 + p["i2"]
        expected = np.array([[d11, d12], [d12, d22]])
        np.testing.assert_allclose(
            mass_matrix(spec, q), expected, rtol=ALGEBRA_RTOL, atol=ALGEBRA_ATOL
        )


def test_bias_matches_two_link_closed_form() -> None:
    p = TWO_LINK
    g = 9.81
    spec = two_link_spec((0.0, -g))
    rng = np.random.default_rng(8)
    for q, qd in zip(rng.uniform(-np.pi, np.pi, (20, 2)), rng.uniform(-5, 5, (20, 2)), strict=True):
        h = -p["m2"] * p["l1"] * p["lc2"] * np.sin(q[1])
        coriolis = np.array([h * (2 * qd[0] * qd[1] + qd[1] ** 2), -h * qd[0] ** 2])
        gravity = g * np.array(
            [
                (p["m1"] * p["lc1"] + p["m2"] * p["l1"]) * np.cos(q[0])
                + p["m2"] * p["lc2"] * np.cos(q[0] + q[1]),
                p["m2"] * p["lc2"] * np.cos(q[0] + q[1]),
            ]
        )
        np.testing.assert_allclose(
            bias_forces(spec, q, qd), coriolis + gravity, rtol=ALGEBRA_RTOL, atol=1e-12
        )


def test_mass_matrix_matches_com_jacobians_with_off_axis_coms() -> None:
    """D = sum_i m_i Jv_i^T Jv_i + I_i Jw_i^T Jw_i, built from the analytic COM Jacobians."""
    spec = skewed_chain()
    rng = np.random.default_rng(9)
    for q in rng.uniform(-np.pi, np.pi, size=(20, spec.n)):
        expected = np.zeros((spec.n, spec.n))
        for i in range(spec.n):
            jac = point_jacobian(spec, q, i, spec.com_offsets[i])
            expected += spec.masses[i] * jac[:2].T @ jac[:2] + spec.inertias[i] * np.outer(
                jac[2], jac[2]
            )
        np.testing.assert_allclose(
            mass_matrix(spec, q), expected, rtol=ALGEBRA_RTOL, atol=ALGEBRA_ATOL
        )


def test_forward_dynamics_inverts_rnea() -> None:
    spec = skewed_chain(GRAVITY)
    rng = np.random.default_rng(10)
    q, qd, tau = rng.normal(size=(3, spec.n))
    qdd = forward_dynamics(spec, q, qd, tau)
    np.testing.assert_allclose(inverse_dynamics(spec, q, qd, qdd), tau, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("make_spec", [haptic_chain, skewed_chain], ids=["haptic", "skewed"])
def test_kinetic_energy_conserved_without_gravity(make_spec) -> None:
    spec = make_spec()
    t = np.linspace(0.0, 2.0, 201)
    sol = simulate(
        spec, [0.3, -0.5, 0.8], [2.0, -3.0, 5.0], Hold(np.zeros(3), 2, [0.02, 0.0]), 2.0, t
    )
    energy = np.array([kinetic_energy(spec, q, qd) for q, qd in zip(sol.q, sol.qd, strict=True)])
    np.testing.assert_allclose(energy, energy[0], rtol=ENERGY_RTOL, atol=0.0)


@pytest.mark.slow
@pytest.mark.parametrize("make_spec", [haptic_chain, skewed_chain], ids=["haptic", "skewed"])
def test_total_energy_conserved_with_gravity(make_spec) -> None:
    spec = make_spec(GRAVITY)
    t = np.linspace(0.0, 2.0, 201)
    sol = simulate(
        spec, [0.3, -0.5, 0.8], [1.0, -2.0, 3.0], Hold(np.zeros(3), 2, [0.02, 0.0]), 2.0, t
    )
    kinetic = np.array([kinetic_energy(spec, q, qd) for q, qd in zip(sol.q, sol.qd, strict=True)])
    total = kinetic + np.array([potential_energy(spec, q) for q in sol.q])
    # Relative to the kinetic energy scale: the potential's zero is arbitrary.
    assert np.ptp(kinetic) > 0.1 * kinetic.max(), "gravity should exchange energy"
    assert np.abs(total - total[0]).max() <= ENERGY_RTOL * kinetic.max()


def test_kinetic_energy_change_equals_hand_work() -> None:
    spec = haptic_chain()
    wrench = np.array([1.5, -0.7, 0.02])
    link, r = 2, np.array([0.03, 0.005])
    t = np.linspace(0.0, 0.5, 4001)
    sol = simulate(spec, [0.3, -0.5, 0.8], [1.0, 0.0, -1.0], Hold(wrench, link, r), 0.5, t)

    power = np.array(
        [
            wrench @ point_jacobian(spec, q, link, r) @ qd
            for q, qd in zip(sol.q, sol.qd, strict=True)
        ]
    )
    work = simpson(power, x=sol.t)
    delta_kinetic = kinetic_energy(spec, sol.q[-1], sol.qd[-1]) - kinetic_energy(
        spec, sol.q[0], sol.qd[0]
    )
    assert abs(work) > 1e-3, "the hand should do appreciable work"
    assert delta_kinetic == pytest.approx(work, rel=WORK_RTOL)
    # A constant wrench is conservative: its work is F . (P_end - P_start) + tau * delta phi.
    assert delta_kinetic == pytest.approx(wrench @ (sol.pose[-1] - sol.pose[0]), rel=ENERGY_RTOL)


@pytest.mark.parametrize("link", [0, 1, 2])
def test_point_jacobian_matches_finite_differences(link: int) -> None:
    spec = skewed_chain()
    r = np.array([0.07, -0.04])
    rng = np.random.default_rng(11 + link)
    for q in rng.uniform(-np.pi, np.pi, size=(10, spec.n)):
        numeric = np.column_stack(
            [
                (
                    point_pose(spec, q + FD_STEP * e, link, r)
                    - point_pose(spec, q - FD_STEP * e, link, r)
                )
                / (2 * FD_STEP)
                for e in np.eye(spec.n)
            ]
        )
        np.testing.assert_allclose(point_jacobian(spec, q, link, r), numeric, rtol=0, atol=FD_ATOL)


def test_point_pose_of_chain_tip() -> None:
    spec = skewed_chain()
    q = np.array([0.2, -0.7, 1.1])
    phi = spec.base_angle + np.cumsum(q)
    tip = np.asarray(spec.base) + sum(
        length * np.array([np.cos(a), np.sin(a)])
        for length, a in zip(spec.lengths, phi, strict=True)
    )
    expected = np.array([tip[0], tip[1], phi[2]])
    np.testing.assert_allclose(point_pose(spec, q, 2, [0.15, 0.0]), expected, rtol=ALGEBRA_RTOL)


def test_pendulum_small_angle_period() -> None:
    spec = single_link(GRAVITY, base_angle=-np.pi / 2)
    g = -GRAVITY[1]
    expected_period = 2 * np.pi * np.sqrt(pivot_inertia(spec) / (spec.masses[0] * g * 0.021))
    t_end = 5.2 * expected_period
    t = np.linspace(0.0, t_end, 2001)
    sol = simulate(spec, [PENDULUM_AMPLITUDE], [0.0], Hold(np.zeros(3), 0, [0.0, 0.0]), t_end, t)

    def swing(time: float) -> float:
        return float(sol.pose_at(time)[2] + np.pi / 2)

    angle = sol.q[:, 0]
    downward = np.flatnonzero((angle[:-1] > 0) & (angle[1:] <= 0))
    crossings = [brentq(swing, sol.t[k], sol.t[k + 1], xtol=1e-14) for k in downward]
    assert len(crossings) >= 5
    period = (crossings[-1] - crossings[0]) / (len(crossings) - 1)
    assert period == pytest.approx(expected_period, rel=PERIOD_RTOL)


def test_pure_hand_torque_spins_link_quadratically() -> None:
    spec = single_link()
    torque = 0.01
    t = np.linspace(0.0, 0.5, 51)
    sol = simulate(spec, [0.0], [0.0], Hold([0.0, 0.0, torque], 0, [0.03, 0.01]), 0.5, t)
    expected = torque * t**2 / (2 * pivot_inertia(spec))
    np.testing.assert_allclose(sol.q[:, 0], expected, rtol=TRAJECTORY_RTOL, atol=1e-14)
    np.testing.assert_allclose(sol.pose[:, 2], expected, rtol=TRAJECTORY_RTOL, atol=1e-14)
    mid = 0.237
    assert sol.pose_at(mid)[2] == pytest.approx(
        torque * mid**2 / (2 * pivot_inertia(spec)), rel=TRAJECTORY_RTOL
    )


def test_joint_damping_decays_spin_exponentially() -> None:
    spec = single_link()
    b, omega0 = 0.004, 3.0
    t = np.linspace(0.0, 2.0, 41)
    sol = simulate(spec, [0.0], [omega0], Hold(np.zeros(3), 0, [0.0, 0.0]), 2.0, t, damping=[b])
    expected = omega0 * np.exp(-b * t / pivot_inertia(spec))
    np.testing.assert_allclose(sol.qd[:, 0], expected, rtol=TRAJECTORY_RTOL)


def test_callable_wrench_and_pose_at_shapes() -> None:
    spec = haptic_chain()
    calls: list[float] = []

    def spring(time: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        calls.append(time)
        tip = point_pose(spec, q, 2, [0.03, 0.0])
        return np.array([-50.0 * tip[0], -50.0 * tip[1], 0.0])

    t = np.linspace(0.0, 0.3, 7)
    sol = simulate(spec, [0.3, -0.5, 0.8], [0.0, 0.0, 0.0], Hold(spring, 2, [0.03, 0.0]), 0.3, t)
    assert calls, "callable wrench was never evaluated"
    assert sol.q.shape == sol.qd.shape == (7, 3) and sol.pose.shape == (7, 3)
    assert sol.pose_at(0.1).shape == (3,)
    np.testing.assert_allclose(sol.pose_at(sol.t), sol.pose, rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError):
        sol.pose_at(0.31)
