"""Task-space inertia M_d(x) (exact rigid-link kinetic energy), its gradient and the
Christoffel matrix C_d(x, xd)."""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.device_models.twin_pantograph.config import INERTIA_FD_STEP
from haptic_local_model.device_models.twin_pantograph.kinematics import _jacobian_row


@njit(cache=True)
def task_inertia(params, handle_pose, inertia):
    """Task-space inertia M_d(x) (3 x 3) from the kinetic energy of every moving part.

    Motor i: J_axis (Jm_i^T Jm_i). Distal link (elbow E to end point P), rigid body with mass
    at its midpoint: m J_c^T J_c + I J_w^T J_w, J_c = (J_E + J_P)/2, J_w = d x (J_P - J_E)/l^2.
    Handle: diag(m_h, m_h, I_h) about its centre.
    """
    p = params[0]
    for a in range(3):
        for b in range(3):
            inertia[a, b] = 0.0
    inertia[0, 0] = p.handle_mass
    inertia[1, 1] = p.handle_mass
    inertia[2, 2] = p.handle_inertia
    for i in range(4):
        ok, r0, r1, r2, ex, ey, px, py, dpx, dpy = _jacobian_row(p, i, handle_pose)
        if not ok:
            return False
        row = (r0, r1, r2)
        # Elbow velocity: perp(E - B) qd_i; end-point velocity: J_P twist.
        nx = -(ey - p.base[i, 1])
        ny = ex - p.base[i, 0]
        je0 = (nx * r0, nx * r1, nx * r2)
        je1 = (ny * r0, ny * r1, ny * r2)
        jp0 = (1.0, 0.0, dpx)
        jp1 = (0.0, 1.0, dpy)
        dx = px - ex
        dy = py - ey
        inv_l2sq = 1.0 / (p.distal_length[i] * p.distal_length[i])
        m = p.distal_mass[i]
        inertia_c = p.distal_inertia[i]
        axis = p.motor_axis_inertia[i]
        for a in range(3):
            jca0 = 0.5 * (je0[a] + jp0[a])
            jca1 = 0.5 * (je1[a] + jp1[a])
            jwa = (dx * (jp1[a] - je1[a]) - dy * (jp0[a] - je0[a])) * inv_l2sq
            for b in range(3):
                jcb0 = 0.5 * (je0[b] + jp0[b])
                jcb1 = 0.5 * (je1[b] + jp1[b])
                jwb = (dx * (jp1[b] - je1[b]) - dy * (jp0[b] - je0[b])) * inv_l2sq
                inertia[a, b] += (
                    axis * row[a] * row[b] + m * (jca0 * jcb0 + jca1 * jcb1) + inertia_c * jwa * jwb
                )
    return True


@njit(cache=True)
def inertia_gradient(params, handle_pose, probe_pose, probe_inertia, gradient):
    """gradient[k] = dM_d/dx_k by central differences (step INERTIA_FD_STEP)."""
    for k in range(3):
        for c in range(3):
            probe_pose[c] = handle_pose[c]
        probe_pose[k] = handle_pose[k] + INERTIA_FD_STEP
        if not task_inertia(params, probe_pose, probe_inertia):
            return False
        for a in range(3):
            for b in range(3):
                gradient[k, a, b] = probe_inertia[a, b]
        probe_pose[k] = handle_pose[k] - INERTIA_FD_STEP
        if not task_inertia(params, probe_pose, probe_inertia):
            return False
        for a in range(3):
            for b in range(3):
                gradient[k, a, b] = (gradient[k, a, b] - probe_inertia[a, b]) / (
                    2.0 * INERTIA_FD_STEP
                )
    return True


@njit(cache=True)
def christoffel_matrix(gradient, twist, coriolis):
    """C_d(x, xd) from the Christoffel symbols of M_d: C_ij = sum_k G_ijk xd_k with
    G_ijk = (dM_ij/dx_k + dM_ik/dx_j - dM_jk/dx_i) / 2. Unlike C = Mdot/2 this gives the
    true velocity-product forces, and Mdot - 2C is skew-symmetric."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += (gradient[k, i, j] + gradient[j, i, k] - gradient[i, j, k]) * twist[k]
            coriolis[i, j] = 0.5 * acc


@njit(cache=True)
def _solve_spd3(m, f):
    """Solve M a = f for a symmetric 3 x 3 M by Cholesky; ok is False if M is not SPD.
    m = (m00, m01, m02, m11, m12, m22), the upper triangle; f = (f0, f1, f2)."""
    m00, m01, m02, m11, m12, m22 = m
    f0, f1, f2 = f
    if m00 <= 0.0:
        return False, 0.0, 0.0, 0.0
    l00 = math.sqrt(m00)
    l10 = m01 / l00
    l20 = m02 / l00
    d11 = m11 - l10 * l10
    if d11 <= 0.0:
        return False, 0.0, 0.0, 0.0
    l11 = math.sqrt(d11)
    l21 = (m12 - l20 * l10) / l11
    d22 = m22 - l20 * l20 - l21 * l21
    if d22 <= 0.0:
        return False, 0.0, 0.0, 0.0
    l22 = math.sqrt(d22)
    y0 = f0 / l00
    y1 = (f1 - l10 * y0) / l11
    y2 = (f2 - l20 * y0 - l21 * y1) / l22
    a2 = y2 / l22
    a1 = (y1 - l21 * a2) / l11
    a0 = (y0 - l10 * a1 - l20 * a2) / l00
    return True, a0, a1, a2
