"""What every hardware adapter shares: the planar map, the plane-holding spring, limits, the
NaN guard, the safe stop.

A real device moves in 3D (the Inverse3, the Force Dimension deltas and omegas, the Touch);
the scenes are planar. The `[planar]` table says which device axis is the scene's x and which
its y (with a sign: "-z"), and which device point is the plane's origin; the remaining axis
is held on the plane by a spring-damper the adapter renders itself (bounded by the device's
force limit), so the hand feels the plane as a wall on both sides. Yaw is not actuated by
these devices: the planar pose's angle reads 0, and a commanded torque is not sent.

Per tick the engine calls `read` (one sample of the device: position and velocity, vendor
units, converted to metres) and `command` (the planar wrench, already clipped by the
kernels per axis; here the whole force, planar and hold, is clipped in magnitude at the
device's limit, and a non-finite wrench is replaced by zero and flagged). Nothing here
allocates per tick: the arrays are made once. `safe_stop` sends zero force, switches the
device's force output off where the binding can, and closes it; it is idempotent, and the
haptic server calls it on every way out (the end of a run, SIGINT/SIGTERM, an exception).
"""

from __future__ import annotations

import contextlib
import glob
import importlib.util
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, NamedTuple, Protocol, Self

import numpy as np

from haptic_local_model.device_models.base import (
    FAULT_INVALID_COMMAND,
    FAULT_NONE,
    FAULT_SATURATED,
    FAULT_WORKSPACE,
    DeviceError,
    DeviceLimits,
    DeviceRenderingSpec,
    SafeStopError,
    require_device_limits,
)
from haptic_local_model.device_models.world_map import DeviceWorldMap, WorldMapSection
from haptic_local_model.shared.config import ConfigError, Vec3, load_dataclass, require, within

AXES = {"x": 0, "y": 1, "z": 2}
#: The smallest torque limit a device config may state (base.TORQUE_LIMIT_RANGE_NM): these
#: devices render no torque, so the kernels' torque command is clipped to almost nothing
NO_TORQUE_NM = 1e-5
HOLD_FADE_S = 0.5  # the plane's hold spring fades in over this from the first command


def parse_axis(text: str, key: str) -> tuple[int, float]:
    """'x', '-z', ... -> (index of the device axis, sign)."""
    sign = -1.0 if text.startswith("-") else 1.0
    name = text.lstrip("+-")
    require(name in AXES, key, f"must be one of x, y, z with an optional sign, got {text!r}")
    return AXES[name], sign


@dataclass(frozen=True)
class PlanarSection:
    """The `[planar]` table: which device axes are the scene's plane, and how it is held."""

    x: str = "x"  # the device axis (with sign) that is the scene's x
    y: str = "y"  # ... and its y; the third axis is held on the plane
    origin_m: Vec3 = (0.0, 0.0, 0.0)  # the device point (its frame, m) at the plane's origin
    hold_stiffness_n_per_m: float = 300.0  # the spring holding the third axis on the plane
    hold_damping_ns_per_m: float = 3.0
    apparent_mass_kg: float = 0.1  # the handle's mass as the local model sees it (M_d)

    def __post_init__(self) -> None:
        ix, _ = parse_axis(self.x, "x")
        iy, _ = parse_axis(self.y, "y")
        require(ix != iy, "y", f"must be another axis than x ({self.x!r})")
        require(all(math.isfinite(v) for v in self.origin_m), "origin_m", "must be finite")
        within(self.hold_stiffness_n_per_m, (0.0, 5000.0), "hold_stiffness_n_per_m", "N/m")
        within(self.hold_damping_ns_per_m, (0.0, 100.0), "hold_damping_ns_per_m", "N s/m")
        within(self.apparent_mass_kg, (1e-3, 10.0), "apparent_mass_kg", "kg")

    def axes(self) -> tuple[int, int, int, float, float]:
        """(x axis, y axis, held axis, x sign, y sign)."""
        ix, sx = parse_axis(self.x, "x")
        iy, sy = parse_axis(self.y, "y")
        return ix, iy, 3 - ix - iy, sx, sy


@dataclass(frozen=True)
class HardwareConfig:
    """The keys every adapter's config has (the vendor modules add theirs)."""

    max_wrench: Vec3 = (5.0, 5.0, NO_TORQUE_NM)  # planar fx, fy (N); no torque
    max_rate_hz: float = 1000.0
    workspace_half_extent_m: tuple[float, float] = (0.05, 0.05)  # planar x, y about the origin
    planar: PlanarSection = field(default_factory=PlanarSection)
    rendering: DeviceRenderingSpec = field(default_factory=DeviceRenderingSpec)
    world_map: WorldMapSection | None = None  # None: scale 1, the engine sets the offset
    #: the vendor's binding (an importable module) and the extra that installs it
    binding: ClassVar[str] = ""
    extra: ClassVar[str] = ""

    @classmethod
    def from_toml_dict(cls, data: dict[str, Any], source: str) -> Self:
        """The config of a table; the binding must be installed (checked after the keys)."""
        config: Self = load_dataclass(cls, data, source)
        if cls.binding:
            require_binding(cls.binding, cls.extra, source)
        return config

    def __post_init__(self) -> None:
        require_device_limits(self.max_wrench, self.max_rate_hz)
        for i, half in enumerate(self.workspace_half_extent_m):
            within(half, (1e-3, 1.0), f"workspace_half_extent_m[{i}]", "m")


def require_binding(module: str, extra: str, source: str) -> None:
    """A ConfigError naming the file and the extra to install when the vendor's binding is
    missing (checked when the config is read, before anything opens the device)."""
    if importlib.util.find_spec(module) is None:
        raise ConfigError(
            source,
            "model",
            f"needs the vendor's Python binding {module!r}, which is not installed: "
            f"pip install 'haptic-local-model[{extra}]'",
        )


class Bringup(NamedTuple):
    """What the device doctor (device_models/doctor.py) needs of a vendor module to say,
    without opening the device, whether it can be opened: its `BRINGUP`."""

    #: modules whose import loads the vendor's runtime (its shared libraries): an OSError or
    #: ImportError on importing them means the runtime is missing
    runtime_modules: tuple[str, ...]
    runtime_fix: str  # what to install when the runtime is missing
    access_fix: str  # permissions a user account needs (udev rule, group)
    #: the devices attached, one line each, without opening them; None: the binding cannot
    #: tell without opening one
    detect: Callable[[], list[str]] | None = None
    #: the device files this account must read and write to open one (serial ports, USB
    #: nodes), found without the binding; None: the binding finds its device its own way
    nodes: Callable[[], list[str]] | None = None


def serial_ports(pattern: str = "/dev/ttyACM*") -> list[str]:
    """The USB serial ports (CDC ACM) attached: where the Inverse3 and the Touch appear."""
    return sorted(glob.glob(pattern))


def usb_nodes(vendor_id: str, sysfs: str = "/sys/bus/usb/devices") -> list[str]:
    """The USB device files (/dev/bus/usb/BUS/DEV) of the attached devices of one vendor
    (its USB vendor id, 4 hex digits, as sysfs writes it), read from sysfs."""
    found = []
    for vendor in sorted(Path(sysfs).glob("*/idVendor")):
        with contextlib.suppress(OSError, ValueError):
            if vendor.read_text().strip().lower() == vendor_id.lower():
                bus = int((vendor.parent / "busnum").read_text())
                dev = int((vendor.parent / "devnum").read_text())
                found.append(f"/dev/bus/usb/{bus:03d}/{dev:03d}")
    return found


class VendorLink(Protocol):
    """The vendor-specific part of an adapter: calls into the maker's binding only."""

    def open(self) -> None:
        """Open the device, calibrate it if it needs it, enable force output."""

    def sample(self, position: np.ndarray, velocity: np.ndarray) -> int:
        """Newest position (m) and velocity (m/s) in the device's frame into the arrays;
        returns vendor fault bits (0: healthy)."""

    def send(self, force: np.ndarray) -> None:
        """Command a force (N, the device's frame), held until the next one."""

    def stop(self) -> None:
        """Zero force, force output off, device closed. Called once."""


class PlanarHardware:
    """A Device (base.Device) over a VendorLink: the planar map, limits, the NaN guard."""

    name = "hardware"

    def __init__(self, config: HardwareConfig, link: VendorLink) -> None:
        self.config = config
        self.rendering = config.rendering
        hx, hy = config.workspace_half_extent_m
        self._limits = DeviceLimits(
            config.max_wrench, (-hx, -hy, -math.pi), (hx, hy, math.pi), config.max_rate_hz
        )
        self.world_map: DeviceWorldMap | None = (
            None
            if config.world_map is None
            else DeviceWorldMap.from_config(config.world_map, (hx, hy, math.pi))
        )
        p = config.planar
        self._ix, self._iy, self._iz, self._sx, self._sy = p.axes()
        self._origin = np.array(p.origin_m, dtype=float)
        self._max = np.array(config.max_wrench, dtype=float)
        self._half = np.array([hx, hy])
        self._position = np.zeros(3)
        self._velocity = np.zeros(3)
        self._force = np.zeros(3)  # the device-frame force sent (N)
        self._applied = np.zeros(3)  # the planar wrench applied
        self._inertia = np.diag([p.apparent_mass_kg, p.apparent_mass_kg, 1e-3])
        self._fault = FAULT_NONE
        self._stopping = False  # no command is sent once a safe stop has begun
        self._stopped = False  # ... and the binding's stop has succeeded
        self._first_command_ns = -1  # the hold spring fades in from the first command
        #: the clock the hold spring's fade reads (ns); the device doctor sets its own so
        #: that its replay against the logged readings is exact
        self.clock_ns: Callable[[], int] = time.monotonic_ns
        self._vendor_fault = 0  # the newest reading's vendor fault bits
        self._fade = 0.0  # ... by this factor, 1 once faded in
        self.not_finite_commands = 0  # commands replaced by zero (never sent)
        self._link = link
        try:
            link.open()
        except Exception as exc:  # no device on the port, not calibrated, ...
            with contextlib.suppress(Exception):  # close whatever it had opened
                link.stop()
            if isinstance(exc, DeviceError):
                raise
            raise DeviceError(f"{self.name}: opening the device failed: {exc}") from exc

    def limits(self) -> DeviceLimits:
        return self._limits

    def read(self, sensors: np.ndarray) -> None:
        pos, vel = self._position, self._velocity
        try:
            vendor_fault = self._vendor_fault = self._link.sample(pos, vel)
        except DeviceError:
            raise
        except Exception as exc:  # the binding's own error: the device is lost
            raise DeviceError(f"{self.name}: reading the device failed: {exc}") from exc
        ix, iy = self._ix, self._iy
        x = self._sx * (pos[ix] - self._origin[ix])
        y = self._sy * (pos[iy] - self._origin[iy])
        fault = self._fault
        if vendor_fault or abs(x) > self._half[0] or abs(y) > self._half[1]:
            fault |= FAULT_WORKSPACE
        if not (math.isfinite(x) and math.isfinite(y)):  # a bad sample: hold the last pose
            fault |= FAULT_WORKSPACE
            x, y = float(sensors[0]["pose"][0]), float(sensors[0]["pose"][1])
        s = sensors[0]
        s["pose"] = (x, y, 0.0)
        vx, vy = self._sx * vel[ix], self._sy * vel[iy]
        if vendor_fault or not (math.isfinite(vx) and math.isfinite(vy)):
            vx = vy = 0.0  # no velocity rather than a stale one
        s["twist"] = (vx, vy, 0.0)
        s["inertia"] = self._inertia
        s["coriolis"] = 0.0
        s["hand_wrench"] = 0.0
        s["has_force_sensor"] = 0
        s["fault"] = fault

    def command(self, wrench: np.ndarray) -> np.ndarray:
        """Send the planar wrench (fx, fy; the torque is not rendered) plus the plane's hold
        spring (faded in over HOLD_FADE_S from the first command); the force's magnitude is
        clipped at max_wrench[0], the planar part returned as applied; a non-finite wrench
        sends zero force."""
        applied, force, limit = self._applied, self._force, self._max
        if self._stopping:
            applied[:] = 0.0
            return applied
        fx, fy = float(wrench[0]), float(wrench[1])
        self._fault = FAULT_NONE
        if not (math.isfinite(fx) and math.isfinite(fy) and math.isfinite(float(wrench[2]))):
            self.not_finite_commands += 1
            self._fault = FAULT_INVALID_COMMAND
            fx = fy = 0.0
        if abs(fx) > limit[0] or abs(fy) > limit[1]:
            self._fault |= FAULT_SATURATED
            fx = min(limit[0], max(-limit[0], fx))
            fy = min(limit[1], max(-limit[1], fy))
        p = self.config.planar
        iz = self._iz
        if self._fade < 1.0:
            now = self.clock_ns()
            if self._first_command_ns < 0:
                self._first_command_ns = now
            self._fade = min(1.0, (now - self._first_command_ns) * 1e-9 / HOLD_FADE_S)
        hold = -p.hold_stiffness_n_per_m * (self._position[iz] - self._origin[iz])
        hold = self._fade * (hold - p.hold_damping_ns_per_m * self._velocity[iz])
        hold = min(limit[0], max(-limit[0], hold)) if math.isfinite(hold) else 0.0
        magnitude = math.sqrt(fx * fx + fy * fy + hold * hold)
        if magnitude > limit[0]:  # the device's limit is on the force, not on each axis
            self._fault |= FAULT_SATURATED
            scale = limit[0] / magnitude
            fx, fy, hold = fx * scale, fy * scale, hold * scale
        force[self._ix] = self._sx * fx
        force[self._iy] = self._sy * fy
        force[iz] = hold
        try:
            self._link.send(force)
        except DeviceError:
            raise
        except Exception as exc:
            raise DeviceError(f"{self.name}: commanding the device failed: {exc}") from exc
        applied[0], applied[1], applied[2] = fx, fy, 0.0
        return applied

    def device_reading(self) -> tuple[np.ndarray, np.ndarray, int]:
        """The newest reading in the device's own frame, before the planar map: position
        (m) and velocity (m/s), copies, and the vendor's fault bits. The device doctor finds
        the plane's axes from it, and its bring-up log keeps it to replay the check."""
        return self._position.copy(), self._velocity.copy(), int(self._vendor_fault)

    def idle(self) -> None:
        """Send zero force and no hold spring: keeps a device that answers only to commands
        (the Inverse3) reading while nothing may be rendered (the device doctor's steps
        before --force)."""
        if self._stopping:
            return
        self._force[:] = 0.0
        try:
            self._link.send(self._force)
        except DeviceError:
            raise
        except Exception as exc:
            raise DeviceError(f"{self.name}: commanding the device failed: {exc}") from exc

    def safe_stop(self) -> None:
        """Zero force, force output off, the device closed. From the first call on nothing
        more is commanded; a binding whose stop fails raises SafeStopError, and a later call
        tries the stop again; once it has succeeded, later calls do nothing."""
        self._stopping = True
        if self._stopped:
            return
        self._force[:] = 0.0
        self._applied[:] = 0.0
        try:
            self._link.stop()
        except Exception as exc:
            raise SafeStopError(f"{self.name}: the safe stop failed: {exc}") from exc
        self._stopped = True
