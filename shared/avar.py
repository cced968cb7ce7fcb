"""Animation-variable dynamics: mechanisms whose bodies are driven by one avar q (seed 003
§4, corrected in DESIGN-WAVE2 §5).

The bodies' world coordinates theta (x, y, angle per body) are theta = f(q), so
theta' = J q', theta'' = J q'' + Jd q'^2 with J = f'(q) and Jd = f''(q). With M theta'' =
tau + tau_lambda (Newton-Euler in world coordinates: no b) and workless constraints
(J^T tau_lambda = 0):

    M_q q'' = J^T tau - J^T M Jd q'^2,    M_q = J^T M J,                        (5.1)

the mass-weighted projection. Seed 003's eq 8 uses the unweighted left inverse
(J^T J)^-1 J^T instead, which is wrong whenever M is not a multiple of the identity on
range(J) (it mixes metres and radians, and loses 93 % of a looping car's energy in 10 s;
shared/reference_avar.py keeps it as the negative check).

A roller coaster's train of cars on a track (shared/track.py), lead car at arc length s and
car k at s - k l, has per car J_k = (t_k, kappa_k) and Jd_k = (kappa_k n_k, kappa'_k), so

    s'' = [sum m_k g.t_k + Q - sum I_k kappa_k kappa'_k s'^2] / sum (m_k + I_k kappa_k^2),

never singular (M_q >= sum m_k). Q is the generalised force of what else pushes the cars
(sum F_c . J_c, J_c the velocity of the contact point per unit s'). The step is classical
RK4 on (s, s'), which holds a looping car's energy to 1e-8 where semi-implicit Euler drifts
1.8 % (DESIGN-WAVE2 §5); within a step the events of the track are met in order:

- a kink (a C0 knot, where a car's tangent jumps): the plastic projection
  s'+ = (J+^T M J+)^-1 J+^T M J- s'-, which never gains energy (§5 (i));
- an open track's end bumper (the lead car at the far end, the last car at the near one):
  s' <- -e s', a hard stop with restitution e.

Every kernel is a numba function of records: TRAIN_DTYPE (the cars, static) and AVAR_DTYPE
(the state, written by train_step).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.shared.track import knot_point, track_heading, track_point, wrap_s

MAX_CARS = 8
MAX_EVENTS = 8  # events met within one step; beyond, the step is clamped (counted)
NUDGE_M = 1.0e-12  # past an event, so the next lookup reads the side the train moves into
SAME_EVENT_M = 1.0e-9  # kinks that cars reach within this of each other are crossed together
LEAVE_M = 1.0e-4  # a bumper contact ends when the train is this far from the stop


TRAIN_DTYPE = np.dtype(
    [
        ("n_cars", np.int64),
        ("spacing", np.float64),  # l, m: car k sits at s - k l
        ("mass", np.float64, (MAX_CARS,)),  # m_k, kg
        ("inertia", np.float64, (MAX_CARS,)),  # I_k about the car's reference point, kg m^2
        ("gravity", np.float64, (2,)),  # g, m/s^2
        ("restitution", np.float64),  # e of the end bumpers (open tracks)
    ]
)

AVAR_DTYPE = np.dtype(
    [
        ("s", np.float64),  # m, the lead car's arc length (on [0, length) for a loop)
        ("sd", np.float64),  # m/s
        ("kinks", np.int64),  # kinks crossed by a car so far
        ("bumps", np.int64),  # end-bumper hits so far
        ("capped", np.int64),  # steps that met more than MAX_EVENTS events
        ("plastic_loss", np.float64),  # J lost at kinks so far
        ("bumper_loss", np.float64),  # J lost at the bumpers so far
        ("singular", np.int64),  # steps whose M_q was regularised (a singular J)
        ("at_stop", np.int64),  # the end bumper of the contact going on (2 far, 3 near; 0)
    ]
)


def train_record(
    n_cars: int,
    spacing: float,
    mass: float,
    inertia: float,
    gravity: tuple[float, float],
    restitution: float = 0.5,
) -> np.ndarray:
    """TRAIN_DTYPE[1] for n equal cars."""
    if not 1 <= n_cars <= MAX_CARS:
        raise ValueError(f"a train has 1..{MAX_CARS} cars, got {n_cars}")
    if not (mass > 0.0 and inertia >= 0.0 and spacing >= 0.0 and 0.0 <= restitution <= 1.0):
        raise ValueError("cars need mass > 0, inertia >= 0, spacing >= 0 and restitution in [0, 1]")
    t = np.zeros(1, dtype=TRAIN_DTYPE)
    t[0]["n_cars"] = n_cars
    t[0]["spacing"] = spacing
    t[0]["mass"][:n_cars] = mass
    t[0]["inertia"][:n_cars] = inertia
    t[0]["gravity"] = gravity
    t[0]["restitution"] = restitution
    return t


def avar_state(s: float, sd: float) -> np.ndarray:
    """AVAR_DTYPE[1] at (s, s')."""
    st = np.zeros(1, dtype=AVAR_DTYPE)
    st[0]["s"] = s
    st[0]["sd"] = sd
    return st


@njit(cache=True)
def mass_weighted_rate(jac, bias, mass, force, n, floor):
    """q'' of eq 5.1 for one avar: jac = J, bias = Jd (theta'' = J q'' + Jd q'^2 has
    Jd q'^2 = bias * q'^2 folded in by the caller), mass = diag M, force = tau, over the first
    n coordinates. M_q below `floor` (a singular J: the avar moves no mass) is regularised
    to M_q + floor and flagged: returns (q'', M_q, singular)."""
    m_q = 0.0
    num = 0.0
    for i in range(n):
        m_q += jac[i] * mass[i] * jac[i]
        num += jac[i] * (force[i] - mass[i] * bias[i])
    singular = m_q < floor
    if singular:
        m_q += floor
    return num / m_q, m_q, singular


@njit(cache=True)
def train_accel(tr, train, s, sd, q_ext):
    """s'' of the train (module docstring) under gravity and the generalised force q_ext."""
    num = q_ext
    den = 0.0
    gx = train.gravity[0]
    gy = train.gravity[1]
    for k in range(train.n_cars):
        psi, kappa, dkappa = track_heading(tr, s - k * train.spacing)
        m = train.mass[k]
        inertia = train.inertia[k]
        num += m * (gx * math.cos(psi) + gy * math.sin(psi)) - inertia * kappa * dkappa * sd * sd
        den += m + inertia * kappa * kappa
    return num / den


@njit(cache=True)
def train_mass(tr, train, s):
    """M_q = sum (m_k + I_k kappa_k^2)."""
    den = 0.0
    for k in range(train.n_cars):
        _, kappa, _ = track_heading(tr, s - k * train.spacing)
        den += train.mass[k] + train.inertia[k] * kappa * kappa
    return den


@njit(cache=True)
def train_energy(tr, train, s, sd):
    """E = 1/2 M_q s'^2 - sum m_k g . p_k (J)."""
    e = 0.0
    for k in range(train.n_cars):
        x, y, _, kappa, _ = track_point(tr, s - k * train.spacing)
        m = train.mass[k]
        e += 0.5 * (m + train.inertia[k] * kappa * kappa) * sd * sd
        e -= m * (train.gravity[0] * x + train.gravity[1] * y)
    return e


@njit(cache=True)
def rk4(tr, train, s, sd, q_ext, h):
    """Classical RK4 on (s, s') over h with q_ext held."""
    a1 = train_accel(tr, train, s, sd, q_ext)
    v2 = sd + 0.5 * h * a1
    a2 = train_accel(tr, train, s + 0.5 * h * sd, v2, q_ext)
    v3 = sd + 0.5 * h * a2
    a3 = train_accel(tr, train, s + 0.5 * h * v2, v3, q_ext)
    v4 = sd + h * a3
    a4 = train_accel(tr, train, s + h * v3, v4, q_ext)
    s1 = s + h / 6.0 * (sd + 2.0 * v2 + 2.0 * v3 + v4)
    sd1 = sd + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return s1, sd1


def rk4_flagged(rate: Callable[..., Any]) -> Callable[..., Any]:
    """Classical RK4 on (q, q') for a mechanism whose `rate(model, q, q', q_ext)` returns
    (q'', flag) (a crank's, an avar tree's): a kernel `step(model, q, q', q_ext, dt)` that
    returns the new (q, q') after dt with q_ext held and whether any stage flagged. (`rate`
    is a constant of the kernel, not an argument: a function passed as a value would keep
    numba from caching its caller.) Its sums keep the order the crank and the tree had, which
    rounds q apart from `rk4`'s by an ulp now and then."""

    @njit(cache=True)
    def step(model, q, qd, q_ext, dt):
        a1, f1 = rate(model, q, qd, q_ext)
        v2 = qd + 0.5 * dt * a1
        a2, f2 = rate(model, q + 0.5 * dt * qd, v2, q_ext)
        v3 = qd + 0.5 * dt * a2
        a3, f3 = rate(model, q + 0.5 * dt * v2, v3, q_ext)
        v4 = qd + dt * a3
        a4, f4 = rate(model, q + dt * v3, v4, q_ext)
        q1 = q + dt / 6.0 * (qd + 2.0 * v2 + 2.0 * v3 + qd + dt * a3)  # not v4: kept bit for bit
        qd1 = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        return q1, qd1, f1 or f2 or f3 or f4

    return step


@njit(cache=True, inline="always")
def _ahead(tr, s0, target, forward):
    """How far the train moves from s0 until the lead car's s reaches target (>= 0; a
    loop: modulo its length)."""
    d = target - s0 if forward else s0 - target
    if tr.closed == 1:
        d = d % tr.length
    return d


@njit(cache=True)
def next_event(tr, train, s0, s1):
    """The first event between s0 and s1: (distance along the motion, kind, index), kind 0
    none, 1 kink (index = kink * MAX_CARS + car), 2 the far bumper, 3 the near one."""
    forward = s1 >= s0
    reach = abs(s1 - s0)
    best = math.inf
    kind = 0
    index = -1
    for j in range(tr.n_kinks):
        for k in range(train.n_cars):
            target = tr.kink_s[j] + k * train.spacing
            if tr.closed == 0 and not (0.0 <= target <= tr.length):
                continue
            d = _ahead(tr, s0, target, forward)
            if 0.0 < d <= reach and d < best:
                best = d
                kind = 1
                index = j * MAX_CARS + k
    if tr.closed == 0:
        near = (train.n_cars - 1) * train.spacing
        if forward and s1 > tr.length and tr.length - s0 < best:
            best = max(tr.length - s0, 0.0)
            kind = 2
        if not forward and s1 < near and s0 - near < best:
            best = max(s0 - near, 0.0)
            kind = 3
    return best, kind, index


@njit(cache=True)
def time_to(distance, v0, a0, h, forward):
    """The time within [0, h] at which s0 + v0 t + a0 t^2 / 2 has moved `distance` in the
    event's direction (`forward`: increasing s), even if it first moved the other way (a
    train just bounced off a bumper, pulled back into it within the step): the event's
    time, to O(h^3)."""
    v = v0 if forward else -v0
    a = a0 if forward else -a0
    if abs(a) * h < 1e-9 * max(abs(v), 1e-12):
        t = distance / v if v > 0.0 else h
    else:
        disc = v * v + 2.0 * a * distance
        t = (-v + math.sqrt(disc)) / a if disc >= 0.0 else h
    return min(max(t, 0.0), h)


@njit(cache=True, inline="always")
def _kink_at(tr, s_car):
    """The kink a car at arc length s_car is on (within SAME_EVENT_M), -1 if none."""
    for j in range(tr.n_kinks):
        gap = tr.kink_s[j] - s_car
        if tr.closed == 1:
            gap -= tr.length * round(gap / tr.length)
        if abs(gap) <= SAME_EVENT_M:
            return j
    return -1


@njit(cache=True)
def cross_kinks(tr, train, st, at, sd, forward):
    """s' after the cars on kinks with the lead car at `at` cross them: the plastic
    projection s'+ = (J+^T M J+)^-1 J+^T M J- s'- of the whole train at once (two cars may
    reach two kinks together; projecting them one by one is not the same), J- and J+ a
    crossing car's tangent and curvature at its kink's two knots, the rest's where they are.
    Counted in st, with the energy it takes (never negative: Cauchy-Schwarz in M)."""
    num = 0.0
    den = 0.0
    m_before = 0.0
    for k in range(train.n_cars):
        m = train.mass[k]
        inertia = train.inertia[k]
        j = _kink_at(tr, at - k * train.spacing)
        if j < 0:
            _, kappa, _ = track_heading(tr, at - k * train.spacing)
            own = m + inertia * kappa * kappa
            num += own
            den += own
            m_before += own
            continue
        before = tr.kink_before[j] if forward else tr.kink_after[j]
        after = tr.kink_after[j] if forward else tr.kink_before[j]
        _, _, psi_a, kappa_a, _ = knot_point(tr, before)
        _, _, psi_b, kappa_b, _ = knot_point(tr, after)
        num += m * math.cos(psi_b - psi_a) + inertia * kappa_b * kappa_a
        den += m + inertia * kappa_b * kappa_b
        m_before += m + inertia * kappa_a * kappa_a
        st.kinks += 1
    sd_after = sd * num / den
    st.plastic_loss += 0.5 * m_before * sd * sd - 0.5 * den * sd_after * sd_after
    return sd_after


@njit(cache=True)
def train_step(tr, train, st, q_ext, dt):
    """One step of dt: RK4 with q_ext held, the track's events met in order (module
    docstring); the result in st (s wrapped on a loop)."""
    s = st.s
    sd = st.sd
    left = dt
    for _ in range(MAX_EVENTS):
        s1, sd1 = rk4(tr, train, s, sd, q_ext, left)
        dist, kind, _ = next_event(tr, train, s, s1)
        if kind == 0:
            s = s1
            sd = sd1
            left = 0.0
            break
        forward = s1 >= s
        a0 = train_accel(tr, train, s, sd, q_ext)
        t = time_to(dist, sd, a0, left, forward)
        _, sd = rk4(tr, train, s, sd, q_ext, t)
        left -= t
        at = s + dist if forward else s - dist
        if kind == 1:  # just past the kink(s), on the side the train moves into
            s = at + NUDGE_M if forward else at - NUDGE_M
            sd = cross_kinks(tr, train, st, at, sd, forward)
        else:  # just inside the stop
            s = at - NUDGE_M if forward else at + NUDGE_M
            sd, left = hit_stop(tr, train, st, kind, s, sd, q_ext, left)
            if left == 0.0:
                break
    if left > 0.0:
        st.capped += 1
    if tr.closed == 0:
        near = (train.n_cars - 1) * train.spacing
        if s > tr.length or s < near:  # only after MAX_EVENTS: held at the stop
            s = min(max(s, near), tr.length)
            sd = 0.0
        gap = tr.length - s if st.at_stop == 2 else s - near
        if st.at_stop != 0 and gap > LEAVE_M:
            st.at_stop = 0  # off the bumper: the next hit is another
    st.s = wrap_s(tr, s) if tr.closed == 1 else s
    st.sd = sd


@njit(cache=True)
def hit_stop(tr, train, st, kind, s, sd, q_ext, left):
    """An end bumper (kind 2 far, 3 near) met at s with s' = sd, `left` of the step to go:
    s' <- -e s', counted once per contact (a train resting on the bumper meets it again every
    step); when the bounce would come back within what is left of the step (a resting train:
    the bounces shrink geometrically, each e times the last, a Zeno series), it settles there,
    s' = 0 for the rest of the step, all its kinetic energy lost. Returns (s', left)."""
    if st.at_stop != kind:
        st.bumps += 1
        st.at_stop = kind
    m = train_mass(tr, train, s)
    e = train.restitution
    st.bumper_loss += 0.5 * m * sd * sd * (1.0 - e * e)
    sd = -e * sd
    a = train_accel(tr, train, s, sd, q_ext)
    a_in = a if kind == 2 else -a  # towards the stop (the far one ahead, the near behind)
    if a_in > 0.0 and 2.0 * abs(sd) < a_in * left:  # back within the step
        st.bumper_loss += 0.5 * m * sd * sd
        return 0.0, 0.0
    return sd, left


@njit(cache=True)
def car_pose(tr, train, s, sd, k, pose, twist):
    """Car k's pose (x, y, psi) and twist (t s', kappa s')."""
    x, y, psi, kappa, _ = track_point(tr, s - k * train.spacing)
    pose[0] = x
    pose[1] = y
    pose[2] = psi
    twist[0] = math.cos(psi) * sd
    twist[1] = math.sin(psi) * sd
    twist[2] = kappa * sd


@njit(cache=True)
def contact_jacobian(tr, train, s, k, cx, cy):
    """J_c: the velocity of the world point (cx, cy) carried by car k, per unit s'
    (t_k + kappa_k perp(c - p_k)); Q = F . J_c for a force F there."""
    x, y, psi, kappa, _ = track_point(tr, s - k * train.spacing)
    return math.cos(psi) - kappa * (cy - y), math.sin(psi) + kappa * (cx - x)


@njit(cache=True)
def track_force(tr, train, s, sd, sdd, k, fx, fy):
    """The force the track puts on car k (the constraint's, N): m_k a_k - m_k g - F with
    a_k = t_k s'' + kappa_k n_k s'^2 and F what else pushes the car."""
    psi, kappa, _ = track_heading(tr, s - k * train.spacing)
    c = math.cos(psi)
    sn = math.sin(psi)
    m = train.mass[k]
    ax = c * sdd - sn * kappa * sd * sd
    ay = sn * sdd + c * kappa * sd * sd
    return m * (ax - train.gravity[0]) - fx, m * (ay - train.gravity[1]) - fy
