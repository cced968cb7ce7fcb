"""`haptic-device`: the device doctor's command line (device_models/doctor.py does the work).

It lives in the harness, not in device_models, because its bring-up log is written and read
with the haptic server's MCAP writer and reader (haptic_server/log.py), which device models
may not import. `haptic-replay LOG` comes here for a bring-up log (`replay_main`): the check
replayed against the logged readings (device_models/doctor_replay.py).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from mcap.records import Channel, Metadata

from haptic_local_model.device_models import doctor
from haptic_local_model.device_models.doctor_check import (
    SAMPLE_DTYPE,
    STEPS,
    Ask,
    CheckOptions,
    CheckResult,
    options_from_json,
    options_json,
    run_check,
)
from haptic_local_model.device_models.doctor_replay import (
    BringupLog,
    first_difference,
    replay_check,
)
from haptic_local_model.device_models.registry import device_config
from haptic_local_model.haptic_server.log import (
    head_records,
    read_topic_rows,
    whole_log_metadata,
    write_rows_log,
)
from haptic_local_model.shared.cli import EXIT_LOG_FAILED, add_version, log_file, run_main, seconds
from haptic_local_model.shared.config import ConfigError

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
    logged = args.log is None or write_log(args.log, args.device, result, options)
    if not logged and code == doctor.EXIT_OK:
        print(f"check passed, but its log was not written (exit {EXIT_LOG_FAILED})")
        return EXIT_LOG_FAILED
    print(f"check {'passed' if code == doctor.EXIT_OK else 'FAILED'} (exit {code})")
    return code


def write_log(path: Path, device: str, result: CheckResult, options: CheckOptions) -> bool:
    """The bring-up log: every sample (t, step, planar pose and twist, the device-frame
    position and velocity, the commanded and the applied force, the fault bits and the
    vendor's) on LOG_TOPIC, and as metadata the findings, the steps' names, the options, the
    adapter and the device config's text, so a user can send it with a question and it
    replays against the logged readings (`haptic-replay LOG`). Whether it was written (a
    failure is said in one line)."""
    findings = [
        {"step": f.step, "ok": f.ok, "exit_code": f.exit_code, "message": f.message,
         "figures": f.figures, "at_sample": f.at_sample}
        for f in result.findings
    ]  # fmt: skip
    metadata = {
        "device_doctor": {
            "device": device,
            "adapter": result.adapter,
            "exit_code": str(result.exit_code),
            "samples": str(len(result.samples)),
            "steps": json.dumps(list(STEPS)),
            "options": json.dumps(options_json(options)),
            "findings": json.dumps(findings),
        },
        "device_config": {"path": str(device_config(device)), "text": result.config_text},
    }
    try:
        write_rows_log(path, result.samples, LOG_TOPIC, LOG_SCHEMA, metadata)
    except OSError as exc:
        print(f"haptic-device: cannot write the log {path}: {exc}", file=sys.stderr)
        return False
    print(f"log: {path} ({len(result.samples)} samples; replay it: haptic-replay {path})")
    return True


def is_bringup_log(path: Path) -> bool:
    """A bring-up log (`check --log`): its device_doctor metadata or its samples' channel
    among the first records."""
    return any(
        (isinstance(record, Metadata) and record.name == "device_doctor")
        or (isinstance(record, Channel) and record.topic == LOG_TOPIC)
        for record in head_records(path)
    )


def read_bringup_log(path: Path) -> BringupLog:
    """A whole bring-up log's samples and metadata; anything else is refused by name (a
    ConfigError naming the file)."""
    where = str(path)
    metadata = whole_log_metadata(
        path, ", so not a bring-up log", "a bring-up log is written whole"
    )
    doctor_record = metadata.get("device_doctor")
    if doctor_record is None:
        raise ConfigError(where, "log", (
            "not a bring-up log: it has no device_doctor metadata (`haptic-device check --log "
            "OUT.mcap` writes one)"))  # fmt: skip
    rows = read_topic_rows(path, LOG_TOPIC, SAMPLE_DTYPE, "sample").copy()
    try:
        expected = int(doctor_record["samples"])
        options = options_from_json(json.loads(doctor_record["options"]))
        findings = json.loads(doctor_record["findings"])
        exit_code = int(doctor_record["exit_code"])
        config_text = metadata["device_config"]["text"]
    except (KeyError, ValueError, TypeError) as exc:
        raise ConfigError(where, "device_doctor", f"incomplete ({type(exc).__name__}: {exc}): "
                          "written by an earlier release?") from None  # fmt: skip
    if len(rows) != expected:
        raise ConfigError(where, "device_doctor.samples", f"{len(rows)} samples logged, "
                          f"{expected} taken")  # fmt: skip
    return BringupLog(
        where, rows, doctor_record.get("device", ""), doctor_record.get("adapter", ""),
        config_text, options, findings, exit_code,
    )  # fmt: skip


def replay_main(path: Path) -> int:
    """`haptic-replay` of a bring-up log: the check's steps again against its readings,
    compared with what it found (device_models/doctor_replay.py): 0 identical, 1 different;
    a log that is not a whole bring-up log is refused (a ConfigError, exit 2)."""
    log = read_bringup_log(path)
    if not log.adapter:  # stopped before the device was opened: nothing was read
        lines = [f"{f['step']}: {'ok' if f['ok'] else 'FAILED'}: {f['message']}"
                 for f in log.findings]  # fmt: skip
        print(f"the check of {log.device} logged in {path} stopped before opening the device: "
              "nothing was read, nothing to replay (its findings are the machine's):")  # fmt: skip
        print("\n".join(f"  {line}" for line in lines))
        return 0
    replayed = replay_check(log)
    result = replayed.result
    print(
        f"replayed the check of {log.device} ({log.adapter}) in {path} against its "
        f"{len(log.rows)} logged readings: {len(result.samples)} taken, "
        f"{len(result.findings)} findings (logged {len(log.findings)}), exit {result.exit_code}"
    )
    for f in result.findings:
        print(f"  {f.line()}")
    difference = first_difference(log, replayed)
    if difference is None:
        print(
            f"identical: every sample's step, pose, twist, forces and fault bits, every "
            f"finding and the exit code ({log.exit_code}) as logged"
        )
        return 0
    print(f"DIFFERENT at sample {difference.at_sample} (step {difference.step}): "
          f"{difference.text}")  # fmt: skip
    return 1


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
