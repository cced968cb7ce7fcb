"""Twin-pantograph device model: kinematics, statics, dynamics, sensors (seed 001 §4)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog, minimize_scalar

from haptic_local_model.device_models.base import (
    FAULT_NONE,
    FAULT_SATURATED,
    FAULT_SINGULAR,
    FAULT_WORKSPACE,
    SENSOR_DTYPE,
)
from haptic_local_model.device_models.twin_pantograph import (
    FAULT_INVALID_COMMAND,
    FrictionSection,
    SimulationSection,
    TwinPantograph,
    TwinPantographConfig,
    pack_parameters,
)
from haptic_local_model.device_models.twin_pantograph.dynamics import (
    christoffel_matrix,
    inertia_gradient,
    task_inertia,
)
from haptic_local_model.device_models.twin_pantograph.kinematics import (
    forward_kinematics,
    inverse_kinematics,
    motor_jacobian,
    pose_faults,
    singularity_measures,
)
from haptic_local_model.device_models.twin_pantograph.torques import resolve_torques

CONFIG_PATH = (
    Path(__file__).resolve().parent.parent / "configs" / "devices" / "twin_pantograph.toml"
)

#: FK(IK(x)) is closed-form trigonometry: only round-off remains (brief: 1e-9).
ROUND_TRIP_TOL = 1e-9
#: Central differences with step 1e-7 have error ~1e-16/1e-7 * |q| + 1e-14 * |q'''|, < 1e-8;
#: Jacobian entries are 1-70 rad/m.
JACOBIAN_FD_STEP = 1e-7
JACOBIAN_FD_TOL = 1e-6
#: The redundancy resolution must reproduce a feasible wrench to this (N, N m; brief).
WRENCH_EXACT_TOL = 1e-9
#: Kinetic energy from link velocities by central differences (step 1e-6): relative error
#: ~1e-10; 1e-7 leaves room for round-off in the sums.
KINETIC_ENERGY_REL_TOL = 1e-7
#: Semi-implicit Euler's energy error is first order in the substep h; the probe run with
#: this twist showed 7e-6 over 50 ms at h = 1e-4 s, so allow 0.2 * h / (1 s) (3x margin).
ENERGY_DRIFT_PER_SUBSTEP_S = 0.2
#: Noise std estimated from N = 20000 samples has ~1/sqrt(2N) = 0.5 % spread: 10 % (brief).
NOISE_STD_REL_TOL = 0.10


@pytest.fixture(scope="module")
def config() -> TwinPantographConfig:
    return TwinPantographConfig.from_toml_file(str(CONFIG_PATH))


@pytest.fixture(scope="module")
def params(config: TwinPantographConfig) -> np.ndarray:
    return pack_parameters(config)


def frictionless(config: TwinPantographConfig, max_substep_s: float = 1e-4) -> TwinPantographConfig:
    return dataclasses.replace(
        config,
        friction=FrictionSection((0.0,) * 4, (0.0,) * 4, 0.05),
        simulation=SimulationSection(max_substep_s=max_substep_s),
    )


def workspace_grid(config: TwinPantographConfig, n: int) -> list[np.ndarray]:
    lo, hi = config.workspace.workspace_min, config.workspace.workspace_max
    axes = [np.linspace(lo[c], hi[c], n) for c in range(3)]
    return [np.array(p) for p in itertools.product(*axes)]


def ik(params: np.ndarray, pose: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    assert inverse_kinematics(params, pose, q)
    return q


def jacobian(params: np.ndarray, pose: np.ndarray) -> np.ndarray:
    jac = np.empty((4, 3))
    assert motor_jacobian(params, pose, jac)
    return jac


def fk_jacobian(params: np.ndarray, q: np.ndarray) -> np.ndarray:
    """dFK/dq (3 x 4) by central differences; FK is defined off the constraint too."""
    plus, minus = np.empty(3), np.empty(3)
    jac = np.empty((3, 4))
    for i in range(4):
        step = np.zeros(4)
        step[i] = JACOBIAN_FD_STEP
        assert forward_kinematics(params, q + step, plus)
        assert forward_kinematics(params, q - step, minus)
        jac[:, i] = (plus - minus) / (2 * JACOBIAN_FD_STEP)
    return jac


def inertia(params: np.ndarray, pose: np.ndarray) -> np.ndarray:
    m = np.empty((3, 3))
    assert task_inertia(params, pose, m)
    return m


# ----------------------------------------------------------------------------- config


def test_config_file_loads_and_limits_match(config: TwinPantographConfig) -> None:
    device = TwinPantograph(config)
    limits = device.limits()
    assert limits.max_wrench == config.actuators.max_wrench
    assert limits.workspace_min == config.workspace.workspace_min
    assert device.name == "twin_pantograph"


@pytest.mark.parametrize(
    ("mutate", "key", "problem"),
    [
        (lambda d: d["geometry"].update(spare_link_m=0.1), "geometry.spare_link_m", "unknown"),
        (lambda d: d["sensors"].pop("noise_seed"), "sensors.noise_seed", "missing"),
        (lambda d: d["geometry"].update(handle_length_m="long"), "handle_length_m", "expected"),
        (lambda d: d["actuators"].update(torque_limit_nm=[0.4, 0.4]), "torque_limit_nm", "4"),
        (
            lambda d: d["actuators"].update(torque_limit_nm=[0.4, -1, 0.4, 0.4]),
            "torque_limit_nm[1]",
            "within",
        ),
        (lambda d: d["sensors"].update(encoder_counts_per_rev=2.5), "encoder_counts", "int"),
        (lambda d: d.update(extra_table={}), "extra_table", "unknown"),
        (lambda d: d["workspace"].update(workspace_max=[0.2, 0.025, 0.4]), "workspace", "reach"),
    ],
)
def test_config_errors_name_file_key_and_problem(mutate, key: str, problem: str) -> None:
    import tomllib

    data = tomllib.loads(CONFIG_PATH.read_text())
    mutate(data)
    with pytest.raises(ValueError) as err:
        TwinPantographConfig.from_toml_dict(data, "devices/pantograph_test.toml")
    message = str(err.value)
    assert "devices/pantograph_test.toml" in message
    assert key in message
    assert problem in message


# ------------------------------------------------------------------------- kinematics


def test_fk_ik_round_trip_over_workspace_grid(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    pose_back = np.empty(3)
    q_back = np.empty(4)
    for pose in workspace_grid(config, 9):
        q = ik(params, pose)
        assert forward_kinematics(params, q, pose_back)
        np.testing.assert_allclose(pose_back, pose, rtol=0, atol=ROUND_TRIP_TOL)
        assert inverse_kinematics(params, pose_back, q_back)
        np.testing.assert_allclose(q_back, q, rtol=0, atol=ROUND_TRIP_TOL)


def test_ik_picks_the_configured_elbow_branch(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    p = params[0]
    for pose in workspace_grid(config, 5):
        q = ik(params, pose)
        u = np.array([math.cos(pose[2]), math.sin(pose[2])])
        ends = (pose[:2] - 0.5 * p["handle_length"] * u, pose[:2] + 0.5 * p["handle_length"] * u)
        for i in range(4):
            base = p["base"][i]
            elbow = base + p["proximal_length"][i] * np.array([math.cos(q[i]), math.sin(q[i])])
            to_end = ends[i // 2] - base
            to_elbow = elbow - base
            side = np.sign(to_end[0] * to_elbow[1] - to_end[1] * to_elbow[0])
            assert side == p["elbow_sign"][i]
            assert np.linalg.norm(ends[i // 2] - elbow) == pytest.approx(p["distal_length"][i])


def test_unreachable_pose_is_refused(params: np.ndarray) -> None:
    assert not inverse_kinematics(params, np.array([0.0, 0.12, 0.0]), np.empty(4))


def test_motor_jacobian_matches_central_differences(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    for pose in workspace_grid(config, 4):
        fd = np.empty((4, 3))
        for c in range(3):
            step = np.zeros(3)
            step[c] = JACOBIAN_FD_STEP
            fd[:, c] = (ik(params, pose + step) - ik(params, pose - step)) / (2 * JACOBIAN_FD_STEP)
        np.testing.assert_allclose(jacobian(params, pose), fd, rtol=0, atol=JACOBIAN_FD_TOL)


def test_forward_kinematics_jacobian_inverts_motor_jacobian(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    """FK(IK(x)) = x, so dFK/dq times Jm = I."""
    for pose in workspace_grid(config, 3):
        fk_jac = fk_jacobian(params, ik(params, pose))
        np.testing.assert_allclose(fk_jac @ jacobian(params, pose), np.eye(3), atol=1e-6)


# ---------------------------------------------------------------- singularity / workspace


def test_parallel_singularity_is_detected_where_distal_links_align(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    """Below the box (handle lowered toward the motors) each pantograph's distal links pass
    through collinear: Jm loses rank there and FAULT_SINGULAR must be raised."""
    measures = np.empty(2)

    def distal_sine(y: float) -> float:
        assert singularity_measures(params, np.array([0.0, y, 0.0]), measures)
        return float(measures[0])

    found = minimize_scalar(distal_sine, bounds=(-0.09, -0.07), method="bounded")
    singular_pose = np.array([0.0, found.x, 0.0])
    assert distal_sine(found.x) < 1e-4
    fault = pose_faults(params, singular_pose, measures)
    assert fault & FAULT_SINGULAR
    sigma_home = np.linalg.svd(jacobian(params, np.zeros(3)), compute_uv=False)[-1]
    sigma_sing = np.linalg.svd(jacobian(params, singular_pose), compute_uv=False)[-1]
    assert sigma_sing < 1e-3 * sigma_home
    # The flag clears once the links are asin(min_distal_sine) away from collinear.
    assert distal_sine(-0.06) > config.workspace.min_distal_sine
    assert not pose_faults(params, np.array([0.0, -0.06, 0.0]), measures) & FAULT_SINGULAR

    device = TwinPantograph(config)
    device.reset(singular_pose)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_SINGULAR


def test_reach_measure_and_workspace_faults(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    p = params[0]
    measures = np.empty(2)
    assert pose_faults(params, np.zeros(3), measures) == FAULT_NONE
    # Reach margin against an independent computation for handle poses straight up.
    for y in (0.0, 0.05, 0.08):
        pose = np.array([0.0, y, 0.0])
        singularity_measures(params, pose, measures)
        half = 0.5 * p["handle_length"]
        ends = [np.array([-half, y]), np.array([half, y])]
        margins = []
        for i in range(4):
            r = np.linalg.norm(ends[i // 2] - p["base"][i])
            l1, l2 = p["proximal_length"][i], p["distal_length"][i]
            margins += [r - abs(l1 - l2), l1 + l2 - r]
        assert measures[1] == pytest.approx(min(margins), abs=1e-12)
    # Reach fault alone: widen the box so that only the reach margin can trip.
    wide = params.copy()
    wide[0]["workspace_max"][1] = 1.0
    near_limit = np.array([0.0, 0.08, 0.0])  # 3.9 mm from full extension
    assert pose_faults(wide, near_limit, measures) == FAULT_WORKSPACE
    assert pose_faults(wide, np.array([0.0, 0.02, 0.0]), measures) == FAULT_NONE
    # Box fault alone.
    outside = np.array([config.workspace.workspace_max[0] + 0.002, 0.0, 0.0])
    assert pose_faults(params, outside, measures) == FAULT_WORKSPACE
    device = TwinPantograph(config)
    device.reset(outside)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_WORKSPACE


# ------------------------------------------------------------------ redundancy resolution


def lp_max_scale(jac: np.ndarray, wrench: np.ndarray, limit: np.ndarray) -> float:
    """Largest s in [0, 1] with Jm^T tau = s W and |tau| <= limit (independent LP)."""
    a_eq = np.hstack([jac.T, -wrench.reshape(3, 1)])
    bounds = [(-lim, lim) for lim in limit] + [(0.0, 1.0)]
    res = linprog(c=[0, 0, 0, 0, -1], A_eq=a_eq, b_eq=np.zeros(3), bounds=bounds, method="highs")
    assert res.status == 0
    return float(res.x[4])


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    pose_unit=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    direction=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    magnitude=st.floats(0.0, 1.5),
)
def test_redundancy_resolution_exact_when_feasible_and_within_limits(
    config: TwinPantographConfig, params: np.ndarray, pose_unit, direction, magnitude
) -> None:
    """Wrenches up to 1.5x the per-axis bound: ~80 % feasible by the minimum-norm torques,
    ~6 % feasible only with a null-space shift, the rest saturated."""
    lo = np.array(config.workspace.workspace_min)
    hi = np.array(config.workspace.workspace_max)
    pose = lo + 0.5 * (np.array(pose_unit) + 1.0) * (hi - lo)
    jac = jacobian(params, pose)
    wrench = magnitude * np.array(direction) * np.array(config.actuators.max_wrench)
    limit = np.array(config.actuators.torque_limit_nm)
    tau = np.empty(4)
    scale = resolve_torques(params, jac, wrench, tau)
    assert np.all(np.abs(tau) <= limit)
    np.testing.assert_allclose(jac.T @ tau, scale * wrench, rtol=0, atol=WRENCH_EXACT_TOL)
    # Feasible with a margin (LP with limits shrunk by 1e-6): exactly the commanded wrench.
    if lp_max_scale(jac, wrench, limit * (1 - 1e-6)) >= 1.0 - 1e-12:
        assert scale == 1.0
        np.testing.assert_allclose(jac.T @ tau, wrench, rtol=0, atol=WRENCH_EXACT_TOL)
    # Never claims an infeasible wrench, and keeps the largest feasible fraction.
    s_lp = lp_max_scale(jac, wrench, limit)
    assert scale <= s_lp + 1e-7
    assert scale >= s_lp - 1e-6


@pytest.mark.slow
def test_null_space_shift_keeps_a_feasible_wrench_exact(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    """Wrenches whose minimum-norm torques break a limit, yet are feasible: the internal
    (null-space) torque must make them exact rather than scaling them down."""
    rng = np.random.default_rng(4)
    limit = np.array(config.actuators.torque_limit_nm)
    lo = np.array(config.workspace.workspace_min)
    hi = np.array(config.workspace.workspace_max)
    tau = np.empty(4)
    shifted = 0
    for _ in range(2000):
        jac = jacobian(params, rng.uniform(lo, hi))
        wrench = rng.uniform(-1, 1, 3) * np.array(config.actuators.max_wrench)
        min_norm = np.linalg.pinv(jac.T) @ wrench
        if np.all(np.abs(min_norm) <= limit) or lp_max_scale(jac, wrench, limit * 0.999) < 1:
            continue
        shifted += 1
        assert resolve_torques(params, jac, wrench, tau) == 1.0
        assert np.all(np.abs(tau) <= limit)
        np.testing.assert_allclose(jac.T @ tau, wrench, rtol=0, atol=WRENCH_EXACT_TOL)
    assert shifted >= 20


def test_unsaturated_torques_are_the_minimum_norm_solution(params: np.ndarray) -> None:
    jac = jacobian(params, np.array([0.01, -0.005, 0.1]))
    wrench = np.array([1.0, -0.5, 0.02])
    tau = np.empty(4)
    assert resolve_torques(params, jac, wrench, tau) == 1.0
    np.testing.assert_allclose(tau, np.linalg.pinv(jac.T) @ wrench, rtol=1e-12, atol=1e-14)


def test_command_saturates_keeps_direction_and_rejects_nan(config: TwinPantographConfig) -> None:
    device = TwinPantograph(config)
    sensors = np.zeros(1, SENSOR_DTYPE)
    small = np.array([1.0, 0.5, 0.02])
    applied = device.command(small).copy()
    np.testing.assert_allclose(applied, small, atol=WRENCH_EXACT_TOL)
    device.read(sensors)
    assert sensors["fault"][0] == FAULT_NONE

    big = np.array([40.0, -30.0, 1.0])
    applied = device.command(big).copy()
    assert np.all(np.abs(applied) <= np.array(config.actuators.max_wrench) + 1e-12)
    ratio = applied / big
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    assert 0 < ratio[0] < 1
    assert np.all(np.abs(device.held_torques()) <= np.array(config.actuators.torque_limit_nm))
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_SATURATED

    applied = device.command(np.array([np.nan, 0.0, 0.0])).copy()
    np.testing.assert_array_equal(applied, 0.0)
    np.testing.assert_array_equal(device.held_torques(), 0.0)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_INVALID_COMMAND
    assert sensors["fault"][0] & FAULT_SATURATED

    device.command(small)
    device.safe_stop()
    np.testing.assert_array_equal(device.held_torques(), 0.0)


# --------------------------------------------------------------------------- dynamics


def kinetic_energy_from_link_motion(
    config: TwinPantographConfig, params: np.ndarray, pose: np.ndarray, twist: np.ndarray
) -> float:
    """Kinetic energy of every body from positions at pose +- eps twist (independent of the
    Jacobians used by task_inertia)."""
    eps = 1e-6
    g, m = config.geometry, config.inertia
    base = np.column_stack([g.motor_base_x_m, g.motor_base_y_m])

    def bodies(x: np.ndarray) -> list[tuple[np.ndarray, float]]:
        q = ik(params, x)
        u = np.array([math.cos(x[2]), math.sin(x[2])])
        ends = [x[:2] - 0.5 * g.handle_length_m * u, x[:2] + 0.5 * g.handle_length_m * u]
        out = [(x[:2].copy(), x[2])]
        for i in range(4):
            elbow = base[i] + g.proximal_length_m[i] * np.array([math.cos(q[i]), math.sin(q[i])])
            d = ends[i // 2] - elbow
            out.append((0.5 * (base[i] + elbow), q[i]))
            out.append((0.5 * (elbow + ends[i // 2]), math.atan2(d[1], d[0])))
        return out

    after, before = bodies(pose + eps * twist), bodies(pose - eps * twist)
    masses = [(m.handle_mass_kg, m.handle_inertia_kgm2)]
    for i in range(4):
        masses.append((m.proximal_mass_kg[i], m.proximal_inertia_kgm2[i] + m.rotor_inertia_kgm2[i]))
        masses.append((m.distal_mass_kg[i], m.distal_inertia_kgm2[i]))
    energy = 0.0
    for (c1, a1), (c0, a0), (mass, inertia_c) in zip(after, before, masses, strict=True):
        v = (c1 - c0) / (2 * eps)
        w = (a1 - a0) / (2 * eps)
        energy += 0.5 * mass * v @ v + 0.5 * inertia_c * w * w
    return energy


def test_task_inertia_is_spd_and_matches_link_kinetic_energy(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    rng = np.random.default_rng(3)
    for pose in workspace_grid(config, 5):
        m = inertia(params, pose)
        np.testing.assert_allclose(m, m.T, rtol=0, atol=1e-15)
        assert np.linalg.eigvalsh(m)[0] > 0
        twist = rng.normal(size=3) * np.array([0.1, 0.1, 1.0])
        expected = kinetic_energy_from_link_motion(config, params, pose, twist)
        assert 0.5 * twist @ m @ twist == pytest.approx(expected, rel=KINETIC_ENERGY_REL_TOL)


def test_christoffel_matrix_gives_the_lagrangian_velocity_forces(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    """C xd = Mdot xd - 1/2 d(xd^T M xd)/dx (from the Euler-Lagrange equations), checked
    with an independent, coarser finite difference; Mdot - 2C is skew-symmetric; and
    C = Mdot / 2 would be wrong here."""
    rng = np.random.default_rng(5)
    grad = np.empty((3, 3, 3))
    coriolis = np.empty((3, 3))
    h = 1e-5
    half_mdot_gap = 0.0
    for pose in workspace_grid(config, 3):
        twist = rng.normal(size=3) * np.array([0.2, 0.2, 2.0])
        assert inertia_gradient(params, pose, np.empty(3), np.empty((3, 3)), grad)
        christoffel_matrix(grad, twist, coriolis)
        m_dot = (inertia(params, pose + h * twist) - inertia(params, pose - h * twist)) / (2 * h)
        d_energy = np.empty(3)
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            d_energy[k] = twist @ (inertia(params, pose + e) - inertia(params, pose - e)) @ twist
            d_energy[k] /= 2 * h
        expected = m_dot @ twist - 0.5 * d_energy
        scale = np.abs(expected).max()
        np.testing.assert_allclose(coriolis @ twist, expected, rtol=0, atol=1e-6 * scale)
        n = np.einsum("kij,k->ij", grad, twist) - 2 * coriolis
        np.testing.assert_allclose(n, -n.T, rtol=0, atol=1e-12 * np.abs(n).max())
        half_mdot_gap = max(half_mdot_gap, np.abs(0.5 * m_dot @ twist - expected).max() / scale)
    assert half_mdot_gap > 0.05


def run_coasting(config: TwinPantographConfig, steps: int) -> tuple[float, np.ndarray]:
    device = TwinPantograph(config)
    device.state[0]["twist"][:] = [0.1, -0.08, 1.0]
    e0 = device.kinetic_energy()
    energies = []
    for _ in range(steps):
        device.advance(1e-3, np.zeros(3))
        energies.append(device.kinetic_energy())
    return e0, np.array(energies)


def test_kinetic_energy_conserved_without_friction(config: TwinPantographConfig) -> None:
    drifts = []
    for h in (1e-4, 5e-5):
        e0, energies = run_coasting(frictionless(config, h), 50)
        drift = np.abs(energies - e0).max() / e0
        assert drift < ENERGY_DRIFT_PER_SUBSTEP_S * h
        drifts.append(drift)
    # First order in h: halving the substep halves the drift.
    assert 1.6 < drifts[0] / drifts[1] < 2.5


def test_friction_only_dissipates(config: TwinPantographConfig) -> None:
    e0, energies = run_coasting(config, 50)
    assert np.all(np.diff(np.concatenate([[e0], energies])) <= 1e-12 * e0)
    assert energies[-1] < 0.99 * e0


def test_zero_order_hold_torques_drive_the_true_dynamics(config: TwinPantographConfig) -> None:
    """From rest, one substep gives twist = h M^-1 Jm^T tau at the true pose: torques are
    held through advance() and the applied wrench is close to the command."""
    device = TwinPantograph(frictionless(config))
    params = device.params
    wrench = np.array([2.0, 1.0, 0.05])
    device.command(wrench)
    tau = device.held_torques()
    h = 1e-4
    pose0 = np.zeros(3)
    expected = h * np.linalg.solve(inertia(params, pose0), jacobian(params, pose0).T @ tau)
    device.advance(h, np.zeros(3))
    twist = np.empty(3)
    device.true_state(np.empty(3), twist)
    np.testing.assert_allclose(twist, expected, rtol=1e-9)
    np.testing.assert_array_equal(device.held_torques(), tau)
    # Torques resolved at the quantised pose: the true wrench differs by quantisation only.
    np.testing.assert_allclose(jacobian(params, pose0).T @ tau, wrench, rtol=2e-3, atol=1e-4)


def test_stop_holds_the_handle_at_the_workspace_face(config: TwinPantographConfig) -> None:
    device = TwinPantograph(config)
    push = 5.0
    for _ in range(1500):
        device.advance(1e-3, np.array([push, 0.0, 0.0]))
    pose = np.empty(3)
    device.true_state(pose, np.empty(3))
    face = config.workspace.workspace_max[0]
    k = config.workspace.stop_stiffness[0]
    # Static penetration push / k, up to the (small) Coulomb friction of the motors.
    assert pose[0] - face == pytest.approx(push / k, rel=0.1)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_WORKSPACE


def test_overpowering_the_stops_holds_a_reachable_pose(config: TwinPantographConfig) -> None:
    """2 kN through the 2e4 N/m stop would put the handle 0.1 m beyond the box, out of the
    mechanism's reach: the simulation must stay finite, reachable, and report it."""
    device = TwinPantograph(config)
    sensors = np.zeros(1, SENSOR_DTYPE)
    pose = np.empty(3)
    for _ in range(200):
        device.advance(1e-3, np.array([0.0, 2000.0, 0.0]))
        device.true_state(pose, np.empty(3))
        assert np.all(np.isfinite(pose))
        assert inverse_kinematics(device.params, pose, np.empty(4))
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_WORKSPACE
    assert np.all(np.isfinite(sensors["inertia"][0]))


# ---------------------------------------------------------------------------- sensors


def test_reported_pose_is_fk_of_quantised_encoder_angles(
    config: TwinPantographConfig, params: np.ndarray
) -> None:
    resolution = 2 * math.pi / config.sensors.encoder_counts_per_rev
    device = TwinPantograph(config)
    sensors = np.zeros(1, SENSOR_DTYPE)
    rng = np.random.default_rng(9)
    lo = np.array(config.workspace.workspace_min)
    hi = np.array(config.workspace.workspace_max)
    expected = np.empty(3)
    errors = []
    for _ in range(200):
        pose = rng.uniform(lo, hi)
        device.reset(pose)
        device.read(sensors)
        counts = device.measured_motor_angles() / resolution
        np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)
        q = ik(params, pose)
        assert forward_kinematics(params, resolution * np.round(q / resolution), expected)
        np.testing.assert_allclose(sensors["pose"][0], expected, rtol=0, atol=1e-12)
        # Error bound: half a count on every motor through the FK Jacobian (first order).
        bound = 0.5 * resolution * np.abs(fk_jacobian(params, q)).sum(axis=1)
        err = np.abs(sensors["pose"][0] - pose)
        assert np.all(err <= 1.01 * bound + 1e-12)
        errors.append(err)
    fine = dataclasses.replace(
        config,
        sensors=dataclasses.replace(
            config.sensors, encoder_counts_per_rev=2 * config.sensors.encoder_counts_per_rev
        ),
    )
    fine_device = TwinPantograph(fine)
    rng = np.random.default_rng(9)
    fine_errors = []
    for _ in range(200):
        pose = rng.uniform(lo, hi)
        fine_device.reset(pose)
        fine_device.read(sensors)
        fine_errors.append(np.abs(sensors["pose"][0] - pose))
    ratio = np.sqrt(np.mean(np.square(errors))) / np.sqrt(np.mean(np.square(fine_errors)))
    assert 1.6 < ratio < 2.5


def test_twist_estimate_follows_a_coasting_handle(config: TwinPantographConfig) -> None:
    device = TwinPantograph(frictionless(config))
    device.state[0]["twist"][:] = [0.05, 0.02, 0.3]
    sensors = np.zeros(1, SENSOR_DTYPE)
    twist = np.empty(3)
    measured, true = [], []
    for _ in range(300):
        device.advance(1e-3, np.zeros(3))
        device.read(sensors)
        device.true_state(np.empty(3), twist)
        measured.append(sensors["twist"][0].copy())
        true.append(twist.copy())
    np.testing.assert_allclose(
        np.mean(measured[100:], axis=0), np.mean(true[100:], axis=0), rtol=0.05
    )


def test_force_sensor_noise_std_matches_config(config: TwinPantographConfig) -> None:
    device = TwinPantograph(config)
    sensors = np.zeros(1, SENSOR_DTYPE)
    hand = np.array([0.3, -0.2, 0.01])
    samples = []
    for _ in range(20000):
        device.advance(1e-3, hand)
        device.read(sensors)
        samples.append(sensors["hand_wrench"][0] - hand)
    assert sensors["has_force_sensor"][0] == 1
    std = np.std(samples, axis=0)
    expected = np.array(
        [config.sensors.force_noise_std_n] * 2 + [config.sensors.torque_noise_std_nm]
    )
    np.testing.assert_allclose(std, expected, rtol=NOISE_STD_REL_TOL)

    no_sensor = dataclasses.replace(
        config, sensors=dataclasses.replace(config.sensors, force_sensor=False)
    )
    device = TwinPantograph(no_sensor)
    device.advance(1e-3, hand)
    device.read(sensors)
    assert sensors["has_force_sensor"][0] == 0
    np.testing.assert_array_equal(sensors["hand_wrench"][0], 0.0)
