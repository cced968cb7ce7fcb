"""`haptic-replay`: re-run the haptic side of a logged run, compare, summarise, plot, recover.

A replay rebuilds the scene, device and user from the config texts stored in the log and
drives the same `HapticEngine` the run used: each logged update's bytes are installed at the
tick they were received (rejected ones too, so every verdict is checked), with the latency
the loop installed them with; each tick uses the logged dt and the logged hand wrench, and
watchdog events switch the safe state at their tick. Every recomputed tick row is compared
with the logged one: the same build and configs give exactly zero difference.

A port world's log (`haptic-run --scene grasp_vertical`, `haptic-world`) is told by its topic
and re-run bit for bit by haptic_server.world_runs; a bring-up log (`haptic-device check
--log`) by its metadata, and its check replayed against its readings by
harness/device_doctor.py.
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import json
import math
import sys
from collections import defaultdict
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.engine import EngineCounters, HapticEngine
from haptic_local_model.haptic_server.harness.plot import plot_run
from haptic_local_model.haptic_server.harness.summary import ReplayError, print_summary, summarise
from haptic_local_model.haptic_server.live_view import EmptyLogError, view_log
from haptic_local_model.haptic_server.log import LogContents, read_log, recover_log
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.stages.install import EPOCH_LAW_HIGHER
from haptic_local_model.haptic_server.stages.tick import store_row
from haptic_local_model.haptic_server.supervisor import Event, LoggedEvents, supervise
from haptic_local_model.haptic_server.view_address import (
    ViewAddress,
    add_view_args,
    view_address,
)
from haptic_local_model.shared import source_hash
from haptic_local_model.shared.cli import add_version, seconds, speed
from haptic_local_model.shared.config import (
    ConfigError,
    SceneConfig,
    UserConfig,
    load_config_text,
    parse_toml_text,
)
from haptic_local_model.shared.net.config import SAFE_RAMP_MS_RANGE, NetworkConfig
from haptic_local_model.shared.protocol.codes import Reason
from haptic_local_model.shared.protocol.codes import reason_tag as reason_of

PROGRESS_MIN_TICKS = 20_000  # show a progress bar on replays longer than 20 s at 1 kHz
PROGRESS_EVERY = 1000  # ticks between progress bar updates (keeps its cost negligible)

#: Quantities the comparison reports first, in this order (all other fields follow).
FORCE_FIELDS = (
    "f_user", "f_contact", "f_impulse", "f_bias", "f_penalty", "f_coordination", "f_damping",
    "wrench_command", "wrench_applied", "contact_force_world", "hand_wrench_measured",
)  # fmt: skip
POSE_FIELDS = ("device_pose", "device_twist", "vm_pose", "vm_twist", "proxy_q", "proxy_qd")


@dataclass
class ReplayResult:
    """What a replay recomputed and how far it is from the log."""

    ticks: np.ndarray  # recomputed TICK_DTYPE rows, one per compared tick
    max_abs_diff: dict[str, float]  # field -> largest |recomputed - logged| (NaN == NaN)
    updates_replayed: int
    verdict_mismatches: list[dict[str, Any]]  # updates whose verdict differs from the log's
    counters: EngineCounters
    note: str = ""  # why fewer ticks than logged were replayed, if so

    @property
    def identical(self) -> bool:
        return not self.verdict_mismatches and all(v == 0.0 for v in self.max_abs_diff.values())

    @property
    def differing(self) -> dict[str, float]:
        return {k: v for k, v in self.max_abs_diff.items() if v != 0.0}


# --- rebuilding the engine ------------------------------------------------------------------


#: The first version whose control law has M_d J_h_dot qd (DESIGN §4.3) and computes a
#: colliding tick's contact forces after its impulses; a log of an earlier build rendered
#: seed 000's law as printed and the forces first, and its scene is replayed that way.
LAW_0_2 = (0, 2, 0)
#: The first version that admits an update only if it is fresh, and another epoch only when
#: the watchdog has fired (haptic_server.stages.install, EPOCH_LAW_LIVE); before, any higher
#: epoch switched at once and no publish time was checked.
ADMISSION_0_3 = (0, 3, 0)
#: The first version that checks every update against the scene (stages/plausible.py) and
#: guards the loop against a runaway proxy and an active port (stages/safety.py): before,
#: any valid update was rendered and a NaN fault kept the device safe until the watchdog.
GUARD_0_4 = (0, 4, 0)
#: The first version whose default impulse law pays the device's share of an impact ahead
#: and returns the offset its limits cause (`[rendering] impulse_law = "0.13"`,
#: stages/control.py impact_ledger); a log of an earlier build that did not name its law
#: rendered "0.2".
LAW_0_13 = (0, 13, 0)


def _version(text: str | None) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in (text or "0").split(".")[:3])
    except ValueError:
        return (0,)


def scene_of_run(scene_text: str, run: dict[str, str] | None) -> SceneConfig:
    """The scene a run rendered: its config text, read with the defaults of the build that
    recorded it (`run` is the log's run metadata: its version)."""
    scene = load_config_text(SceneConfig, scene_text, "log:configs.scene")
    version = _version((run or {}).get("version"))
    if version < LAW_0_2:
        rendering = dataclasses.replace(scene.rendering, jdot_qd=False, impulse_law="0.1")
        scene = dataclasses.replace(scene, rendering=rendering)
    elif version < LAW_0_13 and scene.rendering.impulse_law == "0.13":
        rendering = dataclasses.replace(scene.rendering, impulse_law="0.2")
        scene = dataclasses.replace(scene, rendering=rendering)
    return scene


def engine_from_configs(configs: dict[str, str], run: dict[str, str] | None = None) -> HapticEngine:
    """The engine a run used, from the config texts in its `configs` metadata record and
    the build in its `run` record (see scene_of_run)."""
    from haptic_local_model.device_models.registry import device_from_text

    missing = [k for k in ("scene", "device", "user") if not configs.get(k)]
    if missing:
        raise ReplayError(f"the log's configs metadata lacks {', '.join(missing)}")
    scene = scene_of_run(configs["scene"], run)
    user = load_config_text(UserConfig, configs["user"], "log:configs.user")
    # a run on real hardware replays against no device: opening it would drive it
    device = device_from_text(configs["device"], "log:configs.device", simulated_only=True)
    engine = HapticEngine(scene, device, user)
    if configs.get("network"):  # real-time runs: the safe-state ramp comes from the network
        network = _network_of_run(configs["network"], run)
        engine = HapticEngine(scene, device, user, network.safe_ramp_ms / 1000.0)
        engine.set_admission(network.max_update_age_ms / 1e3, network.clock_skew_ms / 1e3)
    version = _version((run or {}).get("version"))
    if version < ADMISSION_0_3:
        engine.set_admission(math.inf, math.inf, EPOCH_LAW_HIGHER)
    if version < GUARD_0_4:
        engine.check_plausibility(False)
        engine.guard(False)
    return engine


def _network_of_run(text: str, run: dict[str, str] | None) -> NetworkConfig:
    """A run's network config; one of a build before 0.3 may hold values that build took
    and today's ranges refuse: its admission is replaced by the old law anyway."""
    try:
        return load_config_text(NetworkConfig, text, "log:configs.network")
    except ConfigError:
        if _version((run or {}).get("version")) >= ADMISSION_0_3:
            raise
        data = parse_toml_text(text, "log:configs.network")
        ramp = float(data.get("safe_ramp_ms", NetworkConfig.safe_ramp_ms))
        return NetworkConfig(safe_ramp_ms=min(ramp, SAFE_RAMP_MS_RANGE[1]))


def contiguous_ticks(ticks: np.ndarray) -> int:
    """How many rows from the start are ticks 0, 1, 2, ... (a replay cannot cross a gap)."""
    expected = np.arange(len(ticks), dtype=np.uint64)
    bad = np.flatnonzero(ticks["tick"] != expected)
    return int(bad[0]) if bad.size else len(ticks)


# --- replay ---------------------------------------------------------------------------------


def replay(
    log: LogContents, configs: dict[str, str] | None = None, progress: bool = False
) -> ReplayResult:
    """Re-run the logged ticks through a fresh engine; compare every row with the log.

    `configs` replaces the config texts stored in the log (to see what a change would do).
    """
    logged = log.ticks
    if len(logged) == 0:
        raise ReplayError(
            "the log holds no ticks: not a haptic run's log (nor a port world's nor a bring-up log)"
        )
    engine = engine_from_configs(
        configs if configs is not None else log.metadata.get("configs", {}),
        log.metadata.get("run"),
    )
    n = contiguous_ticks(logged)
    note = "" if n == len(logged) else f"ticks stop being contiguous after tick {n - 1}"
    updates_at: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for rec in log.updates:
        updates_at[int(rec["tick"])].append(rec)
    # the events that switched the safe state, applied in the loop's order by the supervisor
    events_at: dict[int, set[str]] = defaultdict(set)
    for ev in log.events:
        if ev["kind"] in (Event.STOP, Event.WATCHDOG_CLEAR, Event.WATCHDOG):
            events_at[int(ev["tick"])].add(ev["kind"])

    out = np.zeros(n, TICK_DTYPE)
    dt = logged["dt"][:n].tolist()
    lateness = logged["lateness_us"][:n].tolist()
    work = logged["work_us"][:n].tolist()
    seq = logged["update_seq"][:n].tolist()
    age = logged["update_age_ms"][:n].tolist()
    hand = np.ascontiguousarray(logged["hand_wrench"][:n])
    mismatches: list[dict[str, Any]] = []
    replayed = 0
    bar = _progress_bar(n, progress)
    k = -1
    try:
        for k in range(n):
            records = updates_at.get(k, ())
            replayed += len(records)
            source = LoggedEvents(
                events_at.get(k, set()), partial(_install_all, engine, records, k, mismatches)
            )
            supervise(engine, source)
            row = engine.tick(dt[k], lateness[k], work[k], seq[k], age[k], hand[k])
            store_row(out, k, row)
            if bar is not None and k % PROGRESS_EVERY == PROGRESS_EVERY - 1:
                bar.update(PROGRESS_EVERY)
    finally:
        if bar is not None:
            bar.update(len(out) - bar.n if k == n - 1 else 0)
            bar.close()
    diffs = max_abs_differences(out, logged[:n], skip=log.absent_tick_fields)
    if log.absent_tick_fields:
        absent = ", ".join(log.absent_tick_fields)
        note = f"{note}; " if note else ""
        note += f"not compared (the log's rows do not have them): {absent}"
    return ReplayResult(out, diffs, replayed, mismatches, engine.counters, note)


def _install_all(
    engine: HapticEngine,
    records: tuple[dict[str, Any], ...] | list[dict[str, Any]],
    tick: int,
    mismatches: list[dict[str, Any]],
) -> int:
    """Install a tick's logged updates as the loop did; verdicts that differ from the log's go
    into `mismatches`. Returns how many were installed."""
    installed = 0
    for rec in records:
        reason = _install(engine, rec)
        installed += reason == ""
        if reason != rec["reason"]:
            mismatches.append({"tick": tick, "logged": rec["reason"], "replayed": reason})
    return installed


def _install(engine: HapticEngine, rec: dict[str, Any]) -> str:
    """Install a logged update as the loop did; returns the verdict ("" or a reason)."""
    raw = base64.b64decode(rec["raw_b64"])
    if int(rec["size_bytes"]) > len(raw):
        return reason_of(Reason.SIZE)  # too big for the mailbox: the loop never parsed it
    if rec["reason"] == Reason.UNBOUND.tag:  # a fact of the network (the sims' liveliness),
        return Reason.UNBOUND.tag  # not of the bytes: refused as the loop refused it
    return engine.receive(raw, float(rec.get("latency_s", 0.0)))


def _progress_bar(total: int, enabled: bool) -> Any:
    if not enabled or total < PROGRESS_MIN_TICKS:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="tick", unit_scale=True, desc="replay", file=sys.stderr)


def max_abs_differences(
    a: np.ndarray, b: np.ndarray, skip: tuple[str, ...] = ()
) -> dict[str, float]:
    """Per field (but those in `skip`), the largest |a - b| over all rows; NaN in both
    counts as equal."""
    diffs: dict[str, float] = {}
    for name in TICK_DTYPE.names or ():
        if name in skip:
            continue
        x = a[name].astype(np.float64)
        y = b[name].astype(np.float64)
        d = np.abs(x - y)
        both_nan = np.isnan(x) & np.isnan(y)
        d = np.where(both_nan, 0.0, np.where(np.isnan(d), np.inf, d))
        diffs[name] = float(d.max()) if d.size else 0.0
    return diffs


def print_comparison(result: ReplayResult, logged_ticks: int) -> None:
    """The largest difference per quantity: forces by source, command, poses, then the rest."""
    n = len(result.ticks)
    print(
        f"replayed {n} of {logged_ticks} ticks and {result.updates_replayed} updates"
        + (f" ({result.note})" if result.note else "")
    )
    print(f"{'quantity':<22}{'max |replay - log|':>20}")
    shown = [*FORCE_FIELDS, *POSE_FIELDS]
    rest = [f for f in result.max_abs_diff if f not in shown]
    for name in shown + [f for f in rest if result.max_abs_diff[f] != 0.0]:
        print(f"{name:<22}{result.max_abs_diff[name]:>20.3e}")
    same = [f for f in rest if result.max_abs_diff[f] == 0.0]
    print(f"{'(all other fields)':<22}{'0':>20}  ({len(same)} fields)")
    for m in result.verdict_mismatches[:10]:
        print(f"update at tick {m['tick']}: logged {m['logged']!r}, replayed {m['replayed']!r}")
    if result.identical:
        print("identical: the replay reproduces every logged tick exactly")
    else:
        print(
            f"DIFFERENT: {len(result.differing)} fields differ, "
            f"{len(result.verdict_mismatches)} update verdicts differ"
        )


# --- command line ---------------------------------------------------------------------------


def main_replay(
    log_path: Path,
    plot: Path | None = None,
    summary: bool = False,
    recover: Path | None = None,
    compare: bool = True,
    progress: bool = True,
    summary_json: Path | None = None,
) -> int:
    """What `haptic-replay` does: 0 if the replay reproduces the log (or none was asked),
    1 if anything differs."""
    if recover is not None:
        counts = recover_log(log_path, recover)
        print(
            f"recovered {counts['messages']} messages ({counts['ticks']} ticks) and "
            f"{counts['metadata']} metadata records into {recover} (indexed)"
        )
        log_path = recover
    log = read_log(log_path)
    code = 0
    if summary or summary_json:
        figures = summarise(log)
        if summary:
            print_summary(figures)
        if summary_json:
            summary_json.parent.mkdir(parents=True, exist_ok=True)
            summary_json.write_text(json.dumps(figures, indent=2))
    if compare:
        recorded = log.metadata.get("run", {}).get("source_hash")
        if recorded and recorded != source_hash():
            print(
                f"note: the log was recorded by another build (sources {recorded}, these are "
                f"{source_hash()}): differences may come from the code, not the run"
            )
        result = replay(log, progress=progress)
        print_comparison(result, len(log.ticks))
        code = 0 if result.identical else 1
    if plot is not None:
        print(f"plot: {plot_run(log, plot).resolve()}")
    return code


def serve_view(path: Path, address: ViewAddress, seconds: float | None, speed: float) -> None:
    """`--view`: draw the log in the browser until Ctrl-C (or for `seconds`)."""
    import signal
    import threading

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if seconds is not None:
        timer = threading.Timer(seconds, stop.set)
        timer.daemon = True  # a stop before it must not wait for it
        timer.start()
    try:
        frames = view_log(path, address, stop, speed)
    except EmptyLogError as exc:
        raise ReplayError(str(exc)) from None
    print(f"view: {frames} frames drawn; stopped")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-replay", description=__doc__)
    add_version(parser)
    parser.add_argument(
        "log",
        type=Path,
        help="MCAP log of a haptic run, a port world or a device check (haptic-device --log)",
    )
    parser.add_argument("--plot", type=Path, default=None, metavar="OUT.png")
    parser.add_argument("--summary", action="store_true", help="print the run's figures")
    parser.add_argument("--summary-json", type=Path, default=None, help="write them as JSON")
    parser.add_argument(
        "--recover", nargs="?", type=Path, const=Path("-"), default=None, metavar="OUT.mcap",
        help="rewrite a log cut short into a valid indexed file (default LOG.recovered.mcap)",
    )  # fmt: skip
    parser.add_argument("--no-replay", action="store_true", help="do not re-run and compare")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_view_args(parser, "the log (instead of replaying it)")
    parser.add_argument(
        "--view-seconds", type=seconds, default=None, metavar="S",
        help="with --view: serve the view this long, then exit (default: until Ctrl-C)",
    )  # fmt: skip
    parser.add_argument(
        "--view-speed", type=speed, default=0.0, metavar="X",
        help="with --view: draw at X times log time (default 0: all at once, then scrub)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    from haptic_local_model.shared.cli import run_main

    recover = args.recover
    if recover == Path("-"):
        recover = args.log.with_suffix(".recovered.mcap")
    if not args.log.is_file():
        print(f"haptic-replay: {args.log}: no such file", file=sys.stderr)
        return 2

    def body() -> int:
        from haptic_local_model.haptic_server.harness import device_doctor
        from haptic_local_model.haptic_server.world_runs import is_port_log, replay_main

        asked = [flag for flag, on in (("--plot", args.plot), ("--summary", args.summary),
                 ("--summary-json", args.summary_json), ("--recover", recover),
                 ("--no-replay", args.no_replay), ("--view", args.view)) if on]  # fmt: skip
        if device_doctor.is_bringup_log(args.log):  # `haptic-device check --log`: the check
            if asked:  # replayed against its readings
                raise ConfigError(str(args.log), asked[0], "not for a bring-up log (it "
                                  "replays the check, nothing else)")  # fmt: skip
            return device_doctor.replay_main(args.log)
        if is_port_log(args.log):  # a port world's log: its rows re-run bit for bit
            if asked:
                raise ConfigError(str(args.log), asked[0], "not for a port world's log (it "
                                  "replays bit for bit, nothing else yet)")  # fmt: skip
            return replay_main(args.log)
        view = view_address(args)
        code = main_replay(
            args.log, args.plot, args.summary, recover, not args.no_replay and view is None,
            not args.no_progress, args.summary_json,
        )  # fmt: skip
        if view is not None:
            serve_view(recover or args.log, view, args.view_seconds, args.view_speed)
        return code

    try:
        return run_main(body)
    except ReplayError as exc:
        print(f"haptic-replay: {args.log}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
