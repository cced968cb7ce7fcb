"""`haptic-bench`: error against run time, scaling with the world, what each scene leaves out.

In the virtual clock:
1. the papers' scenes (docs/papers.md) across rendering methods and rates (sim 30/60/120 Hz, haptic 500/1000/
   2000 Hz): drift |x_h - x_VM|, the VM's error against the independent RNEA reference and
   the wall impact's transient (the device's peak penetration against F/K, the time to settle
   within 5 %, contact losses, port energy); run time as cost per simulated second, split by
   stage (sim step, local model, encode, install, haptic tick), and per tick p50/p99;
2. scaling: the haptic tick cost as the world grows (10, 100, 1000 bodies) for the local
   model, against stepping the whole pymunk world inside the 1 kHz loop;
3. per scene: which optional stages ran (SVD, gravity and velocity terms, penalties, the
   contact stage), the contacts sent and the update sizes;
4. the error-vs-cost front (benchmarks/front.py): the local model against pymunk stepped in
   the 1 kHz loop (the CHAI3D way) and a 60 Hz sim with a virtual coupling (the AMBF way) on
   the linkage, wall and testbed scenes, with where the local model wins in numbers.
Writes report.md with PNG plots into --out (./runs/bench by default; the project's committed
report is docs/bench: `haptic-bench --out docs/bench`); `--quick` runs a subset.

    haptic-bench [--quick] [--out DIR]
    haptic-bench --suite hapticbench [--repeat 3] [--cases NAME,..] [--out DIR]
                                                        (benchmarks/hapticbench.py)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from haptic_local_model.benchmarks import hapticbench
from haptic_local_model.benchmarks.coaster import (
    PUSH_SCENE,
    PUSH_USER,
    crank_flick_figures,
    mechanism_run,
    push_figures,
    wheel_push_figures,
)
from haptic_local_model.benchmarks.front import plot as plot_front
from haptic_local_model.benchmarks.front import points as front_points
from haptic_local_model.benchmarks.front import report as front_report
from haptic_local_model.benchmarks.front import wall_transient
from haptic_local_model.benchmarks.linkage import drift_mm, reference_error_mm
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.harness.virtual import VirtualResult, run_virtual
from haptic_local_model.shared.cli import add_version
from haptic_local_model.shared.config import BodySpec, SceneConfig, load_scene, load_user
from haptic_local_model.shared.protocol.update import encode_update
from haptic_local_model.sim_server.world import SimWorld

SIM_RATES = (30.0, 60.0, 120.0)
HAPTIC_RATES = (500.0, 1000.0, 2000.0)
METHODS = ("local_model", "impedance_only", "virtual_coupling")
WORLD_SIZES = (10, 100, 1000, 3000, 10000)
TICK_BUDGET_US = 1000.0  # 1 kHz


def configure(scene: SceneConfig, method: str, sim_hz: float, haptic_hz: float) -> SceneConfig:
    rendering = dataclasses.replace(scene.rendering, method=method)  # type: ignore[arg-type]
    return dataclasses.replace(
        scene, rendering=rendering, sim_rate_hz=sim_hz, haptic_rate_hz=haptic_hz
    )


def reference_rms_mm(scene: SceneConfig, result: VirtualResult) -> float:
    t = result.ticks["t"]
    err = reference_error_mm(scene, result.ticks, float(t[-1]) + 1e-9)
    return float(np.sqrt(np.mean(err**2)))


def accuracy_runs(seconds: float, quick: bool) -> list[dict[str, Any]]:
    rows = []
    holds = ("linkage_middle", "linkage_distal")
    sims = (60.0,) if quick else SIM_RATES
    haptics = (1000.0,) if quick else HAPTIC_RATES
    configs = [(h, m, s, r) for h in holds for m in METHODS for s in sims for r in haptics]
    # one short run first, thrown away: the first run of a process pays for loading the
    # compiled kernels, which is not the cost of any configuration
    run_virtual(load_scene(holds[0]), load_device("ideal_identity"), load_user("push_04n"), 0.2)
    for hold, method, sim_hz, haptic_hz in tqdm(configs, desc="linkage runs", leave=False):
        base = dataclasses.replace(load_scene(hold), initial_device_offset=(0.0, 0.0, 0.0))
        scene = configure(base, method, sim_hz, haptic_hz)
        result = run_virtual(scene, load_device("ideal_identity"), load_user("push_04n"), seconds)
        drift = drift_mm(result.ticks)
        rows.append(_row(hold, method, sim_hz, haptic_hz, result, {
            "steady_drift_mm": float(drift[-max(1, len(drift) // 5):].mean()),
            "max_drift_mm": float(drift.max()),
            "reference_rms_mm": reference_rms_mm(scene, result),
        }))  # fmt: skip
    for impulses in (True, False):
        for sim_hz in sims:
            for haptic_hz in haptics:
                scene = load_scene("wall_push")
                scene = dataclasses.replace(
                    configure(scene, "local_model", sim_hz, haptic_hz),
                    rendering=dataclasses.replace(scene.rendering, impulses=impulses),
                )
                result = run_virtual(scene, load_device("ideal"), load_user("push_2n"), seconds)
                rows.append(
                    _row(
                        "wall_push" + ("" if impulses else "_penalty"),
                        "local_model",
                        sim_hz,
                        haptic_hz,
                        result,
                        # the transient, not the steady VM penetration (F/K by construction)
                        wall_transient(scene, result.ticks),
                    )
                )
    return rows


def mechanism_runs(quick: bool) -> list[dict[str, Any]]:
    """The mechanisms driven by an animation variable (docs/avars.md) at each sim rate: the
    coaster shoved along its loop (6 s), the crank flicked round and the Ferris wheel pushed
    (4 s each), with the twin
    pantograph: the energy against the rendered finger's work, the free motion after the
    last touch against the independent reference, the sim's mirror, the cost."""
    sims = (60.0,) if quick else SIM_RATES
    rows = []
    mechanism_run(PUSH_SCENE, PUSH_USER, 0.2)  # thrown away: it loads the kernels
    for sim_hz in tqdm(sims, desc="mechanism runs", leave=False):
        coaster = push_figures(sim_hz=sim_hz)
        crank = crank_flick_figures(sim_hz=sim_hz)
        wheel = wheel_push_figures(sim_hz=sim_hz)
        rows.append({**coaster, "free_error": f"{coaster['free_error_um']:.2g} um"})
        rows.append({**crank, "free_error": f"{crank['free_rate_error']:.2g} of phi'"})
        rows.append({**wheel, "free_error": f"{wheel['free_rate_error']:.2g} of q'"})
    return rows


def _row(
    scene: str,
    method: str,
    sim_hz: float,
    haptic_hz: float,
    r: VirtualResult,
    errors: dict[str, float],
) -> dict[str, Any]:
    per_s = {k: v / 1e9 / r.sim_s for k, v in r.stage_ns.items()}
    return {
        "scene": scene, "method": method, "sim_hz": sim_hz, "haptic_hz": haptic_hz,
        "cost_ms_per_sim_s": 1e3 * sum(per_s.values()),
        "stage_ms_per_sim_s": {k: 1e3 * v for k, v in per_s.items()},
        "tick_us": 1e6 * per_s["tick"] / haptic_hz,
        **errors,
    }  # fmt: skip


def crowded_scene(n: int) -> SceneConfig:
    """free_box with n extra small boxes moving about a larger enclosure, far from the tool."""
    base = load_scene("free_box")
    rng = np.random.default_rng(n)
    extra = []
    side = int(np.ceil(np.sqrt(n)))
    for i in range(n):
        x = 0.3 + 0.02 * (i % side)
        y = -0.4 + 0.02 * (i // side)
        extra.append(BodySpec(
            name=f"crowd{i}", kind="dynamic", shape="box", material="wall", size=(0.01, 0.01),
            mass=0.05, position=(x, y), velocity=tuple(rng.uniform(-0.2, 0.2, 2)),
        ))  # fmt: skip
    walls = [
        BodySpec(name=f"outer{i}", kind="static", shape="segment", material="wall", a=a, b=b, radius=0.005)
        for i, (a, b) in enumerate((((0.25, -0.5), (0.25, 1.0)), ((1.0, -0.5), (1.0, 1.0)), ((0.25, -0.5), (1.0, -0.5)), ((0.25, 1.0), (1.0, 1.0))))
    ]  # fmt: skip
    return dataclasses.replace(base, bodies=base.bodies + tuple(walls) + tuple(extra))


def _tick_samples(engine: HapticEngine, ticks: int) -> np.ndarray:
    out = np.zeros(ticks)
    for k in range(ticks):
        t0 = time.perf_counter_ns()
        engine.tick(1e-3)
        out[k] = (time.perf_counter_ns() - t0) / 1e3
    return out[100:]


def scaling(ticks: int = 3000, rounds: int = 3) -> list[dict[str, Any]]:
    """Per-tick cost against the world size: individually timed ticks, in `rounds` interleaved
    rounds (the machine is shared: the lowest round median is the cost, the rest is noise)."""
    engines = {}
    for n in WORLD_SIZES:
        scene = crowded_scene(n)
        world = SimWorld(scene)
        engine = HapticEngine(scene, load_device("ideal"), load_user("waypoints"))
        engine.receive(encode_update(world.local_model(1, 0, 0)))
        engines[n] = (world, engine)
    local: dict[int, list[np.ndarray]] = {n: [] for n in WORLD_SIZES}
    for _ in tqdm(range(rounds), desc="scaling rounds", leave=False):
        for n in WORLD_SIZES:
            local[n].append(_tick_samples(engines[n][1], ticks))
    rows = []
    for n in tqdm(WORLD_SIZES, desc="world sizes", leave=False):
        world = engines[n][0]
        sim = np.zeros(20)
        for k in range(sim.shape[0]):
            t0 = time.perf_counter_ns()
            world.step(None)
            world.local_model(1, k + 1, 0)
            sim[k] = (time.perf_counter_ns() - t0) / 1e6
        # the alternative: step the whole pymunk world at 1 kHz inside the loop
        world.substeps = 1
        world.period = 1e-3
        in_loop = np.zeros(min(ticks, 500))
        for k in range(in_loop.shape[0]):
            t0 = time.perf_counter_ns()
            world.step(None)
            world.tool_state()
            in_loop[k] = (time.perf_counter_ns() - t0) / 1e3
        best = min(local[n], key=lambda a: float(np.median(a)))
        rows.append({
            "bodies": n,
            "local_model_tick_us_p50": float(np.percentile(best, 50)),
            "local_model_tick_us_p99": float(np.percentile(best, 99)),
            "sim_step_ms_at_60hz": float(np.median(sim)),
            "pymunk_in_loop_us_p50": float(np.percentile(in_loop[20:], 50)),
            "pymunk_in_loop_us_p99": float(np.percentile(in_loop[20:], 99)),
        })  # fmt: skip
    return rows


def stages_per_scene(seconds: float) -> list[dict[str, Any]]:
    rows = []
    for scene_name, device, user in (
        ("free_box", "ideal", "waypoints"), ("wall_push", "ideal", "push_2n"),
        ("testbed_free_tool", "ideal", "push_block"), ("linkage_middle", "ideal_identity", "push_04n"),
        ("linkage_distal", "ideal_identity", "push_04n"), ("testbed", "ideal", "swing"),
    ):  # fmt: skip
        scene = load_scene(scene_name)
        result = run_virtual(scene, load_device(device), load_user(user), seconds)
        t = result.ticks
        world = SimWorld(scene)
        sample = world.local_model(1, 0, 0)
        rows.append({
            "scene": scene_name,
            "svd_steps_fraction": result.svd_steps / max(result.updates, 1),
            "gravity_section": sample.gravity is not None,
            "velocity_terms_section": sample.velocity_torque is not None,
            "penalty_ticks_fraction": float((t["n_resisted"] > 0).mean()),
            "contact_stage_ticks_fraction": float(t["contact_stage"].mean()),
            "contacts_sent_mean": float(t["n_contacts"].mean()),
            "update_bytes_mean": float(np.mean(result.update_bytes)),
            "update_bytes_max": int(np.max(result.update_bytes)),
            "tick_us": result.stage_ns["tick"] / 1e3 / len(t),
            "sim_ms_per_step": (result.stage_ns["sim_step"] + result.stage_ns["local_model"]) / 1e6 / result.updates,
        })  # fmt: skip
    return rows


def plot(
    acc: list[dict[str, Any]], scale: list[dict[str, Any]], out: Path, seconds: float
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    markers = {"local_model": "o", "impedance_only": "s", "virtual_coupling": "^"}
    for hold, ax in zip(("linkage_middle", "linkage_distal"), axes[:2], strict=True):
        for r in acc:
            if r["scene"] != hold:
                continue
            ax.loglog(r["cost_ms_per_sim_s"], max(r["reference_rms_mm"], 1e-3), markers[r["method"]],
                      color=plt.cm.viridis(SIM_RATES.index(r["sim_hz"]) / 2), alpha=0.4 + 0.3 * HAPTIC_RATES.index(r["haptic_hz"]))  # fmt: skip
        for m, mk in markers.items():
            ax.plot([], [], mk, color="k", label=m)
        for i, hz in enumerate(SIM_RATES):
            ax.plot([], [], "o", color=plt.cm.viridis(i / 2), label=f"sim {hz:g} Hz")
        ax.set_xlabel("cost per simulated second (ms)")
        ax.set_ylabel("VM error vs reference, RMS (mm)")
        ax.set_title(f"{hold}: error against run time")
        ax.legend(fontsize=7)
    ax = axes[2]
    for r in acc:
        if r["scene"].startswith("wall_push"):
            ax.loglog(
                r["cost_ms_per_sim_s"],
                max(r["peak_over_fk"], 1e-3),
                "o" if r["scene"] == "wall_push" else "x",
                color=plt.cm.viridis(SIM_RATES.index(r["sim_hz"]) / 2),
            )
    ax.plot([], [], "o", color="k", label="penalty + impulses")
    ax.plot([], [], "x", color="k", label="penalty only")
    ax.set_xlabel("cost per simulated second (ms)")
    ax.set_ylabel("the device's peak penetration / (F/K)")
    ax.set_title("wall_push: the impact's transient")
    ax.legend(fontsize=7)
    fig.tight_layout()
    paths.append(out / "error_vs_runtime.png")
    fig.savefig(paths[-1], dpi=100)

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    n = [r["bodies"] for r in scale]
    ax.loglog(
        n,
        [r["local_model_tick_us_p50"] for r in scale],
        "o-",
        label="local model: haptic tick (p50)",
    )
    ax.loglog(
        n, [r["pymunk_in_loop_us_p50"] for r in scale], "s-", label="pymunk world in the loop (p50)"
    )
    ax.loglog(
        n,
        [r["pymunk_in_loop_us_p99"] for r in scale],
        "s--",
        label="pymunk world in the loop (p99)",
    )
    ax.axhline(TICK_BUDGET_US, color="r", lw=0.8, label="1 kHz budget")
    ax.set_xlabel("bodies in the world")
    ax.set_ylabel("cost per 1 ms tick (us)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out / "scaling.png")
    fig.savefig(paths[-1], dpi=100)

    fig, axes = plt.subplots(1, 2, figsize=(13, 4))
    for hold, ax in zip(("linkage_middle", "linkage_distal"), axes, strict=True):
        for method in METHODS:
            base = dataclasses.replace(load_scene(hold), initial_device_offset=(0.0, 0.0, 0.0))
            result = run_virtual(
                configure(base, method, 60.0, 1000.0),
                load_device("ideal_identity"),
                load_user("push_04n"),
                seconds,
            )
            ax.semilogy(result.ticks["t"], np.maximum(drift_mm(result.ticks), 1e-3), label=method)
        ax.set_title(f"{hold}: drift over the run (sim 60 Hz, haptic 1 kHz)")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("drift (mm)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out / "error_over_run.png")
    fig.savefig(paths[-1], dpi=100)
    return paths


def write_report(
    acc: list[dict[str, Any]],
    scale: list[dict[str, Any]],
    stages: list[dict[str, Any]],
    out: Path,
    seconds: float,
    wall_s: float,
    mechanisms: list[dict[str, Any]] | None = None,
) -> None:
    lines = [
        "# haptic-bench report", "",
        f"Virtual clock, {seconds:g} s per run; generated by `haptic-bench` in {wall_s / 60:.1f} min on {time.strftime('%Y-%m-%d')}.", "",
        "## Error against run time", "",
        "| scene | method | sim Hz | haptic Hz | cost ms / sim s | tick us | steady drift mm | max drift mm | ref RMS mm | device peak / (F/K) | settle s | contact losses | port J |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    nan = float("nan")
    for r in acc:
        lines.append(
            f"| {r['scene']} | {r['method']} | {r['sim_hz']:g} | {r['haptic_hz']:g} | {r['cost_ms_per_sim_s']:.1f} | {r['tick_us']:.2f} "
            f"| {r.get('steady_drift_mm', nan):.3f} | {r.get('max_drift_mm', nan):.2f} | {r.get('reference_rms_mm', nan):.3f} "
            f"| {r.get('peak_over_fk', nan):.2f} | {r.get('settle_s', nan):.2f} | {r.get('contact_losses', nan):.0f} | {r.get('port_energy_j', nan):.4f} |"
        )  # fmt: skip
    lines += ["", "Mechanisms driven by an animation variable (docs/avars.md; twin pantograph, haptic 1000 Hz; the coaster 6 s, the crank and the wheel 4 s). The loop integrates the avar, so the rendering is the same at every sim rate; the sim's mirror is its state after its last step against the loop's at that instant (m or rad):", "",
              "| scene | sim Hz | cost ms / sim s | tick us | energy vs finger's work | free motion vs reference | sim mirror | port J given | dead centres / flagged |",
              "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in mechanisms or []:
        lines.append(
            f"| {r['scene']} | {r['sim_hz']:g} | {r['cost_ms_per_sim_s']:.1f} | {r['tick_us']:.2f} | {100 * r['work_energy_error']:.2f} % "
            f"| {r['free_error']} | {r['mirror_error']:.2g} | {r['port_given_max_j']:.2g} | {r.get('dead_centres', 0)} / {r['singular']} |"
        )  # fmt: skip
    lines += ["", "Cost by stage (ms per simulated second), first configuration of each scene:", ""]
    seen = set()
    for r in acc:
        if r["scene"] in seen:
            continue
        seen.add(r["scene"])
        stages_txt = ", ".join(f"{k} {v:.2f}" for k, v in r["stage_ms_per_sim_s"].items())
        lines.append(
            f"- {r['scene']} ({r['method']}, sim {r['sim_hz']:g} Hz, haptic {r['haptic_hz']:g} Hz): {stages_txt}"
        )
    lines += ["", "![error vs run time](error_vs_runtime.png)", "", "![error over a run](error_over_run.png)", "", "## Scaling with the world", "",
              "| bodies | local model haptic tick p50 / p99 (us) | sim step + local model at 60 Hz (ms) | pymunk world in the 1 kHz loop p50 / p99 (us) |", "|---|---|---|---|"]  # fmt: skip
    for r in scale:
        lines.append(
            f"| {r['bodies']} | {r['local_model_tick_us_p50']:.2f} / {r['local_model_tick_us_p99']:.2f} | {r['sim_step_ms_at_60hz']:.2f} | {r['pymunk_in_loop_us_p50']:.0f} / {r['pymunk_in_loop_us_p99']:.0f} |"
        )
    over = [r["bodies"] for r in scale if r["pymunk_in_loop_us_p50"] > TICK_BUDGET_US]
    small = [r for r in scale if r["bodies"] <= 1000]
    ratio = max(r["local_model_tick_us_p50"] for r in small) / min(
        r["local_model_tick_us_p50"] for r in small
    )
    lines += ["", f"Local model tick cost (p50) from 10 to 1000 bodies: max/min = {ratio:.2f}.",
              f"The in-loop pymunk alternative misses the 1 kHz budget (p50 > 1 ms) from {over[0] if over else 'none of the measured'} bodies.", "",
              "![scaling](scaling.png)", "", "## What each scene leaves out", "",
              "| scene | SVD steps | gravity section | velocity terms | penalty ticks | contact-stage ticks | contacts sent (mean) | update bytes mean / max | tick us | sim ms / step |",
              "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in stages:
        lines.append(
            f"| {r['scene']} | {r['svd_steps_fraction']:.0%} | {'yes' if r['gravity_section'] else 'no'} | {'yes' if r['velocity_terms_section'] else 'no'} "
            f"| {r['penalty_ticks_fraction']:.0%} | {r['contact_stage_ticks_fraction']:.0%} | {r['contacts_sent_mean']:.1f} | {r['update_bytes_mean']:.0f} / {r['update_bytes_max']} "
            f"| {r['tick_us']:.2f} | {r['sim_ms_per_step']:.2f} |"
        )
    (out / "report.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="haptic-bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_version(parser)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument(
        "--out", type=Path, default=Path("runs/bench"),
        help="report directory (default ./runs/bench; the project's own: docs/bench)",
    )  # fmt: skip
    parser.add_argument(
        "--suite", choices=tuple(hapticbench.SUITES),
        help="run only the named hapticbench suite (every registered method): writes"
        " hapticbench.md, .json, .schema.json and .png into --out",
    )  # fmt: skip
    parser.add_argument(
        "--repeat", type=int, default=3, help="--suite: rounds per run for its cost spread"
    )
    parser.add_argument(
        "--cases", type=lambda text: tuple(text.split(",")), default=(),
        help="--suite: only these of its cases, comma-separated (no stable stiffness)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    if args.suite:
        # the stable stiffness per rate (about 2 min) with the full suite, not the reduced
        stiffness = args.suite == hapticbench.SUITE_NAME and not args.cases
        try:
            cases = hapticbench.select(hapticbench.SUITES[args.suite], args.cases)
        except ValueError as exc:
            parser.error(str(exc))
        doc = hapticbench.run_suite(cases, args.repeat, stiffness)
        command = f"haptic-bench --suite {args.suite} --repeat {args.repeat}" + (
            f" --cases {','.join(args.cases)}" if args.cases else ""
        )
        print(hapticbench.write(doc, args.out, command, time.perf_counter() - started))
        return 0
    seconds = 2.0 if args.quick else args.seconds
    acc = accuracy_runs(seconds, args.quick)
    mechanisms = mechanism_runs(args.quick)
    scale = scaling()
    stages = stages_per_scene(seconds)
    front = front_points(1 if args.quick else 3, args.quick)
    plot(acc, scale, args.out, seconds)
    plot_front(front, args.out)
    wall_s = time.perf_counter() - started
    write_report(acc, scale, stages, args.out, seconds, wall_s, mechanisms)
    with (args.out / "report.md").open("a") as fh:
        fh.write("\n" + front_report(front, 1 if args.quick else 3).replace("# ", "## ", 1))
    print((args.out / "report.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
