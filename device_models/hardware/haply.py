"""Haply Inverse3 through Haply's Python binding `HaplyHardwareAPI` (extra: `haply`).

The binding talks to the device over a serial stream: `detect_inverse3s()` lists the ports,
`Inverse3(SerialStream(port))` opens one, `device_wakeup_dict()` wakes it (its reply names
the device), and each `end_effector_force([fx, fy, fz])` (N) commands a force, which the
device holds until the next command, and returns its (position, velocity) in m and m/s. One
call per tick both commands and reads: the reading `read` gives is the device's reply to the
previous tick's command (at most one period old), as in Haply's own samples.

The binding has no call that switches forces off or closes the device: the safe stop sends
zero force. The Inverse3 holds the last commanded force; if this process is killed between
two commands, nothing here can take that force off (docs/devices.md §6).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import DeviceError, DeviceModel
from haptic_local_model.device_models.hardware.base import (
    Bringup,
    HardwareConfig,
    PlanarHardware,
    serial_ports,
)

BINDING = "HaplyHardwareAPI"


@dataclass(frozen=True)
class Inverse3Config(HardwareConfig):
    """configs/devices/haply_inverse3.toml."""

    binding = BINDING
    extra = "haply"

    port: str = ""  # the serial port; "" = the first one detect_inverse3s() finds


class Inverse3Link:
    """The calls into HaplyHardwareAPI (base.VendorLink)."""

    def __init__(self, config: Inverse3Config) -> None:
        self.config = config
        self._api: Any = None
        self._device: Any = None
        self._position = np.zeros(3)
        self._velocity = np.zeros(3)

    def open(self) -> None:
        api = self._api = importlib.import_module(BINDING)
        port = self.config.port
        if not port:
            found = list(api.detect_inverse3s())
            if not found:
                raise DeviceError("no Inverse3 found (detect_inverse3s() lists no port)")
            port = str(found[0])
        self._device = api.Inverse3(api.SerialStream(port))
        self._device.device_wakeup_dict()
        self._reply(self._device.end_effector_force([0.0, 0.0, 0.0]))

    def _reply(self, reply: Any) -> None:
        position, velocity = reply
        self._position[:] = position
        self._velocity[:] = velocity

    def sample(self, position: np.ndarray, velocity: np.ndarray) -> int:
        position[:] = self._position
        velocity[:] = self._velocity
        return 0

    def send(self, force: np.ndarray) -> None:
        self._reply(self._device.end_effector_force([force[0], force[1], force[2]]))

    def stop(self) -> None:
        if self._device is not None:
            self._device.end_effector_force([0.0, 0.0, 0.0])
            self._device = None


def detect() -> list[str]:
    """The Inverse3s on the serial ports (detect_inverse3s); their serial numbers are read
    only on opening (device_wakeup_dict)."""
    api = importlib.import_module(BINDING)
    return [f"Inverse3 on {port} (its id is read on opening)" for port in api.detect_inverse3s()]


BRINGUP = Bringup(
    runtime_modules=(),  # the binding talks to the serial port itself: no vendor runtime
    runtime_fix="",
    access_fix="the serial port (/dev/ttyACM*) must be readable: sudo usermod -aG dialout "
    "$USER, then log in again",
    detect=detect,
    nodes=serial_ports,
)


class Inverse3(PlanarHardware):
    name = "haply_inverse3"

    def __init__(self, config: Inverse3Config) -> None:
        super().__init__(config, Inverse3Link(config))


MODEL = DeviceModel(
    Inverse3Config,
    Inverse3,
    "haply_inverse3",
    "Haply Inverse3 (hardware; extra `haply`: HaplyHardwareAPI)",
    simulated=False,
)
