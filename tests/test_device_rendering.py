"""Device-specific rendering gains (the `[rendering]` table): config validation and the
stability of each device's FOH servo (seed 002 §4) at the haptic rate."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_local_model.device_models.base import SENSOR_DTYPE, DeviceRenderingSpec, SimulatedDevice
from haptic_local_model.device_models.registry import (
    DEVICE_MODELS,
    load_device,
    load_simulated_device,
)
from haptic_local_model.shared.config import ConfigError

DEVICES = Path(__file__).resolve().parent.parent / "configs" / "devices"
#: every shipped config of a simulated device: a new device's file is picked up here, its
#: model from the registry (test_every_registered_model_ships_a_config). The hardware
#: adapters' configs are checked against fakes of their bindings (test_hardware_adapters.py).
DEVICE_CONFIGS = sorted(
    p.stem
    for p in DEVICES.glob("*.toml")
    if DEVICE_MODELS[tomllib.loads(p.read_text())["model"]].simulated
)
DT = 1e-3
#: Seed 002's table (N/mm, N m/rad, N/mm/s, N m/rad/s) in SI: the maglev's defaults.
SEED_K_P = (4.0e3, 4.0e3, 25.0)
SEED_K_V = (0.1e3, 0.1e3, 0.5)
#: Plant substeps per tick in the servo stability model (the devices integrate at <= 0.2 ms).
PLANT_SUBSTEPS = 5
#: Per-tick spectral radius a servo must stay below: 0.999^1000 = 0.37, so a disturbance
#: decays at least e-fold per second (stable with a margin, not just marginally).
MAX_SPECTRAL_RADIUS = 0.999


# ---------------------------------------------------------------------------- config


def test_maglev_defaults_are_seed_002s_table_in_si() -> None:
    assert DeviceRenderingSpec().foh_stiffness == SEED_K_P
    assert DeviceRenderingSpec().foh_damping == SEED_K_V
    maglev = load_device("maglev")
    assert maglev.rendering.foh_stiffness == SEED_K_P
    assert maglev.rendering.foh_damping == SEED_K_V
    assert maglev.rendering.setpoint_hold == "first_order"


@pytest.mark.parametrize("name", DEVICE_CONFIGS)
def test_every_device_config_has_a_rendering_table(name: str) -> None:
    raw = tomllib.loads((DEVICES / f"{name}.toml").read_text())
    assert "rendering" in raw
    device = load_device(name)
    table = {k: tuple(v) if isinstance(v, list) else v for k, v in raw["rendering"].items()}
    assert device.rendering == DeviceRenderingSpec(**table)


@pytest.mark.parametrize(
    "key, value, problem",
    [
        ("foh_stiffness", [4000.0, -1.0, 25.0], ">= 0"),
        ("foh_damping", [100.0, 100.0], "expected 3 values"),
        ("setpoint_hold", "linear", "must be one of"),
        ("gravity_feedforward", [0.0, math.inf, 0.0], "finite"),
        ("safe_damping", [5.0, 5.0, math.nan], "finite"),  # the loader refuses nan
        ("stiffness", [1.0, 1.0, 1.0], "unknown key"),
    ],
)
@pytest.mark.parametrize("model", sorted(DEVICE_MODELS))  # hardware too: refused when read
def test_rendering_table_errors_name_file_and_key(
    tmp_path: Path, model: str, key: str, value: Any, problem: str
) -> None:
    """[rendering] is the last table of every device file: a line appended lands in it."""
    source = DEVICES / f"{model}.toml"
    tables = [ln for ln in source.read_text().splitlines() if ln.startswith("[")]
    assert tables[-1] == "[rendering]"
    if isinstance(value, str):
        literal = f'"{value}"'
    else:
        literal = "[" + ", ".join(_toml_float(v) for v in value) + "]"
    kept = [ln for ln in source.read_text().splitlines() if not ln.startswith(f"{key} =")]
    bad = tmp_path / f"{model}.toml"
    bad.write_text("\n".join([*kept, f"{key} = {literal}", ""]))
    with pytest.raises(ConfigError) as err:
        load_device(str(bad))
    message = str(err.value)
    assert str(bad) in message and f"rendering.{key}" in message and problem in message


def _toml_float(v: float) -> str:
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(float(v))


# --------------------------------------------------------------------- servo stability


def servo_spectral_radius(
    mass: float, k_p: float, k_v: float, damping: float, cutoff_hz: float, dt: float = DT
) -> float:
    """Spectral radius per tick of m xdd = u - c xd under u = -K_p x_meas - K_v v_est held
    for a tick, v_est the first-order low-pass (cutoff) of the finite difference of the
    sampled x: the device servo of seed 002 around its setpoint, as the engine samples it."""
    alpha = 1.0 if cutoff_hz <= 0 else 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt)
    h = dt / PLANT_SUBSTEPS

    def step(state: np.ndarray) -> np.ndarray:
        x, v, x_prev, v_est = state
        u = -k_p * x - k_v * v_est
        for _ in range(PLANT_SUBSTEPS):
            v += h * (u - damping * v) / mass
            x += h * v
        v_est += alpha * ((x - x_prev) / dt - v_est)
        return np.array([x, v, x, v_est])

    a = np.column_stack([step(e) for e in np.eye(4)])
    return float(np.max(np.abs(np.linalg.eigvals(a))))


def plant_of(name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Diagonal task-space inertia at home, passive damping per axis, twist filter cutoff."""
    device = load_simulated_device(name)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    inertia = np.diag(sensors["inertia"][0])
    damping, cutoff = device.servo_plant()
    return inertia, damping, cutoff


def test_servo_model_finds_the_closed_form_damping_limit() -> None:
    """Pure damping on the finite-difference twist (no filter, negligible K_p): with
    d_k = x_k - x_(k-1) and w_k = dt v_k, n semi-implicit Euler substeps of the held force give
    d+ = w - c a d, w+ = w - a d, a = K_v dt / m, c = (n + 1) / (2 n): determinant (1 - c) a,
    so the loop is stable iff a < 1 / (1 - c) = 2 n / (n - 1) (2.5 for n = 5)."""
    n = PLANT_SUBSTEPS
    limit = 2.0 * n / (n - 1)
    assert servo_spectral_radius(1.0, 1e-3, 0.98 * limit / DT, 0.0, 0.0) < 1.0
    assert servo_spectral_radius(1.0, 1e-3, 1.02 * limit / DT, 0.0, 0.0) > 1.0


@pytest.mark.parametrize("name", DEVICE_CONFIGS)
def test_every_devices_foh_servo_is_stable_at_1_khz(name: str) -> None:
    device = load_device(name)
    inertia, damping, cutoff = plant_of(name)
    r = device.rendering
    for axis in range(3):
        rho = servo_spectral_radius(
            inertia[axis], r.foh_stiffness[axis], r.foh_damping[axis], damping[axis], cutoff
        )
        assert rho < MAX_SPECTRAL_RADIUS, f"{name} axis {axis}: spectral radius {rho:.5f}"


def test_every_built_in_model_ships_a_config() -> None:
    """A built-in device is its module, its config file and one entry point: the entry
    names the config, the config builds that model, and the generic checks above run on it."""
    from haptic_local_model.device_models.registry import installed_models

    built_in = [m for m in installed_models() if m.built_in and m.model and m.model.simulated]
    assert {m.name for m in built_in} == {"ideal", "maglev", "twin_pantograph"}
    for m in built_in:
        entry = DEVICE_MODELS[m.name]
        assert entry.config in DEVICE_CONFIGS, f"{m.name}: no configs/devices/{entry.config}.toml"
        assert tomllib.loads((DEVICES / f"{entry.config}.toml").read_text())["model"] == m.name
        assert entry.description
        assert isinstance(load_device(entry.config), SimulatedDevice)


def test_a_plugged_in_model_is_loaded_but_not_warmed(monkeypatch: Any) -> None:
    """A model another package registers loads by its `model` name; `make warm` covers the
    built-in models only (building a driver may open its hardware)."""
    from haptic_local_model.device_models import registry
    from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
    from haptic_local_model.haptic_server.harness.warmup import warm_runs

    before = warm_runs()
    assert {r[1] for r in before if r[0] == "maglev_scoop"} == {
        "ideal",
        "maglev",
        "twin_pantograph",
    }
    entry = registry.DeviceModel(IdealDeviceConfig, IdealDevice, "ideal_identity", "a test model")
    monkeypatch.setitem(registry.DEVICE_MODELS, "test_model", entry)
    assert warm_runs() == before
    device = registry.device_from_text('model = "test_model"\n', "test.toml")
    assert isinstance(device, IdealDevice)
    assert registry.device_config("test_model") == registry.device_config("ideal_identity")
