"""`haptic-device`: the device doctor's command line (device_models/doctor.py does the work).

It lives in the harness, not in device_models, because its bring-up log is written with the
haptic server's MCAP writer (haptic_server/log.py), which device models may not import.
"""

from __future__ import annotations

import argparse
import json
import sys

from haptic_local_model.device_models import doctor
from haptic_local_model.shared.cli import add_version, run_main


def _list(args: argparse.Namespace) -> int:
    reports = doctor.list_models()
    if args.json:
        print(json.dumps([r.as_json() for r in reports], indent=2))
    else:
        print(doctor.format_list(reports))
    return doctor.EXIT_OK


def parser() -> argparse.ArgumentParser:
    """The arguments of `haptic-device` and its commands."""
    p = argparse.ArgumentParser(prog="haptic-device", description=__doc__)
    add_version(p)
    commands = p.add_subparsers(dest="command", required=True)
    listing = commands.add_parser(
        "list", help="installed device models: binding, vendor runtime, devices detected"
    )
    listing.add_argument("--json", action="store_true", help="one JSON list, for machines")
    listing.set_defaults(body=_list)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_main(lambda: int(args.body(args)))


if __name__ == "__main__":
    sys.exit(main())
