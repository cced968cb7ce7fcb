"""From the `model` name in a device config file to the class that simulates or drives it.

`DEVICE_MODELS` is the one list of device models: the loader, `make warm` and the device
tests all iterate it. Adding a device is its module, its config file in configs/devices/ and
one entry here (docs/devices.md).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from haptic_local_model.device_models.base import Device, SimulatedDevice
from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_local_model.device_models.maglev import Maglev, MaglevConfig
from haptic_local_model.device_models.twin_pantograph import TwinPantograph, TwinPantographConfig
from haptic_local_model.shared.config import (
    ConfigError,
    load_device_table,
    parse_toml_text,
    split_device_table,
)


class DeviceModel(NamedTuple):
    """A device model: its config class (with `from_toml_dict(table, source)`), the factory
    that builds the device from a config, the config file it ships with (configs/devices/),
    and one line on what it is."""

    config_cls: Any
    factory: Callable[[Any], Device]
    config: str
    description: str


DEVICE_MODELS: dict[str, DeviceModel] = {
    "ideal": DeviceModel(
        IdealDeviceConfig, IdealDevice, "ideal", "a point mass with exact sensing (no hardware)"
    ),
    "twin_pantograph": DeviceModel(
        TwinPantographConfig,
        TwinPantograph,
        "twin_pantograph",
        "seed 001's twin five-bar planar device: 4 motors, encoders, friction",
    ),
    "maglev": DeviceModel(
        MaglevConfig,
        Maglev,
        "maglev",
        "seed 002's magnetic levitation device: 6-DOF flotor, planar x, y, yaw used",
    ),
}


def load_device(name_or_path: str) -> Device:
    """Build the device named by a config file (bare name: configs/devices/<name>.toml)."""
    return device_from_table(*load_device_table(name_or_path))


def load_simulated_device(name_or_path: str) -> SimulatedDevice:
    """A device whose physics this process simulates (the virtual clock, tests, benchmarks)."""
    device = load_device(name_or_path)
    if not isinstance(device, SimulatedDevice):
        raise ConfigError(name_or_path, "model", "drives hardware: a simulated device is needed")
    return device


def device_from_text(text: str, source: str) -> Device:
    """Build a device from a config file's TOML text (as stored in a run's log)."""
    return device_from_table(*split_device_table(parse_toml_text(text, source), source))


def device_from_table(model: str, table: dict[str, Any], source: str) -> Device:
    """Build the device of `model` from the rest of its config table."""
    if model not in DEVICE_MODELS:
        raise ConfigError(
            source, "model", f"unknown device model {model!r} (known: {sorted(DEVICE_MODELS)})"
        )
    entry = DEVICE_MODELS[model]
    try:
        config = entry.config_cls.from_toml_dict(table, source)
    except ConfigError:
        raise
    except ValueError as exc:
        key, _, problem = str(exc).partition(": ")
        raise ConfigError(source, key, problem or str(exc)) from None
    return entry.factory(config)
