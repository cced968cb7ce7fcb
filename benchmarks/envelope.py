"""How close every shipped scene comes to its safety envelope (docs/security.md).

The haptic server refuses an update beyond the scene's envelope (haptic_server/stages/
plausible.py) and its guard trips on a proxy beyond it or a port that gives out more energy
than the passivity observer allows (haptic_server/stages/safety.py). Bounds that a scene's
own sim reaches would refuse its own updates or trip in normal use: this runs every shipped
scene with its usual user on every shipped device on the virtual clock and reports, per
figure, the largest value over its bound (a ratio; 1 would trip). It fails (exit 1) if any
update of a scene's own sim was refused, any guard tripped, or any ratio exceeds --max-ratio.

    python -m haptic_local_model.benchmarks.envelope [--seconds 10] [--max-ratio 0.5] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.virtual_clock import USERS
from haptic_local_model.haptic_server.harness.replay import engine_from_configs
from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.haptic_server.stages.plausible import RATIO_NAMES
from haptic_local_model.shared.config import CONFIG_ROOT, SceneConfig, load_config_text
from haptic_local_model.shared.kinematics import MAX_DOF, fastest_spin, mass_matrix_and_gravity
from haptic_local_model.shared.tool_chain import tool_chain

DEVICES = ("ideal", "twin_pantograph", "maglev")
USER_OF = {**USERS, "crowd": "plough"}
GUARD_NAMES = ("proxy_speed", "proxy_spin", "proxy_energy", "port_energy")


def scene_figures(scene: str, device: str, seconds: float) -> dict[str, Any]:
    """One virtual-clock run: the largest ratio of each update and guard figure."""
    user = USER_OF.get(scene, "swing")
    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "run.mcap"
        run_virtual_named(scene, device, user, seconds, log_path)
        log = read_log(log_path)
    engine = engine_from_configs(log.metadata["configs"], log.metadata.get("run"))
    env = engine.install[0]["envelope"][0]
    worst = dict.fromkeys(RATIO_NAMES, 0.0)
    refused = 0
    for rec in log.updates:
        reason = engine.receive(base64.b64decode(rec["raw_b64"]), float(rec["latency_s"]))
        refused += reason != ""
        for k, name in enumerate(RATIO_NAMES):
            worst[name] = max(worst[name], float(env["ratios"][k]))
    worst.update(_guard_figures(log.ticks, engine, log.metadata["configs"]["scene"]))
    faults = int(np.count_nonzero(np.diff(log.ticks["fault"], prepend=0) > 0))
    return {"scene": scene, "device": device, "user": user, "updates": len(log.updates),
            "refused": refused, "guard_trips": faults, "ratios": worst}  # fmt: skip


def _guard_figures(ticks: np.ndarray, engine: Any, scene_text: str) -> dict[str, float]:
    """The proxy's speed, spin and kinetic energy and the port energy, over the guard's bounds."""
    p = engine.params[0]
    chain = tool_chain(load_config_text(SceneConfig, scene_text, "log")).chain
    d = int(chain[0]["dof"])
    qd = ticks["proxy_qd"][:, :d]
    speed = np.hypot(ticks["vm_twist"][:, 0], ticks["vm_twist"][:, 1])
    spin = fastest_spin(chain[0]["joint_types"][:d], chain[0]["parents"][:d], qd)
    work = (np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF), np.zeros((3, MAX_DOF)))
    mass, grav = np.zeros((d, d)), np.zeros(d)
    energy = np.zeros(len(ticks))
    for k in np.flatnonzero(np.any(qd != 0.0, axis=1)):
        mass_matrix_and_gravity(chain, np.zeros(2), ticks["proxy_q"][k, :d], work, mass, grav)
        energy[k] = 0.5 * qd[k] @ mass @ qd[k]
    return {
        "proxy_speed": float(speed.max()) / float(p["guard_max_speed"]),
        "proxy_spin": float(spin.max()) / float(p["guard_max_angular_speed"]),
        "proxy_energy": float(energy.max()) / float(p["guard_max_energy"]),
        "port_energy": float(ticks["port_energy"].max()) / float(p["passivity_limit_j"]),
    }


def report(results: list[dict[str, Any]], seconds: float) -> str:
    names = (*RATIO_NAMES, *GUARD_NAMES)
    lines = [
        "# The safety envelope's margin on every shipped scene",
        "",
        f"`python -m haptic_local_model.benchmarks.envelope --seconds {seconds:g}`: each scene with its usual user,"
        " virtual clock. A cell is the run's largest figure over its bound (1 refuses the update"
        " or trips the guard); `refused` counts the sim's own updates refused (must be 0).",
        "",
        "| scene | device | updates | refused | trips | " + " | ".join(names) + " |",
        "|---|---|---|---|---|" + "---|" * len(names),
    ]
    for r in results:
        cells = " | ".join(f"{r['ratios'][n]:.3f}" for n in names)
        lines.append(
            f"| {r['scene']} | {r['device']} | {r['updates']} | {r['refused']} |"
            f" {r['guard_trips']} | {cells} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--max-ratio", type=float, default=0.5)
    parser.add_argument("--scenes", nargs="*", default=None)
    parser.add_argument("--devices", nargs="*", default=list(DEVICES))
    parser.add_argument("--out", type=Path, default=None, help="write envelope.md and .json here")
    args = parser.parse_args(argv)
    scenes = args.scenes or sorted(p.stem for p in (CONFIG_ROOT / "scenes").glob("*.toml"))
    results = []
    for scene in scenes:
        for device in args.devices:
            r = scene_figures(scene, device, args.seconds)
            results.append(r)
            top = max(r["ratios"], key=lambda k: r["ratios"][k])
            print(
                f"{scene:<20}{device:<16}refused {r['refused']:<3} trips {r['guard_trips']:<3}"
                f" worst {top} {r['ratios'][top]:.3f}",
                flush=True,
            )
    text = report(results, args.seconds)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "envelope.md").write_text(text)
        (args.out / "envelope.json").write_text(json.dumps(results, indent=1))
    bad = [
        r for r in results
        if r["refused"] or r["guard_trips"] or max(r["ratios"].values()) > args.max_ratio
    ]  # fmt: skip
    for r in bad:
        print(f"FAIL {r['scene']} on {r['device']}: {r}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
