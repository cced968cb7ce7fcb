"""A mechanism driven by an animation variable in the haptic loop (seed 003 §4; DESIGN-WAVE2
§5): a train of cars on a track, or a slider-crank (shared/mechanism.py), its avar integrated
at the tick's rate, pushed by the god-object's finger. The train's words below hold for the
crank with "body" for "car".

The haptic side is authoritative for the train while its proxy states are fresh (the sim
poses its cars from them, sim_server/train.py). Each tick, around the god-object's step:

1. `train_begin`: the free prediction s* of this tick (RK4 with the mass-weighted projection,
   shared/avar.py, without the finger), and every car's pose at the tick's start with the
   twist that carries it, along the chord, to its pose at s*: the god-object meets the cars
   where they go over the tick (Motion.TRACK shapes, stages/god_object.py);
2. the god-object's step renders the finger's force F and splits -F over the touched shapes;
3. `train_end`: the generalised force of the pushes on cars, Q = sum F_c . J_c (J_c the
   velocity of the contact point per unit s', shared/avar.py contact_jacobian), made
   implicit in the coupling (DESIGN-WAVE2 §5, Gauss's principle with one constraint): the
   finger's spring K along the contact normal n stiffens the train by K (n . J_c)^2, so
   Q_eff = Q M_q / (M_q + dt^2 K (n . J_c)^2); then the tick's step from its start under
   Q_eff held (the work Q_eff (s - s0) is what the train gains: RK4 keeps it to 1e-6).

The row reports s, s', Q_eff, the energy and the finger's work on the train so far.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.shared.avar import AVAR_DTYPE
from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.mechanism import (
    MECHANISM_DTYPE,
    body_count,
    body_pose,
    energy,
    mass,
    mechanism_record,
    moved,
    point_rate,
    step,
    turn_between,
)
from haptic_local_model.shared.protocol.static import static_id
from haptic_local_model.shared.shapes import Motion

F8 = np.float64
I8 = np.int64

#: The scene's mechanism, static (MODEL_DTYPE's `train`; kind NONE: none).
TRAIN_MODEL_DTYPE = np.dtype(
    [
        ("enabled", I8),
        ("static_id", I8),  # shared/protocol/static.py: an update must name this one
        ("mech", MECHANISM_DTYPE),
    ]
)

#: The mechanism's state and this tick's results (DATA_DTYPE's `train`).
TRAIN_DATA_DTYPE = np.dtype(
    [
        ("state", AVAR_DTYPE),  # q, q' and the event counters
        ("predicted", AVAR_DTYPE),  # q* of this tick (scratch)
        ("force", F8),  # Q_eff of this tick, N or N m
        ("work", F8),  # the finger's work on the mechanism so far, J
        ("energy", F8),  # its energy after this tick, J
    ]
)


def train_model(scene: SceneConfig) -> np.ndarray:
    """TRAIN_MODEL_DTYPE[1] of a scene (disabled without a mechanism)."""
    rec = np.zeros(1, TRAIN_MODEL_DTYPE)
    rec[0]["static_id"] = static_id(scene)
    rec[0]["mech"] = mechanism_record(scene)[0]
    rec[0]["enabled"] = 1 if rec[0]["static_id"] >= 0 else 0
    return rec


@njit(cache=True)
def restart_train(tm, td, s, sd):
    """The mechanism at (q, q') (a re-initialisation: the sim's state), the work afresh."""
    if tm.enabled == 0:
        return
    td.state.s = s
    td.state.sd = sd
    td.work = 0.0
    td.force = 0.0
    td.energy = energy(tm.mech, s, sd)


@njit(cache=True)
def _place_cars(tm, td, god, dt):
    """Each body's pose at the tick's start and the chord twist to its predicted pose."""
    q0 = td.state.s
    q1 = td.predicted.s
    for k in range(body_count(tm.mech)):
        x0, y0, a0 = body_pose(tm.mech, q0, k)
        x1, y1, a1 = body_pose(tm.mech, q1, k)
        god.car_pose[k, 0] = x0
        god.car_pose[k, 1] = y0
        god.car_pose[k, 2] = a0
        god.car_twist[k, 0] = (x1 - x0) / dt
        god.car_twist[k, 1] = (y1 - y0) / dt
        god.car_twist[k, 2] = turn_between(a0, a1) / dt  # a loop's heading wraps


@njit(cache=True)
def train_begin(tm, td, god, blend, dt):
    """Step 1 (module docstring): the free prediction and the bodies' poses over the tick,
    for the god-object (`god`) and a two-proxy blend's old proxy (`blend.a`)."""
    if tm.enabled == 0:
        return
    p = td.predicted
    p.s = td.state.s
    p.sd = td.state.sd
    step(tm.mech, p, 0.0, dt)
    _place_cars(tm, td, god, dt)
    _place_cars(tm, td, blend.a, dt)


@njit(cache=True)
def _car_of(shapes, n_shapes, key):
    """The body a shape key belongs to (-1: a world shape, or none)."""
    for k in range(n_shapes):
        if shapes[k].key == key:
            return shapes[k].owner if shapes[k].motion == Motion.TRACK else -1
    return -1


@njit(cache=True)
def train_end(tm, td, gp, blend, shapes, n_shapes, dt):
    """Step 3 (module docstring): the pushes on the mechanism's bodies as the implicit
    generalised force, the tick's step under it; the row's fields are `fill_train_row`'s."""
    if tm.enabled == 0:
        return
    q_star = td.predicted.s
    q = 0.0
    stiffness = 0.0
    for j in range(2):
        if blend.env_key[j] < 0:
            continue
        car = _car_of(shapes, n_shapes, blend.env_key[j])
        if car < 0:
            continue
        fx = blend.env_force[j, 0]
        fy = blend.env_force[j, 1]
        jx, jy = point_rate(tm.mech, q_star, car, blend.env_point[j, 0], blend.env_point[j, 1])
        q += fx * jx + fy * jy
        size = math.hypot(fx, fy)
        if size > 0.0:
            nx = fx / size
            ny = fy / size
            along = nx * jx + ny * jy
            stiffness += (nx * nx * gp.stiffness[0] + ny * ny * gp.stiffness[1]) * along * along
    m_q = mass(tm.mech, q_star)
    q_eff = q * m_q / (m_q + dt * dt * stiffness)
    st = td.state
    q0 = st.s
    step(tm.mech, st, q_eff, dt)
    td.force = q_eff
    td.work += q_eff * moved(tm.mech, q0, st.s)
    td.energy = energy(tm.mech, st.s, st.sd)


@njit(cache=True)
def fill_train_row(tm, td, r):
    """The train's fields of the tick row."""
    if tm.enabled == 0:
        return
    st = td.state
    r.avar_cars = body_count(tm.mech)
    r.avar_static_id = tm.static_id
    r.avar_s = st.s
    r.avar_sd = st.sd
    r.avar_force = td.force
    r.avar_energy = td.energy
    r.avar_work = td.work
    r.avar_events = st.kinks + st.bumps
    r.avar_singular = st.singular
