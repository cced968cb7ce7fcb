"""Helpers shared by the console scripts: config errors exit 2, JSON event lines."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from haptic_local_model.shared import __version__
from haptic_local_model.shared.config import CONFIG_KINDS, ConfigError, shipped

EXIT_FAILED = 1  # the run could not go on or finish (a lost I/O process, a summary unwritten)
EXIT_CONFIG = 2  # a config file or argument refused (one line names the file and key)
EXIT_LOG_FAILED = 3  # the run went on, but logging stopped (a full disk): the log is cut short


def add_config_args(
    parser: argparse.ArgumentParser,
    device: bool = True,
    user: bool = True,
    rate: bool = False,
    per_port: bool = False,
) -> None:
    """--scene, --device, --user, --network, --port (and --haptic-rate). With `per_port`,
    --device and --user may be given once per port of a port scene (a list, None when not
    given: the caller takes its defaults, `single` for a scene of one device)."""
    add_version(parser)
    scenes = "configs/scenes (or configs/ports)" if per_port else "configs/scenes"
    parser.add_argument("--scene", default="testbed", help=f"scene name in {scenes} or a path")
    each: dict[str, Any] = {"action": "append", "default": None} if per_port else {}
    again = ", or once per port of a port scene" if per_port else ""
    if device:
        parser.add_argument(
            "--device", **each, help=f"device name in configs/devices or a path (default ideal"
            f"{again})",
        )  # fmt: skip
        if not per_port:
            parser.set_defaults(device="ideal")
    if user:
        parser.add_argument(
            "--user", **each, help=f"user name in configs/users or a path (default swing{again})"
        )
        if not per_port:
            parser.set_defaults(user="swing")
    parser.add_argument(
        "--network", default="loopback", help="network name in configs/network or a path"
    )
    parser.add_argument(
        "--port", type=port, default=None,
        help="the haptic server listens (and the sim connects) on this port instead of the "
        "network config's",
    )  # fmt: skip
    if rate:
        parser.add_argument(
            "--haptic-rate",
            type=haptic_rate,
            default=None,
            metavar="HZ",
            help="the haptic loop's rate, instead of the scene's haptic_rate_hz (100-10000 Hz, "
            "at most the device's max_rate_hz)",
        )


def single(given: list[str] | None, default: str, flag: str) -> str:
    """The one name a scene of one device takes from a per-port flag (add_config_args)."""
    if not given:
        return default
    if len(given) > 1:
        raise ConfigError(flag, flag, f"given {len(given)} times: the scene has one device")
    return given[0]


#: the longest run any console script takes (a week): beyond it, a typo
MAX_SECONDS = 7 * 24 * 3600.0


def _number(text: str, low: float, high: float, unit: str, low_open: bool) -> float:
    """A finite number in (low, high] or [low, high]: argparse's type for durations, rates."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    above = value > low if low_open else value >= low
    if not (math.isfinite(value) and above and value <= high):
        bracket = "(" if low_open else "["
        raise argparse.ArgumentTypeError(
            f"must be a finite number in {bracket}{low:g}, {high:g}] {unit}, got {text!r}"
        )
    return value


def port(text: str) -> int:
    """A TCP/UDP port number: argparse's type for --port."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port in [1, 65535], got {text!r}")
    return value


def seconds(text: str) -> float:
    """A duration for --duration and its kind: finite, > 0, at most MAX_SECONDS."""
    return _number(text, 0.0, MAX_SECONDS, "s", low_open=True)


def minutes(text: str) -> float:
    return _number(text, 0.0, MAX_SECONDS / 60.0, "min", low_open=True)


def speed(text: str) -> float:
    """A playback speed: 0 (all at once) up to 1000x."""
    return _number(text, 0.0, 1000.0, "x", low_open=False)


def haptic_rate(text: str) -> float:
    return _number(text, 100.0, 10_000.0, "Hz", low_open=False)


def log_file(text: str) -> Path:
    """A log path for --log: a file to write, not a directory."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a directory: give a file (run.mcap)")
    return path


def check_log_writable(path: Path) -> None:
    """Before a run, not after it: its log's folder made and a file written there, or a
    ConfigError naming --log (a folder that is a file, no permission)."""
    for folder in (path.parent, *path.parent.parents):
        if folder.exists():
            if not folder.is_dir():
                why = f"cannot write {path}: {folder} is a file, not a folder"
                raise ConfigError("command line", "--log", why)
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".check"):
            pass  # a name of its own: another run's log or its .part is left alone
    except OSError as exc:
        raise ConfigError("command line", "--log", f"cannot write {path}: {exc}") from None


def add_version(parser: argparse.ArgumentParser) -> None:
    """`--version`: the installed distribution's version."""
    parser.add_argument(
        "--version", action="version", version=f"%(prog)s {__version__} (haptic-local-model)"
    )


def print_shipped(extra: Sequence[str] = ()) -> None:
    """The shipped scenes, devices, users, networks and port scenes, a line each, then
    `extra` (the installed device models: `haptic-run --list`)."""
    lines = []
    for kind in (*CONFIG_KINDS, "ports"):
        configs = shipped(kind)
        flag = "--scene" if kind == "ports" else f"--{kind.rstrip('s')}"
        what = ", scenes whose devices run in this process" if kind == "ports" else ""
        lines.append(f"{kind}{what} ({flag} NAME, or a path to a .toml file):")
        width = max(map(len, configs), default=0)
        lines += [f"  {name:<{width}}  {text}" for name, text in configs.items()]
    lines += extra
    try:
        print("\n".join(lines), flush=True)
    except BrokenPipeError:  # `haptic-run --list | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def done_with_signals(code: int, argv: list[str] | None) -> int:
    """A server's or haptic-run's main has done its work (its log closed, its summary
    written): as a process of its own (`argv` None: its arguments are the command line's), a
    SIGTERM or SIGINT during its exit must not kill it with -15 and turn a clean stop into a
    failure. Python restores the default handlers as it finalises, and a teardown of
    threads and sessions takes long enough for a stop sent as the run ends to land in it;
    ignored handlers are left as they are. Called in another program's process (`argv`
    given), its handlers are left alone. Returns `code`."""
    if argv is None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    return code


def run_main(body: Callable[[], int]) -> int:
    """Run a CLI body; a ConfigError prints its message and exits with code 2."""
    try:
        return body()
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        return EXIT_CONFIG


def write_summary(path: Path | None, summary: dict[str, Any], prog: str) -> bool:
    """Write a run's summary as JSON, if asked; on failure (a full disk) say so in one line.
    Returns whether it is written (or was not asked for)."""
    if path is None:
        return True
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(summary, indent=2))
    except OSError as exc:
        print(f"{prog}: cannot write the summary: {exc}", file=sys.stderr)
        return False
    return True


def emit(kind: str, **fields: Any) -> None:
    """One JSON line on stdout: how haptic-run and the tests follow a server.

    If the reader is gone (haptic-run was killed), there is nobody to tell: stdout goes to
    /dev/null so the server still finishes cleanly."""
    try:
        print(json.dumps({"event": kind, **fields}), flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
