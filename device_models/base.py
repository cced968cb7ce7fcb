"""The device interface a hardware driver or a simulated device implements.

The haptic loop talks to a device only through this interface: it reads the sensors into a
preallocated record, commands a task-space wrench, and asks for limits and health. A real
driver implements `Device`; simulated devices also implement `SimulatedDevice.advance`, which
moves their physics forward over one tick under the held command and the true hand wrench.
All arrays are planar task space: pose (x, y, theta) in m and rad, twist (vx, vy, omega),
wrench (fx, fy, tau) in N and N*m, in the device's own frame; the engine maps them to the
world through the device's `world_map` (device_models/world_map.py) when it has one.
docs/devices.md says what a driver must implement and guarantee.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, Protocol, runtime_checkable

import numpy as np

from haptic_local_model.shared.config import Vec3, require, within

if TYPE_CHECKING:
    from haptic_local_model.device_models.common import NoiseBuffer
    from haptic_local_model.device_models.kernels import DeviceRecords
    from haptic_local_model.device_models.world_map import DeviceWorldMap

#: Entries of SENSOR_DTYPE.aux: device-specific readings the engine logs as `device_aux`.
AUX_SIZE = 8

#: One reading of the device's sensors, as the haptic loop consumes it (device frame).
SENSOR_DTYPE = np.dtype(
    [
        ("pose", np.float64, (3,)),  # measured (quantised / noisy) pose
        ("twist", np.float64, (3,)),  # estimated twist
        ("inertia", np.float64, (3, 3)),  # task-space inertia M_d(x)
        ("coriolis", np.float64, (3, 3)),  # task-space Christoffel matrix C_d(x, xd)
        ("hand_wrench", np.float64, (3,)),  # measured hand wrench (zeros without a sensor)
        ("has_force_sensor", np.int64),
        ("fault", np.int64),  # non-zero: the device reports a fault (see device docs)
        ("aux", np.float64, (AUX_SIZE,)),  # device-specific readings (the device's aux_names)
        ("frame_twist", np.float64, (3,)),  # world frame only: the offset's velocity; 0 here
    ]
)

#: Health flags a device may report in SENSOR_DTYPE.fault (bit mask).
FAULT_NONE = 0
FAULT_WORKSPACE = 1  # outside the workspace or at a stop
FAULT_SINGULAR = 2  # at or near a kinematic singularity
FAULT_SATURATED = 4  # the last command was clipped at an actuator limit
FAULT_INVALID_COMMAND = 8  # the last command was not finite: zero force was sent instead


#: The stated ranges of every device's limits (`docs/devices.md`): a desktop haptic device
#: renders at most hundreds of N, an exoskeleton thousands; a limit beyond these is a typo
#: that would switch the force bound off, not a device.
FORCE_LIMIT_RANGE_N = (1e-3, 1e4)
TORQUE_LIMIT_RANGE_NM = (1e-5, 1e3)
RATE_RANGE_HZ = (1.0, 100_000.0)
#: A device's own physical damping (N s/m, N m s/rad) and inertia (kg, kg m^2): beyond these a
#: tick's explicit integration of the simulated device blows up (a typo, not a device)
DAMPING_RANGE = (0.0, 1e4)
INERTIA_RANGE = (0.0, 100.0)


class DeviceError(RuntimeError):
    """A device (its driver or the vendor's binding) failed: not found, not calibrated, not
    answering. The haptic server sends the device to its safe state and names the failure."""


class SafeStopError(DeviceError):
    """The device could not be sent to its safe state: it may still apply force."""


def require_device_limits(max_wrench: tuple[float, float, float], max_rate_hz: float) -> None:
    """A device config's max_wrench and max_rate_hz within the stated ranges above."""
    for axis, value in enumerate(max_wrench):
        low, high = FORCE_LIMIT_RANGE_N if axis < 2 else TORQUE_LIMIT_RANGE_NM
        within(value, (low, high), f"max_wrench[{axis}]", "N" if axis < 2 else "N m")
    within(max_rate_hz, RATE_RANGE_HZ, "max_rate_hz", "Hz")


@dataclass(frozen=True)
class DeviceLimits:
    """What the device can do: the loop never commands beyond these."""

    max_wrench: tuple[float, float, float]  # N, N, N*m (per axis, task space)
    workspace_min: tuple[float, float, float]
    workspace_max: tuple[float, float, float]
    max_rate_hz: float


@dataclass(frozen=True)
class DeviceRenderingSpec:
    """The `[rendering]` table of a device config: gains that belong to the device.

    The servo of `virtual_coupling_foh` (seed 002 §4), in the device's own frame:
    f_dev = f_g + K_p (x_goal - x_dev) - K_v xd_dev. Defaults are seed 002's table in SI
    (K_p 4 N/mm, 25 N m/rad; K_v 0.1 N/mm/s, 0.5 N m s/rad). `setpoint_hold` chooses the
    seed's first-order hold of the sim's setpoints or a plain zero-order hold (for
    comparison). `safe_damping` is the only force of the safe state.
    """

    foh_stiffness: Vec3 = (4000.0, 4000.0, 25.0)  # K_p: N/m, N/m, N m/rad
    foh_damping: Vec3 = (100.0, 100.0, 0.5)  # K_v: N s/m, N s/m, N m s/rad
    setpoint_hold: Literal["first_order", "zero_order"] = "first_order"
    gravity_feedforward: Vec3 = (0.0, 0.0, 0.0)  # f_g: N, N, N m, always added (FOH)
    safe_damping: Vec3 = (5.0, 5.0, 0.01)  # N s/m, N s/m, N m s/rad

    def __post_init__(self) -> None:
        for key in ("foh_stiffness", "foh_damping", "safe_damping"):
            values = getattr(self, key)
            require(all(math.isfinite(v) and v >= 0 for v in values), key, "must be >= 0")
        require(
            all(math.isfinite(v) for v in self.gravity_feedforward),
            "gravity_feedforward",
            "must be finite",
        )


@runtime_checkable
class Device(Protocol):
    """What a hardware driver must provide to the haptic loop.

    Besides these, the engine uses two optional attributes: `world_map` (a
    device_models.world_map.DeviceWorldMap; without one the device maps to the world with
    scale 1 and an offset the engine sets: read it through `world_map_of`) and `aux_names`
    (what SENSOR_DTYPE.aux holds).
    """

    name: str
    rendering: DeviceRenderingSpec

    def limits(self) -> DeviceLimits: ...

    def read(self, sensors: np.ndarray) -> None:
        """Fill `sensors` (a 1-element SENSOR_DTYPE array) with the newest reading."""

    def command(self, wrench: np.ndarray) -> np.ndarray:
        """Command a task-space wrench; returns the wrench actually applied after limits."""

    def safe_stop(self) -> None:
        """Put the device into its safe state (no commanded force)."""


@runtime_checkable
class SimulatedDevice(Device, Protocol):
    """A device whose physics this process simulates.

    `records` is what the compiled tick runs the model's kernels on (its params, state, work,
    noise normals and noise index: device_models.kernels); `noise` is the buffer behind the
    normals, which the Python side refills when a compiled tick reports it spent."""

    records: DeviceRecords
    noise: NoiseBuffer

    def reset(self, pose: np.ndarray) -> None:
        """Place the device at rest at `pose` (device frame)."""

    def sense_hand(self, hand_wrench: np.ndarray) -> None:
        """The simulated hand's true wrench this tick (what a force sensor, if any, measures)."""

    def advance(self, dt: float, hand_wrench: np.ndarray) -> None:
        """Move the physics forward by dt under the held command and the true hand wrench."""

    def true_state(self, pose: np.ndarray, twist: np.ndarray) -> None:
        """Write the true (noise-free) pose and twist: what the simulated hand holds."""

    def servo_plant(self) -> tuple[np.ndarray, float]:
        """What a servo on this device acts against at home: the passive damping per axis
        (N s/m, N s/m, N m s/rad) and the cutoff of its twist estimate (Hz; 0: exact)."""


class DeviceModel(NamedTuple):
    """A device model as a driver package registers it (entry-point group
    `haptic_local_model.devices`, docs/devices.md): its config class (with
    `from_toml_dict(table, source)`), the factory that builds the device from a config, the
    config file it ships with (a bare name: configs/devices/<name>.toml of this project; else
    a path, e.g. a file inside the driver's own package), one line on what it is, and
    whether it is a simulation (False for a hardware driver: building one opens the device,
    so only the haptic server does; warm-ups and device tests leave it out)."""

    config_cls: Any
    factory: Callable[[Any], Device]
    config: str
    description: str
    simulated: bool = True  # False: it drives hardware (building it opens the device)


def world_map_of(device: Device) -> DeviceWorldMap:
    """The device's map onto the world: its own `world_map` (shared: rate control moves its
    offset), or scale 1 with an offset its user sets. The one place the optional attribute
    is read."""
    from haptic_local_model.device_models.world_map import DeviceWorldMap

    own: DeviceWorldMap | None = getattr(device, "world_map", None)
    return own if own is not None else DeviceWorldMap.identity()


def world_limits(device: Device) -> np.ndarray:
    """The device's max_wrench in the world frame: F_world = F_device / (scale force_scale)
    (device_models/world_map.py)."""
    m = world_map_of(device).record[0]
    return np.asarray(device.limits().max_wrench, np.float64) / (m["scale"] * m["force_scale"])
