"""Seed 000's controlled experiments: the three rendering methods on the held linkage.

For `linkage_middle` and `linkage_distal` (seed 000 Table I, a constant 0.4 N push, the
ideal device with M_d = I), in the virtual clock, for 5 s:
- drift |x_h - x_VM| over time for local_model (eq 18), impedance_only (eq 11) and
  virtual_coupling (§VIII): steady value, growth, oscillation; j over time;
- the VM trajectory with local_model against the independent reference (RNEA + solve_ivp,
  Coriolis included, shared/reference.py) with the device starting on the operational
  point, at sim rates 30, 60 and 120 Hz: RMS and max error;
- plots as seed 000 Figs. 6, 7, 11, 12: hand and VM paths per method, drift over time.

    python -m haptic_local_model.benchmarks.linkage [--seconds 5] [--out docs/figures] [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import find_peaks

from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared.config import SceneConfig, load_scene, load_user
from haptic_local_model.shared.reference import ChainSpec, Hold, ReferenceSolution, simulate

METHODS = ("local_model", "impedance_only", "virtual_coupling")
HOLDS = ("linkage_middle", "linkage_distal")
TREES = ("linkage_tree",)  # a tree linkage (DESIGN-WAVE2 C1): its VM against the reference
DEVICE = "ideal_identity"  # seed 000's simulations: M_d = identity
USER = "push_04n"
STEADY_S = 1.0  # steady drift: mean over the last second
OSCILLATION_WINDOW_S = 1.5  # the settling from the initial offset (seed 000 §VIII)
OSCILLATION_PROMINENCE_MM = 0.2  # a turning point of the drift that counts


def with_method(scene: SceneConfig, method: str) -> SceneConfig:
    return dataclasses.replace(scene, rendering=dataclasses.replace(scene.rendering, method=method))  # type: ignore[arg-type]


def run(scene: SceneConfig, seconds: float) -> np.ndarray:
    return run_virtual(scene, load_device(DEVICE), load_user(USER), seconds).ticks


def drift_mm(ticks: np.ndarray) -> np.ndarray:
    return 1e3 * np.hypot(*(ticks["device_pose"][:, :2] - ticks["vm_pose"][:, :2]).T)


def drift_metrics(ticks: np.ndarray) -> dict[str, float]:
    drift = drift_mm(ticks)
    t = ticks["t"]
    steady = t >= t[-1] - STEADY_S
    half = np.searchsorted(t, t[-1] / 2)
    # oscillation: turning points of the drift while it settles from the initial offset
    early = drift[t <= OSCILLATION_WINDOW_S]
    peaks, _ = find_peaks(early, prominence=OSCILLATION_PROMINENCE_MM)
    troughs, _ = find_peaks(-early, prominence=OSCILLATION_PROMINENCE_MM)
    turning_points = len(peaks) + len(troughs)
    return {
        "steady_drift_mm": float(drift[steady].mean()),
        "max_drift_mm": float(drift.max()),
        "drift_end_mm": float(drift[-1]),
        "drift_half_mm": float(drift[half]),
        "growth": float(drift[-1] / max(drift[half], 1e-9)),
        "turning_points": turning_points,
        "resisted_fraction": float((ticks["n_resisted"] > 0).mean()),
    }


def chain_spec(scene: SceneConfig) -> ChainSpec:
    """The held linkage of a scene as the independent reference's ChainSpec."""
    lk = scene.tool_linkage
    return ChainSpec(
        base=lk.base, lengths=lk.lengths, masses=lk.masses, inertias=lk.inertias,
        com_offsets=lk.com_offsets, gravity=scene.gravity, base_angle=lk.base_angle,
        parents=lk.parents,
    )  # fmt: skip


def reference_error_mm(
    scene: SceneConfig, ticks: np.ndarray, t_end: float, field: str = "vm_pose"
) -> np.ndarray:
    """Distance (mm) of the VM's operational point (or the row's `field`: the device's, what
    the hand holds) from the independent reference's at each tick: the linkage released at
    rest from its initial angles under USER's constant push, integrated to t_end."""
    ref = reference_path(scene, ticks["t"], t_end, USER)
    return 1e3 * np.hypot(*(ticks[field][:, :2] - ref.pose[:, :2]).T)


def reference_path(scene: SceneConfig, t: np.ndarray, t_end: float, user: str) -> ReferenceSolution:
    """The independent reference at times t: the scene's linkage released at rest from its
    initial angles under the constant push of `user` (a constant_wrench hand) at its hold."""
    lk = scene.tool_linkage
    return simulate(
        chain_spec(scene),
        np.array(lk.initial_angles),
        np.zeros(len(lk.lengths)),
        Hold(np.array(load_user(user).wrench), scene.tool.link, np.array(scene.tool.point)),
        t_end,
        t,
    )


def reference_error(scene: SceneConfig, seconds: float, sim_hz: float) -> dict[str, float]:
    """local_model VM against the reference, the device starting on the operational point."""
    s = dataclasses.replace(scene, sim_rate_hz=sim_hz, initial_device_offset=(0.0, 0.0, 0.0))
    ticks = run(with_method(s, "local_model"), seconds)
    err = reference_error_mm(s, ticks, seconds)
    first2 = ticks["t"] <= 2.0
    return {
        "sim_hz": sim_hz,
        "rms_mm": float(np.sqrt(np.mean(err**2))),
        "max_mm": float(err.max()),
        "rms_first_2s_mm": float(np.sqrt(np.mean(err[first2] ** 2))),
    }


def plot(runs: dict[str, dict[str, np.ndarray]], out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    fig, axes = plt.subplots(len(HOLDS), len(METHODS), figsize=(13, 8), squeeze=False)
    for r, hold in enumerate(HOLDS):
        for c, method in enumerate(METHODS):
            ticks = runs[hold][method]
            ax = axes[r, c]
            ax.plot(
                ticks["device_pose"][:, 0] * 100,
                ticks["device_pose"][:, 1] * 100,
                label="hand (HD)",
            )
            ax.plot(ticks["vm_pose"][:, 0] * 100, ticks["vm_pose"][:, 1] * 100, "--", label="VM")
            ax.plot(*(ticks["vm_pose"][0, :2] * 100), "ko", ms=3)
            ax.set_title(f"{hold}: {method}", fontsize=10)
            ax.set_xlabel("x (cm)")
            ax.set_ylabel("y (cm)")
            ax.axis("equal")
            ax.legend(fontsize=8)
    fig.suptitle("Hand and VM paths under a constant 0.4 N push (seed 000 Figs. 6, 7, 11, 12)")
    fig.tight_layout()
    paths.append(out_dir / "linkage_paths.png")
    fig.savefig(paths[-1], dpi=100)

    fig, axes = plt.subplots(1, len(HOLDS), figsize=(13, 4.5), squeeze=False)
    for c, hold in enumerate(HOLDS):
        ax = axes[0, c]
        for method in METHODS:
            ticks = runs[hold][method]
            ax.semilogy(ticks["t"], np.maximum(drift_mm(ticks), 1e-3), label=method)
        lm = runs[hold]["local_model"]
        resisted = lm["n_resisted"] > 0
        ax.fill_between(
            lm["t"], 1e-3, 1e3, where=resisted, color="0.85", label="j > 0 (local_model)"
        )
        ax.set_ylim(1e-2, 1e3)
        ax.set_title(hold)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("drift |x_h - x_VM| (mm)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out_dir / "linkage_drift.png")
    fig.savefig(paths[-1], dpi=100)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--out", type=Path, default=Path("docs/figures"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    runs: dict[str, dict[str, np.ndarray]] = {}
    report: dict[str, Any] = {}
    for hold in HOLDS:
        scene = load_scene(hold)
        runs[hold] = {m: run(with_method(scene, m), args.seconds) for m in METHODS}
        report[hold] = {m: drift_metrics(runs[hold][m]) for m in METHODS}
        report[hold]["reference"] = [
            reference_error(scene, args.seconds, hz) for hz in (30.0, 60.0, 120.0)
        ]
    cols = (
        f"{'steady mm':>10}{'max mm':>9}{'at T/2':>9}{'at T':>9}{'growth':>8}{'turns':>6}{'j>0':>6}"
    )
    print(f"{'scene':<16}{'method':<18}{cols}")
    for hold in HOLDS:
        for m in METHODS:
            d = report[hold][m]
            print(
                f"{hold:<16}{m:<18}{d['steady_drift_mm']:>10.3f}{d['max_drift_mm']:>9.2f}"
                f"{d['drift_half_mm']:>9.2f}{d['drift_end_mm']:>9.2f}{d['growth']:>8.2f}"
                f"{d['turning_points']:>6}{d['resisted_fraction']:>6.2f}"
            )
    for tree in TREES:
        report[tree] = {
            "reference": [
                reference_error(load_scene(tree), args.seconds, hz) for hz in (30.0, 60.0, 120.0)
            ]
        }
    print("\nlocal_model VM vs reference (device starting on the operational point):")
    for hold in HOLDS + TREES:
        for e in report[hold]["reference"]:
            print(
                f"  {hold:<16} sim {e['sim_hz']:>5.0f} Hz: RMS {e['rms_mm']:.3f} mm, "
                f"max {e['max_mm']:.3f} mm, RMS over the first 2 s {e['rms_first_2s_mm']:.3f} mm"
            )
    for path in plot(runs, args.out):
        print(f"plot: {path}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
