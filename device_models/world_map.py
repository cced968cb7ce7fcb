"""Device-to-world mapping with rate control (seed 002 §4), shared by the engine and devices.

x_world = offset + scale x_device per axis (positions and the angle), twists likewise plus
the offset's own velocity, and wrenches F_device = force_scale * scale * F_world so the port
power is scaled by force_scale alone. Near the motion limits, rate control moves the offset
outward so the handle's position sets the workspace's velocity. The map is one MAP_DTYPE
record: the engine's kernels read it each tick and step its rate control; the scale and
force scale are fixed for a run, the offset moves (anchoring at an epoch, rate control).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from haptic_local_model.shared.config import Vec3, require, within

F8 = np.float64
I8 = np.int64

#: The device-to-world mapping with rate control (seed 002 §4).
MAP_DTYPE = np.dtype(
    [
        ("offset", F8, (3,)),  # world pose of the device's centred handle: m, m, rad
        ("scale", F8, (3,)),  # position, position, angle scale (world per device unit)
        ("force_scale", F8),  # device power / world power
        ("rate_enabled", I8),
        ("rate_threshold", F8, (3,)),  # device units beyond which rate control acts
        ("rate_gain", F8),  # 1/s: offset speed per unit of excess (scaled to world units)
        ("offset_rate", F8, (3,)),  # current offset velocity, world units/s
        ("rate_active", I8),
    ]
)


@dataclass(frozen=True)
class WorldMapSection:
    """The `[world_map]` table of a device config: mapping and automatic rate control."""

    offset: Vec3 = (0.0, 0.0, 0.0)
    position_scale: float = 1.0
    angle_scale: float = 1.0
    force_scale: float = 1.0
    rate_control: bool = False
    rate_threshold_fraction: float = 0.8
    rate_gain_per_s: float = 20.0

    def __post_init__(self) -> None:
        require(all(math.isfinite(v) for v in self.offset), "offset", "must be finite")
        for key in ("position_scale", "angle_scale", "force_scale"):
            value = getattr(self, key)
            within(value, (1e-3, 1e3), key)
        require(
            0 < self.rate_threshold_fraction < 1, "rate_threshold_fraction", "must be in (0, 1)"
        )
        require(
            math.isfinite(self.rate_gain_per_s) and self.rate_gain_per_s >= 0,
            "rate_gain_per_s",
            "must be finite and >= 0",
        )


# ------------------------------------------------------------------------------ kernels


@njit(cache=True)
def map_pose_to_world(world_map, device_pose, world_pose):
    """x_world = offset + scale x_device, per axis (seed 002 §4)."""
    m = world_map[0]
    for c in range(3):
        world_pose[c] = m.offset[c] + m.scale[c] * device_pose[c]


@njit(cache=True)
def map_pose_to_device(world_map, world_pose, device_pose):
    """Inverse of map_pose_to_world."""
    m = world_map[0]
    for c in range(3):
        device_pose[c] = (world_pose[c] - m.offset[c]) / m.scale[c]


@njit(cache=True)
def map_twist_to_world(world_map, device_twist, world_twist):
    """v_world = scale v_device + the offset's velocity (non-zero under rate control)."""
    m = world_map[0]
    for c in range(3):
        world_twist[c] = m.scale[c] * device_twist[c] + m.offset_rate[c]


@njit(cache=True)
def map_twist_to_device(world_map, world_twist, device_twist):
    """Inverse of map_twist_to_world."""
    m = world_map[0]
    for c in range(3):
        device_twist[c] = (world_twist[c] - m.offset_rate[c]) / m.scale[c]


@njit(cache=True)
def map_wrench_to_device(world_map, world_wrench, device_wrench):
    """F_device = force_scale scale F_world: then F_device . v_device equals force_scale
    times F_world . (scale v_device), so force_scale = 1 keeps the port power consistent."""
    m = world_map[0]
    for c in range(3):
        device_wrench[c] = m.force_scale * m.scale[c] * world_wrench[c]


@njit(cache=True)
def map_wrench_to_world(world_map, device_wrench, world_wrench):
    """Inverse of map_wrench_to_device."""
    m = world_map[0]
    for c in range(3):
        world_wrench[c] = device_wrench[c] / (m.force_scale * m.scale[c])


@njit(cache=True)
def map_rate_step(world_map, device_pose, dt):
    """Rate control (seed 002 §4): beyond the threshold the offset moves, outward, at
    rate_gain * scale * (|x| - threshold), so the workspace follows the handle. Returns
    whether rate control is active."""
    m = world_map[0]
    active = 0
    for c in range(3):
        excess = abs(device_pose[c]) - m.rate_threshold[c]
        rate = 0.0
        if m.rate_enabled == 1 and excess > 0.0:
            rate = math.copysign(m.rate_gain * m.scale[c] * excess, device_pose[c])
            active = 1
        m.offset_rate[c] = rate
        m.offset[c] += rate * dt
    m.rate_active = active
    return active == 1


@njit(cache=True)
def map_sensors_to_world(world_map, sensors, world_sensors):
    """A device reading (SENSOR_DTYPE, device frame) in the world frame.

    Pose and twist map as above; a wrench F maps to F / (force_scale s), an inertia or a
    Christoffel matrix entry (i, j) to M_ij / (force_scale s_i s_j), so M_d xdd = F holds in
    either frame. `frame_twist` is the offset's velocity: the part of the world twist that
    is the workspace moving (rate control), not the handle.
    """
    m = world_map[0]
    src = sensors[0]
    dst = world_sensors[0]
    fs = m.force_scale
    for c in range(3):
        s = m.scale[c]
        dst.pose[c] = m.offset[c] + s * src.pose[c]
        dst.twist[c] = s * src.twist[c] + m.offset_rate[c]
        dst.frame_twist[c] = m.offset_rate[c]
        dst.hand_wrench[c] = src.hand_wrench[c] / (fs * s)
        for k in range(3):
            g = fs * s * m.scale[k]
            dst.inertia[c, k] = src.inertia[c, k] / g
            dst.coriolis[c, k] = src.coriolis[c, k] / g
    for k in range(src.aux.shape[0]):
        dst.aux[k] = src.aux[k]
    dst.has_force_sensor = src.has_force_sensor
    dst.fault = src.fault


@njit(cache=True)
def map_command_to_device(world_map, world_wrench, device_limits, device_wrench):
    """The world-frame command as the device wrench, clipped at the device's own limits (the
    world-frame limits already bound it; this clip only removes round-off). A value that is
    not finite gives 0 on its axis: a clip alone would turn NaN into a full-limit force."""
    m = world_map[0]
    for c in range(3):
        v = m.force_scale * m.scale[c] * world_wrench[c]
        lim = device_limits[c]
        device_wrench[c] = min(lim, max(-lim, v)) if math.isfinite(v) else 0.0


# ------------------------------------------------------------------------------ the map


class DeviceWorldMap:
    """Device-to-world mapping x_world = offset + scale x_device with rate control near the
    device's motion limits (seed 002 §4). Wrenches map by force_scale * scale (power scale
    force_scale; see `map_wrench_to_device`). Methods write into `out` when given."""

    def __init__(
        self,
        offset: tuple[float, float, float],
        position_scale: float,
        angle_scale: float,
        force_scale: float,
        rate_threshold: tuple[float, float, float],
        rate_gain_per_s: float,
        rate_control: bool,
    ) -> None:
        self.record = np.zeros(1, MAP_DTYPE)
        m = self.record[0]
        m["offset"] = offset
        m["scale"] = (position_scale, position_scale, angle_scale)
        m["force_scale"] = force_scale
        m["rate_threshold"] = rate_threshold
        m["rate_gain"] = rate_gain_per_s
        m["rate_enabled"] = 1 if rate_control else 0

    @classmethod
    def identity(cls) -> DeviceWorldMap:
        """Scale 1, force scale 1, offset 0, no rate control: a device without its own map."""
        return cls((0.0, 0.0, 0.0), 1.0, 1.0, 1.0, (math.inf, math.inf, math.inf), 0.0, False)

    @classmethod
    def from_config(
        cls, section: WorldMapSection, motion_range: tuple[float, float, float]
    ) -> DeviceWorldMap:
        """The map of a config; rate thresholds are a fraction of the (x, y, yaw) half-range."""
        threshold = tuple(section.rate_threshold_fraction * r for r in motion_range)
        return cls(
            offset=section.offset,
            position_scale=section.position_scale,
            angle_scale=section.angle_scale,
            force_scale=section.force_scale,
            rate_threshold=(threshold[0], threshold[1], threshold[2]),
            rate_gain_per_s=section.rate_gain_per_s,
            rate_control=section.rate_control,
        )

    @property
    def offset(self) -> np.ndarray:
        """Current offset (world pose of the centred handle), a copy."""
        return np.array(self.record["offset"][0])

    @property
    def scale(self) -> np.ndarray:
        """(position, position, angle) scale, a copy."""
        return np.array(self.record["scale"][0])

    @property
    def force_scale(self) -> float:
        return float(self.record["force_scale"][0])

    def pose_to_world(self, device_pose: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(3) if out is None else out
        map_pose_to_world(self.record, device_pose, out)
        return out

    def pose_to_device(self, world_pose: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(3) if out is None else out
        map_pose_to_device(self.record, world_pose, out)
        return out

    def twist_to_world(self, device_twist: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(3) if out is None else out
        map_twist_to_world(self.record, device_twist, out)
        return out

    def twist_to_device(self, world_twist: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(3) if out is None else out
        map_twist_to_device(self.record, world_twist, out)
        return out

    def wrench_to_device(
        self, world_wrench: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        out = np.empty(3) if out is None else out
        map_wrench_to_device(self.record, world_wrench, out)
        return out

    def wrench_to_world(
        self, device_wrench: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        out = np.empty(3) if out is None else out
        map_wrench_to_world(self.record, device_wrench, out)
        return out

    def step(self, device_pose: np.ndarray, dt: float) -> bool:
        """Advance the offset under rate control by dt; returns whether it is active."""
        return bool(map_rate_step(self.record, device_pose, dt))

    def rate_control_active(self) -> bool:
        """Whether the last step moved the offset (the handle was beyond the threshold)."""
        return bool(self.record["rate_active"][0] == 1)
