"""The linearly implicit step (seed 000 eq 21) of every world: a configuration q with mass
matrix D, stiffness K and damping B of its springs (contacts, couplings, drives) and the
force f they and everything else put on it now, stepped over h at theta of the step:

    (D + theta h B + theta^2 h^2 K) dqd = h f,    qd += dqd,    q += h (qd_old + theta dqd)

where f already holds each spring's motion term (-theta h K v_rel: a world's springs may
move with a wall or a device, which q does not hold, so the world writes it;
`subtract_stiffness_velocity` for springs whose other end is fixed or in q). theta = 1 is
the backward-Euler step of the proxy, the co-simulation and the hands' default.
"""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.shared.linalg import cholesky_inplace, cholesky_solve


@njit(cache=True)
def clear_terms(n, force, extra, stiffness, damping):
    """A step's terms over n coordinates start at zero: the force and the springs' motion
    term (n), their stiffness K and damping B (n x n)."""
    for a in range(n):
        force[a] = 0.0
        extra[a] = 0.0
        for b in range(n):
            stiffness[a, b] = 0.0
            damping[a, b] = 0.0


@njit(cache=True)
def subtract_stiffness_velocity(force, stiffness, qd, th_h, n):
    """force -= theta h K qd (th_h = theta h): the springs' stiffness times the motion of q
    over the step, the implicit step's explicit part."""
    for a in range(n):
        v = force[a]
        for b in range(n):
            v -= th_h * stiffness[a, b] * qd[b]
        force[a] = v


@njit(cache=True)
def implicit_system(system, mass, damping, stiffness, th_h, n):
    """system = D + theta h B + theta^2 h^2 K (th_h = theta h)."""
    th_h2 = th_h * th_h
    for a in range(n):
        for b in range(n):
            system[a, b] = mass[a, b] + th_h * damping[a, b] + th_h2 * stiffness[a, b]


@njit(cache=True)
def implicit_solve(system, chol, force, h, rhs, dqd, n):
    """dqd from system dqd = h f (rhs: its workspace, may be `force` itself). Returns
    whether the system factored and dqd is finite (dqd is not to be used otherwise)."""
    for a in range(n):
        rhs[a] = h * force[a]
    if not cholesky_inplace(system, n, chol):
        return False
    cholesky_solve(chol, n, rhs, dqd)
    ok = True
    for a in range(n):
        if not math.isfinite(dqd[a]):
            ok = False
    return ok


@njit(cache=True)
def implicit_advance(q, qd, dqd, h, theta, n):
    """q += h (qd + theta dqd), then qd += dqd. Returns whether both stay finite."""
    ok = True
    for a in range(n):
        q[a] += h * (qd[a] + theta * dqd[a])
        qd[a] += dqd[a]
        if not (math.isfinite(q[a]) and math.isfinite(qd[a])):
            ok = False
    return ok
