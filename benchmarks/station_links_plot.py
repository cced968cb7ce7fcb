"""The plot of the station-link sweeps (benchmarks/station_links.py's JSON files) against
issue 46's targets, one line per configuration: each port's energy out (J, ≤ 0.05), its force
above 5 Hz over the unimpaired run's (≤ 3×), how far the box ended from its start (mm, ≤ 2;
"fell" drawn at the top) and, for a press sweep, the felt stiffness over the 0 ms run's
(≥ 80 % at 50 ms, ≥ 50 % at 150 ms) and the station's drift from the world after the last
release (mm, ≤ 1), each against the one-way delay.

    python -m haptic_local_model.benchmarks.station_links_plot SWEEP.json [SWEEP.json ...] \\
        --out docs/bench/station_links.png [--base BASE.json]

A configuration is a file's points of one loss, passivity controller and local model; its
ratios are over the same configuration's 0 ms, no-loss point where it has one, else over
--base's (the first file's unimpaired point if no --base is given). Every point plotted is
one run (the sweeps run each once).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from haptic_local_model.benchmarks.station_links import FELL_MM, unimpaired
from haptic_local_model.benchmarks.stations import PORTS

ENERGY_MAX_J = 0.05  # issue 46: energy out of every port over the run
RATIO_MAX = 3.0  # force above 5 Hz within 3x the unimpaired run's
DRIFT_MAX_MM = 2.0  # the box held
FELT_MIN = {50.0: 0.8, 150.0: 0.5}  # the felt stiffness's share of the 0 ms run's
STATION_DRIFT_MAX_MM = 1.0  # a station and the world apart after pressing and releasing
ENERGY_FLOOR_J = 1e-4  # 0 J drawn here on the log axis
DRIFT_FLOOR_MM = 1e-3  # a drift below a micrometre drawn here
FELL_AT_MM = 200.0  # a box that fell, drawn here


def config_label(stem: str, point: dict[str, Any]) -> str:
    """The configuration a point belongs to, as its line's label."""
    imp = point["impairment"]
    return (f"{stem}: {imp['loss']:.0%} loss, PC {point.get('passivity', 'off')}, local "
            f"model {point.get('local_model', 'off')}")  # fmt: skip


def series(sweeps: dict[str, list[dict[str, Any]]], base: dict[str, Any] | None) -> dict:
    """Per configuration, its points by one-way delay: {label: {"delay_ms": [...],
    "energy_j": [...], "ratio": [...], "moved_mm": [...], "felt": [...], "drift_mm": [...]}};
    each port's figure is the worse of the two (the larger energy, ratio and drift, the
    smaller felt stiffness share)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for stem, points in sweeps.items():
        for p in points:
            groups.setdefault(config_label(stem, p), []).append(p)
    out: dict[str, dict[str, list[float]]] = {}
    for label, points in groups.items():
        points.sort(key=lambda p: p["impairment"]["delay_ms"])
        ref = next((p for p in points if p["impairment"]["delay_ms"] == 0.0), None)
        rms_ref = unimpaired(points) or base
        s: dict[str, list[float]] = {k: [] for k in ("delay_ms", "energy_j", "ratio",
                                                     "moved_mm", "felt", "drift_mm")}  # fmt: skip
        for p in points:
            ports = [p[name] for name in PORTS]
            s["delay_ms"].append(p["impairment"]["delay_ms"])
            s["energy_j"].append(max(f["energy_out_j"] for f in ports))
            s["ratio"].append(
                max(f["rms_above_5hz_n"] / rms_ref[n]["rms_above_5hz_n"]
                    for f, n in zip(ports, PORTS, strict=True)) if rms_ref else math.nan
            )  # fmt: skip
            s["moved_mm"].append(p["box_moved_mm"])
            s["felt"].append(_felt_share(ports, ref))
            s["drift_mm"].append(
                max(f["drift"]["drift_mm"] for f in ports)
                if all("drift" in f for f in ports) else math.nan
            )  # fmt: skip
        out[label] = s
    return out


def _felt_share(ports: list[dict[str, Any]], ref: dict[str, Any] | None) -> float:
    """The smaller of the ports' felt stiffness over the reference run's (NaN where a press
    was not run or the fit had no contact)."""
    if ref is None or not all("felt" in f for f in ports):
        return math.nan
    shares = [f["felt"]["n_per_m"] / ref[n]["felt"]["n_per_m"]
              for f, n in zip(ports, PORTS, strict=True)]  # fmt: skip
    return min(shares)


def plot(data: dict[str, dict[str, list[float]]], out: Path) -> None:
    """The five panels, targets dashed, into `out` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(17, 10), sharex=True)
    colours = plt.get_cmap("tab20").colors
    panels = (
        ("energy_j", "energy out of the worse port (J)", ENERGY_MAX_J, "log"),
        ("ratio", "force above 5 Hz / the unimpaired run's", RATIO_MAX, "log"),
        ("moved_mm", "box's distance from its start at the end (mm)", DRIFT_MAX_MM, "log"),
        ("felt", "felt stiffness / 0 ms (press sweeps)", None, "linear"),
        ("drift_mm", "station-world drift after the last release (mm, press sweeps)",
         STATION_DRIFT_MAX_MM, "log"),
    )  # fmt: skip
    axes.flat[-1].axis("off")
    for ax, (key, title, limit, scale) in zip(axes.flat, panels, strict=False):
        for i, (label, s) in enumerate(data.items()):
            y = [_drawn(key, v) for v in s[key]]
            if all(math.isnan(v) for v in y):
                continue
            style = {"color": colours[i % len(colours)], "label": label,
                     "ls": "-" if "PC tdpa" in label else ":",
                     "marker": "s" if "local model on" in label else "o"}  # fmt: skip
            ax.plot(s["delay_ms"], y, **style)
        if limit is not None:
            ax.axhline(limit, color="k", ls="--", lw=1)
        if key == "felt":
            for delay, share in FELT_MIN.items():
                ax.plot([delay], [share], marker="_", ms=30, color="k")
        if key == "moved_mm":
            ax.axhline(FELL_AT_MM, color="r", ls=":", lw=1)
            ax.text(0, FELL_AT_MM * 1.1, "fell", color="r")
        ax.set_yscale(scale)
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("one-way delay (ms), jitter 20 % of it")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8)
    fig.suptitle("grasp_vertical at two stations over impaired links (one run a point); "
                 "dashed: issue 46's targets")  # fmt: skip
    fig.tight_layout(rect=(0, 0.16, 1, 1))
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _drawn(key: str, v: float) -> float:
    """A figure where the log axes can draw it: 0 J and no drift at the floor, a fallen box
    at the top."""
    if key == "energy_j":
        return max(v, ENERGY_FLOOR_J)
    if key == "moved_mm":
        return FELL_AT_MM if v > FELL_MM else max(v, 0.1)
    if key == "drift_mm":
        return max(v, DRIFT_FLOOR_MM)
    return v


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sweeps", type=Path, nargs="+", help="station_links.py --json files")
    ap.add_argument("--out", type=Path, required=True, help="the PNG to write")
    ap.add_argument("--base", type=Path, default=None,
                    help="a sweep whose unimpaired point the ratios of a configuration "
                         "without one are over (default: the first file's)")  # fmt: skip
    args = ap.parse_args(argv)
    sweeps = {}
    for path in args.sweeps:
        try:
            sweeps[path.stem] = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            print(f"station_links_plot: {path}: {exc}", file=sys.stderr)
            return 2
    base_points = json.loads(args.base.read_text()) if args.base else sweeps[args.sweeps[0].stem]
    data = series(sweeps, unimpaired(base_points))
    plot(data, args.out)
    print(f"wrote {args.out}: {len(data)} configurations")
    return 0


if __name__ == "__main__":
    sys.exit(main())
