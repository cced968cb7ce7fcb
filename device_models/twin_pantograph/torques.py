"""Redundancy resolution: four motor torques for a handle wrench under the per-motor limits."""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.device_models.twin_pantograph.config import _SCALE_BISECTIONS
from haptic_local_model.device_models.twin_pantograph.dynamics import _solve_spd3


@njit(cache=True)
def _det3_rows(j, r0, r1, r2):
    """Determinant of rows r0, r1, r2 of the 4 x 3 matrix j."""
    return (
        j[r0, 0] * (j[r1, 1] * j[r2, 2] - j[r1, 2] * j[r2, 1])
        - j[r0, 1] * (j[r1, 0] * j[r2, 2] - j[r1, 2] * j[r2, 0])
        + j[r0, 2] * (j[r1, 0] * j[r2, 1] - j[r1, 1] * j[r2, 0])
    )


@njit(cache=True)
def _alpha_interval(tau0, null, scale, limit):
    """Interval of alpha with |scale tau0_i + alpha n_i| <= limit_i for all i (lo > hi: empty)."""
    lo = -math.inf
    hi = math.inf
    for i in range(4):
        t = scale * tau0[i]
        if abs(null[i]) < 1e-12:
            if abs(t) > limit[i]:
                return 1.0, -1.0
            continue
        b0 = (-limit[i] - t) / null[i]
        b1 = (limit[i] - t) / null[i]
        lo = max(lo, min(b0, b1))
        hi = min(hi, max(b0, b1))
    return lo, hi


@njit(cache=True)
def resolve_torques(params, jacobian, wrench, motor_torques):
    """Motor torques for a handle wrench under the per-motor limits; returns the scale s.

    Solutions of Jm^T tau = W are tau0 + alpha n, with tau0 = Jm (Jm^T Jm)^-1 W the minimum-
    norm one and n the unit null vector of Jm^T (tau0 ⟂ n). The limits cut an interval of
    alpha; its point nearest 0 is the limit-constrained minimum-norm solution, so W is
    produced exactly whenever it is feasible (s = 1). Otherwise the largest feasible s W
    (bisection on s) is produced: the direction is kept and s < 1 reports saturation.
    A rank-deficient Jm gives s = 0 and zero torques.
    """
    limit = params[0].torque_limit
    g00 = g01 = g02 = g11 = g12 = g22 = 0.0
    for i in range(4):
        g00 += jacobian[i, 0] * jacobian[i, 0]
        g01 += jacobian[i, 0] * jacobian[i, 1]
        g02 += jacobian[i, 0] * jacobian[i, 2]
        g11 += jacobian[i, 1] * jacobian[i, 1]
        g12 += jacobian[i, 1] * jacobian[i, 2]
        g22 += jacobian[i, 2] * jacobian[i, 2]
    ok, y0, y1, y2 = _solve_spd3((g00, g01, g02, g11, g12, g22), (wrench[0], wrench[1], wrench[2]))
    # Null vector of Jm^T: signed 3 x 3 minors of Jm (generalised cross product).
    n0 = _det3_rows(jacobian, 1, 2, 3)
    n1 = -_det3_rows(jacobian, 0, 2, 3)
    n2 = _det3_rows(jacobian, 0, 1, 3)
    n3 = -_det3_rows(jacobian, 0, 1, 2)
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
    if not ok or norm == 0.0:
        for i in range(4):
            motor_torques[i] = 0.0
        return 0.0
    null = (n0 / norm, n1 / norm, n2 / norm, n3 / norm)
    tau0 = (
        jacobian[0, 0] * y0 + jacobian[0, 1] * y1 + jacobian[0, 2] * y2,
        jacobian[1, 0] * y0 + jacobian[1, 1] * y1 + jacobian[1, 2] * y2,
        jacobian[2, 0] * y0 + jacobian[2, 1] * y1 + jacobian[2, 2] * y2,
        jacobian[3, 0] * y0 + jacobian[3, 1] * y1 + jacobian[3, 2] * y2,
    )
    scale = 1.0
    lo, hi = _alpha_interval(tau0, null, 1.0, limit)
    if lo > hi:
        feasible = 0.0  # s = 0 is always feasible (alpha = 0)
        infeasible = 1.0
        for _ in range(_SCALE_BISECTIONS):
            mid = 0.5 * (feasible + infeasible)
            lo, hi = _alpha_interval(tau0, null, mid, limit)
            if lo <= hi:
                feasible = mid
            else:
                infeasible = mid
        scale = feasible
        lo, hi = _alpha_interval(tau0, null, scale, limit)
    alpha = min(max(0.0, lo), hi)
    for i in range(4):
        t = scale * tau0[i] + alpha * null[i]
        motor_torques[i] = min(max(t, -limit[i]), limit[i])  # guards the last ulp only
    return scale
