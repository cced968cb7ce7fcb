"""The mass-spring hand (DESIGN-WAVE2 §7) against closed forms, on a tracked hand given
as a script (haptic_server/stages/hand.py), at 1 kHz:

- V5.1 free-space tracking (palm 0.2 kg, k_t 500 N/m, b_t 20 N s/m, the brief's two
  fingers): a 1 Hz, 20 mm sine's separation amplitude against |m s^2 / (m s^2 + b s + k)|
  20 mm with m the whole hand's mass (the fingers ride on the palm); a 50 mm/s ramp's
  steady separation with relative damping (0) and with absolute damping (b v / k = 2 mm);
- V5.2 a palm pressed 5 mm into a wall (its flat underside on a floor, two corner
  contacts of k each): separation against d 2k / (k_t + 2k), and the palm spring's force
  against the wall's contact force (a static balance: any integrator meets it at rest);
  and a fingertip pressed on a frictionless 2 mm post: the joints' deflections against
  -tau / k_j of the post's torques (a static balance too), and the resting force and
  pose against scipy's static equilibrium of the same springs and contact;
- V5.3 the joint drives at 1, 10 and 100 times the explicit limit 4 I / dt^2 of the
  lightest phalanx (I about its joint), the glove stepping 0.3 rad and then holding: no step
  held for not being finite, and the hand's energy (kinetic + drives) never rising after the
  step; the same at theta 0.55 and 0.5 (not shipped), for comparison;
- a hand scene's port (hand_press: the palm driven by a simulated device, the fingers by a
  glove script): what the user's hand holds against at rest against the wall's force on
  the hand, and the cost of a tick, on the ideal device, the twin pantograph and the maglev;
- V5.5 two hands hold the box (`haptic_server/stages/hand_grasp.py`: both hands and the
  box in one theta-step) as in V4.1, scripted and without noise (`two_hands_hold`), and
  in the `hand_grasp` scene with each palm driven by a simulated device (`hand_grasp_port`:
  V4.1's acceptance with its transparency check, and the tick's cost);
- V5.4 a fingertip swept at 1 m/s across a 2 mm post, 1000 placements along the finger:
  how many the post passes through (its centre crossing a phalanx's core line within the
  phalanx), the deepest penetration, and the same with seed 004's emulation (the proxy stepped every 3 ticks),
  at the shipped 15 kN/m contacts and at 60 kN/m. `largest_command_step_n` is the largest
  change of the palm's command from one proxy step to the next (per 3 ms for the
  emulation, which does not model the seed's 1 kHz force from a stale proxy).

    python -m haptic_local_model.benchmarks.hand [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from typing import Any

import numpy as np
from scipy import optimize

from haptic_local_model.benchmarks.grasp import from_frame, to_frame, window_means
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.hand_grasp_ports import (
    HAND_GRASP_ROW_DTYPE,
    HandGraspRun,
)
from haptic_local_model.haptic_server.hand_ports import (
    HAND_ROW_DTYPE,
    HandPortRun,
    run_hand_port_ticks,
)
from haptic_local_model.haptic_server.stages.hand import (
    hand_chain,
    hand_energy,
    hand_records,
    hand_tick,
    run_tracked,
)
from haptic_local_model.haptic_server.stages.hand_grasp import grasp_records, run_grasp
from haptic_local_model.shared.kinematics import MAX_DOF, link_frames, point_jacobian
from haptic_local_model.shared.port_config import (
    FingerSpec,
    HandSpec,
    load_hand_scene,
    shipped_port_scenes,
)

DT = 0.001
CONTACT = (15000.0, 30.0, 0.5, 15000.0)  # k, b, mu, k_t of every hand contact
LIMITS = (50.0, 50.0, 5.0)


def hand_mass(spec: HandSpec) -> float:
    return spec.palm_mass + sum(sum(f.masses) for f in spec.fingers)


def track(spec, walls, targets, rates, dt=DT, contact=CONTACT):
    """Run the hand on a script; (q, command, contact) rows."""
    chain, model, data = hand_records(spec, walls, contact, tuple(targets[0, :3]), LIMITS, dt)
    data[0]["q"][: spec.dof] = targets[0, : spec.dof]
    n = len(targets)
    q = np.zeros((n, MAX_DOF))
    cmd = np.zeros((n, 3))
    contact = np.zeros((n, 3))
    run_tracked(chain, model, data, targets, rates, q, cmd, contact)
    return q, cmd, contact


def _script(spec: HandSpec, n: int) -> tuple[np.ndarray, np.ndarray]:
    targets = np.zeros((n, MAX_DOF))
    targets[:, 3 : spec.dof] = [a for f in spec.fingers for a in f.rest]
    return targets, np.zeros((n, MAX_DOF))


def free_space(spec: HandSpec | None = None) -> dict:
    """V5.1 (module docstring)."""
    spec = spec or HandSpec()
    amp, w = 0.02, 2 * math.pi
    n = 6000
    t = np.arange(n) * DT
    targets, rates = _script(spec, n)
    targets[:, 0] = amp * np.sin(w * t)
    rates[:, 0] = amp * w * np.cos(w * t)
    q, _, _ = track(spec, [], targets, rates)
    sep = amp * np.sin(w * (t + DT)) - q[:, 0]
    measured = (sep[n // 2 :].max() - sep[n // 2 :].min()) / 2
    m = hand_mass(spec)
    k, b = spec.palm_spring[0], spec.palm_damping[0]
    s = 1j * w
    expected = abs(m * s**2 / (m * s**2 + b * s + k)) * amp
    ramp = {}
    for damping in ("relative", "absolute"):
        sp = dataclasses.replace(spec, damping=damping)
        targets, rates = _script(sp, 3000)
        targets[:, 0] = 0.05 * t[:3000]
        rates[:, 0] = 0.05
        q, _, _ = track(sp, [], targets, rates)
        ramp[damping] = float(0.05 * (t[2999] + DT) - q[2999, 0])
    return {
        "sine_expected_m": expected,
        "sine_measured_m": float(measured),
        "sine_error_fraction": float(measured / expected - 1.0),
        "ramp_relative_m": ramp["relative"],
        "ramp_absolute_m": ramp["absolute"],
        "ramp_absolute_expected_m": b * 0.05 / k,
    }


def press(spec: HandSpec | None = None, depth_m: float = 0.005) -> dict:
    """V5.2 (module docstring): the floor's top at the palm's underside."""
    spec = spec or HandSpec(fingers=(FingerSpec(rest=(0.6, 0.4)), FingerSpec(rest=(0.9, 0.4))))
    h = spec.palm_size[1]
    floor = (np.array([(-0.1, -0.01), (0.1, -0.01), (0.1, 0.01), (-0.1, 0.01)]), 0.0,
             (0.0, -h / 2 - 0.01, 0.0))  # fmt: skip
    n = 3000
    targets, rates = _script(spec, n)
    targets[:, 1] = -depth_m * np.minimum(1.0, np.arange(n) / 500)
    rates[:500, 1] = -depth_m / (500 * DT)
    q, _, contact = track(spec, [floor], targets, rates)
    sep = float(q[-1, 1] - targets[-1, 1])  # the proxy stays above the tracked palm
    k = CONTACT[0]
    k_t = spec.palm_spring[1]
    expected = depth_m * 2 * k / (k_t + 2 * k)
    spring = k_t * (targets[-1, 1] - q[-1, 1])  # the palm spring's pull on the palm, y
    return {
        "separation_m": sep,
        "expected_m": expected,
        "separation_error_fraction": sep / expected - 1.0,
        "spring_force_n": float(-spring),
        "wall_force_n": float(contact[-1, 1]),
        "force_error_fraction": float(contact[-1, 1] / -spring - 1.0),
    }


def _frames(chain: np.ndarray, q: np.ndarray, dof: int):
    pos, ang = np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF)
    link_frames(chain[0], q, dof, pos, ang)
    return pos, ang


def fingertip_press(flex_rad: float = 0.02, post_radius_m: float = 0.001) -> dict:
    """V5.2's fingertip press: a frictionless post touches the distal phalanx's pad (80 %
    along it) on its path of flexion; the glove flexes the distal joint `flex_rad` further,
    ramped, and the palm is tracked where it is. At rest: each joint's deflection against
    the torque the post's force puts on it, dalpha = tau / k_j (the brief's check, a static
    balance), and the resting pose and force against an independent reference, the static
    equilibrium of the drives' springs and the pad's penalty contact solved by scipy."""
    spec = HandSpec(fingers=(FingerSpec(rest=(0.3, 0.4)),))
    dof, link = spec.dof, 4  # the distal phalanx
    finger = spec.fingers[0]
    length, r = finger.lengths[1], finger.radius
    chain = hand_chain(spec)
    q0 = np.zeros(MAX_DOF)
    q0[3:dof] = finger.rest
    pos, ang = _frames(chain, q0, dof)
    along = np.array([math.cos(ang[link]), math.sin(ang[link])])
    flexing = np.array([-along[1], along[0]])  # where the pad goes as the joint flexes
    post = pos[link] + 0.8 * length * along + (r + post_radius_m) * flexing
    wall = (np.zeros((1, 2)), post_radius_m, (post[0], post[1], 0.0))
    k = CONTACT[0]
    contact = (k, CONTACT[1], 0.0, CONTACT[3])  # frictionless: the reference has no friction
    n = 3000
    targets, rates = _script(spec, n)
    targets[:, link] += flex_rad * np.minimum(1.0, np.arange(n) / 500)
    rates[:500, link] = flex_rad / (500 * DT)
    chain, model, data = hand_records(spec, [wall], contact, (0.0, 0.0, 0.0), LIMITS, DT)
    q = np.zeros((n, MAX_DOF))
    run_tracked(chain, model, data, targets, rates, q, np.zeros((n, 3)), np.zeros((n, 3)))
    springs = np.array([*spec.palm_spring, spec.joint_spring, spec.joint_spring])
    target = targets[-1, :dof]

    def pad_contact(qq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The post's force on the pad at qq and the 2 x dof Jacobian of where it acts."""
        full = np.zeros(MAX_DOF)
        full[:dof] = qq
        p, a = _frames(chain, full, dof)
        axis = np.array([math.cos(a[link]), math.sin(a[link])])
        core = p[link] + np.clip((post - p[link]) @ axis, 0.0, length) * axis
        gap = post - core
        out = gap / np.linalg.norm(gap)  # from the core to the post's centre
        depth = max(0.0, r + post_radius_m - float(np.linalg.norm(gap)))
        point = post - post_radius_m * out
        jac = np.zeros((3, MAX_DOF))
        point_jacobian(chain[0], p, dof, link, point[0], point[1], jac)
        return -k * depth * out, jac[:2, :dof]

    def balance(qq: np.ndarray) -> np.ndarray:
        f, jac = pad_contact(qq)
        return springs * (target - qq) + jac.T @ f

    reference = optimize.fsolve(balance, target)
    ref_force, _ = pad_contact(reference)
    final = q[-1, :dof]
    force = data[0]["contact_force"][:2].copy()
    _, jac = pad_contact(final)
    tau = jac.T @ force  # the post's torque on each joint: it opens them, dalpha = -tau / k_j
    deflection = target[3:] - final[3:]
    ref_deflection = target[3:] - reference[3:]
    return {
        "flex_rad": flex_rad,
        "post_force_n": float(np.linalg.norm(force)),
        "reference_force_n": float(np.linalg.norm(ref_force)),
        "force_error_fraction": float(
            np.linalg.norm(force - ref_force) / np.linalg.norm(ref_force)
        ),
        "reference_residual": float(np.abs(balance(reference)).max()),
        "deflection_rad": [float(a) for a in deflection],
        "reference_deflection_rad": [float(a) for a in ref_deflection],
        "tau_over_k_error_fraction": float(
            np.abs(-deflection * spec.joint_spring / tau[3:] - 1.0).max()
        ),
        "settled_cycle_rad": float(np.abs(q[-10:, :dof] - final).max()),  # a tick-to-tick chatter
        "reference_deflection_error_fraction": float(
            np.abs(deflection / ref_deflection - 1.0).max()
        ),
    }


def implicit_sweep(
    factors: tuple[float, ...] = (1.0, 10.0, 100.0), theta: float = 0.6
) -> list[dict]:
    """V5.3 (module docstring): `theta` is the step's (hand.py; 0.6 ships)."""
    base = HandSpec()
    f0 = base.fingers[0]
    # the lightest phalanx about its joint: the fingertip's
    inertia = f0.inertias[1] + f0.masses[1] * (f0.lengths[1] / 2) ** 2
    limit = 4 * inertia / DT**2
    out = []
    for factor in factors:
        spec = dataclasses.replace(base, joint_spring=factor * limit, joint_damping=1e-6)
        chain, model, data = hand_records(spec, [], CONTACT, (0.0, 0.0, 0.0), LIMITS, DT, theta)
        d = data[0]
        d["target"][3 : spec.dof] += 0.3
        energy = []
        for _ in range(2000):
            hand_tick(chain, model, data)
            energy.append(hand_energy(chain, model, data))
        e = np.array(energy)
        out.append(
            {
                "theta": theta,
                "factor": factor,
                "k_j": factor * limit,
                "held_steps": int(d["singular"]),  # steps that were not finite
                "substepped_ticks": int(d["substepped"]),
                "largest_rise_j": float(np.diff(e).max()),
                "energy_first_j": float(e[0]),
                "energy_last_j": float(e[-1]),
            }
        )
    return out


def _crossed(chain: np.ndarray, q: np.ndarray, post: tuple[float, float], dof: int) -> bool:
    """Whether the post's centre went from one side of a phalanx's core line to the other
    between two ticks while within the phalanx's length: a pass-through, which the
    penetration depth (measured to the core segment, unsigned) cannot see."""
    c = chain[0]
    pos = np.zeros((MAX_DOF, 2))
    ang = np.zeros(MAX_DOF)
    last: dict[int, float] = {}
    for row in q:
        link_frames(c, row, dof, pos, ang)
        for link in range(3, dof):
            dx = post[0] - pos[link, 0]
            dy = post[1] - pos[link, 1]
            along = math.cos(ang[link]) * dx + math.sin(ang[link]) * dy
            side = -math.sin(ang[link]) * dx + math.cos(ang[link]) * dy
            if 0.0 <= along <= c["lengths"][link]:
                if link in last and last[link] * side < 0.0:
                    return True
                last[link] = side
            else:
                last.pop(link, None)
    return False


def post_sweeps(
    trials: int = 1000, every: int = 1, seed: int = 4, stiffness: float = CONTACT[0]
) -> dict:
    """V5.4 (module docstring): one straight finger; the tracked palm sweeps +y at 1 m/s
    throughout (80 mm), the post (a 1 mm disc) somewhere along the finger, 20 mm ahead.
    `every` = 3 steps the proxy every third tick over 3 ms (the seed's 300 Hz hand), the
    tracked hand sampled then."""
    rng = np.random.default_rng(seed)
    finger = FingerSpec(rest=(0.0, 0.0))
    spec = HandSpec(fingers=(finger,))
    chain = hand_chain(spec)
    reach = spec.palm_size[0] / 2 + sum(finger.lengths)
    n = 80 // every
    dt = DT * every
    t = np.arange(n) * dt
    through = 0
    deepest = 0.0
    jump = 0.0
    for _ in range(trials):
        x = rng.uniform(spec.palm_size[0] / 2 + 0.004, reach - 0.002)
        y = 0.02 + rng.uniform(0, 0.001)
        post = (np.zeros((1, 2)), 0.001, (float(x), float(y), 0.0))
        targets, rates = _script(spec, n)
        targets[:, 1] = t
        rates[:, 1] = 1.0
        law = (stiffness, *CONTACT[1:3], stiffness)
        q, cmd, contact = track(spec, [post], targets, rates, dt, law)
        deepest = max(deepest, float(contact[:, 2].max()))
        if _crossed(chain, q, (float(x), float(y)), spec.dof):
            through += 1
        jump = max(jump, float(np.max(np.abs(np.diff(cmd[:, 1])))))
    return {
        "trials": trials,
        "contact_n_per_m": stiffness,
        "proxy_step_ms": dt * 1e3,
        "passed_through": through,
        "deepest_m": deepest,
        "combined_radius_m": finger.radius + 0.001,
        "largest_command_step_n": jump,
    }


BOX_SIZE = (0.04, 0.02)
BOX_MASS = 0.1


def two_hands(squeeze_n: float, g: float) -> tuple[tuple, tuple, tuple, np.ndarray, np.ndarray]:
    """Two of the brief's hands, palms facing across the 40 x 20 mm, 0.1 kg box (the left
    hand turned -90 degrees, its fingers hanging below the box; the right +90, its fingers
    above), each tracked palm held `squeeze_n` / k_t inside the box's face and raised by
    what its palm spring carries (the hand and half the box). (chains, models, datas,
    coupling model, coupling data)."""
    spec = HandSpec()
    k_t = spec.palm_spring[0]
    half = spec.palm_size[1] / 2
    lift = (hand_mass(spec) + BOX_MASS / 2) * g / k_t
    hands = []
    for side in (-1.0, 1.0):
        x = side * (BOX_SIZE[0] / 2 + half)
        pose = (x, 0.0, side * math.pi / 2)
        chain, model, data = hand_records(spec, [], CONTACT, pose, LIMITS, DT, 0.6, (0.0, -g))
        data[0]["target"][0] = x - side * squeeze_n / k_t
        data[0]["target"][1] = lift
        hands.append((chain, model, data))
    gm, gd = grasp_records(hands, BOX_SIZE, BOX_MASS, (0.0, 0.0, 0.0), CONTACT)
    chains, models, datas = zip(*hands, strict=True)
    return tuple(chains), tuple(models), tuple(datas), gm, gd


def palm_slip(
    box: np.ndarray, palms: tuple[np.ndarray, ...], size: tuple[float, float], half: float
) -> list[float]:
    """For each box corner on a palm's face (its frame's y = half) at the first tick: how
    far that material point moved along the face from then on, the largest (m)."""
    slip = []
    for palm in palms:
        for cx in (-size[0] / 2, size[0] / 2):
            for cy in (-size[1] / 2, size[1] / 2):
                local = to_frame(palm, from_frame(box, np.array([cx, cy])))
                if abs(local[0, 1] - half) > 5e-4:
                    continue  # not on this palm's face
                slip.append(float(np.max(np.abs(local[:, 0] - local[0, 0]))))
    return slip


def two_hands_hold(duration_s: float = 5.2, settle_s: float = 0.2, squeeze_n: float = 2.0) -> dict:
    """V5.5 (module docstring): `two_hands`, g = 9.81, the tracked hands still for 5 s:
    V4.1's slip (each box corner along its palm's face, from the poses), balance (the box's
    contact force + m g in 100 ms means: its m a) and contact losses (fewer hand-box
    contacts than at the hold's start). The hands are scripted and noise-free, and there is
    no device, so V4.1's transparency check has nothing to compare."""
    g = 9.81
    chains, models, datas, gm, gd = two_hands(squeeze_n, g)
    half = HandSpec().palm_size[1] / 2
    n = round(duration_s / DT)
    out = np.zeros((n, 19))
    run_grasp(chains, models, datas, gm, gd, out)
    t = np.arange(1, n + 1) * DT
    k0 = round(settle_s / DT)
    box = out[:, 0:3]
    balance = window_means(t, out[:, 3:5] + np.array([0.0, -BOX_MASS * g]), settle_s, duration_s)
    slip = palm_slip(box[k0:], (out[k0:, 6:9], out[k0:, 9:12]), BOX_SIZE, half)
    return {
        "contacts_tracked": len(slip),
        "slip_max_m": max(slip) if slip else float("nan"),
        "balance_max_fraction": float(np.max(np.linalg.norm(balance, axis=1)) / (BOX_MASS * g)),
        "contact_losses": int(np.sum(out[k0:, 12] < out[k0, 12])),
        "contacts_at_hold": int(out[k0, 12]),
        "box_drop_m": float(box[k0, 1] - box[-1, 1]),
        "held_steps": int(gd[0]["singular"]),
        "squeeze_n": [
            float(np.median(np.abs(out[k0:, 13]))),
            float(np.median(np.abs(out[k0:, 16]))),
        ],
    }


def two_hands_twist(dy_m: float = 0.002, duration_s: float = 1.0) -> dict:
    """g = 0: the right tracked palm `dy_m` up, the left as far down, the squeeze 2 N: the
    box must turn counter-clockwise with the line through the palms (a wrong sign of the
    box's contact torque would turn it the other way). The palms keep their own angle (their
    springs hold it), so past a few millimetres the box sits on corners and leaves the line."""
    chains, models, datas, gm, gd = two_hands(2.0, 0.0)
    datas[0][0]["target"][1] -= dy_m
    datas[1][0]["target"][1] += dy_m
    n = round(duration_s / DT)
    out = np.zeros((n, 19))
    run_grasp(chains, models, datas, gm, gd, out)
    left = out[-1, 6:9]
    right = out[-1, 9:12]
    line = math.atan2(right[1] - left[1], right[0] - left[0])
    return {"box_angle_rad": float(out[-1, 2]), "palm_line_rad": line,
            "held_steps": int(gd[0]["singular"])}  # fmt: skip


def hand_port(scene_name: str, device: str, seconds: float = 2.6) -> dict:
    """A hand scene's port (haptic_server/hand_ports.py) on a simulated device: while the
    palm rests on the wall (1.1-1.4 s of hand_press), what the user's hand holds against
    (its wrench on the device) against the wall's force on the hand mapped to the device
    (100 ms means: the transparency through the palm spring, the map and the device), the
    tracked palm's separation against F / k_t; and each tick's cost, timed from Python
    around its compiled call (the device model, the glove, the hand)."""
    run = HandPortRun(load_hand_scene(scene_name), load_simulated_device(device))
    n = round(seconds * run.scene.haptic_rate_hz)
    rows = np.zeros(n, HAND_ROW_DTYPE)
    args = (run.chain, run.model, run.data, run.io, run.device.records, rows)
    run_hand_port_ticks(*args, 0, 0)  # compile
    ns = np.zeros(n)
    for k in range(n):
        t0 = time.perf_counter_ns()
        if run_hand_port_ticks(*args, k, k + 1) == k:  # the noise block ran out: refill
            refill_noise(run.device.noise, run.device.records, run.scene.period_s)
            t0 = time.perf_counter_ns()
            run_hand_port_ticks(*args, k, k + 1)
        ns[k] = time.perf_counter_ns() - t0
    w = rows[1100:1400]
    wall = w["contact_force"].mean(axis=0)
    m = run.io[0]["map"][0]
    wall_at_device = m["force_scale"] * m["scale"][:2] * wall
    felt = -w["hand_wrench"][:, :2].mean(axis=0)  # what the user's hand holds against
    sep = float((w["target"][:, 0] - w["q"][:, 0]).mean())
    return {
        "scene": scene_name,
        "device": device,
        "wall_force_n": wall.tolist(),
        "felt_n": felt.tolist(),
        "transparency_error_fraction": float(
            np.abs(felt - wall_at_device).max() / np.abs(wall_at_device).max()
        ),
        "separation_error_fraction": sep / (-wall[0] / run.spec.palm_spring[0]) - 1.0,
        "steps_held": int(rows["singular"][-1]),
        "tick_p50_us": float(np.percentile(ns, 50) / 1e3),
        "tick_p99_us": float(np.percentile(ns, 99) / 1e3),
    }


def hand_grasp_port(
    devices: tuple[str, str], duration_s: float = 5.2, settle_s: float = 0.2
) -> dict:
    """V5.5 with devices: `hand_grasp` (haptic_server/hand_grasp_ports.py), each palm
    driven by its simulated device (sensor noise on), each user squeezing 2 N and carrying
    its hand and half the box, g = 9.81, 5 s: V4.1's slip, balance (the box's contact force
    + m g, 100 ms means: its m a), contact losses, and transparency (what each device
    renders against its user's wrench on it, both in the device's frame, 100 ms means: what
    the user feels against what the user pushes); each tick's cost, timed from Python around its compiled call (two device
    models, two gloves, both hands and the box)."""
    scene = load_hand_scene("hand_grasp")
    run = HandGraspRun(scene, [load_simulated_device(d) for d in devices])
    n = round(duration_s * scene.haptic_rate_hz)
    rows = np.zeros(n, HAND_GRASP_ROW_DTYPE)
    run.ticks(rows, 0, 1)  # compile
    ns = np.zeros(n)
    for k in range(1, n):
        t0 = time.perf_counter_ns()
        run.ticks(rows, k, k + 1)
        ns[k] = time.perf_counter_ns() - t0
    box = scene.box
    assert box is not None
    t = rows["t"]
    k0 = round(settle_s * scene.haptic_rate_hz)
    g = abs(scene.gravity[1])
    weight = box.mass * np.array(scene.gravity)
    balance = window_means(t, rows["box_force"][:, :2] + weight, settle_s, duration_s)
    # each hand's force on the box over the hold: its squeeze along x, and its share of the
    # weight along y (the shares are statically indeterminate: friction splits them)
    hand_force = [rows["hand_box_force"][k0:, p, :2].mean(axis=0).tolist() for p in range(2)]
    shares = rows["hand_box_force"][k0:, :, :2].sum(axis=1)
    half = scene.hands[0].palm_size[1] / 2
    palms = tuple(rows["q"][k0:, p, :3] for p in range(2))
    slip = palm_slip(rows["box_q"][k0:], palms, box.size, half)
    felt = rows["out"][:, :, :2] + rows["hand_wrench"][:, :, :2]  # both device frame
    transparency = [
        float(np.max(np.linalg.norm(window_means(t, felt[:, p], settle_s, duration_s), axis=1)))
        for p in range(2)
    ]
    return {
        "devices": "+".join(devices),
        "contacts_tracked": len(slip),
        "slip_max_m": max(slip) if slip else float("nan"),
        "balance_max_fraction": float(np.max(np.linalg.norm(balance, axis=1)) / (box.mass * g)),
        "contact_losses": int(np.sum(rows["n_contacts"][k0:] < rows["n_contacts"][k0])),
        "contacts_at_hold": int(rows["n_contacts"][k0]),
        "box_drop_m": float(rows["box_q"][k0, 1] - rows["box_q"][-1, 1]),
        "transparency_max_n": max(transparency),
        "hand_force_n": hand_force,
        "hand_shares_vs_box_force_n": float(np.abs(shares - rows["box_force"][k0:, :2]).max()),
        "squeeze_n": float(np.median(np.abs(rows["command"][k0:, :, 0]))),
        "steps_held": int(rows["singular"][-1]),
        "not_finite": int(rows["invalid"][-1].sum()),
        "tick_p50_us": float(np.percentile(ns[1:], 50) / 1e3),
        "tick_p99_us": float(np.percentile(ns[1:], 99) / 1e3),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write every figure to this file")
    args = ap.parse_args(argv)
    figures: dict[str, Any] = {
        "V5.1 free-space tracking": free_space(),
        "V5.2 press a wall": press(),
        "V5.2 fingertip press": fingertip_press(),
        "hand scenes: a device drives the palm": [
            hand_port(name, device)
            for name in shipped_port_scenes(hands=True)
            if len(load_hand_scene(name).ports) == 1
            for device in ("ideal", "twin_pantograph", "maglev")
        ],
        "V5.5 hand_grasp: two devices drive the hands": [
            hand_grasp_port(devices)
            for devices in (
                ("maglev", "maglev"),
                ("twin_pantograph", "twin_pantograph"),
                ("ideal", "ideal"),
                ("maglev", "twin_pantograph"),
            )
        ],
        "V5.3 implicit drives": implicit_sweep(),
        "V5.3 with theta 0.55 and 0.5 (not shipped)": implicit_sweep((100.0,), 0.55)
        + implicit_sweep((100.0,), 0.5),
        "V5.4 post, 1 kHz proxy": post_sweeps(),
        "V5.5 two hands hold the box": two_hands_hold(),
        "V5.4 post, seed 004 emulation (proxy every 3 ticks)": post_sweeps(every=3),
        "V5.4 post, 1 kHz, contacts at 60 kN/m": post_sweeps(stiffness=60000.0),
        "V5.4 post, seed 004 emulation, contacts at 60 kN/m": post_sweeps(
            every=3, stiffness=60000.0
        ),
    }
    for name, value in figures.items():
        print(f"\n{name}")
        rows = value if isinstance(value, list) else [value]
        for row in rows:
            print("  " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                   for k, v in row.items()))  # fmt: skip
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
