"""What the simulated device models share, written once: the simulation section, the
invalid-command fault bit, the sensor-noise buffer, and `KernelDevice`, the device class
skeleton that implements the `SimulatedDevice` calls by calling the model's kernels.

A model module keeps its physics (its records, `pack_parameters` and kernels, registered by
their names: device_models/kernels.py) and subclasses `KernelDevice`: see
`device_models/maglev.py` and `device_models/twin_pantograph/device.py`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np

from haptic_local_model.device_models.base import DeviceLimits, DeviceRenderingSpec
from haptic_local_model.device_models.kernels import (
    DeviceRecords,
    ModelKernels,
    advance_device,
    noise_ready,
)
from haptic_local_model.device_models.world_map import DeviceWorldMap
from haptic_local_model.shared.config import load_model_config, read_toml, require

#: Device-specific fault bit (base.py defines bits 0-2): the command held NaN or Inf.
FAULT_INVALID_COMMAND = 8


@dataclass(frozen=True)
class SimulationSection:
    """Integration of the true dynamics: the longest substep (a model sets its own bound)."""

    max_substep_s: float
    MAX_SUBSTEP_S: ClassVar[float] = 0.01

    def __post_init__(self) -> None:
        bound = self.MAX_SUBSTEP_S
        require(0 < self.max_substep_s <= bound, "max_substep_s", f"must be in (0, {bound:g}] s")


class ModelConfig:
    """A device model's config (a frozen dataclass, one section per TOML table) loads from
    its file's table; the file's `model` key, if present, must name MODEL."""

    MODEL: ClassVar[str]

    @classmethod
    def from_toml_dict(cls, d: dict[str, Any], source: str) -> Self:
        """Build from a parsed TOML table; a ConfigError names `source`, the key and the problem."""
        config: Self = load_model_config(cls, d, source, cls.MODEL)
        return config

    @classmethod
    def from_toml_file(cls, path: str | Path) -> Self:
        """Read and validate a device TOML file."""
        return cls.from_toml_dict(read_toml(path), str(path))


class NoiseBuffer:
    """Standard normals drawn in blocks from a seeded generator, so a tick draws none: the
    kernels read `normals` from `index[0]` and advance it (a 1-element array, so a compiled
    tick and the Python side share it); when a tick would run past the block, the Python side
    refills the whole block first (`reserve`, or `refill` after a compiled burst stopped)."""

    def __init__(self, seed: int, block: int) -> None:
        self._rng = np.random.default_rng(seed)
        self.normals = np.empty(block)
        self._rng.standard_normal(out=self.normals)
        self.index = np.zeros(1, np.int64)
        self._next: np.ndarray | None = None  # the next block, drawn ahead (prefetch)
        self._waiting = False

    def refill(self) -> None:
        """A fresh block of normals, read from its start (the prefetched one, if waiting)."""
        if self._waiting and self._next is not None:
            self.normals[:] = self._next
            self._waiting = False
        else:
            self._rng.standard_normal(out=self.normals)
        self.index[0] = 0

    def prefetch(self) -> bool:
        """Draw the next block now, ahead of need (a real-time loop does it in a tick's slack);
        the refill at need then copies it in instead of drawing: the normals read are the same,
        number for number. Whether it drew (False: one is already waiting)."""
        if self._waiting:
            return False
        if self._next is None:
            self._next = np.empty_like(self.normals)
        self._rng.standard_normal(out=self._next)
        self._waiting = True
        return True

    def reserve(self, needed: int) -> int:
        """The start of `needed` fresh normals (refilling the block when it runs out)."""
        block = self.normals.shape[0]
        if self.index[0] + needed > block:
            if needed > block:
                raise ValueError(f"{needed} normals per tick exceed the noise buffer ({block})")
            self.refill()
        start = int(self.index[0])
        self.index[0] += needed
        return start


class KernelDevice:
    """A simulated device whose calls are its model's numba kernels over its records
    (implements `device_models.base.SimulatedDevice` but `reset` and `servo_plant`, which a
    model writes itself).

    A subclass names its kernels (`KERNELS`, what `device_models.kernels.register_model`
    returned for its params dtype) and passes its records: `params`, `state`, a
    scratch `work` record and its sensor-noise buffer. `records` is what the compiled tick
    takes (device_models.kernels.DeviceRecords); the Python calls below run the same kernels."""

    name: str
    aux_names: tuple[str, ...] = ()
    KERNELS: ClassVar[ModelKernels]

    def __init__(
        self,
        records: tuple[np.ndarray, np.ndarray, np.ndarray, NoiseBuffer],
        limits: DeviceLimits,
        rendering: DeviceRenderingSpec,
        world_map: DeviceWorldMap | None,
    ) -> None:
        self.params, self.state, self.work, self.noise = records
        self.rendering = rendering
        self.world_map = world_map
        self._limits = limits
        self._zero_wrench = np.zeros(3)
        self.records: DeviceRecords = (
            self.params, self.state, self.work, self.noise.normals, self.noise.index
        )  # fmt: skip

    def limits(self) -> DeviceLimits:
        return self._limits

    def read(self, sensors: np.ndarray) -> None:
        self.KERNELS.read(self.params, self.state, sensors)

    def command(self, wrench: np.ndarray) -> np.ndarray:
        """Hold the wrench (the model saturates it); returns what the device applies, a view
        the next command overwrites."""
        self.KERNELS.command(self.params, self.state, wrench)
        applied: np.ndarray = self.KERNELS.applied(self.state)
        return applied

    def safe_stop(self) -> None:
        """No commanded force."""
        self.KERNELS.command(self.params, self.state, self._zero_wrench)

    def true_state(self, pose: np.ndarray, twist: np.ndarray) -> None:
        self.KERNELS.true_state(self.state, pose, twist)

    def sense_hand(self, hand_wrench: np.ndarray) -> None:
        """The hand's wrench this tick, as the handle (or the force sensor, if any) feels it."""
        self.KERNELS.sense_hand(self.state, hand_wrench)

    def advance(self, dt: float, hand_wrench: np.ndarray) -> None:
        """The physics over dt under the held command and the hand's true wrench."""
        refill_noise(self.noise, self.records, dt)
        advance_device(self.records, dt, hand_wrench)


def refill_noise(noise: NoiseBuffer, records: DeviceRecords, dt: float) -> None:
    """Refill the noise block if this dt's advance would run past it."""
    if not noise_ready(records, dt):
        noise.refill()
        if not noise_ready(records, dt):
            raise ValueError(f"a tick of {dt:g} s needs more normals than the noise buffer holds")
