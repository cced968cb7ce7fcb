"""Helpers shared by the console scripts: config errors exit 2, JSON event lines."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from typing import Any

from shared import __version__
from shared.config import CONFIG_KINDS, ConfigError, shipped

EXIT_CONFIG = 2


def add_config_args(
    parser: argparse.ArgumentParser, device: bool = True, user: bool = True, rate: bool = False
) -> None:
    add_version(parser)
    parser.add_argument("--scene", default="testbed", help="scene name in configs/scenes or a path")
    if device:
        parser.add_argument(
            "--device", default="ideal", help="device name in configs/devices or a path"
        )
    if user:
        parser.add_argument("--user", default="swing", help="user name in configs/users or a path")
    parser.add_argument(
        "--network", default="loopback", help="network name in configs/network or a path"
    )
    if rate:
        parser.add_argument(
            "--haptic-rate",
            type=float,
            default=None,
            metavar="HZ",
            help="the haptic loop's rate, instead of the scene's haptic_rate_hz (100-10000 Hz, "
            "at most the device's max_rate_hz)",
        )


def add_version(parser: argparse.ArgumentParser) -> None:
    """`--version`: the installed distribution's version."""
    parser.add_argument(
        "--version", action="version", version=f"%(prog)s {__version__} (haptic-local-model)"
    )


def print_shipped() -> None:
    """The shipped scenes, devices, users and networks, a line each (`haptic-run --list`)."""
    lines = []
    for kind in CONFIG_KINDS:
        configs = shipped(kind)
        lines.append(f"{kind} (--{kind.rstrip('s')} NAME, or a path to a .toml file):")
        width = max(map(len, configs), default=0)
        lines += [f"  {name:<{width}}  {text}" for name, text in configs.items()]
    try:
        print("\n".join(lines), flush=True)
    except BrokenPipeError:  # `haptic-run --list | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def run_main(body: Callable[[], int]) -> int:
    """Run a CLI body; a ConfigError prints its message and exits with code 2."""
    try:
        return body()
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        return EXIT_CONFIG


def emit(kind: str, **fields: Any) -> None:
    """One JSON line on stdout: how haptic-run and the tests follow a server.

    If the reader is gone (haptic-run was killed), there is nobody to tell: stdout goes to
    /dev/null so the server still finishes cleanly."""
    try:
        print(json.dumps({"event": kind, **fields}), flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
