"""The device-to-world map in the engine (seed 002 §4): readings, commands, limits, rate
control, checked against closed forms through a scripted driver that implements only the
hardware `Device` interface (no simulated physics, no simulated hand)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from haptic_local_model.device_models.base import SENSOR_DTYPE, DeviceLimits, DeviceRenderingSpec
from haptic_local_model.device_models.world_map import (
    DeviceWorldMap,
    map_command_to_device,
    map_sensors_to_world,
)
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.shared.config import ConfigError, UserConfig, load_scene
from haptic_local_model.shared.kinematics import free_body_chain
from haptic_local_model.shared.protocol.update import ContactSet, LocalModelUpdate, encode_update

DT = 1e-3
EXACT = 1e-12  # relative: a few roundings of the same closed form
SCALE = (2.0, 2.0, 0.5)  # world per device unit: position, position, angle
FORCE_SCALE = 0.25
K_P = (3000.0, 2000.0, 20.0)  # device frame FOH gains, N/m, N/m, N m/rad
K_V = (40.0, 30.0, 0.2)
F_G = (0.3, -0.2, 0.01)  # f_g, device frame
TOOL_POSE = np.array([0.10, -0.05, 0.3])  # world


class ScriptedDriver:
    """A stand-in for a hardware driver: the test sets what it reads and sees what it is
    commanded. Implements `device_models.base.Device` only."""

    name = "scripted"
    aux_names = ("a0",)

    def __init__(self, world_map: DeviceWorldMap | None, max_wrench=(50.0, 50.0, 5.0)) -> None:
        self.world_map = world_map
        self.rendering = DeviceRenderingSpec(
            foh_stiffness=K_P, foh_damping=K_V, gravity_feedforward=F_G
        )
        self.pose = np.zeros(3)
        self.twist = np.zeros(3)
        self.commands: list[np.ndarray] = []
        box = (0.0125, 0.0125, 0.14)
        self._limits = DeviceLimits(max_wrench, (-box[0], -box[1], -box[2]), box, 1000.0)

    def limits(self) -> DeviceLimits:
        return self._limits

    def read(self, sensors: np.ndarray) -> None:
        s = sensors[0]
        s["pose"] = self.pose
        s["twist"] = self.twist
        s["inertia"] = np.diag([0.5, 0.5, 1e-3])
        s["aux"][0] = 7.0

    def command(self, wrench: np.ndarray) -> np.ndarray:
        self.commands.append(wrench.copy())
        return wrench

    def safe_stop(self) -> None:
        pass


def foh_engine(driver: ScriptedDriver, touching: bool = True) -> HapticEngine:
    """An FOH engine on the maglev_scoop scene with one update: a free tool at TOOL_POSE."""
    scene = load_scene("maglev_scoop")
    engine = HapticEngine(scene, driver, UserConfig(name="none", kind="constant_wrench"))
    assert not engine.simulated
    assert engine.receive(encode_update(tool_update(0, TOOL_POSE, touching))) == ""
    return engine


def tool_update(seq: int, pose: np.ndarray, touching: bool = True) -> LocalModelUpdate:
    jt, lengths = free_body_chain()
    return LocalModelUpdate(
        epoch=1, seq=seq, sim_time=seq / 30.0, publish_time_ns=0, joint_types=jt,
        lengths=lengths, base=np.zeros(2), base_angle=0.0, op_link=2, op_point=np.zeros(2),
        q=pose.copy(), qd=np.zeros(3), mass_matrix=np.diag([3.0, 3.0, 6.5e-3]),
        lambda_inv=np.diag([1 / 3.0, 1 / 3.0, 1 / 6.5e-3]), tool_pose=pose.copy(), gravity=None,
        velocity_torque=None, resisted=None, characteristic_length=0.05,
        contacts=ContactSet.empty(), tool_touching=touching,
    )  # fmt: skip


def scaled_map(rate_control: bool = False) -> DeviceWorldMap:
    return DeviceWorldMap(
        offset=(0.0, 0.0, 0.0), position_scale=SCALE[0], angle_scale=SCALE[2],
        force_scale=FORCE_SCALE, rate_threshold=(0.008, 0.008, 0.1), rate_gain_per_s=20.0,
        rate_control=rate_control,
    )  # fmt: skip


def test_a_device_limits_in_the_world_frame_divide_by_scale_and_force_scale() -> None:
    """device_models.base.world_limits, the one place every world takes them from: F_device
    = force_scale scale F_world, so a 50 N device limit along x at scale 2 and force scale
    0.25 is 100 N in the world; a device without a map keeps its own (scale 1)."""
    from haptic_local_model.device_models.base import world_limits, world_map_of

    scaled = ScriptedDriver(scaled_map(), max_wrench=(50.0, 40.0, 5.0))
    np.testing.assert_allclose(world_limits(scaled), [100.0, 80.0, 40.0], rtol=EXACT)
    assert world_map_of(scaled) is scaled.world_map
    bare = ScriptedDriver(None, max_wrench=(50.0, 40.0, 5.0))
    np.testing.assert_array_equal(world_limits(bare), [50.0, 40.0, 5.0])
    assert world_map_of(bare).record[0]["force_scale"] == 1.0


# --------------------------------------------------------------------------- the kernels


def test_sensors_map_to_world_so_newtons_law_holds_in_both_frames() -> None:
    """pose, twist, the offset's velocity, and M_d, C_d, F_h such that M a = F either side."""
    world_map = scaled_map(rate_control=True)
    world_map.record[0]["offset"] = (0.3, -0.1, 1.0)
    world_map.record[0]["offset_rate"] = (0.02, 0.0, -0.1)
    rng = np.random.default_rng(5)
    src = np.zeros(1, SENSOR_DTYPE)
    dst = np.zeros(1, SENSOR_DTYPE)
    s = src[0]
    s["pose"], s["twist"], s["hand_wrench"] = rng.normal(size=(3, 3))
    a = rng.normal(size=(3, 3))
    s["inertia"] = a @ a.T + np.eye(3)
    s["coriolis"] = rng.normal(size=(3, 3))
    s["aux"] = np.arange(8.0)
    s["fault"] = 5
    map_sensors_to_world(world_map.record, src, dst)
    d, m = dst[0], world_map.record[0]
    scale = np.array(SCALE)
    np.testing.assert_allclose(d["pose"], m["offset"] + scale * s["pose"], rtol=EXACT)
    np.testing.assert_allclose(d["twist"], m["offset_rate"] + scale * s["twist"], rtol=EXACT)
    np.testing.assert_array_equal(d["frame_twist"], m["offset_rate"])
    np.testing.assert_array_equal(d["aux"], s["aux"])
    assert d["fault"] == 5
    acc_device = rng.normal(size=3)  # M_d a_d = F_d  <=>  M_w (s a_d) = F_d / (f_s s)
    force_device = s["inertia"] @ acc_device
    np.testing.assert_allclose(
        d["inertia"] @ (scale * acc_device), force_device / (FORCE_SCALE * scale), rtol=1e-10
    )
    twist_device = s["twist"]
    np.testing.assert_allclose(
        d["coriolis"] @ (scale * twist_device),
        (s["coriolis"] @ twist_device) / (FORCE_SCALE * scale),
        rtol=1e-10,
    )
    np.testing.assert_allclose(d["hand_wrench"], s["hand_wrench"] / (FORCE_SCALE * scale))


def test_command_maps_to_the_device_frame_and_never_exceeds_its_limits() -> None:
    world_map = scaled_map()
    limits = np.array([1.0, 2.0, 0.1])
    out = np.empty(3)
    map_command_to_device(world_map.record, np.array([1.0, -1.0, 0.05]), limits, out)
    np.testing.assert_allclose(out, FORCE_SCALE * np.array(SCALE) * [1.0, -1.0, 0.05])
    map_command_to_device(world_map.record, np.array([1e3, -1e3, 1e3]), limits, out)
    np.testing.assert_array_equal(out, [1.0, -2.0, 0.1])


# ------------------------------------------------------------------------------ the engine


def test_foh_servo_acts_in_the_device_frame_through_any_map() -> None:
    """Through scale s and force scale f_s the driver receives exactly seed 002's device law,
    f = f_g + K_p (x_goal,dev - x_dev) - K_v xd_dev, with the device-frame gains."""
    driver = ScriptedDriver(scaled_map())
    engine = foh_engine(driver)
    offset = engine.offset  # anchored: the driver's pose (0) maps onto the tool
    np.testing.assert_allclose(offset, TOOL_POSE, rtol=EXACT)
    driver.pose = np.array([0.001, -0.002, 0.01])
    driver.twist = np.array([0.01, 0.02, -0.1])
    row = engine.tick(DT)[0]
    goal_device = (TOOL_POSE - offset) / np.array(SCALE)
    expected = (
        np.array(F_G) + np.array(K_P) * (goal_device - driver.pose) - np.array(K_V) * driver.twist
    )
    np.testing.assert_allclose(driver.commands[-1], expected, rtol=1e-10)
    # the row is in the world frame
    world_wrench = expected / (FORCE_SCALE * np.array(SCALE))
    np.testing.assert_allclose(row["wrench_command"], world_wrench, rtol=1e-10)
    np.testing.assert_allclose(row["wrench_applied"], world_wrench, rtol=1e-10)
    np.testing.assert_allclose(row["device_pose"], offset + np.array(SCALE) * driver.pose)
    np.testing.assert_allclose(row["device_twist"], np.array(SCALE) * driver.twist)
    np.testing.assert_allclose(row["world_offset"], offset)
    assert row["device_aux"][0] == 7.0


def test_commands_are_clipped_at_the_device_limits_exactly() -> None:
    limits = (1.0, 0.5, 0.02)
    driver = ScriptedDriver(scaled_map(), max_wrench=limits)
    engine = foh_engine(driver)
    driver.pose = np.array([0.005, -0.005, 0.05])  # K_p error far beyond the limits
    for _ in range(20):
        engine.tick(DT)
    for command in driver.commands:
        assert np.all(np.abs(command) <= np.array(limits))
    np.testing.assert_allclose(driver.commands[-1], [-1.0, 0.5, -0.02], rtol=1e-12)


def test_force_is_off_while_the_tool_touches_nothing_but_f_g_stays() -> None:
    driver = ScriptedDriver(scaled_map())
    engine = foh_engine(driver, touching=False)
    driver.pose = np.array([0.003, 0.001, 0.02])
    row = engine.tick(DT)[0]
    np.testing.assert_array_equal(row["f_coordination"], 0.0)
    np.testing.assert_allclose(driver.commands[-1], F_G, rtol=1e-12)


def test_rate_control_moves_the_workspace_and_the_servo_ignores_that_motion() -> None:
    """Beyond the threshold the offset moves at gain * s * (|x| - threshold), outward, each
    tick; the world twist includes that motion, but K_v damps only the handle's own."""
    driver = ScriptedDriver(scaled_map(rate_control=True))
    engine = foh_engine(driver)
    start = engine.offset
    driver.pose = np.array([0.009, -0.0085, 0.0])  # beyond 8 mm in x and y
    rows = [engine.tick(DT)[0].copy() for _ in range(50)]
    rate = 20.0 * SCALE[0] * (np.abs(driver.pose[:2]) - 0.008) * np.sign(driver.pose[:2])
    np.testing.assert_allclose(engine.offset[:2] - start[:2], 50 * DT * rate, rtol=1e-9)
    assert engine.offset[2] == start[2]
    for k in (10, 40):
        offset_k = rows[k]["world_offset"]
        np.testing.assert_allclose(offset_k[:2], start[:2] + k * DT * rate, rtol=1e-9)
        np.testing.assert_allclose(rows[k]["device_twist"][:2], rate, rtol=1e-9)
        goal_device = (TOOL_POSE - offset_k) / np.array(SCALE)
        expected = np.array(F_G) + np.array(K_P) * (goal_device - driver.pose)
        np.testing.assert_allclose(driver.commands[k], expected, rtol=1e-9)


def test_without_a_map_the_device_is_offset_onto_the_tool_at_scale_one() -> None:
    driver = ScriptedDriver(None)
    driver.pose = np.array([0.004, 0.001, -0.02])  # a real device stays where it is
    engine = foh_engine(driver)
    np.testing.assert_allclose(engine.offset, TOOL_POSE - driver.pose, rtol=EXACT)
    row = engine.tick(DT)[0]
    np.testing.assert_allclose(row["device_pose"], TOOL_POSE, rtol=EXACT)
    expected = np.array(F_G) + np.array(K_P) * (TOOL_POSE - row["device_pose"])
    np.testing.assert_allclose(driver.commands[-1], expected, atol=1e-9)


def test_simulated_devices_scale_their_gains_and_limits_with_their_map() -> None:
    """A simulated ideal device with a [world_map] table: the engine's world-frame params are
    the device's over f_s s (wrenches) and f_s s^2 (gains)."""
    from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
    from haptic_local_model.device_models.world_map import WorldMapSection

    config = IdealDeviceConfig(
        world_map=WorldMapSection(position_scale=4.0, angle_scale=2.0, force_scale=0.5)
    )
    device = IdealDevice(config)
    engine = HapticEngine(
        load_scene("maglev_scoop"), device, UserConfig(name="none", kind="constant_wrench")
    )
    p = engine.params[0]
    scale = np.array([4.0, 4.0, 2.0])
    np.testing.assert_allclose(p["max_wrench"], np.array(config.max_wrench) / (0.5 * scale))
    np.testing.assert_allclose(
        p["foh_stiffness"], np.array(config.rendering.foh_stiffness) / (0.5 * scale**2)
    )
    assert engine.simulated and engine.world_map is device.world_map.record


@pytest.mark.parametrize("bad", [{"position_scale": 0.0}, {"force_scale": -1.0}])
def test_world_map_table_is_validated(bad: dict[str, float]) -> None:
    from haptic_local_model.device_models.world_map import WorldMapSection

    with pytest.raises(ValueError, match=next(iter(bad))):
        dataclasses.replace(WorldMapSection(), **bad)


def test_a_scene_faster_than_the_device_is_refused() -> None:
    scene = dataclasses.replace(load_scene("maglev_scoop"), haptic_rate_hz=2000.0)
    driver = ScriptedDriver(None)  # max_rate_hz 1000
    with pytest.raises(ConfigError, match=r"haptic_rate_hz.*exceeds the device's max_rate_hz"):
        HapticEngine(scene, driver, UserConfig(name="none", kind="constant_wrench"))


def test_identity_map_changes_nothing() -> None:
    m = DeviceWorldMap.identity()
    pose = np.array([0.1, 0.2, math.pi / 3])
    np.testing.assert_array_equal(m.pose_to_world(pose), pose)
    assert not m.step(np.array([1e3, 1e3, 1e3]), DT)


# ---------------------------------------------------------------------- setpoint hold


def install(engine: HapticEngine, seq: int, pose: np.ndarray) -> None:
    assert engine.receive(encode_update(tool_update(seq, pose))) == ""


def goal_after(engine: HapticEngine, ticks: int) -> np.ndarray:
    rows = [engine.tick(DT)[0]["vm_pose"].copy() for _ in range(ticks)]
    return np.array(rows)


def test_first_order_hold_moves_over_the_mean_of_the_last_three_intervals() -> None:
    """x_goal advances by (x_new - x_goal) / T_avg per tick, T_avg the mean of the last
    three update intervals in ticks (seed 002 §4); it never jumps."""
    driver = ScriptedDriver(None)
    engine = foh_engine(driver)  # first update at tick 0: the goal starts on it
    pose0 = engine.state[0]["foh_goal"].copy()
    step = np.array([0.001, -0.0005, 0.002])
    intervals = [30, 36, 33, 40, 20]
    poses = [pose0]
    goals = [goal_after(engine, intervals[0])]
    for k, interval in enumerate(intervals[1:], start=1):
        poses.append(pose0 + k * step)
        start_goal = engine.state[0]["foh_goal"].copy()
        install(engine, k, poses[-1])
        seen = intervals[max(0, k - 3) : k]
        t_avg = round(float(np.mean(seen)))
        goals.append(goal_after(engine, interval))
        path = goals[-1]
        moved = min(interval, t_avg)
        rate = (poses[-1] - start_goal) / t_avg
        expected = start_goal + np.outer(np.arange(1, interval + 1).clip(max=moved), rate)
        np.testing.assert_allclose(path, expected, rtol=1e-9, atol=1e-15)
    all_goals = np.concatenate(goals)
    largest_step = np.abs(np.diff(all_goals, axis=0)).max(axis=0)
    bound = np.abs(step) / min(intervals)  # a zero-order hold would jump by |step|
    assert np.all(largest_step <= bound * (1 + 1e-9))


def test_zero_order_hold_jumps_to_each_new_pose() -> None:
    driver = ScriptedDriver(None)
    driver.rendering = dataclasses.replace(driver.rendering, setpoint_hold="zero_order")
    engine = foh_engine(driver)
    goal_after(engine, 33)
    new = engine.state[0]["foh_goal"] + 0.002
    install(engine, 1, new)
    path = goal_after(engine, 5)
    np.testing.assert_array_equal(path, np.tile(new, (5, 1)))
