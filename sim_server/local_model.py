"""The local model the sim publishes each step (DESIGN §3; seed 000 §VII, seed 001 §3): D, G,
C q̇, J_h and Λ⁻¹ at the tool's configuration, the directions its joints resist (SVD of the
scaled J_h), and the neighbourhood's contacts, whose columns are filled by name
(shared.protocol.layout.CONTACT_COLUMNS)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pymunk

from shared.kinematics import velocity_product_torque
from shared.protocol.layout import MAX_CONTACTS
from shared.protocol.update import ContactSet, LocalModelUpdate, contact_rows

if TYPE_CHECKING:  # annotations only: world.py imports this module
    from sim_server.world import SimWorld

VELOCITY_TORQUE_STEP = 1.0e-6  # rad, central differences of D(q) for C(q, qd) qd
TOUCH_TOLERANCE_M = 1.0e-4  # gap below which the tool counts as touching (FOH force gate)
TOOL_GROUP = 1  # pymunk shape-filter group: tool shapes never collide with each other


@dataclass
class StageStats:
    """Which optional stages the last local-model computation ran (leave out what is not needed)."""

    svd: bool = False
    gravity: bool = False
    contacts_sent: int = 0
    shapes_queried: int = 0


def build_local_model(
    world: SimWorld, epoch: int, seq: int, publish_time_ns: int, state_lead_s: float = 0.0
) -> LocalModelUpdate:
    """The local model of DESIGN §3 at the tool's current configuration.

    state_lead_s: how long after publication the state holds (the step just computed
    covers the coming period, driven by the extrapolated proxy).
    """
    q, qd = world.tool_state()
    mass, grav, jac = world.dynamics_terms(q)
    has_gravity = bool(np.any(world.gravity != 0.0))
    mass_inv_jt = np.linalg.solve(mass, jac.T)
    lambda_inv = jac @ mass_inv_jt
    tool = world.scene.tool
    resisted = None
    world.stats = StageStats(gravity=has_gravity)
    if tool.kind == "linkage":  # a free body's J_h is always full rank: no SVD needed
        world.stats.svd = True
        resisted = resisted_directions(jac, tool.characteristic_length_m, tool.rank_tolerance)
    velocity_torque = None
    if tool.kind == "linkage":  # a free body's D is constant: no velocity-product terms
        velocity_torque = np.zeros(world.dof)
        velocity_product_torque(world.chain, q, qd, VELOCITY_TORQUE_STEP, velocity_torque)
    contacts, touching = neighbourhood_contacts(world)
    world.stats.contacts_sent = contacts.count
    return LocalModelUpdate(
        epoch=epoch, seq=seq, sim_time=world.time, publish_time_ns=publish_time_ns,
        joint_types=world.joint_types, lengths=world.lengths, base=world.base,
        base_angle=world.base_angle, op_link=world.op_link, op_point=world.op_point, q=q, qd=qd,
        mass_matrix=mass, lambda_inv=lambda_inv, tool_pose=world.operational_pose(q),
        gravity=grav if has_gravity else None, velocity_torque=velocity_torque,
        resisted=resisted if resisted is not None and len(resisted) else None,
        characteristic_length=tool.characteristic_length_m, contacts=contacts,
        tool_touching=touching, state_lead_s=state_lead_s,
    )  # fmt: skip


def neighbourhood_contacts(world: SimWorld) -> tuple[ContactSet, bool]:
    """Contacts of every tool shape with world shapes within the neighbourhood margin.

    Each tool shape is inflated by the margin and passed to `space.shape_query`; pymunk
    returns the closest features, from which the tool point (link frame), the world
    point, the outward normal and the world point's velocity are read (DESIGN §3).
    """
    margin = world.scene.tool.neighbourhood_margin_m
    rows: list[tuple[float, int, int, dict[str, Any]]] = []
    tool_set = {s for s, _ in world.tool_shapes}
    if world._queries is None:  # inflated copies ride on the tool's own bodies: make once
        world._queries = [_inflated(shape, margin) for shape, _ in world.tool_shapes]
    for index, (shape, link) in enumerate(world.tool_shapes):
        query = world._queries[index]
        world.stats.shapes_queried += 1
        for info in world.space.shape_query(query):
            env = info.shape
            if env is None or env in tool_set:
                continue
            cps = info.contact_point_set
            normal_out = -np.array([cps.normal.x, cps.normal.y])  # from the world to the tool
            n_norm = float(np.hypot(*normal_out))
            if n_norm < 0.5:
                continue
            normal_out /= n_norm
            mat = world._shape_material[env]
            # a material's stiffness and damping belong to the shape pair: the points of
            # one contact manifold share them, so a face on a wall is as stiff as a corner
            share = 1.0 / max(1, len(cps.points))
            for pt in cps.points:
                tool_world = np.array([pt.point_a.x, pt.point_a.y]) + margin * normal_out
                env_world = np.array([pt.point_b.x, pt.point_b.y])
                gap = float(normal_out @ (tool_world - env_world))
                if gap > margin:
                    continue
                assert shape.body is not None and env.body is not None
                local_pt = shape.body.world_to_local(tuple(tool_world))
                vel = (0.0, 0.0)
                if env.body.body_type != pymunk.Body.STATIC:
                    vel = env.body.velocity_at_world_point(tuple(env_world))
                rows.append(
                    (
                        gap,
                        link,
                        world._shape_key[env] * 1024 + index,
                        {  # contact columns by name (shared.protocol.layout)
                            "tool": local_pt, "env": env_world, "normal": normal_out,
                            "env_velocity": vel, "friction": mat.friction,
                            "restitution": mat.restitution,
                            "stiffness": share * mat.stiffness_n_per_m,
                            "damping": share * mat.damping_ns_per_m,
                            "tangential_stiffness": share * mat.tangential_stiffness,
                        },
                    )
                )  # fmt: skip
    rows.sort(key=lambda r: r[0])
    rows = rows[:MAX_CONTACTS]
    touching = bool(rows) and rows[0][0] <= TOUCH_TOLERANCE_M
    if not rows:
        return ContactSet.empty(), False
    table, floats = contact_rows(len(rows))
    for i, (_, _, _, columns) in enumerate(rows):
        for name, value in columns.items():
            table[name][i] = value
    return (
        ContactSet(
            link=np.array([r[1] for r in rows], dtype=np.int64),
            key=np.array([r[2] for r in rows], dtype=np.int64),
            floats=floats,
        ),
        touching,
    )


def resisted_directions(jac: np.ndarray, length: float, tolerance: float) -> np.ndarray:
    """Unit directions (scaled space) spanning N(J_h^T): columns of U whose singular value of
    diag(1, 1, length) J_h is below tolerance * the largest (DESIGN §3; seed 000 eq 14, 22)."""
    scaled = jac.copy()
    scaled[2, :] *= length
    u, sigma, _ = np.linalg.svd(scaled, full_matrices=True)
    s_full = np.zeros(3)
    s_full[: len(sigma)] = sigma
    top = s_full.max()
    if top <= 0.0:
        return np.eye(3)
    return u[:, s_full < tolerance * top].T.copy()


def _inflated(shape: pymunk.Shape, margin: float) -> pymunk.Shape:
    """A copy of a tool shape grown by `margin`, on the same body, for neighbourhood queries."""
    q: pymunk.Shape
    if isinstance(shape, pymunk.Poly):
        q = pymunk.Poly(shape.body, shape.get_vertices(), radius=shape.radius + margin)
    elif isinstance(shape, pymunk.Segment):
        q = pymunk.Segment(shape.body, shape.a, shape.b, shape.radius + margin)
    else:
        assert isinstance(shape, pymunk.Circle)
        q = pymunk.Circle(shape.body, shape.radius + margin, shape.offset)
    q.filter = pymunk.ShapeFilter(group=TOOL_GROUP)
    return q
