"""The pymunk world of a scene, its virtual tool, and the local model computed from it.

`SimWorld.step(target)` advances the world by one sim period (with substeps), driving the
tool toward the haptic proxy (or, for virtual_coupling_foh, coupling it to the device), and
`SimWorld.local_model(...)` computes what DESIGN §3 says the sim publishes: D, G (only when
g != 0), J_h, Lambda^-1, the resisted directions by SVD (only for a linkage) and the
neighbourhood contacts of every tool shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pymunk

from shared.config import BodySpec, Material, SceneConfig
from shared.kinematics import (
    MAX_DOF,
    chain_record,
    free_body_chain,
    link_frames,
    mass_matrix_and_gravity,
    point_jacobian,
    point_on_link,
)
from shared.protocol.update import ContactSet, LocalModelUpdate
from sim_server.local_model import (
    TOOL_GROUP,
    StageStats,
    build_local_model,
    neighbourhood_contacts,
)


@dataclass
class ToolTarget:
    """Where the haptic side wants the tool: proxy configuration, or the device pose (FOH)."""

    q: np.ndarray
    qd: np.ndarray
    device_pose: np.ndarray
    device_twist: np.ndarray
    coupled_to_device: bool  # virtual_coupling_foh: spring to the device instead of the proxy
    fresh: bool  # False: the haptic side is silent; hold the tool


class SimWorld:
    """A scene built in pymunk, with the held tool as a chain (DESIGN §2)."""

    def __init__(self, scene: SceneConfig) -> None:
        self.scene = scene
        self.space = pymunk.Space()
        self.space.gravity = scene.gravity
        self.space.collision_slop = 1.0e-4  # pymunk's default (0.1) assumes pixel units
        self.time = 0.0
        self.period = 1.0 / scene.sim_rate_hz
        self.substeps = scene.sim_substeps
        self._shape_material: dict[pymunk.Shape, Material] = {}
        self._shape_key: dict[pymunk.Shape, int] = {}
        self._kinematic: list[tuple[pymunk.Body, BodySpec]] = []
        self.tool_bodies: list[pymunk.Body] = []
        self.tool_shapes: list[tuple[pymunk.Shape, int]] = []  # (shape, link index)
        for spec in scene.bodies:
            self._add_body(spec)
        for lk in scene.linkages:
            self._add_linkage(lk.name)
        self._setup_tool_chain()
        self._queries: list[pymunk.Shape] | None = None
        self.stats = StageStats()

    # --- construction -------------------------------------------------------------------

    def _register(self, shape: pymunk.Shape, material: str) -> None:
        self._shape_material[shape] = self.scene.materials[material]
        self._shape_key[shape] = len(self._shape_key)

    def _add_body(self, spec: BodySpec) -> None:
        is_tool = self.scene.tool.kind == "body" and self.scene.tool.name == spec.name
        if spec.kind == "static":
            body = (
                self.space.static_body
                if spec.position == (0.0, 0.0) and spec.angle == 0.0
                else pymunk.Body(body_type=pymunk.Body.STATIC)
            )
        elif spec.kind == "kinematic":
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            self._kinematic.append((body, spec))
        else:
            body = pymunk.Body(spec.mass, _moment(spec))
            if spec.linear_damping_per_s > 0.0 and not is_tool:
                body.velocity_func = _table_drag(spec.linear_damping_per_s)
        body.position = spec.position
        body.angle = spec.angle
        if spec.kind != "static":
            body.velocity = spec.velocity
            body.angular_velocity = spec.angular_velocity
        shape: pymunk.Shape
        if spec.shape == "box":
            shape = pymunk.Poly.create_box(body, spec.size, radius=0.0)
        elif spec.shape == "circle":
            shape = pymunk.Circle(body, spec.radius)
        else:
            shape = pymunk.Segment(body, spec.a, spec.b, spec.radius)
        mat = self.scene.materials[spec.material]
        shape.friction = mat.friction
        shape.elasticity = mat.restitution
        if is_tool:
            shape.filter = pymunk.ShapeFilter(group=TOOL_GROUP)
            self.tool_bodies = [body]
            self.tool_shapes = [(shape, 2)]
        if body is self.space.static_body:
            self.space.add(shape)
        else:
            self.space.add(body, shape)
        self._register(shape, spec.material)

    def _add_linkage(self, name: str) -> None:
        lk = next(k for k in self.scene.linkages if k.name == name)
        is_tool = self.scene.tool.kind == "linkage" and self.scene.tool.name == name
        ground = self.space.static_body
        prev: pymunk.Body = ground
        angle = lk.base_angle
        pos = np.array(lk.base, dtype=float)
        mat = self.scene.materials[lk.material]
        bodies = []
        for i, length in enumerate(lk.lengths):
            angle += lk.initial_angles[i]
            body = pymunk.Body(lk.masses[i], lk.inertias[i])
            body.center_of_gravity = lk.com_offsets[i]
            body.position = tuple(pos)
            body.angle = angle
            shape = pymunk.Segment(body, (0.0, 0.0), (length, 0.0), lk.radius)
            shape.friction = mat.friction
            shape.elasticity = mat.restitution
            shape.filter = pymunk.ShapeFilter(
                group=TOOL_GROUP if is_tool else 100 + len(self._shape_key)
            )
            joint = pymunk.PivotJoint(prev, body, tuple(pos))
            joint.collide_bodies = False
            self.space.add(body, shape, joint)
            self._register(shape, lk.material)
            bodies.append(body)
            if is_tool:
                self.tool_shapes.append((shape, i))
            pos = pos + length * np.array([math.cos(angle), math.sin(angle)])
            prev = body
        if is_tool:
            self.tool_bodies = bodies

    def _setup_tool_chain(self) -> None:
        tool = self.scene.tool
        if tool.kind == "body":
            spec = self.scene.tool_body
            self.joint_types, self.lengths = free_body_chain()
            self.base = np.zeros(2)
            self.base_angle = 0.0
            self.masses = np.array([0.0, 0.0, spec.mass])
            self.inertias = np.array([0.0, 0.0, _moment(spec)])
            self.com_offsets = np.zeros((3, 2))
            self.op_link = 2
        else:
            lk = self.scene.tool_linkage
            n = len(lk.lengths)
            self.joint_types = np.zeros(n, dtype=np.int64)
            self.lengths = np.array(lk.lengths, dtype=float)
            self.base = np.array(lk.base, dtype=float)
            self.base_angle = lk.base_angle
            self.masses = np.array(lk.masses, dtype=float)
            self.inertias = np.array(lk.inertias, dtype=float)
            self.com_offsets = np.array(lk.com_offsets, dtype=float)
            self.op_link = tool.link
        self.dof = len(self.joint_types)
        if self.dof > MAX_DOF:
            raise ValueError(f"tool has {self.dof} DOF; at most {MAX_DOF} supported")
        self.op_point = np.array(tool.point, dtype=float)
        self.gravity = np.array(self.scene.gravity, dtype=float)
        self._frame_pos = np.zeros((self.dof, 2))
        self._frame_angle = np.zeros(self.dof)
        self._jac = np.zeros((3, self.dof))
        self._point = np.zeros(2)
        self.chain = chain_record(
            self.joint_types, self.lengths, self.base, self.base_angle, self.masses,
            self.inertias, self.com_offsets,
        )  # fmt: skip

    # --- tool state ---------------------------------------------------------------------

    def tool_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The tool's configuration q and velocity qd read back from pymunk."""
        if self.scene.tool.kind == "body":
            b = self.tool_bodies[0]
            q = np.array([b.position.x, b.position.y, b.angle])
            qd = np.array([b.velocity.x, b.velocity.y, b.angular_velocity])
            return q, qd
        angles = np.array([b.angle for b in self.tool_bodies])
        rates = np.array([b.angular_velocity for b in self.tool_bodies])
        q = np.diff(np.concatenate([[self.base_angle], angles]))
        qd = np.diff(np.concatenate([[0.0], rates]))
        return q, qd

    def set_tool_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Place the tool at q with velocity qd (used to start it where the proxy is)."""
        if self.scene.tool.kind == "body":
            b = self.tool_bodies[0]
            b.position = (q[0], q[1])
            b.angle = q[2]
            b.velocity = (qd[0], qd[1])
            b.angular_velocity = qd[2]
        else:
            link_frames(
                self.joint_types,
                self.lengths,
                self.base,
                self.base_angle,
                q,
                self.dof,
                self._frame_pos,
                self._frame_angle,
            )
            rate = 0.0
            com = np.zeros(2)
            for i, b in enumerate(self.tool_bodies):
                rate += qd[i]
                b.position = tuple(self._frame_pos[i])
                b.angle = self._frame_angle[i]
                b.angular_velocity = rate
                # pymunk's body velocity is that of the centre of gravity
                point_on_link(self._frame_pos, self._frame_angle, i, self.com_offsets[i], com)
                point_jacobian(
                    self.joint_types, self._frame_pos, self.dof, i, com[0], com[1], self._jac
                )
                b.velocity = tuple(self._jac[:2] @ qd)
        for b in self.tool_bodies:
            self.space.reindex_shapes_for_body(b)

    def operational_pose(self, q: np.ndarray) -> np.ndarray:
        link_frames(
            self.joint_types,
            self.lengths,
            self.base,
            self.base_angle,
            q,
            self.dof,
            self._frame_pos,
            self._frame_angle,
        )
        point_on_link(self._frame_pos, self._frame_angle, self.op_link, self.op_point, self._point)
        return np.array([self._point[0], self._point[1], self._frame_angle[self.op_link]])

    def dynamics_terms(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """D(q), G(q) and J_h(q) at the operational point."""
        d = self.dof
        mass = np.zeros((d, d))
        grav = np.zeros(d)
        jac = np.zeros((3, d))
        work = (self._frame_pos, self._frame_angle, jac)
        mass_matrix_and_gravity(self.chain, self.gravity, q, work, mass, grav)
        link_frames(
            self.joint_types,
            self.lengths,
            self.base,
            self.base_angle,
            q,
            d,
            self._frame_pos,
            self._frame_angle,
        )
        point_on_link(self._frame_pos, self._frame_angle, self.op_link, self.op_point, self._point)
        point_jacobian(
            self.joint_types, self._frame_pos, d, self.op_link, self._point[0], self._point[1], jac
        )
        return mass, grav, jac

    # --- stepping -----------------------------------------------------------------------

    def step(self, target: ToolTarget | None) -> None:
        """Advance one sim period: drive the tool, move kinematic bodies, substep pymunk."""
        h = self.period / self.substeps
        q, _ = self.tool_state()
        self._drive_mass, self._drive_gravity, _ = self.dynamics_terms(q)  # frozen for the period
        for k in range(self.substeps):
            t = self.time + k * h
            for body, spec in self._kinematic:
                self._move_kinematic(body, spec, t + h)
            self._drive_tool(target, k * h)
            self.space.step(h)
        self.time += self.period

    def _move_kinematic(self, body: pymunk.Body, spec: BodySpec, t: float) -> None:
        if spec.oscillation_period_s > 0.0:
            w = 2.0 * math.pi / spec.oscillation_period_s
            body.velocity = (
                spec.velocity[0] + spec.oscillation_amplitude[0] * w * math.cos(w * t),
                spec.velocity[1] + spec.oscillation_amplitude[1] * w * math.cos(w * t),
            )

    def _drive_tool(self, target: ToolTarget | None, t_ahead: float) -> None:
        """Computed-torque tracking of the proxy (seed 001 Fig. 1): the tool follows it with
        bandwidth tracking_bandwidth_hz and pushes the world with the forces pymunk resolves."""
        coupled = target is not None and target.fresh and target.coupled_to_device
        if self.scene.tool.kind == "body":
            if coupled:
                assert target is not None
                self._couple_body(target, t_ahead)
            else:
                self._drive_body(target, t_ahead)
            return
        q, qd = self.tool_state()
        mass, grav = self._drive_mass, self._drive_gravity
        w = 2.0 * math.pi * self.scene.tool.tracking_bandwidth_hz
        if target is None or not target.fresh:
            acc = -2.0 * w * qd  # nobody drives it: damp the tool to rest
            tau = mass @ acc
        elif target.coupled_to_device:
            tau = self._device_coupling(target, q, qd, t_ahead)
        else:
            q_goal = target.q + target.qd * t_ahead
            acc = w * w * (q_goal - q) + 2.0 * w * (target.qd - qd)
            tau = mass @ acc
        # pymunk applies gravity itself (-G in generalized form): add G so the drive has no
        # steady error.
        self._apply_generalized(tau + grav)

    def _drive_body(self, target: ToolTarget | None, t_ahead: float) -> None:
        """_drive_tool for a free body (D = diag(m, m, I), no gravity term), in plain floats:
        this runs every substep, and numpy on three numbers costs more than the physics."""
        b = self.tool_bodies[0]
        w = 2.0 * math.pi * self.scene.tool.tracking_bandwidth_hz
        px, py = b.position
        vx, vy = b.velocity
        th, om = b.angle, b.angular_velocity
        if target is None or not target.fresh:
            ax, ay, al = -2.0 * w * vx, -2.0 * w * vy, -2.0 * w * om
        else:
            gq, gv = target.q, target.qd
            ax = w * w * (gq[0] + gv[0] * t_ahead - px) + 2.0 * w * (gv[0] - vx)
            ay = w * w * (gq[1] + gv[1] * t_ahead - py) + 2.0 * w * (gv[1] - vy)
            al = w * w * (gq[2] + gv[2] * t_ahead - th) + 2.0 * w * (gv[2] - om)
        m = b.mass
        fx, fy = m * ax - m * self.scene.gravity[0], m * ay - m * self.scene.gravity[1]
        b.apply_force_at_world_point((fx, fy), b.local_to_world(b.center_of_gravity))
        b.torque += b.moment * al

    def _device_coupling(
        self, target: ToolTarget, q: np.ndarray, qd: np.ndarray, t_ahead: float
    ) -> np.ndarray:
        """virtual_coupling_foh (seed 002 §4): K_spring (x_dev - x_tool) - K_damp v_tool, the
        device pose extrapolated by its twist over the period (as the proxy is)."""
        r = self.scene.rendering
        _, _, jac = self.dynamics_terms(q)
        x_tool = self.operational_pose(q)
        v_tool = jac @ qd
        x_dev = target.device_pose + target.device_twist * t_ahead
        stiffness = np.array(r.foh_spring_stiffness)
        f = stiffness * (x_dev - x_tool) - np.array(r.foh_spring_damping) * v_tool
        return jac.T @ f

    def _couple_body(self, target: ToolTarget, t_ahead: float) -> None:
        """_device_coupling for a free body, in plain floats (it runs every substep, and the
        stiff coupling needs many: shared/coupling.py). The spring acts at the operational
        point r (body frame; the body's centre of mass is its origin); pymunk's gravity on the
        tool is cancelled, as the proxy drive does."""
        b = self.tool_bodies[0]
        r = self.scene.rendering
        k = r.foh_spring_stiffness
        c = r.foh_spring_damping
        dp, dv = target.device_pose, target.device_twist
        x, y = b.position
        vx, vy = b.velocity
        th, om = b.angle, b.angular_velocity
        cos_t, sin_t = math.cos(th), math.sin(th)
        rx = cos_t * self.op_point[0] - sin_t * self.op_point[1]
        ry = sin_t * self.op_point[0] + cos_t * self.op_point[1]
        fx = k[0] * (dp[0] + dv[0] * t_ahead - x - rx) - c[0] * (vx - om * ry)
        fy = k[1] * (dp[1] + dv[1] * t_ahead - y - ry) - c[1] * (vy + om * rx)
        tau = k[2] * (dp[2] + dv[2] * t_ahead - th) - c[2] * om
        g = self.scene.gravity
        m = b.mass
        b.apply_force_at_world_point((fx - m * g[0], fy - m * g[1]), (x, y))
        b.torque += tau + rx * fy - ry * fx

    def _apply_generalized(self, tau: np.ndarray) -> None:
        """Apply configuration-space forces to the pymunk tool bodies."""
        if self.scene.tool.kind == "body":
            b = self.tool_bodies[0]
            b.apply_force_at_world_point(
                (float(tau[0]), float(tau[1])), b.local_to_world(b.center_of_gravity)
            )
            b.torque += float(tau[2])
            return
        for i, b in enumerate(self.tool_bodies):  # joint torque: +tau on link i, -tau on link i-1
            b.torque += float(tau[i])
            if i > 0:
                self.tool_bodies[i - 1].torque -= float(tau[i])

    # --- local model (sim_server/local_model.py) ---------------------------------------

    def local_model(
        self, epoch: int, seq: int, publish_time_ns: int, state_lead_s: float = 0.0
    ) -> LocalModelUpdate:
        """The local model of DESIGN §3 at the tool's current configuration."""
        return build_local_model(self, epoch, seq, publish_time_ns, state_lead_s)

    def neighbourhood_contacts(self) -> tuple[ContactSet, bool]:
        """Contacts of every tool shape with world shapes within the neighbourhood margin."""
        return neighbourhood_contacts(self)


def _table_drag(rate_per_s: float) -> Any:
    """A pymunk velocity function adding exponential drag: a block sliding on a table."""

    def update(body: pymunk.Body, gravity: Any, damping: float, dt: float) -> None:
        pymunk.Body.update_velocity(body, gravity, damping * math.exp(-rate_per_s * dt), dt)

    return update


def _moment(spec: BodySpec) -> float:
    if spec.shape == "box":
        return float(pymunk.moment_for_box(spec.mass, spec.size))
    if spec.shape == "circle":
        return float(pymunk.moment_for_circle(spec.mass, 0.0, spec.radius))
    return float(pymunk.moment_for_segment(spec.mass, spec.a, spec.b, spec.radius))
