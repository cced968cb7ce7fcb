"""The shared world and two stations over bad links (issue 46's baseline): the three-namespace
set-up of benchmarks/stations.py with each station's link through the impairment forwarder
(benchmarks/impair.py: one-way delay D ± jitter, loss L, each direction), `grasp_vertical`
for `--seconds` a point, swept over `--delays-ms` × `--losses`. Per point, from the
processes' own logs and summaries:

- each port's energy out (J): the most work its command has done on its device so far,
  max over t of ∫0^t out · twist dt (a passive coupling gives back no more than it stored);
- each port's force above 5 Hz: the RMS (N) of its command's x-y force in the band above
  5 Hz, and that over the same at the unimpaired point (the 0 ms, no-loss run);
- the box: how far it sank below its start at worst and how far it ended from it (mm);
- each station's watchdog trips (safe entries) and tool states refused;
- each station's share of its ticks at the full coupling from the first it rendered (a box
  thrown out of range leaves the stations safe: its figures after that are of no coupling);
- the stall distribution of ToolStates at each station: the time between ticks that took a
  new one (p50/p99/max, ms; 1 ms is every tick) and the age, since it arrived, of the one
  rendered; the share of its ticks at the full coupling.

Needs root (network namespaces, TUN devices); everything it creates is removed and every
process it starts stopped by its pid, however it ends.

    sudo .venv/bin/python -m haptic_local_model.benchmarks.station_links \
        [--delays-ms 0 10 50] [--losses 0 0.05] [--jitter 0.2] [--seconds 15] \
        [--network stations_three_hosts] [--passivity tdpa off] [--local-model on off] \
        [--press] [--json out.json] [--md out.md]

`--passivity tdpa off` runs each point with the port links' passivity controllers and
without (the observers only), one after the other (the machine is shared); `--local-model
on off` likewise with the stations' local model and without. `--press`: the stations'
users press their pads into the box and release three times (PRESS_USERS), each station's
felt stiffness is fitted (felt_stiffness), and its drift from the world is measured
(registration, drift: the world's log is kept for it).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.impair import Impairment
from haptic_local_model.benchmarks.stations import (
    CLI,
    PORTS,
    STOP_S,
    ThreeHosts,
    netns_unavailable,
    station_rows,
)
from haptic_local_model.haptic_server.stages.station import STATION_DTYPE, pad_depth
from haptic_local_model.haptic_server.station_records import EXTRAPOLATE_S, local_geometry
from haptic_local_model.haptic_server.world_runs import read_port_log
from haptic_local_model.shared.port_config import load_port_scene

#: --press: each station's user presses its pad into the box and releases, three times
#: (their ramps' times: configs/users/press_*_ramp.toml), the felt stiffness fitted over the
#: first press (PRESS_S), the drift measured at rest before it and after each release (REST_S)
PRESS_USERS = {"left": "press_left_ramp", "right": "press_right_ramp"}
PRESS_S = (5.0, 12.0)
REST_S = ((4.0, 5.0), (12.5, 13.0), (20.5, 21.0), (28.9, 29.9))
BAND_HZ = 5.0  # the force spectrum is summed above this (a grip's own motion is slower)
SETTLE_S = 1.0  # the spectrum leaves out the first second the station renders (it joins)
SUMMARY_WAIT_S = 2.0
FELL_MM = 100.0  # a box this far from its start has left the grip (the pads are 60 mm tall)  # for the forwarder's last line after it stopped


def energy_out_j(rows: np.ndarray) -> float:
    """The most work the port's command has done on its device up to any tick (J):
    max over t of ∫0^t out · twist dt, the rectangle rule on the tick's own period."""
    dt = np.diff(rows["t"], prepend=rows["t"][0])
    work = np.cumsum((rows["out"] * rows["twist"]).sum(axis=1) * dt)
    return float(max(0.0, work.max())) if len(work) else 0.0


def rms_above(x: np.ndarray, dt_s: float, band_hz: float) -> float:
    """The RMS of x's (n, k) columns in the band above band_hz, by Parseval over the real
    FFT of each (mean removed): sqrt(2/n² Σ_{f > band} |X(f)|²), summed over the columns."""
    n = len(x)
    if n < 2:
        return 0.0
    spec = np.fft.rfft(x - x.mean(axis=0), axis=0)
    f = np.fft.rfftfreq(n, dt_s)
    return float(np.sqrt(2.0 / n**2 * (np.abs(spec[f > band_hz]) ** 2).sum()))


def stalls_ms(rows: np.ndarray) -> np.ndarray:
    """The times (ms, the loop's clock) between the ticks that took a new ToolState."""
    took = np.flatnonzero(np.diff(rows["received"]) > 0) + 1
    return np.diff(rows["wall_ns"][took]) / 1e6


def percentiles(x: np.ndarray) -> dict[str, float]:
    if len(x) == 0:
        return {"p50": float("nan"), "p99": float("nan"), "max": float("nan")}
    p50, p99 = np.percentile(x, [50, 99])
    return {"p50": float(p50), "p99": float(p99), "max": float(x.max())}


def port_figures(rows: np.ndarray, summary: dict[str, Any]) -> dict[str, Any]:
    """One station's figures (module docstring)."""
    fresh = np.flatnonzero(rows["fresh"] == 1)
    start = int(fresh[0]) if len(fresh) else len(rows)
    dt = float(np.median(np.diff(rows["t"]))) if len(rows) > 1 else 1e-3
    band = rows["out"][start + round(SETTLE_S / dt) :, :2]
    return {
        "energy_out_j": energy_out_j(rows),
        "rms_above_5hz_n": rms_above(band, dt, BAND_HZ),
        "stall_ms": percentiles(stalls_ms(rows)),
        # since the tool state arrived (the station's extrapolation horizon), not since sent
        "tool_age_ms": percentiles(rows["tool_age"][fresh] * 1e3),
        # of its ticks from the first it rendered: those at the full coupling
        "coupled_fraction": float(((rows["fresh"] == 1) & (rows["gain"] == 1.0))[start:].mean())
        if start < len(rows)
        else 0.0,
        "watchdog_trips": summary["safe_entries"],
        "tool_states_received": summary["tool_states_received"],
        "tool_states_rejected": summary["tool_states_rejected"],
        "ticks": summary["ticks"],
    }


def pad_depths(rows: np.ndarray, geometry: tuple) -> np.ndarray:
    """Each row's device pad into the object as the tool state carried it (m, 0 apart): the
    station's own geometry (stages/station.py pad_depth, the pad's and the object's half
    extents `geometry`), the object carried on by its twist for the tool state's age up to
    EXTRAPOLATE_S, as the station renders it (with its local model on or off)."""
    st = np.zeros(1, STATION_DTYPE)
    s = st[0]
    s["pad_half"], s["object_half"] = geometry[0], geometry[1]
    depth = np.zeros(len(rows))
    for k, row in enumerate(rows):
        s["object_pose"], s["object_twist"] = row["object_pose"], row["object_twist"]
        x, y, a = row["pose"]
        depth[k] = pad_depth(s, x, y, a, min(float(row["tool_age"]), EXTRAPOLATE_S))
    return depth


def felt_stiffness(rows: np.ndarray, geometry: tuple) -> dict[str, float]:
    """The stiffness the station rendered while its user pressed (PRESS_S): the least-squares
    line through the origin (N/m: no depth, no force) of the coupling's force along x (its
    magnitude, at the full coupling) against the device's penetration into the object as
    the world last sent it (pad_depths), on the ticks where it is positive; the force's range
    over them (N); and, for comparison, the slope of the line with an intercept
    (`fit_slope_n_per_m`, the figure before 2026-12-01).

    The slope with an intercept was the stiffness of the press's hysteresis loop, not of the
    contact: the two stations start their users' timelines when each starts, up to 2 s
    apart on a loaded 2-core machine, so one user's press pushes the box into the other's
    pad out of phase with the other's own press. In four unimpaired runs on one machine it
    gave 1329 to 2552 N/m at the two ports of one run (the local spring k_s is 1875 N/m) and
    0.77 of the unimpaired run's at 50 ms in a CI run; the line through the origin gave 1816
    to 1931 N/m over the same runs."""
    t = rows["t"]
    sel = (t >= PRESS_S[0]) & (t <= PRESS_S[1]) & (rows["fresh"] == 1) & (rows["gain"] == 1.0)
    depth = np.zeros(len(rows))
    depth[sel] = pad_depths(rows[sel], geometry)
    sel &= depth > 0.0
    if sel.sum() < 100:
        return {"n_per_m": float("nan"), "force_min_n": float("nan"),
                "force_max_n": float("nan"), "ticks": int(sel.sum()),
                "fit_slope_n_per_m": float("nan")}  # fmt: skip
    force, d = np.abs(rows["coupling"][sel, 0]), depth[sel]
    return {"n_per_m": float(force @ d / (d @ d)), "force_min_n": float(force.min()),
            "force_max_n": float(force.max()), "ticks": int(sel.sum()),
            "fit_slope_n_per_m": float(np.polyfit(d, force, 1)[0])}  # fmt: skip


def registration(
    station: np.ndarray, world: np.ndarray, world_start_ns: int, p: int, window: tuple
) -> np.ndarray:
    """Where the world has port p's device less where the device is, over `window` (s of the
    station's clock), x, y (mm) and angle (mrad), the median over the station's ticks in it:
    the pose the world fed the port's tool (its row's device_pose: the last DeviceState it
    took, re-indexed and carried on) less the station's own reading (its row's pose) at the
    same instant of the host's monotonic clock (the world's row nearest it, at world_start_ns
    + its t; the station's at its wall_ns). In motion it holds the link's lag (the twist times the
    delay); at rest only the registration the world took when it indexed the port, so a
    change between two rests is the two ends walking apart: a re-index (the world's offset),
    a DeviceState the world never got, a bias in its carry-on. NaNs if the window has no
    ticks, or none the world's rows cover."""
    t = station["t"]
    sel = (t >= window[0]) & (t < window[1])
    at = (station["wall_ns"][sel] - world_start_ns) / 1e9
    wt = world["t"]
    k = np.clip(np.searchsorted(wt, at), 1, max(1, len(wt) - 1))
    k -= (at - wt[k - 1]) < (wt[np.minimum(k, len(wt) - 1)] - at)  # the nearest row
    ok = (at >= wt[0]) & (at <= wt[-1] + 0.5 * (wt[-1] - wt[-2] if len(wt) > 1 else 0.0))
    if len(wt) < 2 or not ok.any():
        return np.full(3, np.nan)
    e = world["device_pose"][k[ok], p, :] - station["pose"][sel][ok]
    e[:, 2] = np.arctan2(np.sin(e[:, 2]), np.cos(e[:, 2]))
    return np.median(e, axis=0) * 1e3


def drift(station: np.ndarray, world: np.ndarray, world_start_ns: int, p: int) -> dict[str, Any]:
    """Port p's drift from the world: its registration (registration) at each rest of REST_S
    the station's run reached, and how far each later one is from the first, before the
    first press (x-y, mm; angle, mrad); `drift_mm` is the last rest's (after every release)."""
    end = float(station["t"][-1]) if len(station) else 0.0
    rests = [w for w in REST_S if w[1] <= end + 1e-3]
    regs = [registration(station, world, world_start_ns, p, w) for w in rests]
    apart = [float(np.hypot(*(r - regs[0])[:2])) for r in regs[1:]]
    turned = [float(abs(r[2] - regs[0][2])) for r in regs[1:]]
    return {
        "rests_s": [list(w) for w in rests],
        "registration": [r.tolist() for r in regs],
        "apart_mm": apart,
        "apart_mrad": turned,
        "drift_mm": apart[-1] if apart else float("nan"),
    }


def run(
    seconds: float,
    imp: Impairment,
    folder: Path,
    network: str,
    passivity: str = "tdpa",
    local_model: str = "on",
    press: bool = False,
) -> dict[str, Any]:
    """`grasp_vertical` at two stations, each link through `imp`, for `seconds`, the links'
    passivity controllers `passivity` ("tdpa" or "off"), the stations' local model
    `local_model` ("on" or "off"); with `press` their users press into the box and release
    (PRESS_USERS): its figures (module docstring)."""
    with ThreeHosts(impair=dict.fromkeys(PORTS, imp)) as h:
        net = ["--network", network]
        roles = [*net, "--passivity", passivity]
        h.start(h.world_ns, [*CLI, "router", *net]).wait_ready()
        world_json = folder / "world.json"
        world_log = ["--log", str(folder / "world.mcap")] if press else []
        world = h.start(h.world_ns, [*CLI, "world", *roles, "--duration", str(seconds + 6.0),
                                     "--json", str(world_json), *world_log])  # fmt: skip
        world.wait_ready()
        stations = {}
        for p in PORTS:
            args = ["--port", p, "--duration", str(seconds), "--log", str(folder / f"{p}.mcap"),
                    "--json", str(folder / f"{p}.json"), "--local-model", local_model,
                    *(["--user", PRESS_USERS[p]] if press else [])]  # fmt: skip
            stations[p] = h.start(h.station_ns[p], [*CLI, "station", *roles, *args])
        for s in stations.values():
            s.wait_ready()
        codes = {p: s.proc.wait(seconds + STOP_S) for p, s in stations.items()}
        codes["world"] = world.proc.wait(STOP_S + 10.0)
    end = time.monotonic() + SUMMARY_WAIT_S
    while time.monotonic() < end and not all(f.events[-1:] for f in h.forwarders.values()):
        time.sleep(0.05)
    figures: dict[str, Any] = {"exit_codes": codes, "left_over": h.leftovers(),
                               "passivity": passivity, "local_model": local_model,
                               "press": press}  # fmt: skip
    figures["impairment"] = {"delay_ms": imp.delay_s * 1e3, "jitter_ms": imp.jitter_s * 1e3,
                             "loss": imp.loss, "reorder": imp.reorder}  # fmt: skip
    scene = load_port_scene("grasp_vertical")
    world_summary = json.loads(world_json.read_text())
    world_rows = read_port_log(folder / "world.mcap")[0] if press else None
    for i, p in enumerate(PORTS):
        summary = json.loads((folder / f"{p}.json").read_text())
        rows = station_rows(folder / f"{p}.mcap")
        figures[p] = port_figures(rows, summary)
        geometry = local_geometry(scene, i)
        if press and geometry is not None:
            figures[p]["felt"] = felt_stiffness(rows, geometry)
        if world_rows is not None:
            figures[p]["drift"] = drift(rows, world_rows, world_summary["started_ns"], i)
        last = h.forwarders[p].events[-1:]
        figures[p]["link"] = last[0].get("counts") if last else None
    figures["world_ticks_skipped"] = world_summary["ticks_skipped"]  # its rows' t lag by these
    box = world_summary["bodies"]["box"]
    figures["box_sank_mm"] = float(box["start"][1] - box["lowest_y"]) * 1e3
    figures["box_moved_mm"] = float(np.hypot(*np.subtract(box["end"][:2], box["start"][:2]))) * 1e3
    return figures


def box_text(mm: float) -> str:
    """A box's sag or drift in mm; `fell` once it is more than FELL_MM (out of the grip)."""
    return "fell" if mm > FELL_MM else f"{mm:.1f}"


def felt_text(ports: list[dict[str, Any]]) -> str:
    """Each station's felt stiffness (a press run's), or a dash."""
    if not all("felt" in f for f in ports):
        return "–"
    return " / ".join(f"{f['felt']['n_per_m']:.0f}" for f in ports)


def drift_text(ports: list[dict[str, Any]]) -> str:
    """Each station's drift from the world after the last release (mm), or a dash."""
    if not all("drift" in f for f in ports):
        return "–"
    return " / ".join(f"{f['drift']['drift_mm']:.2f}" for f in ports)


def unimpaired(points: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The sweep's point at 0 ms and no loss (the first, with the controllers if both ran),
    if it has one."""
    return next((p for p in points if p["impairment"]["delay_ms"] == 0.0
                 and p["impairment"]["loss"] == 0.0), None)  # fmt: skip


def report(
    points: list[dict[str, Any]], seconds: float, command: str, base: dict[str, Any] | None
) -> str:
    """The sweep as a Markdown table; the force above 5 Hz over the `base` point's (the
    unimpaired run)."""
    lines = [
        f"`{command}` ({seconds:g} s a point, `grasp_vertical`, maglevs at both stations; the "
        "machine's 2 cores shared with other work). Per station: left / right.",
        "",
        "| one-way ms | jitter ms | loss | PC | local model | energy out J | >5 Hz RMS N "
        "| ×0 ms | box sank / moved mm | coupled | watchdog trips "
        "| ToolState gap ms p50 / p99 / max | age since arrival ms p50 / p99 "
        "| felt stiffness N/m | drift mm |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for pt in points:
        imp, lr = pt["impairment"], [pt[p] for p in PORTS]
        ratio = [
            f["rms_above_5hz_n"] / b["rms_above_5hz_n"] if base else float("nan")
            for f, b in zip(lr, [base[p] for p in PORTS] if base else lr, strict=True)
        ]
        gap = " ; ".join(f"{f['stall_ms']['p50']:.0f} / {f['stall_ms']['p99']:.0f} / "
                         f"{f['stall_ms']['max']:.0f}" for f in lr)  # fmt: skip
        age = " ; ".join(
            f"{f['tool_age_ms']['p50']:.1f} / {f['tool_age_ms']['p99']:.1f}" for f in lr
        )
        lines.append(
            f"| {imp['delay_ms']:g} | {imp['jitter_ms']:g} | {imp['loss']:.0%} "
            f"| {pt.get('passivity', 'off')} | {pt.get('local_model', 'off')} "
            f"| {lr[0]['energy_out_j']:.3f} / {lr[1]['energy_out_j']:.3f} "
            f"| {lr[0]['rms_above_5hz_n']:.3f} / {lr[1]['rms_above_5hz_n']:.3f} "
            f"| {ratio[0]:.1f} / {ratio[1]:.1f} "
            f"| {box_text(pt['box_sank_mm'])} / {box_text(pt['box_moved_mm'])} "
            f"| {lr[0]['coupled_fraction']:.0%} / {lr[1]['coupled_fraction']:.0%} "
            f"| {lr[0]['watchdog_trips']} / {lr[1]['watchdog_trips']} | {gap} | {age} "
            f"| {felt_text(lr)} | {drift_text(lr)} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--delays-ms", type=float, nargs="+", default=[0.0, 10.0, 50.0])
    ap.add_argument("--losses", type=float, nargs="+", default=[0.0, 0.05])
    ap.add_argument("--jitter", type=float, default=0.2, help="jitter as a fraction of the delay")
    ap.add_argument("--seconds", type=float, default=15.0, help="the stations' run a point (s)")
    ap.add_argument("--network", default="stations_three_hosts", help="in configs/network")
    ap.add_argument(
        "--passivity",
        nargs="+",
        default=["tdpa"],
        choices=["tdpa", "off"],
        help="the links' passivity controllers; both: each point with and without",
    )
    ap.add_argument(
        "--local-model",
        nargs="+",
        default=["on"],
        choices=["on", "off"],
        help="the stations' local model; both: each point with and without",
    )
    ap.add_argument("--press", action="store_true",
                    help="the users press into the box and release: the felt stiffness, the drift")  # fmt: skip
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    ap.add_argument("--md", type=Path, default=None, help="write the report's table here")
    ap.add_argument("--base", type=Path, default=None,
                    help="a sweep's JSON whose 0 ms, no-loss point the force above 5 Hz is "
                         "compared with (default: this sweep's)")  # fmt: skip
    args = ap.parse_args(argv)
    reason = netns_unavailable()
    if reason:
        print(f"station links benchmark: {reason}", file=sys.stderr)
        return 2
    points = []
    for loss in args.losses:
        for d in args.delays_ms:
            imp = Impairment(d / 1e3, args.jitter * d / 1e3, loss)
            for passivity, local in product(args.passivity, args.local_model):  # interleaved
                with tempfile.TemporaryDirectory() as tmp:
                    points.append(run(args.seconds, imp, Path(tmp), args.network, passivity,
                                      local, args.press))  # fmt: skip
                print(json.dumps(points[-1]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(points, indent=2))
    command = "python -m haptic_local_model.benchmarks.station_links " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    base = unimpaired(json.loads(args.base.read_text()) if args.base else points)
    text = report(points, args.seconds, command.strip(), base)
    print(text)
    if args.md:
        args.md.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
