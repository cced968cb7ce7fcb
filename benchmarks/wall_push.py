"""Seed 001 §5's first experiment, both contact models, measured and plotted.

A rectangle driven into a wall (K = 15000 N/m, B = 20 N s/m) by a constant 2 N, in the
virtual clock: penalty forces alone (`wall_push_penalty`, seed 001 Fig. 4) against penalty
plus impulses (`wall_push`, Fig. 5). Prints penetration against F/K, contact losses after
the first impact, settling time and peak forces, and draws contact force and position over
time for both.

The sweep (`--sweep`): stiffnesses 5, 15 and 50 kN/m x pushes of 1, 2 and 5 N with impulses,
on the `ideal` device at its shipped 50 N limit (the 1 kg device cannot be stopped in one
tick: 280-660 N would be needed), the impulse laws of versions 0.1, 0.2 and 0.13: contact losses,
the VM's largest speed away from the wall in the 10 ticks after the impact relative to the
impact speed (restitution is 0: no more than the spring-back of the depth at which the
impact was detected, sqrt(K/m) (depth - F/K), may push it out), the VM's and the device's penetration over the last half second
relative to F/K, the device's peak penetration after the impact relative to F/K (0.2: the
device's stopping distance at its limit, m v^2 / 2 (F_max - F_h), past the proxy; 0.13: paid
half ahead, it stops where the proxy does), and the energy the device put into the hand's port
(the integral of command . twist; passive if <= 0).

    python -m haptic_local_model.benchmarks.wall_push [--seconds 3] [--out docs/figures/wall_push.png] [--sweep]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual, run_virtual_named
from haptic_local_model.shared.config import SceneConfig, UserConfig, load_scene

PUSH_N = 2.0
WALL_K = 15000.0
WALL_X = 0.05  # inner face of the wall in configs/scenes/wall_push*.toml (m)
HALF_LENGTH = 0.03  # of the rectangle (m)
SETTLE_BAND = 0.05  # settled: contact force within 5% of the push from then on
STEADY_S = 0.5  # penetration averaged over the last half second


@dataclass
class WallPushMetrics:
    scene: str
    first_impact_s: float
    contact_losses: int
    settling_s: float
    steady_force_n: float
    steady_penetration_mm: float
    penetration_error: float  # relative to F/K
    peak_contact_force_n: float
    peak_rendered_force_n: float


def impact(ticks: np.ndarray) -> tuple[int, int]:
    """The first tick the wall pushes back (along -x), and how often contact is lost after."""
    touching = -ticks["contact_force_world"][:, 0] > 0.0
    first = int(np.argmax(touching))
    return first, int(np.sum(touching[first:-1] & ~touching[first + 1 :]))


def measure(scene: str, seconds: float) -> tuple[WallPushMetrics, np.ndarray]:
    ticks = run_virtual_named(scene, "ideal", "push_2n", seconds).ticks
    t = ticks["t"]
    force = -ticks["contact_force_world"][:, 0]  # the wall pushes back along -x
    first, losses = impact(ticks)
    outside = np.abs(force - PUSH_N) > SETTLE_BAND * PUSH_N
    last_out = int(np.nonzero(outside)[0][-1]) if outside.any() else first
    steady = t >= t[-1] - STEADY_S
    penetration = ticks["vm_pose"][steady, 0] + HALF_LENGTH - WALL_X
    expected = PUSH_N / WALL_K
    metrics = WallPushMetrics(
        scene=scene,
        first_impact_s=float(t[first]),
        contact_losses=losses,
        settling_s=float(t[min(last_out + 1, len(t) - 1)] - t[first]),
        steady_force_n=float(force[steady].mean()),
        steady_penetration_mm=float(penetration.mean() * 1e3),
        penetration_error=float(abs(penetration.mean() - expected) / expected),
        peak_contact_force_n=float(force.max()),
        peak_rendered_force_n=float(np.abs(ticks["wrench_command"][:, 0]).max()),
    )
    return metrics, ticks


SWEEP_STIFFNESS = (5000.0, 15000.0, 50000.0)
SWEEP_PUSH = (1.0, 2.0, 5.0)
PUSH_OUT_TICKS = 10  # the impact's own result: the VM's speed away from the wall just after


def sweep_case(stiffness: float, push: float, law: str, seconds: float = 3.0) -> dict[str, float]:
    """One wall push of the sweep (module docstring); `law` is [rendering] impulse_law."""
    scene = load_scene("wall_push")
    materials = {
        name: dataclasses.replace(mat, stiffness_n_per_m=stiffness)
        for name, mat in scene.materials.items()
    }
    rendering = dataclasses.replace(scene.rendering, impulse_law=law)  # type: ignore[arg-type]
    scene = dataclasses.replace(scene, materials=materials, rendering=rendering)
    user = UserConfig(name=f"push {push:g} N", kind="constant_wrench", wrench=(push, 0.0, 0.0))
    ticks = run_virtual(scene, load_device("ideal"), user, seconds).ticks
    t = ticks["t"]
    first, losses = impact(ticks)
    steady = t >= t[-1] - STEADY_S
    expected = push / stiffness
    vm = ticks["vm_pose"][steady, 0] + HALF_LENGTH - WALL_X
    depth_of_device = device_depth(ticks)
    device = depth_of_device[steady]
    # a body stopped at depth d under a push F, on a spring K, springs back at most at
    # sqrt(K / m) (d - F/K) (undamped, from rest): the bound on an honest push-out
    mass = next(b.mass for b in scene.bodies if b.name == scene.tool.name)
    depth = float(ticks["penetration"][first])
    v_impact = float(ticks["vm_twist"][first - 1, 0])
    spring_back = np.sqrt(stiffness / mass) * max(0.0, depth - expected) / v_impact
    # the device converges on the VM with the coordination coupling's slow pole: from when
    # on does its penetration stay within SETTLE_BAND of F/K?
    depth_ratio = depth_of_device / expected
    outside = np.flatnonzero(np.abs(depth_ratio[first:] - 1.0) > SETTLE_BAND)
    settled = outside.size == 0 or outside[-1] + first + 1 < len(t)
    device_settle_s = (
        float(t[first + outside[-1] + 1] - t[first]) if outside.size and settled else 0.0
    )
    return {
        "stiffness_n_per_m": stiffness,
        "push_n": push,
        "law": law,
        "device_settle_s": device_settle_s if settled else float("inf"),
        "coupling_time_constant_s": coupling_time_constant(scene),
        "contact_losses": losses,
        "impact_speed_m_per_s": v_impact,
        "impact_depth_m": depth,
        "push_out": float(
            max(0.0, -ticks["vm_twist"][first : first + PUSH_OUT_TICKS, 0].min()) / v_impact
        ),
        "spring_back_bound": float(spring_back),
        "vm_penetration_ratio": float(vm.mean() / expected),
        "device_penetration_ratio": float(device.mean() / expected),
        "port_energy_j": port_energy_j(ticks),
        "peak_command_n": float(np.abs(ticks["wrench_command"][:, 0]).max()),
        "device_peak_ratio": float(depth_of_device[first:].max() / expected),
        "vm_peak_ratio": float(
            (ticks["vm_pose"][first:, 0] + HALF_LENGTH - WALL_X).max() / expected
        ),
    }


def device_depth(ticks: np.ndarray) -> np.ndarray:
    """How deep the device's bar is in the wall (m; < 0: short of it), every tick."""
    return ticks["device_pose"][:, 0] + HALF_LENGTH - WALL_X


def port_energy_j(ticks: np.ndarray) -> float:
    """The energy the device's actuators gave the hand over the run (J; < 0: they took)."""
    power = (ticks["wrench_command"][:, :2] * ticks["device_twist"][:, :2]).sum(axis=1)
    return float(np.sum(power * ticks["dt"]))


def coupling_time_constant(scene: SceneConfig, device_mass: float = 1.0) -> float:
    """The slow time constant of the device's return to the VM along x: m s^2 + B s + K with
    the coordination coupling's K_pc, B_pc and the device's mass (an overdamped pair of poles:
    the slow one sets how long an overshoot takes to go)."""
    k = scene.rendering.coordination_stiffness[0]
    b = scene.rendering.coordination_damping[0]
    disc = b * b - 4.0 * k * device_mass
    slow = (b - np.sqrt(disc)) / (2.0 * device_mass) if disc > 0 else b / (2.0 * device_mass)
    return float(1.0 / slow)


def sweep(seconds: float) -> list[dict[str, float]]:
    return [
        sweep_case(k, f, law, seconds)
        for k in SWEEP_STIFFNESS
        for f in SWEEP_PUSH
        for law in ("0.1", "0.2", "0.13")
    ]


def plot(results: list[tuple[WallPushMetrics, np.ndarray]], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(results), figsize=(11, 6), sharex=True, squeeze=False)
    for col, (m, ticks) in enumerate(results):
        t = ticks["t"]
        window = (t > m.first_impact_s - 0.05) & (t < m.first_impact_s + 0.6)
        ax = axes[0, col]
        ax.plot(
            t[window], -ticks["contact_force_world"][window, 0], label="contact force on the proxy"
        )
        ax.plot(
            t[window],
            -ticks["wrench_command"][window, 0],
            lw=0.8,
            alpha=0.7,
            label="force rendered to the user",
        )
        ax.axhline(PUSH_N, color="k", lw=0.6, ls="--")
        ax.set_ylabel("force (N)")
        ax.set_title(
            f"{m.scene}: {m.contact_losses} contact losses, settles in {m.settling_s * 1e3:.0f} ms"
        )
        ax.legend(fontsize=8)
        ax = axes[1, col]
        ax.plot(
            t[window],
            (ticks["device_pose"][window, 0] + HALF_LENGTH - WALL_X) * 1e3,
            label="device",
        )
        ax.plot(
            t[window],
            (ticks["vm_pose"][window, 0] + HALF_LENGTH - WALL_X) * 1e3,
            lw=0.8,
            label="proxy",
        )
        ax.axhline(PUSH_N / WALL_K * 1e3, color="k", lw=0.6, ls="--", label="F/K")
        ax.set_ylabel("position - wall (mm)")
        ax.set_xlabel("time (s)")
        ax.legend(fontsize=8)
    fig.suptitle("Seed 001 §5: a rectangle pushed into a wall by 2 N (K = 15000 N/m, B = 20 N s/m)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--out", type=Path, default=Path("docs/figures/wall_push.png"))
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--sweep", action="store_true", help="stiffness x push, both laws")
    args = parser.parse_args(argv)
    if args.sweep:
        print(f"{'K N/m':>8}{'push N':>8}{'law':>6}{'losses':>8}{'push-out':>10}{'VM/(F/K)':>10}"
              f"{'dev/(F/K)':>11}{'dev peak':>10}{'dev settles s':>15}{'port J':>9}")  # fmt: skip
        rows = sweep(args.seconds)
        for r in rows:
            print(
                f"{r['stiffness_n_per_m']:>8.0f}{r['push_n']:>8.1f}{r['law']:>6}"
                f"{r['contact_losses']:>8}{r['push_out']:>10.3f}{r['vm_penetration_ratio']:>10.4f}"
                f"{r['device_penetration_ratio']:>11.3f}{r['device_peak_ratio']:>10.2f}"
                f"{r['device_settle_s']:>15.2f}"
                f"{r['port_energy_j']:>9.4f}"
            )
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2))
        return 0
    results = [measure(scene, args.seconds) for scene in ("wall_push_penalty", "wall_push")]
    for m, _ in results:
        print(
            f"{m.scene:<18} impact {m.first_impact_s:.3f} s  losses {m.contact_losses}  "
            f"settles in {m.settling_s * 1e3:6.1f} ms  steady force {m.steady_force_n:.4f} N  "
            f"penetration {m.steady_penetration_mm:.4f} mm (F/K {PUSH_N / WALL_K * 1e3:.4f}, "
            f"error {m.penetration_error * 100:.2f}%)  "
            f"peak contact {m.peak_contact_force_n:.1f} N  "
            f"peak rendered {m.peak_rendered_force_n:.1f} N"
        )
    plot(results, args.out)
    print(f"plot: {args.out}")
    if args.json:
        args.json.write_text(json.dumps([asdict(m) for m, _ in results], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
