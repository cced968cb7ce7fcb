"""A device driver shipped as a package of its own, for tests/test_plugins.py.

`RecordingArm` is a hardware driver as docs/devices.md describes one (the `Device`
interface, not a simulated device): its "hardware" is a 1 kg point mass in this process,
pushed by a hand of constant force, moved by the commanded wrench. It records what the loop
asked of it — every read and command, their timing, any wrench that was not finite or beyond
its limits, the safe stops — and writes that record (JSON) when the loop stops it. The
project knows nothing of this package: it is found through the entry point in its
pyproject.toml.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import (
    DeviceLimits,
    DeviceModel,
    DeviceRenderingSpec,
    require_device_limits,
)
from haptic_local_model.shared.config import Vec3, load_dataclass, require

#: the handle's end stops (m; yaw ±3 rad). The hand pushes from the loop's first read, before
#: the sim's first update (3.8 s later on a slow 2-core VM, haptic-run starting the sim once
#: the haptic server is ready); at its terminal speed, hand_force / damping = 1 m/s, the
#: handle goes 60 m in the haptic server's longest wait for a first update (60 s). Rendering
#: starts by indexing the handle where it is (the world offset puts it on the tool): one
#: pinned at an end stop then could never push the tool into the wall.
END_STOP_M = 100.0


@dataclass(frozen=True)
class RecordingArmConfig:
    """Parameters of recording_arm.toml."""

    max_wrench: Vec3 = (10.0, 10.0, 1.0)
    max_rate_hz: float = 2000.0
    mass: float = 1.0  # kg (and kg m^2 about the handle's axis, scaled by 1e-3)
    damping: float = 2.0  # N s/m: the hardware's own friction (yaw: scaled as its inertia)
    hand_force: Vec3 = (2.0, 0.0, 0.0)  # the hand's constant push (N, N, N m)
    record: str = "recording_arm.json"  # written on the last safe stop, cwd-relative
    rendering: DeviceRenderingSpec = field(default_factory=DeviceRenderingSpec)

    def __post_init__(self) -> None:
        require_device_limits(self.max_wrench, self.max_rate_hz)
        require(self.mass > 0, "mass", "must be > 0")

    @classmethod
    def from_toml_dict(cls, data: dict[str, Any], source: str) -> RecordingArmConfig:
        return load_dataclass(cls, data, source)


class RecordingArm:
    """The driver: read() samples the "hardware", command() sends a wrench to it."""

    name = "recording_arm"

    def __init__(self, config: RecordingArmConfig) -> None:
        self.config = config
        self.rendering = config.rendering
        self._limits = DeviceLimits(config.max_wrench, (-END_STOP_M, -END_STOP_M, -3.0),
                                    (END_STOP_M, END_STOP_M, 3.0), config.max_rate_hz)  # fmt: skip
        self._inertia = np.array([config.mass, config.mass, config.mass * 1e-3])
        self._pose = np.zeros(3)
        self._twist = np.zeros(3)
        self._applied = np.zeros(3)
        self._last_ns = 0
        self._reads = 0
        self._commands: list[tuple[int, float, float, float]] = []
        self._not_finite = 0
        self._over_limit = 0
        self._safe_stops = 0

    def limits(self) -> DeviceLimits:
        return self._limits

    def read(self, sensors: np.ndarray) -> None:
        now = time.monotonic_ns()
        dt = min((now - self._last_ns) * 1e-9, 0.005) if self._last_ns else 0.0
        self._last_ns = now
        # the hardware's friction, integrated implicitly: on the handle's small yaw inertia an
        # explicit step of it is at its stability limit (b dt / I = 2 at 1 kHz) and rings
        force = np.asarray(self.config.hand_force) + self._applied
        friction = self.config.damping * self._inertia / self.config.mass  # N s/m, N m s/rad
        inertia = self._inertia
        self._twist = (self._twist + dt * force / inertia) / (1.0 + dt * friction / inertia)
        self._pose += dt * self._twist
        low, high = np.asarray(self._limits.workspace_min), np.asarray(self._limits.workspace_max)
        stopped = (self._pose < low) | (self._pose > high)  # the mechanism's end stops
        self._pose = np.clip(self._pose, low, high)
        self._twist[stopped] = 0.0
        s = sensors[0]
        s["pose"] = self._pose
        s["twist"] = self._twist
        s["inertia"] = np.diag(self._inertia)
        s["coriolis"] = 0.0
        s["hand_wrench"] = 0.0
        s["has_force_sensor"] = 0
        s["fault"] = 0
        self._reads += 1

    def command(self, wrench: np.ndarray) -> np.ndarray:
        w = np.asarray(wrench, dtype=float)
        if not np.all(np.isfinite(w)):
            self._not_finite += 1
            w = np.zeros(3)
        limit = np.asarray(self.config.max_wrench)
        if np.any(np.abs(w) > limit * (1 + 1e-9)):
            self._over_limit += 1
        self._applied = np.clip(w, -limit, limit)
        self._commands.append((time.monotonic_ns(), *map(float, self._applied)))
        return self._applied.copy()

    def safe_stop(self) -> None:
        self._applied = np.zeros(3)
        self._safe_stops += 1
        t = np.array([c[0] for c in self._commands], dtype=np.int64)
        fx = [c[1] for c in self._commands]
        gaps = np.diff(t) * 1e-6 if t.size > 1 else np.zeros(1)
        Path(self.config.record).write_text(json.dumps({
            "reads": self._reads,
            "commands": len(self._commands),
            "not_finite": self._not_finite,
            "over_limit": self._over_limit,
            "safe_stops": self._safe_stops,
            "max_abs_force": max((max(abs(c[1]), abs(c[2])) for c in self._commands), default=0.0),
            "fx_last_second": fx[-1000:],
            "gap_ms_p50": float(np.percentile(gaps, 50)),
            "gap_ms_p99": float(np.percentile(gaps, 99)),
            "pose": [float(v) for v in self._pose],
            "finite_pose": bool(all(math.isfinite(v) for v in self._pose)),
        }))  # fmt: skip


MODEL = DeviceModel(
    RecordingArmConfig,
    RecordingArm,
    str(files(__package__) / "recording_arm.toml"),
    "a test driver: a point mass pushed by a constant hand, recording every call",
)
