"""`haptic-replay`: re-run the haptic side of a logged run, compare, summarise, plot, recover.

A replay rebuilds the scene, device and user from the config texts stored in the log and
drives the same `HapticEngine` the run used: each logged update's bytes are installed at the
tick they were received (rejected ones too, so every verdict is checked), with the latency
the loop installed them with; each tick uses the logged dt and the logged hand wrench, and
watchdog events switch the safe state at their tick. Every recomputed tick row is compared
with the logged one: the same build and configs give exactly zero difference.
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
from collections import defaultdict
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from haptic_server.engine import EngineCounters, HapticEngine
from haptic_server.log import LogContents, read_log, recover_log
from haptic_server.model import TICK_DTYPE
from haptic_server.stages.tick import store_row
from haptic_server.supervisor import Event, LoggedEvents, supervise
from shared import source_hash
from shared.config import SceneConfig, UserConfig, load_config_text
from shared.net.config import NetworkConfig
from shared.protocol.codes import Reason
from shared.protocol.codes import reason_tag as reason_of

PROGRESS_MIN_TICKS = 20_000  # show a progress bar on replays longer than 20 s at 1 kHz
PROGRESS_EVERY = 1000  # ticks between progress bar updates (keeps its cost negligible)
LATE_TICK_US = 1000.0  # a tick starting more than 1 ms after its deadline is late

#: Quantities the comparison reports first, in this order (all other fields follow).
FORCE_FIELDS = (
    "f_user", "f_contact", "f_impulse", "f_bias", "f_penalty", "f_coordination", "f_damping",
    "wrench_command", "wrench_applied", "contact_force_world", "hand_wrench_measured",
)  # fmt: skip
FORCE_SOURCES = (
    "f_user", "f_contact", "f_impulse", "f_bias", "f_penalty", "f_coordination", "f_damping",
)  # fmt: skip
TIMING_WINDOW_TICKS = 100  # the timing panel shows max and median per 100 ticks
PLOT_BULK_PERCENTILE = 99.5  # force axes show this much of every curve; spikes go beyond
POSE_FIELDS = ("device_pose", "device_twist", "vm_pose", "vm_twist", "proxy_q", "proxy_qd")


class ReplayError(RuntimeError):
    """The log cannot be replayed (no configs recorded, no ticks)."""


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


def engine_from_configs(configs: dict[str, str]) -> HapticEngine:
    """The engine a run used, from the config texts in its `configs` metadata record."""
    from device_models.registry import device_from_text

    missing = [k for k in ("scene", "device", "user") if not configs.get(k)]
    if missing:
        raise ReplayError(f"the log's configs metadata lacks {', '.join(missing)}")
    scene = load_config_text(SceneConfig, configs["scene"], "log:configs.scene")
    user = load_config_text(UserConfig, configs["user"], "log:configs.user")
    device = device_from_text(configs["device"], "log:configs.device")
    if configs.get("network"):  # real-time runs: the safe-state ramp comes from the network
        network = load_config_text(NetworkConfig, configs["network"], "log:configs.network")
        return HapticEngine(scene, device, user, network.safe_ramp_ms / 1000.0)
    return HapticEngine(scene, device, user)


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
        raise ReplayError("the log holds no ticks")
    engine = engine_from_configs(
        configs if configs is not None else log.metadata.get("configs", {})
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
    diffs = max_abs_differences(out, logged[:n])
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
    return engine.receive(raw, float(rec.get("latency_s", 0.0)))


def _progress_bar(total: int, enabled: bool) -> Any:
    if not enabled or total < PROGRESS_MIN_TICKS:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="tick", unit_scale=True, desc="replay", file=sys.stderr)


def max_abs_differences(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """Per field, the largest |a - b| over all rows; NaN in both counts as equal."""
    diffs: dict[str, float] = {}
    for name in TICK_DTYPE.names or ():
        x = a[name].astype(np.float64)
        y = b[name].astype(np.float64)
        d = np.abs(x - y)
        both_nan = np.isnan(x) & np.isnan(y)
        d = np.where(both_nan, 0.0, np.where(np.isnan(d), np.inf, d))
        diffs[name] = float(d.max()) if d.size else 0.0
    return diffs


# --- summary --------------------------------------------------------------------------------


def _pct(values: np.ndarray, *qs: float) -> dict[str, float]:
    if values.size == 0:
        return {**{f"p{q:g}".replace(".", "_"): float("nan") for q in qs}, "max": float("nan")}
    out = {f"p{q:g}".replace(".", "_"): float(np.percentile(values, q)) for q in qs}
    out["max"] = float(values.max())
    return out


def summarise(log: LogContents) -> dict[str, Any]:
    """The run's figures from its log: ticks, rates, timing, updates, watchdog, drift."""
    ticks = log.ticks
    run = log.metadata.get("run", {})
    configs = log.metadata.get("configs", {})
    n = len(ticks)
    duration = float(ticks["t"][-1] - ticks["t"][0] + ticks["dt"][-1]) if n else 0.0
    installed = [u for u in log.updates if u.get("installed")]
    rejected: dict[str, int] = defaultdict(int)
    for u in log.updates:
        if not u.get("installed"):
            rejected[u.get("reason") or "?"] += 1
    events: dict[str, int] = defaultdict(int)
    for ev in log.events:
        events[ev["kind"]] += 1
    ready = ticks[ticks["update_seq"] >= 0] if n else ticks
    drift_mm = np.hypot(*(ready["device_pose"][:, :2] - ready["vm_pose"][:, :2]).T) * 1e3
    ages = np.array([u["age_ms"] for u in log.updates if "age_ms" in u], dtype=np.float64)
    return {
        "clock": run.get("clock", "?"),
        "host": run.get("host", "?"),
        "version": run.get("version", "?"),
        "source_hash": run.get("source_hash", "?"),
        "start_time_utc": run.get("start_time_utc", "?"),
        "scene": _config_name(configs.get("scene")),
        "device": _config_name(configs.get("device"), "model"),
        "user": _config_name(configs.get("user")),
        "complete": log.indexed,
        "ticks": n,
        "duration_s": duration,
        "tick_rate_hz": n / duration if duration > 0 else 0.0,
        "lateness_us": _pct(ticks["lateness_us"], 50, 99, 99.9),
        "late_ticks_over_1ms": int((ticks["lateness_us"] > LATE_TICK_US).sum()),
        "work_us": _pct(ticks["work_us"], 50, 99, 99.9),
        "updates_received": len(log.updates),
        "updates_installed": len(installed),
        "updates_rejected": dict(rejected),
        "update_rate_hz": len(log.updates) / duration if duration > 0 else 0.0,
        "update_age_ms": _pct(ages[np.isfinite(ages)], 50, 99),
        "watchdog_trips": events.get("watchdog", 0),
        "events": dict(events),
        "drift_mm": _pct(drift_mm, 50, 99),
        "ticks_in_contact": int((ticks["n_active"] > 0).sum()) if n else 0,
        "fault_ticks": int((ticks["fault"] != 0).sum()) if n else 0,
    }


def _config_name(text: str | None, key: str = "name") -> str:
    import tomllib

    if not text:
        return "?"
    try:
        return str(tomllib.loads(text).get(key, "?"))
    except tomllib.TOMLDecodeError:
        return "?"


def print_summary(s: dict[str, Any]) -> None:
    lat, work, age, drift = s["lateness_us"], s["work_us"], s["update_age_ms"], s["drift_mm"]
    complete = "closed properly" if s["complete"] else "cut short (read by streaming)"
    print(f"run:           {s['scene']} / {s['device']} / {s['user']}, {s['clock']} clock")
    print(
        f"recorded:      {s['start_time_utc']} on {s['host']}, version {s['version']} "
        f"(sources {s['source_hash']})"
    )
    print(f"log:           {complete}")
    print(f"ticks:         {s['ticks']} in {s['duration_s']:.3f} s ({s['tick_rate_hz']:.1f} Hz)")
    print(
        f"lateness (us): p50 {lat['p50']:.1f}  p99 {lat['p99']:.1f}  p99.9 {lat['p99_9']:.1f}  "
        f"max {lat['max']:.1f};  late > 1 ms: {s['late_ticks_over_1ms']}"
    )
    print(
        f"work (us):     p50 {work['p50']:.1f}  p99 {work['p99']:.1f}  "
        f"p99.9 {work['p99_9']:.1f}  max {work['max']:.1f}"
    )
    print(
        f"updates:       {s['updates_received']} received ({s['update_rate_hz']:.1f} Hz), "
        f"{s['updates_installed']} installed, rejected {s['updates_rejected'] or 0}; "
        f"age p50 {age['p50']:.2f} ms  p99 {age['p99']:.2f} ms"
    )
    print(f"watchdog:      {s['watchdog_trips']} trips; events {s['events'] or {}}")
    print(
        f"drift (mm):    p50 {drift['p50']:.3f}  p99 {drift['p99']:.3f}  max {drift['max']:.3f};  "
        f"ticks in contact {s['ticks_in_contact']}, fault ticks {s['fault_ticks']}"
    )


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


# --- plot -----------------------------------------------------------------------------------


def plot_run(log: LogContents, out: Path | str, title: str = "") -> Path:
    """One figure of the run: trajectories (hand vs VM), forces by source, drift, timing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ticks = log.ticks
    if len(ticks) == 0:
        raise ReplayError("the log holds no ticks: nothing to plot")
    ready = ticks[ticks["update_seq"] >= 0]  # the VM exists once the first update arrived
    title = title or _default_title(log)
    if len(ready) == 0:
        ready = ticks
        title += " — no update was received"
    t = ready["t"]
    hand, vm = ready["device_pose"], ready["vm_pose"]
    fig, axes = plt.subplots(3, 2, figsize=(14, 12), constrained_layout=True)
    fig.suptitle(title)

    ax = axes[0, 0]
    ax.plot(hand[:, 0] * 1e3, hand[:, 1] * 1e3, lw=1.2, label="hand (device)")
    ax.plot(vm[:, 0] * 1e3, vm[:, 1] * 1e3, lw=1.0, ls="--", label="VM operational point")
    ax.plot(*(hand[0, :2] * 1e3), "ko", ms=4, label="start")
    ax.plot(*(hand[-1, :2] * 1e3), "ks", ms=4, label="end")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title="trajectories in the plane")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)

    ax = axes[0, 1]
    for c, name in enumerate(("x", "y")):
        line = ax.plot(t, hand[:, c] * 1e3, lw=1.2, label=f"hand {name}")[0]
        ax.plot(t, vm[:, c] * 1e3, lw=1.0, ls="--", color=line.get_color(), label=f"VM {name}")
    ax.set(xlabel="run time (s)", ylabel="position (mm)", title="hand vs VM over time")
    ax.legend(fontsize=8, ncol=2)

    ax = axes[1, 0]
    curves = {}
    for name in (*FORCE_SOURCES, "wrench_command"):
        mag = np.hypot(ready[name][:, 0], ready[name][:, 1])
        if np.any(mag):
            curves[name.removeprefix("f_").replace("wrench_", "")] = mag
    top = _robust_top(list(curves.values()))
    for label, mag in curves.items():
        style = {"color": "k", "lw": 1.4} if label == "command" else {"lw": 0.9}
        ax.plot(t, mag, label=_peak_label(label, mag, top, "N"), **style)
    ax.set_ylim(0.0, top)
    ax.set(xlabel="run time (s)", ylabel="|(fx, fy)| (N)", title="forces on the device by source")
    ax.legend(fontsize=8, ncol=2)

    ax = axes[1, 1]
    pushes = {}
    for c, name in enumerate(("fx", "fy")):
        pushes[f"hand {name}"] = ready["hand_wrench"][:, c]
        pushes[f"command {name}"] = ready["wrench_command"][:, c]
    top = _robust_top([np.abs(v) for v in pushes.values()])
    for i, (label, v) in enumerate(pushes.items()):
        ax.plot(t, v, lw=1.0, ls="-" if label.startswith("hand") else "--", color=f"C{i // 2}",
                label=_peak_label(label, np.abs(v), top, "N"))  # fmt: skip
    ax.set_ylim(-top, top)
    ax.set(xlabel="run time (s)", ylabel="force (N)", title="the user's push and what was rendered")
    ax.legend(fontsize=8, ncol=2)

    ax = axes[2, 0]
    drift = np.hypot(*(hand[:, :2] - vm[:, :2]).T) * 1e3
    ax.plot(t, drift, lw=1.0, color="C0", label="|x_h - x_VM| (mm)")
    ax.set(xlabel="run time (s)", ylabel="drift (mm)", title="drift and contact")
    contact = ready["n_active"] > 0
    if contact.any():
        ax.fill_between(t, 0, drift.max() * 1.05, where=contact, color="C2", alpha=0.15,
                        step="mid", label="in contact")  # fmt: skip
    twin = ax.twinx()
    twin.plot(t, np.abs(hand[:, 2] - vm[:, 2]), lw=0.8, color="C3", label="|θ_h - θ_VM| (rad)")
    twin.set_ylabel("angular drift (rad)", color="C3")
    ax.legend(loc="upper left", fontsize=8)
    twin.legend(loc="upper right", fontsize=8)

    ax = axes[2, 1]
    _plot_timing(ax, log)
    span = (float(ticks["t"][0]), float(ticks["t"][-1] + ticks["dt"][-1]))
    for ax in (axes[0, 1], axes[1, 0], axes[1, 1], axes[2, 0], axes[2, 1]):
        ax.set_xlim(*span)  # the same run time everywhere: no update yet shows as a gap
    out_path = Path(out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path


def _robust_top(curves: list[np.ndarray]) -> float:
    """An axis limit that shows the bulk of every curve: brief spikes (a collision impulse
    lasts one tick) are cut at it and their peak is given in the legend instead."""
    bulk = max((float(np.percentile(c, PLOT_BULK_PERCENTILE)) for c in curves), default=0.0)
    return 1.2 * bulk if bulk > 0 else 1.0


def _peak_label(label: str, values: np.ndarray, top: float, unit: str) -> str:
    peak = float(values.max())
    return f"{label} (peak {peak:.3g} {unit})" if peak > top else label


def _plot_timing(ax: Any, log: LogContents) -> None:
    ticks = log.ticks
    t = ticks["t"]
    lateness, work = ticks["lateness_us"], ticks["work_us"]
    ax.set(xlabel="run time (s)", title="timing per tick")
    if not np.any(lateness) and not np.any(work):
        ax.text(0.5, 0.5, "virtual clock: no wall-clock timing", ha="center", va="center",
                transform=ax.transAxes)  # fmt: skip
        return
    window = TIMING_WINDOW_TICKS
    n = len(t) // window * window
    if n == 0:
        window, n = 1, len(t)
    t_win = t[:n].reshape(-1, window)[:, 0]
    floor = 0.1  # us: the log axis starts here (a tick on time has lateness ~0)
    for values, color, name in ((lateness, "C0", "lateness"), (work, "C1", "work")):
        v = values[:n].reshape(-1, window)
        ax.plot(t_win, np.maximum(v.max(axis=1), floor), color=color, lw=1.0,
                label=f"{name}, max per {window} ticks")  # fmt: skip
        ax.plot(t_win, np.maximum(np.median(v, axis=1), floor), color=color, lw=0.8, ls=":",
                label=f"{name}, median per {window} ticks")  # fmt: skip
    late = lateness > LATE_TICK_US
    if late.any():
        ax.plot(t[late], lateness[late], "rx", ms=5, label=f"late > 1 ms ({late.sum()})")
    ax.axhline(LATE_TICK_US, color="r", lw=0.6, ls=":")
    tick_t = {int(k): float(v) for k, v in zip(ticks["tick"], t, strict=True)}
    trips = [tick_t[int(ev["tick"])] for ev in log.events
             if ev["kind"] == "watchdog" and int(ev["tick"]) in tick_t]  # fmt: skip
    for trip in trips:
        ax.axvline(trip, color="m", lw=0.8)
    if trips:
        ax.plot([], [], color="m", lw=0.8, label=f"watchdog trips ({len(trips)})")
    rejected = [tick_t[int(u["tick"])] for u in log.updates
                if not u.get("installed") and int(u["tick"]) in tick_t]  # fmt: skip
    if rejected:
        ax.plot(rejected, [floor * 2] * len(rejected), "k|", ms=10,
                label=f"rejected updates ({len(rejected)})")  # fmt: skip
    ax.set_yscale("log")
    ax.set_ylim(floor, 30.0 * max(float(lateness.max()), float(work.max()), LATE_TICK_US))
    ax.set_ylabel("µs")
    ax.legend(fontsize=8, loc="upper left", ncol=2)


def _default_title(log: LogContents) -> str:
    configs = log.metadata.get("configs", {})
    run = log.metadata.get("run", {})
    return (
        f"{_config_name(configs.get('scene'))} / {_config_name(configs.get('device'), 'model')} / "
        f"{_config_name(configs.get('user'))} — {run.get('clock', '?')} clock, "
        f"{run.get('start_time_utc', '')}"
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-replay", description=__doc__)
    parser.add_argument("log", type=Path, help="MCAP log of a haptic run")
    parser.add_argument("--plot", type=Path, default=None, metavar="OUT.png")
    parser.add_argument("--summary", action="store_true", help="print the run's figures")
    parser.add_argument("--summary-json", type=Path, default=None, help="write them as JSON")
    parser.add_argument(
        "--recover", nargs="?", type=Path, const=Path("-"), default=None, metavar="OUT.mcap",
        help="rewrite a log cut short into a valid indexed file (default LOG.recovered.mcap)",
    )  # fmt: skip
    parser.add_argument("--no-replay", action="store_true", help="do not re-run and compare")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    from shared.cli import run_main

    recover = args.recover
    if recover == Path("-"):
        recover = args.log.with_suffix(".recovered.mcap")
    if not args.log.is_file():
        print(f"haptic-replay: {args.log}: no such file", file=sys.stderr)
        return 2

    def body() -> int:
        return main_replay(
            args.log, args.plot, args.summary, recover, not args.no_replay,
            not args.no_progress, args.summary_json,
        )  # fmt: skip

    try:
        return run_main(body)
    except ReplayError as exc:
        print(f"haptic-replay: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
