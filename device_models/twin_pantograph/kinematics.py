"""Exact kinematics of the twin pantograph (seed 001 §4): end points, motor IK, five-bar FK,
the motor Jacobian Jm and the singularity and workspace measures."""

from __future__ import annotations

import math

from numba import njit

from haptic_local_model.device_models.base import (
    FAULT_NONE,
    FAULT_SINGULAR,
    FAULT_WORKSPACE,
)

#: Tolerance below which a five-bar's proximal-distal cross product counts as zero (m^2).
_DEGENERATE_CROSS_M2 = 1e-12


@njit(cache=True)
def _end_point(p, k, handle_pose):
    """End point k (0: handle end a, 1: end b) and its derivative along theta."""
    half = 0.5 * p.handle_length if k == 1 else -0.5 * p.handle_length
    c = math.cos(handle_pose[2])
    s = math.sin(handle_pose[2])
    return handle_pose[0] + half * c, handle_pose[1] + half * s, -half * s, half * c


@njit(cache=True)
def _motor_ik(p, i, px, py):
    """Motor i's angle and elbow for end point (px, py) on its elbow branch."""
    bx = p.base[i, 0]
    by = p.base[i, 1]
    l1 = p.proximal_length[i]
    l2 = p.distal_length[i]
    vx = px - bx
    vy = py - by
    r = math.sqrt(vx * vx + vy * vy)
    if r == 0.0:
        return False, 0.0, bx, by
    cos_b = (l1 * l1 + r * r - l2 * l2) / (2.0 * l1 * r)
    if not (-1.0 <= cos_b <= 1.0):
        return False, 0.0, bx, by
    q = math.atan2(vy, vx) + p.elbow_sign[i] * math.acos(cos_b)
    return True, q, bx + l1 * math.cos(q), by + l1 * math.sin(q)


@njit(cache=True)
def _fivebar_end_point(p, k, q_first, q_second):
    """Exact FK of pantograph k: intersection of the distal-link circles on its branch."""
    i0 = 2 * k
    i1 = 2 * k + 1
    e0x = p.base[i0, 0] + p.proximal_length[i0] * math.cos(q_first)
    e0y = p.base[i0, 1] + p.proximal_length[i0] * math.sin(q_first)
    e1x = p.base[i1, 0] + p.proximal_length[i1] * math.cos(q_second)
    e1y = p.base[i1, 1] + p.proximal_length[i1] * math.sin(q_second)
    dx = e1x - e0x
    dy = e1y - e0y
    d = math.sqrt(dx * dx + dy * dy)
    if d == 0.0:
        return False, 0.0, 0.0
    r0 = p.distal_length[i0]
    r1 = p.distal_length[i1]
    a = (r0 * r0 - r1 * r1 + d * d) / (2.0 * d)
    h2 = r0 * r0 - a * a
    if h2 < 0.0:
        return False, 0.0, 0.0
    h = p.assembly_sign[k] * math.sqrt(h2)
    ux = dx / d
    uy = dy / d
    return True, e0x + a * ux - h * uy, e0y + a * uy + h * ux


@njit(cache=True)
def forward_kinematics(params, motor_angles, handle_pose):
    """Handle pose from the 4 motor angles; False if a pantograph cannot close.

    Over-determined: each pantograph's end point follows exactly from its two motors; the
    handle centre is their midpoint and theta the direction from end a to end b, which is
    exact for consistent angles and a least-squares-like blend for quantised ones.
    """
    p = params[0]
    ok_a, ax, ay = _fivebar_end_point(p, 0, motor_angles[0], motor_angles[1])
    ok_b, bx, by = _fivebar_end_point(p, 1, motor_angles[2], motor_angles[3])
    if not (ok_a and ok_b):
        return False
    handle_pose[0] = 0.5 * (ax + bx)
    handle_pose[1] = 0.5 * (ay + by)
    handle_pose[2] = math.atan2(by - ay, bx - ax)
    return True


@njit(cache=True)
def inverse_kinematics(params, handle_pose, motor_angles):
    """The 4 motor angles holding the handle at `handle_pose`; False if out of reach."""
    p = params[0]
    for i in range(4):
        px, py, _, _ = _end_point(p, i // 2, handle_pose)
        ok, q, _, _ = _motor_ik(p, i, px, py)
        if not ok:
            return False
        motor_angles[i] = q
    return True


@njit(cache=True)
def _jacobian_row(p, i, handle_pose):
    """Row i of Jm with the link geometry it came from (elbow, end point, dP/dtheta)."""
    px, py, dpx, dpy = _end_point(p, i // 2, handle_pose)
    ok, _, ex, ey = _motor_ik(p, i, px, py)
    # (E - B) x (P - E): zero when the proximal and distal links are collinear.
    cross = (ex - p.base[i, 0]) * (py - ey) - (ey - p.base[i, 1]) * (px - ex)
    if not ok or abs(cross) < _DEGENERATE_CROSS_M2:
        return False, 0.0, 0.0, 0.0, ex, ey, px, py, dpx, dpy
    gx = (px - ex) / cross
    gy = (py - ey) / cross
    return True, gx, gy, gx * dpx + gy * dpy, ex, ey, px, py, dpx, dpy


@njit(cache=True)
def motor_jacobian(params, handle_pose, jacobian):
    """Jm = d(motor angles)/d(handle pose), 4 x 3, from |P - E_i| = l2 differentiated.

    (P - E)·(dP - dE) = 0 with dE = perp(E - B) dq gives dq = (P - E)·dP / ((E - B) x (P - E)).
    The handle wrench of motor torques is W = Jm^T tau (virtual work).
    """
    p = params[0]
    for i in range(4):
        ok, j0, j1, j2, _, _, _, _, _, _ = _jacobian_row(p, i, handle_pose)
        if not ok:
            return False
        jacobian[i, 0] = j0
        jacobian[i, 1] = j1
        jacobian[i, 2] = j2
    return True


@njit(cache=True)
def torques_to_wrench(jacobian, motor_torques, wrench):
    """Handle wrench W = Jm^T tau produced by motor torques (3 x 4 map A = Jm^T)."""
    for c in range(3):
        acc = 0.0
        for i in range(4):
            acc += jacobian[i, c] * motor_torques[i]
        wrench[c] = acc


@njit(cache=True)
def singularity_measures(params, handle_pose, measures):
    """measures[0]: smallest |sine| between a pantograph's distal links (0 = collinear).
    measures[1]: smallest distance (m) of an end point from its motors' reach annulus
    boundary (negative outside). Returns False if the pose is out of reach."""
    p = params[0]
    reach = math.inf
    for i in range(4):
        px, py, _, _ = _end_point(p, i // 2, handle_pose)
        r = math.hypot(px - p.base[i, 0], py - p.base[i, 1])
        l1 = p.proximal_length[i]
        l2 = p.distal_length[i]
        reach = min(reach, r - abs(l1 - l2), l1 + l2 - r)
    measures[1] = reach
    measures[0] = 0.0
    if reach < 0.0:
        return False
    sine = math.inf
    for k in range(2):
        px, py, _, _ = _end_point(p, k, handle_pose)
        _, _, e0x, e0y = _motor_ik(p, 2 * k, px, py)
        _, _, e1x, e1y = _motor_ik(p, 2 * k + 1, px, py)
        cross = (px - e0x) * (py - e1y) - (py - e0y) * (px - e1x)
        sine = min(sine, abs(cross) / (p.distal_length[2 * k] * p.distal_length[2 * k + 1]))
    measures[0] = sine
    return True


@njit(cache=True)
def pose_faults(params, handle_pose, measures):
    """FAULT_WORKSPACE outside the box or near the reach limits, FAULT_SINGULAR when a
    pantograph's distal links are near collinear (parallel singularity)."""
    p = params[0]
    fault = FAULT_NONE
    for c in range(3):
        if not (p.workspace_min[c] <= handle_pose[c] <= p.workspace_max[c]):
            fault |= FAULT_WORKSPACE
    if not singularity_measures(params, handle_pose, measures):
        return fault | FAULT_WORKSPACE | FAULT_SINGULAR
    if measures[1] < p.reach_margin:
        fault |= FAULT_WORKSPACE
    if measures[0] < p.min_distal_sine:
        fault |= FAULT_SINGULAR
    return fault
