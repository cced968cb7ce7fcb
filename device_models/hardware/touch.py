"""3D Systems Touch (and other OpenHaptics devices) through `pyOpenHaptics` (extra: `touch`).

OpenHaptics runs its own servo thread (the HD scheduler, 1 kHz): `HapticDevice(callback=...,
device_name=..., scheduler_type="async")` initialises the device, enables force output and
schedules the callback, which runs in that thread between a begin and an end frame. The
callback here reads the handle's transform (`hd.get_transform()`, mm; position in row 3),
estimates the velocity from it, and sets the force (`hd.set_force`, N) this loop last
commanded. The loop's `read` and `command` only exchange these values with the callback.

The callback is also the device-side watchdog: a command older than `command_timeout_ms`
(this loop stopped commanding: it hung or died without its safe stop) is replaced by zero
force; a servo silent for `servo_timeout_ms` (OpenHaptics unschedules a callback after an
error) stops the run, unless it ticks once the loop has let go of the CPU and the GIL for
`SERVO_GRACE_S`: a servo only kept from running (its process descheduled on a loaded
machine, the loop's thread holding the CPU at real-time priority) is alive. The callback is
Python, so it takes the GIL every servo tick: the adapter shortens CPython's switch interval
so it does not wait behind the loop's thread for the default 5 ms. Safe stop: zero force,
then `HapticDevice.close()` (scheduler stopped, device disabled).
"""

from __future__ import annotations

import importlib
import math
import sys
import threading
import time
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
from haptic_local_model.shared.config import within
from haptic_local_model.shared.timing import GIL_SWITCH_INTERVAL_S

BINDING = "pyOpenHaptics"
MM = 1e-3
STOP_WAIT_S = 0.05  # the safe stop waits this long at most for the servo to send zero
#: how long a read lets a silent servo tick before it calls it stopped: 20 servo periods
SERVO_GRACE_S = 0.02


@dataclass(frozen=True)
class TouchConfig(HardwareConfig):
    """configs/devices/touch.toml."""

    binding = BINDING
    extra = "touch"

    device_name: str = "Default Device"  # as named in the Touch setup tool
    command_timeout_ms: float = 20.0  # the callback's watchdog: older commands -> zero force
    servo_timeout_ms: float = 100.0  # the servo silent this long: it has stopped (an error)
    velocity_cutoff_hz: float = 100.0  # low-pass of the differentiated position

    def __post_init__(self) -> None:
        super().__post_init__()
        within(self.command_timeout_ms, (1.0, 1000.0), "command_timeout_ms", "ms")
        within(self.servo_timeout_ms, (10.0, 1000.0), "servo_timeout_ms", "ms")
        within(self.velocity_cutoff_hz, (1.0, 1000.0), "velocity_cutoff_hz", "Hz")


class TouchLink:
    """The calls into pyOpenHaptics (base.VendorLink); the servo callback runs in the HD
    scheduler's thread, so the values it shares with the loop are guarded by a lock."""

    def __init__(self, config: TouchConfig) -> None:
        self.config = config
        self._lock = threading.Lock()
        self._position = np.zeros(3)  # m, written by the callback
        self._velocity = np.zeros(3)
        self._force = [0.0, 0.0, 0.0]  # N, the loop's newest command
        self._commanded_ns = 0  # when (monotonic); 0: nothing commanded yet
        self._timeout_ns = int(config.command_timeout_ms * 1e6)
        self._servo_timeout_ns = int(config.servo_timeout_ms * 1e6)
        self._last_ns = 0
        self._zero = [0.0, 0.0, 0.0]
        self._out = [0.0, 0.0, 0.0]  # what the servo sets (its thread only)
        self.servo_ticks = 0
        self._device: Any = None
        self._hd: Any = None

    def open(self) -> None:
        # the servo callback is Python: it needs the GIL every millisecond, and must not wait
        # behind the loop's thread for CPython's default 5 ms switch interval
        sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_INTERVAL_S))
        self._hd = importlib.import_module(f"{BINDING}.hd")
        callback = importlib.import_module(f"{BINDING}.hd_callback").hd_callback
        device_cls = importlib.import_module(f"{BINDING}.hd_device").HapticDevice
        self._callback = callback(self._servo)  # kept: the scheduler holds only a pointer
        self._device = device_cls(
            callback=self._callback, device_name=self.config.device_name, scheduler_type="async"
        )
        deadline = time.monotonic() + 1.0
        while self.servo_ticks == 0:  # the first reading, before the loop asks for one
            if time.monotonic() > deadline:
                self.stop()
                raise DeviceError(
                    f"Touch {self.config.device_name!r}: the servo callback never ran"
                )
            time.sleep(0.001)

    def _servo(self) -> None:
        """One servo tick of the HD scheduler (its thread): read, then set the force."""
        hd = self._hd
        transform = hd.get_transform()
        now = time.monotonic_ns()
        x, y, z = transform[3][0] * MM, transform[3][1] * MM, transform[3][2] * MM
        with self._lock:
            pos, vel = self._position, self._velocity
            if self._last_ns:
                dt = (now - self._last_ns) * 1e-9
                if dt > 0:
                    a = 1.0 - math.exp(-2.0 * math.pi * self.config.velocity_cutoff_hz * dt)
                    vel[0] += a * ((x - pos[0]) / dt - vel[0])
                    vel[1] += a * ((y - pos[1]) / dt - vel[1])
                    vel[2] += a * ((z - pos[2]) / dt - vel[2])
            pos[0], pos[1], pos[2] = x, y, z
            self._last_ns = now
            fresh = self._commanded_ns and now - self._commanded_ns <= self._timeout_ns
            out = self._out  # a copy made under the lock: send() may rewrite _force meanwhile
            if fresh:
                out[0], out[1], out[2] = self._force
            else:
                out[0] = out[1] = out[2] = 0.0
            self.servo_ticks += 1
        hd.set_force(out)

    def sample(self, position: np.ndarray, velocity: np.ndarray) -> int:
        """The servo's newest reading; a servo that has not run for `servo_timeout_ms`
        (OpenHaptics unscheduled the callback after an error) stops the run."""
        if time.monotonic_ns() - self._last_ns > self._servo_timeout_ns and not self._ticks():
            raise DeviceError(
                f"Touch {self.config.device_name!r}: the servo callback has not run for "
                f"{self.config.servo_timeout_ms:g} ms"
            )
        with self._lock:
            position[:] = self._position
            velocity[:] = self._velocity
        return 0

    def _ticks(self) -> bool:
        """Whether the servo ticks while this thread sleeps (releasing the GIL and, at real-time
        priority, its CPU) for up to SERVO_GRACE_S: a starved servo does, a stopped one not.
        Seen once in a clean-clone CI: a living servo silent past 100 ms before the loop's
        first force, the run stopped as if the device had failed."""
        ticks = self.servo_ticks
        deadline = time.monotonic() + SERVO_GRACE_S
        while time.monotonic() < deadline:
            time.sleep(0.0005)
            if self.servo_ticks != ticks:
                return True
        return False

    def send(self, force: np.ndarray) -> None:
        with self._lock:
            f = self._force
            f[0], f[1], f[2] = float(force[0]), float(force[1]), float(force[2])
            self._commanded_ns = time.monotonic_ns()

    def stop(self) -> None:
        """Zero force, sent by the servo's next ticks (OpenHaptics sets forces only inside
        its frames), then the scheduler stopped and the device disabled."""
        with self._lock:
            self._force[:] = self._zero
            self._commanded_ns = time.monotonic_ns()
            ticks = self.servo_ticks
        device, self._device = self._device, None
        if device is None:
            return
        deadline = time.monotonic() + STOP_WAIT_S
        while self.servo_ticks < ticks + 2 and time.monotonic() < deadline:
            time.sleep(0.0005)
        device.close()


BRINGUP = Bringup(
    # importing hd loads OpenHaptics' libHD (an OSError when it is not installed)
    runtime_modules=(f"{BINDING}.hd",),
    runtime_fix="install OpenHaptics and the Touch device driver from 3D Systems, then name "
    "the device in Touch_Setup (device_name)",
    access_fix="the Touch's port (/dev/ttyACM*) must be readable: sudo usermod -aG dialout "
    "$USER, then log in again",
    detect=None,  # OpenHaptics finds a device only by initialising it (hdInitDevice)
    nodes=serial_ports,
)


class Touch(PlanarHardware):
    name = "touch"

    def __init__(self, config: TouchConfig) -> None:
        super().__init__(config, TouchLink(config))


MODEL = DeviceModel(
    TouchConfig,
    Touch,
    "touch",
    "3D Systems Touch / OpenHaptics devices (hardware; extra `touch`: pyOpenHaptics)",
    simulated=False,
)
