"""Force jumps at local-model updates while sliding along a wall, with and without blending.

A box pressed into a floor with about 1 N is dragged 20 cm along it (`wall_slide` scene,
`slide` hand) in the virtual clock, so it slides across dozens of geometry updates. Each
case runs with the scene's cross-fade (blend_ms = 8) and without it (blend_ms = 0), at the
scene's 30 Hz sim rate and at 60 Hz. Over the sliding ticks (n_active > 0 on the tick and
the one before, and the proxy moving faster than SLIDING_SPEED_M_PER_S: the press at the
start and the stop at the end of the drag are transients of the hand, not sliding) the
tick-to-tick change |dF| of the rendered force (wrench_command, x and y) and of the contact
force on the proxy (contact_force_world) is split into ticks at which an update was
installed (update_seq changed) and the other ticks; their max and p99 are printed, and
plotted with the force around a few updates.

The floor of `wall_slide` is flat and static: every update describes the same half-plane
(the box's corners, normal +y), so old and new models render the same force and blending
has nothing to smooth. A contrast case, built here from the same scene, makes the floor
kinematic and oscillate 1 mm vertically: the haptic side extrapolates each update's contact
points by their velocity, which drifts from the truth between updates, so each update moves
the rendered surface, the step that the cross-fade exists to spread out.

    python -m haptic_local_model.benchmarks.blending [--seconds 3.5] [--out docs/figures/blending.png]
                                  [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared.config import SceneConfig, load_scene, load_user

SCENE = "wall_slide"
USER = "slide"
RATES_HZ = (30.0, 60.0)
RUN_S = 3.5  # press 0.3 s, hold 0.2 s, drag 2.5 s, hold 0.5 s (configs/users/slide.toml)
FLOOR = "floor"
MOVING_FLOOR_AMPLITUDE_M = 1.0e-3  # contrast case: the floor oscillates vertically
MOVING_FLOOR_PERIOD_S = 1.0
PLOT_WINDOW_S = (1.50, 1.64)  # mid-slide: four or five 30 Hz updates
CASES = ("static floor", "moving floor")
SLIDING_SPEED_M_PER_S = 0.02  # a quarter of the drag speed (8 cm/s)


@dataclass
class JumpMetrics:
    case: str
    sim_rate_hz: float
    blend_ms: float
    sliding_ticks: int  # in contact on this tick and the one before, and moving
    update_instants: int  # of those, the ones at which an update was installed
    rendered_update_max_n: float  # |d wrench_command[xy]| at update instants
    rendered_update_p99_n: float
    rendered_other_max_n: float  # ... at the other sliding ticks
    rendered_other_p99_n: float
    contact_update_max_n: float  # |d contact_force_world[xy]| at update instants
    contact_update_p99_n: float
    contact_other_max_n: float
    contact_other_p99_n: float


def scene_variant(case: str, sim_rate_hz: float, blend_ms: float) -> SceneConfig:
    """wall_slide at the given sim rate and blend time; "moving floor" oscillates the floor."""
    scene = load_scene(SCENE)
    bodies = scene.bodies
    if case == "moving floor":
        bodies = tuple(
            dataclasses.replace(
                b,
                kind="kinematic",
                oscillation_amplitude=(0.0, MOVING_FLOOR_AMPLITUDE_M),
                oscillation_period_s=MOVING_FLOOR_PERIOD_S,
            )
            if b.name == FLOOR
            else b
            for b in bodies
        )
    return dataclasses.replace(
        scene,
        sim_rate_hz=sim_rate_hz,
        bodies=bodies,
        rendering=dataclasses.replace(scene.rendering, blend_ms=blend_ms),
    )


def tick_jumps(ticks: np.ndarray, field: str) -> np.ndarray:
    """|F[k] - F[k-1]| of the x, y components of `field` (0 at the first tick)."""
    f = ticks[field][:, :2]
    out = np.zeros(len(ticks))
    out[1:] = np.hypot(f[1:, 0] - f[:-1, 0], f[1:, 1] - f[:-1, 1])
    return out


def masks(ticks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sliding: in contact on this tick and the one before and moving; an update was
    installed at this tick)."""
    active = ticks["n_active"] > 0
    moving = np.hypot(ticks["vm_twist"][:, 0], ticks["vm_twist"][:, 1]) > SLIDING_SPEED_M_PER_S
    sliding = np.zeros(len(ticks), bool)
    sliding[1:] = active[1:] & active[:-1] & moving[1:]
    seq = ticks["update_seq"]
    update = np.zeros(len(ticks), bool)
    update[1:] = seq[1:] != seq[:-1]
    return sliding, update


def measure(
    case: str, sim_rate_hz: float, blend_ms: float, seconds: float = RUN_S
) -> tuple[JumpMetrics, np.ndarray]:
    scene = scene_variant(case, sim_rate_hz, blend_ms)
    ticks = run_virtual(scene, load_device("ideal"), load_user(USER), seconds).ticks
    sliding, update = masks(ticks)
    at_update = sliding & update
    other = sliding & ~update
    stats: dict[str, float] = {}
    for name, field in (("rendered", "wrench_command"), ("contact", "contact_force_world")):
        jump = tick_jumps(ticks, field)
        for part, sel in (("update", at_update), ("other", other)):
            values = jump[sel] if sel.any() else np.zeros(1)
            stats[f"{name}_{part}_max_n"] = float(values.max())
            stats[f"{name}_{part}_p99_n"] = float(np.percentile(values, 99))
    metrics = JumpMetrics(
        case=case,
        sim_rate_hz=sim_rate_hz,
        blend_ms=blend_ms,
        sliding_ticks=int(sliding.sum()),
        update_instants=int(at_update.sum()),
        **stats,
    )
    return metrics, ticks


def measure_all(seconds: float = RUN_S) -> list[tuple[JumpMetrics, np.ndarray]]:
    blend_ms = load_scene(SCENE).rendering.blend_ms
    return [
        measure(case, rate, blend, seconds)
        for case in CASES
        for rate in RATES_HZ
        for blend in (blend_ms, 0.0)
    ]


def plot(results: list[tuple[JumpMetrics, np.ndarray]], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(14, 7.5))
    grid = fig.add_gridspec(2, 3, width_ratios=(1, 1, 1.1))
    rate = RATES_HZ[0]
    first_f = first_d = None
    for col, case in enumerate(CASES):
        runs = sorted(
            ((m, t) for m, t in results if m.case == case and m.sim_rate_hz == rate),
            key=lambda r: r[0].blend_ms,
        )
        ax_f = fig.add_subplot(grid[0, col], sharey=first_f)
        ax_d = fig.add_subplot(grid[1, col], sharex=ax_f, sharey=first_d)
        first_f, first_d = first_f or ax_f, first_d or ax_d
        for m, ticks in runs:
            t = ticks["t"]
            win = (t >= PLOT_WINDOW_S[0]) & (t <= PLOT_WINDOW_S[1])
            blended = m.blend_ms > 0
            style: dict[str, Any] = (
                {"lw": 1.2, "color": "C0", "zorder": 3}
                if blended
                else {"lw": 3.5, "color": "C1", "alpha": 0.5, "zorder": 2}
            )
            label = f"blend {m.blend_ms:g} ms" if blended else "no blending"
            ax_f.plot(t[win], ticks["wrench_command"][win, 1], label=label, **style)
            jump = tick_jumps(ticks, "wrench_command")
            ax_d.plot(t[win], jump[win], marker="o", ms=2.5 if blended else 5, label=label, **style)
            _, update = masks(ticks)
            for ti in t[win & update]:
                for ax in (ax_f, ax_d):
                    ax.axvline(ti, color="k", lw=0.6, ls=":", zorder=1)
        gap = np.abs(runs[0][1]["wrench_command"] - runs[-1][1]["wrench_command"]).max()
        ax_f.text(
            0.02,
            0.04,
            f"with and without blending differ by at most {gap:.1e} N",
            transform=ax_f.transAxes,
            fontsize=8,
        )
        ax_f.set_title(f"{case}, sim {rate:g} Hz (dotted: updates installed)", fontsize=10)
        ax_f.set_ylabel("rendered normal force $F_y$ (N)")
        ax_d.set_ylabel("tick-to-tick |ΔF| of the rendered force (N)")
        ax_d.set_xlabel("time (s)")
        ax_f.legend(fontsize=8, loc="upper right")
    ax_b = fig.add_subplot(grid[:, 2])
    pairs = [(c, r) for c in CASES for r in RATES_HZ]
    width = 0.38
    for i, (case, rate_b) in enumerate(pairs):
        for j, blended in enumerate((True, False)):
            m = next(
                m
                for m, _ in results
                if m.case == case and m.sim_rate_hz == rate_b and (m.blend_ms > 0) == blended
            )
            x = i + (j - 0.5) * width
            legend = (f"blend {m.blend_ms:g} ms" if blended else "no blending") if i == 0 else None
            ax_b.bar(
                x, m.rendered_update_max_n, width, color="C0" if blended else "C1", label=legend
            )
            ax_b.text(
                x, m.rendered_update_max_n, f"{m.rendered_update_max_n:.2g}", ha="center",
                va="bottom", fontsize=7,
            )  # fmt: skip
            ax_b.plot(
                [x - width / 2, x + width / 2],
                [m.rendered_other_p99_n] * 2,
                color="k",
                lw=1.5,
                label="p99 at the other sliding ticks" if i == 0 and j == 0 else None,
            )
    ax_b.set_xticks(range(len(pairs)), [f"{c}\nsim {r:g} Hz" for c, r in pairs], fontsize=8)
    ax_b.set_yscale("log")
    ax_b.set_ylabel("largest tick-to-tick |ΔF| at an update instant (N, log)")
    ax_b.set_title("rendered force, sliding: the largest jump at an update", fontsize=10)
    ax_b.legend(fontsize=8)
    fig.suptitle(
        "A box pressed into a floor with ~1 N and slid 20 cm across geometry updates "
        "(moving floor: ±1 mm vertical oscillation, a contrast case)"
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=RUN_S)
    parser.add_argument("--out", type=Path, default=Path("docs/figures/blending.png"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    results = measure_all(args.seconds)
    head = f"{'upd max':>9} {'upd p99':>9} {'oth max':>9} {'oth p99':>9}"
    print(f"{'':<13} {'sim':>4} {'blend':>5} {'slid':>5} {'upd':>4}  "
          f"{'rendered |dF| (N)':^39}  {'contact |dF| (N)':^39}")  # fmt: skip
    print(f"{'case':<13} {'Hz':>4} {'ms':>5} {'ticks':>5} {'':>4}  {head}  {head}")
    for m, _ in results:
        print(
            f"{m.case:<13} {m.sim_rate_hz:4.0f} {m.blend_ms:5.1f} {m.sliding_ticks:5d} "
            f"{m.update_instants:4d}  "
            f"{m.rendered_update_max_n:9.2e} {m.rendered_update_p99_n:9.2e} "
            f"{m.rendered_other_max_n:9.2e} {m.rendered_other_p99_n:9.2e}  "
            f"{m.contact_update_max_n:9.2e} {m.contact_update_p99_n:9.2e} "
            f"{m.contact_other_max_n:9.2e} {m.contact_other_p99_n:9.2e}"
        )
    plot(results, args.out)
    print(f"plot: {args.out}")
    if args.json:
        args.json.write_text(json.dumps([asdict(m) for m, _ in results], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
