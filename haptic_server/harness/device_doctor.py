"""`haptic-device`: the device doctor's command line (device_models/doctor.py does the work).

It lives in the harness, not in device_models, because its bring-up log is written with the
haptic server's MCAP writer (haptic_server/log.py), which device models may not import.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from haptic_local_model.device_models import doctor
from haptic_local_model.device_models.doctor_check import (
    STEPS,
    Ask,
    CheckOptions,
    CheckResult,
    run_check,
)
from haptic_local_model.device_models.registry import device_config
from haptic_local_model.haptic_server.log import write_rows_log
from haptic_local_model.shared.cli import EXIT_LOG_FAILED, add_version, log_file, run_main, seconds

#: the bring-up log's channel and schema (one message per sample, doctor_check.SAMPLE_DTYPE)
LOG_TOPIC = "/device_doctor/sample"
LOG_SCHEMA = "haptic_local_model/DeviceDoctorSample"


def _list(args: argparse.Namespace) -> int:
    reports = doctor.list_models()
    if args.json:
        print(json.dumps([r.as_json() for r in reports], indent=2))
    else:
        print(doctor.format_list(reports))
    return doctor.EXIT_OK


def ask_user(step: str, text: str) -> None:
    """The interactive prompt: the text, then wait for Enter (without a terminal on stdin,
    it goes straight on: the move's window still runs)."""
    try:
        input(f"{step}: {text} ")
    except EOFError:
        print("(stdin is closed: not waiting for Enter)", flush=True)


def _check(args: argparse.Namespace, ask: Ask) -> int:
    options = CheckOptions(
        seconds=args.seconds, force=args.force, write=args.write, move_timeout_s=args.move_seconds
    )
    result = run_check(args.device, options, ask, lambda line: print(line, flush=True))
    code = result.exit_code
    if args.log is not None and not write_log(args.log, args.device, result):
        code = code or EXIT_LOG_FAILED
    print(f"check {'passed' if code == doctor.EXIT_OK else 'FAILED'} (exit {code})")
    return code


def write_log(path: Path, device: str, result: CheckResult) -> bool:
    """The bring-up log: every sample (t, step, planar pose and twist, the device-frame
    position, the commanded and the applied force, the fault bits) on LOG_TOPIC, and as
    metadata the findings, the steps' names and the device config's text, so a user can
    send it with a question. Whether it was written (a failure is said in one line)."""
    source = device_config(device)
    findings = [
        {"step": f.step, "ok": f.ok, "exit_code": f.exit_code, "message": f.message,
         "figures": f.figures}
        for f in result.findings
    ]  # fmt: skip
    metadata = {
        "device_doctor": {
            "device": device,
            "exit_code": str(result.exit_code),
            "steps": json.dumps(list(STEPS)),
            "findings": json.dumps(findings),
        },
        "device_config": {"path": str(source), "text": source.read_text()},
    }
    try:
        write_rows_log(path, result.samples, LOG_TOPIC, LOG_SCHEMA, metadata)
    except OSError as exc:
        print(f"haptic-device: cannot write the log {path}: {exc}", file=sys.stderr)
        return False
    print(f"log: {path} ({len(result.samples)} samples)")
    return True


def parser() -> argparse.ArgumentParser:
    """The arguments of `haptic-device` and its commands."""
    p = argparse.ArgumentParser(prog="haptic-device", description=__doc__)
    add_version(p)
    commands = p.add_subparsers(dest="command", required=True)
    listing = commands.add_parser(
        "list", help="installed device models: binding, vendor runtime, devices detected"
    )
    listing.add_argument("--json", action="store_true", help="one JSON list, for machines")
    listing.set_defaults(body=lambda args, ask: _list(args))
    check = commands.add_parser(
        "check", help="open a device: read rate, jitter, noise; the [planar] map; the force"
    )
    check.add_argument("--device", required=True, help="device name in configs/devices or a path")
    check.add_argument("--seconds", type=seconds, default=3.0, help="read at rest this long")
    check.add_argument(
        "--move-seconds", type=seconds, default=10.0,
        help="how long to wait for each move of the handle the check asks for",
    )  # fmt: skip
    check.add_argument(
        "--force", action="store_true",
        help="render a gentle spring (10 %% of the limit, faded in) and check its direction",
    )  # fmt: skip
    check.add_argument(
        "--write", type=Path, default=None, metavar="FILE",
        help="if the [planar] map is wrong, write a corrected device config here",
    )  # fmt: skip
    check.add_argument(
        "--log", type=log_file, default=None, metavar="OUT.mcap",
        help="write the bring-up log: every sample and the findings (MCAP)",
    )  # fmt: skip
    check.set_defaults(body=_check)
    return p


def main(argv: list[str] | None = None, ask: Callable[[str, str], None] = ask_user) -> int:
    """`haptic-device`; `ask` plays the user in tests (the fake handle's moves)."""
    args = parser().parse_args(argv)
    return run_main(lambda: int(args.body(args, ask)))


if __name__ == "__main__":
    sys.exit(main())
