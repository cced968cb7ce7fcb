"""The device doctor: finds, checks and maps a real device before it renders anything (issue 49).

`list_models` says, for every installed device model, whether it can be opened: for a
hardware one, whether its binding imports (else the `pip install` extra), whether the
vendor's runtime loads (else what to install), and the devices the binding detects without
opening one (or that it cannot tell). `haptic-device` (haptic_server/harness/device_doctor.py)
prints it; docs/devices.md "Bring-up: the device doctor" says what each finding means.

Every finding that stops a bring-up has its own exit code (`EXIT_*`), so a script and a test
tell them apart.
"""

from __future__ import annotations

import grp
import importlib
import os
import stat
from dataclasses import asdict, dataclass, field
from typing import Any

from haptic_local_model.device_models.base import DeviceModel
from haptic_local_model.device_models.hardware.base import Bringup
from haptic_local_model.device_models.registry import installed_models

EXIT_OK = 0
EXIT_BINDING = 10  # the vendor's Python binding is not installed
EXIT_RUNTIME = 11  # the binding imports, the vendor's runtime (its libraries) does not load
EXIT_NO_DEVICE = 12  # no device detected, or opening it failed
EXIT_FROZEN = 13  # the pose does not change, at rest or when moved
EXIT_AXES = 14  # the [planar] map's axes or signs do not match the motion seen
EXIT_FORCE = 15  # the force pushes away from the spring's start (its sign is flipped)
EXIT_DEVICE_FAILED = 16  # a binding call failed during the check
EXIT_SAFE_STOP = 17  # the safe stop failed: the device may still apply force
EXIT_FORCE_SCALE = 18  # the handle responds to a fraction or a multiple of the force sent
EXIT_ACCESS = 19  # the device's files are there, but this account may not open any of them


@dataclass
class ModelReport:
    """One installed device model as `haptic-device list` reports it."""

    name: str
    description: str
    simulated: bool
    binding: str = ""  # the vendor's Python module ("" for a simulated model)
    binding_ok: bool = True
    runtime_ok: bool = True
    devices: list[str] | None = None  # detected without opening; None: cannot tell
    problem: str = ""  # what is wrong, "" if nothing
    fix: str = ""  # what to do about it
    access: str = ""  # the permissions a user account needs (hardware)
    #: the device files found (serial ports, USB nodes); None: the model has none to look for
    nodes: list[str] | None = None
    blocked: list[str] = field(default_factory=list)  # of those, what this account may not open
    exit_code: int = EXIT_OK  # what `check` of this model would stop with before opening

    def as_json(self) -> dict[str, Any]:
        return asdict(self)


def bringup_of(model: DeviceModel) -> Bringup | None:
    """The vendor module's `BRINGUP` (device_models/hardware/base.Bringup), if it has one."""
    module = importlib.import_module(model.config_cls.__module__)
    found = getattr(module, "BRINGUP", None)
    return found if isinstance(found, Bringup) else None


def _import_error(module: str) -> tuple[bool, str]:
    """(whether it is the module itself that is missing, the error) on importing it; the
    error is "" when it imports."""
    try:
        importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = exc.name is not None and module.startswith(exc.name)
        return missing, f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # OSError from ctypes, the binding's own ImportError, ...
        return False, f"{type(exc).__name__}: {exc}"
    return False, ""


def may_open(path: str) -> bool:
    """Whether this account may read and write the device file (root may)."""
    return os.access(path, os.R_OK | os.W_OK)


def _blocked(path: str) -> str:
    """ "" if this account may open the device file, else the file, its mode, its group and
    whether this account is in it."""
    if may_open(path):
        return ""
    try:
        st = os.stat(path)
    except OSError as exc:
        return f"{path} ({exc.strerror})"
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    member = st.st_gid == os.getegid() or st.st_gid in os.getgroups()
    where = "" if member else ", which this account is not in"
    return f"{path} ({stat.filemode(st.st_mode)}, group {group}{where})"


def probe(name: str, model: DeviceModel) -> ModelReport:
    """What can be found out about a model without opening a device."""
    report = ModelReport(name, model.description, model.simulated)
    binding = getattr(model.config_cls, "binding", "")
    if model.simulated or not binding:
        return report
    report.binding = binding
    bringup = bringup_of(model)
    report.access = bringup.access_fix if bringup else ""
    if bringup is not None and bringup.nodes is not None:  # shown whatever else is missing
        report.nodes = bringup.nodes()
        report.blocked = [why for why in map(_blocked, report.nodes) if why]
    missing, error = _import_error(binding)
    if missing:
        extra = getattr(model.config_cls, "extra", "") or name
        report.binding_ok, report.exit_code = False, EXIT_BINDING
        report.problem = f"the binding {binding!r} is not installed"
        report.fix = f"pip install 'haptic-local-model[{extra}]'"
        return report
    for module in bringup.runtime_modules if bringup and not error else ():
        error = _import_error(module)[1]  # the binding's own import may have failed already
        if error:
            break
    if error:
        report.runtime_ok, report.exit_code = False, EXIT_RUNTIME
        report.problem = f"the vendor runtime does not load ({error})"
        report.fix = bringup.runtime_fix if bringup else "install the vendor's runtime"
        return report
    if report.nodes and len(report.blocked) == len(report.nodes):
        report.exit_code = EXIT_ACCESS
        report.problem = f"this account may not open {'; '.join(report.blocked)}"
        report.fix = report.access
        return report
    if bringup is None or bringup.detect is None:
        return report
    try:
        report.devices = bringup.detect()
    except Exception as exc:
        report.problem = f"detecting devices failed: {type(exc).__name__}: {exc}"
        report.fix = bringup.access_fix
        report.exit_code = EXIT_NO_DEVICE
        return report
    if not report.devices:
        report.exit_code = EXIT_NO_DEVICE
        report.problem = "no device detected"
        report.fix = f"plug it in and switch it on; {bringup.access_fix}"
    return report


def list_models() -> list[ModelReport]:
    """Every installed device model (a broken plug-in too), probed."""
    reports = []
    for entry in installed_models():
        if entry.model is None:
            reports.append(
                ModelReport(entry.name, "", False, problem=entry.problem, exit_code=EXIT_BINDING)
            )
        else:
            reports.append(probe(entry.name, entry.model))
    return reports


def format_list(reports: list[ModelReport]) -> str:
    """`haptic-device list`'s plain text: a line per model, indented findings under it."""
    out: list[str] = []
    width = max((len(r.name) for r in reports), default=0)
    for r in reports:
        kind = "simulated: " if r.simulated else ""  # a hardware one's description says so
        out.append(f"{r.name:<{width}}  {kind}{r.description or r.problem}")
        if r.simulated or not r.binding:
            continue
        out.append(f"  binding {r.binding}: {'imports' if r.binding_ok else 'NOT INSTALLED'}")
        if r.binding_ok:
            out.append(f"  vendor runtime: {'found' if r.runtime_ok else 'NOT FOUND'}")
        if r.binding_ok and r.runtime_ok and r.exit_code != EXIT_ACCESS:
            if r.devices is None and not r.problem:
                out.append("  devices: the binding cannot tell without opening one (run check)")
            else:
                out.append(f"  devices: {len(r.devices or [])} detected")
                for d in r.devices or []:
                    out.append(f"    {d}")
        if r.nodes is not None and r.exit_code != EXIT_ACCESS:  # else the problem says it
            shown = ", ".join(r.nodes) or "none"
            out.append(f"  device files: {shown}")
            out.extend(f"    may not open {why}" for why in r.blocked)
        if r.problem:
            out.append(f"  problem: {r.problem}")
            out.append(f"  fix: {r.fix}")
        elif r.access:
            out.append(f"  if it is not found: {r.access}")
    return "\n".join(out)
