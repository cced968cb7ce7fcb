"""The device doctor's check replayed against its bring-up log (issue 49).

`haptic-device check --log` keeps every reading the check took (the device's own position,
velocity and fault bits, and the time) and what it found. `replay_check` rebuilds the device
from the log: the adapter's planar map, limits and hold spring from the logged device config,
over a `ScriptLink` that plays the logged readings back in their order in place of the
vendor's binding (which need not be installed). The same steps then run against it
(doctor_check.run_steps, with the logged options, the user's prompts answered at once, the
logged time as the clock, nothing written), and `first_difference` compares what they
computed with the log: every sample's step, planar pose and twist, commanded and applied
force and fault bits, then every finding (step, verdict, exit code, message, figures) and
the exit code. The readings are the check's only inputs, so a log replays identically; a
log edited after the check (a sample's reading or a finding) is told at the first sample or
finding that no longer follows. A binding's failure or a failed safe stop is replayed from
the error the log kept.

haptic_server/harness/device_doctor.py reads the log (MCAP) and prints the comparison;
`haptic-replay LOG` dispatches a bring-up log there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import DeviceError
from haptic_local_model.device_models.doctor_check import (
    STEPS,
    CheckOptions,
    CheckResult,
    CheckSession,
    Finding,
    run_steps,
)
from haptic_local_model.device_models.hardware.base import HardwareConfig, PlanarHardware
from haptic_local_model.device_models.registry import DEVICE_MODELS
from haptic_local_model.shared.config import (
    ConfigError,
    load_dataclass,
    parse_toml_text,
    split_device_table,
)

#: the sample fields the replay plays back (its script); every other one it recomputes
SCRIPT_FIELDS = ("t", "device_position", "device_velocity", "vendor_fault")
#: the recomputed fields, compared in this order within a sample
COMPUTED_FIELDS = ("step", "pose", "twist", "commanded", "applied", "fault")
FINDING_KEYS = ("step", "ok", "exit_code", "message", "figures")


@dataclass
class BringupLog:
    """What a bring-up log holds (harness/device_doctor.read_bringup_log reads it)."""

    source: str  # the log's path, for messages
    rows: np.ndarray  # SAMPLE_DTYPE, in order
    device: str  # the --device value the check was given
    adapter: str  # the adapter's name (PlanarHardware.name); "" if it was never opened
    config_text: str  # the device config's text
    options: CheckOptions
    findings: list[dict[str, Any]]  # as logged: step, ok, exit_code, message, figures, at_sample
    exit_code: int


class LoggedDeviceError(DeviceError):
    """A binding's failure as the log kept it (its type's name set to the logged one)."""


class ScriptEndError(DeviceError):
    """The replay asked for a reading beyond the last one logged."""


class ScriptLink:
    """A VendorLink (hardware/base.py) that plays a bring-up log's readings back in order;
    past the last one it raises the failure the log kept (or ScriptEndError); its stop fails as
    the logged safe stop did."""

    def __init__(
        self, rows: np.ndarray, failure: tuple[str, str] | None, stop_error: str | None
    ) -> None:
        self.rows = rows
        self.failure = failure  # (the error's type name, its text) of a mid-check failure
        self.stop_error = stop_error
        self.index = -1  # the reading just taken
        self.ran_out = False

    def open(self) -> None:
        pass

    def sample(self, position: np.ndarray, velocity: np.ndarray) -> int:
        self.index += 1
        if self.index >= len(self.rows):
            if self.failure is not None:
                name, text = self.failure
                raise type(name, (LoggedDeviceError,), {})(text)
            self.ran_out = True
            raise ScriptEndError(f"the log has no reading {self.index} (it holds {len(self.rows)})")
        row = self.rows[self.index]
        position[:] = row["device_position"]
        velocity[:] = row["device_velocity"]
        return int(row["vendor_fault"])

    def send(self, force: np.ndarray) -> None:
        pass

    def stop(self) -> None:
        if self.stop_error is not None:
            raise RuntimeError(self.stop_error)

    def time(self) -> float:
        """The logged time of the reading just taken (the replay's clock)."""
        return float(self.rows[self.index]["t"]) if 0 <= self.index < len(self.rows) else 0.0


@dataclass
class Replayed:
    """A replay's result: what the steps computed, and whether they ran out of readings."""

    result: CheckResult
    lines: list[str] = field(default_factory=list)  # what the check said, as it said it
    ran_out: bool = False


@dataclass(frozen=True)
class Difference:
    """The first place a replay departs from its log."""

    at_sample: int  # the samples taken before it
    step: str
    text: str


def hardware_config(text: str, source: str) -> HardwareConfig:
    """The logged device config, read without the vendor's binding (the replay does not open
    a device): its model must be an installed hardware model."""
    model, table, where = split_device_table(parse_toml_text(text, source), source)
    entry = DEVICE_MODELS.get(model)
    if entry is None or not issubclass(entry.config_cls, HardwareConfig):
        installed = sorted(n for n, m in DEVICE_MODELS.items() if not m.simulated)
        raise ConfigError(where, "model", f"{model!r} is not an installed hardware model "
                          f"(installed: {installed})")  # fmt: skip
    try:
        config: HardwareConfig = load_dataclass(entry.config_cls, table, where)
    except ValueError as exc:
        key, _, problem = str(exc).partition(": ")
        raise ConfigError(where, key, problem or str(exc)) from None
    return config


def _logged_error(findings: list[dict[str, Any]], step: str | None) -> dict[str, Any] | None:
    """The figures of the logged failure that kept an error: the safe stop's (`step`
    "stop"), or a mid-check one (any other step)."""
    for f in findings:
        figures = f.get("figures") or {}
        if f.get("ok") or "error" not in figures:
            continue
        if (f.get("step") == "stop") == (step == "stop"):
            return dict(figures)
    return None


def replay_check(log: BringupLog) -> Replayed:
    """The check's steps run again against the logged readings (module docstring)."""
    config = hardware_config(log.config_text, f"{log.source} (its device config)")
    failure = _logged_error(log.findings, None)
    stop = _logged_error(log.findings, "stop")
    link = ScriptLink(
        log.rows,
        (str(failure["error_type"]), str(failure["error"])) if failure else None,
        str(stop["error"]) if stop else None,
    )
    device = PlanarHardware(config, link)
    device.name = log.adapter or device.name
    replayed = Replayed(CheckResult(log.device, config_text=log.config_text, adapter=device.name))
    session = CheckSession(
        device, log.config_text, log.options, lambda step, text: None, replayed.result,
        replayed.lines.append, clock=link.time, write=False,
    )  # fmt: skip
    run_steps(session)
    replayed.ran_out = link.ran_out
    return replayed


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN (JSON keeps NaN; figures may hold it)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(a == b)


def _differs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per sample: whether any element differs in any bit of its value (NaN == NaN)."""
    same = (a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind == "f" else a == b
    return ~same.reshape(len(a), -1).all(axis=1)


def _value(v: Any) -> str:
    if isinstance(v, np.ndarray):
        return "[" + ", ".join(f"{x:.9g}" for x in v) + "]"
    return f"{v}"


def _step_name(index: int) -> str:
    return STEPS[index] if 0 <= index < len(STEPS) else f"#{index}"


#: a candidate difference: (where it falls among the samples, its order there, it)
Found = tuple[float, int, Difference]


def first_difference(log: BringupLog, replayed: Replayed) -> Difference | None:
    """Where the replay first departs from the log: a sample, the number of samples, a
    finding or the exit code (None: identical). A finding made after n samples falls
    between sample n - 1 and sample n."""
    found = [*_sample_differences(log, replayed), *_finding_difference(log, replayed)]
    if not found and log.exit_code != replayed.result.exit_code:
        what = f"exit code logged {log.exit_code}, replayed {replayed.result.exit_code}"
        found.append((math.inf, 0, Difference(len(replayed.result.samples), "stop", what)))
    return min(found, key=lambda f: (f[0], f[1]))[2] if found else None


def _sample_differences(log: BringupLog, replayed: Replayed) -> list[Found]:
    """The first sample at which each computed field differs; a replay that ran out of
    readings or took another number of them."""
    logged, again = log.rows, replayed.result.samples
    found: list[Found] = []
    n = min(len(logged), len(again))
    for order, name in enumerate(COMPUTED_FIELDS):
        bad = np.flatnonzero(_differs(logged[name][:n], again[name][:n]))
        if bad.size:
            k = int(bad[0])
            step = _step_name(int(logged["step"][k]))
            what = (
                f"sample {k} (step {step}, t {logged['t'][k]:.6f} s): {name} logged "
                f"{_value(logged[name][k])}, replayed {_value(again[name][k])}"
            )
            if name in ("pose", "twist", "fault"):
                what += " (the replay computes it from the logged device readings)"
            elif name in ("commanded", "applied"):
                what += " (the check computes it from the readings before it)"
            found.append((k, order, Difference(k, step, what)))
    if replayed.ran_out:  # found when the replay asked for one reading more than logged
        step = next((f.step for f in replayed.result.findings if not f.ok), "?")
        what = (
            f"the replayed check asked for more readings than the {len(logged)} logged (in its "
            f"{step} step): the log was cut or its readings altered"
        )
        found.append((len(logged) - 0.75, 0, Difference(len(logged), step, what)))
    elif len(logged) != len(again):
        longer = logged if n < len(logged) else again
        step = _step_name(int(longer["step"][n]))
        what = f"the replayed check took {len(again)} readings, the log holds {len(logged)}"
        found.append((n - 0.25, 0, Difference(n, step, what)))
    return found


def _finding_difference(log: BringupLog, replayed: Replayed) -> list[Found]:
    """The first finding that differs from the logged one (its first differing key), or
    that only one of them has."""
    mine = [_finding_dict(f) for f in replayed.result.findings]
    for i in range(max(len(log.findings), len(mine))):
        a = log.findings[i] if i < len(log.findings) else None
        b = mine[i] if i < len(mine) else None
        if a is None or b is None:
            only = a if a is not None else b
            assert only is not None
            where = "only in the log" if b is None else "only in the replay"
            what = (
                f"finding {i + 1} (step {only.get('step')}) is {where}: "
                f"{'ok' if only.get('ok') else 'FAILED'}: {only.get('message')}"
            )
            at = int(only.get("at_sample", 0))
            return [(at - 0.5, 0, Difference(at, str(only.get("step")), what))]
        key = next((k for k in FINDING_KEYS if not _same(a.get(k), b[k])), None)
        if key is None:
            continue
        logged_value, replayed_value = a.get(key), b[key]
        if key == "figures" and isinstance(logged_value, dict):
            names = sorted(set(logged_value) | set(replayed_value))
            names = [k for k in names if not _same(logged_value.get(k), replayed_value.get(k))]
            key = f"figures {', '.join(names)}"
            logged_value = {k: logged_value.get(k) for k in names}
            replayed_value = {k: replayed_value.get(k) for k in names}
        what = (
            f"finding {i + 1} (step {a.get('step')}): {key} logged {logged_value!r}, "
            f"replayed {replayed_value!r}"
        )
        at = int(a.get("at_sample", b["at_sample"]))
        return [(at - 0.5, 0, Difference(at, str(a.get("step")), what))]
    return []


def _finding_dict(f: Finding) -> dict[str, Any]:
    return {
        "step": f.step, "ok": f.ok, "exit_code": f.exit_code, "message": f.message,
        "figures": f.figures, "at_sample": f.at_sample,
    }  # fmt: skip


__all__ = [
    "SCRIPT_FIELDS",
    "BringupLog",
    "Difference",
    "Replayed",
    "ScriptLink",
    "first_difference",
    "hardware_config",
    "replay_check",
]
