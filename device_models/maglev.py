"""Simulated magnetic-levitation haptic device (seed 002 §2 and §4, DESIGN §5).

A levitated flotor with 6 rigid-body DOF q = (x, y, z, roll, pitch, yaw); the planar world
uses x, y and yaw. The device's own PD loop holds z, roll and pitch at their setpoints with
gravity feed-forward, at ~100 Hz bandwidth (seed 002 §2). Eddy currents damp every axis,
stiff spring-damper stops bound the motion range, and the planar wrench the haptic loop
commands is applied at the flotor centre while the hand's wrench acts at the handle tip,
`handle_height` above it, so planar hand forces also load roll and pitch.

Rotations use small-angle dynamics (I_k d(omega_k)/dt = tau_k, angle rates = omega; no
gyroscopic or attitude coupling): within the +-8 deg range the neglected terms are < 1 %.
Its `world_map` (device_models/world_map.py, the `[world_map]` table) is the device-to-world
mapping with rate control of seed 002 §4; the engine applies and steps it. `aux` readings:
measured z, roll, pitch and the levitation's fz, tau_roll, tau_pitch (`AUX_NAMES`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numba import njit

from haptic_local_model.device_models import common
from haptic_local_model.device_models.base import (
    DAMPING_RANGE,
    FAULT_NONE,
    FAULT_SATURATED,
    FAULT_WORKSPACE,
    DeviceLimits,
    DeviceModel,
    DeviceRenderingSpec,
    require_device_limits,
)
from haptic_local_model.device_models.common import (
    FAULT_INVALID_COMMAND,
    KernelDevice,
    ModelConfig,
    NoiseBuffer,
)
from haptic_local_model.device_models.kernels import register_model
from haptic_local_model.device_models.world_map import DeviceWorldMap, WorldMapSection
from haptic_local_model.shared.config import Vec3, require, within, within_all

#: Indices of the flotor coordinates in q and v.
X, Y, Z, ROLL, PITCH, YAW = 0, 1, 2, 3, 4, 5

F8 = np.float64
I8 = np.int64

#: Static model of the flotor (built once from the config by `pack_parameters`).
PARAMS_DTYPE = np.dtype(
    [
        ("mass", F8),  # kg
        ("inertia", F8, (3,)),  # roll, pitch, yaw about the flotor centre, kg m^2
        ("gravity", F8),  # m/s^2, acting along -z
        ("handle_height", F8),  # m, handle tip above the flotor centre
        ("eddy_damping", F8, (6,)),  # N s/m (x, y, z), N m s/rad (roll, pitch, yaw)
        ("levitation_stiffness", F8, (3,)),  # z (N/m), roll, pitch (N m/rad)
        ("levitation_damping", F8, (3,)),  # z (N s/m), roll, pitch (N m s/rad)
        ("levitation_setpoint", F8, (3,)),  # z (m), roll, pitch (rad)
        ("motion_range", F8, (6,)),  # half-ranges: m (x, y, z), rad (roll, pitch, yaw)
        ("stop_stiffness", F8, (6,)),  # N/m, N m/rad
        ("stop_damping", F8, (6,)),  # N s/m, N m s/rad
        ("peak_force", F8),  # N per axis
        ("peak_torque", F8),  # N m per axis
        ("position_noise_std", F8),  # m
        ("angle_noise_std", F8),  # rad
        ("twist_cutoff_hz", F8),  # <= 0: no low-pass on the twist estimate
        ("max_substep", F8),  # s
    ]
)

#: Mutable state: true flotor motion, the held command and the newest sensor sample.
STATE_DTYPE = np.dtype(
    [
        ("q", F8, (6,)),  # x, y, z (m), roll, pitch, yaw (rad)
        ("v", F8, (6,)),  # their rates
        ("held_wrench", F8, (3,)),  # saturated planar command fx, fy, tau_yaw (zero-order hold)
        ("command_fault", I8),
        ("physics_fault", I8),  # saturation of the levitation during the last advance
        ("levitation_effort", F8, (3,)),  # last fz (incl. feed-forward), tau_roll, tau_pitch
        ("hand_wrench", F8, (3,)),  # true planar hand wrench at the handle tip
        ("measured_pose", F8, (3,)),  # x, y, yaw with sensor noise
        ("measured_twist", F8, (3,)),  # filtered finite difference of measured poses
        ("measured_out_of_plane", F8, (3,)),  # z, roll, pitch with sensor noise
        ("pose_fault", I8),  # FAULT_WORKSPACE when a measured coordinate is at a stop
    ]
)

# --------------------------------------------------------------------------------- config


@dataclass(frozen=True)
class FlotorSection:
    """Rigid-body parameters of the levitated flotor and its handle."""

    mass_kg: float
    inertia_kgm2: Vec3
    gravity_m_per_s2: float
    handle_height_m: float

    def __post_init__(self) -> None:
        require(self.mass_kg > 0, "mass_kg", "must be > 0")
        require(all(v > 0 for v in self.inertia_kgm2), "inertia_kgm2", "must be > 0")
        require(self.gravity_m_per_s2 >= 0, "gravity_m_per_s2", "must be >= 0")
        require(self.handle_height_m >= 0, "handle_height_m", "must be >= 0")


@dataclass(frozen=True)
class LevitationSection:
    """The device's own PD loop on z, roll and pitch (gains from bandwidth and damping)."""

    bandwidth_hz: float
    damping_ratio: float
    setpoint_z_m: float
    setpoint_roll_rad: float
    setpoint_pitch_rad: float

    def __post_init__(self) -> None:
        require(self.bandwidth_hz > 0, "bandwidth_hz", "must be > 0")
        require(self.damping_ratio > 0, "damping_ratio", "must be > 0")


@dataclass(frozen=True)
class DampingSection:
    """Passive eddy-current damping of each axis."""

    translational_ns_per_m: Vec3
    rotational_nms_per_rad: Vec3

    def __post_init__(self) -> None:
        for key in ("translational_ns_per_m", "rotational_nms_per_rad"):
            within_all(getattr(self, key), DAMPING_RANGE, key)


@dataclass(frozen=True)
class RangeSection:
    """Motion range (half-widths about the centre) and the stops at its ends."""

    translation_m: Vec3
    rotation_rad: Vec3
    translational_stop_stiffness_n_per_m: float
    translational_stop_damping_ns_per_m: float
    rotational_stop_stiffness_nm_per_rad: float
    rotational_stop_damping_nms_per_rad: float

    def __post_init__(self) -> None:
        require(all(v > 0 for v in self.translation_m), "translation_m", "must be > 0")
        require(all(v > 0 for v in self.rotation_rad), "rotation_rad", "must be > 0")
        for key in (
            "translational_stop_stiffness_n_per_m",
            "translational_stop_damping_ns_per_m",
            "rotational_stop_stiffness_nm_per_rad",
            "rotational_stop_damping_nms_per_rad",
        ):
            require(getattr(self, key) >= 0, key, "must be >= 0")


@dataclass(frozen=True)
class ActuatorSection:
    """Amplifier limits and the highest control rate (seed 002 §2).

    `max_wrench` is every device's spelling of its limit (N, N, N m): here the peak force of
    the x and y amplifiers (z has the same ones) and the peak torque about yaw (roll and
    pitch have the same). `peak_force_n` / `peak_torque_nm` are the previous release's
    spelling, still read from the device configs stored in its logs."""

    max_rate_hz: float
    max_wrench: Vec3 | None = None
    peak_force_n: float | None = None  # previous spelling
    peak_torque_nm: float | None = None  # previous spelling

    def __post_init__(self) -> None:
        if self.max_wrench is None:
            require(
                self.peak_force_n is not None and self.peak_torque_nm is not None,
                "max_wrench",
                "missing (N, N, N m)",
            )
            assert self.peak_force_n is not None and self.peak_torque_nm is not None
            limit = (self.peak_force_n, self.peak_force_n, self.peak_torque_nm)
            object.__setattr__(self, "max_wrench", limit)
        else:
            require(
                self.peak_force_n is None and self.peak_torque_nm is None,
                "peak_force_n",
                "the old spelling of max_wrench: give one of them",
            )
        fx, fy, tz = self.wrench_limit
        require_device_limits((fx, fy, tz), self.max_rate_hz)
        require(fx == fy, "max_wrench", "the x and y amplifiers are alike: give fx == fy")

    @property
    def wrench_limit(self) -> tuple[float, float, float]:
        assert self.max_wrench is not None  # set in __post_init__
        return self.max_wrench

    @property
    def peak_force(self) -> float:
        """Per force axis (x, y and z), N."""
        return self.wrench_limit[0]

    @property
    def peak_torque(self) -> float:
        """Per torque axis (yaw, roll and pitch), N m."""
        return self.wrench_limit[2]


@dataclass(frozen=True)
class SensorSection:
    """Optical position sensing noise and the twist estimate."""

    position_noise_std_m: float
    angle_noise_std_rad: float
    twist_cutoff_hz: float
    noise_seed: int

    def __post_init__(self) -> None:
        within(self.position_noise_std_m, (0.0, 0.01), "position_noise_std_m", "m")
        within(self.angle_noise_std_rad, (0.0, 0.1), "angle_noise_std_rad", "rad")
        require(self.twist_cutoff_hz >= 0, "twist_cutoff_hz", "must be >= 0")
        require(0 <= self.noise_seed < 2**63, "noise_seed", "must be in [0, 2^63)")


@dataclass(frozen=True)
class SimulationSection(common.SimulationSection):
    """Integration of the true dynamics: the levitation loop is stiff, substeps <= 1 ms."""

    MAX_SUBSTEP_S: ClassVar[float] = 0.001


@dataclass(frozen=True)
class MaglevConfig(ModelConfig):
    """The maglev device, one frozen section per TOML table."""

    MODEL: ClassVar[str] = "maglev"

    flotor: FlotorSection
    levitation: LevitationSection
    damping: DampingSection
    range: RangeSection
    actuators: ActuatorSection
    sensors: SensorSection
    world_map: WorldMapSection
    simulation: SimulationSection
    rendering: DeviceRenderingSpec = field(default_factory=DeviceRenderingSpec)

    def __post_init__(self) -> None:
        weight = self.flotor.mass_kg * self.flotor.gravity_m_per_s2
        require(
            weight < self.actuators.peak_force,
            "actuators.max_wrench",
            f"cannot levitate the flotor's weight {weight:.2f} N",
        )


def pack_parameters(config: MaglevConfig) -> np.ndarray:
    """The config as a 1-element PARAMS_DTYPE record (the one conversion).

    Levitation gains place the PD poles at the configured bandwidth and damping ratio for
    the flotor's mass and roll/pitch inertia: K = m w^2, D = 2 zeta w m.
    """
    fl, lev, r = config.flotor, config.levitation, config.range
    rec = np.zeros(1, PARAMS_DTYPE)
    p = rec[0]
    p["mass"] = fl.mass_kg
    p["inertia"] = fl.inertia_kgm2
    p["gravity"] = fl.gravity_m_per_s2
    p["handle_height"] = fl.handle_height_m
    p["eddy_damping"][:3] = config.damping.translational_ns_per_m
    p["eddy_damping"][3:] = config.damping.rotational_nms_per_rad
    omega = 2.0 * math.pi * lev.bandwidth_hz
    levitated = (fl.mass_kg, fl.inertia_kgm2[0], fl.inertia_kgm2[1])
    p["levitation_stiffness"] = [m * omega**2 for m in levitated]
    p["levitation_damping"] = [2.0 * lev.damping_ratio * omega * m for m in levitated]
    p["levitation_setpoint"] = (lev.setpoint_z_m, lev.setpoint_roll_rad, lev.setpoint_pitch_rad)
    p["motion_range"][:3] = r.translation_m
    p["motion_range"][3:] = r.rotation_rad
    p["stop_stiffness"][:3] = r.translational_stop_stiffness_n_per_m
    p["stop_stiffness"][3:] = r.rotational_stop_stiffness_nm_per_rad
    p["stop_damping"][:3] = r.translational_stop_damping_ns_per_m
    p["stop_damping"][3:] = r.rotational_stop_damping_nms_per_rad
    p["peak_force"] = config.actuators.peak_force
    p["peak_torque"] = config.actuators.peak_torque
    p["position_noise_std"] = config.sensors.position_noise_std_m
    p["angle_noise_std"] = config.sensors.angle_noise_std_rad
    p["twist_cutoff_hz"] = config.sensors.twist_cutoff_hz
    p["max_substep"] = config.simulation.max_substep_s
    return rec


# -------------------------------------------------------------------------- tick kernels


@njit(cache=True)
def _stop_force(p, k, x, v):
    """Unilateral spring-damper of the stop of coordinate k at +-motion_range[k]."""
    limit = p.motion_range[k]
    if x > limit:
        push = p.stop_stiffness[k] * (x - limit) + p.stop_damping[k] * v
        return -push if push > 0.0 else 0.0
    if x < -limit:
        push = p.stop_stiffness[k] * (-limit - x) - p.stop_damping[k] * v
        return push if push > 0.0 else 0.0
    return 0.0


@njit(cache=True)
def _clip(value, limit):
    return min(max(value, -limit), limit)


@njit(cache=True)
def _sample_sensors(params, state, dt, normals, noise_index):
    """Noisy optical pose sample; twist by filtered finite difference; stop faults."""
    p = params[0]
    st = state[0]
    sp = p.position_noise_std
    sa = p.angle_noise_std
    new_x = st.q[X] + sp * normals[noise_index]
    new_y = st.q[Y] + sp * normals[noise_index + 1]
    new_yaw = st.q[YAW] + sa * normals[noise_index + 2]
    st.measured_out_of_plane[0] = st.q[Z] + sp * normals[noise_index + 3]
    st.measured_out_of_plane[1] = st.q[ROLL] + sa * normals[noise_index + 4]
    st.measured_out_of_plane[2] = st.q[PITCH] + sa * normals[noise_index + 5]
    if dt > 0.0:
        alpha = 1.0
        if p.twist_cutoff_hz > 0.0:
            alpha = 1.0 - math.exp(-2.0 * math.pi * p.twist_cutoff_hz * dt)
        st.measured_twist[0] += alpha * ((new_x - st.measured_pose[0]) / dt - st.measured_twist[0])
        st.measured_twist[1] += alpha * ((new_y - st.measured_pose[1]) / dt - st.measured_twist[1])
        st.measured_twist[2] += alpha * (
            (new_yaw - st.measured_pose[2]) / dt - st.measured_twist[2]
        )
    else:
        for c in range(3):
            st.measured_twist[c] = 0.0
    st.measured_pose[0] = new_x
    st.measured_pose[1] = new_y
    st.measured_pose[2] = new_yaw
    fault = FAULT_NONE
    oop = st.measured_out_of_plane
    measured = (new_x, new_y, oop[0], oop[1], oop[2], new_yaw)
    for k in range(6):
        if abs(measured[k]) >= p.motion_range[k]:
            fault = FAULT_WORKSPACE
    st.pose_fault = fault


@njit(cache=True)
def advance(params, state, work, dt, hand_wrench, normals, noise_index):
    """Flotor dynamics over dt by semi-implicit Euler substeps (<= max_substep), then a
    sensor sample.

    Per substep the levitation PD acts on z, roll, pitch measured with fresh sensor noise,
    with gravity feed-forward, saturated at the peak force/torque (seed 002 §2, §4 f_g).
    Uses 3 normals per substep and 6 for the sample, from normals[noise_index:]. (No
    scratch record: `work` is unused.)
    """
    p = params[0]
    st = state[0]
    for c in range(3):
        st.hand_wrench[c] = hand_wrench[c]
    n_sub = max(1, math.ceil(dt / p.max_substep))
    h = dt / n_sub
    weight = p.mass * p.gravity
    fault = FAULT_NONE
    k_lev = p.levitation_stiffness
    d_lev = p.levitation_damping
    sp = p.levitation_setpoint
    arm = p.handle_height
    idx = noise_index
    for _ in range(n_sub):
        z_meas = st.q[Z] + p.position_noise_std * normals[idx]
        roll_meas = st.q[ROLL] + p.angle_noise_std * normals[idx + 1]
        pitch_meas = st.q[PITCH] + p.angle_noise_std * normals[idx + 2]
        idx += 3
        fz = weight + k_lev[0] * (sp[0] - z_meas) - d_lev[0] * st.v[Z]
        t_roll = k_lev[1] * (sp[1] - roll_meas) - d_lev[1] * st.v[ROLL]
        t_pitch = k_lev[2] * (sp[2] - pitch_meas) - d_lev[2] * st.v[PITCH]
        if abs(fz) > p.peak_force or abs(t_roll) > p.peak_torque:
            fault = FAULT_SATURATED
        if abs(t_pitch) > p.peak_torque:
            fault = FAULT_SATURATED
        fz = _clip(fz, p.peak_force)
        t_roll = _clip(t_roll, p.peak_torque)
        t_pitch = _clip(t_pitch, p.peak_torque)
        st.levitation_effort[0] = fz
        st.levitation_effort[1] = t_roll
        st.levitation_effort[2] = t_pitch
        # The hand's planar force at the handle tip (0, 0, arm) adds r x F to roll, pitch.
        load = (
            st.held_wrench[0] + hand_wrench[0],
            st.held_wrench[1] + hand_wrench[1],
            fz - weight,
            t_roll - arm * hand_wrench[1],
            t_pitch + arm * hand_wrench[0],
            st.held_wrench[2] + hand_wrench[2],
        )
        for k in range(6):
            f = load[k] - p.eddy_damping[k] * st.v[k] + _stop_force(p, k, st.q[k], st.v[k])
            inertia = p.mass if k < 3 else p.inertia[k - 3]
            st.v[k] += h * f / inertia
        for k in range(6):
            st.q[k] += h * st.v[k]
    st.physics_fault = fault
    _sample_sensors(params, state, dt, normals, idx)


@njit(cache=True)
def command(params, state, wrench):
    """Saturate the planar command at the peak force and torque by one uniform scale (the
    direction is kept) and hold it; NaN or Inf commands zero."""
    p = params[0]
    st = state[0]
    finite = True
    for c in range(3):
        if not math.isfinite(wrench[c]):
            finite = False
    if not finite:
        for c in range(3):
            st.held_wrench[c] = 0.0
        st.command_fault = FAULT_SATURATED | FAULT_INVALID_COMMAND
        return
    scale = 1.0
    for c in range(3):
        limit = p.peak_torque if c == 2 else p.peak_force
        if abs(wrench[c]) > limit:
            scale = min(scale, limit / abs(wrench[c]))
    for c in range(3):
        limit = p.peak_torque if c == 2 else p.peak_force
        st.held_wrench[c] = _clip(scale * wrench[c], limit)
    st.command_fault = FAULT_SATURATED if scale < 1.0 else FAULT_NONE


@njit(cache=True)
def read(params, state, sensors):
    """Copy the newest sample into a SENSOR_DTYPE record: the planar rigid body has constant
    M_d = diag(m, m, I_yaw) and C_d = 0; no force sensor. aux: AUX_NAMES."""
    p = params[0]
    st = state[0]
    r = sensors[0]
    for a in range(3):
        r.pose[a] = st.measured_pose[a]
        r.twist[a] = st.measured_twist[a]
        r.hand_wrench[a] = 0.0
        for b in range(3):
            r.inertia[a, b] = 0.0
            r.coriolis[a, b] = 0.0
    r.inertia[0, 0] = p.mass
    r.inertia[1, 1] = p.mass
    r.inertia[2, 2] = p.inertia[2]
    r.has_force_sensor = 0
    r.fault = st.pose_fault | st.command_fault | st.physics_fault
    for k in range(r.aux.shape[0]):
        r.aux[k] = 0.0
    for c in range(3):
        r.aux[c] = st.measured_out_of_plane[c]
        r.aux[3 + c] = st.levitation_effort[c]


@njit(cache=True)
def _place_at_rest(params, state, planar_pose, zero_noise):
    """Flotor at rest at (x, y, yaw) with z, roll, pitch on their setpoints; noise-free sample."""
    p = params[0]
    st = state[0]
    for k in range(6):
        st.q[k] = 0.0
        st.v[k] = 0.0
    st.q[X] = planar_pose[0]
    st.q[Y] = planar_pose[1]
    st.q[YAW] = planar_pose[2]
    st.q[Z] = p.levitation_setpoint[0]
    st.q[ROLL] = p.levitation_setpoint[1]
    st.q[PITCH] = p.levitation_setpoint[2]
    for c in range(3):
        st.held_wrench[c] = 0.0
        st.hand_wrench[c] = 0.0
    st.levitation_effort[0] = p.mass * p.gravity
    st.levitation_effort[1] = 0.0
    st.levitation_effort[2] = 0.0
    st.command_fault = FAULT_NONE
    st.physics_fault = FAULT_NONE
    _sample_sensors(params, state, 0.0, zero_noise, 0)


@njit(cache=True)
def true_state(state, pose, twist):
    st = state[0]
    pose[0] = st.q[X]
    pose[1] = st.q[Y]
    pose[2] = st.q[YAW]
    twist[0] = st.v[X]
    twist[1] = st.v[Y]
    twist[2] = st.v[YAW]


@njit(cache=True)
def _copy_out_of_plane(params, state, out):
    p = params[0]
    st = state[0]
    out[0] = st.q[Z]
    out[1] = st.q[ROLL]
    out[2] = st.q[PITCH]
    for c in range(3):
        out[3 + c] = out[c] - p.levitation_setpoint[c]


# ---------------------------------------------------------------------------- the device


@njit(cache=True)
def noise_needed(params, dt):
    """Three normals per substep (levitation sensing) and six for the sample."""
    return 3 * max(1, math.ceil(dt / params[0].max_substep)) + 6


@njit(cache=True)
def applied(state):
    """The saturated planar wrench (the flotor stays levitated)."""
    return state[0].held_wrench


KERNELS = register_model(PARAMS_DTYPE, globals())  # sense_hand: the default

_NOISE_BLOCK = 3 * 8192  # standard normals per refill of the sensor-noise buffer

#: What SENSOR_DTYPE.aux holds (the engine logs it as device_aux): the measured out-of-plane
#: pose (with sensor noise) and the levitation loop's last efforts.
AUX_NAMES = (
    "z_m",
    "roll_rad",
    "pitch_rad",
    "levitation_fz_n",
    "levitation_roll_nm",
    "levitation_pitch_nm",
)


class Maglev(KernelDevice):
    """Simulated maglev device implementing `SimulatedDevice` (device frame, SI units).

    `world_map` is the engine's device-to-world map (it steps rate control each tick on the
    measured pose); `rendering` holds the FOH servo gains of the `[rendering]` table.
    """

    aux_names = AUX_NAMES

    name = "maglev"
    KERNELS = KERNELS

    def __init__(self, config: MaglevConfig) -> None:
        self.config = config
        r = config.range
        planar_range = (r.translation_m[0], r.translation_m[1], r.rotation_rad[2])
        limits = DeviceLimits(
            max_wrench=config.actuators.wrench_limit,
            workspace_min=(-planar_range[0], -planar_range[1], -planar_range[2]),
            workspace_max=planar_range,
            max_rate_hz=config.actuators.max_rate_hz,
        )
        world_map = DeviceWorldMap.from_config(config.world_map, planar_range)
        records = (
            pack_parameters(config),
            np.zeros(1, STATE_DTYPE),
            np.zeros(1),  # no scratch record
            NoiseBuffer(config.sensors.noise_seed, _NOISE_BLOCK),
        )
        super().__init__(records, limits, config.rendering, world_map)
        self.world_map: DeviceWorldMap = world_map  # always one: rate control
        self._zero_noise = np.zeros(6)
        self.reset(np.zeros(3))

    def servo_plant(self) -> tuple[np.ndarray, float]:
        d = self.config.damping  # passive eddy-current damping of the planar axes
        damping = np.array([*d.translational_ns_per_m[:2], d.rotational_nms_per_rad[2]])
        return damping, self.config.sensors.twist_cutoff_hz

    def reset(self, pose: np.ndarray) -> None:
        planar_pose = np.array(pose, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(planar_pose)):
            raise ValueError(f"reset pose must be finite, got {planar_pose}")
        if np.any(np.abs(planar_pose) > np.asarray(self._limits.workspace_max)):
            raise ValueError(f"reset pose {planar_pose} is outside the motion range")
        _place_at_rest(self.params, self.state, planar_pose, self._zero_noise)

    def out_of_plane(self, out: np.ndarray | None = None) -> np.ndarray:
        """True (z, roll, pitch, z error, roll error, pitch error): m and rad, errors from
        the levitation setpoints."""
        out = np.empty(6) if out is None else out
        _copy_out_of_plane(self.params, self.state, out)
        return out

    def rate_control_active(self) -> bool:
        """Whether rate control moved the world-map offset in the engine's last tick."""
        return self.world_map.rate_control_active()


#: The entry point of this model (pyproject.toml, group haptic_local_model.devices).
MODEL = DeviceModel(
    MaglevConfig,
    Maglev,
    "maglev",
    "seed 002's magnetic levitation device: 6-DOF flotor, planar x, y, yaw used",
)
