"""The real-device adapters (device_models/hardware) against fakes of the makers' bindings.

No device is attached here. tests/fake_vendors/ holds a fake of each binding at the calls the
adapter makes (HaplyHardwareAPI, forcedimension_core, pyOpenHaptics), with the maker's call
names and units, over one simulated handle that records every call (_fake_handle.py). The
tests check start-up and calibration, units and frames (mm for OpenHaptics, the planar axes
and the plane's hold spring), force limits, that no NaN reaches the binding, the time a read
and a command take, and the safe stop: at the end of a run, on SIGINT, on the watchdog (the
sim stopped) and on an exception in the binding, with the real haptic server over Zenoh.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_device_rendering import MAX_SPECTRAL_RADIUS, servo_spectral_radius

from haptic_local_model.device_models.base import (
    FAULT_INVALID_COMMAND,
    FAULT_SATURATED,
    SENSOR_DTYPE,
    DeviceError,
)
from haptic_local_model.device_models.hardware.base import HOLD_FADE_S, PlanarHardware
from haptic_local_model.device_models.registry import (
    device_config,
    installed_models,
    load_device,
)
from haptic_local_model.haptic_server.harness.warmup import built_in_models
from haptic_local_model.shared.config import ConfigError, read_toml
from haptic_local_model.shared.net.config import load_network

FAKES = Path(__file__).resolve().parent / "fake_vendors"
ADAPTERS = ("haply_inverse3", "forcedimension", "touch")
COMMANDS_BEYOND_TICKS = 10  # the start-up's first command and the safe stop's
BINDINGS = {"haply_inverse3": "HaplyHardwareAPI", "forcedimension": "forcedimension_core",
            "touch": "pyOpenHaptics"}  # fmt: skip
#: the calls each binding sees at start-up, in order (repeats of a call listed once)
START_UP = {
    "haply_inverse3": ["Inverse3", "device_wakeup_dict", "end_effector_force"],
    "forcedimension": ["drd.open", "drd.isInitialized", "drd.stop", "dhd.setMaxForce",
                       "dhd.enableForce"],
    "touch": ["hdInitDevice", "hdEnable(HD_FORCE_OUTPUT)", "hdStartScheduler",
              "hd.get_transform", "hd.set_force"],
}  # fmt: skip
PERIOD_S = 1e-3


def _config(name: str) -> dict[str, Any]:
    return read_toml(device_config(name))


def _axes(name: str) -> tuple[int, int, int, float, float]:
    from haptic_local_model.device_models.hardware.base import PlanarSection

    planar = _config(name)["planar"]
    return PlanarSection(x=planar["x"], y=planar["y"]).axes()


@pytest.fixture
def fake_vendor(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[Path]:
    """The fake bindings importable in this process (and in the servers a test starts);
    the record's path. The fakes' modules are forgotten afterwards."""
    record = tmp_path / "vendor.json"
    monkeypatch.syspath_prepend(str(FAKES))
    path = os.pathsep.join(p for p in (str(FAKES), os.environ.get("PYTHONPATH", "")) if p)
    monkeypatch.setenv("PYTHONPATH", path)
    monkeypatch.setenv("FAKE_VENDOR_RECORD", str(record))
    yield record
    for module in list(sys.modules):
        if module.split(".")[0] in {*BINDINGS.values(), "_fake_handle"}:
            del sys.modules[module]


def _handle() -> Any:
    return importlib.import_module("_fake_handle").HANDLE


def _start_at(monkeypatch: pytest.MonkeyPatch, name: str, planar: tuple[float, float, float]):
    """Put the fake handle at (x, y) on the scene's plane and `held` off it (vendor frame)."""
    ix, iy, iz, sx, sy = _axes(name)
    origin = np.array(_config(name)["planar"]["origin_m"], dtype=float)
    start = origin.copy()
    start[ix] += sx * planar[0]
    start[iy] += sy * planar[1]
    start[iz] += planar[2]
    monkeypatch.setenv("FAKE_VENDOR_START", ",".join(map(str, start)))


def _wait_for_servo(ticks: int = 3) -> None:
    """For the Touch: the servo thread applies what the loop commands at its next tick."""
    h = _handle()
    n = h.counts.get("hd.set_force", 0) if h else 0
    end = time.monotonic() + 1.0
    while _handle().counts.get("hd.set_force", 0) < n + ticks and time.monotonic() < end:
        time.sleep(0.001)


def test_the_adapters_are_built_in_hardware_models() -> None:
    """Each adapter registers like any device model (an entry point of this project), is
    marked as hardware (warm-ups and simulated-device tests leave it out) and ships a config
    whose [rendering] table is the last, as in every device config."""
    installed = {m.name: m for m in installed_models()}
    for name in ADAPTERS:
        entry = installed[name]
        assert entry.built_in and entry.model is not None and not entry.model.simulated
        assert read_toml(device_config(name))["model"] == name
        tables = [ln for ln in device_config(name).read_text().splitlines() if ln[:1] == "["]
        assert tables[-1] == "[rendering]"
    assert not set(ADAPTERS) & {Path(c).stem for c in built_in_models()}


@pytest.mark.parametrize("name", ADAPTERS)
def test_the_servo_gains_are_stable_on_the_apparent_mass(name: str) -> None:
    """virtual_coupling_foh's servo with the config's gains on a handle of the configured
    apparent mass, sampled at the device's highest rate: spectral radius < 0.999 per tick
    (the model of tests/test_device_rendering.py, without the device's own damping)."""
    config = _config(name)
    mass = config["planar"]["apparent_mass_kg"]
    k_p, k_v = config["rendering"]["foh_stiffness"], config["rendering"]["foh_damping"]
    for axis in (0, 1):
        for dt in (1e-3, 1.0 / config["max_rate_hz"]):
            rho = servo_spectral_radius(mass, k_p[axis], k_v[axis], 0.0, 0.0, dt)
            assert rho < MAX_SPECTRAL_RADIUS, f"{name} axis {axis} dt {dt}: {rho:.5f}"


def test_without_the_binding_the_config_names_the_extra() -> None:
    """Choosing an adapter whose binding is not installed is a config error naming the
    file, the key and the extra to install, before anything opens a device."""
    for name, binding in BINDINGS.items():
        if importlib.util.find_spec(binding) is not None:
            continue  # a real binding is installed here
        with pytest.raises(ConfigError) as err:
            load_device(name)
        text = str(err.value)
        assert f"{name}.toml" in text and "model" in text and binding in text
        assert f"haptic-local-model[{name.split('_')[0]}]" in text


@pytest.mark.slow
@pytest.mark.parametrize("name", ADAPTERS)
def test_start_up_then_a_tick_then_the_safe_stop(name: str, fake_vendor: Path) -> None:
    """The binding is opened as its maker documents it; the safe stop sends zero force last
    and closes the device (the Inverse3's binding has no close); a second stop and a late
    command send nothing."""
    device = load_device(name)
    assert isinstance(device, PlanarHardware)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    device.command(np.array([0.5, 0.25, 0.0]))
    _wait_for_servo()
    h = _handle()
    assert h.calls[: len(START_UP[name])] == START_UP[name]
    device.safe_stop()
    n = len(h.forces)
    assert h.forces[-1][1:4] == (0.0, 0.0, 0.0)
    device.safe_stop()
    device.command(np.array([1.0, 1.0, 0.0]))
    assert len(h.forces) == n
    if name == "haply_inverse3":
        assert not h.closed  # nothing to close: the zero force is the stop
    else:
        assert h.closed
        tail = {"forcedimension": ["stop", "close"], "touch": ["hdStopScheduler",
                                                              "hdDisableDevice"]}  # fmt: skip
        assert h.calls[-2:] == tail[name]


def test_an_uncalibrated_force_dimension_device(
    fake_vendor: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Calibration moves the device: without `calibrate = true` the adapter refuses to start
    (and closes the device); with it, drd.autoInit runs before forces are enabled."""
    monkeypatch.setenv("FAKE_VENDOR_CALIBRATED", "0")
    with pytest.raises(RuntimeError, match=r"not calibrated.*calibrate = true"):
        load_device("forcedimension")
    assert _handle().closed and "dhd.enableForce" not in _handle().calls
    text = device_config("forcedimension").read_text()
    allowed = tmp_path / "fd.toml"
    allowed.write_text(text.replace("calibrate = false", "calibrate = true"))
    device = load_device(str(allowed))
    calls = _handle().calls
    assert calls.index("drd.autoInit") < calls.index("dhd.enableForce")
    device.safe_stop()


@pytest.mark.slow
@pytest.mark.parametrize("name", ADAPTERS)
def test_units_frames_and_the_plane(
    name: str, fake_vendor: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The handle at (12 mm, -7 mm) on the plane and 4 mm off it reads as that planar pose
    (OpenHaptics reports mm, the others m); a planar command arrives on the configured
    device axes with their signs, and the third axis gets the hold spring, -k z - b v,
    faded in from zero over HOLD_FADE_S (no step at start-up if the handle rests off the
    plane)."""
    _start_at(monkeypatch, name, (0.012, -0.007, 0.004))
    device = load_device(name)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    assert sensors[0]["pose"] == pytest.approx([0.012, -0.007, 0.0], abs=1e-9)
    device.command(np.array([0.8, -0.3, 0.0]))
    _wait_for_servo()
    ix, iy, iz, sx, sy = _axes(name)
    assert abs(_handle().forces[-1][1 + iz]) < 1e-9  # the hold spring starts at zero ...
    time.sleep(HOLD_FADE_S)  # ... and fades in
    device.read(sensors)
    device.command(np.array([0.8, -0.3, 0.0]))
    _wait_for_servo()
    h = _handle()
    f = np.array(h.forces[-1][1:4])
    v = np.array(h.forces[-1][4:7])
    planar = _config(name)["planar"]
    assert f[ix] == pytest.approx(sx * 0.8) and f[iy] == pytest.approx(sy * -0.3)
    hold = -planar["hold_stiffness_n_per_m"] * 0.004 - planar["hold_damping_ns_per_m"] * v[iz]
    assert f[iz] == pytest.approx(hold, abs=0.02 * abs(hold))  # the Touch's servo: a tick on
    device.safe_stop()


@pytest.mark.slow
@pytest.mark.parametrize("name", ADAPTERS)
def test_force_limits_and_nan_never_sent(name: str, fake_vendor: Path) -> None:
    """A command beyond the limit is clipped in magnitude (the device's limit is on the
    force, planar and hold together) and flagged; a NaN or infinite one is replaced by zero
    force, flagged in the next reading, and never reaches the binding."""
    limit = _config(name)["max_wrench"][0]
    device = load_device(name)
    sensors = np.zeros(1, SENSOR_DTYPE)
    device.read(sensors)
    applied = device.command(np.array([100.0, -100.0, 5.0]))
    assert applied == pytest.approx([limit / np.sqrt(2), -limit / np.sqrt(2), 0.0])
    device.read(sensors)
    assert sensors[0]["fault"] & FAULT_SATURATED
    _wait_for_servo()
    h = _handle()
    assert np.linalg.norm(h.forces[-1][1:4]) == pytest.approx(limit)
    for bad in (math.nan, math.inf, -math.inf):
        applied = device.command(np.array([0.5, bad, 0.0]))
        assert list(applied) == [0.0, 0.0, 0.0]
        device.read(sensors)
        assert sensors[0]["fault"] & FAULT_INVALID_COMMAND
    _wait_for_servo()
    assert h.not_finite == 0 and all(math.isfinite(c) for f in h.forces for c in f)
    assert device.not_finite_commands == 3
    device.command(np.array([0.1, 0.1, 0.0]))
    device.read(sensors)
    assert not sensors[0]["fault"] & FAULT_INVALID_COMMAND
    device.safe_stop()


@pytest.mark.slow
@pytest.mark.parametrize("name", ADAPTERS)
def test_a_read_and_a_command_take_a_small_part_of_a_period(name: str, fake_vendor: Path) -> None:
    """3000 ticks paced at 1 kHz: read + command (the adapter and the fake binding) take
    well under one period (p99), so the loop keeps its rate."""
    device = load_device(name)
    sensors = np.zeros(1, SENSOR_DTYPE)
    wrench = np.array([0.2, -0.1, 0.0])
    spent = np.empty(3000)
    next_ns = time.perf_counter_ns()
    for k in range(spent.size):
        t0 = time.perf_counter_ns()
        device.read(sensors)
        device.command(wrench)
        spent[k] = (time.perf_counter_ns() - t0) / 1e3
        next_ns += int(PERIOD_S * 1e9)
        while time.perf_counter_ns() < next_ns:
            pass
    device.safe_stop()
    p50, p99 = np.percentile(spent, [50, 99])
    print(f"\n{name}: read + command p50 {p50:.1f} us, p99 {p99:.1f} us")
    assert p99 < PERIOD_S * 1e6


@pytest.mark.slow
def test_the_touch_servo_zeroes_a_stale_command(fake_vendor: Path) -> None:
    """The Touch's servo runs on its own: when the loop stops commanding (hung, or killed
    before its safe stop), the servo sends zero force after command_timeout_ms."""
    device = load_device("touch")
    timeout_s = _config("touch")["command_timeout_ms"] / 1e3
    device.command(np.array([1.0, 0.5, 0.0]))
    sent = time.monotonic_ns()
    time.sleep(timeout_s + 0.03)
    h = _handle()
    late = [f for f in h.forces if f[0] > sent + (timeout_s + 0.005) * 1e9]
    assert late and all(f[1:4] == (0.0, 0.0, 0.0) for f in late)
    early = [f for f in h.forces if sent < f[0] < sent + (timeout_s - 0.005) * 1e9]
    assert early and all(abs(f[1] - 1.0) < 1e-12 for f in early)
    device.safe_stop()


@pytest.mark.slow
def test_a_starved_touch_servo_is_not_taken_for_a_stopped_one(fake_vendor: Path) -> None:
    """A servo that has not ticked for servo_timeout_ms stops the run only if it does not
    tick while the read yields: one kept from running (a loaded machine) goes on, one that
    OpenHaptics unscheduled does not. The timeout set to zero makes every read suspect."""
    device = load_device("touch")
    assert isinstance(device, PlanarHardware)
    link: Any = device._link
    sensors = np.zeros(1, SENSOR_DTYPE)
    link._servo_timeout_ns = 0  # every reading finds the servo silent "too long"
    for _ in range(20):
        device.read(sensors)  # alive: it ticks within the grace, every time
    scheduler = link._device
    scheduler._running = False  # the servo stops, as after a callback's error
    scheduler._thread.join(1.0)
    with pytest.raises(DeviceError, match="the servo callback has not run"):
        device.read(sensors)
    device.safe_stop()


# --- the real servers, over Zenoh -----------------------------------------------------------

SCENE = "wall_push"  # the wall 2 cm in front of the tool along +x
HAND_N = 1.0


def _hand_env(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    """The fake hand pushes the handle along the scene's +x with HAND_N, in the vendor's
    frame; forces beyond the device's limit are counted."""
    ix, _, _, sx, _ = _axes(name)
    hand = [0.0, 0.0, 0.0]
    hand[ix] = sx * HAND_N
    monkeypatch.setenv("FAKE_VENDOR_HAND", ",".join(map(str, hand)))
    monkeypatch.setenv("FAKE_VENDOR_LIMIT", str(_config(name)["max_wrench"][0]))
    _start_at(monkeypatch, name, (0.0, 0.0, 0.0))


def _scene_x(name: str, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time s, force along the scene's x, velocity along it) of recorded forces."""
    ix, _, _, sx, _ = _axes(name)
    return rows[:, 0] / 1e9, sx * rows[:, 1 + ix], sx * rows[:, 4 + ix]


@pytest.mark.slow
@pytest.mark.processes
@pytest.mark.parametrize("name", ADAPTERS)
def test_a_run_the_watchdog_and_sigint_reach_the_device(
    name: str,
    fake_vendor: Path,
    monkeypatch: pytest.MonkeyPatch,
    network_file: Path,
    start_server: Any,
    tmp_path: Path,
) -> None:
    """Both servers over Zenoh with the adapter on the fake binding. The hand pushes the
    handle into the wall: the commanded force balances it. The sim is stopped (SIGSTOP):
    within the watchdog and the ramp the device gets only the safe state's damping; the sim
    resumes and the wall is back. SIGINT: the server stops cleanly, zero force last, the
    device closed. Commands came every period, none beyond the limit, none NaN."""
    _hand_env(monkeypatch, name)
    net = load_network(str(network_file))
    common = ["--scene", SCENE, "--network", str(network_file)]
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", *common, "--device", name,
        "--summary-json", str(tmp_path / "haptic.json"),
    )  # fmt: skip
    haptic.wait_ready()
    ticking_from = time.monotonic_ns() / 1e9  # after the device's open and first command
    sim = start_server("haptic_local_model.sim_server.cli", *common)
    sim.wait_ready()
    time.sleep(3.0)
    pushed_until = time.monotonic_ns() / 1e9
    os.kill(sim.proc.pid, signal.SIGSTOP)
    stopped_at = time.monotonic_ns() / 1e9
    time.sleep(0.6)
    # taken before the signal: the sim may publish (and the device leave the safe state)
    # before this process runs again after it (2 of 4 runs failed so, the last samples of
    # the "safe" window already ramping back in)
    resumed_at = time.monotonic_ns() / 1e9
    os.kill(sim.proc.pid, signal.SIGCONT)
    time.sleep(2.5)
    assert haptic.stop(signal.SIGINT) == 0
    assert sim.stop(signal.SIGINT) == 0

    record = json.loads(fake_vendor.read_text())
    rows = np.array(record["forces"])
    t, fx, vx = _scene_x(name, rows)
    limit = _config(name)["max_wrench"][0]
    assert record["not_finite"] == 0 and record["over_limit"] == 0
    assert record["max_force_norm"] <= limit * (1 + 1e-9)
    assert record["last_force"] == [0.0, 0.0, 0.0]
    assert record["closed"] == (name != "haply_inverse3")
    # at the wall, before the stop and after the resumption: the command balances the hand
    before = fx[(t > pushed_until - 1.0) & (t < pushed_until)]
    after = fx[(t > resumed_at + 1.5) & (t < resumed_at + 2.4)]
    for window in (before, after):
        assert window.size > 500 and np.mean(window) == pytest.approx(-HAND_N, rel=0.15)
    # the watchdog: after it and the ramp, only the safe state's damping, -b v
    b = _config(name)["rendering"]["safe_damping"][0]
    safe_from = stopped_at + (net.watchdog_ms + net.safe_ramp_ms) / 1e3 + 0.02
    safe = (t > safe_from) & (t < resumed_at)
    assert safe.sum() > 200
    assert np.all(np.abs(fx[safe]) <= b * np.abs(vx[safe]) * 1.2 + 0.02)
    # a command every tick: the binding saw as many commands as the loop ran ticks (and the
    # start-up's and the safe stop's few); an adapter that dropped one in ten misses by 10 %.
    # The Touch's servo sets the force on its own 1 kHz clock: the gaps' median is its
    # period. How evenly the ticks come, and their mean rate (a 150 ms stall of a loaded
    # machine takes 2 % off it), are the machine's load: benchmarks/loop_timing.py
    summary = json.loads((tmp_path / "haptic.json").read_text())
    sent = t[(t > ticking_from) & (t < pushed_until)]
    gaps_ms = np.diff(sent) * 1e3
    p50, p99 = np.percentile(gaps_ms, [50, 99])
    print(f"\n{name}: command gap p50 {p50:.3f} ms, mean {np.mean(gaps_ms):.4f} ms, "
          f"p99 {p99:.3f} ms; wall force {np.mean(before):.3f} N; {len(rows)} commands, "
          f"{summary['ticks']} ticks")  # fmt: skip
    if name != "touch":
        assert 0 <= len(rows) - summary["ticks"] <= COMMANDS_BEYOND_TICKS, summary["ticks"]
    assert p50 == pytest.approx(1.0, abs=0.05) and sent.size > 2500
    assert summary["watchdog_trips"] >= 1 and summary["reinitialisations"] >= 1


@pytest.mark.slow
@pytest.mark.processes
@pytest.mark.parametrize("name", ADAPTERS)
def test_an_exception_in_the_binding_stops_the_run_safe(
    name: str,
    fake_vendor: Path,
    monkeypatch: pytest.MonkeyPatch,
    network_file: Path,
    start_server: Any,
) -> None:
    """The binding fails at its 300th force after the first that was not zero (the loop is
    rendering; the device stopped answering; for the Touch the failure is in OpenHaptics'
    servo thread, which then stops): the haptic server ends with an error naming it, after
    sending zero force and closing the device. Both servers run: the wall pushes back."""
    _hand_env(monkeypatch, name)
    monkeypatch.setenv("FAKE_VENDOR_RAISE_AT", "300")
    sim = start_server(
        "haptic_local_model.sim_server.cli", "--scene", SCENE, "--network", str(network_file)
    )
    res = subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.cli", "--scene", SCENE,
         "--network", str(network_file), "--device", name, "--duration", "20"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 1
    why = "servo callback has not run" if name == "touch" else "stopped answering"
    line = res.stderr.strip().splitlines()[-1]
    assert line.startswith("haptic-server: device error:") and why in line, res.stderr
    assert line.endswith("the device is in its safe state")
    sim.stop(signal.SIGINT)
    record = json.loads(fake_vendor.read_text())
    assert record["pushed_before_failure"] and record["max_abs_force"] > 0.1
    assert record["not_finite"] == 0
    if name == "touch":  # its servo is dead: no zero force can be set, the device is disabled
        assert record["last_calls"][-2:] == ["hdStopScheduler", "hdDisableDevice"]
    else:
        assert record["last_force"] == [0.0, 0.0, 0.0]
    assert record["closed"] == (name != "haply_inverse3")


class _BrokenLink:
    """A binding that opens and reads, but whose stop fails (the cable is out)."""

    def open(self) -> None:
        self.sent: list[list[float]] = []

    def sample(self, position: np.ndarray, velocity: np.ndarray) -> int:
        position[:] = velocity[:] = 0.0
        return 0

    def send(self, force: np.ndarray) -> None:
        self.sent.append([float(f) for f in force])

    def stop(self) -> None:
        self.stops = getattr(self, "stops", 0) + 1
        raise OSError("the device is gone")


def test_a_failing_safe_stop_says_so_and_is_tried_again() -> None:
    """A stop the binding cannot carry out is a SafeStopError naming it (the server reports
    that the device may still apply force, and still closes its log); nothing more is
    commanded, and a later safe stop tries the binding's stop again."""
    from haptic_local_model.device_models.base import SafeStopError
    from haptic_local_model.device_models.hardware.base import HardwareConfig

    link = _BrokenLink()
    device = PlanarHardware(HardwareConfig(), link)
    device.command(np.array([1.0, 0.0, 0.0]))
    with pytest.raises(SafeStopError, match="safe stop failed: the device is gone"):
        device.safe_stop()
    assert list(device.command(np.array([1.0, 0.0, 0.0]))) == [0.0, 0.0, 0.0]
    assert len(link.sent) == 1
    with pytest.raises(SafeStopError):
        device.safe_stop()
    assert link.stops == 2
    link.stop = lambda: None  # type: ignore[method-assign]  # the cable is back
    device.safe_stop()
    device.safe_stop()  # stopped: nothing more to do


@pytest.mark.processes
def test_nothing_but_the_haptic_server_opens_a_real_device(
    fake_vendor: Path, tmp_path: Path
) -> None:
    """The virtual clock and haptic-replay need a simulated device: a hardware model is
    refused before it is built (building it opens, maybe calibrates, the device); and the
    haptic server checks every config before it opens one (a typo opens nothing)."""
    from haptic_local_model.device_models.registry import device_from_text, load_simulated_device

    for name in ADAPTERS:
        with pytest.raises(ConfigError, match="drives hardware"):
            load_simulated_device(name)
        with pytest.raises(ConfigError, match="drives hardware"):
            device_from_text(device_config(name).read_text(), "log", simulated_only=True)
    assert _handle() is None  # no fake device was ever opened
    res = subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.cli", "--scene",
         str(tmp_path / "missing.toml"), "--device", "forcedimension"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 2 and "missing.toml" in res.stderr
    assert not fake_vendor.exists()  # the fake writes its record once a device is opened
