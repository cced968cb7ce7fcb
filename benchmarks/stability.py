"""`haptic-stability`: numerical stability on stiff and extreme cases (issue 7).

Two parts, written to docs/stability/ as markdown + PNG:

1. The sampled virtual wall against Colgate's passivity bound b > K T / 2 + |B|: a device
   (mass m, physical damping b) hits a wall F = -K x - B v rendered with a zero-order hold
   at period T (the worst-case period measured on this machine). For each (b, B) the
   stiffness is bisected for the boundary between energy-dissipating and energy-generating
   contact (passivity observer: the wall's net work on the device over a run that starts
   and ends out of contact), and compared with K_bound = 2 (b - |B|) / T.
2. The local model's stability map in the virtual clock, one axis at a time: contact
   stiffness 1e2..1e6 N/m and damping, tool masses and inertias over six decades, haptic
   time steps, exactly at and near singular configurations, 32+ simultaneous contacts,
   impact speeds up to 2 m/s, user forces up to the device limits. Each case is classified
   stable / unstable by the energy at the device port (the controller's net work on the
   device, which a passive rendering cannot make positive) and by bounded state; every
   case is also checked for NaN/Inf reaching the device (the guards must prevent it).

    haptic-stability [--quick] [--out docs/stability]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from benchmarks.kernel_cost import engine_with_contacts
from device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_server.harness.virtual import run_virtual
from shared.config import SceneConfig, UserConfig, load_scene, load_user
from sim_server.world import SimWorld

WORST_PERIOD_S = 1.0e-3 + 60e-6  # 1 kHz plus the p99.9 lateness measured by loop_timing
DEVICE_MASS = 0.5  # kg, the sampled-wall device
ENERGY_TOL_J = 1e-6  # net work below this counts as no generation (round-off)
DEVICE_LIMIT_N = IdealDeviceConfig().max_wrench[0]
SATURATION_FRACTION = 0.999
PASSIVITY_TOL_J = 1e-3  # the device may hold this much more than the user put in (noise)
BOUNDED_M = 1.0  # a stable case never leaves +-1 m


# --- 1. sampled wall ----------------------------------------------------------------------


@njit(cache=True)
def sampled_wall_energy(k, b_wall, b_device, mass, period, v0, n_periods, substeps):
    """Energy gained by a damped mass over one contact with a zero-order-hold wall (J).

    The mass (physical damping b) enters the wall at v0; the wall force -K x - B v (x > 0
    inside, v by backward difference of the samples) is computed each period and held; the
    motion is integrated with `substeps` per period until the mass leaves the wall. Returns
    (kinetic + wall energy) at exit minus at entry: > 0 means the contact generated energy,
    which Colgate's condition b > K T / 2 + |B| rules out.
    """
    x = 0.0
    v = v0
    h = period / substeps
    x_prev = x
    entry = 0.5 * mass * v0 * v0
    for _ in range(n_periods):
        v_est = (x - x_prev) / period
        x_prev = x
        force = -k * x - b_wall * v_est if x > 0.0 else 0.0
        for _ in range(substeps):
            a = (force - b_device * v) / mass
            v_new = v + h * a
            x += h * 0.5 * (v + v_new)
            v = v_new
        if x < 0.0 and v < 0.0:
            return 0.5 * mass * v * v - entry
        if abs(x) > 1e3:
            return 1e9
    stored = 0.5 * k * x * x if x > 0.0 else 0.0
    return 0.5 * mass * v * v + stored - entry


def sampled_wall_boundary(
    b_device: float, b_wall: float, period: float, lo: float = 1.0, hi: float = 1e8, steps: int = 40
) -> float:
    """The smallest stiffness whose wall generates energy (bisection on log K in [lo, hi])."""

    def generates(k: float) -> bool:
        # work can only be negative for a passive wall: the mass arrives with its kinetic
        # energy and leaves with less
        gained = sampled_wall_energy(k, b_wall, b_device, DEVICE_MASS, period, 0.05, 200000, 20)
        return gained > ENERGY_TOL_J

    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        if generates(mid):
            hi = mid
        else:
            lo = mid
    return math.sqrt(lo * hi)


def colgate_bound(b_device: float, b_wall: float, period: float) -> float:
    """K below which b > K T / 2 + |B| holds (Colgate and Schenkel)."""
    return 2.0 * (b_device - abs(b_wall)) / period


# --- 2. the local model's map -------------------------------------------------------------


@dataclass
class Case:
    axis: str
    label: str
    stable: bool
    finite: bool
    energy_excess_j: float  # max over time of device kinetic energy - the user's work
    max_abs_pose: float
    faults: int
    note: str = ""


def proxy_kinetic(ticks: np.ndarray, scene: SceneConfig) -> np.ndarray:
    """Kinetic energy of the rendered VM, 1/2 qd^T D(q) qd, at every tick."""
    world = SimWorld(scene)
    d = world.dof
    out = np.zeros(ticks.shape[0])
    mass = None
    for k in range(ticks.shape[0]):
        q = ticks["proxy_q"][k, :d]
        if mass is None or scene.tool.kind == "linkage":
            mass = world.dynamics_terms(np.nan_to_num(q))[0]
        qd = np.nan_to_num(ticks["proxy_qd"][k, :d])
        out[k] = 0.5 * qd @ mass @ qd
    return out


def classify(axis: str, label: str, ticks: np.ndarray, rendered_energy: np.ndarray) -> Case:
    """Stable: finite at the device, bounded, and passive at the user's port.

    Passivity observer: the hand's work on the device, W(t) = sum F_h . v dt, must always
    cover the energy stored in what is rendered (the VM's kinetic energy): a passive
    rendering stores or dissipates what the user puts in and cannot give back more. (The
    controller's own work is not the test: making a heavy device feel like a light VM takes
    positive work in free motion.)
    """
    command = ticks["wrench_command"]
    finite = bool(np.isfinite(command).all())
    v = np.nan_to_num(ticks["device_twist"])
    dt = np.nan_to_num(ticks["dt"])
    user_work = np.cumsum(np.sum(np.nan_to_num(ticks["hand_wrench"]) * v, axis=1) * dt)
    stored = rendered_energy - rendered_energy[0] if ticks.size else rendered_energy
    excess = float(np.max(stored - user_work)) if ticks.size else 0.0
    pose = float(np.nanmax(np.abs(ticks["device_pose"][:, :2]))) if ticks.size else 0.0
    at_limit = np.abs(command[:, :2]) >= SATURATION_FRACTION * DEVICE_LIMIT_N
    saturated = float(np.mean(np.any(at_limit, axis=1)))
    stable = finite and pose < BOUNDED_M and excess < PASSIVITY_TOL_J
    note = f"at the device force limit {saturated:.0%} of the time" if saturated > 0.001 else ""
    return Case(axis, label, stable, finite, excess, pose, int((ticks["fault"] != 0).sum()), note)


def _wall_scene(
    k: float, b: float, mass: float = 0.5, rate_hz: float = 1000.0, v0: float = 0.0
) -> SceneConfig:
    scene = load_scene("wall_push")
    materials = {
        name: dataclasses.replace(m, stiffness_n_per_m=k, damping_ns_per_m=b)
        for name, m in scene.materials.items()
    }
    bodies = tuple(
        dataclasses.replace(body, mass=mass, velocity=(v0, 0.0))
        if body.name == "rectangle"
        else body
        for body in scene.bodies
    )
    return dataclasses.replace(scene, materials=materials, bodies=bodies, haptic_rate_hz=rate_hz)


def _run(
    scene: SceneConfig, user: UserConfig, seconds: float, device: IdealDevice | None = None
) -> np.ndarray:
    dev = device or IdealDevice(IdealDeviceConfig())
    return run_virtual(scene, dev, user, seconds).ticks


def _push(newtons: float) -> UserConfig:
    return UserConfig(name=f"push_{newtons}", kind="constant_wrench", wrench=(newtons, 0.0, 0.0))


def many_contacts_case(n: int, seconds: float = 1.0) -> np.ndarray:
    """A box pressed onto n contact points (no sim: a fixed synthetic local model)."""
    engine = engine_with_contacts(n, press_n=5.0, depth_m=0.0)
    out = np.zeros(int(seconds * 1000), engine.row.dtype)
    for k in range(out.shape[0]):
        out[k] = engine.tick(1e-3)[0]
    return out


def _case(
    axis: str,
    label: str,
    scene: SceneConfig,
    user: UserConfig,
    seconds: float,
    device: IdealDevice | None = None,
) -> Case:
    ticks = _run(scene, user, seconds, device)
    return classify(axis, label, ticks, proxy_kinetic(ticks, scene))


def local_model_map(quick: bool) -> list[Case]:
    cases: list[Case] = []
    seconds = 0.6 if quick else 1.5
    push = _push(2.0)
    for k in (1e2, 1e4, 1e6) if quick else (1e2, 1e3, 1e4, 1e5, 1e6):
        for b in (20.0,) if quick else (0.0, 20.0, 300.0):
            cases.append(
                _case(
                    "contact stiffness / damping",
                    f"K={k:.0e} B={b:g}",
                    _wall_scene(k, b),
                    push,
                    seconds,
                )
            )
    for mass in (1e-3, 1.0, 1e3) if quick else (1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3):
        cases.append(
            _case(
                "tool mass (6 decades)",
                f"m={mass:g} kg",
                _wall_scene(15000.0, 20.0, mass=mass),
                push,
                seconds,
            )
        )
    for rate in (250.0, 1000.0) if quick else (250.0, 500.0, 1000.0, 2000.0, 4000.0):
        cases.append(
            _case(
                "haptic time step",
                f"dt={1e3 / rate:g} ms",
                _wall_scene(15000.0, 20.0, rate_hz=rate),
                push,
                seconds,
            )
        )
    for v0 in (2.0,) if quick else (0.1, 0.5, 1.0, 2.0):
        cases.append(
            _case("impact speed", f"v={v0:g} m/s", _wall_scene(15000.0, 20.0, v0=v0), push, seconds)
        )
    # up to 90% of the device limit: at the limit itself the device cannot hold any wall (the
    # hand overpowers it; the command stays clipped, tested in tests/test_stability.py)
    for force in (45.0,) if quick else (1.0, 10.0, 25.0, 45.0):
        cases.append(
            _case("user force", f"F={force:g} N", _wall_scene(15000.0, 20.0), _push(force), seconds)
        )
    free = load_scene("free_box")
    for n in (32,) if quick else (16, 32, 48):
        ticks = many_contacts_case(n, seconds)
        cases.append(classify("simultaneous contacts", f"n={n}", ticks, proxy_kinetic(ticks, free)))
    distal = load_scene("linkage_distal")
    for q2 in (0.0,) if quick else (0.0, 1e-6, 0.05):
        arm = dataclasses.replace(distal.tool_linkage, initial_angles=(0.3, q2, 0.4))
        scene = dataclasses.replace(distal, linkages=(arm,))
        device = IdealDevice(IdealDeviceConfig(inertia=(1.0, 1.0, 1.0)))
        cases.append(
            _case(
                "singular configuration",
                f"q2={q2:g}",
                scene,
                load_user("push_04n"),
                seconds,
                device,
            )
        )
    return cases


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="haptic-stability",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--quick", action="store_true", help="a fast subset of every axis")
    parser.add_argument("--out", type=Path, default=Path("docs/stability"))
    parser.add_argument(
        "--period-s", type=float, default=WORST_PERIOD_S, help="worst-case haptic period"
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    lines = ["# Stability report", "", f"Worst-case period T = {args.period_s * 1e6:.0f} us.", ""]
    lines += [
        "## Sampled wall vs Colgate's bound b > K T / 2 + |B|",
        "",
        "| b (N s/m) | B (N s/m) | measured K boundary (N/m) | bound 2(b-|B|)/T (N/m) | ratio |",
        "|---|---|---|---|---|",
    ]
    walls = []
    for b_device in (1.0, 5.0, 20.0):
        for b_wall in (0.0, 0.5):
            if b_wall >= b_device:
                continue
            measured = sampled_wall_boundary(b_device, b_wall, args.period_s)
            bound = colgate_bound(b_device, b_wall, args.period_s)
            walls.append((b_device, b_wall, measured, bound))
            ratio = measured / bound
            lines.append(
                f"| {b_device:g} | {b_wall:g} | {measured:.0f} | {bound:.0f} | {ratio:.3f} |"
            )
    cases = local_model_map(args.quick)
    lines += [
        "",
        "## The local model's stability map",
        "",
        "| axis | case | stable | finite at the device | energy excess (J) | max |pose| (m) "
        "| fault ticks | note |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        lines.append(
            f"| {c.axis} | {c.label} | {'yes' if c.stable else 'NO'} "
            f"| {'yes' if c.finite else 'NO'} | {c.energy_excess_j:.3g} | {c.max_abs_pose:.3g} "
            f"| {c.faults} | {c.note} |"
        )
    (args.out / "report.md").write_text("\n".join(lines) + "\n")
    _plot_walls(walls, args.out / "sampled_wall.png")
    print("\n".join(lines))
    bad = [c for c in cases if not c.finite]
    return 1 if bad else 0


def _plot_walls(walls: list[tuple[float, float, float, float]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for b_device, b_wall, measured, bound in walls:
        ax.loglog(bound, measured, "o", label=f"b={b_device:g}, B={b_wall:g}")
    lim = [min(w[3] for w in walls) * 0.5, max(w[3] for w in walls) * 2]
    ax.plot(lim, lim, "k--", lw=0.8, label="measured = bound")
    ax.fill_between(
        lim, [0.8 * v for v in lim], [1.2 * v for v in lim], color="0.9", label="within 20%"
    )
    ax.set_xlabel("Colgate bound 2(b-|B|)/T (N/m)")
    ax.set_ylabel("measured stability boundary (N/m)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
