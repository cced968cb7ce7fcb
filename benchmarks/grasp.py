"""Two devices squeezing one co-simulated box (DESIGN-WAVE2 §6), on the virtual clock.

The port scene `grasp_vertical` (configs/ports/) with its simulated devices and hands
(`haptic_server/ports.py`), at 1 kHz, on the validation cases of DESIGN-WAVE2 §6
(vertical plane g = 9.81, box 40 x 20 mm, 0.1 kg, mu = 0.5, K_c = 15 kN/m):

- V4.1 hold: both hands push 2 N and hold their height (maglevs, sensor noise on) for 5 s:
  slip of every contact (a box corner's position on its pad's face, from the logged
  poses), force balance of the box (100 ms means of its logged contact wrench + m g: the
  brief's measure, which is m a of the box, so it shows the box at rest, not a separate
  law), contact losses, and transparency (each device's command against its hand's wrench,
  100 ms means: what the user feels against what the user pushes);
- V4.2 below the cone: 0.8 N each; the box's acceleration (a quadratic fit of its logged
  height) against g - 2 mu N / m = 1.81 m/s^2 (pads 80 mm tall so it slides in view, the
  box sliding across their centres, the grip starting as it slides; also from a touching
  start);
- creep: the box held at 1.25x its friction threshold for 10 s on each device: how far it
  moves along its pads (target <= 0.2 mm);
- V4.3 lift and carry: twin pantographs raise 30 mm in 0.5 s: slip, and each device's
  vertical force against (m_O / 2 + m_pad)(a + g) in 100 ms means (a the box's logged
  acceleration);
- V4.4 stability map over K_c x m_O on ideal devices (no noise): NaN, failed factorings,
  whether the box is held, and whether the kinetic energy at rest grows;
- V4.5 twist (g = 0): the hands move 10 mm in opposite y, squeezing along their grip line;
  the box's angle against the hands' line and the pads' (the pads turn freely: no angular
  coupling); and the same hands pushing along x, whose couple turns the box past them;
- first touch (g = 0): the pads start 3 mm from the box and the hands close them on it
  with 2 N; with the simultaneous impulses and with penalty contacts alone: the pads'
  speed at the touch, how deep the contacts go and whether they bounce (contacts lost
  after the first touch), each device's largest command against the 2 N;
- the cost of one tick of both ports (the co-simulation and two device models), for every
  shipped port scene (grasp_clutter: 64 shapes).

    python -m haptic_local_model.benchmarks.grasp [--json out.json]
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

from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.ports import (
    PORT_ROW_DTYPE,
    PortResult,
    PortRun,
    run_port_ticks,
    run_ports,
)
from haptic_local_model.haptic_server.stages.cosim import kinetic_energy
from haptic_local_model.shared.config import UserConfig, load_user
from haptic_local_model.shared.port_config import (
    PortSceneConfig,
    load_port_scene,
    shipped_port_scenes,
)

SCENE = "grasp_vertical"
WINDOW_S = 0.1  # the brief's 100 ms means


def scene_with(
    scene: PortSceneConfig,
    devices: tuple[str, str] | None = None,
    **changes: Any,
) -> PortSceneConfig:
    """The scene with its devices (and any top-level keys) replaced."""
    if devices is not None:
        ports = tuple(
            dataclasses.replace(p, device=dev) for p, dev in zip(scene.ports, devices, strict=True)
        )
        changes["ports"] = ports
    return dataclasses.replace(scene, **changes)


def squeeze_users(
    scene: PortSceneConfig,
    squeeze_n: float,
    waypoints: tuple[tuple[tuple[float, float, float, float], ...], ...] | None = None,
) -> list[UserConfig]:
    """The scene's users pushing `squeeze_n` toward each other, with other waypoints if
    given (one script per port)."""
    out = []
    for p, port in enumerate(scene.ports):
        u = load_user(port.user)
        sign = 1.0 if u.wrench[0] > 0 else -1.0
        change: dict[str, Any] = {"wrench": (sign * squeeze_n, 0.0, 0.0)}
        if waypoints is not None:
            change["waypoints"] = waypoints[p]
        out.append(dataclasses.replace(u, **change))
    return out


def window_means(t: np.ndarray, x: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Means of x over consecutive WINDOW_S windows of [t0, t1)."""
    edges = np.arange(t0, t1 - 1e-9, WINDOW_S)
    return np.array([x[(t >= a) & (t < a + WINDOW_S)].mean(axis=0) for a in edges])


def to_frame(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World points (n x 2) into the frames of poses (n x 3)."""
    c = np.cos(pose[:, 2])
    s = np.sin(pose[:, 2])
    dx = pts[:, 0] - pose[:, 0]
    dy = pts[:, 1] - pose[:, 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=1)


def from_frame(pose: np.ndarray, local: np.ndarray) -> np.ndarray:
    c = np.cos(pose[:, 2])
    s = np.sin(pose[:, 2])
    return np.stack(
        [pose[:, 0] + c * local[0] - s * local[1], pose[:, 1] + s * local[0] + c * local[1]],
        axis=1,
    )


def pose_of(result: PortResult, name: str) -> np.ndarray:
    i = result.body(name)
    return result.rows["q"][:, 3 * i : 3 * i + 3]


def contact_slip(result: PortResult, scene: PortSceneConfig, k0: int) -> dict[str, float]:
    """For each pad, each box corner touching it at tick k0: how far that material point
    of the box moved along the pad's face, in the pad's frame, from k0 on (m): the largest
    over the run. The corners come from the box's geometry, the motion from the poses."""
    box = scene.body("box")
    w, h = box.size
    corners = [(-w / 2, -h / 2), (-w / 2, h / 2), (w / 2, -h / 2), (w / 2, h / 2)]
    box_pose = pose_of(result, "box")[k0:]
    out = {}
    for port in scene.ports:
        pad = scene.body(port.tool)
        pad_pose = pose_of(result, port.tool)[k0:]
        for cx, cy in corners:
            world = from_frame(box_pose, np.array([cx, cy]))
            local = to_frame(pad_pose, world)
            if abs(abs(local[0, 0]) - pad.size[0] / 2) > 5e-4:
                continue  # not on this pad's face
            out[f"{port.name} ({cx * 1e3:+.0f}, {cy * 1e3:+.0f}) mm"] = float(
                np.max(np.abs(local[:, 1] - local[0, 1]))
            )
    return out


def hold(scene: PortSceneConfig, duration_s: float = 5.2, settle_s: float = 0.2) -> dict:
    """V4.1 (module docstring)."""
    users = squeeze_users(scene, 2.0)
    res = run_ports(scene, duration_s, users=users)
    r = res.rows
    t = r["t"]
    k0 = round(settle_s * scene.haptic_rate_hz)
    box = scene.body("box")
    ib = res.body("box")
    weight = box.mass * np.array(scene.gravity)
    net = r["body_force"][:, ib, :2] + weight
    balance = window_means(t, net, settle_s, duration_s)
    slip = contact_slip(res, scene, k0)
    transparency = []
    for p in range(len(scene.ports)):
        # what the hand feels against what it pushes: the device's command and the hand's
        # wrench on it cancel at rest, up to the device's own dynamics (scale-1 maps)
        diff = r["command"][:, p, :2] + r["hand_wrench"][:, p, :2]
        means = window_means(t, diff, settle_s, duration_s)
        transparency.append(float(np.max(np.linalg.norm(means, axis=1))))
    m_g = box.mass * abs(scene.gravity[1])
    return {
        "slip_max_m": max(slip.values()),
        "slip_m": slip,
        "contacts_tracked": len(slip),
        "balance_max_fraction": float(np.max(np.linalg.norm(balance, axis=1)) / m_g),
        "contact_losses": int(np.sum(r["n_contacts"][k0:] < r["n_contacts"][k0])),
        "contacts_at_hold": int(r["n_contacts"][k0]),
        "squeeze_n": float(
            np.median(np.abs(r["body_force"][k0:, res.body(scene.ports[0].tool), 0]))
        ),
        "transparency_max_n": transparency,
        "box_drop_m": float(pose_of(res, "box")[-1, 1] - pose_of(res, "box")[k0, 1]),
        "faults": int(r["invalid"][-1] + r["singular"][-1]),
    }


def fit_weights(t: np.ndarray) -> np.ndarray:
    """How a quadratic fit of positions at times t weighs the acceleration at each t: the
    fit's 2 c_2 = sum_k p_k y_k (p: the pseudo-inverse's t^2 row) and y_k is the double
    integral of a, so a at s counts as sum over t_k > s of p_k (t_k - s). Normalised; a
    series of accelerations dotted with them is what the fit reports of it."""
    basis = np.stack([t**2, t, np.ones_like(t)], axis=1)
    p = np.linalg.pinv(basis)[0]
    tail = np.cumsum(p[::-1])[::-1]  # sum over k >= j of p_k
    w = np.cumsum((tail * np.gradient(t))[::-1])[::-1]
    return w / w.sum()


def below_cone(
    scene: PortSceneConfig, devices: tuple[str, str], squeeze_n: float = 0.8, preload: bool = True
) -> dict:
    """V4.2 (module docstring): the box's acceleration over [20, 120] ms against the
    nominal g - 2 mu N / m and against the same with the squeeze both pads measured
    (along their normals, weighted as the quadratic fit weighs the window's ticks).

    The box starts 7 mm above the pads' centres, so over the window it slides from above
    their centres to below them (about 13 mm): off-centre, the friction's couple tilts the
    pads and the squeeze with them. With `preload` (the case's figures) the grip starts as
    it slides: the pads pressed in by N / 2k at their two corners each, each hand pushing
    up what its pad carries (its weight and mu N) through its coupling; without it, the
    pads start just touching and unloaded, the box falls freely for the first ticks and
    the devices lunge in, and the fit sees that transient (reported as `touching start`)."""
    box0 = scene.body("box")
    shift = squeeze_n / (2.0 * scene.contact.stiffness_n_per_m) if preload else 0.0
    bodies = []
    for b in scene.bodies:
        if b.name.startswith("pad"):
            inward = -math.copysign(shift, b.position[0] - box0.position[0])
            b = dataclasses.replace(b, size=(b.size[0], 0.08),
                                    position=(b.position[0] + inward, b.position[1]))  # fmt: skip
        elif b.name == "box":
            b = dataclasses.replace(b, position=(b.position[0], b.position[1] + 0.007))
        bodies.append(b)
    sc = scene_with(scene, devices, bodies=tuple(bodies))
    mu = sc.contact.friction
    g = abs(sc.gravity[1])
    users = squeeze_users(sc, squeeze_n)
    if preload:
        carried = [sc.body(p.tool).mass * g + mu * squeeze_n for p in sc.ports]
        users = [
            dataclasses.replace(u, wrench=(u.wrench[0], up, 0.0))
            for u, up in zip(users, carried, strict=True)
        ]
    res = run_ports(sc, 0.15, users=users)
    r = res.rows
    t = r["t"]
    y = pose_of(res, "box")[:, 1]
    box = sc.body("box")
    sel = (t >= 0.02) & (t <= 0.12)
    fit = np.polyfit(t[sel], y[sel], 2)
    measured = -2.0 * fit[0]
    weights = fit_weights(t[sel])
    normals = []
    for port in sc.ports:
        i = res.body(port.tool)
        angle = pose_of(res, port.tool)[:, 2]
        f = r["body_force"][:, i, :2]
        normals.append(np.abs(f[:, 0] * np.cos(angle) + f[:, 1] * np.sin(angle))[sel])
    squeeze = float(weights @ ((normals[0] + normals[1]) / 2))
    expected = g - 2 * mu * squeeze_n / box.mass
    return {
        "devices": "+".join(devices) + ("" if preload else " (touching start)"),
        "expected_m_per_s2": expected,
        "measured_m_per_s2": float(measured),
        "error_fraction": float(measured / expected - 1.0),
        "squeeze_measured_n": squeeze,
        "error_vs_measured_squeeze": float(measured / (g - 2 * mu * squeeze / box.mass) - 1.0),
    }


CREEP_FACTOR = 1.25  # the squeeze over the friction threshold 2 mu N = m g
CREEP_TARGET_M = 2e-4  # a held box moves <= 0.2 mm along its pads over 10 s


def creep(
    scene: PortSceneConfig, device: str, factor: float = CREEP_FACTOR, hold_s: float = 10.0
) -> dict:
    """`creep_run`'s figures (its docstring)."""
    return creep_run(scene, device, factor, hold_s)[1]


def creep_run(
    scene: PortSceneConfig, device: str, factor: float = CREEP_FACTOR, hold_s: float = 10.0
) -> tuple[PortResult, dict]:
    """A box held at `factor` times its friction threshold (each pad squeezing
    factor m g / (2 mu)) on two `device`s for hold_s after 0.5 s to settle: how far its
    centre moved along the pads' faces (in each pad's frame, the two averaged), the net and
    the largest, and its rate. Up to 0.9 the stick spring's anchor was reset against the
    relative motion whenever the damping's share crossed the cone, and sensor noise
    ratcheted the box up its pads (+1.35 mm on twin pantographs, +0.28 mm on maglevs)."""
    settle_s = 0.5
    scene = scene_with(scene, (device, device))
    box = scene.body("box")
    squeeze = factor * box.mass * abs(scene.gravity[1]) / (2.0 * scene.contact.friction)
    res = run_ports(scene, settle_s + hold_s, users=squeeze_users(scene, squeeze))
    t = res.rows["t"]
    k0 = int(np.searchsorted(t, settle_s))
    box_pose = pose_of(res, "box")
    along = np.mean(
        [to_frame(pose_of(res, p.tool), box_pose[:, :2])[:, 1] for p in scene.ports], axis=0
    )
    moved = along[k0:] - along[k0]
    return res, {
        "device": device, "squeeze_n": squeeze, "drift_m": float(moved[-1]),
        "max_m": float(np.abs(moved).max()),
        "rate_m_per_s": float(np.polyfit(t[k0:] - t[k0], moved, 1)[0]),
        "contacts_min": int(res.rows["n_contacts"][k0:].min()),
    }  # fmt: skip


def lift(scene: PortSceneConfig, height_m: float = 0.03, ramp_s: float = 0.5) -> dict:
    """V4.3 (module docstring): twin pantographs, starting 15 mm low in their range."""
    start = (0.0, -height_m / 2, 0.0)
    ports = tuple(
        dataclasses.replace(p, device="twin_pantograph", device_start=start) for p in scene.ports
    )
    sc = dataclasses.replace(scene, ports=ports)
    t0, t1, end = 0.3, 0.3 + ramp_s, 1.3
    script = ((t0, 0.0, 0.0, 0.0), (t1, 0.0, height_m, 0.0))
    res = run_ports(sc, end, users=squeeze_users(sc, 2.0, (script, script)))
    r = res.rows
    t = r["t"]
    dt = sc.period_s
    y = pose_of(res, "box")[:, 1]
    acc = np.gradient(np.gradient(y, dt), dt)
    box = sc.body("box")
    g = abs(sc.gravity[1])
    worst = 0.0
    for p, port in enumerate(sc.ports):
        pad = sc.body(port.tool)
        a_mean = window_means(t, acc, t0 - 0.1, end)
        f_mean = window_means(t, -r["command"][:, p, 1], t0 - 0.1, end)
        expected = (box.mass / 2 + pad.mass) * (a_mean + g)
        worst = max(worst, float(np.max(np.abs(f_mean / expected - 1.0))))
    k0 = round((t0 - 0.1) / dt)
    slip = contact_slip(res, sc, k0)
    return {
        "raised_m": float(y[-1] - y[k0]),
        "slip_max_m": max(slip.values()),
        "force_error_max_fraction": worst,
        "peak_acceleration_m_per_s2": float(np.max(np.abs(window_means(t, acc, t0, end)))),
    }


TWIST_DEVICES = ("twin_pantograph", "twin_pantograph")


def twist(
    scene: PortSceneConfig,
    dy_m: float = 0.01,
    ramp_s: float = 1.0,
    squeeze_n: float = 2.0,
    devices: tuple[str, str] = TWIST_DEVICES,
    along_grip: bool = True,
) -> dict:
    """V4.5 (module docstring): g = 0, no angular coupling (the pads turn with the box's
    faces). Each hand holds its device by springs on x and y (2 kN/m) and squeezes through
    them: its target is inside the box along the grip line (the line through both hands) by
    `squeeze_n` times the compliance in series (its spring, the device's coupling, the pad's
    two contacts), so its push turns with the grip as a hand's does. The hands move 10 mm in
    opposite y along the arc of a rigid grip (a circle of radius r - inset about the box's
    centre, r the pad's distance from it), in 20 waypoints over 1 s; the hands' line is at
    theta = asin(y / (r - inset)) by construction. The box's angle is compared, every tick,
    with the hands' line (the brief's V4.5) and with the line through the pads' centres.

    On twin pantographs: the pads travel 10.5 mm, and a maglev's rate control engages past
    80 % of its 12.5 mm half-range (10 mm), moving its map's offset under the grip (the
    case on maglevs is reported beside it).

    A constant push along x instead (`along_grip=False`: the shipped squeeze users) does
    work as the grip turns: its couple turns the box past the hands (the brief's
    "off-centre squeeze" failure mode, physical), which that case reports."""
    return _twist(scene_with(scene, devices), dy_m, ramp_s, squeeze_n, along_grip)


def _twist(
    scene: PortSceneConfig, dy_m: float, ramp_s: float, squeeze_n: float, along_grip: bool
) -> dict:
    ports = tuple(
        dataclasses.replace(
            p,
            coupling_stiffness=(*p.coupling_stiffness[:2], 0.0),
            coupling_damping=(*p.coupling_damping[:2], 0.0),
        )
        for p in scene.ports
    )
    sc = dataclasses.replace(scene, ports=ports, gravity=(0.0, 0.0))
    radius = abs(sc.body(sc.ports[0].tool).position[0] - sc.body("box").position[0])
    k_hand = 2000.0
    # the push through the springs in series: the hand's, the device's coupling to its
    # pad, and the pad's two corner contacts
    compliance = (
        1.0 / k_hand
        + 1.0 / sc.ports[0].coupling_stiffness[0]
        + 1.0 / (2.0 * sc.contact.stiffness_n_per_m)
    )
    inset = squeeze_n * compliance if along_grip else 0.0
    t0, end = 0.2, 0.2 + ramp_s + 0.5
    scripts = []
    for side in (-1.0, 1.0):  # left goes down and right, right up and left
        script = [(0.0, -side * inset, 0.0, 0.0), (t0, -side * inset, 0.0, 0.0)]
        for s in np.linspace(0.0, 1.0, 21)[1:]:
            theta = math.asin(s * dy_m / (radius - inset))  # the hand itself moves dy
            dx = -side * (radius - (radius - inset) * math.cos(theta))
            script.append(
                (t0 + s * ramp_s, float(dx), side * (radius - inset) * math.sin(theta), 0.0)
            )
        scripts.append(tuple(script))
    users = [
        dataclasses.replace(u, stiffness=(k_hand, k_hand, u.stiffness[2]))
        for u in squeeze_users(sc, 0.0 if along_grip else squeeze_n, (scripts[0], scripts[1]))
    ]
    res = run_ports(sc, end, users=users)
    r = res.rows
    t = r["t"]
    starts = [np.asarray(sc.body(p.tool).position) for p in sc.ports]
    hands = [
        np.stack([np.interp(t, [w[0] for w in sc_], [w[1 + c] for w in sc_]) for c in (0, 1)], 1)
        + start
        for sc_, start in zip(scripts, starts, strict=True)
    ]
    hands_line = np.arctan2(hands[1][:, 1] - hands[0][:, 1], hands[1][:, 0] - hands[0][:, 0])
    left = pose_of(res, sc.ports[0].tool)
    right = pose_of(res, sc.ports[1].tool)
    pads_line = np.arctan2(right[:, 1] - left[:, 1], right[:, 0] - left[:, 0])
    angle = pose_of(res, "box")[:, 2]
    k0 = round(t0 / sc.period_s)
    intended = math.asin(dy_m / (radius - inset))
    return {
        "push": "along the grip" if along_grip else "along x",
        "devices": "+".join(p.device for p in sc.ports),
        "intended_rad": intended,
        "final_angle_rad": float(angle[-1]),
        "error_max_vs_hands_rad": float(np.max(np.abs(angle[k0:] - hands_line[k0:]))),
        "final_error_vs_hands_rad": float(angle[-1] - hands_line[-1]),
        "error_max_vs_pads_rad": float(np.max(np.abs(angle[k0:] - pads_line[k0:]))),
        "contact_losses": int(np.sum(r["n_contacts"][k0:] < 4)),
        "squeeze_min_n": float(
            np.min(np.linalg.norm(r["body_force"][k0:, res.body(sc.ports[0].tool), :2], axis=1))
        ),
    }


def stability_map(
    scene: PortSceneConfig,
    stiffnesses: tuple[float, ...] = (1e3, 1e4, 1e5, 1e6),
    masses: tuple[float, ...] = (0.01, 0.1, 1.0),
    duration_s: float = 2.0,
) -> list[dict]:
    """V4.4 (module docstring): ideal devices; each hand squeezes twice what the box needs
    (at least 0.2 N). K_c is the brief's: the contacts' stiffness, each of the box's four
    corner contacts; the couplings stay at the scene's. omega_dt = sqrt(4 K_c / m_O) dt
    (two contacts a side; symplectic Euler's limit is 2);
    `sink` is the squeeze's penetration per contact, N / 2 K_c: past the pad's half width
    (3 mm) the box's corners go through the pad, which is geometry, not instability. Energy
    at rest: the bodies' kinetic energy, largest in the last 0.25 s against the 0.25 s
    before."""
    out = []
    g = abs(scene.gravity[1])
    for k_c in stiffnesses:
        for m_o in masses:
            bodies = tuple(
                dataclasses.replace(b, mass=m_o) if b.name == "box" else b for b in scene.bodies
            )
            contact = dataclasses.replace(scene.contact, stiffness_n_per_m=k_c)
            sc = scene_with(scene, ("ideal", "ideal"), bodies=bodies, contact=contact)
            squeeze = max(0.2, 2.0 * m_o * g / (2.0 * sc.contact.friction))
            res = run_ports(sc, duration_s, users=squeeze_users(sc, squeeze))
            r = res.rows
            ke = kinetic_energy(res.model, r["qd"])
            n = len(ke)
            q = n // 8
            y = pose_of(res, "box")[:, 1]
            out.append(
                {
                    "k_c": k_c,
                    "m_o": m_o,
                    "omega_dt": math.sqrt(4 * k_c / m_o) * sc.period_s,
                    "sink_m": squeeze / (2 * k_c),
                    "finite": bool(
                        np.all(np.isfinite(r["q"])) and np.all(np.isfinite(r["command"]))
                    ),
                    "faults": int(r["invalid"][-1] + r["singular"][-1]),
                    "drop_m": float(y[n // 4] - y[-1]),
                    "ke_last": float(np.max(ke[n - q :])),
                    "ke_before": float(np.max(ke[n - 2 * q : n - q])),
                }
            )
    return out


def first_touch(
    scene: PortSceneConfig,
    impulses: bool,
    devices: tuple[str, str] = ("maglev", "maglev"),
    gap_m: float = 0.003,
    duration_s: float = 0.3,
) -> dict:
    """The grasp's first touch (module docstring), g = 0, the devices' noise on."""
    bodies = []
    for b in scene.bodies:
        if b.name in (p.tool for p in scene.ports):
            side = -1.0 if b.position[0] < 0 else 1.0
            b = dataclasses.replace(b, position=(b.position[0] + side * gap_m, b.position[1]))
        bodies.append(b)
    sc = scene_with(
        scene,
        devices,
        gravity=(0.0, 0.0),
        bodies=tuple(bodies),
        contact=dataclasses.replace(scene.contact, impulses=impulses),
    )
    res = run_ports(sc, duration_s, users=squeeze_users(sc, 2.0))
    r = res.rows
    touched = np.flatnonzero(r["n_contacts"] > 0)
    if touched.size == 0:
        raise ValueError(f"first_touch: the pads never touched the box in {duration_s} s")
    k = int(touched[0])
    after = slice(k, min(len(r), k + round(0.05 * sc.haptic_rate_hz)))
    tools = [res.body(p.tool) for p in sc.ports]
    ib = res.body("box")
    return {
        "impulses": impulses,
        "devices": "+".join(devices),
        "touch_ms": k * sc.period_s * 1e3,
        "pad_speed_m_per_s": [float(abs(r["qd"][k - 1, 3 * i])) for i in tools],
        "collisions": int(r["collisions"][-1]),
        "deepest_m": float(r["penetration"][after].max()),
        "bounces": int(np.sum(np.diff((r["n_contacts"][k:] > 0).astype(int)) < 0)),
        "command_peak_n": [float(np.abs(r["command"][after, p, 0]).max()) for p in range(2)],
        "command_end_n": [float(abs(r["command"][-1, p, 0])) for p in range(2)],
        "box_speed_max_m_per_s": float(np.abs(r["qd"][k:, 3 * ib]).max()),
    }


def tick_cost(scene: PortSceneConfig, ticks: int = 20000) -> dict:
    """Wall time of one tick of both ports (the co-simulation and two maglev models), each
    tick its own compiled call timed from Python (so the call's own cost is in): p50,
    p99 and the worst, against the 25 % of the period the loop's work may take."""
    run = PortRun(scene, users=squeeze_users(scene, 2.0))
    rows = np.zeros(ticks, PORT_ROW_DTYPE)
    d0, d1 = run.devices
    args = (run.model, run.data, run.io, (d0.records, d1.records), rows)
    run_port_ticks(*args, 0, 1)  # compile
    ns = np.zeros(ticks)
    clock = time.perf_counter_ns
    for k in range(ticks):
        t0 = clock()
        done = run_port_ticks(*args, k, k + 1)
        ns[k] = clock() - t0
        if done == k:  # the noise block ran out: refill, then time the tick itself
            for dev in run.devices:
                refill_noise(dev.noise, dev.records, scene.period_s)
            t0 = clock()
            run_port_ticks(*args, k, k + 1)
            ns[k] = clock() - t0
    us = ns / 1e3
    return {
        "ticks": ticks,
        "p50_us": float(np.percentile(us, 50)),
        "p99_us": float(np.percentile(us, 99)),
        "max_us": float(us.max()),
        "budget_us": 0.25e6 * scene.period_s,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write every figure to this file")
    args = ap.parse_args(argv)
    scene = load_port_scene(SCENE)
    load_simulated_device("maglev")  # fail early on a broken install
    figures: dict[str, Any] = {
        "V4.1 hold": hold(scene),
        "V4.2 below the cone": [
            below_cone(scene, devices, preload=preload)
            for preload in (True, False)
            for devices in (
                ("maglev", "maglev"),
                ("twin_pantograph", "twin_pantograph"),
                ("ideal", "ideal"),
            )
        ],
        "V4.3 lift and carry": lift(scene),
        "held at 1.25x the friction threshold, 10 s (creep)": [
            creep(scene, dev) for dev in ("twin_pantograph", "maglev", "ideal")
        ],
        "V4.5 twist": twist(scene),
        "V4.5 twist, each push a constant force along x": twist(scene, along_grip=False),
        "V4.5 twist on maglevs (their rate control engages past 10 mm)": twist(
            scene, devices=("maglev", "maglev")
        ),
        "V4.4 stability map": stability_map(scene),
        "first touch": [
            first_touch(scene, impulses, devices)
            for devices in (("maglev", "maglev"), ("twin_pantograph", "twin_pantograph"))
            for impulses in (True, False)
        ],
    }
    for name in shipped_port_scenes(hands=False):  # every two-port scene, the 64-shape one too
        figures[f"tick cost, {name}"] = tick_cost(load_port_scene(name))
    _print(figures)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=2)
    return 0


def _print(figures: dict) -> None:
    for name, value in figures.items():
        print(f"\n{name}")
        if isinstance(value, list):
            for row in value:
                print("  " + ", ".join(f"{k} {_fmt(v)}" for k, v in row.items()))
        else:
            for k, v in value.items():
                print(f"  {k}: {_fmt(v)}")


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_fmt(x)}" for k, x in v.items()) + "}"
    return str(v)


if __name__ == "__main__":
    sys.exit(main())
