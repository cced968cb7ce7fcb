"""Simulated twin-pantograph haptic device (seed 001 §4, DESIGN §5).

Two five-bar pantographs, each with two base-mounted motors, hold the two ends of a rigid
handle bar: a planar 3-DOF device (handle centre x, y and angle theta) with 4 motors.

Conventions (device frame; origin = handle home pose):
- Motors 0, 1 form pantograph A, whose end point holds handle end a = c - (L/2) u(theta);
  motors 2, 3 form pantograph B holding end b = c + (L/2) u(theta), u = (cos, sin).
- elbow_sign[i] = +1 puts motor i's elbow counter-clockwise of the ray from its base point
  to its end point, -1 clockwise (the IK branch). assembly_sign[k] = +1 puts pantograph k's
  end point left of the ray from its first elbow to its second (the FK branch).
- Jm = d(motor angles)/d(handle pose), 4 x 3. By virtual work (massless, frictionless
  links) the handle wrench of motor torques tau is W = A tau with A = Jm^T (3 x 4).

Kinetic energy is exact for rigid links with their centre of mass at the link midpoint:
rotor + proximal link about the motor axis, each distal link as a rigid body (mass at its
midpoint, inertia about it), the handle bar (joint masses lumped into it). Per-tick work is
in numba kernels over the preallocated records PARAMS_DTYPE, STATE_DTYPE and WORK_DTYPE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from device_models.base import (
    FAULT_NONE,
    FAULT_SATURATED,
    FAULT_SINGULAR,
    FAULT_WORKSPACE,
    DeviceLimits,
    DeviceRenderingSpec,
)
from device_models.world_map import DeviceWorldMap, WorldMapSection
from shared.config import load_model_config, read_toml, require

#: Device-specific fault bit (base.py defines bits 0-2): the command held NaN or Inf.
FAULT_INVALID_COMMAND = 8

#: Central-difference step for dM/dx, m and rad: truncation (~(h/0.1 m)^2) and round-off
#: (~1e-16/h) errors are both ~1e-10 relative at the device's 0.1 m link scale.
INERTIA_FD_STEP = 1e-6

#: Tolerance below which a five-bar's proximal-distal cross product counts as zero (m^2).
_DEGENERATE_CROSS_M2 = 1e-12

#: Bisection steps for the largest feasible wrench scale: 2^-60 is below double precision.
_SCALE_BISECTIONS = 60

F8 = np.float64
I8 = np.int64

#: Static model of the device (built once from the config by `pack_parameters`).
PARAMS_DTYPE = np.dtype(
    [
        ("base", F8, (4, 2)),  # motor axis positions, m
        ("proximal_length", F8, (4,)),  # m
        ("distal_length", F8, (4,)),  # m
        ("elbow_sign", F8, (4,)),  # IK branch per motor (+1 / -1)
        ("assembly_sign", F8, (2,)),  # FK branch per pantograph (+1 / -1)
        ("handle_length", F8),  # m, between the two end-point joints
        ("motor_axis_inertia", F8, (4,)),  # rotor + proximal link about the motor axis, kg m^2
        ("distal_mass", F8, (4,)),  # kg
        ("distal_inertia", F8, (4,)),  # about the link's centre of mass, kg m^2
        ("handle_mass", F8),  # kg
        ("handle_inertia", F8),  # about the handle centre, kg m^2
        ("viscous", F8, (4,)),  # N m s/rad
        ("coulomb", F8, (4,)),  # N m
        ("coulomb_smoothing", F8),  # rad/s, tanh width of the Coulomb term
        ("torque_limit", F8, (4,)),  # N m
        ("max_wrench", F8, (3,)),  # N, N, N m
        ("workspace_min", F8, (3,)),  # m, m, rad
        ("workspace_max", F8, (3,)),
        ("reach_margin", F8),  # m
        ("min_distal_sine", F8),
        ("stop_stiffness", F8, (3,)),  # N/m, N/m, N m/rad
        ("stop_damping", F8, (3,)),  # N s/m, N s/m, N m s/rad
        ("encoder_resolution", F8),  # rad per count
        ("twist_cutoff_hz", F8),  # <= 0: no low-pass on the twist estimate
        ("max_substep", F8),  # s
        ("force_noise_std", F8, (3,)),  # N, N, N m
        ("has_force_sensor", I8),
    ]
)

#: Mutable state: the true physics, the held command and the newest sensor sample.
STATE_DTYPE = np.dtype(
    [
        ("pose", F8, (3,)),  # true handle pose
        ("twist", F8, (3,)),  # true handle twist
        ("held_torque", F8, (4,)),  # zero-order-held motor torques, N m
        ("applied_wrench", F8, (3,)),  # A tau at the measured pose
        ("command_fault", I8),
        ("physics_fault", I8),
        ("hand_wrench", F8, (3,)),  # true hand wrench of the last advance
        ("measured_hand_wrench", F8, (3,)),
        ("measured_motor_angles", F8, (4,)),  # quantised
        ("measured_pose", F8, (3,)),  # FK of the quantised angles
        ("measured_twist", F8, (3,)),  # filtered finite difference of measured poses
        ("measured_valid", I8),  # 1 if Jm, M_d, C_d below are valid at the measured pose
        ("measured_jacobian", F8, (4, 3)),
        ("measured_inertia", F8, (3, 3)),
        ("measured_coriolis", F8, (3, 3)),
        ("pose_fault", I8),  # workspace / singularity flags at the measured pose
    ]
)

#: Scratch space of the kernels.
WORK_DTYPE = np.dtype(
    [
        ("jacobian", F8, (4, 3)),
        ("inertia", F8, (3, 3)),
        ("inertia_gradient", F8, (3, 3, 3)),  # [k, i, j] = dM_ij / dx_k
        ("probe_pose", F8, (3,)),
        ("probe_inertia", F8, (3, 3)),
        ("coriolis", F8, (3, 3)),
        ("measures", F8, (2,)),
        ("motor_angles", F8, (4,)),
        ("fk_pose", F8, (3,)),
    ]
)


# --------------------------------------------------------------------------------- config


Vec3 = tuple[float, float, float]
Vec4 = tuple[float, float, float, float]


@dataclass(frozen=True)
class GeometrySection:
    """Link lengths, motor positions and branches (see the module docstring)."""

    motor_base_x_m: Vec4
    motor_base_y_m: Vec4
    proximal_length_m: Vec4
    distal_length_m: Vec4
    elbow_sign: tuple[int, int, int, int]
    assembly_sign: tuple[int, int]
    handle_length_m: float

    def __post_init__(self) -> None:
        require(all(v > 0 for v in self.proximal_length_m), "proximal_length_m", "must be > 0")
        require(all(v > 0 for v in self.distal_length_m), "distal_length_m", "must be > 0")
        require(all(v in (-1, 1) for v in self.elbow_sign), "elbow_sign", "entries must be ±1")
        require(all(v in (-1, 1) for v in self.assembly_sign), "assembly_sign", "must be ±1")
        require(self.handle_length_m > 0, "handle_length_m", "must be > 0")


@dataclass(frozen=True)
class InertiaSection:
    """Masses and inertias of the moving parts (links have their mass centre at midpoint)."""

    rotor_inertia_kgm2: Vec4
    proximal_mass_kg: Vec4
    proximal_inertia_kgm2: Vec4
    distal_mass_kg: Vec4
    distal_inertia_kgm2: Vec4
    handle_mass_kg: float
    handle_inertia_kgm2: float

    def __post_init__(self) -> None:
        for key in (
            "rotor_inertia_kgm2",
            "proximal_mass_kg",
            "proximal_inertia_kgm2",
            "distal_mass_kg",
            "distal_inertia_kgm2",
        ):
            require(all(v >= 0 for v in getattr(self, key)), key, "must be >= 0")
        require(self.handle_mass_kg > 0, "handle_mass_kg", "must be > 0")
        require(self.handle_inertia_kgm2 > 0, "handle_inertia_kgm2", "must be > 0")


@dataclass(frozen=True)
class FrictionSection:
    """Motor friction: tau_f = -viscous qd - coulomb tanh(qd / smoothing)."""

    viscous_nms_per_rad: Vec4
    coulomb_nm: Vec4
    coulomb_smoothing_rad_per_s: float

    def __post_init__(self) -> None:
        require(all(v >= 0 for v in self.viscous_nms_per_rad), "viscous_nms_per_rad", ">= 0")
        require(all(v >= 0 for v in self.coulomb_nm), "coulomb_nm", "must be >= 0")
        require(self.coulomb_smoothing_rad_per_s > 0, "coulomb_smoothing_rad_per_s", "must be > 0")


@dataclass(frozen=True)
class ActuatorSection:
    """Motor torque limits, the per-axis wrench bound reported by limits(), the servo rate."""

    torque_limit_nm: Vec4
    max_wrench: Vec3
    max_rate_hz: float

    def __post_init__(self) -> None:
        require(all(v > 0 for v in self.torque_limit_nm), "torque_limit_nm", "must be > 0")
        require(all(v > 0 for v in self.max_wrench), "max_wrench", "must be > 0")
        require(self.max_rate_hz > 0, "max_rate_hz", "must be > 0")


@dataclass(frozen=True)
class WorkspaceSection:
    """Workspace box with stops, and the reach and singularity fault thresholds."""

    workspace_min: Vec3
    workspace_max: Vec3
    reach_margin_m: float
    min_distal_sine: float
    stop_stiffness: Vec3
    stop_damping: Vec3

    def __post_init__(self) -> None:
        require(
            all(lo < hi for lo, hi in zip(self.workspace_min, self.workspace_max, strict=True)),
            "workspace_max",
            "must exceed workspace_min on every axis",
        )
        require(self.reach_margin_m >= 0, "reach_margin_m", "must be >= 0")
        require(0 <= self.min_distal_sine < 1, "min_distal_sine", "must be in [0, 1)")
        require(all(v >= 0 for v in self.stop_stiffness), "stop_stiffness", "must be >= 0")
        require(all(v >= 0 for v in self.stop_damping), "stop_damping", "must be >= 0")


@dataclass(frozen=True)
class SensorSection:
    """Encoders, the twist estimate and the optional handle force sensor."""

    encoder_counts_per_rev: int
    twist_cutoff_hz: float
    force_sensor: bool
    force_noise_std_n: float
    torque_noise_std_nm: float
    noise_seed: int

    def __post_init__(self) -> None:
        require(self.encoder_counts_per_rev > 0, "encoder_counts_per_rev", "must be > 0")
        require(self.twist_cutoff_hz >= 0, "twist_cutoff_hz", "must be >= 0")
        require(self.force_noise_std_n >= 0, "force_noise_std_n", "must be >= 0")
        require(self.torque_noise_std_nm >= 0, "torque_noise_std_nm", "must be >= 0")


@dataclass(frozen=True)
class SimulationSection:
    """Integration of the true dynamics."""

    max_substep_s: float

    def __post_init__(self) -> None:
        require(0 < self.max_substep_s <= 0.01, "max_substep_s", "must be in (0, 0.01] s")


@dataclass(frozen=True)
class TwinPantographConfig:
    """The twin-pantograph device, one frozen section per TOML table."""

    geometry: GeometrySection
    inertia: InertiaSection
    friction: FrictionSection
    actuators: ActuatorSection
    workspace: WorkspaceSection
    sensors: SensorSection
    simulation: SimulationSection
    rendering: DeviceRenderingSpec = field(default_factory=DeviceRenderingSpec)
    world_map: WorldMapSection | None = None  # None: scale 1, the engine sets the offset

    def __post_init__(self) -> None:
        """The workspace box must lie inside the reach and singularity limits: checked on a
        5 x 5 x 5 grid of the box (a grid check, not a proof for the whole box)."""
        params = pack_parameters(self)
        lo, hi = self.workspace.workspace_min, self.workspace.workspace_max
        axes = [np.linspace(lo[c], hi[c], 5) for c in range(3)]
        measures = np.empty(2)
        for x in axes[0]:
            for y in axes[1]:
                for t in axes[2]:
                    fault = pose_faults(params, np.array([x, y, t]), measures)
                    require(
                        fault == FAULT_NONE,
                        "workspace.workspace_max",
                        f"box point ({x:.4g}, {y:.4g}, {t:.4g}) is outside the reach or "
                        f"singularity limits (fault {fault})",
                    )

    @classmethod
    def from_toml_dict(cls, d: dict[str, Any], source: str) -> TwinPantographConfig:
        """Build from a parsed TOML table; a ConfigError names `source`, the key and the problem."""
        config: TwinPantographConfig = load_model_config(cls, d, source, "twin_pantograph")
        return config

    @classmethod
    def from_toml_file(cls, path: str | Path) -> TwinPantographConfig:
        """Read and validate a device TOML file."""
        return cls.from_toml_dict(read_toml(path), str(path))


def pack_parameters(config: TwinPantographConfig) -> np.ndarray:
    """The config as a 1-element PARAMS_DTYPE record for the kernels (the one conversion)."""
    g, m, f = config.geometry, config.inertia, config.friction
    a, w, s = config.actuators, config.workspace, config.sensors
    rec = np.zeros(1, PARAMS_DTYPE)
    p = rec[0]
    p["base"][:, 0] = g.motor_base_x_m
    p["base"][:, 1] = g.motor_base_y_m
    p["proximal_length"] = g.proximal_length_m
    p["distal_length"] = g.distal_length_m
    p["elbow_sign"] = g.elbow_sign
    p["assembly_sign"] = g.assembly_sign
    p["handle_length"] = g.handle_length_m
    l1 = np.asarray(g.proximal_length_m)
    p["motor_axis_inertia"] = (
        np.asarray(m.rotor_inertia_kgm2)
        + np.asarray(m.proximal_inertia_kgm2)
        + np.asarray(m.proximal_mass_kg) * (0.5 * l1) ** 2
    )
    p["distal_mass"] = m.distal_mass_kg
    p["distal_inertia"] = m.distal_inertia_kgm2
    p["handle_mass"] = m.handle_mass_kg
    p["handle_inertia"] = m.handle_inertia_kgm2
    p["viscous"] = f.viscous_nms_per_rad
    p["coulomb"] = f.coulomb_nm
    p["coulomb_smoothing"] = f.coulomb_smoothing_rad_per_s
    p["torque_limit"] = a.torque_limit_nm
    p["max_wrench"] = a.max_wrench
    p["workspace_min"] = w.workspace_min
    p["workspace_max"] = w.workspace_max
    p["reach_margin"] = w.reach_margin_m
    p["min_distal_sine"] = w.min_distal_sine
    p["stop_stiffness"] = w.stop_stiffness
    p["stop_damping"] = w.stop_damping
    p["encoder_resolution"] = 2.0 * math.pi / s.encoder_counts_per_rev
    p["twist_cutoff_hz"] = s.twist_cutoff_hz
    p["max_substep"] = config.simulation.max_substep_s
    p["force_noise_std"] = (s.force_noise_std_n, s.force_noise_std_n, s.torque_noise_std_nm)
    p["has_force_sensor"] = 1 if s.force_sensor else 0
    return rec


# ----------------------------------------------------------------------------- kinematics


@njit(cache=True)
def _end_point(p, k, handle_pose):
    """End point k (0: handle end a, 1: end b) and its derivative along theta."""
    half = 0.5 * p.handle_length if k == 1 else -0.5 * p.handle_length
    c = math.cos(handle_pose[2])
    s = math.sin(handle_pose[2])
    return handle_pose[0] + half * c, handle_pose[1] + half * s, -half * s, half * c


@njit(cache=True)
def _motor_ik(p, i, px, py):
    """Motor i's angle and elbow for end point (px, py) on its elbow branch."""
    bx = p.base[i, 0]
    by = p.base[i, 1]
    l1 = p.proximal_length[i]
    l2 = p.distal_length[i]
    vx = px - bx
    vy = py - by
    r = math.sqrt(vx * vx + vy * vy)
    if r == 0.0:
        return False, 0.0, bx, by
    cos_b = (l1 * l1 + r * r - l2 * l2) / (2.0 * l1 * r)
    if not (-1.0 <= cos_b <= 1.0):
        return False, 0.0, bx, by
    q = math.atan2(vy, vx) + p.elbow_sign[i] * math.acos(cos_b)
    return True, q, bx + l1 * math.cos(q), by + l1 * math.sin(q)


@njit(cache=True)
def _fivebar_end_point(p, k, q_first, q_second):
    """Exact FK of pantograph k: intersection of the distal-link circles on its branch."""
    i0 = 2 * k
    i1 = 2 * k + 1
    e0x = p.base[i0, 0] + p.proximal_length[i0] * math.cos(q_first)
    e0y = p.base[i0, 1] + p.proximal_length[i0] * math.sin(q_first)
    e1x = p.base[i1, 0] + p.proximal_length[i1] * math.cos(q_second)
    e1y = p.base[i1, 1] + p.proximal_length[i1] * math.sin(q_second)
    dx = e1x - e0x
    dy = e1y - e0y
    d = math.sqrt(dx * dx + dy * dy)
    if d == 0.0:
        return False, 0.0, 0.0
    r0 = p.distal_length[i0]
    r1 = p.distal_length[i1]
    a = (r0 * r0 - r1 * r1 + d * d) / (2.0 * d)
    h2 = r0 * r0 - a * a
    if h2 < 0.0:
        return False, 0.0, 0.0
    h = p.assembly_sign[k] * math.sqrt(h2)
    ux = dx / d
    uy = dy / d
    return True, e0x + a * ux - h * uy, e0y + a * uy + h * ux


@njit(cache=True)
def forward_kinematics(params, motor_angles, handle_pose):
    """Handle pose from the 4 motor angles; False if a pantograph cannot close.

    Over-determined: each pantograph's end point follows exactly from its two motors; the
    handle centre is their midpoint and theta the direction from end a to end b, which is
    exact for consistent angles and a least-squares-like blend for quantised ones.
    """
    p = params[0]
    ok_a, ax, ay = _fivebar_end_point(p, 0, motor_angles[0], motor_angles[1])
    ok_b, bx, by = _fivebar_end_point(p, 1, motor_angles[2], motor_angles[3])
    if not (ok_a and ok_b):
        return False
    handle_pose[0] = 0.5 * (ax + bx)
    handle_pose[1] = 0.5 * (ay + by)
    handle_pose[2] = math.atan2(by - ay, bx - ax)
    return True


@njit(cache=True)
def inverse_kinematics(params, handle_pose, motor_angles):
    """The 4 motor angles holding the handle at `handle_pose`; False if out of reach."""
    p = params[0]
    for i in range(4):
        px, py, _, _ = _end_point(p, i // 2, handle_pose)
        ok, q, _, _ = _motor_ik(p, i, px, py)
        if not ok:
            return False
        motor_angles[i] = q
    return True


@njit(cache=True)
def _jacobian_row(p, i, handle_pose):
    """Row i of Jm with the link geometry it came from (elbow, end point, dP/dtheta)."""
    px, py, dpx, dpy = _end_point(p, i // 2, handle_pose)
    ok, _, ex, ey = _motor_ik(p, i, px, py)
    # (E - B) x (P - E): zero when the proximal and distal links are collinear.
    cross = (ex - p.base[i, 0]) * (py - ey) - (ey - p.base[i, 1]) * (px - ex)
    if not ok or abs(cross) < _DEGENERATE_CROSS_M2:
        return False, 0.0, 0.0, 0.0, ex, ey, px, py, dpx, dpy
    gx = (px - ex) / cross
    gy = (py - ey) / cross
    return True, gx, gy, gx * dpx + gy * dpy, ex, ey, px, py, dpx, dpy


@njit(cache=True)
def motor_jacobian(params, handle_pose, jacobian):
    """Jm = d(motor angles)/d(handle pose), 4 x 3, from |P - E_i| = l2 differentiated.

    (P - E)·(dP - dE) = 0 with dE = perp(E - B) dq gives dq = (P - E)·dP / ((E - B) x (P - E)).
    The handle wrench of motor torques is W = Jm^T tau (virtual work).
    """
    p = params[0]
    for i in range(4):
        ok, j0, j1, j2, _, _, _, _, _, _ = _jacobian_row(p, i, handle_pose)
        if not ok:
            return False
        jacobian[i, 0] = j0
        jacobian[i, 1] = j1
        jacobian[i, 2] = j2
    return True


@njit(cache=True)
def torques_to_wrench(jacobian, motor_torques, wrench):
    """Handle wrench W = Jm^T tau produced by motor torques (3 x 4 map A = Jm^T)."""
    for c in range(3):
        acc = 0.0
        for i in range(4):
            acc += jacobian[i, c] * motor_torques[i]
        wrench[c] = acc


@njit(cache=True)
def singularity_measures(params, handle_pose, measures):
    """measures[0]: smallest |sine| between a pantograph's distal links (0 = collinear).
    measures[1]: smallest distance (m) of an end point from its motors' reach annulus
    boundary (negative outside). Returns False if the pose is out of reach."""
    p = params[0]
    reach = math.inf
    for i in range(4):
        px, py, _, _ = _end_point(p, i // 2, handle_pose)
        r = math.hypot(px - p.base[i, 0], py - p.base[i, 1])
        l1 = p.proximal_length[i]
        l2 = p.distal_length[i]
        reach = min(reach, r - abs(l1 - l2), l1 + l2 - r)
    measures[1] = reach
    measures[0] = 0.0
    if reach < 0.0:
        return False
    sine = math.inf
    for k in range(2):
        px, py, _, _ = _end_point(p, k, handle_pose)
        _, _, e0x, e0y = _motor_ik(p, 2 * k, px, py)
        _, _, e1x, e1y = _motor_ik(p, 2 * k + 1, px, py)
        cross = (px - e0x) * (py - e1y) - (py - e0y) * (px - e1x)
        sine = min(sine, abs(cross) / (p.distal_length[2 * k] * p.distal_length[2 * k + 1]))
    measures[0] = sine
    return True


@njit(cache=True)
def pose_faults(params, handle_pose, measures):
    """FAULT_WORKSPACE outside the box or near the reach limits, FAULT_SINGULAR when a
    pantograph's distal links are near collinear (parallel singularity)."""
    p = params[0]
    fault = FAULT_NONE
    for c in range(3):
        if not (p.workspace_min[c] <= handle_pose[c] <= p.workspace_max[c]):
            fault |= FAULT_WORKSPACE
    if not singularity_measures(params, handle_pose, measures):
        return fault | FAULT_WORKSPACE | FAULT_SINGULAR
    if measures[1] < p.reach_margin:
        fault |= FAULT_WORKSPACE
    if measures[0] < p.min_distal_sine:
        fault |= FAULT_SINGULAR
    return fault


# ------------------------------------------------------------------------------- dynamics


@njit(cache=True)
def task_inertia(params, handle_pose, inertia):
    """Task-space inertia M_d(x) (3 x 3) from the kinetic energy of every moving part.

    Motor i: J_axis (Jm_i^T Jm_i). Distal link (elbow E to end point P), rigid body with mass
    at its midpoint: m J_c^T J_c + I J_w^T J_w, J_c = (J_E + J_P)/2, J_w = d x (J_P - J_E)/l^2.
    Handle: diag(m_h, m_h, I_h) about its centre.
    """
    p = params[0]
    for a in range(3):
        for b in range(3):
            inertia[a, b] = 0.0
    inertia[0, 0] = p.handle_mass
    inertia[1, 1] = p.handle_mass
    inertia[2, 2] = p.handle_inertia
    for i in range(4):
        ok, r0, r1, r2, ex, ey, px, py, dpx, dpy = _jacobian_row(p, i, handle_pose)
        if not ok:
            return False
        row = (r0, r1, r2)
        # Elbow velocity: perp(E - B) qd_i; end-point velocity: J_P twist.
        nx = -(ey - p.base[i, 1])
        ny = ex - p.base[i, 0]
        je0 = (nx * r0, nx * r1, nx * r2)
        je1 = (ny * r0, ny * r1, ny * r2)
        jp0 = (1.0, 0.0, dpx)
        jp1 = (0.0, 1.0, dpy)
        dx = px - ex
        dy = py - ey
        inv_l2sq = 1.0 / (p.distal_length[i] * p.distal_length[i])
        m = p.distal_mass[i]
        inertia_c = p.distal_inertia[i]
        axis = p.motor_axis_inertia[i]
        for a in range(3):
            jca0 = 0.5 * (je0[a] + jp0[a])
            jca1 = 0.5 * (je1[a] + jp1[a])
            jwa = (dx * (jp1[a] - je1[a]) - dy * (jp0[a] - je0[a])) * inv_l2sq
            for b in range(3):
                jcb0 = 0.5 * (je0[b] + jp0[b])
                jcb1 = 0.5 * (je1[b] + jp1[b])
                jwb = (dx * (jp1[b] - je1[b]) - dy * (jp0[b] - je0[b])) * inv_l2sq
                inertia[a, b] += (
                    axis * row[a] * row[b] + m * (jca0 * jcb0 + jca1 * jcb1) + inertia_c * jwa * jwb
                )
    return True


@njit(cache=True)
def inertia_gradient(params, handle_pose, probe_pose, probe_inertia, gradient):
    """gradient[k] = dM_d/dx_k by central differences (step INERTIA_FD_STEP)."""
    for k in range(3):
        for c in range(3):
            probe_pose[c] = handle_pose[c]
        probe_pose[k] = handle_pose[k] + INERTIA_FD_STEP
        if not task_inertia(params, probe_pose, probe_inertia):
            return False
        for a in range(3):
            for b in range(3):
                gradient[k, a, b] = probe_inertia[a, b]
        probe_pose[k] = handle_pose[k] - INERTIA_FD_STEP
        if not task_inertia(params, probe_pose, probe_inertia):
            return False
        for a in range(3):
            for b in range(3):
                gradient[k, a, b] = (gradient[k, a, b] - probe_inertia[a, b]) / (
                    2.0 * INERTIA_FD_STEP
                )
    return True


@njit(cache=True)
def christoffel_matrix(gradient, twist, coriolis):
    """C_d(x, xd) from the Christoffel symbols of M_d: C_ij = sum_k G_ijk xd_k with
    G_ijk = (dM_ij/dx_k + dM_ik/dx_j - dM_jk/dx_i) / 2. Unlike C = Mdot/2 this gives the
    true velocity-product forces, and Mdot - 2C is skew-symmetric."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += (gradient[k, i, j] + gradient[j, i, k] - gradient[i, j, k]) * twist[k]
            coriolis[i, j] = 0.5 * acc


@njit(cache=True)
def _solve_spd3(m00, m01, m02, m11, m12, m22, f0, f1, f2):
    """Solve M a = f for a symmetric 3 x 3 M by Cholesky; ok is False if M is not SPD."""
    if m00 <= 0.0:
        return False, 0.0, 0.0, 0.0
    l00 = math.sqrt(m00)
    l10 = m01 / l00
    l20 = m02 / l00
    d11 = m11 - l10 * l10
    if d11 <= 0.0:
        return False, 0.0, 0.0, 0.0
    l11 = math.sqrt(d11)
    l21 = (m12 - l20 * l10) / l11
    d22 = m22 - l20 * l20 - l21 * l21
    if d22 <= 0.0:
        return False, 0.0, 0.0, 0.0
    l22 = math.sqrt(d22)
    y0 = f0 / l00
    y1 = (f1 - l10 * y0) / l11
    y2 = (f2 - l20 * y0 - l21 * y1) / l22
    a2 = y2 / l22
    a1 = (y1 - l21 * a2) / l11
    a0 = (y0 - l10 * a1 - l20 * a2) / l00
    return True, a0, a1, a2


# --------------------------------------------------------------------- redundancy resolution


@njit(cache=True)
def _det3_rows(j, r0, r1, r2):
    """Determinant of rows r0, r1, r2 of the 4 x 3 matrix j."""
    return (
        j[r0, 0] * (j[r1, 1] * j[r2, 2] - j[r1, 2] * j[r2, 1])
        - j[r0, 1] * (j[r1, 0] * j[r2, 2] - j[r1, 2] * j[r2, 0])
        + j[r0, 2] * (j[r1, 0] * j[r2, 1] - j[r1, 1] * j[r2, 0])
    )


@njit(cache=True)
def _alpha_interval(tau0, null, scale, limit):
    """Interval of alpha with |scale tau0_i + alpha n_i| <= limit_i for all i (lo > hi: empty)."""
    lo = -math.inf
    hi = math.inf
    for i in range(4):
        t = scale * tau0[i]
        if abs(null[i]) < 1e-12:
            if abs(t) > limit[i]:
                return 1.0, -1.0
            continue
        b0 = (-limit[i] - t) / null[i]
        b1 = (limit[i] - t) / null[i]
        lo = max(lo, min(b0, b1))
        hi = min(hi, max(b0, b1))
    return lo, hi


@njit(cache=True)
def resolve_torques(params, jacobian, wrench, motor_torques):
    """Motor torques for a handle wrench under the per-motor limits; returns the scale s.

    Solutions of Jm^T tau = W are tau0 + alpha n, with tau0 = Jm (Jm^T Jm)^-1 W the minimum-
    norm one and n the unit null vector of Jm^T (tau0 ⟂ n). The limits cut an interval of
    alpha; its point nearest 0 is the limit-constrained minimum-norm solution, so W is
    produced exactly whenever it is feasible (s = 1). Otherwise the largest feasible s W
    (bisection on s) is produced: the direction is kept and s < 1 reports saturation.
    A rank-deficient Jm gives s = 0 and zero torques.
    """
    limit = params[0].torque_limit
    g00 = g01 = g02 = g11 = g12 = g22 = 0.0
    for i in range(4):
        g00 += jacobian[i, 0] * jacobian[i, 0]
        g01 += jacobian[i, 0] * jacobian[i, 1]
        g02 += jacobian[i, 0] * jacobian[i, 2]
        g11 += jacobian[i, 1] * jacobian[i, 1]
        g12 += jacobian[i, 1] * jacobian[i, 2]
        g22 += jacobian[i, 2] * jacobian[i, 2]
    ok, y0, y1, y2 = _solve_spd3(g00, g01, g02, g11, g12, g22, wrench[0], wrench[1], wrench[2])
    # Null vector of Jm^T: signed 3 x 3 minors of Jm (generalised cross product).
    n0 = _det3_rows(jacobian, 1, 2, 3)
    n1 = -_det3_rows(jacobian, 0, 2, 3)
    n2 = _det3_rows(jacobian, 0, 1, 3)
    n3 = -_det3_rows(jacobian, 0, 1, 2)
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
    if not ok or norm == 0.0:
        for i in range(4):
            motor_torques[i] = 0.0
        return 0.0
    null = (n0 / norm, n1 / norm, n2 / norm, n3 / norm)
    tau0 = (
        jacobian[0, 0] * y0 + jacobian[0, 1] * y1 + jacobian[0, 2] * y2,
        jacobian[1, 0] * y0 + jacobian[1, 1] * y1 + jacobian[1, 2] * y2,
        jacobian[2, 0] * y0 + jacobian[2, 1] * y1 + jacobian[2, 2] * y2,
        jacobian[3, 0] * y0 + jacobian[3, 1] * y1 + jacobian[3, 2] * y2,
    )
    scale = 1.0
    lo, hi = _alpha_interval(tau0, null, 1.0, limit)
    if lo > hi:
        feasible = 0.0  # s = 0 is always feasible (alpha = 0)
        infeasible = 1.0
        for _ in range(_SCALE_BISECTIONS):
            mid = 0.5 * (feasible + infeasible)
            lo, hi = _alpha_interval(tau0, null, mid, limit)
            if lo <= hi:
                feasible = mid
            else:
                infeasible = mid
        scale = feasible
        lo, hi = _alpha_interval(tau0, null, scale, limit)
    alpha = min(max(0.0, lo), hi)
    for i in range(4):
        t = scale * tau0[i] + alpha * null[i]
        motor_torques[i] = min(max(t, -limit[i]), limit[i])  # guards the last ulp only
    return scale


# -------------------------------------------------------------------------- tick kernels


@njit(cache=True)
def _dynamics_terms(params, handle_pose, twist, work):
    """Jm, M_d, dM_d/dx and C_d at (handle_pose, twist) into `work`; False if out of reach."""
    w = work[0]
    if not motor_jacobian(params, handle_pose, w.jacobian):
        return False
    if not task_inertia(params, handle_pose, w.inertia):
        return False
    if not inertia_gradient(params, handle_pose, w.probe_pose, w.probe_inertia, w.inertia_gradient):
        return False
    christoffel_matrix(w.inertia_gradient, twist, w.coriolis)
    return True


@njit(cache=True)
def _stop_force(p, c, x, v):
    """Unilateral spring-damper of the workspace stop on axis c (task-space stand-in for the
    mechanism's joint stops)."""
    if x > p.workspace_max[c]:
        push = p.stop_stiffness[c] * (x - p.workspace_max[c]) + p.stop_damping[c] * v
        return -push if push > 0.0 else 0.0
    if x < p.workspace_min[c]:
        push = p.stop_stiffness[c] * (p.workspace_min[c] - x) - p.stop_damping[c] * v
        return push if push > 0.0 else 0.0
    return 0.0


@njit(cache=True)
def _sample_sensors(params, state, work, dt, normals, noise_index):
    """Encoders -> quantised angles -> FK pose; twist by filtered finite difference; M_d, C_d,
    Jm and faults at the measured pose; hand wrench plus sensor noise (none if
    noise_index < 0)."""
    p = params[0]
    st = state[0]
    w = work[0]
    if inverse_kinematics(params, st.pose, w.motor_angles):
        res = p.encoder_resolution
        for i in range(4):
            st.measured_motor_angles[i] = res * math.floor(w.motor_angles[i] / res + 0.5)
    if forward_kinematics(params, st.measured_motor_angles, w.fk_pose):
        if dt > 0.0:
            alpha = 1.0
            if p.twist_cutoff_hz > 0.0:
                alpha = 1.0 - math.exp(-2.0 * math.pi * p.twist_cutoff_hz * dt)
            for c in range(3):
                step = w.fk_pose[c] - st.measured_pose[c]
                if c == 2:
                    step = (step + math.pi) % (2.0 * math.pi) - math.pi
                st.measured_twist[c] += alpha * (step / dt - st.measured_twist[c])
        else:
            for c in range(3):
                st.measured_twist[c] = 0.0
        for c in range(3):
            st.measured_pose[c] = w.fk_pose[c]
    st.measured_valid = 0
    if _dynamics_terms(params, st.measured_pose, st.measured_twist, work):
        st.measured_valid = 1
        for a in range(3):
            for b in range(3):
                st.measured_inertia[a, b] = w.inertia[a, b]
                st.measured_coriolis[a, b] = w.coriolis[a, b]
        for i in range(4):
            for c in range(3):
                st.measured_jacobian[i, c] = w.jacobian[i, c]
    st.pose_fault = pose_faults(params, st.measured_pose, w.measures)
    for c in range(3):
        if p.has_force_sensor == 0:
            st.measured_hand_wrench[c] = 0.0
        elif noise_index < 0:
            st.measured_hand_wrench[c] = st.hand_wrench[c]
        else:
            noise = p.force_noise_std[c] * normals[noise_index + c]
            st.measured_hand_wrench[c] = st.hand_wrench[c] + noise


@njit(cache=True)
def advance_kernel(params, state, work, dt, hand_wrench, normals, noise_index):
    """True dynamics M_d(x) xdd + C_d xd = Jm^T (tau_held + tau_friction) + W_hand + W_stop
    over dt by semi-implicit Euler substeps (<= max_substep), then one sensor sample."""
    p = params[0]
    st = state[0]
    w = work[0]
    for c in range(3):
        st.hand_wrench[c] = hand_wrench[c]
    n_sub = max(1, math.ceil(dt / p.max_substep))
    h = dt / n_sub
    st.physics_fault = FAULT_NONE
    last0 = st.pose[0]
    last1 = st.pose[1]
    last2 = st.pose[2]
    for _ in range(n_sub):
        ok = _dynamics_terms(params, st.pose, st.twist, work)
        a0 = a1 = a2 = 0.0
        if ok:
            f0 = hand_wrench[0] + _stop_force(p, 0, st.pose[0], st.twist[0])
            f1 = hand_wrench[1] + _stop_force(p, 1, st.pose[1], st.twist[1])
            f2 = hand_wrench[2] + _stop_force(p, 2, st.pose[2], st.twist[2])
            for i in range(4):
                qd = w.jacobian[i, 0] * st.twist[0]
                qd += w.jacobian[i, 1] * st.twist[1] + w.jacobian[i, 2] * st.twist[2]
                tau = st.held_torque[i] - p.viscous[i] * qd
                tau -= p.coulomb[i] * math.tanh(qd / p.coulomb_smoothing)
                f0 += w.jacobian[i, 0] * tau
                f1 += w.jacobian[i, 1] * tau
                f2 += w.jacobian[i, 2] * tau
            m = w.inertia
            c = w.coriolis
            f0 -= c[0, 0] * st.twist[0] + c[0, 1] * st.twist[1] + c[0, 2] * st.twist[2]
            f1 -= c[1, 0] * st.twist[0] + c[1, 1] * st.twist[1] + c[1, 2] * st.twist[2]
            f2 -= c[2, 0] * st.twist[0] + c[2, 1] * st.twist[1] + c[2, 2] * st.twist[2]
            ok, a0, a1, a2 = _solve_spd3(
                m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2], f0, f1, f2
            )
        if not ok:
            # Out of reach despite the stops: hold the last valid pose, at rest.
            st.pose[0] = last0
            st.pose[1] = last1
            st.pose[2] = last2
            for k in range(3):
                st.twist[k] = 0.0
            st.physics_fault = FAULT_WORKSPACE
            break
        last0 = st.pose[0]
        last1 = st.pose[1]
        last2 = st.pose[2]
        st.twist[0] += h * a0
        st.twist[1] += h * a1
        st.twist[2] += h * a2
        for k in range(3):
            st.pose[k] += h * st.twist[k]
    _sample_sensors(params, state, work, dt, normals, noise_index)


@njit(cache=True)
def command_kernel(params, state, wrench):
    """Saturate a wrench command and hold the motor torques resolving it (zero-order hold).

    The per-axis max_wrench and the torque limits both scale the wrench uniformly (its
    direction is kept). NaN or Inf commands zero torque. Uses Jm at the measured pose, as a
    real driver would."""
    p = params[0]
    st = state[0]
    finite = True
    for c in range(3):
        if not math.isfinite(wrench[c]):
            finite = False
    if not finite or st.measured_valid == 0:
        for i in range(4):
            st.held_torque[i] = 0.0
        for c in range(3):
            st.applied_wrench[c] = 0.0
        st.command_fault = FAULT_SATURATED
        if not finite:
            st.command_fault |= FAULT_INVALID_COMMAND
        return
    axis_scale = 1.0
    for c in range(3):
        if abs(wrench[c]) > p.max_wrench[c]:
            axis_scale = min(axis_scale, p.max_wrench[c] / abs(wrench[c]))
    for c in range(3):
        st.applied_wrench[c] = axis_scale * wrench[c]
    scale = resolve_torques(params, st.measured_jacobian, st.applied_wrench, st.held_torque)
    torques_to_wrench(st.measured_jacobian, st.held_torque, st.applied_wrench)
    st.command_fault = FAULT_SATURATED if (axis_scale < 1.0 or scale < 1.0) else FAULT_NONE


@njit(cache=True)
def read_kernel(params, state, sensors):
    """Copy the newest sensor sample into a SENSOR_DTYPE record with the current faults;
    aux: the quantised encoder angles and the held motor torques (AUX_NAMES)."""
    p = params[0]
    st = state[0]
    r = sensors[0]
    for a in range(3):
        r.pose[a] = st.measured_pose[a]
        r.twist[a] = st.measured_twist[a]
        r.hand_wrench[a] = st.measured_hand_wrench[a]
        for b in range(3):
            r.inertia[a, b] = st.measured_inertia[a, b]
            r.coriolis[a, b] = st.measured_coriolis[a, b]
    r.has_force_sensor = p.has_force_sensor
    fault = st.pose_fault | st.command_fault | st.physics_fault
    if st.measured_valid == 0:
        fault |= FAULT_WORKSPACE
    r.fault = fault
    for i in range(4):
        r.aux[i] = st.measured_motor_angles[i]
        r.aux[4 + i] = st.held_torque[i]


@njit(cache=True)
def _copy_true_state(state, handle_pose, twist):
    st = state[0]
    for c in range(3):
        handle_pose[c] = st.pose[c]
        twist[c] = st.twist[c]


@njit(cache=True)
def _place_at_rest(params, state, work, handle_pose):
    """Put the true handle at rest at `handle_pose` with no held torque, and sample sensors."""
    st = state[0]
    for c in range(3):
        st.pose[c] = handle_pose[c]
        st.twist[c] = 0.0
        st.hand_wrench[c] = 0.0
        st.applied_wrench[c] = 0.0
        st.measured_twist[c] = 0.0
    for i in range(4):
        st.held_torque[i] = 0.0
    st.command_fault = FAULT_NONE
    st.physics_fault = FAULT_NONE
    _sample_sensors(params, state, work, 0.0, work[0].probe_pose, -1)  # -1: noise-free


# ---------------------------------------------------------------------------- the device

_NOISE_BLOCK = 3 * 4096  # standard normals drawn per refill of the force-sensor noise buffer

#: What SENSOR_DTYPE.aux holds (logged as device_aux): encoder angles (integer multiples of
#: the encoder resolution) and the zero-order-held motor torques.
AUX_NAMES = (
    "encoder_0_rad",
    "encoder_1_rad",
    "encoder_2_rad",
    "encoder_3_rad",
    "torque_0_nm",
    "torque_1_nm",
    "torque_2_nm",
    "torque_3_nm",
)


class TwinPantograph:
    """Simulated twin pantograph implementing `SimulatedDevice` (device frame, SI units).

    `command` returns a view of an internal buffer that the next command overwrites.
    `world_map` exists only when the config has a `[world_map]` table.
    """

    aux_names = AUX_NAMES

    def __init__(self, config: TwinPantographConfig) -> None:
        self.name: str = "twin_pantograph"
        self.config = config
        self.rendering = config.rendering
        self.world_map: DeviceWorldMap | None = None
        if config.world_map is not None:
            w = config.workspace
            half = tuple(
                min(-lo, hi) for lo, hi in zip(w.workspace_min, w.workspace_max, strict=True)
            )
            self.world_map = DeviceWorldMap.from_config(
                config.world_map, (half[0], half[1], half[2])
            )
        self.params = pack_parameters(config)
        self.state = np.zeros(1, STATE_DTYPE)
        self.work = np.zeros(1, WORK_DTYPE)
        self._applied = self.state["applied_wrench"][0]
        self._rng = np.random.default_rng(config.sensors.noise_seed)
        self._normals = np.empty(_NOISE_BLOCK)
        self._rng.standard_normal(out=self._normals)
        self._noise_index = 0
        self._zero_wrench = np.zeros(3)
        a, w = config.actuators, config.workspace
        self._limits = DeviceLimits(
            max_wrench=a.max_wrench,
            workspace_min=w.workspace_min,
            workspace_max=w.workspace_max,
            max_rate_hz=a.max_rate_hz,
        )
        self.reset(np.zeros(3))

    def limits(self) -> DeviceLimits:
        return self._limits

    def read(self, sensors: np.ndarray) -> None:
        read_kernel(self.params, self.state, sensors)

    def command(self, wrench: np.ndarray) -> np.ndarray:
        command_kernel(self.params, self.state, wrench)
        return self._applied

    def safe_stop(self) -> None:
        """Zero motor torque (the motors then only add their friction)."""
        command_kernel(self.params, self.state, self._zero_wrench)

    def servo_plant(self) -> tuple[np.ndarray, float]:
        return np.zeros(3), self.config.sensors.twist_cutoff_hz  # friction left out

    def reset(self, pose: np.ndarray) -> None:
        handle_pose = np.array(pose, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(handle_pose)):
            raise ValueError(f"reset pose must be finite, got {handle_pose}")
        if not inverse_kinematics(self.params, handle_pose, np.empty(4)):
            raise ValueError(f"reset pose {handle_pose} is out of the mechanism's reach")
        _place_at_rest(self.params, self.state, self.work, handle_pose)

    def advance(self, dt: float, hand_wrench: np.ndarray) -> None:
        if self._noise_index + 3 > _NOISE_BLOCK:
            self._rng.standard_normal(out=self._normals)
            self._noise_index = 0
        advance_kernel(
            self.params, self.state, self.work, dt, hand_wrench, self._normals, self._noise_index
        )
        self._noise_index += 3

    def true_state(self, pose: np.ndarray, twist: np.ndarray) -> None:
        _copy_true_state(self.state, pose, twist)

    def sense_hand(self, hand_wrench: np.ndarray) -> None:
        """The hand's wrench this tick, as the handle (or the force sensor, if any) feels it."""
        self.state[0]["hand_wrench"] = hand_wrench

    def held_torques(self) -> np.ndarray:
        """The zero-order-held motor torques (N m), a copy."""
        return np.array(self.state["held_torque"][0])

    def measured_motor_angles(self) -> np.ndarray:
        """The quantised encoder angles of the newest sample (rad), a copy."""
        return np.array(self.state["measured_motor_angles"][0])

    def kinetic_energy(self) -> float:
        """True kinetic energy 1/2 xd^T M_d(x) xd (J)."""
        st = self.state[0]
        inertia = np.empty((3, 3))
        task_inertia(self.params, st["pose"], inertia)
        twist = st["twist"]
        return float(0.5 * twist @ inertia @ twist)
