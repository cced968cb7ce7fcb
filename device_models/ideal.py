"""The ideal device: a task-space point mass with perfect sensing.

Seed 000's simulations assume this device (M_d = identity): M_d xdd = F_h + u. Commands are
clipped at `max_wrench` and held (zero-order hold); the pose and the hand wrench are sensed
exactly. Optionally (`viscous_damping`, `substeps`) the mass has physical viscous damping b,
M_d xdd = F_h + u - b xd, integrated in `substeps` steps per tick: the continuous, damped
plant of Colgate and Schenkel's passivity condition b > K T / 2 + |B| (benchmarks/stability.py).
The defaults (no damping, one step per tick) are seed 000's device, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.device_models.base import (
    DAMPING_RANGE,
    FAULT_NONE,
    FAULT_SATURATED,
    DeviceLimits,
    DeviceModel,
    DeviceRenderingSpec,
    require_device_limits,
)
from haptic_local_model.device_models.common import KernelDevice, NoiseBuffer
from haptic_local_model.device_models.kernels import register_model
from haptic_local_model.device_models.world_map import DeviceWorldMap, WorldMapSection
from haptic_local_model.shared.config import Vec3, load_dataclass, require, within, within_all


@dataclass(frozen=True)
class IdealDeviceConfig:
    """Parameters of configs/devices/ideal.toml."""

    inertia: Vec3 = (1.0, 1.0, 0.001)  # kg, kg, kg m^2 (diagonal M_d)
    max_wrench: Vec3 = (50.0, 50.0, 5.0)  # N, N, N m
    workspace_half_extent: Vec3 = (1.0, 1.0, 10.0)  # m, m, rad around the home pose
    max_rate_hz: float = 10000.0
    viscous_damping: Vec3 = (0.0, 0.0, 0.0)  # b: N s/m, N s/m, N m s/rad (physical friction)
    substeps: int = 1  # semi-implicit Euler steps per advance (per tick)
    rendering: DeviceRenderingSpec = field(default_factory=DeviceRenderingSpec)
    world_map: WorldMapSection | None = None  # None: scale 1, the engine sets the offset

    def __post_init__(self) -> None:
        require(all(v > 0 for v in self.inertia), "inertia", "must be > 0")
        require_device_limits(self.max_wrench, self.max_rate_hz)
        within_all(self.viscous_damping, DAMPING_RANGE, "viscous_damping")
        within(self.substeps, (1, 100), "substeps")  # each one costs in every tick

    @classmethod
    def from_toml_dict(cls, data: dict[str, Any], source: str) -> IdealDeviceConfig:
        return load_dataclass(cls, data, source)


#: The ideal device's parameters and state, as kernel records.
PARAMS_DTYPE = np.dtype(
    [
        ("inertia", np.float64, (3,)),
        ("max_wrench", np.float64, (3,)),
        ("viscous_damping", np.float64, (3,)),
        ("substeps", np.int64),
    ]
)
STATE_DTYPE = np.dtype(
    [
        ("pose", np.float64, (3,)),
        ("twist", np.float64, (3,)),
        ("held", np.float64, (3,)),  # the held (clipped) command
        ("hand_wrench", np.float64, (3,)),
        ("fault", np.int64),
    ]
)


@njit(cache=True)
def command(params, state, wrench):
    """Hold the command (zero-order hold) clipped at the limits; NaN -> zero."""
    st = state[0]
    max_wrench = params[0].max_wrench
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
        st.held[c] = v
    st.fault = fault


@njit(cache=True)
def advance(params, state, work, dt, hand, normals, noise_index):
    """Semi-implicit Euler of M xdd = F_h + u - b xd over dt in `substeps` equal steps, the
    hand's wrench and the command u held (zero-order hold). Without damping and with one
    step this is the original single step, term for term."""
    st = state[0]
    inertia = params[0].inertia
    damping = params[0].viscous_damping
    n = params[0].substeps
    h = dt / n if n > 1 else dt
    for _ in range(n):
        for c in range(3):
            force = hand[c] + st.held[c]
            if damping[c] != 0.0:
                force -= damping[c] * st.twist[c]
            st.twist[c] += h * force / inertia[c]
            st.pose[c] += h * st.twist[c]


@njit(cache=True)
def read(params, state, sensors):
    st = state[0]
    inertia = params[0].inertia
    s = sensors[0]
    for c in range(3):
        s.pose[c] = st.pose[c]
        s.twist[c] = st.twist[c]
        s.hand_wrench[c] = st.hand_wrench[c]
        for k in range(3):
            s.inertia[c, k] = inertia[c] if c == k else 0.0
            s.coriolis[c, k] = 0.0
    s.has_force_sensor = 1
    s.fault = st.fault


@njit(cache=True)
def noise_needed(params, dt):
    return 0  # perfect sensing


@njit(cache=True)
def applied(state):
    return state[0].held


KERNELS = register_model(PARAMS_DTYPE, globals())  # true_state, sense_hand: the defaults


class IdealDevice(KernelDevice):
    """Seed 000's transparent device; implements device_models.base.SimulatedDevice."""

    name = "ideal"
    aux_names: tuple[str, ...] = ()
    KERNELS = KERNELS

    def __init__(self, config: IdealDeviceConfig) -> None:
        self.config = config
        world_map: DeviceWorldMap | None = None
        if config.world_map is not None:
            world_map = DeviceWorldMap.from_config(config.world_map, config.workspace_half_extent)
        params = np.zeros(1, PARAMS_DTYPE)
        params[0]["inertia"] = config.inertia
        params[0]["max_wrench"] = config.max_wrench
        params[0]["viscous_damping"] = config.viscous_damping
        params[0]["substeps"] = config.substeps
        h = config.workspace_half_extent
        limits = DeviceLimits(
            max_wrench=config.max_wrench,
            workspace_min=(-h[0], -h[1], -h[2]),
            workspace_max=h,
            max_rate_hz=config.max_rate_hz,
        )
        records = (params, np.zeros(1, STATE_DTYPE), np.zeros(1), NoiseBuffer(0, 0))
        super().__init__(records, limits, config.rendering, world_map)

    def servo_plant(self) -> tuple[np.ndarray, float]:
        return np.array(self.config.viscous_damping, dtype=np.float64), 0.0  # exact twist

    def reset(self, pose: np.ndarray) -> None:
        st = self.state[0]
        st["pose"] = pose
        st["twist"] = 0.0
        st["held"] = 0.0


#: The entry point of this model (pyproject.toml, group haptic_local_model.devices).
MODEL = DeviceModel(
    IdealDeviceConfig, IdealDevice, "ideal", "a point mass with exact sensing (no hardware)"
)
