"""`haptic-pointer`: a mouse or a gamepad as the user's hand, when there is no haptic device.

It reads a Linux input device through `evdev` (extra: `pointer`) — a gamepad's or a
joystick's stick (absolute axes: the stick's deflection is the hand's displacement, up to
`--reach-m`), or a mouse (relative motion: counts times `--m-per-count`, held within the
reach) — or a file of recorded or synthetic input events, played back in real time. Each
complete frame of events (evdev's SYN_REPORT) becomes one PointerInput published over Zenoh
(`<ns>/input/pointer`, shared/protocol/pointer.py), connecting as the network's sim does.
The haptic server's simulated hand of kind "pointer" (`--user pointer`) follows it: the
device model (the twin pantograph, the maglev, ...) is held and moved by a spring-damper
hand whose target the input sets, and the scene pushes back on it as on any hand.

    haptic-run --scene testbed --user pointer --view      # one terminal
    haptic-pointer --evdev /dev/input/event5              # another: your gamepad or mouse
    haptic-pointer --list                                 # the input devices evdev sees

Buttons: the right mouse button or a gamepad's east button (B) recentres the hand.

Event files (JSON lines; `--events FILE`): an optional first line `{"mode": "absolute",
"absinfo": {"ABS_X": [-32768, 32767], ...}}`, then one event per line, `{"t": 0.5, "type":
"EV_ABS", "code": "ABS_X", "value": 16384}` (t in s from the start; type and code by their
Linux names or numbers), frames ended by `{"t": 0.5, "type": "EV_SYN", "code":
"SYN_REPORT", "value": 0}` as evdev delivers them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from haptic_local_model.shared.cli import add_version, emit, run_main
from haptic_local_model.shared.config import ConfigError
from haptic_local_model.shared.protocol.pointer import MAX_POINTER_M, encode_pointer

#: The event types and codes used here, as linux/input-event-codes.h defines them (evdev's
#: `ecodes` has the same numbers; they are the kernel's ABI, so a file can name them
#: without evdev installed).
EV_SYN, EV_KEY, EV_REL, EV_ABS = 0x00, 0x01, 0x02, 0x03
SYN_REPORT = 0x00
REL_X, REL_Y, REL_WHEEL = 0x00, 0x01, 0x08
ABS_X, ABS_Y, ABS_RX = 0x00, 0x01, 0x03
BTN_LEFT, BTN_RIGHT, BTN_SOUTH, BTN_EAST = 0x110, 0x111, 0x130, 0x131
#: ... by their names, as an event file gives them
CODES = {
    "EV_SYN": EV_SYN, "EV_KEY": EV_KEY, "EV_REL": EV_REL, "EV_ABS": EV_ABS,
    "SYN_REPORT": SYN_REPORT, "REL_X": REL_X, "REL_Y": REL_Y, "REL_WHEEL": REL_WHEEL,
    "ABS_X": ABS_X, "ABS_Y": ABS_Y, "ABS_RX": ABS_RX, "BTN_LEFT": BTN_LEFT,
    "BTN_RIGHT": BTN_RIGHT, "BTN_SOUTH": BTN_SOUTH, "BTN_EAST": BTN_EAST,
}  # fmt: skip
RECENTRE = (BTN_RIGHT, BTN_EAST)
BUTTON_BITS = {BTN_LEFT: 1, BTN_RIGHT: 2, BTN_SOUTH: 1, BTN_EAST: 2}
DEFAULT_ABSINFO = (-32768, 32767)  # a gamepad stick, when the device does not say
DEAD_ZONE = 0.05  # of the stick's half-range: a stick at rest reads a little off centre
WHEEL_RAD = math.radians(5.0)  # a mouse wheel notch turns the hand this much


@dataclass
class PointerMapper:
    """Input events -> the hand's target (dx, dy, dtheta), in the scene's frame (y up).

    absolute: a stick's deflection in [-1, 1] (after a dead zone) times `reach_m`; ABS_RX
    turns the hand by up to `reach_rad`. relative: a mouse's counts times `m_per_count`,
    clamped to the reach; the wheel turns it. Screen and stick y grow downward: negated."""

    mode: str = "absolute"
    reach_m: float = 0.08
    reach_rad: float = 0.5
    m_per_count: float = 2e-4
    absinfo: dict[int, tuple[int, int]] = field(default_factory=dict)
    target: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    buttons: int = 0

    def _normalised(self, code: int, value: int) -> float:
        low, high = self.absinfo.get(code, DEFAULT_ABSINFO)
        centre, half = (low + high) / 2.0, (high - low) / 2.0
        s = max(-1.0, min(1.0, (value - centre) / half)) if half > 0 else 0.0
        if abs(s) < DEAD_ZONE:
            return 0.0
        return math.copysign((abs(s) - DEAD_ZONE) / (1.0 - DEAD_ZONE), s)

    def feed(self, kind: int, code: int, value: int) -> bool:
        """One event; True when it completes a frame (publish the target then)."""
        t = self.target
        if kind == EV_SYN:
            return code == SYN_REPORT
        if kind == EV_KEY:
            bit = BUTTON_BITS.get(code, 0)
            self.buttons = (self.buttons | bit) if value else (self.buttons & ~bit)
            if value == 1 and code in RECENTRE:
                t[0] = t[1] = t[2] = 0.0
        elif kind == EV_ABS and self.mode == "absolute":
            if code == ABS_X:
                t[0] = self.reach_m * self._normalised(code, value)
            elif code == ABS_Y:
                t[1] = -self.reach_m * self._normalised(code, value)
            elif code == ABS_RX:
                t[2] = self.reach_rad * self._normalised(code, value)
        elif kind == EV_REL and self.mode == "relative":
            r = self.reach_m
            if code == REL_X:
                t[0] = max(-r, min(r, t[0] + self.m_per_count * value))
            elif code == REL_Y:
                t[1] = max(-r, min(r, t[1] - self.m_per_count * value))
            elif code == REL_WHEEL:
                t[2] = max(-self.reach_rad, min(self.reach_rad, t[2] + WHEEL_RAD * value))
        return False


def _code(value: Any, source: str, line: int, key: str) -> int:
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and value in CODES:
        return CODES[value]
    raise ConfigError(source, f"line {line}: {key}", f"unknown event {key} {value!r}")


def file_events(path: Path, mapper: PointerMapper) -> Iterator[tuple[int, int, int]]:
    """The events of a JSON-lines file, each at its time `t` after the start (a header line
    sets the mode and the axis ranges). A bad line is an error naming the file and line."""
    source = str(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise ConfigError(source, "", f"cannot read: {exc.strerror}") from None
    start = time.monotonic()
    for n, text in enumerate(lines, 1):
        if not text.strip():
            continue
        try:
            item = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(source, f"line {n}", f"not JSON: {exc.msg}") from None
        if not isinstance(item, dict):
            raise ConfigError(source, f"line {n}", "expected an object")
        if "absinfo" in item or "mode" in item:
            _header(item, mapper, source, n)
            continue
        t = item.get("t")
        value = item.get("value")
        if not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
            raise ConfigError(source, f"line {n}: t", f"must be a time >= 0 s, got {t!r}")
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(source, f"line {n}: value", f"must be an integer, got {value!r}")
        kind = _code(item.get("type"), source, n, "type")
        code = _code(item.get("code"), source, n, "code")
        delay = start + float(t) - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield kind, code, value


def _header(item: dict[str, Any], mapper: PointerMapper, source: str, n: int) -> None:
    mode = item.get("mode", mapper.mode)
    if mode not in ("absolute", "relative"):
        raise ConfigError(source, f"line {n}: mode", f"must be absolute or relative, got {mode!r}")
    mapper.mode = mode
    for name, span in dict(item.get("absinfo", {})).items():
        code = _code(name, source, n, "absinfo")
        ok = isinstance(span, list) and len(span) == 2 and span[0] < span[1]
        if not ok or not all(isinstance(v, int) for v in span):
            raise ConfigError(source, f"line {n}: absinfo.{name}", "must be [min, max], min < max")
        mapper.absinfo[code] = (span[0], span[1])


def _evdev() -> Any:
    try:
        import evdev  # type: ignore[import-not-found, unused-ignore]
    except ImportError:
        raise ConfigError(
            "--evdev",
            "",
            "needs the Python package evdev: pip install 'haptic-local-model[pointer]'",
        ) from None
    return evdev


def evdev_events(path: str, mapper: PointerMapper, mode: str) -> Iterator[tuple[int, int, int]]:
    """The events of a Linux input device; the mode from its axes unless given (a stick's
    ABS_X: absolute; a mouse's REL_X: relative), the stick's range from the device."""
    evdev = _evdev()
    try:
        device = evdev.InputDevice(path)
    except OSError as exc:
        raise ConfigError(path, "", f"cannot open the input device: {exc.strerror}") from None
    caps = device.capabilities()
    axes = dict(caps.get(EV_ABS, []))
    if mode == "auto":
        kinds = _kinds(caps)
        mode = "absolute" if "stick" in kinds else "relative" if "mouse" in kinds else ""
        if not mode:
            raise ConfigError(
                path, "", f"{device.name}: neither a stick (ABS_X) nor a mouse (REL_X)"
            )
    mapper.mode = mode
    for code, info in axes.items():
        mapper.absinfo[code] = (int(info.min), int(info.max))
    print(f"haptic-pointer: {device.name} ({path}), {mode}", file=sys.stderr, flush=True)
    for event in device.read_loop():
        yield event.type, event.code, event.value


def list_devices() -> int:
    evdev = _evdev()
    for path in evdev.list_devices():
        device = evdev.InputDevice(path)
        print(f"{path}  {device.name}  {', '.join(_kinds(device.capabilities())) or '-'}")
    return 0


def _kinds(caps: dict[int, Any]) -> list[str]:
    """What an input device is, from its capabilities: a stick (ABS_X), a mouse (REL_X)."""
    stick = ABS_X in dict(caps.get(EV_ABS, []))
    mouse = REL_X in caps.get(EV_REL, [])
    return [kind for kind, has in (("stick", stick), ("mouse", mouse)) if has]


def publish(
    events: Iterator[tuple[int, int, int]], mapper: PointerMapper, network: Any, quiet: bool
) -> int:
    """Each complete frame's target, published; returns how many were."""
    import zenoh

    from haptic_local_model.shared.net.transport import keys, open_session

    session = open_session(network.sim, None, network.namespace)
    try:
        publisher = session.declare_publisher(
            keys(network.namespace).pointer,
            congestion_control=zenoh.CongestionControl.DROP,
            express=True,
        )
        seq = 0
        # a JSON line, as the servers give theirs: an event file's times count from here
        emit("ready", process="pointer", wall_ns=time.time_ns())
        for kind, code, value in events:
            if mapper.feed(kind, code, value):
                t = mapper.target
                publisher.put(
                    encode_pointer(seq, time.time_ns(), (t[0], t[1], t[2]), mapper.buttons)
                )
                seq += 1
                if not quiet:
                    print(f"\r{t[0]:+.3f} {t[1]:+.3f} m {t[2]:+.2f} rad", end="", file=sys.stderr)
        return seq
    finally:
        session.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="haptic-pointer",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_version(parser)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--evdev", metavar="PATH", help="a Linux input device, /dev/input/eventN")
    source.add_argument("--events", type=Path, metavar="FILE", help="a JSON-lines event file")
    source.add_argument("--list", action="store_true", help="the input devices evdev sees")
    parser.add_argument(
        "--mode",
        choices=("auto", "absolute", "relative"),
        default="auto",
        help="stick (absolute) or mouse (relative); auto: from the device",
    )
    parser.add_argument(
        "--reach-m",
        type=float,
        default=0.08,
        help="the hand's largest displacement (m; default 0.08)",
    )
    parser.add_argument(
        "--m-per-count",
        type=float,
        default=2e-4,
        help="a mouse count's displacement (m; default 0.0002)",
    )
    parser.add_argument("--network", default="loopback", help="network name or path")
    parser.add_argument("--port", type=int, default=None, help="the haptic server's port")
    parser.add_argument("--quiet", action="store_true", help="do not print the target")
    args = parser.parse_args(argv)
    if not 0 < args.reach_m <= MAX_POINTER_M:
        parser.error(f"--reach-m: must be in (0, {MAX_POINTER_M:g}] m, got {args.reach_m}")
    if not 0 < args.m_per_count <= 0.01:
        parser.error(f"--m-per-count: must be in (0, 0.01] m, got {args.m_per_count}")

    def body() -> int:
        from haptic_local_model.shared.net.config import load_network, on_port

        if args.list:
            return list_devices()
        network = load_network(args.network, roles=("sim",))
        if args.port is not None:
            network = on_port(network, args.port)
        mode = "absolute" if args.mode == "auto" else args.mode
        mapper = PointerMapper(mode=mode, reach_m=args.reach_m, m_per_count=args.m_per_count)
        events = (
            file_events(args.events, mapper)
            if args.events is not None
            else evdev_events(args.evdev, mapper, args.mode)
        )
        try:
            sent = publish(events, mapper, network, args.quiet)
        except KeyboardInterrupt:
            return 0
        except OSError as exc:  # the input device was unplugged (or went away) while read
            print(f"\nhaptic-pointer: {args.evdev or args.events}: {exc.strerror or exc}",
                  file=sys.stderr)  # fmt: skip
            return 1
        print(f"\nhaptic-pointer: {sent} targets published", file=sys.stderr)
        return 0

    return run_main(body)


if __name__ == "__main__":
    sys.exit(main())
