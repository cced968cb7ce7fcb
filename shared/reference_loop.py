"""The whole closed loop in continuous time, as a reference: hand -> device -> controller ->
virtual mechanism, with the exact (never frozen) dynamics of the linkage.

The hand pushes an ideal device (M_d xdd_h = u + F_h, no friction or Coriolis terms, so
M_d cancels from the device's path); the controller is DESIGN §4.3's law
evaluated at every instant with the linkage's exact D(q), bias and J_h(q) (from the
recursive Newton-Euler reference, `shared.reference`), with or without M_d J_h_dot qd and
with or without the joint penalties along the resisted directions (the local model; without
them the law is seed 000's impedance control). The virtual mechanism is pulled by the hand
and the coordination wrench: D qdd + bias = J_h^T (F_h - F_c).

What it separates: the project's error against the linkage driven by the hand alone
(`shared.reference.simulate`) is the sum of the control law's own error (this loop against
the linkage alone) and what sampling, the frozen local model and the sim rate add (the
project against this loop). It writes the law itself, in numpy, from DESIGN §4.3; it calls
no haptic kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from haptic_local_model.shared.reference import (
    ChainSpec,
    Hold,
    Integrator,
    bias_forces,
    mass_matrix,
    point_jacobian,
    point_pose,
)

FloatArray = NDArray[np.float64]
LOOP_INTEGRATOR = Integrator(rtol=1e-9, atol=1e-12)  # the loop's fast device modes: not 1e-10


@dataclass(frozen=True)
class LoopGains:
    """The law's gains (a scene's [rendering] and [tool]) and switches."""

    coordination_stiffness: tuple[float, float, float]
    coordination_damping: tuple[float, float, float]
    jdot_qd: bool = True
    penalties: bool = True  # the local model's joint penalties (False: impedance control)
    penalty_stiffness: float = 200.0
    penalty_damping: float = 50.0
    characteristic_length_m: float = 0.05
    rank_tolerance: float = 0.05


@dataclass(frozen=True)
class LoopSolution:
    t: FloatArray
    vm_pose: FloatArray  # (len(t), 3) the hold point on the virtual mechanism
    device_pose: FloatArray  # (len(t), 3)


def jdot_qd(spec: ChainSpec, q: FloatArray, qd: FloatArray, link: int, r: FloatArray) -> FloatArray:
    """J_h_dot qd by a central difference of J_h along qd (relative error ~1e-10)."""
    speed = float(np.linalg.norm(qd))
    if speed == 0.0:
        return np.zeros(3)
    h = 1e-6 / speed
    plus = point_jacobian(spec, q + h * qd, link, r)
    minus = point_jacobian(spec, q - h * qd, link, r)
    return np.asarray(((plus - minus) / (2.0 * h)) @ qd, dtype=float)


def resisted_projection(jac: FloatArray, gains: LoopGains) -> FloatArray:
    """sum (S n)(S n)^T over the left singular vectors n of S J_h (S = diag(1, 1, L)) whose
    singular value is below rank_tolerance times the largest (DESIGN §3)."""
    scale = np.array([1.0, 1.0, gains.characteristic_length_m])
    u, sigma, _ = np.linalg.svd(scale[:, None] * jac)
    full = np.zeros(3)
    full[: len(sigma)] = sigma
    top = full[0]
    proj = np.zeros((3, 3))
    for k in range(3):
        if top <= 0.0 or full[k] < gains.rank_tolerance * top:
            sn = scale * u[:, k]
            proj += np.outer(sn, sn)
    return proj


def simulate_loop(
    spec: ChainSpec,
    q0: ArrayLike,
    hold: Hold,
    gains: LoopGains,
    t_end: float,
    t_eval: ArrayLike,
    *,
    device_offset: ArrayLike = (0.0, 0.0, 0.0),
    integrator: Integrator = LOOP_INTEGRATOR,
) -> LoopSolution:
    """The loop from rest, the device at the hold point plus `device_offset`, under a
    constant world hand wrench (fx, fy, tau) at the hold."""
    if callable(hold.wrench):
        raise TypeError("simulate_loop takes a constant hand wrench")
    n = spec.n
    link = hold.link
    r = np.asarray(hold.point, dtype=float).reshape(2)
    f_h = np.asarray(hold.wrench, dtype=float).reshape(3)
    k_c = np.asarray(gains.coordination_stiffness, dtype=float)
    b_c = np.asarray(gains.coordination_damping, dtype=float)
    q_start = np.asarray(q0, dtype=float).reshape(n)

    def rhs(t: float, s: FloatArray) -> FloatArray:
        q, qd, x_h, v_h = s[:n], s[n : 2 * n], s[2 * n : 2 * n + 3], s[2 * n + 3 :]
        jac = point_jacobian(spec, q, link, r)
        d = mass_matrix(spec, q)
        tau = -bias_forces(spec, q, qd)  # gravity, Coriolis and centripetal torques
        e = point_pose(spec, q, link, r) - x_h
        ed = jac @ qd - v_h
        f_c = k_c * e + b_c * ed
        qdd = np.linalg.solve(d, tau + jac.T @ (f_h - f_c))
        d_inv_jt = np.linalg.solve(d, jac.T)
        lam_inv = jac @ d_inv_jt
        # the device's acceleration (u + F_h) / M_d with u of DESIGN §4.3: M_d cancels
        acc = lam_inv @ (f_h + f_c) + d_inv_jt.T @ tau
        if gains.jdot_qd:
            acc = acc + jdot_qd(spec, q, qd, link, r)
        if gains.penalties:
            proj = resisted_projection(jac, gains)
            acc = acc + proj @ (gains.penalty_stiffness * e + gains.penalty_damping * ed)
        return np.concatenate((qd, qdd, v_h, acc))

    x0 = point_pose(spec, q_start, link, r) + np.asarray(device_offset, dtype=float)
    s0 = np.concatenate((q_start, np.zeros(n), x0, np.zeros(3)))
    t, states = integrator.states(rhs, s0, t_end, t_eval, "closed-loop reference")
    vm = np.array([point_pose(spec, s[:n], link, r) for s in states])
    return LoopSolution(t=t, vm_pose=vm, device_pose=states[:, 2 * n : 2 * n + 3])
