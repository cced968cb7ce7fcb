"""The ideal device: a task-space point mass with no friction and perfect sensing.

Seed 000's simulations assume this device (M_d = identity): M_d xdd = F_h + u. Commands are
clipped at `max_wrench`; the pose and the hand wrench are sensed exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from device_models.base import FAULT_NONE, FAULT_SATURATED, DeviceLimits, DeviceRenderingSpec
from device_models.world_map import DeviceWorldMap, WorldMapSection
from shared.config import Vec3, load_dataclass, require


@dataclass(frozen=True)
class IdealDeviceConfig:
    """Parameters of configs/devices/ideal.toml."""

    inertia: Vec3 = (1.0, 1.0, 0.001)  # kg, kg, kg m^2 (diagonal M_d)
    max_wrench: Vec3 = (50.0, 50.0, 5.0)  # N, N, N m
    workspace_half_extent: Vec3 = (1.0, 1.0, 10.0)  # m, m, rad around the home pose
    max_rate_hz: float = 10000.0
    rendering: DeviceRenderingSpec = field(default_factory=DeviceRenderingSpec)
    world_map: WorldMapSection | None = None  # None: scale 1, the engine sets the offset

    def __post_init__(self) -> None:
        require(all(v > 0 for v in self.inertia), "inertia", "must be > 0")
        require(all(v > 0 for v in self.max_wrench), "max_wrench", "must be > 0")

    @classmethod
    def from_toml_dict(cls, data: dict[str, Any], source: str) -> IdealDeviceConfig:
        return load_dataclass(cls, data, source)


@njit(cache=True)
def _clip_command(wrench, max_wrench, held):
    """Hold the command (zero-order hold) clipped at the limits; NaN -> zero. Returns fault."""
    fault = FAULT_NONE
    for c in range(3):
        v = wrench[c]
        if not np.isfinite(v):
            v = 0.0
            fault = FAULT_SATURATED
        if v > max_wrench[c]:
            v = max_wrench[c]
            fault = FAULT_SATURATED
        elif v < -max_wrench[c]:
            v = -max_wrench[c]
            fault = FAULT_SATURATED
        held[c] = v
    return fault


@njit(cache=True)
def _advance_point_mass(pose, twist, inertia, held, hand, dt):
    """Semi-implicit Euler of M xdd = F_h + u over dt."""
    for c in range(3):
        twist[c] += dt * (hand[c] + held[c]) / inertia[c]
        pose[c] += dt * twist[c]


@njit(cache=True)
def _read_ideal(pose, twist, inertia, hand, fault, sensors):
    s = sensors[0]
    for c in range(3):
        s.pose[c] = pose[c]
        s.twist[c] = twist[c]
        s.hand_wrench[c] = hand[c]
        for k in range(3):
            s.inertia[c, k] = inertia[c] if c == k else 0.0
            s.coriolis[c, k] = 0.0
    s.has_force_sensor = 1
    s.fault = fault


class IdealDevice:
    """Seed 000's transparent device; implements device_models.base.SimulatedDevice."""

    name = "ideal"
    aux_names: tuple[str, ...] = ()

    def __init__(self, config: IdealDeviceConfig) -> None:
        self.config = config
        self.rendering = config.rendering
        self.world_map: DeviceWorldMap | None = None
        if config.world_map is not None:
            self.world_map = DeviceWorldMap.from_config(
                config.world_map, config.workspace_half_extent
            )
        self._inertia = np.array(config.inertia, dtype=np.float64)
        self._max_wrench = np.array(config.max_wrench, dtype=np.float64)
        self._pose = np.zeros(3)
        self._twist = np.zeros(3)
        self._held = np.zeros(3)
        self._hand = np.zeros(3)
        self._fault = FAULT_NONE

    def limits(self) -> DeviceLimits:
        h = self.config.workspace_half_extent
        return DeviceLimits(
            max_wrench=self.config.max_wrench,
            workspace_min=(-h[0], -h[1], -h[2]),
            workspace_max=h,
            max_rate_hz=self.config.max_rate_hz,
        )

    def servo_plant(self) -> tuple[np.ndarray, float]:
        return np.zeros(3), 0.0  # no damping, exact twist

    def reset(self, pose: np.ndarray) -> None:
        self._pose[:] = pose
        self._twist[:] = 0.0
        self._held[:] = 0.0

    def sense_hand(self, hand_wrench: np.ndarray) -> None:
        """The simulated hand's wrench this tick (what a perfect force sensor reads)."""
        self._hand[:] = hand_wrench

    def read(self, sensors: np.ndarray) -> None:
        _read_ideal(self._pose, self._twist, self._inertia, self._hand, self._fault, sensors)

    def command(self, wrench: np.ndarray) -> np.ndarray:
        self._fault = _clip_command(wrench, self._max_wrench, self._held)
        return self._held

    def safe_stop(self) -> None:
        self._held[:] = 0.0

    def advance(self, dt: float, hand_wrench: np.ndarray) -> None:
        _advance_point_mass(self._pose, self._twist, self._inertia, self._held, hand_wrench, dt)

    def true_state(self, pose: np.ndarray, twist: np.ndarray) -> None:
        pose[:] = self._pose
        twist[:] = self._twist
