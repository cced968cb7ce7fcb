"""The error-vs-cost front: the local model against what a user would build instead.

Three ways to render the same scene to the same simulated device and hand, in the virtual
clock (1 kHz haptic loop):

- **local model** (this project): the world in pymunk at 30, 60 or 120 Hz, the local model
  rendered at 1 kHz (`local_model`);
- **pymunk in the loop** (the CHAI3D way): the whole world stepped every 1 ms tick, the
  device servoed to the tool and the tool pulled to the device by a virtual coupling
  (`virtual_coupling_foh` with the sim at the haptic rate, the setpoint held; the spring on in
  free space and its damper on the relative velocity, as a virtual coupling has them; seed
  002's gains, and the substeps a stable pymunk needs for them);
- **60 Hz sim + virtual coupling** (the AMBF way): the world at 60 Hz, the device servoed to
  the tool's last pose (zero-order hold); and seed 002's first-order hold of that pose (FOH).

Scenes and their errors (each against a reference the rendering does not contain):
- **linkage** (`linkage_distal`, held at the distal COM, a constant 0.4 N push, device
  `ideal_identity` started on the operational point, 5 s): RMS distance of the device (what
  the hand holds) from the independent reference, the VM alone driven by the hand
  (benchmarks/linkage.py: RNEA and solve_ivp);
- **wall** (`wall_push`, 2 N, device `ideal`, 5 s): the device's penetration against F/K: its
  peak (the impact's transient), its error after 2 s and over the last 0.5 s (what stiffness
  the hand feels), the time it takes to settle within 5 %, contact losses, and the energy the
  device gave the hand (port energy, passive if <= 0);
- **testbed** (`testbed`, the swinging hand, device `ideal`, 5 s): the device against a
  fine-step reference: the same pymunk world stepped at 10 kHz with the hand's spring acting
  on the operational point directly (a perfectly transparent device): the RMS over the first
  second, how long the device stays within 1 mm of it, and the RMS over 5 s (after the
  impacts the paths part by chance). The reference's contacts are pymunk's, not the penalty
  walls of the local model (a wall's 15 kN/m under the hand's 3 N moves 0.2 mm): it favours
  the pymunk ways by that much.

Cost: wall-clock ms per simulated second of what each way needs: the local model's sim step,
local model, install and ticks; the alternatives' sim steps and ticks (they need no local
model). One process, runs interleaved, the lowest of `--repeat` costs.

    python -m haptic_local_model.benchmarks.front [--repeat 3] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.linkage import reference_error_mm
from haptic_local_model.benchmarks.wall_push import device_depth, impact, port_energy_j
from haptic_local_model.device_models.registry import device_config, device_from_text
from haptic_local_model.haptic_server.harness.virtual import VirtualResult, run_virtual
from haptic_local_model.haptic_server.users import hand_wrench, user_record
from haptic_local_model.shared import coupling
from haptic_local_model.shared.config import SceneConfig, load_scene, load_user
from haptic_local_model.shared.kinematics import MAX_DOF, link_frames, point_jacobian, point_on_link
from haptic_local_model.sim_server.world import SimWorld

HAPTIC_HZ = 1000.0
WAYS = {
    "local_model": "local model (this project)",
    "pymunk_in_loop": "pymunk in the 1 kHz loop + virtual coupling (CHAI3D way)",
    "vc_zoh": "sim + virtual coupling, pose held (AMBF way)",
    "vc_foh": "sim + virtual coupling, pose interpolated (seed 002)",
}
LOCAL_RATES = (30.0, 60.0, 120.0)
SETTLE_BAND = 0.05
REFERENCE_STEP_S = 1e-4  # the testbed's fine-step reference: pymunk at 10 kHz
#: the swing is a contact-rich path: once the device and the reference part at an impact,
#: they stay apart by chance (tens of mm over 5 s, whichever way). So the testbed's error is
#: the RMS over the first second (the free swing to the wall) and how long the device follows
#: the reference within 1 mm; the 5 s RMS is reported beside them
TESTBED_FIRST_S, TESTBED_BAND_MM = 1.0, 1.0

#: scene, device, user, seconds, the device starting on the operational point
SCENES = {
    "linkage": ("linkage_distal", "ideal_identity", "push_04n", 5.0),
    "wall": ("wall_push", "ideal", "push_2n", 5.0),
    "testbed": ("testbed", "ideal", "swing", 5.0),
}


@dataclass
class FrontPoint:
    scene: str
    way: str
    sim_hz: float
    substeps: int  # pymunk steps per sim period (a coupling's: what its stability needs)
    cost_ms_per_sim_s: float
    error: dict[str, float]


def configure(scene: SceneConfig, way: str, sim_hz: float, factor: int = 1) -> SceneConfig:
    """The scene rendered `way` at `sim_hz` (the in-loop way: at the scene's haptic rate,
    HAPTIC_HZ in every scene here; hapticbench's stable stiffness varies it). A virtual
    coupling's sim takes the substeps its stiff spring needs to be stable in pymunk (seed
    002's gains; shared/coupling.py), times `factor` (stable_configuration): the cost of that
    way, counted."""
    method = "local_model" if way == "local_model" else "virtual_coupling_foh"
    # a virtual coupling: its spring always on (it holds the mechanism too), its damper on the
    # relative velocity (seed 002's absolute damping makes the tool viscous)
    rendering = dataclasses.replace(
        scene.rendering, method=method, foh_free_space_force=True,  # type: ignore[arg-type]
        foh_relative_damping=True,
    )  # fmt: skip
    rate = scene.haptic_rate_hz if way == "pymunk_in_loop" else sim_hz
    substeps = scene.sim_substeps
    if way != "local_model":
        substeps = max(substeps, factor * coupling_substeps_needed(scene, rate))
    return dataclasses.replace(
        scene, rendering=rendering, sim_rate_hz=rate, sim_substeps=substeps,
        initial_device_offset=(0.0, 0.0, 0.0),
    )  # fmt: skip


#: a virtual coupling's substeps are doubled up to this factor until the scene's run stays
#: within the protocol's bounds: the linkage's chain near its singularity needed 16x the
#: held link's own bound (its stiffest mode is the chain's, not the link's)
MAX_SUBSTEP_FACTOR = 64


def stable_configuration(
    scene: SceneConfig, way: str, sim_hz: float, device: str, user: str, seconds: float
) -> SceneConfig:
    """`configure`, with the substeps doubled until a run of the scene is stable (a user of a
    virtual coupling tunes its step so); raises if none up to MAX_SUBSTEP_FACTOR is."""
    factor = 1
    while True:
        configured = configure(scene, way, sim_hz, factor)
        if way == "local_model":
            return configured
        try:
            run_virtual(configured, device_for(device, way), load_user(user), seconds)
            return configured
        except RuntimeError:  # the sim's tool left the protocol's bounds: unstable
            if factor >= MAX_SUBSTEP_FACTOR:
                raise
            factor *= 2


def coupling_substeps_needed(scene: SceneConfig, sim_hz: float) -> int:
    """The substeps per period the tool's coupling spring needs at `sim_hz`: a free body's,
    or the held link's as if it were free (the rest of the chain only adds inertia)."""
    r = scene.rendering
    if scene.tool.kind == "body":
        body = scene.tool_body
        mass, moment, point = body.mass, body.moment, scene.tool.point
    else:
        lk, i = scene.tool_linkage, scene.tool.link
        mass, moment = lk.masses[i], lk.inertias[i]
        point = (
            scene.tool.point[0] - lk.com_offsets[i][0],
            scene.tool.point[1] - lk.com_offsets[i][1],
        )
    needed, _ = coupling.coupling_substeps(
        sim_hz, mass, moment, point, r.foh_spring_stiffness, r.foh_spring_damping
    )
    return needed


def device_for(name: str, way: str) -> Any:
    """The device with the way's setpoint hold (the in-loop and AMBF ways hold the pose)."""
    text = device_config(name).read_text()
    if way in ("pymunk_in_loop", "vc_zoh"):
        text = text.replace('setpoint_hold = "first_order"', 'setpoint_hold = "zero_order"')
    return device_from_text(text, f"{name} ({way})")


def cost_ms(result: VirtualResult, way: str) -> float:
    """Wall-clock ms per simulated second of the stages the way needs."""
    stages = result.stage_ns
    needed = ("sim_step", "tick") if way != "local_model" else tuple(stages)
    return 1e3 * sum(stages[k] for k in needed) / 1e9 / result.sim_s


def points(repeat: int, quick: bool = False) -> list[FrontPoint]:
    """Every scene rendered every way (quick: the local model at 60 Hz only, 2 s runs)."""
    local_rates = (60.0,) if quick else LOCAL_RATES
    runs = [
        (key, way, hz)
        for key in SCENES
        for way, rates in (
            ("local_model", local_rates), ("pymunk_in_loop", (HAPTIC_HZ,)),
            ("vc_zoh", (60.0,)), ("vc_foh", (60.0,)),
        )
        for hz in rates
    ]  # fmt: skip
    length = {key: 2.0 if quick else spec[3] for key, spec in SCENES.items()}
    costs: dict[tuple[str, str, float], float] = {}
    errors: dict[tuple[str, str, float], dict[str, float]] = {}
    references = {"testbed": testbed_reference(*SCENES["testbed"][:3], length["testbed"])}
    scenes = {}
    for key, way, hz in runs:
        scene_name, device, user, _ = SCENES[key]
        scenes[(key, way, hz)] = stable_configuration(
            load_scene(scene_name), way, hz, device, user, length[key]
        )
    for _ in range(repeat):  # interleaved: every configuration once a round
        for key, way, hz in runs:
            _, device, user, _ = SCENES[key]
            seconds = length[key]
            scene = scenes[(key, way, hz)]
            result = run_virtual(scene, device_for(device, way), load_user(user), seconds)
            c = cost_ms(result, way)
            costs[(key, way, hz)] = min(c, costs.get((key, way, hz), np.inf))
            errors[(key, way, hz)] = error_of(key, scene, result, references)
    return [
        FrontPoint(k, w, h, scenes[(k, w, h)].sim_substeps, costs[(k, w, h)], errors[(k, w, h)])
        for k, w, h in runs
    ]


def error_of(
    key: str, scene: SceneConfig, result: VirtualResult, references: dict[str, np.ndarray]
) -> dict[str, float]:
    ticks = result.ticks
    if key == "linkage":
        err = reference_error_mm(scene, ticks, float(ticks["t"][-1]) + 1e-9, "device_pose")
        return {"rms_mm": float(np.sqrt(np.mean(err**2))), "max_mm": float(err.max())}
    if key == "wall":
        return wall_transient(scene, ticks)
    ref = references["testbed"]
    n = min(len(ref), len(ticks))
    err = 1e3 * np.hypot(*(ticks["device_pose"][:n, :2] - ref[:n]).T)
    first = ticks["t"][:n] < TESTBED_FIRST_S
    apart = np.flatnonzero(err > TESTBED_BAND_MM)
    return {
        "rms_first_s_mm": float(np.sqrt(np.mean(err[first] ** 2))),
        "follows_ms": 1e3 * float(ticks["t"][apart[0]] if apart.size else ticks["t"][n - 1]),
        "rms_mm": float(np.sqrt(np.mean(err**2))),
    }


def wall_transient(scene: SceneConfig, ticks: np.ndarray) -> dict[str, float]:
    """The device's penetration against F/K after the first impact: peak, error after 2 s,
    settling within SETTLE_BAND, contact losses; the energy the device gave the hand."""
    push = 2.0  # configs/users/push_2n.toml
    stiffness = max(m.stiffness_n_per_m for m in scene.materials.values())
    expected = push / stiffness
    t = ticks["t"]
    depth = device_depth(ticks)
    first, losses = impact(ticks)
    outside = np.abs(depth - expected) > SETTLE_BAND * expected
    last_out = int(np.flatnonzero(outside)[-1]) if outside.any() else first
    after2 = t >= t[first] + 2.0
    last = t >= t[-1] - 0.5
    return {
        "peak_over_fk": float(depth[first:].max() / expected),
        "final_error": float(abs(depth[last].mean() / expected - 1.0)),
        "error_after_2s": float(np.abs(depth[after2] / expected - 1.0).max())
        if after2.any() else float("nan"),
        "settle_s": float(t[min(last_out + 1, len(t) - 1)] - t[first]),
        "contact_losses": float(losses),
        "port_energy_j": port_energy_j(ticks),
    }  # fmt: skip


def testbed_reference(scene_name: str, device: str, user_name: str, seconds: float) -> np.ndarray:
    """The operational point's path (x, y) at every 1 ms tick when the hand's spring acts on
    the tool directly: the scene's pymunk world stepped at REFERENCE_STEP_S, the kinematic
    bodies moved as the sim moves them, the hand's law (haptic_server/users.py) applied at
    the operational point. No device, no rendering: what a transparent device would let the
    hand feel."""
    scene = load_scene(scene_name)
    world = SimWorld(scene)
    space = world.space
    user = user_record(load_user(user_name))
    chain = world.chain[0]
    d = world.dof
    frame_pos, frame_angle = np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF)
    point, jac = np.zeros(2), np.zeros((3, MAX_DOF))
    q = np.zeros(MAX_DOF)
    wrench = np.zeros(3)
    moving = [(b, spec) for b, spec in world.kinematic_bodies if spec.oscillation_period_s > 0]

    def operational() -> tuple[np.ndarray, np.ndarray]:
        tq, tqd = world.tool_state()
        q[:d] = tq
        link_frames(chain, q, d, frame_pos, frame_angle)
        point_on_link(frame_pos, frame_angle, world.op_link, world.op_point, point)
        point_jacobian(chain, frame_pos, d, world.op_link, point[0], point[1], jac)
        pose = np.array([point[0], point[1], frame_angle[world.op_link]])
        return pose, jac[:, :d] @ tqd

    pose, _ = operational()
    user[0]["start_pose"] = pose
    op_body = world.tool_bodies[world.op_link if scene.tool.kind == "linkage" else 0]
    per_tick = round(1.0 / HAPTIC_HZ / REFERENCE_STEP_S)
    ticks = round(seconds * HAPTIC_HZ)
    path = np.zeros((ticks, 2))
    t = 0.0
    for k in range(ticks):
        path[k] = operational()[0][:2]
        for _ in range(per_tick):
            for body, spec in moving:
                _move_kinematic(body, spec, t + REFERENCE_STEP_S)
            pose, twist = operational()
            hand_wrench(user, t, pose, twist, wrench)
            op_body.apply_force_at_world_point((wrench[0], wrench[1]), (pose[0], pose[1]))
            op_body.torque += wrench[2]
            space.step(REFERENCE_STEP_S)
            t += REFERENCE_STEP_S
    return path


def _move_kinematic(body: Any, spec: Any, t: float) -> None:
    """An oscillating kinematic body's velocity at t, as the sim's step sets it before each
    pymunk step (sim_server/drive.py: the velocity at the step's end; the others keep the
    velocity they were made with)."""
    w = 2 * np.pi / spec.oscillation_period_s
    body.velocity = (
        spec.velocity[0] + spec.oscillation_amplitude[0] * w * np.cos(w * t),
        spec.velocity[1] + spec.oscillation_amplitude[1] * w * np.cos(w * t),
    )


def where_the_local_model_wins(front: list[FrontPoint]) -> list[str]:
    """Sentences with numbers: the local model at 60 Hz against each alternative, per scene."""
    by = {(p.scene, p.way, p.sim_hz): p for p in front}
    lines = []
    for key, metric in (
        ("linkage", "rms_mm"),
        ("testbed", "rms_first_s_mm"),
        ("wall", "peak_over_fk"),
        ("wall", "final_error"),
    ):
        ours = by[(key, "local_model", 60.0)]
        for way, hz in (("pymunk_in_loop", HAPTIC_HZ), ("vc_zoh", 60.0), ("vc_foh", 60.0)):
            other = by[(key, way, hz)]
            e0, e1 = ours.error[metric], other.error[metric]
            c0, c1 = ours.cost_ms_per_sim_s, other.cost_ms_per_sim_s
            verdict = (
                "wins on both" if e0 <= e1 and c0 <= c1 else
                "more accurate, dearer" if e0 <= e1 else
                "cheaper, less accurate" if c0 <= c1 else "loses on both"
            )  # fmt: skip
            lines.append(
                f"- {key}: local model (60 Hz) {metric} {e0:.3g} at {c0:.0f} ms/s against "
                f"{WAYS[way]} {e1:.3g} at {c1:.0f} ms/s: {verdict} "
                f"({e1 / max(e0, 1e-12):.3g}x the error, {c1 / max(c0, 1e-12):.2f}x the cost)"
            )
    return lines


def plot(front: list[FrontPoint], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    marks = {"local_model": "o", "pymunk_in_loop": "s", "vc_zoh": "^", "vc_foh": "v"}
    panels = (("linkage", "rms_mm", "device vs reference, RMS (mm)"),
              ("wall", "peak_over_fk", "the device's peak penetration / (F/K)"),
              ("testbed", "rms_first_s_mm", "device vs 10 kHz reference, RMS over 1 s (mm)"))  # fmt: skip
    for ax, (key, metric, label) in zip(axes, panels, strict=True):
        for p in front:
            if p.scene != key:
                continue
            value = max(p.error[metric], 1e-4)
            ax.loglog(p.cost_ms_per_sim_s, value, marks[p.way], ms=8,
                      label=f"{WAYS[p.way]}" + (f", {p.sim_hz:g} Hz" if p.way == "local_model" else ""))  # fmt: skip
        ax.set_xlabel("cost per simulated second (ms)")
        ax.set_ylabel(label)
        ax.set_title(f"{key}: error against cost")
        ax.legend(fontsize=6)
    fig.tight_layout()
    path = out / "front.png"
    fig.savefig(path, dpi=100)
    return path


def report(front: list[FrontPoint], repeat: int) -> str:
    lines = [
        "# The error-vs-cost front",
        "",
        f"`python -m haptic_local_model.benchmarks.front --repeat {repeat}` (and `haptic-bench`): virtual clock, haptic"
        " 1 kHz; cost = wall-clock ms per simulated second of the stages each way needs (the"
        f" lowest of {repeat} interleaved rounds). Module docstring: the ways, the scenes, the"
        " references.",
        "",
        "| scene | way | sim Hz | substeps | cost (ms / sim s) | error |",
        "|---|---|---|---|---|---|",
    ]
    for p in front:
        err = ", ".join(f"{k} {v:.4g}" for k, v in p.error.items())
        lines.append(
            f"| {p.scene} | {WAYS[p.way]} | {p.sim_hz:g} | {p.substeps} |"
            f" {p.cost_ms_per_sim_s:.1f} | {err} |"
        )
    lines += ["", "Where the local model wins (at 60 Hz):", "", *where_the_local_model_wins(front)]
    lines += ["", "![front](front.png)", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("runs/bench"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    front = points(args.repeat)
    plot(front, args.out)
    text = report(front, args.repeat)
    (args.out / "front.md").write_text(text)
    (args.out / "front.json").write_text(json.dumps([p.__dict__ for p in front], indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
