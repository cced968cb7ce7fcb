"""How many sim substeps the stiff tool-device coupling of virtual_coupling_foh needs.

The sim applies f = K (x_dev - x_tool) - B v_tool to the tool once per pymunk substep h,
and pymunk integrates by semi-implicit Euler (v += h f / m, then x += h v). For one axis of
m xdd = -K x - B xd that map has the characteristic polynomial

    lambda^2 - (2 - beta - kappa) lambda + (1 - beta),  beta = h B / m,  kappa = h^2 K / m,

whose roots lie inside the unit circle iff beta < 2 and kappa + 2 beta < 4, i.e. iff
h < h_max = (sqrt(B^2 + 4 K m) - B) / K (the second condition implies the first). With seed
002's gains on a light planar tool the damping dominates: h_max ~ 2 m / B (for B = 1e4 N s/m
and m = 3 kg, 0.6 ms). Scenes must use h <= h_max / 2, so that beta <= 1 when the damping
dominates: one substep of the damper never reverses the tool's velocity.
"""

from __future__ import annotations

import math

#: Scenes use at most this fraction of the stability limit h_max.
SUBSTEP_MARGIN = 0.5


def stable_step_limit(mass: float, stiffness: float, damping: float) -> float:
    """h_max of semi-implicit Euler for m xdd = -K x - B xd (s); inf without K and B."""
    if stiffness <= 0.0:
        return 2.0 * mass / damping if damping > 0.0 else math.inf
    return (math.sqrt(damping * damping + 4.0 * stiffness * mass) - damping) / stiffness


def box_moment(mass: float, width: float, height: float) -> float:
    """Moment of a box about its centre (pymunk.moment_for_box)."""
    return mass * (width * width + height * height) / 12.0


def circle_moment(mass: float, radius: float) -> float:
    """Moment of a solid disc about its centre: pymunk.moment_for_circle(m, 0, r), bit for
    bit (Chipmunk's cpMomentForCircle, its order of operations)."""
    return mass * (0.5 * (0.0 * 0.0 + radius * radius) + 0.0)


def segment_moment(
    mass: float, a: tuple[float, float], b: tuple[float, float], radius: float
) -> float:
    """Moment of a capsule segment about the body origin: pymunk.moment_for_segment, bit
    for bit (Chipmunk's cpMomentForSegment, its order of operations)."""
    mid_x, mid_y = a[0] * 0.5 + b[0] * 0.5, a[1] * 0.5 + b[1] * 0.5
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = math.sqrt(dx * dx + dy * dy) + 2.0 * radius
    offset_sq = mid_x * mid_x + mid_y * mid_y
    return mass * ((length * length + 4.0 * radius * radius) / 12.0 + offset_sq)


NO_STABLE_STEP = 2**62  # coupling_substeps' answer when no step is stable


def coupling_substeps(
    sim_rate_hz: float,
    mass: float,
    moment: float,
    point: tuple[float, float],
    stiffness: tuple[float, float, float],
    damping: tuple[float, float, float],
) -> tuple[int, float]:
    """Least substeps per sim period for the coupling of a free body held at `point` (body
    frame, from its centre of mass), and the step limit h_max (s) that sets it.

    Along x and y the spring sees the body's effective mass at the point,
    1 / (1/m + |r|^2 / I) (the lightest direction); the angle sees I.
    """
    r2 = point[0] ** 2 + point[1] ** 2
    m_eff = 1.0 / (1.0 / mass + r2 / moment)
    h_max = min(
        stable_step_limit(m_eff, stiffness[0], damping[0]),
        stable_step_limit(m_eff, stiffness[1], damping[1]),
        stable_step_limit(moment, stiffness[2], damping[2]),
    )
    if not math.isfinite(h_max):
        return 1, h_max
    if not h_max > 0.0:  # no step is stable (an effective mass or a gain out of range)
        return NO_STABLE_STEP, h_max
    return max(1, math.ceil(1.0 / (sim_rate_hz * SUBSTEP_MARGIN * h_max))), h_max
