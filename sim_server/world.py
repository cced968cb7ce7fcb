"""The pymunk world of a scene, its virtual tool, and the local model computed from it.

`SimWorld.step(target)` advances the world by one sim period (with substeps), driving the
tool toward the haptic proxy (or, for virtual_coupling_foh, coupling it to the device), and
`SimWorld.local_model_bytes(...)` encodes what DESIGN §3 says the sim publishes: D, G (only
when g != 0), J_h, Lambda^-1, the resisted directions (only for a linkage) and the
neighbourhood contacts of every tool shape. Both are one compiled call each, over pymunk's
C core (sim_server/drive.py, sim_server/local_model.py); this class builds the world and the
records they read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pymunk

from haptic_local_model.shared.config import BodySpec, Material, SceneConfig
from haptic_local_model.shared.kinematics import (
    link_frames,
    mass_matrix_and_gravity,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.shared.protocol.proxy import ShapeImpulses, TrainState
from haptic_local_model.shared.protocol.update import LocalModelUpdate, update_from_record
from haptic_local_model.shared.tool_chain import tool_chain
from haptic_local_model.sim_server.chipmunk import body_ptr, set_velocity_function
from haptic_local_model.sim_server.drive import (
    DRIVE_DEVICE,
    DRIVE_PROXY,
    KINEMATIC_DTYPE,
    table_drag,
)
from haptic_local_model.sim_server.local_model import TOOL_GROUP, StageStats
from haptic_local_model.sim_server.membrane import Membrane
from haptic_local_model.sim_server.shapes import LocalShapes
from haptic_local_model.sim_server.space_model import MAX_UPDATE_BYTES, SpaceLocalModel
from haptic_local_model.sim_server.tool import tool_state
from haptic_local_model.sim_server.tool_drive import ToolDrive
from haptic_local_model.sim_server.train import SimTrain

#: the most haptic time of impulses a step keeps for the next (in steps): enough to even out
#: 4 and 5 proxy states between two steps, while a stall's backlog is let out at once
KEPT_SPAN_STEPS = 0.5
__all__ = ["MAX_UPDATE_BYTES", "SimWorld", "ToolTarget"]


#: pymunk takes a contact's friction (and restitution) as the product of its two shapes';
#: the haptic side renders a tool's contact with the touched material's alone
#: (docs/scenes.md), so the sim's tool shapes take the product's identity for both and its
#: contacts agree with what is felt
TOOL_FRICTION = 1.0


@dataclass
class ToolTarget:
    """Where the haptic side wants the tool: proxy configuration, or the device pose (FOH)."""

    q: np.ndarray
    qd: np.ndarray
    device_pose: np.ndarray
    device_twist: np.ndarray
    coupled_to_device: bool  # virtual_coupling_foh: spring to the device instead of the proxy
    fresh: bool  # False: the haptic side is silent; hold the tool
    # god_object: the impulses on the shapes the proxy touched since the previous step
    impulses: ShapeImpulses = field(default_factory=ShapeImpulses.none)
    # the haptic side's train (a scene with one) and its age when the step begins (s)
    train: TrainState | None = None
    train_age_s: float = 0.0


class SimWorld:
    """A scene built in pymunk, with the held tool as a chain (DESIGN §2)."""

    def __init__(self, scene: SceneConfig) -> None:
        self.scene = scene
        self.space = pymunk.Space()
        self.space.gravity = scene.gravity
        self.space.collision_slop = 1.0e-4  # pymunk's default (0.1) assumes pixel units
        self.time = 0.0
        self.period = 1.0 / scene.sim_rate_hz
        # the god-object's impulses received and not yet applied (_deliver)
        self.pending_impulses = ShapeImpulses.none()
        self.substeps = scene.sim_substeps
        self.shape_materials: dict[pymunk.Shape, Material] = {}
        self.shape_keys: dict[pymunk.Shape, int] = {}  # in the order registered
        self._kinematic: list[tuple[pymunk.Body, BodySpec]] = []
        self.tool_bodies: list[pymunk.Body] = []
        self.tool_shapes: list[tuple[pymunk.Shape, int]] = []  # (shape, link index)
        self.body_names: dict[pymunk.Body, str] = {}  # what the live view calls them
        _configure_space(self.space, scene)
        for spec in scene.all_bodies:
            self._add_body(spec)
        for lk in scene.linkages:
            self._add_linkage(lk.name)
        self.membranes: list[Membrane] = []
        first_key = len(self.shape_keys)
        for string in scene.deformables:
            mat = scene.materials[string.material]
            substep = self.period / self.substeps
            mem = Membrane(self.space, string, mat, first_key, substep)
            mem.every = max(1, round(scene.sim_rate_hz / string.publish_hz))
            self.membranes.append(mem)
            first_key += string.nodes - 1
        # a train's cars or a crank's bodies (kinematic; their keys after the strings')
        mechanism = bool(scene.cars) or scene.crank is not None or scene.avar_tree is not None
        self.train = SimTrain(scene, self.space, self._register_car) if mechanism else None
        self._setup_tool_chain()
        self.space.step(0.0)  # pymunk's checks of the bodies added (a zero step moves nothing)
        tool = {t for t, _ in self.tool_shapes}
        # the local model's builder, the same for a user's own space (sim_server/user_space.py)
        self.model = SpaceLocalModel(
            self.space, self.tool_bodies, self.tool_shapes, self._tool_chain,
            [(s, k, self.shape_materials[s]) for s, k in self.shape_keys.items() if s not in tool],
            scene.tool, scene.rendering,
        )  # fmt: skip
        self.tool = self.model.tool
        train = self.train.record if self.train else None
        self._drive = ToolDrive(_kinematic_records(self._kinematic), train)
        self._local = self.model.kernel
        # a god_object tool is rendered against the shapes near it (DESIGN-WAVE2 C2)
        self.local_shapes = (
            LocalShapes(
                {s: (k, self.shape_materials[s]) for s, k in self.shape_keys.items()},
                [s for s, _ in self.tool_shapes],
                scene.tool.neighbourhood_margin_m,
                self.membranes,
                self.train.owner if self.train else None,
            )
            if scene.rendering.method == "god_object"
            else None
        )
        # the god-object's proxy (x, y, r) from the newest proxy state: the shapes are sent
        # about it (LocalShapes.fill); None while the haptic side is silent
        self._proxy: tuple[float, float, float] | None = None
        self._dynamic_by_key = {  # the bodies a god-object's push is applied to, by shape key
            k: s.body
            for s, k in self.shape_keys.items()
            if s.body is not None and s.body.body_type == pymunk.Body.DYNAMIC and s not in tool
        }

    # --- construction -------------------------------------------------------------------

    def _register(self, shape: pymunk.Shape, material: str) -> None:
        self.shape_materials[shape] = self.scene.materials[material]
        self.shape_keys[shape] = len(self.shape_keys)

    def _register_car(self, shape: pymunk.Shape, material: str) -> None:
        """A car's shape: its key after the strings' segments (which take keys of their own)."""
        self.shape_materials[shape] = self.scene.materials[material]
        strings = sum(s.nodes - 1 for s in self.scene.deformables)
        self.shape_keys[shape] = len(self.shape_keys) + strings

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
            body = pymunk.Body(spec.mass, spec.moment)
            if spec.linear_damping_per_s > 0.0 and not is_tool:
                # table_drag's cache keeps the cfunc alive as long as the process
                set_velocity_function(body, table_drag(spec.linear_damping_per_s).address)
        body.position = spec.position
        body.angle = spec.angle
        if spec.kind != "static":
            body.velocity = spec.velocity
            body.angular_velocity = spec.angular_velocity
        shape = body_shape(body, spec)
        mat = self.scene.materials[spec.material]
        shape.friction = TOOL_FRICTION if is_tool else mat.friction
        shape.elasticity = TOOL_FRICTION if is_tool else mat.restitution
        if is_tool:
            # a god-object's finger only shows where the proxy is: the proxy's forces reach the
            # world through the proxy state (collisions too would count them twice)
            god = self.scene.rendering.method == "god_object"
            mask = 0 if god else pymunk.ShapeFilter.ALL_MASKS()
            shape.filter = pymunk.ShapeFilter(group=TOOL_GROUP, mask=mask)
            self.tool_bodies = [body]
            self.tool_shapes = [(shape, 2)]
        self.body_names.setdefault(body, "static" if body is self.space.static_body else spec.name)
        if body is self.space.static_body:
            self.space.add(shape)
        else:
            self.space.add(body, shape)
        self._register(shape, spec.material)

    def _add_linkage(self, name: str) -> None:
        lk = next(k for k in self.scene.linkages if k.name == name)
        is_tool = self.scene.tool.kind == "linkage" and self.scene.tool.name == name
        ground = self.space.static_body
        mat = self.scene.materials[lk.material]
        bodies: list[pymunk.Body] = []
        tips: list[np.ndarray] = []  # the far end of each link, where its children hang
        first_key = len(self.shape_keys)
        for i, length in enumerate(lk.lengths):
            up = lk.parent_of(i)
            prev = ground if up < 0 else bodies[up]
            pos = np.array(lk.base, dtype=float) if up < 0 else tips[up]
            angle = (lk.base_angle if up < 0 else bodies[up].angle) + lk.initial_angles[i]
            body = pymunk.Body(lk.masses[i], lk.inertias[i])
            body.center_of_gravity = lk.com_offsets[i]
            body.angle = angle  # before the position: see set_tool_state
            body.position = tuple(pos)
            shape = pymunk.Segment(body, (0.0, 0.0), (length, 0.0), lk.radius)
            shape.friction = TOOL_FRICTION if is_tool else mat.friction
            shape.elasticity = TOOL_FRICTION if is_tool else mat.restitution
            # a passive serial linkage's links collide with all but their neighbours; a
            # tree's siblings share their pivot, so a tree's links are one group
            group = 100 + len(self.shape_keys) if not lk.parents else 100 + first_key
            shape.filter = pymunk.ShapeFilter(group=TOOL_GROUP if is_tool else group)
            joint = pymunk.PivotJoint(prev, body, tuple(pos))
            joint.collide_bodies = False
            self.space.add(body, shape, joint)
            self.body_names[body] = f"{name}/{i}"
            self._register(shape, lk.material)
            bodies.append(body)
            if is_tool:
                self.tool_shapes.append((shape, i))
            tips.append(pos + length * np.array([math.cos(angle), math.sin(angle)]))
        if is_tool:
            self.tool_bodies = bodies

    def _setup_tool_chain(self) -> None:
        chain = tool_chain(self.scene)  # the haptic server builds the same (shared/tool_chain.py)
        self._tool_chain = chain
        c = chain.chain[0]
        self.dof = chain.dof
        self.joint_types = c["joint_types"][: self.dof].copy()
        self.lengths = c["lengths"][: self.dof].copy()
        self.base = c["base"].copy()
        self.base_angle = float(c["base_angle"])
        self.masses = c["masses"][: self.dof].copy()
        self.inertias = c["inertias"][: self.dof].copy()
        self.com_offsets = c["com_offsets"][: self.dof].copy()
        self.op_link = chain.op_link
        self.op_point = chain.op_point
        self.gravity = chain.gravity
        self._frame_pos = np.zeros((self.dof, 2))
        self._frame_angle = np.zeros(self.dof)
        self._jac = np.zeros((3, self.dof))
        self._point = np.zeros(2)
        self.chain = chain.chain

    # --- tool state ---------------------------------------------------------------------

    def tool_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The tool's configuration q and velocity qd read back from pymunk (the kernels'
        reader, sim_server/tool.py)."""
        q, qd = np.zeros(self.dof), np.zeros(self.dof)
        tool_state(self.tool, q, qd)
        return q, qd

    def set_tool_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Place the tool at q with velocity qd (used to start it where the proxy is)."""
        if self.scene.tool.kind == "body":
            b = self.tool_bodies[0]
            # the angle first: Chipmunk keeps the centre of gravity where it is when the
            # angle changes, so a position set before it would move the body's origin
            b.angle = q[2]
            b.position = (q[0], q[1])
            b.velocity = (qd[0], qd[1])
            b.angular_velocity = qd[2]
        else:
            c = self.chain[0]
            link_frames(c, q, self.dof, self._frame_pos, self._frame_angle)
            rates = np.zeros(self.dof)
            com = np.zeros(2)
            for i, b in enumerate(self.tool_bodies):
                up = int(c["parents"][i])
                rates[i] = (rates[up] if up >= 0 else 0.0) + qd[i]
                b.angle = self._frame_angle[i]  # first, as above
                b.position = tuple(self._frame_pos[i])
                b.angular_velocity = rates[i]
                # pymunk's body velocity is that of the centre of gravity
                point_on_link(self._frame_pos, self._frame_angle, i, self.com_offsets[i], com)
                point_jacobian(c, self._frame_pos, self.dof, i, com[0], com[1], self._jac)
                b.velocity = tuple(self._jac[:2] @ qd)
        for b in self.tool_bodies:
            self.space.reindex_shapes_for_body(b)

    def dynamics_terms(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """D(q), G(q) and J_h(q) at the operational point."""
        d = self.dof
        mass = np.zeros((d, d))
        grav = np.zeros(d)
        jac = np.zeros((3, d))
        work = (self._frame_pos, self._frame_angle, jac)
        # it leaves the link frames of q in its scratch: J_h is taken from them
        mass_matrix_and_gravity(self.chain, self.gravity, q, work, mass, grav)
        point_on_link(self._frame_pos, self._frame_angle, self.op_link, self.op_point, self._point)
        point_jacobian(
            self.chain[0], self._frame_pos, d, self.op_link, self._point[0], self._point[1], jac
        )
        return mass, grav, jac

    # --- stepping (sim_server/drive.py) ------------------------------------------------

    def step(self, target: ToolTarget | None) -> None:
        """Advance one sim period: drive the tool, move kinematic bodies, substep pymunk (one
        compiled call)."""
        self._drive.target[0]["env_body"] = 0
        self._proxy = None
        if self.local_shapes is not None:  # delivered to the hand: applied, fresh or not
            self._touched(self._deliver(target))
        if self.train is not None and target is not None and target.fresh:
            self.train.follow(target.train, target.train_age_s)
        coupled = target is not None and target.coupled_to_device
        aimed = self._drive.aim(target, DRIVE_DEVICE if coupled else DRIVE_PROXY)
        if aimed and target is not None and self.local_shapes is not None:
            radius = self.scene.tool_body.radius
            self._proxy = (float(target.q[0]), float(target.q[1]), radius)
        self._drive.step(self.tool, self.chain, self.time, self.period, self.substeps)
        self.time += self.period
        for mem in self.membranes:
            mem.stepped()

    def _deliver(self, target: ToolTarget | None) -> ShapeImpulses:
        """This step's share of the impulses received (DESIGN-WAVE2 C4): all of them if they
        cover at most a step of haptic time, else a step's worth, the rest kept for the next
        steps. The force on a shape is then the mean the haptic side rendered, however the
        proxy states fall between steps (4 or 5 of them at 250 Hz and 60 Hz: applying each
        step's whole sum swung a pressed string's force by 0.1 N), and every impulse is
        applied once."""
        pending = self.pending_impulses
        if target is not None:
            pending = pending.merged(target.impulses)
        span, period = pending.span_s, self.period
        keep = min(span - period, KEPT_SPAN_STEPS * period)  # never more: a stall is let out
        if keep <= 0.0 or pending.count == 0:
            self.pending_impulses = ShapeImpulses.none()
            return pending
        share = 1.0 - keep / span
        self.pending_impulses = pending.scaled(1.0 - share, keep)
        return pending.scaled(share, span - keep)

    def _touched(self, imp: ShapeImpulses) -> None:
        """The god-object's impulses on dynamic bodies into the step's target, each as the
        force that delivers it over the step (by shape key; a membrane's segment passes its
        force to its two nodes)."""
        tg = self._drive.target[0]
        slot = 0
        for j in range(imp.count):
            key = int(imp.keys[j])
            force = imp.impulses[j] / self.period
            arm = imp.points[j]  # from the shape's centre
            pushes = []
            body = self._dynamic_by_key.get(key)
            if body is not None:
                centre = body.local_to_world(body.center_of_gravity)
                pushes = [(body, np.array([centre[0] + arm[0], centre[1] + arm[1]]), force)]
            for mem in self.membranes:
                if key in mem.keys:
                    pushes = mem.pushes(key, mem.midpoint(key) + arm, force)
            for body, point, force in pushes:
                tg["env_body"][slot] = body_ptr(body)
                tg["env_point"][slot] = point
                tg["env_force"][slot] = force
                slot += 1

    # --- the local model (sim_server/local_model.py) ------------------------------------

    def local_model_bytes(
        self, epoch: int, seq: int, publish_time_ns: int, state_lead_s: float = 0.0
    ) -> bytes:
        """The encoded local model of DESIGN §3 at the tool's current state (two compiled
        calls: the model, then its stamp and encoding).

        state_lead_s: how long after publication the state holds (the step just computed
        covers the coming period, driven by the extrapolated proxy)."""
        lm = self._local
        self.model.build()
        if self.local_shapes is not None:  # the god-object needs shapes, not contact points
            lm.record[0]["n_contacts"] = 0
            self.local_shapes.fill(self.space, lm.record[0], self._proxy)
        if self.train is not None:
            rec = lm.record[0]
            rec["has_avars"] = 1
            rec["avar_static_id"] = self.train.static_id
            rec["avar_cars"] = self.train.n_cars
            rec["avar_s"], rec["avar_sd"] = self.train.state
        return self.model.encode(epoch, seq, self.time, publish_time_ns, state_lead_s)

    @property
    def kinematic_bodies(self) -> list[tuple[pymunk.Body, BodySpec]]:
        """The kinematic bodies and their specs (the sim moves them)."""
        return list(self._kinematic)

    @property
    def tool_pose(self) -> np.ndarray:
        """The operational point's pose in the last local model built (a copy)."""
        return self._local.record[0]["tool_pose"].copy()

    @property
    def stats(self) -> StageStats:
        """Which optional stages the last local model ran, and what its query found."""
        m, counts = self._local.record[0], self._local.counts
        return StageStats(
            svd=self.scene.tool.kind == "linkage",
            gravity=bool(m["has_gravity"]),
            contacts_sent=int(m["n_contacts"]),
            shapes_queried=int(counts[0]),
            hits_dropped=int(counts[1]),
        )

    def local_model(
        self, epoch: int, seq: int, publish_time_ns: int, state_lead_s: float = 0.0
    ) -> LocalModelUpdate:
        """local_model_bytes as the dataclass (tools and tests)."""
        self.local_model_bytes(epoch, seq, publish_time_ns, state_lead_s)
        return update_from_record(self._local.record[0])


def body_shape(body: pymunk.Body, spec: BodySpec) -> pymunk.Shape:
    """A body table's shape on `body`: a box, a circle or a segment (its material not set)."""
    if spec.shape == "box":
        return pymunk.Poly.create_box(body, spec.size, radius=0.0)
    if spec.shape == "circle":
        return pymunk.Circle(body, spec.radius)
    return pymunk.Segment(body, spec.a, spec.b, spec.radius)


def _configure_space(space: pymunk.Space, scene: SceneConfig) -> None:
    """The scene's broad phase and sleeping ([space]): a spatial hash and sleeping bodies let
    a crowd of a thousand cost what its awake part costs."""
    spec = scene.space
    if spec.spatial_hash_cell_m > 0.0:
        space.use_spatial_hash(spec.spatial_hash_cell_m, spec.spatial_hash_count)
    if spec.sleep_time_s > 0.0:
        space.sleep_time_threshold = spec.sleep_time_s
        if spec.idle_speed_m_per_s > 0.0:
            space.idle_speed_threshold = spec.idle_speed_m_per_s


def warm_kernels(scene: SceneConfig) -> None:
    """Load the compiled step and local model (from numba's cache, or compile them) before a
    run starts: on a spare world, one step and one local model."""
    spare = SimWorld(scene)
    spare.step(None)
    spare.local_model_bytes(0, 0, 0)


def _kinematic_records(kinematic: list[tuple[pymunk.Body, BodySpec]]) -> np.ndarray:
    """The oscillating kinematic bodies, for the compiled step (the others keep the velocity
    they were given)."""
    moving = [
        (b, spec)
        for b, spec in kinematic
        if spec.oscillation_period_s > 0.0 or spec.angle_period_s > 0.0
    ]
    rec = np.zeros(len(moving), KINEMATIC_DTYPE)
    for i, (body, spec) in enumerate(moving):
        rec[i] = (
            body_ptr(body),
            spec.velocity,
            spec.oscillation_amplitude,
            spec.oscillation_period_s,
            spec.angular_velocity,
            spec.angle_amplitude,
            spec.angle_period_s,
        )
    return rec
