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
  device's force limit and faded in over FADE_S, the handle let go of; it must come back
  toward the start (moving away: the force's sign is flipped, and the force is taken off at
  once);
- force (only after a spring that restored): the force's magnitude against the one sent,
  from the handle's response (`force_gain`): the devices have no force sensor, so the
  handle's motion under the spring is fitted with the config's apparent mass; a device
  rendering a fraction or a multiple of the force asked is named;
- stop: always, also after any exception: the adapter's safe stop (zero force, device
  closed).

Every sample is kept (`CheckResult.samples`, SAMPLE_DTYPE) for the bring-up log, with the
device's own readings (position, velocity, fault bits) and the time: every decision the
steps take reads the samples' time, never the clock directly, so the same readings replay
to the same findings (device_models/doctor_replay.py, `haptic-replay LOG`).
"""

from __future__ import annotations

import itertools
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import SENSOR_DTYPE, SafeStopError
from haptic_local_model.device_models.doctor import (
    EXIT_AXES,
    EXIT_DEVICE_FAILED,
    EXIT_FORCE,
    EXIT_FORCE_SCALE,
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
        ("device_velocity", np.float64, (3,)),  # ... (m/s)
        ("commanded", np.float64, (3,)),  # the planar force asked for (N)
        ("applied", np.float64, (3,)),  # what the adapter sent after its limits
        ("fault", np.int64),  # the reading's fault bits (base.FAULT_*)
        ("vendor_fault", np.int64),  # the binding's own fault bits in the reading
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
MEASURE_S = 1.5  # a spring that restores stays on this long from its start (the force fit)
#: the force's magnitude passes if the handle responds as to this range of the force sent
GAIN_RANGE = (0.5, 2.0)
FIT_MIN_SPEED = 0.005  # m/s: a handle slower than this under the spring tells no magnitude
FIT_MIN_R2 = 0.9  # ... nor a fit that explains less of its motion
FIT_MIN_READINGS = 20  # ... nor fewer readings
FIT_GAP_PERIODS = 3  # a gap of more periods between readings splits the fit (force_gain)
FIT_MAX_LAG = 3  # readings: how far behind the force the fit looks for the readings
ONE_AXIS = 0.5  # a move is along one device axis if the others moved less than this part
AXIS_NAMES = "xyz"

#: tells the user what to do next (the step, the text); returns when they are ready
Ask = Callable[[str, str], None]
Say = Callable[[str], None]
#: the time of the reading just taken (s since the check began)
Clock = Callable[[], float]

PROMPTS = {
    "x": "Press Enter, then move the handle about 2 cm along the scene's +x (to the right) "
    "and hold it there.",
    "y": "Press Enter, then move the handle about 2 cm along the scene's +y (up) and hold "
    "it there.",
    "away": "Press Enter, then move the handle 1-2 cm away from where it started and hold it "
    "lightly.",
    "spring": "Press Enter, then let go of the handle (keep your hand near it; if it sinks "
    "under its own weight, rest a fingertip on it): a gentle spring toward where it started "
    "fades in and should bring it back there.",
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


def options_json(options: CheckOptions) -> dict[str, float | bool | str]:
    """The options as the bring-up log keeps them (`write`: the path, "" for none)."""
    return {
        "seconds": options.seconds, "force": options.force,
        "write": "" if options.write is None else str(options.write),
        "move_timeout_s": options.move_timeout_s, "spring_s": options.spring_s,
        "period_s": options.period_s,
    }  # fmt: skip


def options_from_json(data: dict[str, Any]) -> CheckOptions:
    """The options a bring-up log kept (options_json); a ValueError, KeyError or TypeError
    if they are not whole."""
    return CheckOptions(
        seconds=float(data["seconds"]), force=bool(data["force"]),
        write=Path(data["write"]) if data["write"] else None,
        move_timeout_s=float(data["move_timeout_s"]), spring_s=float(data["spring_s"]),
        period_s=float(data["period_s"]),
    )  # fmt: skip


@dataclass
class Finding:
    """What one step found: ok or not, a message, the exit code of a failure, figures."""

    step: str
    ok: bool
    message: str
    exit_code: int = EXIT_OK
    figures: dict[str, float | str] = field(default_factory=dict)
    at_sample: int = 0  # how many samples had been taken when it was found

    def line(self) -> str:
        return f"{self.step}: {'ok' if self.ok else 'FAILED'}: {self.message}"


@dataclass
class CheckResult:
    """A check's findings in order and its samples (SAMPLE_DTYPE)."""

    device: str
    findings: list[Finding] = field(default_factory=list)
    samples: np.ndarray = field(default_factory=lambda: np.zeros(0, SAMPLE_DTYPE))
    config_text: str = ""  # the device config's text
    adapter: str = ""  # the adapter's name (PlanarHardware.name), once opened

    @property
    def exit_code(self) -> int:
        """The first failure's exit code, EXIT_OK if none."""
        return next((f.exit_code for f in self.findings if not f.ok), EXIT_OK)


def _axis_text(index: int, sign: float) -> str:
    return ("-" if sign < 0 else "") + AXIS_NAMES[index]


def _norm(text: str) -> str:
    index, sign = parse_axis(text, "axis")
    return _axis_text(index, sign)


class CheckSession:
    """One check of an open device: its samples, its findings and its steps.

    `clock` gives the time of the reading just taken (s since the check began): the
    perf_counter on a device, the logged time in a replay (no pacing then); `write`: whether
    a corrected config is written (not in a replay, which says what the check wrote)."""

    def __init__(
        self, device: PlanarHardware, config_text: str, options: CheckOptions, ask: Ask,
        result: CheckResult, say: Say, clock: Clock | None = None, write: bool = True,
    ) -> None:  # fmt: skip
        self.device, self.options, self.ask, self.say = device, options, ask, say
        self.config_text = config_text  # the device config the device was built from
        self.result = result
        self.write = write
        self.rows: list[tuple] = []
        self.sensors = np.zeros(1, SENSOR_DTYPE)
        self.step = "rest"
        self.pace = clock is None
        t0 = time.perf_counter()
        self.clock: Clock = clock if clock is not None else lambda: time.perf_counter() - t0
        self._next = t0
        self.now = 0.0  # the time of the newest reading
        # the adapter's hold spring fades in on the readings' time too (a replay is exact)
        device.clock_ns = lambda: round(self.now * 1e9)
        self.start_pose = np.zeros(3)
        self.constant_at_rest = False

    def add(self, finding: Finding) -> Finding:
        finding.at_sample = len(self.rows)
        self.result.findings.append(finding)
        self.say(finding.line())
        return finding

    def sample(self, force: np.ndarray | None = None) -> np.ndarray:
        """One reading (and a command: zero force without the hold spring, or `force`),
        paced at the options' period on a device; the device-frame position."""
        if self.pace:
            now = time.perf_counter()
            if self._next > now:
                time.sleep(self._next - now)
            self._next = max(self._next + self.options.period_s, time.perf_counter())
        s = self.sensors[0]
        self.device.read(self.sensors)
        self.now = self.clock()
        zero = (0.0, 0.0, 0.0)
        if force is None:
            self.device.idle()
            applied: tuple[float, ...] = zero
        else:
            applied = tuple(self.device.command(force))
        position, velocity, vendor_fault = self.device.device_reading()
        commanded = zero if force is None else tuple(force)
        self.rows.append((
            self.now, STEPS.index(self.step), tuple(s["pose"]), tuple(s["twist"]),
            tuple(position), tuple(velocity), commanded, applied, int(s["fault"]), vendor_fault,
        ))  # fmt: skip
        return position

    def samples(self) -> np.ndarray:
        return np.array(self.rows, dtype=SAMPLE_DTYPE)

    def rest(self) -> None:
        """Read for `seconds`: rate, jitter and noise."""
        self.step = "rest"
        first = len(self.rows)
        self.sample()
        end = self.now + self.options.seconds
        while self.now < end:
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
        position = self.sample()
        deadline = self.now + self.options.move_timeout_s
        moved_at: float | None = None
        while True:
            if moved_at is None and np.max(np.abs(position - start)) >= MOVE_MIN_M:
                moved_at = self.now
            if moved_at is not None and self.now - moved_at >= SETTLE_S:
                break
            if self.now >= deadline:
                break
            position = self.sample()
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
        rows = self.samples()
        positions = rows["device_position"]
        return bool(np.all(positions == positions[0]) and not np.any(rows["fault"]))

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
        """Write the corrected config if asked (not in a replay); what to do next."""
        path = self.options.write
        if path is None:
            return (f". Set [planar] x = {found[0]!r}, y = {found[1]!r} (or run check with "
                    "--write FILE to have a corrected config written)")  # fmt: skip
        if self.write:
            text = corrected_config(self.config_text, found)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
        return (f". Wrote {path} with [planar] x = {found[0]!r}, y = {found[1]!r}: "
                f"haptic-device check --device {path}")  # fmt: skip

    def spring(self) -> None:
        """A spring toward the start pose, capped and faded in, the handle let go of: does
        it come back (the force's direction), and as fast as the force sent would move the
        config's apparent mass (its magnitude)?"""
        limit = float(self.device.limits().max_wrench[0])
        cap = FORCE_FRACTION * limit
        k = cap / SPRING_FULL_M
        mass = self.device.config.planar.apparent_mass_kg
        b = 2.0 * SPRING_DAMPING_RATIO * math.sqrt(k * mass)
        if self._distance() < AWAY_MIN_M:
            self.step = "away"
            self.ask("away", PROMPTS["away"])
            self.sample()
            end = self.now + self.options.move_timeout_s
            while self.now < end and self._distance() < AWAY_MIN_M:
                self.sample()
        self.step = "spring"
        self.ask("spring", PROMPTS["spring"])
        self.sample()  # the spring's start (no force yet)
        first, begin = len(self.rows) - 1, self.now
        d0 = self._distance()
        d, force = d0, np.zeros(3)
        verdict = 0  # +1: came back toward the start, -1: went away from it
        while (t := self.now - begin) < self.options.spring_s:
            s = self.sensors[0]
            f = -k * (s["pose"][:2] - self.start_pose[:2]) - b * s["twist"][:2]
            size = float(np.hypot(f[0], f[1]))
            scale = min(1.0, t / FADE_S) * (min(1.0, cap / size) if size > 0 else 0.0)
            force[:2] = f * scale if math.isfinite(size) else 0.0
            self.sample(force)
            if verdict == 0:
                d = self._distance()
                verdict = 1 if d <= d0 - DECIDE_M else -1 if d >= d0 + DECIDE_M else 0
            if verdict < 0 or (verdict > 0 and self.now - begin >= MEASURE_S):
                break  # away: the force off at once; back: held long enough for the fit
        last = len(self.rows)
        self.sample()  # zero force again
        figures: dict[str, float | str] = {"cap_n": cap, "start_mm": d0 * 1e3, "end_mm": d * 1e3}
        what = (
            f"the distance to the start went {d0 * 1e3:.1f} -> {d * 1e3:.1f} mm (cap {cap:.2f} N)"
        )
        if d0 < AWAY_MIN_M:
            self.add(Finding("spring", True, f"not tried: the handle stayed at the start ({what})",
                             figures=figures))  # fmt: skip
            self.add(Finding("force", True, "not measured: no spring was tried"))
            return
        if verdict < 0:
            self.add(Finding("spring", False, (
                f"the spring pushes away from the start: {what}. The force's sign is flipped "
                "relative to the position: the adapter sends force along the opposite axis "
                "direction; do not run with this device until it is fixed (report it)"),
                EXIT_FORCE, figures))  # fmt: skip
            return
        if verdict > 0:
            self.add(Finding("spring", True, f"the spring restores toward the start: {what}",
                             figures=figures))  # fmt: skip
            self.magnitude(self.samples()[first:last], mass)
            return
        self.add(Finding("spring", True, (
            f"inconclusive: {what}; let go of the handle and run check --force again"),
            figures=figures))  # fmt: skip
        self.add(Finding("force", True, "not measured: the spring did not bring the handle "
                         "back"))  # fmt: skip

    def magnitude(self, rows: np.ndarray, mass: float) -> None:
        """The force finding: the handle's response to the spring's force (force_gain)."""
        fit = force_gain(rows, mass, FIT_GAP_PERIODS * self.options.period_s)
        if fit is None:
            self.add(Finding("force", True, (
                f"not measured: the handle moved too little or too unevenly under the spring "
                f"to tell the force's magnitude ({len(rows)} readings); let go of the handle "
                "and run check --force again")))  # fmt: skip
            return
        gain, r2, peak, lag = fit
        figures: dict[str, float | str] = {
            "gain": gain, "r2": r2, "peak_speed_m_s": peak, "lag_readings": lag,
            "apparent_mass_kg": mass,
        }  # fmt: skip
        what = (
            f"the handle moved as if the force were {gain:.2f} x the force sent (a fit of "
            f"{len(rows)} readings, R^2 {r2:.3f}, with [planar].apparent_mass_kg = {mass:g} kg)"
        )
        low, high = GAIN_RANGE
        if low <= gain <= high:
            self.add(Finding("force", True, what, figures=figures))
            return
        heavier = mass / gain
        if gain < low:
            cause = (
                f"the device renders a fraction of the force asked (its force scale or units: "
                f"report it), or the handle is heavier than apparent_mass_kg says (as fitted: "
                f"{heavier:.3g} kg), or it was held: let go of it and run check --force again"
            )
        else:
            cause = (
                f"the device renders more force than asked (its force scale or units: do not "
                f"run with it until it is fixed, report it), or the handle is lighter than "
                f"apparent_mass_kg says (as fitted: {heavier:.3g} kg)"
            )
        self.add(Finding("force", False, f"{what}: outside {low:g}-{high:g} x. Either {cause}",
                         EXIT_FORCE_SCALE, figures))  # fmt: skip

    def _distance(self) -> float:
        pose = self.sensors[0]["pose"]
        return float(np.hypot(pose[0] - self.start_pose[0], pose[1] - self.start_pose[1]))


def force_gain(
    rows: np.ndarray, mass: float, max_gap_s: float
) -> tuple[float, float, float, int] | None:
    """How much of the force sent the handle responded to: (gain, R^2 of the fit, peak
    speed, the readings' lag), or None when the motion tells nothing (too slow, too few
    readings, a poor fit).

    No adapter has a force sensor, so the force is seen through the motion it causes: over
    the spring's readings (SAMPLE_DTYPE), with the force `applied` held from one reading to
    the next, the planar velocity change is fitted as

        mass * (v(t) - v(t0)) = gain * (impulse sent) - c * (x(t) - x(t0)) + f0 * (t - t0)

    per planar axis: `gain` on the impulse of the force sent, a viscous friction c, and a
    steady force f0 per axis (gravity the device does not compensate, a resting finger).
    With the config's apparent mass as the handle's, a device that renders the force asked
    gives a gain near 1; a gain of 0.3 is a device rendering 0.3 of it, or a handle 3.3
    times heavier (a hand holding it) -- the motion alone cannot tell these apart.

    A reading may lag the force (the Inverse3's is its reply to the previous command): the
    fit is made with the readings 0 to FIT_MAX_LAG readings later, and the best kept. A gap
    between two readings longer than `max_gap_s` starts the sums again (t0 is the reading
    after it): what the device did in it is not known (the Touch's servo, for one, zeroes a
    force older than its command_timeout_ms)."""
    t = rows["t"]
    peak = float(np.max(np.hypot(rows["twist"][:, 0], rows["twist"][:, 1]), initial=0.0))
    if not peak >= FIT_MIN_SPEED:  # (NaN too)
        return None
    gaps = np.flatnonzero(np.diff(t) > max_gap_s) + 1  # the first reading after each gap
    bounds = [0, *gaps.tolist(), len(rows)]
    best: tuple[float, float, float, int] | None = None
    for lag in range(FIT_MAX_LAG + 1):
        parts: list[tuple[np.ndarray, ...]] = []
        for lo, hi in itertools.pairwise(bounds):
            n = hi - lo - lag  # the equations of this stretch
            if n < 2:
                continue
            seg = rows[lo:hi]
            ts = seg["t"][:n] - seg["t"][0]
            impulse = np.zeros((n, 2))
            impulse[1:] = np.cumsum(seg["applied"][: n - 1, :2] * np.diff(ts)[:, None], axis=0)
            dv = seg["twist"][lag:, :2] - seg["twist"][lag, :2]
            dx = seg["pose"][lag:, :2] - seg["pose"][lag, :2]
            parts.append((impulse, dx, ts, dv))
        fit = _fit(parts, mass)
        if fit is not None and (best is None or fit[1] > best[1]):
            best = (fit[0], fit[1], peak, lag)
    return best


def _fit(parts: list[tuple[np.ndarray, ...]], mass: float) -> tuple[float, float] | None:
    """force_gain's least squares over its stretches: (gain, R^2) or None."""
    if sum(len(p[0]) for p in parts) < FIT_MIN_READINGS:
        return None
    impulse, dx, ts, dv = (np.concatenate([p[i] for p in parts]) for i in range(4))
    if not all(np.all(np.isfinite(v)) for v in (impulse, dx, dv)):
        return None
    n = len(ts)
    a = np.zeros((2 * n, 4))
    a[:n, 0], a[n:, 0] = impulse[:, 0], impulse[:, 1]
    a[:n, 1], a[n:, 1] = -dx[:, 0], -dx[:, 1]
    a[:n, 2], a[n:, 3] = ts, ts
    y = mass * np.concatenate([dv[:, 0], dv[:, 1]])
    solution, _, rank, _ = np.linalg.lstsq(a, y, rcond=None)
    if rank < 4:
        return None
    residual = y - a @ solution
    total = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / total if total > 0 else 0.0
    if r2 < FIT_MIN_R2:
        return None
    return float(solution[0]), r2


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
    read_toml(source)  # a missing or malformed file: a ConfigError naming it
    result = CheckResult(str(name), config_text=source.read_text())
    if not _before_opening(name, source, result, say):
        return result
    device = _open(source, result, say)
    if device is None:
        return result
    result.adapter = device.name
    run_steps(CheckSession(device, result.config_text, options, ask, result, say))
    return result


def run_steps(session: CheckSession) -> None:
    """The steps on an open device and, always, its safe stop: a check's, and its replay's
    against the logged readings (doctor_replay.py). The failures' errors are kept in the
    findings' figures (`error_type`, `error`) for the replay."""
    options, say, device = session.options, session.say, session.device
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
            EXIT_DEVICE_FAILED, {"error_type": type(exc).__name__, "error": str(exc)}))  # fmt: skip
    finally:
        session.step = "stop"
        try:
            device.safe_stop()
            session.add(Finding("stop", True, "safe stop: zero force, the device closed"))
        except SafeStopError as exc:
            cause = str(exc.__cause__) if exc.__cause__ is not None else str(exc)
            session.add(Finding("stop", False, (
                f"{exc}: the device may still push; switch it off"), EXIT_SAFE_STOP,
                {"error_type": type(exc).__name__, "error": cause}))  # fmt: skip
        session.result.samples = session.samples()
