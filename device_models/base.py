"""The device interface a hardware driver or a simulated device implements.

The haptic loop talks to a device only through this interface: it reads the sensors into a
preallocated record, commands a task-space wrench, and asks for limits and health. A real
driver implements `Device`; simulated devices also implement `SimulatedDevice.advance`, which
moves their physics forward over one tick under the held command and the true hand wrench.
All arrays are planar task space: pose (x, y, theta) in m and rad, twist (vx, vy, omega),
wrench (fx, fy, tau) in N and N*m.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

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
    ]
)

#: Health flags a device may report in SENSOR_DTYPE.fault (bit mask).
FAULT_NONE = 0
FAULT_WORKSPACE = 1  # outside the workspace or at a stop
FAULT_SINGULAR = 2  # at or near a kinematic singularity
FAULT_SATURATED = 4  # the last command was clipped at an actuator limit


@dataclass(frozen=True)
class DeviceLimits:
    """What the device can do: the loop never commands beyond these."""

    max_wrench: tuple[float, float, float]  # N, N, N*m (per axis, task space)
    workspace_min: tuple[float, float, float]
    workspace_max: tuple[float, float, float]
    max_rate_hz: float


class Device(Protocol):
    """What a hardware driver must provide to the haptic loop."""

    name: str

    def limits(self) -> DeviceLimits: ...

    def read(self, sensors: np.ndarray) -> None:
        """Fill `sensors` (a 1-element SENSOR_DTYPE array) with the newest reading."""

    def command(self, wrench: np.ndarray) -> np.ndarray:
        """Command a task-space wrench; returns the wrench actually applied after limits."""

    def safe_stop(self) -> None:
        """Put the device into its safe state (no commanded force)."""


class SimulatedDevice(Device, Protocol):
    """A device whose physics this process simulates."""

    def reset(self, pose: np.ndarray) -> None:
        """Place the device at rest at `pose` (device frame)."""

    def sense_hand(self, hand_wrench: np.ndarray) -> None:
        """The simulated hand's true wrench this tick (what a force sensor, if any, measures)."""

    def advance(self, dt: float, hand_wrench: np.ndarray) -> None:
        """Move the physics forward by dt under the held command and the true hand wrench."""

    def true_state(self, pose: np.ndarray, twist: np.ndarray) -> None:
        """Write the true (noise-free) pose and twist: what the simulated hand holds."""
