"""Maglev device model: levitation, stops, sensors, saturation, world mapping (seed 002)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.device_models.base import (
    FAULT_NONE,
    FAULT_SATURATED,
    FAULT_WORKSPACE,
    SENSOR_DTYPE,
)
from haptic_local_model.device_models.maglev import (
    FAULT_INVALID_COMMAND,
    DeviceWorldMap,
    Maglev,
    MaglevConfig,
)

CONFIG_PATH = Path(__file__).resolve().parent.parent / "configs" / "devices" / "maglev.toml"
DT = 1e-3  # haptic tick, s

#: Levitation hold tolerances under a planar load (brief): 0.1 mm and 0.1 deg.
Z_HOLD_TOL_M = 1e-4
ANGLE_HOLD_TOL_RAD = math.radians(0.1)
#: Static pitch deflection arm * F / K_pitch: the noise (~1e-6 rad) and eddy terms are small.
STATIC_DEFLECTION_REL_TOL = 0.05
#: Noise std from >= 5000 samples has ~1 % spread: 10 % (brief).
NOISE_STD_REL_TOL = 0.10
#: Static stop penetration is F / k_stop; the sensor-noise-driven jitter is ~um: 10 %.
STOP_PENETRATION_REL_TOL = 0.10


@pytest.fixture(scope="module")
def config() -> MaglevConfig:
    return MaglevConfig.from_toml_file(str(CONFIG_PATH))


class SpringHand:
    """A stiff hand holding the handle at the origin (the seed's fingertip grip)."""

    def __init__(self, stiffness: np.ndarray, damping: np.ndarray) -> None:
        self.stiffness, self.damping = stiffness, damping
        self.pose, self.twist = np.zeros(3), np.zeros(3)

    def wrench(self, device: Maglev) -> np.ndarray:
        device.true_state(self.pose, self.twist)
        return -self.stiffness * self.pose - self.damping * self.twist


# ----------------------------------------------------------------------------- config


def test_config_loads_and_limits_match_the_seed(config: MaglevConfig) -> None:
    device = Maglev(config)
    limits = device.limits()
    assert limits.max_wrench == (50.0, 50.0, 6.0)
    assert limits.max_rate_hz == 1400.0
    assert limits.workspace_max[0] == pytest.approx(0.0125)
    assert limits.workspace_max[2] == pytest.approx(math.radians(8.0), rel=1e-3)


def test_the_previous_spelling_of_the_limit_still_loads() -> None:
    """Logs of the previous release store peak_force_n / peak_torque_nm: they replay."""
    data = tomllib.loads(CONFIG_PATH.read_text())
    del data["actuators"]["max_wrench"]
    data["actuators"].update(peak_force_n=50.0, peak_torque_nm=6.0)
    old = MaglevConfig.from_toml_dict(data, "devices/maglev_old.toml")
    assert old.actuators.wrench_limit == (50.0, 50.0, 6.0)


@pytest.mark.parametrize(
    ("mutate", "key", "problem"),
    [
        (lambda d: d["flotor"].update(colour="red"), "flotor.colour", "unknown"),
        (lambda d: d["range"].pop("translation_m"), "range.translation_m", "missing"),
        (lambda d: d["flotor"].update(mass_kg=[0.6]), "flotor.mass_kg", "expected"),
        (lambda d: d["world_map"].update(rate_control="yes"), "rate_control", "bool"),
        (lambda d: d["world_map"].update(rate_threshold_fraction=1.5), "rate_threshold", "(0, 1)"),
        (lambda d: d["actuators"].update(max_wrench=[5.0, 5.0, 6.0]), "max_wrench", "levitate"),
        (lambda d: d["actuators"].update(peak_force_n=5.0), "peak_force_n", "old spelling"),
        (lambda d: d["actuators"].update(max_wrench=[50.0, 40.0, 6.0]), "max_wrench", "alike"),
        (lambda d: d.update(model="twin_pantograph"), "model", "maglev"),
    ],
)
def test_config_errors_name_file_key_and_problem(mutate, key: str, problem: str) -> None:
    data = tomllib.loads(CONFIG_PATH.read_text())
    mutate(data)
    with pytest.raises(ValueError) as err:
        MaglevConfig.from_toml_dict(data, "devices/maglev_test.toml")
    message = str(err.value)
    assert "devices/maglev_test.toml" in message
    assert key in message
    assert problem in message


# ------------------------------------------------------------------------- levitation


def test_levitation_holds_z_roll_pitch_under_a_planar_wrench(config: MaglevConfig) -> None:
    """10 N and 0.5 N m commanded, resisted by a stiff hand at the handle tip: the hand's
    force loads pitch through the handle arm, and the PD loop must hold it."""
    device = Maglev(config)
    hand = SpringHand(np.array([3000.0, 3000.0, 20.0]), np.array([60.0, 60.0, 0.2]))
    command = np.array([10.0, 0.0, 0.5])
    out_of_plane = np.empty(6)
    worst = np.zeros(3)
    for _ in range(1000):
        device.command(command)
        device.advance(DT, hand.wrench(device))
        device.out_of_plane(out_of_plane)
        worst = np.maximum(worst, np.abs(out_of_plane[3:]))
    assert worst[0] < Z_HOLD_TOL_M
    assert worst[1] < ANGLE_HOLD_TOL_RAD
    assert worst[2] < ANGLE_HOLD_TOL_RAD
    # Closed form: static pitch = arm * hand_fx / K_pitch, hand_fx = -10 N at equilibrium.
    k_pitch = config.flotor.inertia_kgm2[1] * (2 * math.pi * config.levitation.bandwidth_hz) ** 2
    expected = config.flotor.handle_height_m * -10.0 / k_pitch
    assert out_of_plane[5] == pytest.approx(expected, rel=STATIC_DEFLECTION_REL_TOL)


def test_levitation_holds_while_driven_into_the_stops(config: MaglevConfig) -> None:
    device = Maglev(config)
    out_of_plane = np.empty(6)
    worst = np.zeros(3)
    for _ in range(500):
        device.command(np.array([10.0, 0.0, 0.5]))
        device.advance(DT, np.zeros(3))
        device.out_of_plane(out_of_plane)
        worst = np.maximum(worst, np.abs(out_of_plane[3:]))
    assert worst[0] < Z_HOLD_TOL_M
    assert np.all(worst[1:] < ANGLE_HOLD_TOL_RAD)


def test_gravity_feedforward_removes_the_static_sag(config: MaglevConfig) -> None:
    """Without feed-forward the flotor would sag m g / K_z (~25 um); with it the mean z error
    at rest is noise only."""
    device = Maglev(config)
    out_of_plane = np.empty(6)
    z_errors = []
    for _ in range(500):
        device.advance(DT, np.zeros(3))
        z_errors.append(device.out_of_plane(out_of_plane)[3])
    fl = config.flotor
    weight = fl.mass_kg * fl.gravity_m_per_s2
    k_z = fl.mass_kg * (2 * math.pi * config.levitation.bandwidth_hz) ** 2
    assert abs(np.mean(z_errors)) < 0.1 * weight / k_z


def test_levitation_saturates_at_the_peak_force(config: MaglevConfig) -> None:
    device = Maglev(config)
    device.state[0]["q"][2] = -0.01  # 10 mm low: K_z * 0.01 m is far beyond 50 N
    device.advance(DT, np.zeros(3))
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_SATURATED
    effort = device.state[0]["levitation_effort"]
    assert abs(effort[0]) <= config.actuators.peak_force
    assert np.all(np.abs(effort[1:]) <= config.actuators.peak_torque)


# ------------------------------------------------------------------------------ stops


@pytest.mark.parametrize(("axis", "push"), [(0, 50.0), (1, -50.0), (2, 6.0)])
def test_stops_hold_the_flotor_at_the_range_under_peak_load(
    config: MaglevConfig, axis: int, push: float
) -> None:
    device = Maglev(config)
    hand = np.zeros(3)
    hand[axis] = push
    pose = np.empty(3)
    worst = 0.0
    for _ in range(1000):
        device.advance(DT, hand)
        device.true_state(pose, np.empty(3))
        worst = max(worst, abs(pose[axis]))
    limit = device.limits().workspace_max[axis]
    r = config.range
    k = r.translational_stop_stiffness_n_per_m
    if axis == 2:
        k = r.rotational_stop_stiffness_nm_per_rad
    # The stop takes the whole load at rest: penetration F / k beyond the range.
    assert abs(pose[axis]) - limit == pytest.approx(abs(push) / k, rel=STOP_PENETRATION_REL_TOL)
    # Impact overshoot: at most the undamped penetration p with k p^2 / 2 = F (range + p)
    # (work of the load from the centre); stop and eddy damping only lower it.
    static = abs(push) / k
    assert worst - limit < static + math.sqrt(static**2 + 2 * static * limit)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_WORKSPACE


# ---------------------------------------------------------------------------- sensors


def test_sensor_noise_std_matches_config(config: MaglevConfig) -> None:
    device = Maglev(config)
    sensors = np.zeros(1, SENSOR_DTYPE)
    pose = np.empty(3)
    errors = []
    for _ in range(6000):
        device.advance(DT, np.zeros(3))
        device.read(sensors)
        device.true_state(pose, np.empty(3))
        errors.append(sensors["pose"][0] - pose)
    std = np.std(errors, axis=0)
    s = config.sensors
    expected = np.array([s.position_noise_std_m, s.position_noise_std_m, s.angle_noise_std_rad])
    np.testing.assert_allclose(std, expected, rtol=NOISE_STD_REL_TOL)
    np.testing.assert_allclose(np.mean(errors, axis=0), 0.0, atol=0.1 * expected.max())
    assert sensors["has_force_sensor"][0] == 0
    np.testing.assert_array_equal(sensors["coriolis"][0], 0.0)
    np.testing.assert_allclose(
        np.diag(sensors["inertia"][0]),
        [config.flotor.mass_kg, config.flotor.mass_kg, config.flotor.inertia_kgm2[2]],
    )


# ------------------------------------------------------------------------- saturation


def test_command_saturates_at_peak_force_and_torque(config: MaglevConfig) -> None:
    device = Maglev(config)
    sensors = np.zeros(1, SENSOR_DTYPE)
    applied = device.command(np.array([20.0, -10.0, 1.0])).copy()
    np.testing.assert_array_equal(applied, [20.0, -10.0, 1.0])
    device.read(sensors)
    assert sensors["fault"][0] == FAULT_NONE

    applied = device.command(np.array([80.0, 0.0, 0.0])).copy()
    np.testing.assert_allclose(applied, [50.0, 0.0, 0.0])
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_SATURATED

    applied = device.command(np.array([30.0, 40.0, 12.0])).copy()  # torque binds: scale 1/2
    np.testing.assert_allclose(applied, [15.0, 20.0, 6.0])

    applied = device.command(np.array([1.0, np.inf, 0.0])).copy()
    np.testing.assert_array_equal(applied, 0.0)
    device.read(sensors)
    assert sensors["fault"][0] & FAULT_INVALID_COMMAND

    device.command(np.array([5.0, 0.0, 0.0]))
    device.safe_stop()
    np.testing.assert_array_equal(device.state[0]["held_wrench"], 0.0)


# ------------------------------------------------------------------- world mapping


def test_world_map_round_trips_and_keeps_power_consistent() -> None:
    rng = np.random.default_rng(2)
    world_map = DeviceWorldMap(
        offset=(0.3, -0.1, 0.5),
        position_scale=8.0,
        angle_scale=2.0,
        force_scale=0.5,
        rate_threshold=(0.01, 0.01, 0.1),
        rate_gain_per_s=20.0,
        rate_control=True,
    )
    world_map.step(np.array([0.0125, 0.0, 0.0]), DT)  # rate control on: offset moving
    assert world_map.rate_control_active()
    offset_rate = world_map.record["offset_rate"][0].copy()
    for _ in range(20):
        pose, twist, wrench = rng.normal(size=(3, 3))
        np.testing.assert_allclose(world_map.pose_to_device(world_map.pose_to_world(pose)), pose)
        np.testing.assert_allclose(
            world_map.twist_to_device(world_map.twist_to_world(twist)), twist
        )
        np.testing.assert_allclose(
            world_map.wrench_to_world(world_map.wrench_to_device(wrench)), wrench
        )
        world_wrench = world_map.wrench_to_world(wrench)
        world_twist = world_map.twist_to_world(twist)
        # Device power = force_scale * world power, counting only the handle's own motion.
        assert wrench @ twist == pytest.approx(0.5 * world_wrench @ (world_twist - offset_rate))


def test_rate_control_moves_the_offset_only_beyond_the_threshold(config: MaglevConfig) -> None:
    """The engine steps the device's map each tick on the measured pose; here by hand."""
    device = Maglev(config)
    sensors = np.zeros(1, SENSOR_DTYPE)

    def tick() -> None:
        device.advance(DT, np.zeros(3))
        device.read(sensors)
        device.world_map.step(sensors["pose"][0], DT)

    limit = np.array(device.limits().workspace_max)
    threshold = config.world_map.rate_threshold_fraction * limit
    for fraction in (0.5, 0.75):
        device.reset(np.array([fraction * limit[0], -fraction * limit[1], fraction * limit[2]]))
        before = device.world_map.offset
        for _ in range(100):
            tick()
            assert not device.rate_control_active()
        np.testing.assert_array_equal(device.world_map.offset, before)

    start = np.array([0.9 * limit[0], -0.95 * limit[1], 0.9 * limit[2]])
    device.reset(start)
    before = device.world_map.offset
    for _ in range(100):
        tick()
        assert device.rate_control_active()
    pose = np.empty(3)
    device.true_state(pose, np.empty(3))
    np.testing.assert_allclose(pose, start, rtol=0, atol=1e-5)  # at rest: stays put
    # Offset speed = gain * scale * (|x| - threshold), outward along each axis.
    scale = np.array([config.world_map.position_scale] * 2 + [config.world_map.angle_scale])
    expected = config.world_map.rate_gain_per_s * scale * (np.abs(start) - threshold)
    moved = device.world_map.offset - before
    np.testing.assert_allclose(moved, np.sign(start) * expected * 100 * DT, rtol=0.02)
