"""The device doctor (`haptic-device`, device_models/doctor.py) end to end against the fakes
of the three makers' bindings (tests/fake_vendors): the faults a real bring-up meets, each
with its message and exit code (issue 49)."""

from __future__ import annotations

import grp
import importlib
import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_local_model.device_models import doctor
from haptic_local_model.device_models.hardware.base import serial_ports, usb_nodes
from haptic_local_model.haptic_server.harness.device_doctor import main

FAKES = Path(__file__).resolve().parent / "fake_vendors"
BINDINGS = {"haply_inverse3": "HaplyHardwareAPI", "forcedimension": "forcedimension_core",
            "touch": "pyOpenHaptics"}  # fmt: skip
EXTRAS = {"haply_inverse3": "haply", "forcedimension": "forcedimension", "touch": "touch"}


def _forget_fakes() -> None:
    for module in list(sys.modules):
        if module.split(".")[0] in {*BINDINGS.values(), "_fake_handle"}:
            del sys.modules[module]


@pytest.fixture
def fakes(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[Path]:
    """The fake bindings importable here and in the processes a test starts; the record's
    path. The fakes' modules are forgotten before and after (an env setting is read on
    import)."""
    _forget_fakes()
    record = tmp_path / "vendor.json"
    monkeypatch.syspath_prepend(str(FAKES))
    path = os.pathsep.join(p for p in (str(FAKES), os.environ.get("PYTHONPATH", "")) if p)
    monkeypatch.setenv("PYTHONPATH", path)
    monkeypatch.setenv("FAKE_VENDOR_RECORD", str(record))
    yield record
    _forget_fakes()


def _list_json(capsys: pytest.CaptureFixture[str]) -> dict[str, dict]:
    assert main(["list", "--json"]) == 0
    return {r["name"]: r for r in json.loads(capsys.readouterr().out)}


def test_list_without_the_bindings_names_the_extra(capsys: pytest.CaptureFixture[str]) -> None:
    """No fake on the path (and no real binding here): each hardware model says its binding
    is not installed and the pip extra that installs it; simulated models are listed too."""
    _forget_fakes()
    reports = _list_json(capsys)
    assert {"ideal", "maglev", "twin_pantograph"} <= set(reports)
    assert reports["ideal"]["simulated"] and reports["ideal"]["exit_code"] == 0
    for name, binding in BINDINGS.items():
        r = reports[name]
        assert not r["binding_ok"] and r["exit_code"] == doctor.EXIT_BINDING
        assert r["problem"] == f"the binding {binding!r} is not installed"
        assert r["fix"] == f"pip install 'haptic-local-model[{EXTRAS[name]}]'"
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    assert "binding pyOpenHaptics: NOT INSTALLED" in text
    assert "fix: pip install 'haptic-local-model[touch]'" in text


def test_list_with_the_fakes_detects_devices(
    fakes: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With the bindings: the runtime loads; the Inverse3 and Force Dimension bindings detect
    a device without opening it; OpenHaptics cannot tell without opening one."""
    reports = _list_json(capsys)
    haply, fd, touch = (reports[n] for n in ("haply_inverse3", "forcedimension", "touch"))
    assert haply["devices"] == ["Inverse3 on /dev/ttyFAKE0 (its id is read on opening)"]
    assert len(fd["devices"]) == 1 and touch["devices"] is None
    assert all(r["binding_ok"] and r["runtime_ok"] and r["exit_code"] == 0 for r in (haply, fd))
    main(["list"])
    assert "devices: the binding cannot tell without opening one" in capsys.readouterr().out


def test_list_runtime_missing(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The binding imports but the vendor's library does not load (the OSError ctypes
    raises): named with what to install; the Inverse3 has no runtime beyond its binding."""
    monkeypatch.setenv("FAKE_VENDOR_RUNTIME", "0")
    reports = _list_json(capsys)
    fd, touch = reports["forcedimension"], reports["touch"]
    for r, library in ((fd, "libdhd.so.3"), (touch, "libHD.so")):
        assert r["binding_ok"] and not r["runtime_ok"]
        assert r["exit_code"] == doctor.EXIT_RUNTIME
        assert f"the vendor runtime does not load (OSError: {library}: cannot open" in r["problem"]
    assert "Force Dimension SDK" in fd["fix"] and "OpenHaptics" in touch["fix"]
    assert reports["haply_inverse3"]["runtime_ok"]


def test_list_no_device(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Nothing attached: the bindings that can detect say so, with the permission to check."""
    monkeypatch.setenv("FAKE_VENDOR_DEVICES", "0")
    reports = _list_json(capsys)
    for name in ("haply_inverse3", "forcedimension"):
        r = reports[name]
        assert r["devices"] == [] and r["problem"] == "no device detected"
        assert r["exit_code"] == doctor.EXIT_NO_DEVICE
    assert "dialout" in reports["haply_inverse3"]["fix"]
    assert "udev" in reports["forcedimension"]["fix"]


def test_device_files_are_found_without_the_binding(tmp_path: Path) -> None:
    """The serial ports by their glob; a vendor's USB nodes from sysfs (bus and device
    numbers), another vendor's and an unreadable entry left out."""
    for name in ("ttyACM1", "ttyACM0", "ttyUSB0"):
        (tmp_path / name).touch()
    assert serial_ports(str(tmp_path / "ttyACM*")) == [str(tmp_path / f"ttyACM{i}") for i in (0, 1)]
    sysfs = tmp_path / "usb"
    for entry, vendor, bus, dev in (("1-2", "1451", 1, 7), ("2-1", "046d", 2, 3),
                                    ("3-1", "1451", 3, 12), ("4-1", "1451", "x", 1)):  # fmt: skip
        (sysfs / entry).mkdir(parents=True)
        (sysfs / entry / "idVendor").write_text(f"{vendor}\n")
        (sysfs / entry / "busnum").write_text(f"{bus}\n")
        (sysfs / entry / "devnum").write_text(f"{dev}\n")
    assert usb_nodes("1451", str(sysfs)) == ["/dev/bus/usb/001/007", "/dev/bus/usb/003/012"]


def _with_nodes(monkeypatch: pytest.MonkeyPatch, model: str, nodes: list[str],
                blocked: set[str]) -> None:  # fmt: skip
    """The model's device files are `nodes`, of which this account may not open `blocked`
    (the tests run as root, who may open anything)."""
    module = importlib.import_module(f"haptic_local_model.device_models.hardware.{model}")
    monkeypatch.setattr(module, "BRINGUP", module.BRINGUP._replace(nodes=lambda: nodes))
    monkeypatch.setattr(doctor, "may_open", lambda path: path not in blocked)


def test_list_device_files_this_account_may_not_open(
    fakes: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """Every device file found but none this account may open: exit 19, each named with its
    mode and group, the fix the model's (dialout); one of two blocked: listed, not a fault."""
    port = tmp_path / "ttyACM0"
    port.touch()
    port.chmod(0o660)
    group = grp.getgrgid(port.stat().st_gid).gr_name  # root's: this account is in it
    _with_nodes(monkeypatch, "haply", [str(port)], {str(port)})
    r = _list_json(capsys)["haply_inverse3"]
    assert r["exit_code"] == doctor.EXIT_ACCESS and r["blocked"] == [
        f"{port} (-rw-rw----, group {group})"
    ]
    assert r["problem"] == f"this account may not open {port} (-rw-rw----, group {group})"
    assert "dialout" in r["fix"]
    assert main(["list"]) == 0
    assert f"problem: this account may not open {port}" in capsys.readouterr().out
    other = tmp_path / "ttyACM1"
    other.touch()
    _with_nodes(monkeypatch, "haply", [str(port), str(other)], {str(port)})
    r = _list_json(capsys)["haply_inverse3"]
    assert r["exit_code"] == 0 and len(r["blocked"]) == 1 and r["nodes"] == [str(port), str(other)]
    main(["list"])
    text = capsys.readouterr().out
    assert f"device files: {port}, {other}" in text and f"may not open {port} (" in text


def test_the_device_files_are_listed_before_the_binding_is_installed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A user who has plugged the device in but not installed the binding sees its port,
    and the binding's fix stays the problem (exit 10, not 19)."""
    _forget_fakes()
    port = tmp_path / "ttyACM0"
    port.touch()
    _with_nodes(monkeypatch, "haply", [str(port)], {str(port)})
    r = _list_json(capsys)["haply_inverse3"]
    assert r["exit_code"] == doctor.EXIT_BINDING and r["nodes"] == [str(port)]
    main(["list"])
    text = capsys.readouterr().out
    assert f"device files: {port}\n    may not open {port} (" in text
    assert "fix: pip install 'haptic-local-model[haply]'" in text


def test_a_blocked_file_names_a_group_this_account_is_not_in(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    port = tmp_path / "ttyACM0"
    port.touch()
    port.chmod(0o660)
    os.chown(port, -1, 54321)  # a group without a name, this account not in it (root may)
    monkeypatch.setattr(doctor, "may_open", lambda path: False)
    assert doctor._blocked(str(port)) == (
        f"{port} (-rw-rw----, group 54321, which this account is not in)"
    )


def test_check_stops_before_opening_a_device_file_it_may_not_open(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The Force Dimension's USB node is there but not this account's: exit 19 before the
    device is opened, with the udev rule as the fix; a missing file is named so."""
    _with_nodes(
        monkeypatch,
        "forcedimension",
        ["/nonexistent/bus/usb/001/007"],
        {"/nonexistent/bus/usb/001/007"},
    )
    code, out = _check(capsys, "--device", "forcedimension")
    assert code == doctor.EXIT_ACCESS, out
    assert (
        "find: FAILED: this account may not open /nonexistent/bus/usb/001/007 (No such file" in out
    )
    assert "udev rule" in out and "open:" not in out


@pytest.mark.processes
def test_the_console_script_lists(fakes: Path) -> None:
    """`haptic-device list` as installed: exit 0, the fakes' devices listed."""
    script = Path(sys.executable).parent / "haptic-device"
    out = subprocess.run([str(script), "list"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "Inverse3 on /dev/ttyFAKE0" in out.stdout and "twin_pantograph" in out.stdout


ADAPTERS = tuple(BINDINGS)
#: where each shipped config's [planar] origin is (the fake handle starts there)
QUICK = ["--seconds", "0.1", "--move-seconds", "0.4"]


def _start_at_origin(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    """The fake handle starts at the config's [planar] origin, its plane and its mass as the
    config says."""
    from haptic_local_model.device_models.registry import device_config
    from haptic_local_model.shared.config import read_toml

    planar = read_toml(device_config(name))["planar"]
    monkeypatch.setenv("FAKE_VENDOR_START", ",".join(map(str, planar["origin_m"])))
    monkeypatch.setenv("FAKE_VENDOR_PLANE", f"{planar['x']},{planar['y']}")
    # the handle weighs what the config says it does (the force's magnitude is told by it),
    # its friction of the fake's default time constant (0.2 kg at 1 N s/m)
    mass = float(planar["apparent_mass_kg"])
    monkeypatch.setenv("FAKE_VENDOR_MASS", str(mass))
    monkeypatch.setenv("FAKE_VENDOR_FRICTION", str(mass / 0.2))


def _user(step: str, text: str) -> None:
    """The fake user: moves the handle along the scene's axis it is asked for."""
    if step in ("x", "y"):
        importlib.import_module("_fake_handle").HANDLE.user_moves(step)


def _check(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    code = main(["check", *QUICK, *args], ask=_user)
    return code, capsys.readouterr().out


def _record() -> Any:
    return importlib.import_module("_fake_handle").HANDLE


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_check_passes_on_a_healthy_fake(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Rate, jitter and noise reported; the moves match the shipped [planar] map; no force
    without --force; the safe stop closes the device."""
    _start_at_origin(monkeypatch, name)
    code, out = _check(capsys, "--device", name)
    assert code == 0, out
    assert re.search(r"rest: ok: \d+ readings at \d+ Hz; period p50 [\d.]+ ms, p99", out)
    assert "axes: ok:" in out and "spring: not tried (forces only with --force)" in out
    assert "stop: ok: safe stop: zero force, the device closed" in out
    assert out.rstrip().endswith("check passed (exit 0)")
    h = _record()
    assert max((max(map(abs, f[1:4])) for f in h.forces), default=0.0) == 0.0
    assert h.closed or name == "haply_inverse3"  # the Inverse3's binding has no close


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_one_axis_flipped_is_found_and_the_written_table_fixes_it(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:  # fmt: skip
    """The device's y runs the other way than the config says: named, exit 14, and the
    config --write writes makes the next check pass."""
    _start_at_origin(monkeypatch, name)
    x, y = os.environ["FAKE_VENDOR_PLANE"].split(",")
    flipped = y[1:] if y.startswith("-") else f"-{y}"
    monkeypatch.setenv("FAKE_VENDOR_PLANE", f"{x},{flipped}")
    fixed = tmp_path / "fixed.toml"
    code, out = _check(capsys, "--device", name, "--write", str(fixed))
    assert code == doctor.EXIT_AXES, out
    assert "axes: FAILED: the scene's y is flipped" in out
    assert f"Wrote {fixed} with [planar] x = {x!r}, y = {flipped!r}" in out
    assert h_closed_or_zero(name)
    _forget_fakes()
    code, out = _check(capsys, "--device", str(fixed))
    assert code == 0, out


def h_closed_or_zero(name: str) -> bool:
    """The device is closed (the Inverse3: its last force is zero, its binding has no close)."""
    h = _record()
    return (
        h.closed if name != "haply_inverse3" else (not h.forces or h.forces[-1][1:4] == (0, 0, 0))
    )


@pytest.mark.slow  # real time: the device is read at 1 kHz
def test_swapped_axes_are_named(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _start_at_origin(monkeypatch, "touch")
    monkeypatch.setenv("FAKE_VENDOR_PLANE", "y,x")
    code, out = _check(capsys, "--device", "touch")
    assert code == doctor.EXIT_AXES and "axes: FAILED: x and y are swapped" in out


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_a_frozen_pose(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The readings never change, at rest nor when the user moves: a named failure."""
    _start_at_origin(monkeypatch, name)
    monkeypatch.setenv("FAKE_VENDOR_FROZEN", "1")
    code, out = _check(capsys, "--device", name)
    assert code == doctor.EXIT_FROZEN, out
    assert (
        "x: FAILED: the pose did not change at all, at rest nor when the handle was to move" in out
    )
    assert "its readings are frozen" in out and h_closed_or_zero(name)


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_a_force_sign_flipped(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """With --force the spring toward the start pushes the handle away: a named failure;
    the force stays within 10 % of the device's limit and the device ends closed."""
    _start_at_origin(monkeypatch, name)
    monkeypatch.setenv("FAKE_VENDOR_FORCE_SIGN", "-1")
    code, out = _check(capsys, "--device", name, "--force")
    assert code == doctor.EXIT_FORCE, out
    assert "spring: FAILED: the spring pushes away from the start" in out
    assert "The force's sign is flipped" in out
    _assert_gentle(name)
    assert h_closed_or_zero(name)


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_the_spring_restores(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _start_at_origin(monkeypatch, name)
    code, out = _check(capsys, "--device", name, "--force")
    assert code == 0, out
    assert "spring: ok: the spring restores toward the start" in out
    gain = re.search(r"force: ok: the handle moved as if the force were ([\d.]+) x the force", out)
    assert gain is not None, out
    assert 0.9 <= float(gain.group(1)) <= 1.1
    _assert_gentle(name)


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
@pytest.mark.parametrize(
    ("scale", "cause"),
    [("0.3", "the device renders a fraction of the force asked"),
     ("3", "the device renders more force than asked")],
)  # fmt: skip
def test_a_force_scaled(
    name: str, scale: str, cause: str, fakes: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """The device renders 0.3 or 3 times the force sent: the spring still restores, the
    handle's response names the scale (exit 18); the force sent stays gentle, the device
    ends closed."""
    _start_at_origin(monkeypatch, name)
    monkeypatch.setenv("FAKE_VENDOR_FORCE_SCALE", scale)
    code, out = _check(capsys, "--device", name, "--force")
    assert code == doctor.EXIT_FORCE_SCALE, out
    assert "spring: ok: the spring restores toward the start" in out
    found = re.search(r"force: FAILED: the handle moved as if the force were ([\d.]+) x", out)
    assert found is not None, out
    assert float(found.group(1)) == pytest.approx(float(scale), rel=0.15)
    assert f"outside 0.5-2 x. Either {cause}" in out
    assert out.rstrip().endswith("check FAILED (exit 18)")
    _assert_gentle(name)
    assert h_closed_or_zero(name)


def _assert_gentle(name: str) -> None:
    """No force beyond 10 % of the limit in the plane (the hold spring aside), none NaN."""
    from haptic_local_model.device_models.hardware.base import PlanarSection
    from haptic_local_model.device_models.registry import device_config
    from haptic_local_model.shared.config import read_toml

    config = read_toml(device_config(name))
    ix, iy, _, _, _ = PlanarSection(x=config["planar"]["x"], y=config["planar"]["y"]).axes()
    h = _record()
    planar = [math.hypot(f[1 + ix], f[1 + iy]) for f in h.forces]
    assert max(planar) <= 0.1 * config["max_wrench"][0] + 1e-9
    assert h.not_finite == 0 and max(planar) > 0


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_a_binding_call_that_raises_mid_check(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The binding fails on a reading (during the rest step; the Touch's servo thread reads
    from the open on, its adapter notices a servo that stopped later): a message naming the step
    and the binding's error, exit 16, the safe stop done and the device closed."""
    _start_at_origin(monkeypatch, name)
    monkeypatch.setenv("FAKE_VENDOR_READ_FAIL_AT", "40")
    code, out = _check(capsys, "--device", name)
    assert code == doctor.EXIT_DEVICE_FAILED, out
    step = "rest" if name != "touch" else r"\w+"  # the Touch's servo reads on its own
    assert re.search(rf"({step}): FAILED: the device failed during the \1 step: DeviceError:", out)
    assert "the device stopped answering" in out or "servo callback has not run" in out
    assert "stop: ok: safe stop" in out and h_closed_or_zero(name)


@pytest.mark.parametrize(
    ("env", "code", "text"),
    [
        ({"FAKE_VENDOR_RUNTIME": "0"}, doctor.EXIT_RUNTIME, "find: FAILED: the vendor runtime "
         "does not load (OSError: libdhd.so.3: cannot open"),
        ({"FAKE_VENDOR_DEVICES": "0"}, doctor.EXIT_NO_DEVICE, "find: FAILED: no device detected"),
    ],
)  # fmt: skip
def test_check_before_opening(
    env: dict[str, str], code: int, text: str, fakes: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """A missing runtime or no device ends the check before anything is opened."""
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    got, out = _check(capsys, "--device", "forcedimension")
    assert got == code and text in out, out


@pytest.mark.slow  # real time: the device is read at 1 kHz
def test_check_no_touch_found_on_opening(
    fakes: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """OpenHaptics cannot detect without opening: the open fails, named, exit 12, closed."""
    monkeypatch.setenv("FAKE_VENDOR_DEVICES", "0")
    code, out = _check(capsys, "--device", "touch")
    assert code == doctor.EXIT_NO_DEVICE
    assert "open: FAILED: opening the device failed: " in out and "HD_DEVICE_ERROR" in out


def test_check_binding_missing(capsys: pytest.CaptureFixture[str]) -> None:
    _forget_fakes()
    code, out = _check(capsys, "--device", "haply_inverse3")
    assert code == doctor.EXIT_BINDING
    fix = "fix: pip install 'haptic-local-model[haply]'"
    assert f"find: FAILED: the binding 'HaplyHardwareAPI' is not installed; {fix}" in out


def test_check_a_simulated_device_is_a_config_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--device", "ideal"]) == 2
    assert "is simulated: the doctor checks a real device" in capsys.readouterr().err


@pytest.mark.slow  # real time: the device is read at 1 kHz
def test_the_bring_up_log(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:  # fmt: skip
    """`check --log` writes every sample (each step's) and the findings as metadata; the
    spring's commanded and applied forces are in it."""
    from mcap.reader import make_reader

    from haptic_local_model.device_models.doctor_check import SAMPLE_DTYPE, STEPS
    from haptic_local_model.haptic_server.harness.device_doctor import LOG_TOPIC

    _start_at_origin(monkeypatch, "forcedimension")
    log = tmp_path / "bring-up.mcap"
    code, out = _check(capsys, "--device", "forcedimension", "--force", "--log", str(log))
    assert code == 0, out
    assert f"log: {log} (" in out
    with log.open("rb") as fh:
        reader = make_reader(fh)
        rows = np.array(
            [np.frombuffer(m.data, SAMPLE_DTYPE)[0] for _, c, m in reader.iter_messages()
             if c.topic == LOG_TOPIC]
        )  # fmt: skip
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    steps = {STEPS[s] for s in rows["step"]}
    assert {"rest", "x", "y", "spring"} <= steps
    spring = rows[rows["step"] == STEPS.index("spring")]
    assert np.abs(spring["commanded"]).max() > 0 and np.abs(spring["applied"]).max() > 0
    findings = json.loads(metadata["device_doctor"]["findings"])
    assert [f["step"] for f in findings] == ["rest", "axes", "spring", "force", "stop"]
    assert metadata["device_doctor"]["exit_code"] == "0"
    assert 'model = "forcedimension"' in metadata["device_config"]["text"]


@pytest.mark.processes
def test_the_console_script_checks_a_frozen_device(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """`haptic-device check` as installed, stdin closed: the frozen fake's exit code and
    message, the device closed (the fake's record), the log written."""
    _start_at_origin(monkeypatch, "forcedimension")
    monkeypatch.setenv("FAKE_VENDOR_FROZEN", "1")
    script = Path(sys.executable).parent / "haptic-device"
    log = tmp_path / "frozen.mcap"
    out = subprocess.run(
        [str(script), "check", "--device", "forcedimension", *QUICK, "--log", str(log)],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert out.returncode == doctor.EXIT_FROZEN, out.stdout + out.stderr
    assert "its readings are frozen" in out.stdout and log.is_file()
    assert json.loads(fakes.read_text())["closed"]


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize(
    ("name", "error"),
    [("touch", "HD_COMM_ERROR: hdDisableDevice failed (FAKE_VENDOR_CLOSE_FAIL)"),
     ("forcedimension", "Force Dimension dhd.stop failed: communication error (fake: "
      "FAKE_VENDOR_CLOSE_FAIL)")],
)  # fmt: skip
def test_the_safe_stop_fails(
    name: str, error: str, fakes: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], tmp_path: Path,
) -> None:  # fmt: skip
    """The binding's closing call fails (OpenHaptics' disable raises, the Force Dimension
    SDK's dhd.stop returns -1): a check that passed every step ends with exit 17 and says
    the device may still push. (The Inverse3's binding has no closing call: its stop is a
    zero-force command, whose failure is this same finding.) The log replays it."""
    _start_at_origin(monkeypatch, name)
    monkeypatch.setenv("FAKE_VENDOR_CLOSE_FAIL", "1")
    log = tmp_path / "stop.mcap"
    code, out = _check(capsys, "--device", name, "--log", str(log))
    assert code == doctor.EXIT_SAFE_STOP, out
    assert "axes: ok:" in out
    assert (
        f"stop: FAILED: {name}: the safe stop failed: {error}: the device may still push; "
        "switch it off" in out
    )
    assert out.rstrip().endswith("check FAILED (exit 17)")
    assert _replay(capsys, log)[0] == 0


@pytest.mark.slow  # real time: the device is read at 1 kHz
def test_a_log_that_cannot_be_written(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:  # fmt: skip
    """A check that passed but whose bring-up log cannot be written exits 3, naming the
    file; a check that failed keeps its own exit code."""
    _start_at_origin(monkeypatch, "forcedimension")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    log = blocker / "bring-up.mcap"  # under a file: not a directory
    args = ["check", *QUICK, "--device", "forcedimension", "--log", str(log)]
    assert main(args, ask=_user) == 3
    captured = capsys.readouterr()
    assert f"haptic-device: cannot write the log {log}: " in captured.err
    assert captured.out.rstrip().endswith("check passed, but its log was not written (exit 3)")
    _forget_fakes()
    monkeypatch.setenv("FAKE_VENDOR_FROZEN", "1")
    assert main(args, ask=_user) == doctor.EXIT_FROZEN
    captured = capsys.readouterr()
    assert f"haptic-device: cannot write the log {log}: " in captured.err
    assert captured.out.rstrip().endswith("check FAILED (exit 13)")


def _replay(capsys: pytest.CaptureFixture[str], log: Path) -> tuple[int, str]:
    """`haptic-replay LOG` in this process: its exit code and what it printed."""
    from haptic_local_model.haptic_server.harness import replay

    capsys.readouterr()
    code = replay.main([str(log)])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


@pytest.mark.slow  # real time: the device is read at 1 kHz
@pytest.mark.parametrize("name", ADAPTERS)
def test_a_healthy_log_replays_identical_without_the_binding(
    name: str, fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:  # fmt: skip
    """`haptic-replay` of a healthy device's bring-up log (--force: the spring and the
    force fit too) rebuilds the adapter over the logged readings, with no vendor binding
    importable, and reproduces every sample and finding."""
    _start_at_origin(monkeypatch, name)
    log = tmp_path / "bring-up.mcap"
    code, out = _check(capsys, "--device", name, "--force", "--log", str(log))
    assert code == 0, out
    assert f"replay it: haptic-replay {log}" in out
    sys.path.remove(str(FAKES))  # the replay opens no device: no binding needed
    _forget_fakes()
    assert importlib.util.find_spec(BINDINGS[name]) is None
    code, out = _replay(capsys, log)
    assert code == 0, out
    assert f"replayed the check of {name} ({name}) in {log} against its " in out
    assert "  force: ok: the handle moved as if the force were" in out
    assert "identical: every sample's step, pose, twist, forces and fault bits, every finding " \
        "and the exit code (0) as logged" in out  # fmt: skip


def _tamper(log: Path, out: Path, rows: Any = None, findings: Any = None) -> None:
    """`log` rewritten to `out` with its samples or its findings replaced."""
    from haptic_local_model.haptic_server.harness.device_doctor import (
        LOG_SCHEMA,
        LOG_TOPIC,
        read_bringup_log,
    )
    from haptic_local_model.haptic_server.log import read_metadata, write_rows_log

    metadata = read_metadata(log)
    if findings is not None:
        metadata["device_doctor"]["findings"] = json.dumps(findings)
    rows = read_bringup_log(log).rows if rows is None else rows
    write_rows_log(out, rows, LOG_TOPIC, LOG_SCHEMA, metadata)


@pytest.mark.slow  # real time: the device is read at 1 kHz
def test_a_flipped_axis_log_replays_to_the_same_finding_and_edits_are_found(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:  # fmt: skip
    """A check that found a flipped axis (and wrote the corrected config) replays to the
    same finding without writing anything; the same log with one finding or one sample
    edited is told at that finding's step, or at that sample."""
    from haptic_local_model.device_models.doctor_check import STEPS
    from haptic_local_model.haptic_server.harness.device_doctor import read_bringup_log

    _start_at_origin(monkeypatch, "touch")
    monkeypatch.setenv("FAKE_VENDOR_PLANE", "x,-y")
    log, fixed = tmp_path / "flipped.mcap", tmp_path / "fixed.toml"
    code, out = _check(capsys, "--device", "touch", "--write", str(fixed), "--log", str(log))
    assert code == doctor.EXIT_AXES, out
    fixed.unlink()
    code, out = _replay(capsys, log)
    assert code == 0, out
    assert "  axes: FAILED: the scene's y is flipped" in out and f"Wrote {fixed}" in out
    assert "identical: " in out and "the exit code (14) as logged" in out
    assert not fixed.exists()  # said as the check said it, not written again

    findings = [dict(f) for f in read_bringup_log(log).findings]
    assert [f["step"] for f in findings] == ["rest", "axes", "stop"]
    findings[1]["ok"] = True  # an edited verdict
    edited = tmp_path / "edited-finding.mcap"
    _tamper(log, edited, findings=findings)
    code, out = _replay(capsys, edited)
    assert code == 1, out
    at = read_bringup_log(log).findings[1]["at_sample"]
    assert f"DIFFERENT at sample {at} (step axes): finding 2 (step axes): ok logged True, " \
        "replayed False" in out  # fmt: skip

    rows = read_bringup_log(log).rows.copy()
    in_y = np.flatnonzero(rows["step"] == STEPS.index("y"))
    k = int(in_y[len(in_y) // 2])
    rows["device_position"][k][0] += 1e-3  # one reading moved by 1 mm
    edited = tmp_path / "edited-sample.mcap"
    _tamper(log, edited, rows=rows)
    code, out = _replay(capsys, edited)
    assert code == 1, out
    assert f"DIFFERENT at sample {k} (step y): sample {k} (step y, t " in out
    assert ": pose logged [" in out and "(the replay computes it from the logged device" in out


def test_a_log_of_a_check_that_found_no_device(
    fakes: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:  # fmt: skip
    """A check that stopped before opening the device read nothing: its log replays to
    "nothing to replay" and its finding, exit 0."""
    monkeypatch.setenv("FAKE_VENDOR_DEVICES", "0")
    log = tmp_path / "none.mcap"
    code, _ = _check(capsys, "--device", "forcedimension", "--log", str(log))
    assert code == doctor.EXIT_NO_DEVICE
    code, out = _replay(capsys, log)
    assert code == 0, out
    assert "stopped before opening the device: nothing was read, nothing to replay" in out
    assert "  find: FAILED: no device detected" in out
    from haptic_local_model.haptic_server.harness import replay

    assert replay.main([str(log), "--summary"]) == 2  # a run's options are not a check's
    err = capsys.readouterr().err
    assert f"config error: {log}: key '--summary': not for a bring-up log (it replays" in err


def test_a_log_that_is_not_a_bring_up_log_is_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The bring-up replay refuses another MCAP file and a file that is not MCAP, naming
    it; `haptic-replay` names the file it cannot replay either."""
    from mcap.writer import Writer

    from haptic_local_model.haptic_server.harness.device_doctor import (
        is_bringup_log,
        read_bringup_log,
    )
    from haptic_local_model.shared.config import ConfigError

    other = tmp_path / "other.mcap"
    with other.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        schema = writer.register_schema(name="x", encoding="jsonschema", data=b"{}")
        channel = writer.register_channel("/other", message_encoding="json", schema_id=schema)
        writer.add_message(channel, log_time=0, data=b"{}", publish_time=0)
        writer.finish()
    text = tmp_path / "notes.mcap"
    text.write_text("not a log\n")
    assert not is_bringup_log(other) and not is_bringup_log(text)
    with pytest.raises(ConfigError, match="not a bring-up log: it has no device_doctor") as err:
        read_bringup_log(other)
    assert str(other) in str(err.value)
    with pytest.raises(ConfigError, match="not an MCAP file, so not a bring-up log") as err:
        read_bringup_log(text)
    assert str(text) in str(err.value)
    code, out = _replay(capsys, other)
    assert code == 2 and f"haptic-replay: {other}: the log holds no ticks" in out
