"""The figure of a logged run (`haptic-replay --plot`): hand and VM paths among the scene's
static bodies, forces by source, drift and timing."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.haptic_server.harness.summary import LATE_TICK_US, ReplayError, config_name
from haptic_local_model.haptic_server.log import LogContents
from haptic_local_model.shared.config import BodySpec, static_bodies

FORCE_SOURCES = (
    "f_user", "f_contact", "f_impulse", "f_bias", "f_penalty", "f_coordination", "f_damping",
)  # fmt: skip
TIMING_WINDOW_TICKS = 100  # the timing panel shows max and median per 100 ticks
PLOT_BULK_PERCENTILE = 99.5  # force axes show this much of every curve; spikes go beyond
STATIC_COLOR = "0.6"  # static bodies: grey, as in the Foxglove view
CAP_POINTS = 12  # points on each round end of a segment's outline
VIEW_MARGIN_MM = 100.0  # the path panel shows the bodies this far around the path at least


def plot_run(log: LogContents, out: Path | str, title: str = "") -> Path:
    """One figure of the run (run_figure), saved to `out`."""
    fig = run_figure(log, title)
    import matplotlib.pyplot as plt  # after run_figure chose the backend

    out_path = Path(out)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path


def run_figure(log: LogContents, title: str = "") -> Any:
    """One figure of the run: trajectories (hand vs VM) among the scene's static bodies,
    forces by source, drift, timing. The caller saves and closes it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ticks = log.ticks
    if len(ticks) == 0:
        raise ReplayError("the log holds no ticks: nothing to plot")
    ready = ticks[ticks["update_seq"] >= 0]  # the VM exists once the first update arrived
    title = title or _default_title(log)
    if len(ready) == 0:
        ready = ticks
        title += " — no update was received"
    t = ready["t"]
    hand, vm = ready["device_pose"], ready["vm_pose"]
    fig, axes = plt.subplots(3, 2, figsize=(14, 12), constrained_layout=True)
    fig.suptitle(title)

    ax = axes[0, 0]
    draw_static_bodies(ax, log.metadata.get("configs", {}).get("scene"))
    ax.plot(hand[:, 0] * 1e3, hand[:, 1] * 1e3, lw=1.2, label="hand (device)")
    ax.plot(vm[:, 0] * 1e3, vm[:, 1] * 1e3, lw=1.0, ls="--", label="VM operational point")
    ax.plot(*(hand[0, :2] * 1e3), "ko", ms=4, label="start")
    ax.plot(*(hand[-1, :2] * 1e3), "ks", ms=4, label="end")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title="trajectories in the plane")
    _frame_path(ax, np.concatenate([hand[:, :2], vm[:, :2]]) * 1e3)
    ax.set_aspect("equal", adjustable="datalim")  # 1 mm is 1 mm along both axes
    # beside the panel: inside, it would hide the path where it meets a wall
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))

    ax = axes[0, 1]
    for c, name in enumerate(("x", "y")):
        line = ax.plot(t, hand[:, c] * 1e3, lw=1.2, label=f"hand {name}")[0]
        ax.plot(t, vm[:, c] * 1e3, lw=1.0, ls="--", color=line.get_color(), label=f"VM {name}")
    ax.set(xlabel="run time (s)", ylabel="position (mm)", title="hand vs VM over time")
    ax.legend(fontsize=8, ncol=2)

    ax = axes[1, 0]
    curves = {}
    for name in (*FORCE_SOURCES, "wrench_command"):
        mag = np.hypot(ready[name][:, 0], ready[name][:, 1])
        if np.any(mag):
            curves[name.removeprefix("f_").replace("wrench_", "")] = mag
    top = _robust_top(list(curves.values()))
    for label, mag in curves.items():
        style = {"color": "k", "lw": 1.4} if label == "command" else {"lw": 0.9}
        ax.plot(t, mag, label=_peak_label(label, mag, top, "N"), **style)
    ax.set_ylim(0.0, top)
    ax.set(xlabel="run time (s)", ylabel="|(fx, fy)| (N)", title="forces on the device by source")
    ax.legend(fontsize=8, ncol=2)

    ax = axes[1, 1]
    pushes = {}
    for c, name in enumerate(("fx", "fy")):
        pushes[f"hand {name}"] = ready["hand_wrench"][:, c]
        pushes[f"command {name}"] = ready["wrench_command"][:, c]
    top = _robust_top([np.abs(v) for v in pushes.values()])
    for i, (label, v) in enumerate(pushes.items()):
        ax.plot(t, v, lw=1.0, ls="-" if label.startswith("hand") else "--", color=f"C{i // 2}",
                label=_peak_label(label, np.abs(v), top, "N"))  # fmt: skip
    ax.set_ylim(-top, top)
    ax.set(xlabel="run time (s)", ylabel="force (N)", title="the user's push and what was rendered")
    ax.legend(fontsize=8, ncol=2)

    ax = axes[2, 0]
    drift = np.hypot(*(hand[:, :2] - vm[:, :2]).T) * 1e3
    ax.plot(t, drift, lw=1.0, color="C0", label="|x_h - x_VM| (mm)")
    ax.set(xlabel="run time (s)", ylabel="drift (mm)", title="drift and contact")
    contact = ready["n_active"] > 0
    if contact.any():
        ax.fill_between(t, 0, drift.max() * 1.05, where=contact, color="C2", alpha=0.15,
                        step="mid", label="in contact")  # fmt: skip
    twin = ax.twinx()
    twin.plot(t, np.abs(hand[:, 2] - vm[:, 2]), lw=0.8, color="C3", label="|θ_h - θ_VM| (rad)")
    twin.set_ylabel("angular drift (rad)", color="C3")
    ax.legend(loc="upper left", fontsize=8)
    twin.legend(loc="upper right", fontsize=8)

    ax = axes[2, 1]
    _plot_timing(ax, log)
    span = (float(ticks["t"][0]), float(ticks["t"][-1] + ticks["dt"][-1]))
    for ax in (axes[0, 1], axes[1, 0], axes[1, 1], axes[2, 0], axes[2, 1]):
        ax.set_xlim(*span)  # the same run time everywhere: no update yet shows as a gap
    return fig


def draw_static_bodies(ax: Any, scene_text: str | None, scale: float = 1e3) -> list[Any]:
    """The scene's static bodies (walls, floors) as patches on `ax`, one per body, in units
    of m / `scale` (mm by default); none if the log's scene text is missing or does not load.
    Moving and dynamic bodies are the sim's and are not in the log."""
    patches: list[Any] = []
    for body in static_bodies(scene_text):
        patch = _body_patch(body, scale)
        patch.set(facecolor=STATIC_COLOR, edgecolor=STATIC_COLOR, lw=0.5, gid=body.name,
                  label="_nolegend_" if patches else "static bodies")  # fmt: skip
        ax.add_patch(patch)
        patches.append(patch)
    return patches


def _frame_path(ax: Any, points: np.ndarray) -> None:
    """Autoscale to the path and the bodies around it: everything drawn, but no further from
    the path than its own extent or VIEW_MARGIN_MM (a floor 0.8 m long would shrink a path of
    a few mm to a dot). The equal aspect then widens one of the two ranges to fit the panel."""
    drawn = ax.dataLim.get_points()
    finite = points[np.isfinite(points).all(axis=1)]
    if finite.size == 0:
        return
    low, high = finite.min(axis=0), finite.max(axis=0)
    pad = max(VIEW_MARGIN_MM, float((high - low).max()))
    ax.dataLim.set_points(
        np.array([np.maximum(drawn[0], low - pad), np.minimum(drawn[1], high + pad)])
    )
    ax.autoscale_view()


def _body_patch(body: BodySpec, scale: float) -> Any:
    """A static body's shape (BodySpec: a box or circle about its position, or a segment of
    half-thickness `radius` between its end points), placed and turned as the sim does."""
    from matplotlib.patches import Circle, Polygon, Rectangle

    x, y, a = body.position[0] * scale, body.position[1] * scale, body.angle
    if body.shape == "box":
        w, h = body.size[0] * scale, body.size[1] * scale
        return Rectangle(
            (x - w / 2, y - h / 2), w, h, angle=math.degrees(a), rotation_point="center"
        )
    if body.shape == "circle":
        return Circle((x, y), body.radius * scale)
    p, q = ((wx * scale, wy * scale) for wx, wy in (body.to_world(*body.a), body.to_world(*body.b)))
    return Polygon(_capsule(p, q, body.radius * scale), closed=True)


def _capsule(p: tuple[float, float], q: tuple[float, float], r: float) -> np.ndarray:
    """The outline of the points within `r` of the segment p-q: a round end about q, then
    one about p."""
    heading = math.atan2(q[1] - p[1], q[0] - p[0])
    arc = heading + np.linspace(-math.pi / 2, math.pi / 2, CAP_POINTS)
    ends = [(q, arc), (p, arc + math.pi)]
    return np.vstack([np.c_[e[0] + r * np.cos(t), e[1] + r * np.sin(t)] for e, t in ends])


def _robust_top(curves: list[np.ndarray]) -> float:
    """An axis limit that shows the bulk of every curve: brief spikes (a collision impulse
    lasts one tick) are cut at it and their peak is given in the legend instead."""
    bulk = max((float(np.percentile(c, PLOT_BULK_PERCENTILE)) for c in curves), default=0.0)
    return 1.2 * bulk if bulk > 0 else 1.0


def _peak_label(label: str, values: np.ndarray, top: float, unit: str) -> str:
    peak = float(values.max())
    return f"{label} (peak {peak:.3g} {unit})" if peak > top else label


def _plot_timing(ax: Any, log: LogContents) -> None:
    ticks = log.ticks
    t = ticks["t"]
    lateness, work = ticks["lateness_us"], ticks["work_us"]
    ax.set(xlabel="run time (s)", title="timing per tick")
    if not np.any(lateness) and not np.any(work):
        ax.text(0.5, 0.5, "virtual clock: no wall-clock timing", ha="center", va="center",
                transform=ax.transAxes)  # fmt: skip
        return
    window = TIMING_WINDOW_TICKS
    n = len(t) // window * window
    if n == 0:
        window, n = 1, len(t)
    t_win = t[:n].reshape(-1, window)[:, 0]
    floor = 0.1  # us: the log axis starts here (a tick on time has lateness ~0)
    for values, color, name in ((lateness, "C0", "lateness"), (work, "C1", "work")):
        v = values[:n].reshape(-1, window)
        ax.plot(t_win, np.maximum(v.max(axis=1), floor), color=color, lw=1.0,
                label=f"{name}, max per {window} ticks")  # fmt: skip
        ax.plot(t_win, np.maximum(np.median(v, axis=1), floor), color=color, lw=0.8, ls=":",
                label=f"{name}, median per {window} ticks")  # fmt: skip
    late = lateness > LATE_TICK_US
    if late.any():
        ax.plot(t[late], lateness[late], "rx", ms=5, label=f"late > 1 ms ({late.sum()})")
    ax.axhline(LATE_TICK_US, color="r", lw=0.6, ls=":")
    tick_t = {int(k): float(v) for k, v in zip(ticks["tick"], t, strict=True)}
    trips = [tick_t[int(ev["tick"])] for ev in log.events
             if ev["kind"] == "watchdog" and int(ev["tick"]) in tick_t]  # fmt: skip
    for trip in trips:
        ax.axvline(trip, color="m", lw=0.8)
    if trips:
        ax.plot([], [], color="m", lw=0.8, label=f"watchdog trips ({len(trips)})")
    rejected = [tick_t[int(u["tick"])] for u in log.updates
                if not u.get("installed") and int(u["tick"]) in tick_t]  # fmt: skip
    if rejected:
        ax.plot(rejected, [floor * 2] * len(rejected), "k|", ms=10,
                label=f"rejected updates ({len(rejected)})")  # fmt: skip
    ax.set_yscale("log")
    ax.set_ylim(floor, 30.0 * max(float(lateness.max()), float(work.max()), LATE_TICK_US))
    ax.set_ylabel("µs")
    ax.legend(fontsize=8, loc="upper left", ncol=2)


def _default_title(log: LogContents) -> str:
    configs = log.metadata.get("configs", {})
    run = log.metadata.get("run", {})
    return (
        f"{config_name(configs.get('scene'))} / {config_name(configs.get('device'), 'model')} / "
        f"{config_name(configs.get('user'))} — {run.get('clock', '?')} clock, "
        f"{run.get('start_time_utc', '')}"
    )
