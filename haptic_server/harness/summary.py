"""The figures of a logged run (`haptic-replay --summary`): rates, timing, updates, watchdog,
drift; the same as `haptic-run` prints for a live run."""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.log import LogContents


class ReplayError(RuntimeError):
    """The log cannot be replayed (no configs recorded, no ticks)."""


LATE_TICK_US = 1000.0  # a tick starting more than 1 ms after its deadline is late


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
    # one name per figure, as in haptic-run's summary: the age is publish -> installed (the
    # latency each update was installed with), the transit publish -> received
    ages = np.array([u.get("latency_s", np.nan) * 1e3 for u in installed], dtype=np.float64)
    transits = np.array([u.get("age_ms", np.nan) for u in log.updates], dtype=np.float64)
    return {
        "clock": run.get("clock", "?"),
        "host": run.get("host", "?"),
        "version": run.get("version", "?"),
        "source_hash": run.get("source_hash", "?"),
        "start_time_utc": run.get("start_time_utc", "?"),
        "scene": config_name(configs.get("scene")),
        "device": config_name(configs.get("device"), "model"),
        "user": config_name(configs.get("user")),
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
        "update_transit_ms": _pct(transits[np.isfinite(transits)], 50, 99),
        "watchdog_trips": events.get("watchdog", 0),
        "events": dict(events),
        "drift_mm": _pct(drift_mm, 50, 99),
        "ticks_in_contact": int((ticks["n_active"] > 0).sum()) if n else 0,
        "fault_ticks": int((ticks["fault"] != 0).sum()) if n else 0,
    }


def config_name(text: str | None, key: str = "name") -> str:
    import tomllib

    if not text:
        return "?"
    try:
        return str(tomllib.loads(text).get(key, "?"))
    except tomllib.TOMLDecodeError:
        return "?"


def print_summary(s: dict[str, Any]) -> None:
    lat, work, age, drift = s["lateness_us"], s["work_us"], s["update_age_ms"], s["drift_mm"]
    transit = s["update_transit_ms"]
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
        f"age (publish -> installed) p50 {age['p50']:.2f} ms  p99 {age['p99']:.2f} ms, "
        f"transit (publish -> received) p50 {transit['p50']:.2f} ms  p99 {transit['p99']:.2f} ms"
    )
    print(f"watchdog:      {s['watchdog_trips']} trips; events {s['events'] or {}}")
    print(
        f"drift (mm):    p50 {drift['p50']:.3f}  p99 {drift['p99']:.3f}  max {drift['max']:.3f};  "
        f"ticks in contact {s['ticks_in_contact']}, fault ticks {s['fault_ticks']}"
    )
