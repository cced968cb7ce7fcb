"""Independent references for the avar dynamics (DESIGN-WAVE2 §5, V3.1 and V3.3).

Nothing here uses shared/track.py or shared/avar.py: the ellipse is the closed form
p(u) = c + (a sin u, -b cos u), s = 0 at its lowest point, counter-clockwise, and scipy's
DOP853 integrates at rtol 1e-11.

- `ellipse_car`: one car by Lagrange's equation in the ellipse's native parameter u (no
  arc length, no Jacobian, no pseudo-inverse): L = 1/2 (m |p_u|^2 + I psi_u^2) u'^2 - V(u).
- `ellipse_train`: n cars spaced l apart in arc length. The state carries each car's u_k
  (u_k' = s' / |p_u(u_k)|) and the common s'; the equation is the Lagrangian
  1/2 sum (m_k + I_k kappa_k^2) s'^2 - V in arc length, with kappa and kappa' in closed form
  in u. The cars' starting u_k come from inverting the arc length by `quad` + `brentq`.
- `crank_reference_mass`: a slider-crank's M(phi) = sum m |dp/dphi|^2 + I (dtheta/dphi)^2 of
  its uniform crank and rod and point slider, by central differences of the closed-form
  positions (none of shared/crank.py's Jacobians).
- `ellipse_car_seed_form`: seed 003's eq 8 as printed, q'' = J+ [M^-1 (tau - g) - Jd q'],
  with the unweighted left inverse J+ = (J^T J)^-1 J^T over theta = (x, y, psi): the
  documented wrong form, kept so a test shows it fails V3.1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

FloatArray = NDArray[np.float64]
RTOL = 1e-11
ATOL = 1e-13


@dataclass(frozen=True)
class Ellipse:
    """A vertical elliptic loop and the cars on it."""

    a: float
    b: float
    center: tuple[float, float] = (0.0, 0.0)
    mass: float = 0.05
    inertia: float = 2.0e-6
    gravity: tuple[float, float] = (0.0, -9.81)

    def point(self, u: FloatArray) -> FloatArray:
        """p(u), shape (..., 2)."""
        return np.stack(
            (self.center[0] + self.a * np.sin(u), self.center[1] - self.b * np.cos(u)), axis=-1
        )

    def _rho(self, u: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """|p_u|^2 and its first two derivatives in u."""
        a2, b2 = self.a**2, self.b**2
        return (
            a2 * np.cos(u) ** 2 + b2 * np.sin(u) ** 2,
            (b2 - a2) * np.sin(2.0 * u),
            2.0 * (b2 - a2) * np.cos(2.0 * u),
        )

    def heading_rates(self, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """psi_u = ab / rho and psi_uu."""
        rho, rho_u, _ = self._rho(u)
        ab = self.a * self.b
        return ab / rho, -ab * rho_u / rho**2

    def curvature(self, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """kappa and d kappa / ds."""
        rho, rho_u, _ = self._rho(u)
        ab = self.a * self.b
        return ab * rho**-1.5, -1.5 * ab * rho**-2.5 * rho_u / np.sqrt(rho)

    def arc_length(self, u: float) -> float:
        return float(quad(lambda v: np.sqrt(self._rho(v)[0]), 0.0, u, epsabs=1e-15, limit=200)[0])

    def u_at(self, s: float) -> float:
        """The u of arc length s (on one lap)."""
        perimeter = self.arc_length(2.0 * np.pi)
        s = s % perimeter
        return float(brentq(lambda u: self.arc_length(u) - s, 0.0, 2.0 * np.pi, xtol=1e-15))

    def potential(self, u: FloatArray) -> FloatArray:
        p = self.point(u)
        return -self.mass * (self.gravity[0] * p[..., 0] + self.gravity[1] * p[..., 1])


def ellipse_car(e: Ellipse, sd0: float, t_eval: FloatArray) -> tuple[FloatArray, FloatArray]:
    """One car from the bottom at speed sd0: (track points (n, 2), energy (n,))."""

    def rates(_t: float, y: FloatArray) -> list[float]:
        u, ud = y
        rho, rho_u, _ = e._rho(u)
        psi_u, psi_uu = e.heading_rates(u)
        mass_u = e.mass * rho + e.inertia * psi_u**2
        dmass_u = e.mass * rho_u + 2.0 * e.inertia * psi_u * psi_uu
        p_u = np.array([e.a * np.cos(u), e.b * np.sin(u)])
        force = e.mass * (e.gravity[0] * p_u[0] + e.gravity[1] * p_u[1])  # -dV/du
        return [ud, (force - 0.5 * dmass_u * ud * ud) / mass_u]

    return _from_bottom(e, rates, sd0, t_eval)


def _from_bottom(
    e: Ellipse, rates: Any, sd0: float, t_eval: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """One car's (u, u') equation from the bottom at speed sd0 (|p_u(0)| = a) by DOP853:
    its track points and its energy."""
    sol = solve_ivp(
        rates, (0.0, t_eval[-1]), [0.0, sd0 / e.a], "DOP853", t_eval, rtol=RTOL, atol=ATOL
    )
    u, ud = sol.y
    rho, _, _ = e._rho(u)
    psi_u, _ = e.heading_rates(u)
    energy = 0.5 * (e.mass * rho + e.inertia * psi_u**2) * ud**2 + e.potential(u)
    return e.point(u), energy


def ellipse_train(
    e: Ellipse, n_cars: int, spacing: float, sd0: float, t_eval: FloatArray, s0: float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """n cars, the lead one at arc length s0 (0: the bottom) at speed sd0, car k spacing*k
    behind it, from t_eval[0]: (the lead car's track points (n, 2), energy (n,))."""
    u0 = [e.u_at(s0 - k * spacing) for k in range(n_cars)]

    def rates(_t: float, y: FloatArray) -> FloatArray:
        u = y[:n_cars]
        sd = y[n_cars]
        rho, _, _ = e._rho(u)
        kappa, dkappa = e.curvature(u)
        tangent_y = e.b * np.sin(u) / np.sqrt(rho)
        tangent_x = e.a * np.cos(u) / np.sqrt(rho)
        num = np.sum(
            e.mass * (e.gravity[0] * tangent_x + e.gravity[1] * tangent_y)
            - e.inertia * kappa * dkappa * sd * sd
        )
        den = np.sum(e.mass + e.inertia * kappa**2)
        out = np.empty(n_cars + 1)
        out[:n_cars] = sd / np.sqrt(rho)
        out[n_cars] = num / den
        return out

    span = (t_eval[0], t_eval[-1])
    sol = solve_ivp(rates, span, [*u0, sd0], "DOP853", t_eval, rtol=RTOL, atol=ATOL)
    u = sol.y[:n_cars]
    sd = sol.y[n_cars]
    kappa, _ = e.curvature(u)
    energy = 0.5 * np.sum(e.mass + e.inertia * kappa**2, axis=0) * sd**2 + np.sum(
        e.potential(u), axis=0
    )
    return e.point(u[0]), energy


def ellipse_car_seed_form(
    e: Ellipse, sd0: float, t_eval: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """One car by seed 003's eq 8 as printed (module docstring): (track points, energy)."""

    def rates(_t: float, y: FloatArray) -> list[float]:
        u, ud = y
        psi_u, psi_uu = e.heading_rates(u)
        jac = np.array([e.a * np.cos(u), e.b * np.sin(u), psi_u])
        jd = np.array([-e.a * np.sin(u), e.b * np.cos(u), psi_uu]) * ud * ud
        accel = np.array([e.gravity[0], e.gravity[1], 0.0])  # M^-1 (tau - g) with tau = 0
        return [ud, float(jac @ (accel - jd) / (jac @ jac))]

    return _from_bottom(e, rates, sd0, t_eval)


def crank_reference_mass(
    crank_length: float,
    rod_length: float,
    crank_mass: float,
    rod_mass: float,
    slider_mass: float,
    phi: float,
    h: float = 1e-6,
) -> float:
    """M(phi) of a slider-crank (module docstring)."""
    r, rod = crank_length, rod_length

    def bodies(p: float) -> FloatArray:
        tip = np.array([r * np.cos(p), r * np.sin(p)])
        slider = np.array([tip[0] + np.sqrt(rod**2 - tip[1] ** 2), 0.0])
        rod_angle = np.arctan2(slider[1] - tip[1], slider[0] - tip[0])
        return np.array([*(tip / 2), p, *((tip + slider) / 2), rod_angle, slider[0]])

    rate = (bodies(phi + h) - bodies(phi - h)) / (2 * h)
    mass = np.array([
        crank_mass, crank_mass, crank_mass * r**2 / 12, rod_mass, rod_mass,
        rod_mass * rod**2 / 12, slider_mass,
    ])  # fmt: skip
    return float(np.sum(mass * rate**2))
