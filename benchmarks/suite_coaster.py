"""hapticbench's coaster case (benchmarks/hapticbench.py): seed 003's train on its loop
(`coaster_loop`), shoved by a hand through a device, against a fine-step reference.

**The reference** is a transparent device: the hand's law (haptic_server/users.py) on the
device's mass, the finger disc fixed to the device and touching the cars' boxes through the
scene's own contact law of the cars' material (15 kN/m, 20 N s/m, Coulomb friction mu_k,
smoothed over FRICTION_SMOOTH_M_PER_S), and the train by the arc-length Lagrangian with the
contact's generalised force, all by fixed-step RK4 at REFERENCE_STEP_S (10 kHz). Its track
geometry is shared/reference_avar.py's closed-form ellipse (each car integrated in the
ellipse's own parameter u, as `ellipse_train` does): nothing of shared/track.py,
shared/avar.py or the god-object, so it is independent of the rendering under test. A
closed form has no push in it and DOP853 cannot step through the contacts' corners, hence
a fine step; halving it moves the reference's s by < 2 um over the case's 4 s, doubling it
by 11 um (tests/test_hapticbench.py checks its free ride against `ellipse_train`'s DOP853).
The friction is a small part: with mu_k = 0 the reference's s moves by 65 um at most and the
energy the push gives by 1 %.

What it leaves out, and so what the error includes: the god-object's coupling spring
(K_vc = 1000 N/m between the device and its proxy on the car) and its stick/slip friction
with hysteresis. A transparent device would let the hand feel the car as the finger does;
the error is how far the rendering is from that.

**The metrics** read the records every method hands back plus the train's two fields
(`avar_s`, `avar_sd`: a method that renders the coaster logs its train there; the row
holds the train after the tick's step, so row i is compared with the reference at tick
i + 1): the lead car's arc length against the reference over the run (RMS, max) and over
the push (PUSH_FROM_S to PUSH_UNTIL_S: the hand's shove and the train's first swing back
against the finger), the device against the reference's finger over the push, and the
energy the push gave the train (at the end of the run, the finger gone) against the
reference's, relative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from haptic_local_model.benchmarks.suite_metrics import device_inertia
from haptic_local_model.haptic_server.users import hand_wrench, user_record
from haptic_local_model.shared.config import SceneConfig, load_user
from haptic_local_model.shared.reference_avar import Ellipse

REFERENCE_STEP_S = 1e-4  # 10 kHz: the contact's 15 kN/m against the train's 0.15 kg
TICK_S = 1e-3  # the haptic loop's period: the reference is sampled at every tick
FRICTION_SMOOTH_M_PER_S = 1e-3  # Coulomb's friction as mu N tanh(v_t / this)
#: the push (configs/users/push_car.toml): the hand leaves at 0.3 s and is back out of the
#: way at 1.3 s; the train swings back onto the finger until about 1.2 s
PUSH_FROM_S, PUSH_UNTIL_S = 0.3, 1.5

#: a reference run: per tick (k * TICK_S) the lead car's arc length s (unwrapped), s', the
#: finger's centre, the train's energy
REFERENCE_DTYPE = np.dtype(
    [("t", "f8"), ("s", "f8"), ("sd", "f8"), ("finger", "f8", (2,)), ("energy", "f8")]
)

SCENE = "coaster_loop"
#: why a coupling to the pymunk sim cannot render a train (hapticbench's front ways, Isaac Lab)
NO_TRAIN_IN_PYMUNK = (
    "pymunk holds no train to push: the sim moves the cars as kinematic bodies along the"
    " haptic side's animation variable (sim_server/train.py), which only the god-object's"
    " finger pushes (a scene with a train refuses any other rendering method); a coupling"
    " of the sim's tool would meet cars of infinite mass"
)


def has_mechanism(scene: SceneConfig) -> bool:
    """Whether the scene has an avar mechanism (a train, a crank, a geared tree)."""
    return bool(scene.cars) or scene.crank is not None or scene.avar_tree is not None


@dataclass(frozen=True)
class Coaster:
    """What the reference reads of a coaster scene and its device."""

    loop: Ellipse  # the track and the cars' mass, inertia and gravity
    n_cars: int
    spacing: float
    half: tuple[float, float]  # a car's box, half extents along and across the track
    radius: float  # the finger disc's
    stiffness: float  # the cars' material: N/m, N s/m, mu_k
    damping: float
    friction: float
    start: tuple[float, float]  # the finger's centre at the start
    s0: float
    device_mass: tuple[float, float]

    @classmethod
    def of(cls, scene: SceneConfig, device: str) -> Coaster:
        cars, track = scene.cars[0], scene.tracks[0]
        if track.kind != "ellipse":
            raise ValueError(
                f"coaster reference: {scene.name}: track {track.name!r} is not an ellipse"
            )
        finger = next(b for b in scene.bodies if b.name == scene.tool.name)
        material = scene.materials[cars.material]
        mass = device_inertia(device)  # the device the hand moves (M_d's x, y)
        return cls(
            Ellipse(*track.semi_axes, tuple(track.center), cars.mass, cars.inertia, scene.gravity),
            cars.count, cars.spacing_m, (cars.size[0] / 2, cars.size[1] / 2), finger.radius,
            material.stiffness_n_per_m, material.damping_ns_per_m, material.friction,
            tuple(finger.position), cars.initial_s, (float(mass[0]), float(mass[1])),
        )  # fmt: skip

    def energy(self, u: np.ndarray, sd: np.ndarray) -> np.ndarray:
        """The train's energy for cars at u (n_cars, ...) moving at s' (...)."""
        kappa, _ = self.loop.curvature(u)
        inertia = np.sum(self.loop.mass + self.loop.inertia * kappa**2, axis=0)
        return 0.5 * inertia * sd**2 + np.sum(self.loop.potential(u), axis=0)

    def energy_at(self, s: float, sd: float) -> float:
        """The energy with the lead car at arc length s (the cars' u by quadrature)."""
        u = np.array([self.loop.u_at(s - k * self.spacing) for k in range(self.n_cars)])
        return float(self.energy(u, np.array(sd)))


def _contact(c: Coaster, k_state: tuple[float, ...], finger: tuple[float, ...], sd: float):
    """The force (x, y) of car k's box on the finger and its generalised force on the train
    (Q = F_car . J_c), or None apart. k_state: the car's point, unit tangent, curvature."""
    px, py, tx, ty, kappa = k_state
    x, y, vx, vy = finger
    hx, hy = c.half
    lx, ly = tx * (x - px) + ty * (y - py), -ty * (x - px) + tx * (y - py)
    if abs(lx) > hx + c.radius or abs(ly) > hy + c.radius:
        return None
    qx, qy = min(max(lx, -hx), hx), min(max(ly, -hy), hy)
    dist = math.hypot(lx - qx, ly - qy)
    if dist > 0.0:
        if dist >= c.radius:
            return None
        nlx, nly, depth = (lx - qx) / dist, (ly - qy) / dist, c.radius - dist
    elif hx - abs(lx) < hy - abs(ly):  # the centre inside the box: out by the nearer face
        nlx, nly, depth = math.copysign(1.0, lx), 0.0, c.radius + hx - abs(lx)
        qx = math.copysign(hx, lx)
    else:
        nlx, nly, depth = 0.0, math.copysign(1.0, ly), c.radius + hy - abs(ly)
        qy = math.copysign(hy, ly)
    nx, ny = tx * nlx - ty * nly, ty * nlx + tx * nly
    cx, cy = px + tx * qx - ty * qy, py + ty * qx + tx * qy
    jx, jy = tx - kappa * (cy - py), ty + kappa * (cx - px)  # the contact point per unit s'
    rx, ry = vx - jx * sd, vy - jy * sd
    normal = c.stiffness * depth - c.damping * (rx * nx + ry * ny)
    if normal <= 0.0:
        return None
    slip = -c.friction * normal * math.tanh((-rx * ny + ry * nx) / FRICTION_SMOOTH_M_PER_S)
    fx, fy = normal * nx - slip * ny, normal * ny + slip * nx
    return fx, fy, -(fx * jx + fy * jy)


def _rates(c: Coaster, user: np.ndarray, t: float, y: np.ndarray, hand: np.ndarray) -> np.ndarray:
    """d/dt of (u_0 .. u_(n-1), s, s', x, y, x', y'): the cars, the finger on the device."""
    n, e = c.n_cars, c.loop
    sd = float(y[n + 1])
    finger = (float(y[n + 2]), float(y[n + 3]), float(y[n + 4]), float(y[n + 5]))
    out = np.empty(n + 6)
    num, den, fx, fy = 0.0, 0.0, 0.0, 0.0
    ab = e.a * e.b
    for k in range(n):
        u = float(y[k])
        cu, su = math.cos(u), math.sin(u)
        rho = e.a**2 * cu * cu + e.b**2 * su * su
        root = math.sqrt(rho)
        tx, ty = e.a * cu / root, e.b * su / root
        kappa = ab / (rho * root)
        dkappa = -1.5 * ab * (e.b**2 - e.a**2) * math.sin(2.0 * u) / (rho**3)
        num += e.mass * (e.gravity[0] * tx + e.gravity[1] * ty) - e.inertia * kappa * dkappa * sd**2
        den += e.mass + e.inertia * kappa**2
        out[k] = sd / root
        point = (e.center[0] + e.a * su, e.center[1] - e.b * cu, tx, ty, kappa)
        touch = _contact(c, point, finger, sd)
        if touch is not None:
            fx, fy, num = fx + touch[0], fy + touch[1], num + touch[2]
    out[n], out[n + 1] = sd, num / den
    hand_wrench(user, t, np.array([finger[0], finger[1], 0.0]),
                np.array([finger[2], finger[3], 0.0]), hand)  # fmt: skip
    out[n + 2], out[n + 3] = finger[2], finger[3]
    out[n + 4] = (hand[0] + fx) / c.device_mass[0]
    out[n + 5] = (hand[1] + fy) / c.device_mass[1]
    return out


def reference(
    scene: SceneConfig, device: str, user_name: str, seconds: float,
    step_s: float = REFERENCE_STEP_S,
) -> np.ndarray:  # fmt: skip
    """The transparent device's run (module docstring): REFERENCE_DTYPE at every tick,
    0 to `seconds` inclusive."""
    c = Coaster.of(scene, device)
    user = user_record(load_user(user_name))
    user[0]["start_pose"] = (*c.start, 0.0)
    return integrate(c, user, np.zeros(2), seconds, step_s)


def integrate(
    c: Coaster, user: np.ndarray, finger_v: np.ndarray, seconds: float, step_s: float,
    s0: float | None = None, sd0: float = 0.0,
) -> np.ndarray:  # fmt: skip
    """RK4 of `_rates` from the train at (s0 or the scene's, sd0) and the finger at its start
    moving at finger_v; sampled every TICK_S."""
    s_start = c.s0 if s0 is None else s0
    n = c.n_cars
    y = np.zeros(n + 6)
    y[:n] = [c.loop.u_at(s_start - k * c.spacing) for k in range(n)]
    y[n], y[n + 1] = s_start, sd0
    y[n + 2], y[n + 3] = c.start
    y[n + 4 :] = finger_v
    per_tick = round(TICK_S / step_s)
    ticks = round(seconds / TICK_S) + 1
    out = np.zeros(ticks, REFERENCE_DTYPE)
    us = np.zeros((n, ticks))
    hand = np.zeros(3)
    t = 0.0
    for i in range(ticks):
        out[i]["t"], out[i]["s"], out[i]["sd"] = i * TICK_S, y[n], y[n + 1]
        out[i]["finger"] = y[n + 2 : n + 4]
        us[:, i] = y[:n]
        if i == ticks - 1:
            break
        for j in range(per_tick):
            t = i * TICK_S + j * step_s
            k1 = _rates(c, user, t, y, hand)
            k2 = _rates(c, user, t + step_s / 2, y + step_s / 2 * k1, hand)
            k3 = _rates(c, user, t + step_s / 2, y + step_s / 2 * k2, hand)
            k4 = _rates(c, user, t + step_s, y + step_s * k3, hand)
            y = y + step_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    out["energy"] = c.energy(us, out["sd"])
    return out


def unwrapped(s: np.ndarray, perimeter: float) -> np.ndarray:
    """Arc lengths on a closed loop without its wraps."""
    steps = np.mod(np.diff(s) + perimeter / 2, perimeter) - perimeter / 2
    return s[0] + np.concatenate(([0.0], np.cumsum(steps)))


def coaster_errors(
    scene: SceneConfig, device: str, ticks: np.ndarray, ref: np.ndarray
) -> dict[str, float]:
    """The rendered train and device against the reference (module docstring): mm, and the
    energy given to the train relative to the reference's."""
    c = Coaster.of(scene, device)
    n = min(len(ticks), len(ref) - 1)
    ticks = ticks[:n]
    s = unwrapped(ticks["avar_s"], c.loop.arc_length(2.0 * np.pi))
    err = 1e3 * np.abs(s - ref["s"][1 : n + 1])  # row i holds the train at tick i + 1
    push = (ticks["t"] >= PUSH_FROM_S) & (ticks["t"] < PUSH_UNTIL_S)
    device_err = 1e3 * np.hypot(*(ticks["device_pose"][:, :2] - ref["finger"][:n]).T)
    # both from the scene's start (the train at rest), by the closed form
    given = c.energy_at(float(s[-1]), float(ticks["avar_sd"][-1])) - float(ref["energy"][0])
    ref_given = float(ref["energy"][n] - ref["energy"][0])
    return {
        "rms_mm": float(np.sqrt(np.mean(err**2))),
        "max_mm": float(err.max()),
        "push_rms_mm": float(np.sqrt(np.mean(err[push] ** 2))),
        "device_push_rms_mm": float(np.sqrt(np.mean(device_err[push] ** 2))),
        "energy_given_rel_error": abs(given / ref_given - 1.0),
    }
