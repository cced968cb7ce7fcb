"""A scene's mechanism driven by one animation variable, whichever it is (DESIGN-WAVE2 §5):
a train of cars on a track (shared/avar.py), a slider-crank (shared/crank.py) or a geared
tree linkage (shared/avar_tree.py).

The haptic stage (haptic_server/stages/train.py) and the sim (sim_server/train.py) see only
this: the mechanism's bodies by index, each body's pose at q (the frame its shapes are
given in), the velocity of a point carried by a body per unit q' (to turn a force there into
the generalised force Q = F . J_c), one step under a held Q, M_q and the energy. Kernels
branch on `kind`; the records of the kinds not in use are zeros.
"""

from __future__ import annotations

import enum
import math

import numpy as np
from numba import njit

from haptic_local_model.shared.avar import (
    TRAIN_DTYPE,
    contact_jacobian,
    train_energy,
    train_mass,
    train_record,
    train_step,
)
from haptic_local_model.shared.avar_tree import (
    TREE_DTYPE,
    tree_body_pose,
    tree_energy,
    tree_mass,
    tree_point_rate,
    tree_record,
    tree_step,
)
from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.crank import (
    CRANK_DTYPE,
    CrankDriver,
    crank_body_pose,
    crank_body_rates,
    crank_energy,
    crank_mass,
    crank_record,
    crank_step,
)
from haptic_local_model.shared.track import TRACK_DTYPE, tabulate, track_point

MAX_BODIES = 8  # a mechanism's bodies: a train's cars, a geared tree's links (the wire's
# bound, shared/protocol/update.py MAX_TRAIN_CARS); a crank has 3


class MechanismKind(enum.IntEnum):
    NONE = 0
    TRAIN = 1
    CRANK = 2
    TREE = 3


MECHANISM_DTYPE = np.dtype(
    [
        ("kind", np.int64),  # MechanismKind
        ("track", TRACK_DTYPE),  # a train's
        ("train", TRAIN_DTYPE),
        ("crank", CRANK_DTYPE),  # a slider-crank's
        ("tree", TREE_DTYPE),  # a geared tree linkage's
    ]
)


def mechanism_record(scene: SceneConfig) -> np.ndarray:
    """MECHANISM_DTYPE[1] of a scene (kind NONE without one)."""
    rec = np.zeros(1, MECHANISM_DTYPE)
    r = rec[0]
    if scene.cars:
        cars = scene.cars[0]
        r["kind"] = MechanismKind.TRAIN
        r["track"] = tabulate(scene.track_spec)[0]
        r["train"] = train_record(
            cars.count, cars.spacing_m, cars.mass, cars.inertia, scene.gravity, cars.restitution
        )[0]
    elif scene.crank is not None:
        c = scene.crank
        r["kind"] = MechanismKind.CRANK
        r["crank"] = crank_record(
            c.crank_length, c.rod_length, c.crank_mass, c.rod_mass, c.slider_mass,
            scene.gravity, CrankDriver[c.driver.upper()], c.pivot,
        )[0]  # fmt: skip
    elif scene.avar_tree is not None:
        r["kind"] = MechanismKind.TREE
        r["tree"] = tree_of(scene)[0]
    return rec


def tree_of(scene: SceneConfig) -> np.ndarray:
    """The scene's geared tree as TREE_DTYPE[1], with the scene's gravity."""
    a = scene.avar_tree
    assert a is not None
    rec = tree_record(
        a.base, a.lengths, a.masses, a.inertias, a.com_offsets, a.parents, a.gears, a.offsets
    )
    rec[0]["gravity"] = scene.gravity
    return rec


def initial_state(scene: SceneConfig) -> tuple[float, float]:
    """(q, q') the scene's mechanism starts at."""
    if scene.cars:
        return scene.cars[0].initial_s, scene.cars[0].initial_speed
    if scene.crank is not None:
        c = scene.crank
        q = c.initial_q % (2.0 * math.pi) if c.driver == "crank_angle" else c.initial_q
        return q, c.initial_rate
    if scene.avar_tree is not None:
        return scene.avar_tree.initial_q % (2.0 * math.pi), scene.avar_tree.initial_rate
    return 0.0, 0.0


@njit(cache=True)
def body_count(mc):
    if mc.kind == MechanismKind.TRAIN:
        return mc.train.n_cars
    if mc.kind == MechanismKind.CRANK:
        return 3
    if mc.kind == MechanismKind.TREE:
        return mc.tree.chain.dof
    return 0


@njit(cache=True)
def body_pose(mc, q, k):
    """Body k's pose (x, y, angle) at q."""
    if mc.kind == MechanismKind.TRAIN:
        x, y, psi, _, _ = track_point(mc.track, q - k * mc.train.spacing)
        return x, y, psi
    if mc.kind == MechanismKind.TREE:
        return tree_body_pose(mc.tree, q, k)
    return crank_body_pose(mc.crank, q, k)


@njit(cache=True)
def point_rate(mc, q, k, px, py):
    """The velocity of the world point (px, py) carried by body k, per unit q'."""
    if mc.kind == MechanismKind.TRAIN:
        return contact_jacobian(mc.track, mc.train, q, k, px, py)
    if mc.kind == MechanismKind.TREE:
        return tree_point_rate(mc.tree, q, k, px, py)
    x, y, _ = crank_body_pose(mc.crank, q, k)
    vx, vy, w = crank_body_rates(mc.crank, q, k)
    return vx - w * (py - y), vy + w * (px - x)


@njit(cache=True)
def step(mc, st, q_ext, dt):
    """One step of dt under the generalised force q_ext (N or N m) held."""
    if mc.kind == MechanismKind.TRAIN:
        train_step(mc.track, mc.train, st, q_ext, dt)
    elif mc.kind == MechanismKind.CRANK:
        crank_step(mc.crank, st, q_ext, dt)
    elif mc.kind == MechanismKind.TREE:
        tree_step(mc.tree, st, q_ext, dt)


@njit(cache=True)
def mass(mc, q):
    """M_q at q."""
    if mc.kind == MechanismKind.TRAIN:
        return train_mass(mc.track, mc.train, q)
    if mc.kind == MechanismKind.TREE:
        return tree_mass(mc.tree, q)
    return crank_mass(mc.crank, q)


@njit(cache=True)
def energy(mc, q, qd):
    if mc.kind == MechanismKind.TRAIN:
        return train_energy(mc.track, mc.train, q, qd)
    if mc.kind == MechanismKind.TREE:
        return tree_energy(mc.tree, q, qd)
    return crank_energy(mc.crank, q, qd)


@njit(cache=True)
def moved(mc, q0, q1):
    """q1 - q0, the short way round a loop (a closed track; a crank's angle on [0, 2 pi))."""
    d = q1 - q0
    if mc.kind == MechanismKind.TRAIN and mc.track.closed == 1:
        d -= mc.track.length * round(d / mc.track.length)
    elif mc.kind == MechanismKind.TREE or (
        mc.kind == MechanismKind.CRANK and mc.crank.driver == CrankDriver.CRANK_ANGLE
    ):
        d = turn_between(q0, q1)
    return d


@njit(cache=True)
def turn_between(a, b):
    """b - a wrapped to [-pi, pi]."""
    d = b - a
    return d - 2.0 * math.pi * round(d / (2.0 * math.pi))
