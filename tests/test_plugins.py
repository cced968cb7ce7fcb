"""Device models are plug-ins: a driver ships as a package of its own and registers its
models in the entry-point group `haptic_local_model.devices`; the built-in models register
the same way. A plug-in that fails to load is reported, not fatal to the others.

The end-to-end test builds the driver package of tests/plugin_driver/ in a temporary
directory, installs it beside the project's wheel in a fresh virtual environment, and from
an unrelated directory finds it with `haptic-run --list` and runs the two servers on it over
Zenoh: the driver records every call the loop makes, and the record is checked against the
device's limits and the physics of the push (at rest against the wall, the command balances
the hand).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest
from conftest import run_installed

from haptic_local_model.device_models import registry
from haptic_local_model.device_models.base import DeviceModel
from haptic_local_model.shared.config import ConfigError

PLUGIN = Path(__file__).resolve().parent / "plugin_driver"
BUILT_IN = {"ideal", "maglev", "twin_pantograph"}


def test_the_built_in_models_are_entry_points() -> None:
    """The three built-in models come through the same entry-point group as any plug-in."""
    installed = {m.name: m for m in registry.installed_models()}
    assert set(installed) >= BUILT_IN
    for name in BUILT_IN:
        entry = installed[name]
        assert entry.built_in and entry.problem == ""
        assert isinstance(entry.model, DeviceModel)
        assert entry.value == f"haptic_local_model.device_models.{name}:MODEL"
        assert registry.device_config(name).is_file()  # its shipped config
    assert registry.load_device("ideal").name == "ideal"


def test_a_broken_plugin_is_reported_not_fatal(monkeypatch: pytest.MonkeyPatch) -> None:
    """A plug-in that does not import, one that registers something else than a
    DeviceModel and a second registration of a taken name: each is listed with its reason,
    the good one still loads, and choosing a broken one is a config error that says why."""
    group = registry.GROUP
    points = [
        EntryPoint("ideal", "haptic_local_model.device_models.ideal:MODEL", group),
        EntryPoint("ideal", "haptic_local_model.device_models.maglev:MODEL", group),
        EntryPoint("ghost", "no_such_driver_package:MODEL", group),
        EntryPoint("number", "math:pi", group),
    ]
    monkeypatch.setattr(registry, "entry_points", lambda group: points)
    found = registry.discover()
    good = [m for m in found if m.model is not None]
    assert [m.name for m in good] == ["ideal"] and good[0].value.endswith("ideal:MODEL")
    problems = {m.value: m.problem for m in found if m.model is None}
    assert "also registered" in problems["haptic_local_model.device_models.maglev:MODEL"]
    assert "ModuleNotFoundError" in problems["no_such_driver_package:MODEL"]
    assert "not a DeviceModel" in problems["math:pi"]

    monkeypatch.setitem(registry.BROKEN_MODELS, "ghost", problems["no_such_driver_package:MODEL"])
    with pytest.raises(ConfigError, match=r"my\.toml: key 'model': .*ghost.*ModuleNotFoundError"):
        registry.device_from_table("ghost", {}, "my.toml")
    with pytest.raises(ConfigError, match=r"unknown device model 'nobody'.*entry-point group"):
        registry.device_from_table("nobody", {}, "my.toml")


@pytest.mark.slow
@pytest.mark.processes
def test_a_driver_package_is_found_and_drives_a_run(
    installed: Path, tmp_path: Path, network_file: Path
) -> None:
    source = tmp_path / "driver-source"
    shutil.copytree(PLUGIN, source)
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(source)],
        check=True, timeout=600,
    )  # fmt: skip
    (wheel,) = wheels.glob("haptic_test_driver-*.whl")
    pip = [str(installed / "bin" / "python"), "-m", "pip"]
    subprocess.run([*pip, "install", "-q", "--no-deps", str(wheel)], check=True, timeout=600)
    try:
        work = tmp_path / "elsewhere"
        work.mkdir()
        (work / "net.toml").write_text(network_file.read_text())  # loopback, a free port

        listed = run_installed(installed, work, "haptic-run", "--list")
        assert listed.returncode == 0, listed.stderr
        (line,) = [row for row in listed.stdout.splitlines() if "recording_arm" in row]
        assert "from haptic-test-driver (haptic_test_driver:MODEL)" in line, line
        assert "BROKEN" not in listed.stdout

        # a fresh environment compiles its kernels on the first run, and its sim starts
        # a minute late: meanwhile the driver's hand pushes the handle for a minute (its
        # end stops: END_STOP_M). Warm up first, as `make warm` does for a checkout.
        warm = run_installed(
            installed, work, "haptic-run", "--scene", "wall_push", "--device", "recording_arm",
            "--network", "net.toml", "--duration", "1", "--no-log",
        )  # fmt: skip
        assert warm.returncode == 0, warm.stderr + warm.stdout
        seconds = 5.0
        run = run_installed(
            installed, work, "haptic-run", "--scene", "wall_push", "--device", "recording_arm",
            "--network", "net.toml", "--duration", str(seconds), "--log", "out/run.mcap",
            "--summary-json", "out/run.json",
        )  # fmt: skip
        assert run.returncode == 0, run.stderr + run.stdout
        summary = json.loads((work / "out/run.json").read_text())
        assert summary["exit_codes"] == {"haptic": 0, "sim": 0}
        assert summary["updates_received"] > 0.8 * 60 * seconds

        record = json.loads((work / "recording_arm.json").read_text())
        # the loop read and commanded the driver every tick, within its limits, never NaN
        assert record["commands"] >= 0.95 * 1000 * seconds, record["commands"]
        assert record["reads"] >= record["commands"]
        assert record["not_finite"] == 0 and record["over_limit"] == 0
        assert record["max_abs_force"] <= 10.0 and record["finite_pose"]
        assert record["safe_stops"] >= 1  # the run's end sends it to its safe state
        # pushed by 2 N into the wall, the handle comes to rest: the command balances the
        # hand (within the slow creep of the coordination coupling, docs/bench/front.md)
        fx = np.array(record["fx_last_second"][-500:])
        assert abs(float(np.mean(fx)) + 2.0) < 0.3, float(np.mean(fx))
        assert record["pose"][0] > 0.0  # it moved toward the wall, as pushed
    finally:
        subprocess.run([*pip, "uninstall", "-q", "-y", "haptic-test-driver"], check=False)
