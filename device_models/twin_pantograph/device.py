"""The per-tick kernels (advance, command, read) and the `TwinPantograph` device."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.device_models.base import (
    FAULT_NONE,
    FAULT_SATURATED,
    FAULT_WORKSPACE,
    DeviceLimits,
)
from haptic_local_model.device_models.common import (
    FAULT_INVALID_COMMAND,
    KernelDevice,
    NoiseBuffer,
)
from haptic_local_model.device_models.kernels import register_model
from haptic_local_model.device_models.twin_pantograph.config import (
    PARAMS_DTYPE,
    STATE_DTYPE,
    WORK_DTYPE,
    TwinPantographConfig,
    pack_parameters,
)
from haptic_local_model.device_models.twin_pantograph.dynamics import (
    _solve_spd3,
    christoffel_matrix,
    inertia_gradient,
    task_inertia,
)
from haptic_local_model.device_models.twin_pantograph.kinematics import (
    forward_kinematics,
    inverse_kinematics,
    motor_jacobian,
    pose_faults,
    torques_to_wrench,
)
from haptic_local_model.device_models.twin_pantograph.torques import resolve_torques
from haptic_local_model.device_models.world_map import DeviceWorldMap


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
def advance(params, state, work, dt, hand_wrench, normals, noise_index):
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
                (m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2]), (f0, f1, f2)
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
def command(params, state, wrench):
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
def read(params, state, sensors):
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


@njit(cache=True)
def noise_needed(params, dt):
    """The force sensor's three normals."""
    return 3


@njit(cache=True)
def applied(state):
    """What the saturated motor torques produce."""
    return state[0].applied_wrench


KERNELS = register_model(PARAMS_DTYPE, globals())  # true_state, sense_hand: the defaults

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


class TwinPantograph(KernelDevice):
    """Simulated twin pantograph implementing `SimulatedDevice` (device frame, SI units).

    `command` returns a view of an internal buffer that the next command overwrites.
    `world_map` exists only when the config has a `[world_map]` table.
    """

    aux_names = AUX_NAMES

    name = "twin_pantograph"
    KERNELS = KERNELS

    def __init__(self, config: TwinPantographConfig) -> None:
        self.config = config
        world_map: DeviceWorldMap | None = None
        if config.world_map is not None:
            w = config.workspace
            half = tuple(
                min(-lo, hi) for lo, hi in zip(w.workspace_min, w.workspace_max, strict=True)
            )
            world_map = DeviceWorldMap.from_config(config.world_map, (half[0], half[1], half[2]))
        a, w = config.actuators, config.workspace
        limits = DeviceLimits(
            max_wrench=a.max_wrench,
            workspace_min=w.workspace_min,
            workspace_max=w.workspace_max,
            max_rate_hz=a.max_rate_hz,
        )
        records = (
            pack_parameters(config),
            np.zeros(1, STATE_DTYPE),
            np.zeros(1, WORK_DTYPE),
            NoiseBuffer(config.sensors.noise_seed, _NOISE_BLOCK),
        )
        super().__init__(records, limits, config.rendering, world_map)
        self.reset(np.zeros(3))

    def servo_plant(self) -> tuple[np.ndarray, float]:
        return np.zeros(3), self.config.sensors.twist_cutoff_hz  # friction left out

    def reset(self, pose: np.ndarray) -> None:
        handle_pose = np.array(pose, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(handle_pose)):
            raise ValueError(f"reset pose must be finite, got {handle_pose}")
        if not inverse_kinematics(self.params, handle_pose, np.empty(4)):
            raise ValueError(f"reset pose {handle_pose} is out of the mechanism's reach")
        _place_at_rest(self.params, self.state, self.work, handle_pose)

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
