"""A slider-crank driven by one animation variable (seed 003 §4; DESIGN-WAVE2 §5, V3.6).

A crank of length r turns about the origin (angle phi); a rod of length l joins the crank's
tip A = r (cos phi, sin phi) to a slider on the x axis at x_s = r cos phi + w,
w = sqrt(l^2 - r^2 sin^2 phi); the rod's angle is beta = -asin(r sin phi / l). The crank and
the rod are uniform bars (I = m L^2 / 12 about their centres), the slider a point mass. Its
world coordinates theta = (x_c, y_c, phi, x_r, y_r, beta, x_s) are closed-form functions of
the avar, with J = f' and Jd = f'' in closed form, and eq 5.1 (shared/avar.py) gives q''.

- Driven by the crank angle (q = phi, an immersion): J has phi' = 1, so M_q >= I_c > 0 and
  the crank turns through both dead centres (phi = 0, pi, where the slider stops).
- Driven by the slider position (q = x_s, phi on its upper branch [0, pi]): dphi/dx_s =
  1 / x_s'(phi) is unbounded at the dead centres, where x_s' = 0. The parametrisation is
  singular there, which `conditioning` finds when a scene loads (min M_q / max M_q over the
  domain < MIN_CONDITIONING) and which a scene must accept with allow_singular. At run time
  |x_s'| is floored at X_RATE_FLOOR and the term of phi'' in x_s'' / x_s'^3 is dropped there
  (J and Jd stay bounded), M_q below its floor is regularised (M_q + floor), a slider that
  would leave its stroke is stopped at its end, and every such step is flagged in the
  state's `singular` count: the slider stalls at the dead centre instead of passing it.
  Nothing becomes NaN.
"""

from __future__ import annotations

import enum
import math

import numpy as np
from numba import njit

from haptic_local_model.shared.avar import mass_weighted_rate, rk4_flagged

N_COORDS = 7
MIN_CONDITIONING = 1e-8  # DESIGN-WAVE2 §5: sigma_min(M_q) / sigma_max below this is singular
FLOOR_FRACTION = 1e-6  # the run-time regularisation eps = 1e-6 sigma_max
X_RATE_FLOOR = (
    1e-4  # |dx_s / dphi| (m/rad) floor of the slider-driven form (0.5 % of a 20 mm crank)
)
CONDITIONING_SAMPLES = 4001


class CrankDriver(enum.IntEnum):
    CRANK_ANGLE = 0
    SLIDER_POSITION = 1


CRANK_DTYPE = np.dtype(
    [
        ("driver", np.int64),  # CrankDriver
        ("crank_length", np.float64),  # r, m
        ("rod_length", np.float64),  # l > r, m
        ("mass", np.float64, (N_COORDS,)),  # diag M over theta
        ("gravity_force", np.float64, (N_COORDS,)),  # M g over theta, N (and 0 N m)
        ("floor", np.float64),  # M_q's regularisation (1e-6 of its median over the domain)
        ("pivot", np.float64, (2,)),  # the crank's pivot (world); the slider runs on its x axis
        ("jac", np.float64, (N_COORDS,)),  # scratch: J at the last evaluation
        ("bias", np.float64, (N_COORDS,)),  # scratch: Jd
        ("force", np.float64, (N_COORDS,)),  # scratch: tau
    ]
)


def crank_record(
    crank_length: float,
    rod_length: float,
    crank_mass: float,
    rod_mass: float,
    slider_mass: float,
    gravity: tuple[float, float],
    driver: CrankDriver,
    pivot: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """CRANK_DTYPE[1], its floor from the conditioning sweep."""
    if not 0.0 < crank_length < rod_length:
        raise ValueError(
            f"a slider-crank needs 0 < crank_length < rod_length, got {crank_length}, {rod_length}"
        )
    if not (crank_mass > 0.0 and rod_mass > 0.0 and slider_mass > 0.0):
        raise ValueError("the crank, the rod and the slider need mass > 0")
    c = np.zeros(1, dtype=CRANK_DTYPE)
    r = c[0]
    r["driver"] = int(driver)
    r["pivot"] = pivot
    r["crank_length"] = crank_length
    r["rod_length"] = rod_length
    i_c = crank_mass * crank_length**2 / 12.0
    i_r = rod_mass * rod_length**2 / 12.0
    r["mass"] = (crank_mass, crank_mass, i_c, rod_mass, rod_mass, i_r, slider_mass)
    gx, gy = gravity
    r["gravity_force"] = (
        crank_mass * gx,
        crank_mass * gy,
        0.0,
        rod_mass * gx,
        rod_mass * gy,
        0.0,
        slider_mass * gx,
    )
    r["floor"] = FLOOR_FRACTION * typical_mass_q(c)
    return c


def domain(c: np.ndarray) -> tuple[float, float]:
    """The avar's range: a turn of the crank, or the slider's stroke."""
    r = c[0]
    if r["driver"] == CrankDriver.CRANK_ANGLE:
        return 0.0, 2.0 * math.pi
    return r["rod_length"] - r["crank_length"], r["rod_length"] + r["crank_length"]


def _sweep(c: np.ndarray) -> np.ndarray:
    lo, hi = domain(c)
    return np.array([crank_mass_q(c, q) for q in np.linspace(lo, hi, CONDITIONING_SAMPLES)])


def conditioning(c: np.ndarray) -> float:
    """min M_q / max M_q over the avar's domain (sampled, ends included)."""
    m_q = _sweep(c)
    return float(m_q.min() / m_q.max()) if np.isfinite(m_q.max()) else 0.0


def typical_mass_q(c: np.ndarray) -> float:
    """The median M_q over the domain: the scale of the run-time regularisation (the largest
    is no scale where J is unbounded)."""
    return float(np.median(_sweep(c)))  # finite: only the stroke's ends are unbounded


def check_conditioning(c: np.ndarray, allow_singular: bool, where: str) -> None:
    """A scene-load check: a singular parametrisation is refused unless allowed."""
    ratio = conditioning(c)
    if ratio < MIN_CONDITIONING and not allow_singular:
        raise ValueError(
            f"{where}: the avar's M_q is singular over its domain (min/max {ratio:.3g} < "
            f"{MIN_CONDITIONING:g}); drive it by an immersion (the crank angle) or set "
            "allow_singular = true"
        )


def crank_mass_q(c: np.ndarray, q: float) -> float:
    """M_q = J^T M J at q, unregularised (Python; the conditioning sweep): inf where the
    slider-driven form's J is unbounded."""
    r = c[0]
    if r["driver"] == CrankDriver.CRANK_ANGLE:
        crank_angle_terms(r, q)
        return float(np.sum(r["jac"] ** 2 * r["mass"]))
    xs1, _ = crank_angle_terms(r, slider_angle(r, q))
    if xs1 == 0.0:
        return math.inf
    return float(np.sum(r["jac"] ** 2 * r["mass"])) / xs1**2


@njit(cache=True)
def crank_angle_terms(c, phi):
    """J and Jd of theta in phi into c.jac, c.bias; returns x_s' (dx_s / dphi) and x_s''."""
    r = c.crank_length
    sn = math.sin(phi)
    cs = math.cos(phi)
    w = math.sqrt(c.rod_length**2 - (r * sn) ** 2)
    w1 = -r * r * sn * cs / w
    w2 = (-r * r * math.cos(2.0 * phi) - w1 * w1) / w
    j = c.jac
    b = c.bias
    j[0] = -0.5 * r * sn
    b[0] = -0.5 * r * cs
    j[1] = 0.5 * r * cs
    b[1] = -0.5 * r * sn
    j[2] = 1.0
    b[2] = 0.0
    j[3] = -r * sn + 0.5 * w1
    b[3] = -r * cs + 0.5 * w2
    j[4] = 0.5 * r * cs
    b[4] = -0.5 * r * sn
    j[5] = -r * cs / w
    b[5] = (r * sn * w + r * cs * w1) / (w * w)
    j[6] = -r * sn + w1
    b[6] = -r * cs + w2
    return j[6], b[6]


@njit(cache=True)
def slider_angle(c, x):
    """phi on the upper branch [0, pi] for the slider at x (clamped to its stroke)."""
    r = c.crank_length
    rod = c.rod_length
    x = min(max(x, rod - r), rod + r)
    return math.acos(min(max((x * x + r * r - rod * rod) / (2.0 * x * r), -1.0), 1.0))


@njit(cache=True)
def crank_jacobian(c, q):
    """J and Jd in the driver's avar into c.jac, c.bias; returns whether J was clipped (the
    slider-driven form at a dead centre)."""
    if c.driver == CrankDriver.CRANK_ANGLE:
        crank_angle_terms(c, q)
        return False
    phi = slider_angle(c, q)
    xs1, xs2 = crank_angle_terms(c, phi)
    clipped = abs(xs1) < X_RATE_FLOOR
    if clipped:
        xs1 = -X_RATE_FLOOR  # on the upper branch x_s decreases with phi
    phi_x = 1.0 / xs1
    phi_xx = 0.0 if clipped else -xs2 * phi_x**3
    for i in range(N_COORDS):
        jac = c.jac[i]
        c.jac[i] = jac * phi_x
        c.bias[i] = jac * phi_xx + c.bias[i] * phi_x * phi_x
    return clipped


@njit(cache=True)
def crank_rate(c, q, qd, q_ext):
    """q'' (eq 5.1) under gravity and the generalised force q_ext (along q: a torque on the
    crank when it drives): (q'', singular)."""
    clipped = crank_jacobian(c, q)
    for i in range(N_COORDS):
        c.force[i] = c.gravity_force[i]
        c.bias[i] *= qd * qd
    qdd, m_q, singular = mass_weighted_rate(c.jac, c.bias, c.mass, c.force, N_COORDS, c.floor)
    return qdd + q_ext / m_q, singular or clipped


@njit(cache=True)
def crank_mass(c, q):
    """M_q = J^T M J at q (as regularised in the step)."""
    crank_jacobian(c, q)
    m_q = 0.0
    for i in range(N_COORDS):
        m_q += c.jac[i] * c.mass[i] * c.jac[i]
    return m_q + c.floor if m_q < c.floor else m_q


@njit(cache=True)
def crank_angle(c, q):
    """phi at q."""
    return q if c.driver == CrankDriver.CRANK_ANGLE else slider_angle(c, q)


@njit(cache=True)
def crank_body_pose(c, q, k):
    """Body k's frame at q: 0 the crank (at the pivot, along it), 1 the rod (at the crank's
    tip A, along it to the slider), 2 the slider (at the rod's end, unturned)."""
    phi = crank_angle(c, q)
    r = c.crank_length
    px = c.pivot[0]
    py = c.pivot[1]
    if k == 0:
        return px, py, phi
    sn = math.sin(phi)
    cs = math.cos(phi)
    if k == 1:
        return px + r * cs, py + r * sn, -math.asin(r * sn / c.rod_length)
    w = math.sqrt(c.rod_length**2 - (r * sn) ** 2)
    return px + r * cs + w, py, 0.0


@njit(cache=True)
def crank_body_rates(c, q, k):
    """Body k's frame velocity and angular velocity per unit q' (from J: A = 2 x the crank's
    centre)."""
    crank_jacobian(c, q)
    j = c.jac
    if k == 0:
        return 0.0, 0.0, j[2]
    if k == 1:
        return 2.0 * j[0], 2.0 * j[1], j[5]
    return j[6], 0.0, 0.0


@njit(cache=True)
def crank_energy(c, q, qd):
    """1/2 M_q q'^2 - sum m g . p (J)."""
    crank_jacobian(c, q)
    m_q = 0.0
    for i in range(N_COORDS):
        m_q += c.jac[i] * c.mass[i] * c.jac[i]
    phi = crank_angle(c, q)
    r = c.crank_length
    w = math.sqrt(c.rod_length**2 - (r * math.sin(phi)) ** 2)
    theta0 = 0.5 * r * math.cos(phi)
    theta1 = 0.5 * r * math.sin(phi)
    theta3 = r * math.cos(phi) + 0.5 * w
    theta6 = r * math.cos(phi) + w
    g = c.gravity_force
    potential = -(g[0] * theta0 + g[1] * theta1 + g[3] * theta3 + g[4] * theta1 + g[6] * theta6)
    return 0.5 * m_q * qd * qd + potential


_crank_rk4 = rk4_flagged(crank_rate)


@njit(cache=True)
def crank_step(c, st, q_ext, dt):
    """One RK4 step of dt with the generalised force held; a flagged step counts once."""
    st.s, st.sd, flagged = _crank_rk4(c, st.s, st.sd, q_ext, dt)
    if c.driver == CrankDriver.CRANK_ANGLE:  # the angle on [0, 2 pi): it turns for ever
        st.s = st.s % (2.0 * math.pi)
    if c.driver == CrankDriver.SLIDER_POSITION:
        lo = c.rod_length - c.crank_length
        hi = c.rod_length + c.crank_length
        if not lo <= st.s <= hi:
            st.s = min(max(st.s, lo), hi)
            st.sd = 0.0
            flagged = True
    if flagged:
        st.singular += 1
