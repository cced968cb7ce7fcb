"""Force Dimension devices (delta, omega, sigma, lambda) through `forcedimension-core`
(extra: `forcedimension`), the maintained Python binding of the Force Dimension SDK.

Start-up: `drd.open()` (the device's ID, -1 on failure), calibration by `drd.autoInit` when
the device is not initialised yet (the device moves itself: `calibrate = true` allows it),
`drd.stop(True, ID)` hands the device from the SDK's regulation to this loop with forces on,
`dhd.setMaxForce` sets the SDK's own force cap to this config's limit, `dhd.enableForce`.
Per tick: `dhd.getPosition` and `dhd.getLinearVelocity` (m, m/s), `dhd.setForce` (N). The
binding returns error codes (-1) rather than raising: a failed call raises here, with
`dhd.errorGetLastStr()`, which ends the run and sends the device safe. Safe stop: zero force,
`dhd.stop` (forces off, brakes on), `dhd.close`; a code of failure from any of them raises
once all three are made (the safe stop fails, loudly).
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
    usb_nodes,
)

USB_VENDOR_ID = "1451"  # Force Dimension's (its udev rule matches it)
BINDING = "forcedimension_core"
SDK_ERROR = -1


@dataclass(frozen=True)
class ForceDimensionConfig(HardwareConfig):
    """configs/devices/forcedimension.toml."""

    binding = BINDING
    extra = "forcedimension"

    calibrate: bool = False  # may drd.autoInit move the device to calibrate it?


class ForceDimensionLink:
    """The calls into forcedimension_core (base.VendorLink)."""

    def __init__(self, config: ForceDimensionConfig) -> None:
        self.config = config
        self._dhd: Any = None
        self.id = -1
        self._pos = [0.0, 0.0, 0.0]  # the binding fills these in place
        self._vel = [0.0, 0.0, 0.0]
        self._force = [0.0, 0.0, 0.0]

    def _check(self, code: int, call: str) -> int:
        if code <= SDK_ERROR:
            raise DeviceError(f"Force Dimension {call} failed: {self._dhd.errorGetLastStr()}")
        return code

    def open(self) -> None:
        dhd = self._dhd = importlib.import_module(f"{BINDING}.dhd")
        drd = importlib.import_module(f"{BINDING}.drd")
        self.id = self._check(drd.open(), "drd.open")  # the first device found
        if not drd.isInitialized(self.id):
            if not self.config.calibrate:  # (the adapter then closes it: stop())
                raise DeviceError(
                    "the Force Dimension device is not calibrated; set calibrate = true to "
                    "let drd.autoInit move it, or calibrate it with the maker's tool"
                )
            self._check(drd.autoInit(self.id), "drd.autoInit")
        self._check(drd.stop(True, self.id), "drd.stop")
        self._check(dhd.setMaxForce(float(self.config.max_wrench[0]), self.id), "setMaxForce")
        self._check(dhd.enableForce(True, self.id), "dhd.enableForce")

    def sample(self, position: np.ndarray, velocity: np.ndarray) -> int:
        dhd, pos, vel = self._dhd, self._pos, self._vel
        self._check(dhd.getPosition(pos, self.id), "dhd.getPosition")
        fault = 1 if dhd.getLinearVelocity(vel, self.id) <= SDK_ERROR else 0
        position[0], position[1], position[2] = pos
        velocity[0], velocity[1], velocity[2] = vel
        return fault

    def send(self, force: np.ndarray) -> None:
        f = self._force
        f[0], f[1], f[2] = float(force[0]), float(force[1]), float(force[2])
        self._check(self._dhd.setForce(f, self.id), "dhd.setForce")

    def stop(self) -> None:
        """Zero force, forces off and brakes on, closed: every call is made, and one that
        fails (the binding's -1) raises after them, so the safe stop reports it."""
        dhd = self._dhd
        if dhd is None:
            return
        self._dhd = None
        codes = {}
        try:
            codes["dhd.setForce"] = dhd.setForce([0.0, 0.0, 0.0], self.id)
        finally:
            codes["dhd.stop"] = dhd.stop(self.id)  # forces off, brakes on
            codes["dhd.close"] = dhd.close(self.id)
        failed = [call for call, code in codes.items() if code <= SDK_ERROR]
        if failed:
            raise DeviceError(
                f"Force Dimension {', '.join(failed)} failed: {dhd.errorGetLastStr()}"
            )


def detect() -> list[str]:
    """How many Force Dimension devices the SDK sees (dhd.getDeviceCount); their model and
    serial number are read only on opening."""
    dhd = importlib.import_module(f"{BINDING}.dhd")
    count = int(dhd.getDeviceCount())
    return [f"Force Dimension device #{i} (model and serial read on opening)" for i in range(count)]


BRINGUP = Bringup(
    # importing dhd and drd loads the SDK's libdhd and libdrd
    runtime_modules=(f"{BINDING}.dhd", f"{BINDING}.drd"),
    runtime_fix="install the Force Dimension SDK (https://www.forcedimension.com/software) "
    "and put its lib/ directory on LD_LIBRARY_PATH",
    access_fix="USB access: install the SDK's udev rule (its README) or the device is seen "
    "but cannot be opened",
    detect=detect,
    nodes=lambda: usb_nodes(USB_VENDOR_ID),
)


class ForceDimension(PlanarHardware):
    name = "forcedimension"

    def __init__(self, config: ForceDimensionConfig) -> None:
        super().__init__(config, ForceDimensionLink(config))


MODEL = DeviceModel(
    ForceDimensionConfig,
    ForceDimension,
    "forcedimension",
    "Force Dimension delta/omega/sigma (hardware; extra `forcedimension`: forcedimension-core)",
    simulated=False,
)
