"""Loop timing on this machine, measured in one run, at each haptic rate asked for:

1. a bare loop that only waits for each deadline (the loop's own compiled wait: sleep, then
   spin) with the sim server running beside it: the limit of the machine at that rate;
2. the two-process system (haptic-run, real time) with logging on;
3. the same with logging off.

Reports the tick rate, lateness p50/p99/p99.9/max, late ticks (later than one period) and
work per tick for each, the targets (ticks delivered >= 99.9%, late ticks <= 2x the bare
loop's, work p99 <= 25% of the period with logging on), and
writes the figures as JSON. Machines are shared and noisy (on this VM the host steals the
vCPU now and then): the three runs are repeated `--repeat` times, interleaved, and the
targets are judged on the median of each figure over the repetitions. From the log of each
logging run it also splits work per tick into the ticks that installed an update and the rest.

With --view, also the system with its live view open in a headless Chromium (interleaved),
and for the logging runs the CPU each group of processes took and waited for
(`benchmarks/process_cpu.py`: the sim, the haptic server, the view, the Rerun server, the
browser, the rest of the machine), the watchdog trips and the view's level changes
(docs/live-view.md). HAPTIC_BENCH_KEEP_LOGS=DIR keeps each logging run's log there.

With --stations, instead: a shared world and its two stations (docs/stations.md:
haptic-router, haptic-world, two haptic-station processes) on loopback, for every shipped
port scene (grasp_clutter: two ports and 64 shapes), interleaved: each process's tick rate,
lateness and work per tick, the world's work p99 judged against 25 % of the period.

    python -m haptic_local_model.benchmarks.loop_timing [--rate 1000 4000 10000] [--seconds 20] [--repeat 3]
                                     [--scene testbed] [--user U] [--json out.json]
    python -m haptic_local_model.benchmarks.loop_timing --stations [--seconds 20] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.benchmarks.stations import loopback_run
from haptic_local_model.haptic_server.log import read_ticks
from haptic_local_model.haptic_server.view_address import ViewAddress
from haptic_local_model.shared.clock import monotonic_ns, wait_until_ns
from haptic_local_model.shared.port_config import shipped_station_scenes
from haptic_local_model.shared.timing import spin_for, try_realtime_priority


@njit(cache=True)
def _bare_ticks(n, period_ns, spin_ns, lateness_us):
    """Only wait for deadlines, with the loop's own compiled wait; lateness into the array."""
    ts = np.zeros(2, np.int64)
    deadline = monotonic_ns(ts) + period_ns
    for i in range(n):
        now = wait_until_ns(ts, deadline, spin_ns)
        lateness_us[i] = (now - deadline) / 1e3
        if now - deadline > period_ns:
            deadline = now
        deadline += period_ns


def bare_loop(seconds: float, period_ns: int = 1_000_000) -> dict[str, Any]:
    """Only wait for deadlines; lateness is all there is. Its tick rate is the ticks over the
    wall time they took: a late tick resynchronises (as the system's loop does), so a
    machine that stalls the bare loop delivers fewer ticks than nominal too."""
    n = int(seconds * 1e9 / period_ns)
    lateness = np.zeros(n)
    _bare_ticks(1, period_ns, spin_for(period_ns), lateness)  # loaded (numba's cache) first
    started = time.perf_counter_ns()
    _bare_ticks(n, period_ns, spin_for(period_ns), lateness)
    elapsed_ns = time.perf_counter_ns() - started
    return {
        "ticks": n,
        "lateness_us": _pct(lateness),
        "late_ticks_over_1ms": int((lateness > 1000).sum()),
        "overruns": int((lateness > period_ns / 1e3).sum()),
        "tick_rate_hz": n * 1e9 / elapsed_ns,
    }


def _pct(v: np.ndarray) -> dict[str, float]:
    return {
        "p50": float(np.percentile(v, 50)),
        "p99": float(np.percentile(v, 99)),
        "p99_9": float(np.percentile(v, 99.9)),
        "max": float(v.max()),
    }


def with_sim_beside(seconds: float, network: str, rate_hz: float = 1000.0) -> dict[str, Any]:
    """The bare loop (its own process, with the loop's real-time priority) while a sim server
    runs as another process: the same load and privileges as the system."""
    sim = subprocess.Popen(
        [sys.executable, "-m", "haptic_local_model.sim_server.cli", "--network", network],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        sim.stdout.readline()  # the "ready" line
        argv = [
            "-m",
            "haptic_local_model.benchmarks.loop_timing",
            "--bare-only",
            "--seconds",
            str(seconds),
        ]
        argv += ["--rate", str(rate_hz)]
        out = subprocess.run([sys.executable, *argv], check=True, capture_output=True, text=True)
        return json.loads(out.stdout)  # type: ignore[no-any-return]
    finally:
        os.kill(sim.pid, signal.SIGTERM)
        sim.wait(30)


def system(
    seconds: float,
    log: bool,
    network: str,
    scene: str,
    device: str,
    rate_hz: float,
    view: bool = False,
    user: str | None = None,
) -> dict[str, Any]:
    """One haptic-run; with `view`, its live view open in a headless browser throughout (if
    there is one: `benchmarks.browser`), and the view's own cost in `view`. The CPU each
    group of processes took per second (`benchmarks.process_cpu`) in `cpu_shares`."""
    with tempfile.TemporaryDirectory() as tmp:
        summary = Path(tmp) / "summary.json"
        log_path = Path(tmp) / "run.mcap"
        argv = [
            sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--duration", str(seconds),
            "--network", network, "--scene", scene, "--device", device,
            "--summary-json", str(summary), "--haptic-rate", str(rate_hz),
        ]  # fmt: skip
        argv += ["--log", str(log_path)] if log else ["--no-log"]
        argv += ["--user", user] if user else []
        if view:
            argv += ViewAddress("127.0.0.1", *VIEW_PORTS).argv()
            watched, shares = _run_watched(argv)
        else:
            proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL)
            shares = _sampled_until_done(proc)
        result: dict[str, Any] = json.loads(summary.read_text())
        result["cpu_shares"] = shares
        if KEEP_LOGS_ENV in os.environ and log:
            kept = Path(os.environ[KEEP_LOGS_ENV])
            kept.mkdir(parents=True, exist_ok=True)
            shutil.copy(log_path, kept / f"{'view' if view else 'plain'}-{time.time_ns()}.mcap")
        if log:
            result["work_split_us"] = work_split(read_ticks(log_path))
        if view:
            result["view"] = watched
        return result


KEEP_LOGS_ENV = "HAPTIC_BENCH_KEEP_LOGS"  # a directory: each logging run's log kept there
SCREENSHOT_ENV = "HAPTIC_BENCH_SCREENSHOT"  # a PNG: each view run's last frame written there
SHOT_SETTLE_S = 5.0  # the viewer, which lags the data on a machine without a GPU, catches up


def _sampled_until_done(proc: subprocess.Popen[Any], poll_s: float = 0.2) -> dict[str, float]:
    """Wait for a run, sampling every process's CPU while it runs; raise if it failed."""
    from haptic_local_model.benchmarks.process_cpu import CpuSampler

    sampler = CpuSampler().start()
    while proc.poll() is None:
        time.sleep(poll_s)
    shares = sampler.stop()
    if proc.wait() != 0:
        raise RuntimeError(f"haptic-run failed (exit {proc.returncode})")
    return shares


def _run_watched(argv: list[str]) -> tuple[dict[str, Any], dict[str, float]]:
    """Run haptic-run --view with a headless browser on its view while it runs; returns
    whether a browser watched and the view's own report, and the CPU per process group."""
    import threading

    from haptic_local_model.benchmarks.browser import chromium, open_page
    from haptic_local_model.benchmarks.process_cpu import CpuSampler

    sampler = CpuSampler().start()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    browser = chromium()
    watched = threading.Event()
    lines: list[str] = []
    watchers: list[threading.Thread] = []

    def watch(url: str) -> None:
        assert browser is not None
        with open_page(url, browser) as page:
            watched.set()
            proc.wait()
            shot = os.environ.get(SCREENSHOT_ENV)
            if shot:  # the viewer keeps the run's last frame after the run
                time.sleep(SHOT_SETTLE_S)
                Path(shot).parent.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=shot)

    assert proc.stderr is not None
    for line in proc.stderr:
        lines.append(line)
        if line.startswith("live view: http") and browser is not None:
            url = line.split("live view: ", 1)[1].strip()
            watcher = threading.Thread(target=watch, args=(url,), daemon=True)
            watcher.start()
            watchers.append(watcher)
    code = proc.wait()
    shares = sampler.stop()
    for watcher in watchers:  # its browser closed before the next run starts
        watcher.join(60)
    if code != 0:
        raise RuntimeError(f"haptic-run --view failed: {''.join(lines[-5:])}")
    return {"browser": watched.is_set(), "report": _view_report(lines)}, shares


VIEW_PORTS = (19090, 19876)  # the view's web and data ports in this benchmark


def _view_report(lines: list[str]) -> dict[str, Any]:
    """The view's own figures from its last line: frames, seconds, CPU ms per frame in the
    view process and in the Rerun server; and the levels it degraded to or restored
    (view_degrade.py), as it said them."""
    import re

    for line in reversed(lines):
        m = re.search(
            r"live view: (\d+) frames in ([\d.]+) s; CPU per frame ([\d.]+) ms here, "
            r"([\d.]+) ms in the Rerun server", line,
        )  # fmt: skip
        if m:
            frames, secs, here, server = (float(g) for g in m.groups())
            said = [
                line.split("live view: ", 1)[1].strip()
                for line in lines
                if "live view: view degraded" in line or "live view: view restored" in line
            ]
            return {"frames": frames, "seconds": secs, "cpu_ms_per_frame_view": here,
                    "cpu_ms_per_frame_rerun_server": server, "level_changes": said}  # fmt: skip
    return {}


def work_split(ticks: np.ndarray) -> dict[str, dict[str, float]]:
    """Work per tick on the ticks that installed an update and on the others (a row holds
    the work of the tick before it, and the seq of the newest installed update)."""
    work = ticks["work_us"][1:]
    seq = ticks["update_seq"]
    installed = seq[:-1] != np.concatenate(([-1], seq[:-2]))
    out = {}
    for name, mask in (("update_ticks", installed), ("other_ticks", ~installed)):
        v = work[mask]
        out[name] = {"n": int(v.size), **_pct(v)} if v.size else {"n": 0}
    return out


CONFIGS = ("bare_loop_with_sim", "system_log_on", "system_log_off")
VIEW_CONFIG = "system_log_on_view"


def median_of(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The median of each figure over repeated runs of one configuration."""
    out: dict[str, Any] = {"runs": len(runs)}
    for key in ("ticks", "tick_rate_hz", "late_ticks_over_1ms", "overruns"):
        out[key] = float(np.median([r[key] for r in runs]))
    out["realtime_priority"] = all(r["realtime_priority"] for r in runs)
    for key in ("lateness_us", "work_us"):
        if key in runs[0]:
            out[key] = {q: float(np.median([r[key][q] for r in runs])) for q in runs[0][key]}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--network", default="loopback")
    parser.add_argument("--scene", default="testbed")
    parser.add_argument("--device", default="ideal")
    parser.add_argument("--user", default=None, help="the haptic-run default if not given")
    parser.add_argument(
        "--rate", type=float, nargs="+", default=[1000.0], metavar="HZ",
        help="haptic rates to measure, each beside a bare loop at that rate (default 1000)",
    )  # fmt: skip
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repetitions")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--bare-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--view", action="store_true",
        help="also the system with its live view open in a headless browser (interleaved)",
    )  # fmt: skip
    parser.add_argument(
        "--screenshot", type=Path, default=None, metavar="PNG",
        help="with --view: the browser's view at the end of each view run, written here (the "
        "last run's stays; the README's docs/figures/live_view.png is made so)",
    )  # fmt: skip
    parser.add_argument(
        "--stations", action="store_true",
        help="instead: a shared world and two stations on loopback, every shipped port scene",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.stations:
        return stations_timing(args.seconds, args.repeat, args.json)
    configs = (*CONFIGS, VIEW_CONFIG) if args.view else CONFIGS
    if args.screenshot is not None:
        os.environ[SCREENSHOT_ENV] = str(args.screenshot.resolve())
    if args.bare_only:
        realtime = try_realtime_priority()
        period_ns = round(1e9 / args.rate[0])
        print(json.dumps({**bare_loop(args.seconds, period_ns), "realtime_priority": realtime}))
        return 0
    results: dict[str, Any] = {}
    for rate in args.rate:
        runs: dict[str, list[dict[str, Any]]] = {name: [] for name in configs}
        for _ in range(args.repeat):  # interleaved: slow spells of the host hit every config
            runs["bare_loop_with_sim"].append(with_sim_beside(args.seconds, args.network, rate))
            for name, log in (("system_log_on", True), ("system_log_off", False)):
                runs[name].append(
                    system(
                        args.seconds,
                        log,
                        args.network,
                        args.scene,
                        args.device,
                        rate,
                        user=args.user,
                    )
                )
            if args.view:
                runs[VIEW_CONFIG].append(
                    system(args.seconds, True, args.network, args.scene, args.device, rate, True)
                )
        medians = {name: median_of(rs) for name, rs in runs.items()}
        print(f"\n=== {rate:g} Hz: {args.scene}, {args.device}, {args.repeat} x {args.seconds:g} s")
        _print_table(runs, medians)
        _print_targets(medians, rate)
        if args.view:
            _print_view(runs, medians)
        results[f"{rate:g}"] = {"runs": runs, "medians": medians}
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


def stations_timing(seconds: float, repeat: int, out: Path | None) -> int:
    """The shared world and its two stations (docs/stations.md) on loopback, for every
    shipped scene they serve (grasp_clutter: 64 shapes; hand_grasp: two hands), `repeat` times interleaved: each
    process's tick rate, lateness and work per tick (the compiled tick and the Python around
    it: decoding, publishing), the world's judged against 25 % of the period."""
    scenes = shipped_station_scenes()  # hand_grasp too (one hand has no stations)
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in scenes}
    for _ in range(repeat):
        for scene in runs:
            with tempfile.TemporaryDirectory() as tmp:
                runs[scene].append(loopback_run(scene, seconds, Path(tmp)))
    columns = ("Hz p50", "min", "lat p99", "work p50", "p99", "p99.9", "max")
    print(f"\n=== shared world + 2 stations, loopback, {repeat} x {seconds:g} s")
    print(f"{'run':<34}" + "".join(f"{c:>10}" for c in columns))
    medians: dict[str, dict[str, float]] = {}
    for scene, rs in runs.items():
        for i, r in enumerate(rs):
            for who in ("world", "left", "right"):
                s = r[who]
                values = (s["tick_rate_hz"]["p50"], s["tick_rate_hz"]["min"], s["late_us"]["p99"],
                          s["work_us"]["p50"], s["work_us"]["p99"], s["work_us"]["p99_9"],
                          s["work_us"]["max"])  # fmt: skip
                print(f"{scene + ' #' + str(i + 1) + ' ' + who:<34}"
                      + "".join(f"{v:>10.1f}" for v in values))  # fmt: skip
        medians[scene] = {
            who: float(np.median([r[who]["work_us"]["p99"] for r in rs]))
            for who in ("world", "left", "right")
        }
        for i, r in enumerate(rs):  # a scene with a sim: the world's ticks that met it, apart
            if "sim" in r["world"]:
                a, b = (
                    r["world"]["sim"]["work_us_sim_ticks"],
                    r["world"]["sim"]["work_us_other_ticks"],
                )
                print(f"{scene} #{i + 1} world work, ticks that took or sent the sim's bodies: "
                      f"p50 {a['p50']:.0f} p99 {a['p99']:.0f} us; the others: p50 {b['p50']:.0f} "
                      f"p99 {b['p99']:.0f} us")  # fmt: skip
    budget = 0.25 * 1e6 / 1000.0
    for scene, m in medians.items():
        ok = "met" if m["world"] <= budget else "MISSED"
        print(f"{scene}: world work p99 {m['world']:.0f} us (median of {repeat}), budget "
              f"{budget:.0f} us: {ok}; stations {m['left']:.0f} / {m['right']:.0f} us")  # fmt: skip
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"runs": runs, "work_p99_medians_us": medians}, indent=2))
    return 0


def _print_table(runs: dict[str, list[dict[str, Any]]], medians: dict[str, Any]) -> None:
    columns = ("Hz", "lat p50", "p99", "p99.9", "max", ">period", "work p50", "p99", "max")
    print(f"{'run':<24}" + "".join(f"{c:>9}" for c in columns) + "  realtime")
    nan = float("nan")
    for name in runs:
        rows = [(f"{name} #{i + 1}", r) for i, r in enumerate(runs[name])]
        for label, r in [*rows, (f"{name} median", medians[name])]:
            lat = r["lateness_us"]
            work = r.get("work_us", {"p50": nan, "p99": nan, "max": nan})
            values = (
                r["tick_rate_hz"], lat["p50"], lat["p99"], lat["p99_9"], lat["max"],
                r["overruns"], work["p50"], work["p99"], work["max"],
            )  # fmt: skip
            print(
                f"{label:<24}"
                + "".join(f"{v:>9.1f}" for v in values)
                + f"  {r['realtime_priority']}"
            )


def _print_view(runs: dict[str, list[dict[str, Any]]], medians: dict[str, Any]) -> None:
    """Loop work and lateness with the view (and a browser) against without, and the view's
    own cost."""
    on, view = medians["system_log_on"], medians[VIEW_CONFIG]
    print(
        f"view on vs off (log on both): work p50 {view['work_us']['p50']:.1f} vs "
        f"{on['work_us']['p50']:.1f} us, p99 {view['work_us']['p99']:.1f} vs "
        f"{on['work_us']['p99']:.1f} us; lateness p99 {view['lateness_us']['p99']:.1f} vs "
        f"{on['lateness_us']['p99']:.1f} us; late ticks {view['overruns']:g} vs {on['overruns']:g}"
    )
    for name in ("system_log_on", VIEW_CONFIG):  # the sim starved by the browser shows here
        rs = runs[name]
        print(
            f"{name}: watchdog trips {[r.get('watchdog_trips') for r in rs]}, updates installed "
            f"{[r.get('updates_installed') for r in rs]}, world messages from the sim "
            f"{[(r.get('sim') or {}).get('view_messages') for r in rs]}"
        )
    for name in ("system_log_on", VIEW_CONFIG):
        groups = runs[name][0].get("cpu_shares") or {}
        shares = {g: np.median([r["cpu_shares"].get(g, 0.0) for r in runs[name]]) for g in groups}
        print(f"{name}: CPU s per s (median), " + ", ".join(
            f"{g} {v:.2f}" for g, v in sorted(shares.items(), key=lambda kv: -kv[1])
        ))  # fmt: skip
    reports = [r["view"]["report"] for r in runs[VIEW_CONFIG] if r["view"]["report"]]
    if reports:
        here = np.median([r["cpu_ms_per_frame_view"] for r in reports])
        server = np.median([r["cpu_ms_per_frame_rerun_server"] for r in reports])
        rate = np.median([r["frames"] / r["seconds"] for r in reports])
        browser = all(r["view"]["browser"] for r in runs[VIEW_CONFIG])
        print(
            f"view cost: {rate:.1f} frames/s; CPU per frame {here:.2f} ms in the view process, "
            f"{server:.2f} ms in the Rerun server (browser watching: {browser}); level "
            f"changes per run {[len(r.get('level_changes', [])) for r in reports]}"
        )


def _print_targets(medians: dict[str, Any], rate: float) -> None:
    """The issue's targets at this rate, on the medians."""
    bare, on = medians["bare_loop_with_sim"], medians["system_log_on"]
    delivered = on["tick_rate_hz"] / rate
    budget_us = 0.25 * 1e6 / rate
    bare_delivered = bare["tick_rate_hz"] / rate
    print(
        f"ticks delivered (log on): {100 * delivered:.2f}% of {rate:g} Hz (target >= 99.9%);"
        f" the bare loop beside the sim: {100 * bare_delivered:.2f}%"
    )
    print(
        f"late ticks (> one period): log on {on['overruns']:g}, bare loop {bare['overruns']:g}"
        f" (target <= 2x the bare loop's)"
    )
    print(f"work p99 with logging: {on['work_us']['p99']:.1f} us (target <= {budget_us:.0f} us)")


if __name__ == "__main__":
    sys.exit(main())
