"""From the `model` name in a device config file to the class that simulates or drives it.

Device models are plug-ins: every installed distribution may register models in the
entry-point group `haptic_local_model.devices` (name: the model, as a device config's
`model` key says it; value: a `DeviceModel`), and the built-in ones (ideal, maglev,
twin_pantograph) register there the same way, in this project's pyproject.toml. A driver
therefore ships as a package of its own; `haptic-run --list` shows what is installed.
docs/devices.md says how to write one.

`DEVICE_MODELS` is the one table of installed models, read once per process: the loader,
`make warm` and the device tests iterate it. A plug-in that fails to load does not take the
others down: it is listed in `BROKEN_MODELS` with its reason, and choosing it is a config
error that says why.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any, NamedTuple

from haptic_local_model.device_models.base import Device, DeviceModel, SimulatedDevice
from haptic_local_model.shared.config import (
    ConfigError,
    is_config_path,
    parse_toml_text,
    read_toml,
    resolve,
    split_device_table,
)

GROUP = "haptic_local_model.devices"
#: The distribution whose models are built in (its own entry points)
BUILT_IN = "haptic-local-model"

__all__ = [
    "BROKEN_MODELS",
    "DEVICE_MODELS",
    "GROUP",
    "DeviceModel",
    "InstalledModel",
    "check_device",
    "device_config",
    "device_from_table",
    "device_from_text",
    "discover",
    "installed_models",
    "load_device",
    "load_simulated_device",
    "model_lines",
]


class InstalledModel(NamedTuple):
    """A registered model and where it comes from: the distribution and the entry point."""

    name: str
    model: DeviceModel | None  # None: it failed to load (`problem` says why)
    distribution: str
    value: str  # the entry point's `module:attribute`
    problem: str = ""

    @property
    def built_in(self) -> bool:
        return self.distribution == BUILT_IN


def _distribution(ep: EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    return str(dist.metadata["Name"]) if dist is not None else "?"


def discover() -> list[InstalledModel]:
    """Every model registered in the entry-point group, loaded (sorted by name; the first
    registration of a name wins, a second one is reported as broken)."""
    found: dict[str, InstalledModel] = {}
    broken: list[InstalledModel] = []
    for ep in sorted(entry_points(group=GROUP), key=lambda e: (e.name, e.value)):
        dist, model, problem = _distribution(ep), None, ""
        if ep.name in found:
            problem = f"is also registered by {found[ep.name].distribution}, whose model is used"
        else:
            try:
                model = ep.load()
            except Exception as exc:  # a plug-in's import error must not take the others down
                problem = f"failed to load: {type(exc).__name__}: {exc}"
            if model is not None and not isinstance(model, DeviceModel):
                model, problem = None, f"is a {type(model).__name__}, not a DeviceModel"
        entry = InstalledModel(ep.name, model, dist, ep.value, problem)
        if model is None:
            broken.append(entry)
        else:
            found[ep.name] = entry
    return sorted([*found.values(), *broken], key=lambda m: (m.name, m.model is None))


_INSTALLED = discover()
DEVICE_MODELS: dict[str, DeviceModel] = {m.name: m.model for m in _INSTALLED if m.model is not None}
BROKEN_MODELS: dict[str, str] = {m.name: m.problem for m in _INSTALLED if m.model is None}


def installed_models() -> list[InstalledModel]:
    """The models registered in this environment, the broken ones included."""
    return list(_INSTALLED)


def model_lines() -> list[str]:
    """The installed device models for `haptic-run --list`: name, what it is, which package
    registered it; a broken plug-in with its reason."""
    lines = [f"device models (a device config's `model`; entry points {GROUP}):"]
    models = installed_models()
    width = max((len(m.name) for m in models), default=0)
    for m in models:
        source = "built in" if m.built_in else f"from {m.distribution} ({m.value})"
        what = m.model.description if m.model is not None else f"BROKEN: {m.problem}"
        lines.append(f"  {m.name:<{width}}  {what}; {source}")
    return lines


def device_config(name_or_path: str) -> Path:
    """The device config file a `--device` value names: a path as it is; a bare name is the
    shipped configs/devices/<name>.toml, else the config an installed model of that name
    ships (a plug-in's own file)."""
    if is_config_path(name_or_path):
        return Path(name_or_path)
    shipped = resolve("devices", name_or_path)
    model = DEVICE_MODELS.get(name_or_path)
    if shipped.is_file() or model is None:
        return shipped  # (a missing file is read_toml's error to name)
    if not is_config_path(model.config):
        return resolve("devices", model.config)
    return Path(model.config)


def load_device(name_or_path: str, simulated_only: bool = False) -> Device:
    """Build the device a config file describes (`device_config` says which file); with
    `simulated_only`, a hardware model is refused before it is built (device_from_table)."""
    path = device_config(name_or_path)
    model, table, source = split_device_table(read_toml(path), str(path))
    return device_from_table(model, table, source, simulated_only)


def check_device(name_or_path: str) -> DeviceModel:
    """Read and check a device config without building the device (building a hardware
    driver opens the hardware: only the haptic server may do that): the model it names."""
    path = device_config(name_or_path)
    model, table, source = split_device_table(read_toml(path), str(path))
    _config(model, table, source)
    return DEVICE_MODELS[model]


def load_simulated_device(name_or_path: str) -> SimulatedDevice:
    """A device whose physics this process simulates (the virtual clock, tests, benchmarks).
    A hardware model is refused before it is built: building it would open the device."""
    device = load_device(name_or_path, simulated_only=True)
    if not isinstance(device, SimulatedDevice):  # a plug-in that did not say it drives hardware
        path = str(device_config(name_or_path))
        raise ConfigError(path, "model", "drives hardware: a simulated device is needed")
    return device


def device_from_text(text: str, source: str, simulated_only: bool = False) -> Device:
    """Build a device from a config file's TOML text (as stored in a run's log); with
    `simulated_only`, a hardware model is refused before it is built (a replay)."""
    model, table, where = split_device_table(parse_toml_text(text, source), source)
    return device_from_table(model, table, where, simulated_only)


def device_from_table(
    model: str, table: dict[str, Any], source: str, simulated_only: bool = False
) -> Device:
    """Build the device of `model` from the rest of its config table; with
    `simulated_only`, a hardware model is refused first (building it would open it)."""
    config = _config(model, table, source)  # first: it names an unknown or broken model
    entry = DEVICE_MODELS[model]
    if simulated_only and not entry.simulated:
        raise ConfigError(
            source, "model",
            f"{model!r} drives hardware: only the haptic server opens a real device; this "
            "needs a simulated one (ideal, twin_pantograph, maglev, ...)",
        )  # fmt: skip
    return entry.factory(config)


def _config(model: str, table: dict[str, Any], source: str) -> Any:
    """The model's config object from the rest of its table (a ConfigError names the key)."""
    if model in BROKEN_MODELS and model not in DEVICE_MODELS:
        raise ConfigError(source, "model", f"device model {model!r} {BROKEN_MODELS[model]}")
    if model not in DEVICE_MODELS:
        raise ConfigError(
            source, "model",
            f"unknown device model {model!r} (installed: {sorted(DEVICE_MODELS)}; "
            f"a driver package registers its models in the entry-point group {GROUP})",
        )  # fmt: skip
    try:
        return DEVICE_MODELS[model].config_cls.from_toml_dict(table, source)
    except ConfigError:
        raise
    except ValueError as exc:
        key, _, problem = str(exc).partition(": ")
        raise ConfigError(source, key, problem or str(exc)) from None
