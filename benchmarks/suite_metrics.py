"""hapticbench's metrics over a method's records (benchmarks/hapticbench.py), for the cases
whose references are closed forms: the slide with friction, the moving wall and the
two-device grasp (its run too: only the ports' co-simulation renders it); the held linkage
through its singularity against the independent integration (benchmarks/linkage.py), over
the run and around the reference's rank loss; and the port energy and the passivity
observer's margin, which every case reports.

They read only the haptic loop's records every method hands back (`MethodRun.ticks`:
`t`, `dt`, `device_pose`, `device_twist`, `wrench_command`), so a plug-in's run is graded
as the built-ins' are, whatever it logs beside them.
"""

from __future__ import annotations

import math
import time
import tomllib

import numpy as np

from haptic_local_model.benchmarks import grasp
from haptic_local_model.benchmarks.linkage import chain_spec, reference_path
from haptic_local_model.benchmarks.suite_records import Case, MethodRun
from haptic_local_model.device_models.registry import device_config
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.shared.config import SafetySpec, SceneConfig, load_user
from haptic_local_model.shared.port_config import load_port_scene
from haptic_local_model.shared.reference import point_jacobian

#: the slide (configs/users/slide.toml): the hand drags at 8 cm/s between 0.5 s and 3.0 s;
#: a tick is sliding when the device moves along x faster than this, after the first 0.2 s
#: of the drag (the box starting to slide), until the hand stops
SLIDING_M_PER_S = 0.02
SLIDE_FROM_S, SLIDE_UNTIL_S = 0.7, 3.0
#: the floor presses back when the device's rendered normal force is above this (N)
PRESSED_N = 0.05

#: the moving wall (configs/scenes/wall_moving.toml): its face's law, the push, the masses
WALL_X0, WALL_RADIUS, WALL_AMPLITUDE, WALL_PERIOD_S = 0.055, 0.005, 0.01, 1.0
TOOL_HALF_X, TOOL_MASS = 0.03, 0.5
#: the wall's error is taken once the first impact has settled
WALL_SETTLED_S = 1.0

#: the linkage through its singularity: the transient is graded over this much either side of
#: the instant the reference's hold is nearest rank loss
SINGULAR_HALF_WINDOW_S = 0.25

#: the grasp (configs/ports/grasp_vertical.toml, the case's device on both ports): the slip
#: below the friction cone (V4.2, a 0.15 s run) and the hold at 1.25x the threshold (creep)
SLIP_RUN_S = 0.15
GRASP_HOLD_S = 10.0


def port_metrics(ticks: np.ndarray, window_s: float, device: str) -> dict[str, float]:
    """The energy the device's actuators gave the hand over the run (J; < 0: they took;
    benchmarks/wall_push.py's port_energy_j), and the passivity observer's margin over the
    same records (`observed`)."""
    command, twist = ticks["wrench_command"], ticks["device_twist"]
    work = float(np.sum((command[:, :2] * twist[:, :2]).sum(axis=1) * ticks["dt"]))
    margin = observed(command, twist, ticks["dt"], device_inertia(device), window_s)
    return {"port_energy_j": work, "passivity_margin_j": margin}


def observed(
    command: np.ndarray, twist: np.ndarray, dt: np.ndarray, inertia: np.ndarray, window_s: float
) -> float:
    """The passivity observer's margin: minus the most energy the device gave the hand over
    the observer's forgetting window (J; >= 0: it never gave any), recomputed from the
    records so every method is graded by one observer, the project's own
    (haptic_server/stages/safety.py): given_k = u_(k-1) . v_k dt less the change of the
    device's kinetic energy, W_k = W_(k-1) exp(-dt / window) + given_k."""
    kinetic = 0.5 * (inertia * twist**2).sum(axis=1)
    work = np.zeros(len(dt))
    work[1:] = (command[:-1] * twist[1:]).sum(axis=1) * dt[1:]
    given = work - np.diff(kinetic, prepend=0.0)
    decay = np.exp(-dt / window_s)
    level, worst = 0.0, 0.0
    for d, g in zip(decay.tolist(), given.tolist(), strict=True):
        level = level * d + g
        worst = max(worst, level)
    return 0.0 - worst


def slide_errors(scene: SceneConfig, ticks: np.ndarray) -> dict[str, float]:
    """The friction the device renders while the box slides, against mu_k N: mu_eff =
    sum |F_t| / sum |F_n| of the rendered force over the sliding ticks, its relative error
    against the floor's mu_k (the tool's own friction is 1: a contact's is the touched
    shape's, sim_server/world.py), and how long the floor stopped pressing while sliding."""
    mu_k = scene.materials["floor"].friction
    t = ticks["t"]
    force = ticks["wrench_command"]
    window = (t >= SLIDE_FROM_S) & (t < SLIDE_UNTIL_S)
    sliding = window & (ticks["device_twist"][:, 0] > SLIDING_M_PER_S)
    normal = float(np.sum(np.abs(force[sliding, 1])))
    mu = float(np.sum(np.abs(force[sliding, 0]))) / normal if normal > 0 else math.nan
    lost = sliding & (force[:, 1] < PRESSED_N)
    return {
        "mu_rel_error": abs(mu / mu_k - 1.0),
        "mu_eff": mu,
        "sliding_ms": float(np.sum(ticks["dt"][sliding]) * 1e3),
        "unpressed_ms": float(np.sum(ticks["dt"][lost]) * 1e3),
    }


def wall_law(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The moving wall's face (x, m) and its acceleration (m/s^2) at t: the sim moves a
    kinematic body's centre as x0 + A sin(w t) (sim_server/drive.py)."""
    w = 2 * np.pi / WALL_PERIOD_S
    face = WALL_X0 - WALL_RADIUS + WALL_AMPLITUDE * np.sin(w * t)
    return face, -WALL_AMPLITUDE * w * w * np.sin(w * t)


def moving_wall_errors(scene: SceneConfig, device: str, ticks: np.ndarray) -> dict[str, float]:
    """The device riding the moving wall against the wall's law: the rectangle's face inside
    the wall by (F - (m_device + m_tool) a(t)) / K, F the hand's push (the rigid pair pushed
    onto the wall, the wall's acceleration a(t)). The error of the device's face from there
    once settled (RMS, max), the peak depth at the first impact over F/K, contact losses
    (the face leaving the wall's law after the first contact)."""
    push = load_user("push_2n").wrench[0]
    stiffness = scene.materials["wall"].stiffness_n_per_m
    mass = float(device_inertia(device)[0]) + TOOL_MASS
    t = ticks["t"]
    face, accel = wall_law(t)
    depth = ticks["device_pose"][:, 0] + TOOL_HALF_X - face
    expected = (push - mass * accel) / stiffness
    touching = depth > 0.0
    first = int(np.argmax(touching)) if touching.any() else len(t) - 1
    settled = t >= WALL_SETTLED_S
    err = 1e3 * (depth - expected)
    early = ~settled & (np.arange(len(t)) >= first)
    return {
        "rms_mm": float(np.sqrt(np.mean(err[settled] ** 2))),
        "max_mm": float(np.abs(err[settled]).max()),
        "peak_over_fk": float(depth[early].max() / (push / stiffness)) if early.any() else math.nan,
        "contact_losses": float(np.sum(touching[first:-1] & ~touching[first + 1 :])),
    }


def device_inertia(device: str) -> np.ndarray:
    """A simulated device's diagonal inertia (its config's `inertia`: kg, kg, kg m^2)."""
    return np.array(tomllib.loads(device_config(device).read_text())["inertia"], dtype=float)


def grasp_run(case: Case) -> MethodRun:
    """The two-device grasp as this project renders it (the ports' co-simulation at 1 kHz,
    haptic_server/ports.py): benchmarks/grasp.py's slip below the cone and its hold, on
    the case's device at both ports; the cost is the wall time of both runs (with their
    setup) over their simulated seconds."""
    scene = load_port_scene(case.scene)
    start = time.perf_counter()
    slip = grasp.below_cone(scene, (case.device, case.device))
    held, drift = grasp.creep_run(scene, case.device, hold_s=GRASP_HOLD_S)
    wall_s = time.perf_counter() - start
    sim_s = SLIP_RUN_S + len(held.rows) / scene.haptic_rate_hz
    return MethodRun(
        np.zeros(0, TICK_DTYPE), scene, 1e3 * wall_s / sim_s, scene.haptic_rate_hz, 1,
        (held, {"slip": slip, "drift": drift}),
    )  # fmt: skip


def grasp_errors(case: Case, run: MethodRun) -> dict[str, float]:
    """The box's acceleration below the cone against g - 2 mu N / m (relative), against
    the same with the squeeze the pads measured, the drift of the held box along its pads
    (net and largest, mm), the fewest contact points in the hold; the passivity observer's
    margin over the hold (the smaller of the two devices')."""
    held, figures = run.records
    slip, drift = figures["slip"], figures["drift"]
    rows = held.rows
    dt = np.full(len(rows), 1.0 / run.scene.haptic_rate_hz)
    inertia = device_inertia(case.device)
    window = SafetySpec().passivity_window_s  # a port scene has the default observer
    margin = min(
        observed(rows["command"][:, p], rows["device_twist"][:, p], dt, inertia, window)
        for p in range(len(run.scene.ports))
    )
    return {
        "slip_accel_rel_error": abs(slip["error_fraction"]),
        "slip_vs_measured_squeeze": abs(slip["error_vs_measured_squeeze"]),
        "drift_mm": 1e3 * abs(drift["drift_m"]),
        "drift_max_mm": 1e3 * drift["max_m"],
        "contacts_min": float(drift["contacts_min"]),
        "passivity_margin_j": margin,
    }


def relative_sigma_min(scene: SceneConfig, q: np.ndarray) -> np.ndarray:
    """The smallest relative singular value of diag(1, 1, L) J_h at each row of joint angles
    q (the hold's rank test, benchmarks/holds.py): 0 where the hold has lost rank."""
    spec = chain_spec(scene)
    tool = scene.tool
    scale = np.array([1.0, 1.0, tool.characteristic_length_m])[:, None]
    out = np.empty(len(q))
    for i, qi in enumerate(q):
        s = np.linalg.svd(scale * point_jacobian(spec, qi, tool.link, tool.point), compute_uv=False)
        out[i] = s[-1] / s[0] if len(s) == 3 else 0.0
    return out


def window_rms(t: np.ndarray, err: np.ndarray, t0: float, half: float) -> float:
    """RMS of err over the samples with |t - t0| <= half."""
    inside = np.abs(t - t0) <= half
    if not inside.any():
        raise ValueError(f"hapticbench: no sample within {half} s of t = {t0} s")
    return float(np.sqrt(np.mean(err[inside] ** 2)))


def singular_errors(scene: SceneConfig, user: str, ticks: np.ndarray) -> dict[str, float]:
    """The device (what the hand holds) against the linkage driven by `user`'s push alone,
    over the run and within SINGULAR_HALF_WINDOW_S of the instant the reference's hold is
    nearest rank loss (its smallest relative singular value)."""
    t = ticks["t"]
    ref = reference_path(scene, t, float(t[-1]) + 1e-9, user)
    err = 1e3 * np.hypot(*(ticks["device_pose"][:, :2] - ref.pose[:, :2]).T)
    sigma = relative_sigma_min(scene, ref.q)
    i = int(np.argmin(sigma))
    return {
        "rms_mm": float(np.sqrt(np.mean(err**2))),
        "max_mm": float(err.max()),
        "rms_singular_mm": window_rms(t, err, float(t[i]), SINGULAR_HALF_WINDOW_S),
        "singular_t_s": float(t[i]),
        "sigma_min_rel": float(sigma[i]),
    }
