"""A sim step in one compiled call: the tool drive, the kinematic bodies and pymunk's substeps.

`step_world` advances the world by one sim period: at each of its substeps it sets the
velocity of the oscillating kinematic bodies, drives the tool toward the haptic side's
target (seed 001 Fig. 1: computed-torque tracking of the proxy; seed 002 §4: a spring to the
device for virtual_coupling_foh; damped to rest when the haptic side is silent) and calls
Chipmunk's `cpSpaceStep` (sim_server/chipmunk.py), all without returning to Python. The
arithmetic is the Python drive's, operation for operation.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numba import cfunc, njit, types

from haptic_local_model.shared.kinematics import (
    MAX_DOF,
    link_frames,
    mass_matrix_and_gravity,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.shared.protocol.proxy import MAX_IMPULSES
from haptic_local_model.sim_server import chipmunk as cp
from haptic_local_model.sim_server.tool import TOOL_LINKAGE, tool_state
from haptic_local_model.sim_server.train import move_train, no_train

DRIVE_REST, DRIVE_PROXY, DRIVE_DEVICE = 0, 1, 2  # no fresh target / follow the proxy / FOH
#: bodies a god-object pushes per step: the shapes of a step's impulses, each a body or a
#: string segment's two nodes
MAX_PUSHES = 2 * MAX_IMPULSES

I8, F8 = np.int64, np.float64

#: What the haptic side wants of the tool over the step being run (set before each step).
TARGET_DTYPE = np.dtype(
    [
        ("mode", I8),  # DRIVE_REST, DRIVE_PROXY or DRIVE_DEVICE
        ("q", F8, (MAX_DOF,)),  # the proxy
        ("qd", F8, (MAX_DOF,)),
        ("device_pose", F8, (3,)),  # the device, world frame (DRIVE_DEVICE)
        ("device_twist", F8, (3,)),
        # a god-object's forces on the bodies it touches (0: none), applied every substep
        ("env_body", I8, (MAX_PUSHES,)),  # cpBody pointers of dynamic bodies
        ("env_point", F8, (MAX_PUSHES, 2)),  # world, m
        ("env_force", F8, (MAX_PUSHES, 2)),  # N
    ]
)

#: An oscillating kinematic body: v(t) = velocity + amplitude w cos(w t), w = 2 pi / period;
#: and turning: theta(t) = theta0 + spin t + angle_amplitude sin(2 pi t / angle_period_s).
KINEMATIC_DTYPE = np.dtype(
    [
        ("body", I8), ("velocity", F8, (2,)), ("amplitude", F8, (2,)), ("period_s", F8),
        ("spin", F8), ("angle_amplitude", F8), ("angle_period_s", F8),
    ]
)  # fmt: skip


def drive_work(train: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Scratch for step_world: frame positions, frame angles, Jacobian, D, G, q, qd, tau,
    the acceleration asked of the tool, a 3-vector; and the scene's train
    (sim_server/train.py SIM_TRAIN_DTYPE[1], a disabled one if none)."""
    return (
        np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF), np.zeros((3, MAX_DOF)),
        np.zeros((MAX_DOF, MAX_DOF)), np.zeros(MAX_DOF), np.zeros(MAX_DOF), np.zeros(MAX_DOF),
        np.zeros(MAX_DOF), np.zeros(MAX_DOF), np.zeros(3), no_train() if train is None else train,
    )  # fmt: skip


@njit(cache=True)
def set_target(target, mode, q, qd, device_pose, device_twist):
    """The haptic side's target for the next step into its record (one call, not four
    field writes from Python)."""
    tg = target[0]
    tg.mode = mode
    for i in range(q.shape[0]):
        tg.q[i] = q[i]
        tg.qd[i] = qd[i]
    for c in range(3):
        tg.device_pose[c] = device_pose[c]
        tg.device_twist[c] = device_twist[c]


@njit(cache=True)
def step_world(tool, target, chain, kinematic, sim_time, period, substeps, work):
    """One sim period of `substeps` Chipmunk steps (see the module docstring).

    tool: TOOL_DTYPE[1]; target: TARGET_DTYPE[1]; chain: the tool's CHAIN_DTYPE[1];
    kinematic: KINEMATIC_DTYPE[k]; work: drive_work()."""
    t, tg = tool[0], target[0]
    h = period / substeps
    if t.kind == TOOL_LINKAGE:  # D and G at the period's start, frozen for it
        q = work[5]
        tool_state(tool, q, work[6])
        mass_matrix_and_gravity(chain, t.gravity, q, (work[0], work[1], work[2]), work[3], work[4])
    for k in range(substeps):
        now = sim_time + k * h
        for i in range(kinematic.shape[0]):
            _move_kinematic(kinematic[i], now + h, h)
        move_train(work[10], h)
        _push_touched(tg)
        if t.kind == TOOL_LINKAGE:
            _drive_linkage(tool, tg, chain, work, k * h)
        elif tg.mode == DRIVE_DEVICE:
            _couple_body(t, tg, k * h)
        else:
            _drive_body(t, tg, k * h)
        cp.space_step(t.space, h)
    for i in range(kinematic.shape[0]):
        _move_kinematic(kinematic[i], sim_time + period, 0.0)


@njit(cache=True)
def _push_touched(tg):
    """The god-object's forces on the dynamic bodies it touches, for this substep (pymunk
    clears a body's force after each step); a sleeping body is woken."""
    for j in range(MAX_PUSHES):
        b = tg.env_body[j]
        if b != 0:
            cp.body_activate(b)
            cp.body_apply_force_at_world_point(
                b, tg.env_force[j, 0], tg.env_force[j, 1], tg.env_point[j, 0], tg.env_point[j, 1]
            )


@njit(cache=True, inline="always")
def _sine_rate(w, t, h):
    """The rate of sin(w t): at t (h = 0), or its mean over [t - h, t]."""
    if h == 0.0:
        return w * math.cos(w * t)
    return (math.sin(w * t) - math.sin(w * (t - h))) / h


@njit(cache=True)
def _move_kinematic(kin, t, h):
    """The velocities of the substep ending at t: the law's mean over [t - h, t], so that
    pymunk's step (x += v h) lands the body on its law at every substep's end. The law's
    velocity at t instead (before 0.13) drew the body (h / 2)(v(t) - v(0)) off its law: a
    platform of 5 mm at 1 Hz was 105 um off peak to peak at 30 Hz with 10 substeps. With
    h = 0, the law's own twist at t: what the update announcing the state at t publishes
    (the mean of the last substep is the twist half a substep earlier)."""
    if kin.period_s > 0.0:
        rate = _sine_rate(2.0 * math.pi / kin.period_s, t, h)
        cp.body_set_velocity(
            kin.body,
            kin.velocity[0] + kin.amplitude[0] * rate,
            kin.velocity[1] + kin.amplitude[1] * rate,
        )
    if kin.angle_period_s > 0.0:
        swing = kin.angle_amplitude * _sine_rate(2.0 * math.pi / kin.angle_period_s, t, h)
        cp.body_set_angular_velocity(kin.body, kin.spin + swing)


@njit(cache=True)
def _drive_linkage(tool, tg, chain, work, t_ahead):
    """Computed-torque tracking of the proxy with D, G frozen for the period (or the device
    coupling, or damping to rest), as joint torques on the link bodies; G is added because
    pymunk applies gravity itself, so the drive has no steady error."""
    t = tool[0]
    mass, grav, q, qd, tau, acc = work[3], work[4], work[5], work[6], work[7], work[8]
    d = t.dof
    tool_state(tool, q, qd)
    w = 2.0 * math.pi * t.bandwidth_hz
    if tg.mode == DRIVE_DEVICE:
        _device_coupling(t, tg, chain, q, qd, t_ahead, work)
    else:
        for i in range(d):
            if tg.mode == DRIVE_REST:
                acc[i] = -2.0 * w * qd[i]
            else:
                q_goal = tg.q[i] + tg.qd[i] * t_ahead
                acc[i] = w * w * (q_goal - q[i]) + 2.0 * w * (tg.qd[i] - qd[i])
        for i in range(d):
            s = 0.0
            for j in range(d):
                s += mass[i, j] * acc[j]
            tau[i] = s
    for i in range(d):
        torque = tau[i] + grav[i]
        body = t.bodies[i]
        cp.body_set_torque(body, cp.body_torque(body) + torque)
        up = t.parents[i]  # the joint's reaction: on the link it hangs from (a root: ground)
        if 0 <= up < i:
            prev = t.bodies[up]
            cp.body_set_torque(prev, cp.body_torque(prev) - torque)


@njit(cache=True)
def _device_coupling(t, tg, chain, q, qd, t_ahead, work):
    """virtual_coupling_foh (seed 002 §4) on a linkage: tau = J^T (K_spring (x_dev - x_tool)
    - K_damp v_tool), the device pose extrapolated by its twist over the period (v_tool less
    the device's twist with foh_relative_damping: a virtual coupling's damper)."""
    frame_pos, frame_angle, jac, tau, f = work[0], work[1], work[2], work[7], work[9]
    c = chain[0]
    d = t.dof
    link_frames(c, q, d, frame_pos, frame_angle)
    point_on_link(frame_pos, frame_angle, t.op_link, t.op_point, f)
    px, py = f[0], f[1]
    point_jacobian(c, frame_pos, d, t.op_link, px, py, jac)
    x_tool = (px, py, frame_angle[t.op_link])
    for r in range(3):
        v = 0.0
        for j in range(d):
            v += jac[r, j] * qd[j]
        x_dev = tg.device_pose[r] + tg.device_twist[r] * t_ahead
        v -= t.foh_relative * tg.device_twist[r]
        f[r] = t.foh_stiffness[r] * (x_dev - x_tool[r]) - t.foh_damping[r] * v
    for j in range(d):
        tau[j] = jac[0, j] * f[0] + jac[1, j] * f[1] + jac[2, j] * f[2]


@njit(cache=True)
def _drive_body(t, tg, t_ahead):
    """Computed-force tracking of the proxy by a free body (D = diag(m, m, I)): force at the
    centre of gravity, gravity cancelled; damped to rest without a target."""
    b = t.bodies[0]
    w = 2.0 * math.pi * t.bandwidth_hz
    px, py = cp.body_position(b)
    vx, vy = cp.body_velocity(b)
    th, om = cp.body_angle(b), cp.body_angular_velocity(b)
    if tg.mode == DRIVE_REST:
        ax, ay, al = -2.0 * w * vx, -2.0 * w * vy, -2.0 * w * om
    else:
        gq, gv = tg.q, tg.qd
        ax = w * w * (gq[0] + gv[0] * t_ahead - px) + 2.0 * w * (gv[0] - vx)
        ay = w * w * (gq[1] + gv[1] * t_ahead - py) + 2.0 * w * (gv[1] - vy)
        al = w * w * (gq[2] + gv[2] * t_ahead - th) + 2.0 * w * (gv[2] - om)
    m = cp.body_mass(b)
    fx, fy = m * ax - m * t.gravity[0], m * ay - m * t.gravity[1]
    cx, cy = cp.body_center_of_gravity(b)
    wx, wy = cp.body_local_to_world(b, cx, cy)
    cp.body_apply_force_at_world_point(b, fx, fy, wx, wy)
    cp.body_set_torque(b, cp.body_torque(b) + cp.body_moment(b) * al)


@njit(cache=True)
def _couple_body(t, tg, t_ahead):
    """virtual_coupling_foh on a free body: the spring K_spring (x_dev - x_tool) - K_damp
    v_tool at the operational point r (body frame; the centre of mass is the body's origin),
    pymunk's gravity on the tool cancelled as the proxy drive does."""
    b = t.bodies[0]
    k, c = t.foh_stiffness, t.foh_damping
    dp, dv = tg.device_pose, tg.device_twist
    x, y = cp.body_position(b)
    vx, vy = cp.body_velocity(b)
    th, om = cp.body_angle(b), cp.body_angular_velocity(b)
    cos_t, sin_t = math.cos(th), math.sin(th)
    rx = cos_t * t.op_point[0] - sin_t * t.op_point[1]
    ry = sin_t * t.op_point[0] + cos_t * t.op_point[1]
    rel = t.foh_relative  # 1: the damper acts on the velocity relative to the device's
    fx = k[0] * (dp[0] + dv[0] * t_ahead - x - rx) - c[0] * (vx - om * ry - rel * dv[0])
    fy = k[1] * (dp[1] + dv[1] * t_ahead - y - ry) - c[1] * (vy + om * rx - rel * dv[1])
    tau = k[2] * (dp[2] + dv[2] * t_ahead - th) - c[2] * (om - rel * dv[2])
    m = cp.body_mass(b)
    cp.body_apply_force_at_world_point(b, fx - m * t.gravity[0], fy - m * t.gravity[1], x, y)
    cp.body_set_torque(b, cp.body_torque(b) + (tau + rx * fy - ry * fx))


@functools.cache
def table_drag(rate_per_s: float) -> Any:
    """A Chipmunk velocity function (a numba cfunc) adding exponential drag at `rate_per_s`
    to pymunk's update: a block sliding on a table. One per rate, compiled on first use."""

    @cfunc(
        types.void(types.int64, types.float64, types.float64, types.float64, types.float64),
        cache=True,
    )
    def update(body, gravity_x, gravity_y, damping, dt):  # pragma: no cover - runs in C
        cp.body_update_velocity(
            body, gravity_x, gravity_y, damping * math.exp(-rate_per_s * dt), dt
        )

    return update
