"""Held-out linkage holds against independent references, and singular holds.

The family: the three-link arm of `linkage_distal` (seed 000 Table I) held at every link, at
its COM, its tip and 10 mm off its axis, pushed by a constant world wrench along x, along y,
diagonally, by a pure torque and by a force with a torque; the ideal device with M_d = I
starting on the operational point; virtual clock, 5 s, sim at 30, 60 and 120 Hz. For each:

- `rms_mm`: the project's operational point against the linkage driven by the hand alone
  (`shared.reference`, recursive Newton-Euler, DOP853), with today's law;
- `rms_old_mm`: the same with `jdot_qd = false` (seed 000's law as printed), at 60 Hz;
- `law_mm` / `law_old_mm`: the continuous closed loop (`shared.reference_loop`: hand ->
  ideal device -> the law with exact dynamics -> linkage) against the linkage alone, with
  and without J_h_dot qd: the law's own error, with no sampling and no frozen model;
- `singular`: whether the hand alone takes the hold near or through rank loss (a relative
  singular value of diag(1, 1, L) J_h within a factor 2 of the rank tolerance, or the
  resisted count changing); reported apart from the holds away from rank loss. A hold the
  push does not move (travel < 1 mm: a push along link 0 at its base) is left out of both.

The singular sweep: the distal hold pushed through the elbow's singularity (push directions
-30..30 degrees), and held at it (the arm started straight, pushed along itself), the device
starting 5 mm, 3 mm off the operational point as in seed 000; steady drift |x_h - x_VM|
(mean of the last second) for the local model and for impedance control.

    python -m haptic_local_model.benchmarks.holds [--seconds 5] [--rates 30 60 120] [--quick] [--out runs/holds]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.linkage import chain_spec, drift_metrics
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared.config import SceneConfig, UserConfig, load_scene
from haptic_local_model.shared.reference import ChainSpec, Hold, point_jacobian, simulate
from haptic_local_model.shared.reference_loop import LoopGains, simulate_loop

BASE_SCENE = "linkage_distal"
DEVICE = "ideal_identity"
WRENCHES: dict[str, tuple[float, float, float]] = {
    "+x": (0.4, 0.0, 0.0),
    "+y": (0.0, 0.4, 0.0),
    "-x+y": (-0.28, 0.28, 0.0),
    "torque": (0.0, 0.0, 0.004),
    "x+torque": (0.3, 0.0, 0.003),
}
OFF_AXIS_M = 0.01
TARGET_RMS_MM = 0.5  # the goal away from singularities, at every sim rate
MIN_TRAVEL_MM = 1.0  # a hold the push does not move (along a link at its base) grades nothing
SINGULAR_MARGIN = 2.0  # within this factor of the rank tolerance counts as near rank loss
SWEEP_ANGLES_DEG = (-30.0, -15.0, 0.0, 15.0, 30.0)
SWEEP_PUSH_N = 0.4
SEED_OFFSET = (0.005, 0.003, 0.0)  # seed 000's initial device offset


@dataclasses.dataclass(frozen=True)
class HoldCase:
    link: int
    where: str  # com, tip, off-axis
    point: tuple[float, float]
    push: str
    wrench: tuple[float, float, float]

    @property
    def name(self) -> str:
        return f"link{self.link}-{self.where}-{self.push}"


def family(scene: SceneConfig, quick: bool = False) -> list[HoldCase]:
    """Every link x (COM, tip, off the axis) x every push; `quick`: one point per link and
    three pushes (the test's subset)."""
    lk = scene.tool_linkage
    cases = []
    for link, length in enumerate(lk.lengths):
        com = lk.com_offsets[link]
        points = {
            "com": (com[0], com[1]),
            "tip": (length, 0.0),
            "off-axis": (com[0], com[1] + OFF_AXIS_M),
        }
        for where, point in points.items():
            if quick and where != ("off-axis" if link == 2 else "tip"):
                continue
            for push, wrench in WRENCHES.items():
                if quick and push not in ("+x", "-x+y", "x+torque"):
                    continue
                cases.append(HoldCase(link, where, point, push, wrench))
    return cases


def case_scene(
    scene: SceneConfig,
    case: HoldCase,
    sim_hz: float,
    method: str = "local_model",
    jdot_qd: bool = True,
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    initial_angles: tuple[float, ...] | None = None,
) -> SceneConfig:
    tool = dataclasses.replace(scene.tool, link=case.link, point=case.point)
    rendering = dataclasses.replace(scene.rendering, method=method, jdot_qd=jdot_qd)  # type: ignore[arg-type]
    linkages = scene.linkages
    if initial_angles is not None:
        linkages = tuple(
            dataclasses.replace(lk, initial_angles=initial_angles) if lk.name == tool.name else lk
            for lk in linkages
        )
    return dataclasses.replace(
        scene, tool=tool, rendering=rendering, sim_rate_hz=sim_hz,
        initial_device_offset=offset, linkages=linkages,
    )  # fmt: skip


def run_case(scene: SceneConfig, case: HoldCase, seconds: float) -> np.ndarray:
    user = UserConfig(name=f"push {case.push}", kind="constant_wrench", wrench=case.wrench)
    return run_virtual(scene, load_device(DEVICE), user, seconds).ticks


def rms(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2)))


def distance_mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return 1e3 * np.hypot(*(a[:, :2] - b[:, :2]).T)


def singular_along(scene: SceneConfig, spec: ChainSpec, case: HoldCase, q: np.ndarray) -> bool:
    """Near or through rank loss along a path of joint angles (see the module docstring)."""
    tol = scene.tool.rank_tolerance
    scale = np.array([1.0, 1.0, scene.tool.characteristic_length_m])
    counts = set()
    near = False
    for qi in q[:: max(1, len(q) // 500)]:
        sigma = np.zeros(3)
        s = np.linalg.svd(
            scale[:, None] * point_jacobian(spec, qi, case.link, case.point), compute_uv=False
        )
        sigma[: len(s)] = s
        ratio = sigma / sigma[0]
        counts.add(int((ratio < tol).sum()))
        near = near or bool(
            np.any((ratio > tol / SINGULAR_MARGIN) & (ratio < tol * SINGULAR_MARGIN))
        )
    return near or len(counts) > 1


def measure_case(
    scene: SceneConfig, case: HoldCase, seconds: float, rates: tuple[float, ...]
) -> dict[str, Any]:
    spec = chain_spec(scene)
    lk = scene.tool_linkage
    q0 = np.array(lk.initial_angles)
    runs = {hz: run_case(case_scene(scene, case, hz), case, seconds) for hz in rates}
    old = run_case(case_scene(scene, case, 60.0, jdot_qd=False), case, seconds)
    t = old["t"]
    hold = Hold(np.array(case.wrench), case.link, np.array(case.point))
    ref = simulate(spec, q0, np.zeros(len(q0)), hold, seconds, t)
    r = scene.rendering
    gains = LoopGains(
        coordination_stiffness=r.coordination_stiffness,
        coordination_damping=r.coordination_damping,
        penalty_stiffness=r.penalty_stiffness, penalty_damping=r.penalty_damping,
        characteristic_length_m=scene.tool.characteristic_length_m,
        rank_tolerance=scene.tool.rank_tolerance,
    )  # fmt: skip
    law = {
        jd: simulate_loop(spec, q0, hold, dataclasses.replace(gains, jdot_qd=jd), seconds, t)
        for jd in (True, False)
    }
    return {
        "case": case.name,
        "link": case.link,
        "where": case.where,
        "push": case.push,
        "singular": singular_along(scene, spec, case, ref.q),
        "rms_mm": {f"{hz:g}": rms(distance_mm(runs[hz]["vm_pose"], ref.pose)) for hz in rates},
        "max_mm": {
            f"{hz:g}": float(distance_mm(runs[hz]["vm_pose"], ref.pose).max()) for hz in rates
        },
        "rms_old_mm": rms(distance_mm(old["vm_pose"], ref.pose)),
        "law_mm": rms(distance_mm(law[True].vm_pose, ref.pose)),
        "law_old_mm": rms(distance_mm(law[False].vm_pose, ref.pose)),
        "travel_mm": float(distance_mm(ref.pose[-1:], ref.pose[:1])[0]),
    }


def steady_drift_mm(ticks: np.ndarray) -> float:
    return drift_metrics(ticks)["steady_drift_mm"]  # mean of the last second


def singular_sweep(scene: SceneConfig, seconds: float) -> list[dict[str, Any]]:
    """Pushes through the distal hold's singularity and holds at it (module docstring)."""
    lk = scene.tool_linkage
    distal = len(lk.lengths) - 1
    com = lk.com_offsets[distal]
    straight = (lk.initial_angles[0], 0.0, 0.0)
    cases: list[tuple[str, HoldCase, tuple[float, ...] | None]] = []
    for deg in SWEEP_ANGLES_DEG:
        a = np.radians(deg)
        w = (SWEEP_PUSH_N * float(np.cos(a)), SWEEP_PUSH_N * float(np.sin(a)), 0.0)
        cases.append(
            (
                f"through {deg:+.0f} deg",
                HoldCase(distal, "com", (com[0], com[1]), f"{deg:+.0f}deg", w),
                None,
            )
        )
    # held at the singularity: the arm straight along its first link, pulled along itself
    a0 = lk.initial_angles[0]
    for deg in (0.0, 10.0):
        a = a0 + np.radians(deg)
        w = (SWEEP_PUSH_N * float(np.cos(a)), SWEEP_PUSH_N * float(np.sin(a)), 0.0)
        cases.append(
            (
                f"held straight, pull {deg:+.0f} deg",
                HoldCase(distal, "com", (com[0], com[1]), f"pull{deg:+.0f}", w),
                straight,
            )
        )
    rows = []
    for label, case, angles in cases:
        drifts = {}
        for method in ("local_model", "impedance_only"):
            s = case_scene(
                scene, case, 60.0, method=method, offset=SEED_OFFSET, initial_angles=angles
            )
            drifts[method] = steady_drift_mm(run_case(s, case, seconds))
        rows.append(
            {
                "case": label,
                "local_model_mm": drifts["local_model"],
                "impedance_only_mm": drifts["impedance_only"],
                "ratio": drifts["impedance_only"] / max(drifts["local_model"], 1e-12),
            }
        )
    return rows


def write_report(result: dict[str, Any], out: Path) -> Path:
    rates = result["rates"]
    lines = [
        "# Linkage holds against independent references",
        "",
        "Written by `python -m haptic_local_model.benchmarks.holds`; see its docstring for the cases and columns.",
        f"Device `{DEVICE}` started on the operational point, {result['seconds']:g} s, virtual clock.",
        "",
        "| hold | push | singular | " + " | ".join(f"RMS @{r:g} Hz mm" for r in rates)
        + " | RMS old law @60 mm | law alone mm | old law alone mm | travel mm |",
        "|---|---|---|" + "---|" * len(rates) + "---|---|---|---|",
    ]  # fmt: skip
    for row in result["family"]:
        lines.append(
            f"| link{row['link']} {row['where']} | {row['push']} | {'yes' if row['singular'] else ''} | "
            + " | ".join(f"{row['rms_mm'][f'{r:g}']:.3f}" for r in rates)
            + f" | {row['rms_old_mm']:.3f} | {row['law_mm']:.2g} | {row['law_old_mm']:.3f} | {row['travel_mm']:.0f} |"
        )  # fmt: skip
    s = result["summary"]
    lines += [
        "",
        f"Away from singularities ({s['away_cases']} cases): worst RMS {s['away_worst_rms_mm']:.3f} mm "
        f"(goal <= {TARGET_RMS_MM} mm at every rate); old law worst {s['away_worst_old_mm']:.2f} mm.",
        f"Near or through rank loss ({s['singular_cases']} cases): worst RMS {s['singular_worst_rms_mm']:.3f} mm.",
        f"Left out of both (the push does not move the hold, travel < {MIN_TRAVEL_MM:g} mm): {', '.join(s['unmoved']) or 'none'}.",
        "",
        "## Singular holds (distal link, device starting 5 mm, 3 mm off, 60 Hz)",
        "",
        "| case | local model steady drift mm | impedance only mm | ratio |",
        "|---|---|---|---|",
    ]  # fmt: skip
    for row in result["sweep"]:
        lines.append(
            f"| {row['case']} | {row['local_model_mm']:.4f} | {row['impedance_only_mm']:.3f} | {row['ratio']:.0f} |"
        )
    out.mkdir(parents=True, exist_ok=True)
    path = out / "holds.md"
    path.write_text("\n".join(lines) + "\n")
    (out / "holds.json").write_text(json.dumps(result, indent=2))
    return path


def summarise(family_rows: list[dict[str, Any]]) -> dict[str, Any]:
    moved = [r for r in family_rows if r["travel_mm"] >= MIN_TRAVEL_MM]
    away = [r for r in moved if not r["singular"]]
    near = [r for r in moved if r["singular"]]

    def worst(rows: list[dict[str, Any]], key: str) -> float:
        values = [max(r[key].values()) if isinstance(r[key], dict) else r[key] for r in rows]
        return max(values, default=0.0)

    return {
        "unmoved": [r["case"] for r in family_rows if r["travel_mm"] < MIN_TRAVEL_MM],
        "away_cases": len(away),
        "singular_cases": len(near),
        "away_worst_rms_mm": worst(away, "rms_mm"),
        "away_worst_old_mm": worst(away, "rms_old_mm"),
        "singular_worst_rms_mm": worst(near, "rms_mm"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rates", type=float, nargs="+", default=[30.0, 60.0, 120.0])
    parser.add_argument("--quick", action="store_true", help="the test's subset of holds")
    parser.add_argument("--out", type=Path, default=Path("runs/holds"))
    args = parser.parse_args(argv)
    scene = load_scene(BASE_SCENE)
    started = time.perf_counter()
    rows = []
    for case in family(scene, args.quick):
        row = measure_case(scene, case, args.seconds, tuple(args.rates))
        rows.append(row)
        rates = "  ".join(f"{v:.3f}" for v in row["rms_mm"].values())
        print(
            f"{row['case']:<26}{'singular' if row['singular'] else '':<10}RMS mm {rates}"
            f"  old {row['rms_old_mm']:.3f}  law {row['law_mm']:.1e}  old law {row['law_old_mm']:.3f}",
            flush=True,
        )
    sweep = singular_sweep(scene, args.seconds)
    for row in sweep:
        print(
            f"{row['case']:<34} local {row['local_model_mm']:.4f} mm  impedance "
            f"{row['impedance_only_mm']:.3f} mm  ratio {row['ratio']:.0f}"
        )
    result = {
        "seconds": args.seconds, "rates": args.rates, "family": rows, "sweep": sweep,
        "summary": summarise(rows), "elapsed_s": time.perf_counter() - started,
    }  # fmt: skip
    print(json.dumps(result["summary"]))
    print(f"report: {write_report(result, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
