"""A second, independent reference for a held planar linkage: the links as free rigid bodies
joined by pin constraints (maximal coordinates), integrated with a tight-tolerance scipy ODE
solver.

It shares no code and no formulation with `shared.reference` (recursive Newton-Euler in joint
coordinates) or with the haptic kernels: each link is a body with its own position, angle,
mass and inertia; the joints are the constraint forces that keep consecutive links pinned
together, solved each step from the constraint's acceleration equation (with a light
Baumgarte term against drift). Two formulations that agree to solver tolerance check each
other; `tests/test_holds.py` requires it.

Conventions are those of `shared.reference.ChainSpec` (SI, link i's frame at joint i with
its x axis along the link, points on a link given in that frame).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from haptic_local_model.shared.reference import ChainSpec, Hold, Integrator

FloatArray = NDArray[np.float64]
#: The hand's world wrench (fx, fy, tau) at time t given the hand point's pose and twist.
BodyWrench = Callable[[float, FloatArray, FloatArray], ArrayLike]

TIGHT = Integrator()  # the reference's own tolerances
BAUMGARTE_RATE = 20.0  # 1/s: the constraint's position and velocity error decay (light)


def _rot(angle: float) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def _perp(v: FloatArray) -> FloatArray:
    return np.array([-v[1], v[0]])


@dataclass(frozen=True)
class BodySolution:
    """Samples of the hold point's pose (x, y, angle of its link) and the joint angles."""

    t: FloatArray
    pose: FloatArray  # (len(t), 3)
    q: FloatArray  # (len(t), n) joint angles recovered from the bodies' angles
    constraint_error: float  # largest pin separation seen at the samples, m


class PinnedBodies:
    """The chain as n rigid bodies (COM x, y, absolute angle) with 2n pin constraints."""

    def __init__(self, spec: ChainSpec) -> None:
        self.spec = spec
        self.n = spec.n
        self.com = np.array(spec.com_offsets, dtype=float)
        self.lengths = np.array(spec.lengths, dtype=float)
        mass = np.empty(3 * self.n)
        for i in range(self.n):
            mass[3 * i : 3 * i + 3] = (spec.masses[i], spec.masses[i], spec.inertias[i])
        self.mass = mass
        self.base = np.array(spec.base, dtype=float)

    def point(self, state: FloatArray, link: int, local: FloatArray) -> FloatArray:
        """World position of a point given in link `link`'s joint frame."""
        c = state[3 * link : 3 * link + 2]
        rot = _rot(state[3 * link + 2])
        return c + rot @ (local - self.com[link])

    def from_joints(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """Bodies' positions and velocities (6n) for joint angles and rates."""
        n = self.n
        x = np.empty(3 * n)
        v = np.empty(3 * n)
        origin = self.base.copy()
        origin_v = np.zeros(2)
        angle = self.spec.base_angle
        rate = 0.0
        for i in range(n):
            angle += q[i]
            rate += qd[i]
            arm = _rot(angle) @ self.com[i]
            x[3 * i : 3 * i + 3] = (*(origin + arm), angle)
            v[3 * i : 3 * i + 3] = (*(origin_v + rate * _perp(arm)), rate)
            tip = _rot(angle) @ np.array([self.lengths[i], 0.0])
            origin = origin + tip
            origin_v = origin_v + rate * _perp(tip)
        return np.concatenate((x, v))

    def _pins(self, x: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Constraint error g (2n), its Jacobian G (2n x 3n) and the velocity-product part of
        its second derivative (G_dot v), for the pins base-link 0 and link i-1 - link i."""
        n = self.n
        g = np.zeros(2 * n)
        jac = np.zeros((2 * n, 3 * n))
        bias = np.zeros(2 * n)

        def attach(row: int, body: int, local: FloatArray, sign: float) -> FloatArray:
            """Add sign * (the world point `local` of `body`) to the constraint rows."""
            angle = x[3 * body + 2]
            arm = _rot(angle) @ (local - self.com[body])
            jac[row : row + 2, 3 * body : 3 * body + 2] += sign * np.eye(2)
            jac[row : row + 2, 3 * body + 2] += sign * _perp(arm)
            bias[row : row + 2] += sign * (-(v[3 * body + 2] ** 2) * arm)
            return sign * (x[3 * body : 3 * body + 2] + arm)

        g[0:2] = attach(0, 0, np.zeros(2), 1.0) - self.base
        for i in range(1, n):
            end = np.array([self.lengths[i - 1], 0.0])
            g[2 * i : 2 * i + 2] = attach(2 * i, i - 1, end, 1.0) + attach(
                2 * i, i, np.zeros(2), -1.0
            )
        return g, jac, bias

    def accelerations(self, x: FloatArray, v: FloatArray, force: FloatArray) -> FloatArray:
        """M a = f + G^T lambda with G a = -G_dot v - 2 k G v - k^2 g (pins held)."""
        g, jac, bias = self._pins(x, v)
        k = BAUMGARTE_RATE
        n3 = 3 * self.n
        m2 = 2 * self.n
        kkt = np.zeros((n3 + m2, n3 + m2))
        kkt[:n3, :n3] = np.diag(self.mass)
        kkt[:n3, n3:] = -jac.T
        kkt[n3:, :n3] = jac
        rhs = np.concatenate((force, -bias - 2.0 * k * (jac @ v) - k * k * g))
        return np.asarray(np.linalg.solve(kkt, rhs)[:n3], dtype=np.float64)

    def joint_angles(self, x: FloatArray) -> FloatArray:
        angles = x[2::3]
        return np.diff(np.concatenate(([self.spec.base_angle], angles)))


def simulate_bodies(
    spec: ChainSpec,
    q0: ArrayLike,
    qd0: ArrayLike,
    hold: Hold,
    t_end: float,
    t_eval: ArrayLike,
    *,
    integrator: Integrator = TIGHT,
) -> BodySolution:
    """The chain released from (q0, qd0) under the hand's world wrench at the hold: a
    constant (fx, fy, tau) or a function of (t, pose, twist) of the hold point (not of the
    joint state, which this formulation does not have)."""
    wrench, link, point = hold.wrench, hold.link, hold.point
    bodies = PinnedBodies(spec)
    n = spec.n
    if not 0 <= link < n:
        raise IndexError(f"link {link} out of range for a {n}-link chain")
    local = np.asarray(point, dtype=float).reshape(2)
    gravity = np.array(spec.gravity, dtype=float)
    constant = None if callable(wrench) else np.asarray(wrench, dtype=float).reshape(3)

    def held(x: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        p = bodies.point(x, link, local)
        arm = p - x[3 * link : 3 * link + 2]
        pd = v[3 * link : 3 * link + 2] + v[3 * link + 2] * _perp(arm)
        pose = np.array([p[0], p[1], x[3 * link + 2]])
        twist = np.array([pd[0], pd[1], v[3 * link + 2]])
        return pose, twist, arm

    def rhs(t: float, s: FloatArray) -> FloatArray:
        x, v = s[: 3 * n], s[3 * n :]
        pose, twist, arm = held(x, v)
        w = constant if constant is not None else np.asarray(wrench(t, pose, twist), float)  # type: ignore[operator]
        force = np.zeros(3 * n)
        for i in range(n):
            force[3 * i : 3 * i + 2] = spec.masses[i] * gravity
        force[3 * link : 3 * link + 2] += w[:2]
        force[3 * link + 2] += arm[0] * w[1] - arm[1] * w[0] + w[2]
        return np.concatenate((v, bodies.accelerations(x, v, force)))

    s0 = bodies.from_joints(np.asarray(q0, float), np.asarray(qd0, float))
    t, states = integrator.states(rhs, s0, t_end, t_eval, "pinned-body reference")
    pose = np.array([held(s[: 3 * n], s[3 * n :])[0] for s in states])
    q = np.array([bodies.joint_angles(s[: 3 * n]) for s in states])
    worst = max(float(np.abs(bodies._pins(s[: 3 * n], s[3 * n :])[0]).max()) for s in states)
    return BodySolution(t=t, pose=pose, q=q, constraint_error=worst)
