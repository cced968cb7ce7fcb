"""The device doctor's check of one real device (`haptic-device check`, issue 49).

`run_check` opens the device and goes through its steps, each a finding with a message
that says what was seen and what to do:

- rest: pose and velocity read for `seconds` at 1 kHz, nothing commanded; the read rate,
  the jitter of the period (p50, p99) and the noise (the pose's std);
- x, y: the user moves the handle along the scene's +x, then +y; the device axis it moved
  along, with its sign, is compared with the `[planar]` map (a flipped or swapped axis is
  named, and with `write` a config with the corrected table is written); a pose that never
  changed, at rest nor when moved, is a frozen device;
- spring (only with `force`): a spring toward the start pose, capped at 10 % of the
  device's force limit and faded in over FADE_S; the handle must come back toward the
  start (moving away: the force's sign is flipped);
- stop: always, also after any exception: the adapter's safe stop (zero force, device
  closed).

Every sample is kept (`CheckResult.samples`, SAMPLE_DTYPE) for the bring-up log.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haptic_local_model.device_models.base import SENSOR_DTYPE, SafeStopError
from haptic_local_model.device_models.doctor import (
    EXIT_AXES,
    EXIT_DEVICE_FAILED,
    EXIT_FORCE,
    EXIT_FROZEN,
    EXIT_NO_DEVICE,
    EXIT_OK,
    EXIT_SAFE_STOP,
    probe,
)
from haptic_local_model.device_models.hardware.base import PlanarHardware, parse_axis
from haptic_local_model.device_models.registry import (
    DEVICE_MODELS,
    check_device,
    device_config,
    load_device,
)
from haptic_local_model.shared.config import ConfigError, read_toml, split_device_table

STEPS = ("rest", "x", "y", "away", "spring", "stop")
SAMPLE_DTYPE = np.dtype(
    [
        ("t", np.float64),  # s since the check began
        ("step", np.uint8),  # index in STEPS
        ("pose", np.float64, (3,)),  # the planar pose through the config's [planar] map
        ("twist", np.float64, (3,)),
        ("device_position", np.float64, (3,)),  # the device's own frame (m)
        ("commanded", np.float64, (3,)),  # the planar force asked for (N)
        ("applied", np.float64, (3,)),  # what the adapter sent after its limits
        ("fault", np.int64),
    ]
)
FORCE_FRACTION = 0.1  # the spring's force is capped at this fraction of the device's limit
FADE_S = 0.5  # ... and fades in over this
SPRING_FULL_M = 0.01  # the spring reaches its cap this far from the start
SPRING_DAMPING_RATIO = 0.5  # on the config's apparent mass
MOVE_MIN_M = 0.01  # a move the user was asked for: at least this far
SETTLE_S = 0.15  # read on this long after it
AWAY_MIN_M = 0.005  # the spring needs the handle at least this far from the start
DECIDE_M = 0.003  # the spring's verdict: the distance to the start changed by this much
ONE_AXIS = 0.5  # a move is along one device axis if the others moved less than this part
AXIS_NAMES = "xyz"

#: tells the user what to do next (the step, the text); returns when they are ready
Ask = Callable[[str, str], None]
Say = Callable[[str], None]

PROMPTS = {
    "x": "Press Enter, then move the handle about 2 cm along the scene's +x (to the right) "
    "and hold it there.",
    "y": "Press Enter, then move the handle about 2 cm along the scene's +y (up) and hold "
    "it there.",
    "away": "Press Enter, then move the handle 1-2 cm away from where it started and hold it "
    "lightly.",
    "spring": "Hold the handle lightly and press Enter: a gentle spring toward where it "
    "started fades in.",
}


@dataclass(frozen=True)
class CheckOptions:
    """What `haptic-device check` was asked for."""

    seconds: float = 3.0  # the rest step's reading
    force: bool = False  # the spring step (forces) only when asked
    write: Path | None = None  # where to write a corrected config, if the map is wrong
    move_timeout_s: float = 10.0  # how long a move the user was asked for may take
    spring_s: float = 3.0  # the spring step's longest duration
    period_s: float = 1e-3  # the reading period


@dataclass
class Finding:
    """What one step found: ok or not, a message, the exit code of a failure, figures."""

    step: str
    ok: bool
    message: str
    exit_code: int = EXIT_OK
    figures: dict[str, float | str] = field(default_factory=dict)

    def line(self) -> str:
        return f"{self.step}: {'ok' if self.ok else 'FAILED'}: {self.message}"


@dataclass
class CheckResult:
    """A check's findings in order and its samples (SAMPLE_DTYPE)."""

    device: str
    findings: list[Finding] = field(default_factory=list)
    samples: np.ndarray = field(default_factory=lambda: np.zeros(0, SAMPLE_DTYPE))

    @property
    def exit_code(self) -> int:
        """The first failure's exit code, EXIT_OK if none."""
        return next((f.exit_code for f in self.findings if not f.ok), EXIT_OK)


def _axis_text(index: int, sign: float) -> str:
    return ("-" if sign < 0 else "") + AXIS_NAMES[index]


def _norm(text: str) -> str:
    index, sign = parse_axis(text, "axis")
    return _axis_text(index, sign)


class _Session:
    """One check of an open device: its samples, its findings and its steps."""

    def __init__(
        self, device: PlanarHardware, source: Path, options: CheckOptions, ask: Ask,
        result: CheckResult, say: Say,
    ) -> None:  # fmt: skip
        self.device, self.options, self.ask, self.say = device, options, ask, say
        self.source = source  # the device config the device was built from
        self.result = result
        self.rows: list[tuple] = []
        self.sensors = np.zeros(1, SENSOR_DTYPE)
        self.step = "rest"
        self.t0 = time.perf_counter()
        self._next = self.t0
        self.start_pose = np.zeros(3)
        self.constant_at_rest = False

    def add(self, finding: Finding) -> Finding:
        self.result.findings.append(finding)
        self.say(finding.line())
        return finding

    def sample(self, force: np.ndarray | None = None) -> np.ndarray:
        """One reading (and a command: zero force without the hold spring, or `force`),
        paced at the options' period; the device-frame position."""
        now = time.perf_counter()
        if self._next > now:
            time.sleep(self._next - now)
        self._next = max(self._next + self.options.period_s, time.perf_counter())
        s = self.sensors[0]
        self.device.read(self.sensors)
        zero = (0.0, 0.0, 0.0)
        if force is None:
            self.device.idle()
            applied: tuple[float, ...] = zero
        else:
            applied = tuple(self.device.command(force))
        position = self.device.device_position()
        commanded = zero if force is None else tuple(force)
        self.rows.append((
            time.perf_counter() - self.t0, STEPS.index(self.step), tuple(s["pose"]),
            tuple(s["twist"]), tuple(position), commanded, applied, int(s["fault"]),
        ))  # fmt: skip
        return position

    def samples(self) -> np.ndarray:
        return np.array(self.rows, dtype=SAMPLE_DTYPE)

    def rest(self) -> None:
        """Read for `seconds`: rate, jitter and noise."""
        self.step = "rest"
        first = len(self.rows)
        end = time.perf_counter() + self.options.seconds
        while time.perf_counter() < end:
            self.sample()
        rows = self.samples()[first:]
        self.start_pose = rows["pose"][0].copy()
        periods_ms = np.diff(rows["t"]) * 1e3
        span = rows["t"][-1] - rows["t"][0]
        rate = (len(rows) - 1) / span if span > 0 else 0.0
        p50, p99 = np.percentile(periods_ms, [50, 99]) if len(periods_ms) else (math.nan,) * 2
        noise_um = rows["device_position"].std(axis=0) * 1e6
        self.constant_at_rest = bool(np.all(rows["device_position"] == rows["device_position"][0]))
        message = (
            f"{len(rows)} readings at {rate:.0f} Hz; period p50 {p50:.3f} ms, p99 {p99:.3f} ms; "
            f"noise (std at rest) x {noise_um[0]:.1f} um, y {noise_um[1]:.1f} um, "
            f"z {noise_um[2]:.1f} um"
        )
        if self.constant_at_rest:
            message += " (not one bit of change at rest: the moves tell whether it is frozen)"
        if np.any(rows["fault"]):
            message += (
                "; the device reports a fault or the handle is outside the workspace about "
                "[planar].origin_m: move it to the middle of its workspace"
            )
        figures: dict[str, float | str] = {
            "rate_hz": rate,
            "period_p50_ms": float(p50),
            "period_p99_ms": float(p99),
        }
        figures.update(
            {f"noise_{a}_um": float(v) for a, v in zip(AXIS_NAMES, noise_um, strict=False)}
        )
        self.add(Finding("rest", True, message, figures=figures))

    def move(self, axis: str) -> str | None:
        """The user moves along the scene's +`axis`: the device axis it moved along (with
        its sign), or None after a failure finding."""
        self.step = axis
        start = self.sample()
        self.ask(axis, PROMPTS[axis])
        deadline = time.perf_counter() + self.options.move_timeout_s
        moved_at, position = 0.0, start
        while time.perf_counter() < deadline:
            position = self.sample()
            if not moved_at and np.max(np.abs(position - start)) >= MOVE_MIN_M:
                moved_at = time.perf_counter()
            if moved_at and time.perf_counter() - moved_at >= SETTLE_S:
                break
        d = position - start
        size = np.abs(d)
        i = int(np.argmax(size))
        if self.constant_at_rest and not np.any(d) and self.frozen_so_far():
            self.add(Finding(axis, False, (
                "the pose did not change at all, at rest nor when the handle was to move "
                f"({len(self.rows)} readings), while the device reported no fault: its readings "
                "are frozen. Check the cable and power, that no other program holds the device, "
                "power-cycle it and run check again"), EXIT_FROZEN))  # fmt: skip
            return None
        if size[i] < MOVE_MIN_M:
            self.add(Finding(axis, False, (
                f"no move of {MOVE_MIN_M * 1e3:.0f} mm seen in {self.options.move_timeout_s:g} s "
                f"(largest {size[i] * 1e3:.1f} mm): move the handle further along the scene's "
                f"+{axis} and run check again"), EXIT_AXES))  # fmt: skip
            return None
        if np.sort(size)[-2] > ONE_AXIS * size[i]:
            mm = ", ".join(f"{a} {v * 1e3:+.1f} mm" for a, v in zip(AXIS_NAMES, d, strict=False))
            self.add(Finding(axis, False, (
                f"the move was not along one device axis ({mm}): move straight along the "
                f"scene's +{axis} and run check again"), EXIT_AXES))  # fmt: skip
            return None
        found = _axis_text(i, float(np.sign(d[i])))
        self.say(
            f"{axis}: the scene's +{axis} moved the device along {found} ({d[i] * 1e3:+.1f} mm)"
        )
        return found

    def frozen_so_far(self) -> bool:
        """Not one bit of change in any reading so far, and no fault reported."""
        positions = np.array([r[4] for r in self.rows])
        return bool(np.all(positions == positions[0]) and not any(r[7] for r in self.rows))

    def axes(self) -> bool:
        """Both moves against the `[planar]` map; True if it matches."""
        found_x = self.move("x")
        if found_x is None:
            return False
        found_y = self.move("y")
        if found_y is None:
            return False
        planar = self.device.config.planar
        want = (_norm(planar.x), _norm(planar.y))
        found = (found_x, found_y)
        if found[0].lstrip("-") == found[1].lstrip("-"):
            self.add(Finding("axes", False, (
                f"+x and +y both moved the device along its {found[0].lstrip('-')} axis: move "
                "along the scene's x and y as asked and run check again"), EXIT_AXES))  # fmt: skip
            return False
        if found == want:
            self.add(Finding("axes", True, f"[planar] x = {want[0]!r}, y = {want[1]!r} match"))
            return True
        self.add(Finding("axes", False, _mismatch(want, found) + self.write_fix(found),
                         EXIT_AXES, figures={"x": found[0], "y": found[1]}))  # fmt: skip
        return False

    def write_fix(self, found: tuple[str, str]) -> str:
        """Write the corrected config if asked; what to do next."""
        path = self.options.write
        if path is None:
            return (f". Set [planar] x = {found[0]!r}, y = {found[1]!r} (or run check with "
                    "--write FILE to have a corrected config written)")  # fmt: skip
        text = corrected_config(self.source.read_text(), found)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return (f". Wrote {path} with [planar] x = {found[0]!r}, y = {found[1]!r}: "
                f"haptic-device check --device {path}")  # fmt: skip

    def spring(self) -> None:
        """A spring toward the start pose, capped and faded in: does the handle come back?"""
        limit = float(self.device.limits().max_wrench[0])
        cap = FORCE_FRACTION * limit
        k = cap / SPRING_FULL_M
        b = 2.0 * SPRING_DAMPING_RATIO * math.sqrt(k * self.device.config.planar.apparent_mass_kg)
        if self._distance() < AWAY_MIN_M:
            self.step = "away"
            self.ask("away", PROMPTS["away"])
            end = time.perf_counter() + self.options.move_timeout_s
            while time.perf_counter() < end and self._distance() < AWAY_MIN_M:
                self.sample()
        self.step = "spring"
        self.ask("spring", PROMPTS["spring"])
        d0 = self._distance()
        d, begin, force = d0, time.perf_counter(), np.zeros(3)
        while (t := time.perf_counter() - begin) < self.options.spring_s:
            s = self.sensors[0]
            f = -k * (s["pose"][:2] - self.start_pose[:2]) - b * s["twist"][:2]
            size = float(np.hypot(f[0], f[1]))
            scale = min(1.0, t / FADE_S) * (min(1.0, cap / size) if size > 0 else 0.0)
            force[:2] = f * scale if math.isfinite(size) else 0.0
            self.sample(force)
            d = self._distance()
            if abs(d - d0) >= DECIDE_M:
                break
        self.sample()  # zero force again
        figures: dict[str, float | str] = {"cap_n": cap, "start_mm": d0 * 1e3, "end_mm": d * 1e3}
        what = (
            f"the distance to the start went {d0 * 1e3:.1f} -> {d * 1e3:.1f} mm (cap {cap:.2f} N)"
        )
        if d0 < AWAY_MIN_M:
            self.add(Finding("spring", True, f"not tried: the handle stayed at the start ({what})",
                             figures=figures))  # fmt: skip
        elif d >= d0 + DECIDE_M:
            self.add(Finding("spring", False, (
                f"the spring pushes away from the start: {what}. The force's sign is flipped "
                "relative to the position: the adapter sends force along the opposite axis "
                "direction; do not run with this device until it is fixed (report it)"),
                EXIT_FORCE, figures))  # fmt: skip
        elif d <= d0 - DECIDE_M:
            self.add(Finding("spring", True, f"the spring restores toward the start: {what}",
                             figures=figures))  # fmt: skip
        else:
            self.add(Finding("spring", True, (
                f"inconclusive: {what}; hold the handle more lightly and run check --force "
                "again"), figures=figures))  # fmt: skip

    def _distance(self) -> float:
        pose = self.sensors[0]["pose"]
        return float(np.hypot(pose[0] - self.start_pose[0], pose[1] - self.start_pose[1]))


def _mismatch(want: tuple[str, str], found: tuple[str, str]) -> str:
    """The [planar] map's fault in words: a flipped axis, swapped axes, or a wrong axis."""
    parts = []
    if found[0].lstrip("-") == want[1].lstrip("-") and found[1].lstrip("-") == want[0].lstrip("-"):
        parts.append("x and y are swapped")
    for axis, w, f in zip("xy", want, found, strict=False):
        if w != f and w.lstrip("-") == f.lstrip("-"):
            parts.append(f"the scene's {axis} is flipped")
    text = "; ".join(parts) or "the plane is mapped onto the wrong device axes"
    return (f"{text}: [planar] says x = {want[0]!r}, y = {want[1]!r}, the moves went along "
            f"x = {found[0]!r}, y = {found[1]!r}")  # fmt: skip


def corrected_config(text: str, found: tuple[str, str]) -> str:
    """A device config's text with its [planar] table's x and y set to `found` (the rest,
    comments included, as it was)."""
    out, table, done = [], "", set()
    for line in text.splitlines(keepends=True):
        header = re.match(r"\s*\[([^\]]+)\]", line)
        if header:
            table = header.group(1).strip()
        key = re.match(r"\s*([xy])\s*=", line)
        if table == "planar" and key:
            name = key.group(1)
            line = f'{name} = "{found[0] if name == "x" else found[1]}"\n'
            done.add(name)
        out.append(line)
    if done != {"x", "y"}:  # the shipped configs state both; a config relying on defaults
        text = "".join(out)
        missing = "".join(f'{n} = "{found["xy".index(n)]}"\n' for n in "xy" if n not in done)
        if "[planar]" in text:
            return text.replace("[planar]\n", "[planar]\n" + missing, 1)
        return text + "\n[planar]\n" + missing
    return "".join(out)


def _before_opening(name: str, source: Path, result: CheckResult, say: Say) -> bool:
    """What `list` finds for the device's model (binding, runtime, devices detected): True
    if the device may be opened, else a failure finding."""
    model, _, _ = split_device_table(read_toml(source), str(source))
    entry = DEVICE_MODELS.get(model)
    if entry is None or entry.simulated:
        check_device(name)  # an unknown or broken model: its config error
        raise ConfigError(str(source), "model", f"{model!r} is simulated: the doctor checks "
                          "a real device (haply_inverse3, forcedimension, touch, ...)")  # fmt: skip
    report = probe(model, entry)
    if report.exit_code != EXIT_OK:
        finding = Finding("find", False, f"{report.problem}; fix: {report.fix}", report.exit_code)
        result.findings.append(finding)
        say(finding.line())
        return False
    check_device(name)  # the config's keys
    return True


def _open(source: Path, result: CheckResult, say: Say) -> PlanarHardware | None:
    """The device, opened; None after a failure finding."""
    try:
        device = load_device(str(source))
    except ConfigError:
        raise
    except Exception as exc:  # DeviceError from the adapter, or the binding's own
        model = split_device_table(read_toml(source), str(source))[0]
        access = getattr(probe(model, DEVICE_MODELS[model]), "access", "")
        finding = Finding("open", False, (
            f"opening the device failed: {exc}. Is it plugged in and switched on, and not "
            f"held by another program? {access}"), EXIT_NO_DEVICE)  # fmt: skip
        result.findings.append(finding)
        say(finding.line())
        return None
    if not isinstance(device, PlanarHardware):  # a plug-in's own hardware class
        device.safe_stop()
        raise ConfigError(str(source), "model", "the doctor checks the planar hardware adapters")
    return device


def run_check(name: str, options: CheckOptions, ask: Ask, say: Say) -> CheckResult:
    """Check the device a `--device` value names (registry.device_config): find it, open it,
    its steps (module docstring), and always its safe stop. A ConfigError is the config's."""
    source = device_config(name)
    result = CheckResult(str(name))
    if not _before_opening(name, source, result, say):
        return result
    device = _open(source, result, say)
    if device is None:
        return result
    session = _Session(device, source, options, ask, result, say)
    try:
        session.rest()
        if session.axes():
            if options.force:
                session.spring()
            else:
                say("spring: not tried (forces only with --force)")
        elif options.force:
            say("spring: not tried: fix the [planar] map first (the spring would push wrong)")
    except Exception as exc:
        session.add(Finding(session.step, False, (
            f"the device failed during the {session.step} step: {type(exc).__name__}: {exc}. "
            "It was sent to its safe stop; check the cable and power, then run check again"),
            EXIT_DEVICE_FAILED))  # fmt: skip
    finally:
        session.step = "stop"
        try:
            device.safe_stop()
            session.add(Finding("stop", True, "safe stop: zero force, the device closed"))
        except SafeStopError as exc:
            session.add(Finding("stop", False, (
                f"{exc}: the device may still push; switch it off"), EXIT_SAFE_STOP))  # fmt: skip
        result.samples = session.samples()
    return result
