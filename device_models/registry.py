"""From the `model` name in a device config file to the class that simulates or drives it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from device_models.ideal import IdealDevice, IdealDeviceConfig
from device_models.maglev import Maglev, MaglevConfig
from device_models.twin_pantograph import TwinPantograph, TwinPantographConfig
from shared.config import ConfigError, load_device_table, parse_toml_text, split_device_table

#: model name -> (config class with from_toml_dict, device factory)
DEVICE_MODELS: dict[str, tuple[Any, Callable[[Any], Any]]] = {
    "ideal": (IdealDeviceConfig, IdealDevice),
    "twin_pantograph": (TwinPantographConfig, TwinPantograph),
    "maglev": (MaglevConfig, Maglev),
}


def load_device(name_or_path: str) -> Any:
    """Build the device named by a config file (bare name: configs/devices/<name>.toml)."""
    return device_from_table(*load_device_table(name_or_path))


def device_from_text(text: str, source: str) -> Any:
    """Build a device from a config file's TOML text (as stored in a run's log)."""
    return device_from_table(*split_device_table(parse_toml_text(text, source), source))


def device_from_table(model: str, table: dict[str, Any], source: str) -> Any:
    """Build the device of `model` from the rest of its config table."""
    if model not in DEVICE_MODELS:
        raise ConfigError(
            source, "model", f"unknown device model {model!r} (known: {sorted(DEVICE_MODELS)})"
        )
    config_cls, factory = DEVICE_MODELS[model]
    try:
        config = config_cls.from_toml_dict(table, source)
    except ConfigError:
        raise
    except ValueError as exc:
        key, _, problem = str(exc).partition(": ")
        raise ConfigError(source, key, problem or str(exc)) from None
    return factory(config)
