"""The sim mirroring a shared world (docs/stations.md, DESIGN-WAVE2 §6): the router, `haptic-world`
and `sim-server --mirror` on this host's loopback, `grasp_ball` (the box held by its two
ports' anchors, no stations: the scene's users squeeze with 2 N; the sim drops a 20 g ball
onto it). From the world's log and the sim's summary:

- the landing: the impulse the world applied to the box from the sim's impulses over the
  first 100 ms of contact, against the ball's momentum at impact and its weight over those
  100 ms, m (sqrt(2 g h) + g 0.1 s);
- resting: the sim's mean force on the box against the ball's weight m g; the devices'
  commands (summed along y) against the weight of everything they hold (box, pads, ball);
  how far the pads sank when the ball came to rest against m g over the couplings' vertical
  stiffness (the ports are held on fixed anchors: the couplings carry the load);
- the box's slip against the pads through the landing, and the most it sank;
- the mirror: its lag (p50, p99), and where the sim's ball came to rest against the
  mirror's top;
- the world's work per tick, and whether its log replays bit for bit.

Then the same with `sim_contact = "shape"` (the ball a moving shape of infinite mass at
1 kHz): where the box went.

    python -m haptic_local_model.benchmarks.mirror [--seconds 4] [--rate 60] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.stations import CLI, Process, loopback_network
from haptic_local_model.haptic_server.ports import PORT_ROW_DTYPE
from haptic_local_model.haptic_server.stages.cosim import cosim_order
from haptic_local_model.haptic_server.world_runs import PORT_TICK_TOPIC, read_port_log, replay_log
from haptic_local_model.shared.config import resolve
from haptic_local_model.shared.port_config import PortSceneConfig, load_port_scene

SIM = [sys.executable, "-m", "haptic_local_model.sim_server.cli"]
SCENE = "grasp_ball"
LANDING_S = 0.1  # the landing's window for the impulse
SETTLED_S = 0.5  # resting figures from this long after the landing


def run_processes(folder: Path, seconds: float, rate_hz: float, scene: str = SCENE) -> None:
    """The router, the world (logged) and the sim for `seconds` of the sim's run; the world
    is stopped before the sim, so every logged tick is within the sim's run or before it."""
    folder.mkdir(parents=True, exist_ok=True)
    net = ["--network", loopback_network(folder)]
    started: list[Process] = []
    try:
        started.append(Process([*CLI, "router", *net]))
        started[-1].wait_ready()
        started.append(Process([*CLI, "world", *net, "--scene", scene, "--duration",
                                str(seconds + 60.0), "--log", str(folder / "world.mcap"),
                                "--json", str(folder / "world.json")]))  # fmt: skip
        started[-1].wait_ready()
        started.append(Process([*SIM, "--mirror", scene, *net, "--rate", str(rate_hz),
                                "--summary-json", str(folder / "sim.json")]))  # fmt: skip
        started[-1].wait_ready()
        time.sleep(seconds)
        if started[1].stop() != 0:
            raise RuntimeError("haptic-world did not exit cleanly")
        if started[2].stop() != 0:
            raise RuntimeError("sim-server --mirror did not exit cleanly")
    finally:
        for s in reversed(started):
            s.stop()


def figures(folder: Path, scene: PortSceneConfig) -> dict[str, Any]:
    """The figures of a run's world log and summaries (module docstring)."""
    rows, _ = read_port_log(folder / "world.mcap", PORT_TICK_TOPIC, PORT_ROW_DTYPE)
    sim = json.loads((folder / "sim.json").read_text())
    world = json.loads((folder / "world.json").read_text())
    order = cosim_order(scene)
    box, pads = order.index("box"), [order.index(p.tool) for p in scene.ports]
    ball = scene.sim_body_specs[0]
    g = -scene.gravity[1]
    dt = scene.period_s
    t = rows["t"]
    wy = rows["sim_wrench"][:, box, 1]
    touching = np.flatnonzero(wy < 0.0)
    if touching.size == 0:
        raise RuntimeError("the ball never landed on the box in the world's log")
    land = int(touching[0])
    top = rows["q"][land, 3 * box + 1] + scene.body("box").size[1] / 2
    drop = ball.position[1] - ball.radius - top
    n = round(LANDING_S / dt)
    impulse = float(np.sum(wy[land : land + n]) * dt)
    expected = -ball.mass * (math.sqrt(2.0 * g * drop) + g * LANDING_S)
    rest = t >= t[land] + SETTLED_S
    before = (t >= t[land] - 0.2) & (t < t[land] - 0.05)
    pad_y = rows["q"][:, [3 * p + 1 for p in pads]].mean(axis=1)
    k_vertical = sum(p.coupling_stiffness[1] for p in scene.ports)
    held = sum(scene.body(name).mass for name in order) + ball.mass
    slip = rows["q"][:, 3 * box + 1] - pad_y
    mirror_top = sim["mirror"]["box"][1] + scene.body("box").size[1] / 2
    return {
        "ticks": len(rows),
        "landing_s": float(t[land]),
        "drop_m": float(drop),
        "landing_impulse_ns": impulse,
        "landing_impulse_expected_ns": expected,
        "resting_s": float(np.sum(rest) * dt),
        "wrench_y_n": float(wy[rest].mean()),
        "ball_weight_n": -ball.mass * g,
        "commands_y_n": float(rows["command"][rest, :, 1].sum(axis=1).mean()),
        "held_weight_n": held * g,
        "pads_sank_m": float(pad_y[before].mean() - pad_y[rest].mean()),
        "pads_sank_expected_m": ball.mass * g / k_vertical,
        "slip_m": float(np.ptp(slip[land - 50 :])),
        "box_lowest_y_m": float(rows["q"][land:, 3 * box + 1].min()),
        "lag_mm": sim["lag_mm"],
        "ball_above_mirror_m": sim["sim_bodies"]["ball"]["end"][1] - ball.radius - mirror_top,
        "sim_steps": sim["steps"],
        "sim_rejected": sim["world_bodies_rejected"],
        "world_work_us": world["work_us"],
        "world_sim": world["sim"],
    }


def shape_figures(folder: Path, scene: PortSceneConfig) -> dict[str, Any]:
    """With the sim's bodies as moving shapes: where the box went."""
    rows, _ = read_port_log(folder / "world.mcap", PORT_TICK_TOPIC, PORT_ROW_DTYPE)
    box = 3 * scene.cosim_order().index("box")
    return {
        "box_start_y_m": float(rows["q"][0, box + 1]),
        "box_lowest_y_m": float(rows["q"][:, box + 1].min()),
        "box_end_y_m": float(rows["q"][-1, box + 1]),
        "collisions": int(rows["collisions"][-1]),
    }


def run(seconds: float, rate_hz: float, folder: Path) -> dict[str, Any]:
    """Both ways of meeting the sim's bodies (module docstring), one after the other."""
    run_processes(folder / "wrench", seconds, rate_hz)
    out = figures(folder / "wrench", load_port_scene(SCENE))
    compared, differs = replay_log(folder / "wrench" / "world.mcap")
    out["replayed_ticks"], out["replay_differs_at"] = compared, differs
    text = resolve("ports", SCENE).read_text()
    shape = folder / "grasp_ball_shape.toml"
    shape.write_text(
        text.replace('sim_bodies = ["ball"]', 'sim_bodies = ["ball"]\nsim_contact = "shape"')
    )
    run_processes(folder / "shape", seconds, rate_hz, str(shape))
    out["shape"] = shape_figures(folder / "shape", load_port_scene(str(shape)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="the sim's run (s)")
    ap.add_argument("--rate", type=float, default=60.0, help="the sim's rate (Hz)")
    ap.add_argument("--out", type=Path, default=None, help="keep the logs here")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        out = run(args.seconds, args.rate, folder)
    print(json.dumps(out, indent=2))
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
