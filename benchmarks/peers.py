"""Baselines written as peers write them, for hapticbench (benchmarks/hapticbench.py).

**Isaac Lab + Haply** (`isaac_haply`): the sim's contact force sent straight to the device
and clipped, as Isaac Lab's `scripts/demos/haply_teleoperation.py` does it: physics at 200
Hz (`SimulationCfg(dt=1 / 200)`), five physics steps per pass of its loop, then the net
contact force on the tool read and sent to the device (`set_force_feedback`), clipped at 2 N
(`HaplyDeviceCfg(limit_force=2.0)`); the tool is driven to the device's pose by a stiff
position drive (its Franka's high-gain PD and IK). Here: the scene's pymunk world at 200 Hz,
the tool's operational point pulled to the device's pose by seed 002's coupling spring and
damper (the scene's `foh_spring_*`, with the substeps that spring needs to be stable), the
contact impulses on the tool over the last pymunk substep (over its length) as the force,
held for the 25 ms until the next, clipped at 2 N in magnitude. No local model and no force
between contacts: the device feels the world only through the contact force, so a mechanism
the tool holds (the linkage) is not rendered at all, and an avar train (the coaster) is not
in pymunk to be pushed (its row says so). The device and the hand are the case's,
at 1 kHz.
"""

from __future__ import annotations

import time

import numpy as np

from haptic_local_model.benchmarks.front import coupling_substeps_needed
from haptic_local_model.benchmarks.suite_coaster import NO_TRAIN_IN_PYMUNK, has_mechanism
from haptic_local_model.benchmarks.suite_records import Case, MethodRun, NotApplicableError
from haptic_local_model.device_models.base import world_map_of
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.users import hand_wrench, user_record
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.kinematics import (
    MAX_DOF,
    link_frames,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

ISAAC_PHYSICS_HZ = 200.0  # SimulationCfg(dt=1 / 200)
ISAAC_STEPS_PER_FEEDBACK = 5  # `for _ in range(5): sim.step()` before each force read
HAPLY_LIMIT_FORCE_N = 2.0  # HaplyDeviceCfg(limit_force=2.0)
ISAAC_HAPLY = "contact force to the device every 25 ms, clipped at 2 N (Isaac Lab + Haply way)"


class ToolPoint:
    """The operational point of a SimWorld's tool: its pose, its velocity, a force on it."""

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self.frame_pos, self.frame_angle = np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF)
        self.point, self.jac, self.q = np.zeros(2), np.zeros((3, MAX_DOF)), np.zeros(MAX_DOF)
        linkage = world.scene.tool.kind == "linkage"
        self.body = world.tool_bodies[world.op_link if linkage else 0]

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        w, d = self.world, self.world.dof
        tq, tqd = w.tool_state()
        self.q[:d] = tq
        link_frames(w.chain[0], self.q, d, self.frame_pos, self.frame_angle)
        point_on_link(self.frame_pos, self.frame_angle, w.op_link, w.op_point, self.point)
        point_jacobian(w.chain[0], self.frame_pos, d, w.op_link, *self.point, self.jac)
        pose = np.array([self.point[0], self.point[1], self.frame_angle[w.op_link]])
        return pose, self.jac[:, :d] @ tqd

    def contact_force(self, step_s: float) -> np.ndarray:
        """The net contact force (x, y) on the tool's body over the last pymunk step."""
        total = np.zeros(2)

        def add(arbiter: object) -> None:
            impulse = arbiter.total_impulse  # type: ignore[attr-defined]
            # pymunk gives the impulse on the arbiter's first body
            sign = 1.0 if arbiter.bodies[0] is self.body else -1.0  # type: ignore[attr-defined]
            total[0] += sign * impulse.x
            total[1] += sign * impulse.y

        self.body.each_arbiter(add)
        return total / step_s


def isaac_haply(case: Case) -> MethodRun:
    """The case rendered the Isaac Lab + Haply way (module docstring)."""
    if case.ports != 1:
        raise NotApplicableError(
            "one device's contact force: the demo drives one Haply device, and the grasp's"
            " two would each feel the box only through a clipped 25 ms sample"
        )
    scene = load_scene(case.scene)
    if has_mechanism(scene):
        raise NotApplicableError(NO_TRAIN_IN_PYMUNK)
    substeps = max(scene.sim_substeps, coupling_substeps_needed(scene, ISAAC_PHYSICS_HZ))
    world = SimWorld(scene)
    tool = ToolPoint(world)
    world.period, world.substeps = 1.0 / ISAAC_PHYSICS_HZ, substeps
    step_s = world.period / substeps
    device = load_device(case.device)
    scale = world_map_of(device).record[0]["scale"]
    if not np.all(scale == 1.0):
        raise ValueError(
            f"isaac_haply: device {case.device!r} maps with a scale; only 1 is supported"
        )
    user = user_record(load_user(case.user))
    start, _ = tool.state()
    device.reset(np.zeros(3))
    user[0]["start_pose"] = start
    haptic_hz = scene.haptic_rate_hz  # HAPTIC_HZ but in hapticbench's stiffness search
    n = round(case.seconds * haptic_hz)
    ticks = np.zeros(n, TICK_DTYPE)
    dt = 1.0 / haptic_hz
    pose, twist, hand = np.zeros(3), np.zeros(3), np.zeros(3)
    feedback, command = np.zeros(2), np.zeros(3)
    steps, sim_ns, tick_ns = 0, 0, 0
    for i in range(n):
        t = i * dt
        t0 = time.perf_counter_ns()
        device.true_state(pose, twist)
        world_pose = pose + start
        # a physics step when one is due (every fifth tick at 1 kHz): the tool pulled to the
        # device's pose
        if i * ISAAC_PHYSICS_HZ >= steps * haptic_hz:
            q, qd = world.tool_state()
            world.step(ToolTarget(q, qd, world_pose, twist.copy(), True, True))
            steps += 1
            if steps % ISAAC_STEPS_PER_FEEDBACK == 0:
                feedback = tool.contact_force(step_s)
                norm = float(np.hypot(*feedback))
                if norm > HAPLY_LIMIT_FORCE_N:
                    feedback = feedback * (HAPLY_LIMIT_FORCE_N / norm)
        t1 = time.perf_counter_ns()
        command[:2] = feedback
        applied = device.command(command)
        hand_wrench(user, t, world_pose, twist, hand)
        device.sense_hand(hand)
        device.advance(dt, hand)
        row = ticks[i]
        row["t"], row["dt"] = t, dt
        row["device_pose"], row["device_twist"] = world_pose, twist
        row["wrench_command"] = applied
        row["contact_force_world"][:2] = feedback
        t2 = time.perf_counter_ns()
        sim_ns += t1 - t0
        tick_ns += t2 - t1
    cost = 1e3 * (sim_ns + tick_ns) / 1e9 / case.seconds
    return MethodRun(ticks, scene, cost, ISAAC_PHYSICS_HZ, substeps)
