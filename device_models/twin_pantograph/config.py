"""The twin pantograph's parameters: constants, the kernel records and the config sections
(one frozen dataclass per TOML table) with `pack_parameters` beside its dtype."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from haptic_local_model.device_models.base import (
    FAULT_NONE,
    INERTIA_RANGE,
    TORQUE_LIMIT_RANGE_NM,
    DeviceRenderingSpec,
    require_device_limits,
)
from haptic_local_model.device_models.common import ModelConfig, SimulationSection
from haptic_local_model.device_models.twin_pantograph.kinematics import pose_faults
from haptic_local_model.device_models.world_map import WorldMapSection
from haptic_local_model.shared.config import require, within, within_all

#: Central-difference step for dM/dx, m and rad: truncation (~(h/0.1 m)^2) and round-off
#: (~1e-16/h) errors are both ~1e-10 relative at the device's 0.1 m link scale.
INERTIA_FD_STEP = 1e-6


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
            within_all(getattr(self, key), INERTIA_RANGE, key)
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
        for i, torque in enumerate(self.torque_limit_nm):
            within(torque, TORQUE_LIMIT_RANGE_NM, f"torque_limit_nm[{i}]", "N m")
        require_device_limits(self.max_wrench, self.max_rate_hz)


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
        within(self.encoder_counts_per_rev, (1, 2**32), "encoder_counts_per_rev")
        require(self.twist_cutoff_hz >= 0, "twist_cutoff_hz", "must be >= 0")
        within(self.force_noise_std_n, (0.0, 10.0), "force_noise_std_n", "N")
        within(self.torque_noise_std_nm, (0.0, 1.0), "torque_noise_std_nm", "N m")
        require(0 <= self.noise_seed < 2**63, "noise_seed", "must be in [0, 2^63)")


@dataclass(frozen=True)
class TwinPantographConfig(ModelConfig):
    """The twin-pantograph device, one frozen section per TOML table."""

    MODEL: ClassVar[str] = "twin_pantograph"

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
