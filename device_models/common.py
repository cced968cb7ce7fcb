"""What the simulated device models share, written once: the simulation section, the
invalid-command fault bit, the sensor-noise buffer, and `KernelDevice`, the device class
skeleton that implements the `SimulatedDevice` calls by calling the model's kernels.

A model module keeps its physics (its records, `pack_parameters` and kernels) and subclasses
`KernelDevice`, naming its kernels: see `device_models/maglev.py` and
`device_models/twin_pantograph/device.py`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np

from device_models.base import DeviceLimits, DeviceRenderingSpec
from device_models.world_map import DeviceWorldMap
from shared.config import load_model_config, read_toml, require

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
    kernels read `normals` from the index `reserve` returns."""

    def __init__(self, seed: int, block: int) -> None:
        self._rng = np.random.default_rng(seed)
        self.normals = np.empty(block)
        self._rng.standard_normal(out=self.normals)
        self._index = 0

    def reserve(self, needed: int) -> int:
        """The start of `needed` fresh normals (refilling the block when it runs out)."""
        block = self.normals.shape[0]
        if self._index + needed > block:
            if needed > block:
                raise ValueError(f"{needed} normals per tick exceed the noise buffer ({block})")
            self._rng.standard_normal(out=self.normals)
            self._index = 0
        start = self._index
        self._index += needed
        return start


Kernel = Callable[..., Any]


class KernelDevice:
    """A simulated device whose calls are its model's numba kernels over `params` and
    `state` records (implements `device_models.base.SimulatedDevice` but `reset`, `advance`
    and `servo_plant`, which a model writes itself).

    A subclass names its kernels: `read_kernel(params, state, sensors)`,
    `command_kernel(params, state, wrench)`, `true_state_kernel(state, pose, twist)`, and
    `applied_field`, the state field that holds what the device applies."""

    name: str
    aux_names: tuple[str, ...] = ()
    read_kernel: ClassVar[Kernel]
    command_kernel: ClassVar[Kernel]
    true_state_kernel: ClassVar[Kernel]
    applied_field: ClassVar[str]

    def __init__(
        self,
        params: np.ndarray,
        state: np.ndarray,
        limits: DeviceLimits,
        rendering: DeviceRenderingSpec,
        world_map: DeviceWorldMap | None,
    ) -> None:
        self.params = params
        self.state = state
        self.rendering = rendering
        self.world_map = world_map
        self._limits = limits
        self._applied = state[self.applied_field][0]
        self._zero_wrench = np.zeros(3)

    def limits(self) -> DeviceLimits:
        return self._limits

    def read(self, sensors: np.ndarray) -> None:
        type(self).read_kernel(self.params, self.state, sensors)

    def command(self, wrench: np.ndarray) -> np.ndarray:
        """Hold the wrench (the model saturates it); returns what the device applies, a view
        the next command overwrites."""
        type(self).command_kernel(self.params, self.state, wrench)
        return self._applied

    def safe_stop(self) -> None:
        """No commanded force."""
        type(self).command_kernel(self.params, self.state, self._zero_wrench)

    def true_state(self, pose: np.ndarray, twist: np.ndarray) -> None:
        type(self).true_state_kernel(self.state, pose, twist)

    def sense_hand(self, hand_wrench: np.ndarray) -> None:
        """The hand's wrench this tick, as the handle (or the force sensor, if any) feels it."""
        self.state[0]["hand_wrench"] = hand_wrench
