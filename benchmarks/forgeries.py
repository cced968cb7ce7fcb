"""Forged local models for the plausibility check and the loop's guard (tests, benchmarks).

Each forgery takes a real update of the scene's sim (its own tool state, so everything else
in it is consistent and plausible) and changes what an attacker with the sim's credentials
would change, as the issue's attacks and the validator's bounds suggest. `EXPECTED` says
what the haptic server must make of each: refused with a reason, or installed and
neutralised by the loop's guard ("guard").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from shared.config import SceneConfig
from shared.protocol.layout import CONTACT_FLOATS
from shared.protocol.update import ContactSet, LocalModelUpdate, contact_rows

Forgery = Callable[[LocalModelUpdate, SceneConfig], LocalModelUpdate]


def _with_contact(u: LocalModelUpdate, depth: float, **columns: float) -> LocalModelUpdate:
    """u with one contact more: at the operational point, `depth` inside a wall whose
    outward normal points along -x of the world (columns override the material)."""
    rows, floats = contact_rows(1)
    link = u.op_link
    rows[0]["tool"] = u.op_point
    x, y = u.tool_pose[0], u.tool_pose[1]
    rows[0]["env"] = (x - depth, y)  # the wall's surface: the tool point is depth beyond it
    rows[0]["normal"] = (-1.0, 0.0)
    rows[0]["friction"] = columns.get("friction", 0.0)
    rows[0]["restitution"] = 0.0
    rows[0]["stiffness"] = columns.get("stiffness", 15000.0)
    rows[0]["damping"] = columns.get("damping", 0.0)
    rows[0]["tangential_stiffness"] = columns.get("stiffness", 15000.0)
    rows[0]["env_velocity"] = (columns.get("env_speed", 0.0), 0.0)
    old = u.contacts
    contacts = ContactSet(
        np.concatenate([old.link, [link]]).astype(np.int64),
        np.concatenate([old.key, [10**6]]).astype(np.int64),
        np.concatenate([old.floats.reshape(-1, CONTACT_FLOATS), floats]),
    )
    return dataclasses.replace(u, contacts=contacts, tool_touching=True)


def stiff_contact(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: a contact of stiffness 1e8 N/m with mu = 10, 1 mm deep."""
    return _with_contact(u, 1e-3, stiffness=1e8, friction=10.0)


def tiny_mass(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: D = 1e-6 I (with the Lambda^-1 it implies, to look consistent)."""
    d = u.dof
    return dataclasses.replace(u, mass_matrix=1e-6 * np.eye(d), lambda_inv=u.lambda_inv * 1e6)


def fast_joints(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: joint velocities of 100 rad/s."""
    return dataclasses.replace(u, qd=np.full(u.dof, 100.0))


def heavy_gravity(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: gravity torques of 1e4."""
    return dataclasses.replace(u, gravity=np.full(u.dof, 1e4))


def flipped_lambda(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: a Lambda^-1 of the opposite sign to J D^-1 J^T."""
    return dataclasses.replace(u, lambda_inv=-u.lambda_inv)


def deep_contact(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """At the envelope's edge: a contact of the scene's stiffest material, 95 % of
    max_penetration_m deep. Plausible, so installed: the guard must stop what it does."""
    stiffest = max(m.stiffness_n_per_m for m in scene.materials.values())
    return _with_contact(u, 0.95 * scene.safety.max_penetration_m, stiffness=stiffest)


def fast_wall(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """A wall point moving at 50 m/s."""
    return _with_contact(u, 0.0, env_speed=50.0)


def teleport(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The tool moved far since the last update (the first joint turned by 2.5 rad, or a
    free body 0.3 m along x), every field as the sim computes it there."""
    from sim_server.world import SimWorld

    world = SimWorld(scene)
    q = u.q.copy()
    q[0] += 2.5 if scene.tool.kind == "linkage" else 0.3
    world.set_tool_state(q, u.qd)
    world.time = u.sim_time
    moved = world.local_model(u.epoch, u.seq, u.publish_time_ns, u.state_lead_s)
    return dataclasses.replace(moved, contacts=ContactSet.empty(), tool_touching=False)


def other_tool(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """A longer first link than the scene's."""
    lengths = u.lengths.copy()
    lengths[0] += 0.05 if scene.tool.kind == "linkage" else 0.0
    base = u.base + (0.0 if scene.tool.kind == "linkage" else 0.05)
    return dataclasses.replace(u, lengths=lengths, base=base)


def seq_ahead(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """A sequence number 1000 ahead (it would lock the sim's own updates out)."""
    return dataclasses.replace(u, seq=u.seq + 1000)


def forged_velocity_torque(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """C(q, qd) qd of 100 N m on every joint (a linkage's)."""
    return dataclasses.replace(u, velocity_torque=np.full(u.dof, 100.0))


def resisted_everywhere(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """Every direction resisted, away from any singularity (a linkage's)."""
    return dataclasses.replace(u, resisted=np.eye(3))


FORGERIES: dict[str, Forgery] = {
    "stiff_contact": stiff_contact,
    "tiny_mass": tiny_mass,
    "fast_joints": fast_joints,
    "heavy_gravity": heavy_gravity,
    "flipped_lambda": flipped_lambda,
    "deep_contact": deep_contact,
    "fast_wall": fast_wall,
    "teleport": teleport,
    "other_tool": other_tool,
    "seq_ahead": seq_ahead,
    "forged_velocity_torque": forged_velocity_torque,
    "resisted_everywhere": resisted_everywhere,
}

#: what the haptic server makes of each (a linkage scene's; "guard": installed, neutralised)
EXPECTED = {
    "stiff_contact": "implausible",
    "tiny_mass": "inconsistent",
    "fast_joints": "implausible",
    "heavy_gravity": "inconsistent",
    "flipped_lambda": "inconsistent",
    "deep_contact": "guard",
    "fast_wall": "implausible",
    "teleport": "jump",
    "other_tool": "inconsistent",
    "seq_ahead": "jump",
    "forged_velocity_torque": "inconsistent",
    "resisted_everywhere": "inconsistent",
}
