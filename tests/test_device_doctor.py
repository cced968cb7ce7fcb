"""The device doctor (`haptic-device`, device_models/doctor.py) end to end against the fakes
of the three makers' bindings (tests/fake_vendors): the faults a real bring-up meets, each
with its message and exit code (issue 49)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from haptic_local_model.device_models import doctor
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


@pytest.mark.processes
def test_the_console_script_lists(fakes: Path) -> None:
    """`haptic-device list` as installed: exit 0, the fakes' devices listed."""
    script = Path(sys.executable).parent / "haptic-device"
    out = subprocess.run([str(script), "list"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "Inverse3 on /dev/ttyFAKE0" in out.stdout and "twin_pantograph" in out.stdout
