"""High-accuracy reference dynamics for a grounded planar serial linkage with revolute joints.

This module is deliberately independent of the real-time simulator: it uses the recursive
Newton-Euler algorithm (RNEA) in world coordinates, builds the mass matrix column by column
from RNEA, and integrates with a tight-tolerance scipy ODE solver. Use it to check the simulator.

Conventions (SI): absolute link angle phi_i = base_angle + sum_{j<=i} q_j, joint positions
p_0 = base and p_{i+1} = p_i + l_i (cos phi_i, sin phi_i), link-frame vectors are rotated by
R(phi_i), and the equations of motion read D(q) qdd + bias(q, qd) = tau.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import OdeSolution, solve_ivp

FloatArray = NDArray[np.float64]
WrenchFunction = Callable[[float, FloatArray, FloatArray], ArrayLike]


@dataclass(frozen=True)
class ChainSpec:
    """Geometry and inertia of a planar chain of revolute joints; per-link tuples are ordered
    base to tip. A tree when `parents` is given: link i hangs from the tip of link
    parents[i] (-1: the base), every parent before its child."""

    base: tuple[float, float]
    lengths: tuple[float, ...]
    masses: tuple[float, ...]
    inertias: tuple[float, ...]
    com_offsets: tuple[tuple[float, float], ...]
    gravity: tuple[float, float] = (0.0, 0.0)
    base_angle: float = 0.0
    parents: tuple[int, ...] = ()  # empty: serial

    def __post_init__(self) -> None:
        n = len(self.lengths)
        if n == 0:
            raise ValueError("chain needs at least one link")
        if self.parents and (
            len(self.parents) != n or any(not -1 <= p < i for i, p in enumerate(self.parents))
        ):
            raise ValueError("parents needs one entry per link, each -1 or an earlier link")
        if not (len(self.masses) == len(self.inertias) == len(self.com_offsets) == n):
            raise ValueError("lengths, masses, inertias and com_offsets must have equal length")
        if any(m <= 0.0 for m in self.masses) or any(i < 0.0 for i in self.inertias):
            raise ValueError("masses must be positive and inertias non-negative")

    @property
    def n(self) -> int:
        """Number of links (and joints)."""
        return len(self.lengths)

    def parent(self, i: int) -> int:
        """The link link i hangs from (-1: the base)."""
        return self.parents[i] if self.parents else i - 1

    def moved_by(self, link: int) -> list[int]:
        """The joints that move `link`: it and its ancestors."""
        out = []
        while link >= 0:
            out.append(link)
            link = self.parent(link)
        return sorted(out)


def _rot(phi: float) -> FloatArray:
    """Planar rotation matrix R(phi)."""
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s], [s, c]])


def _perp(v: FloatArray) -> FloatArray:
    """Return e_z x v for a planar vector v (rotation by +90 degrees)."""
    return np.array([-v[1], v[0]])


def _cross(a: FloatArray, b: FloatArray) -> float:
    """Scalar z-component of the planar cross product a x b."""
    return float(a[0] * b[1] - a[1] * b[0])


def _rooted_sum(spec: ChainSpec, root: float, x: FloatArray) -> FloatArray:
    """y_i = y_parent(i) + x_i (root for the base): angles, rates, accelerations of links."""
    y = np.empty(spec.n)
    for i in range(spec.n):
        p = spec.parent(i)
        y[i] = (root if p < 0 else y[p]) + x[i]
    return y


def _link_angles(spec: ChainSpec, q: FloatArray) -> FloatArray:
    """Absolute link angles phi_i = phi_parent + q_i (base_angle for a root)."""
    return _rooted_sum(spec, spec.base_angle, q)


def _link_vectors(spec: ChainSpec, phi: FloatArray) -> FloatArray:
    """Each link's pivot-to-tip vector (n, 2)."""
    lengths = np.asarray(spec.lengths, dtype=float)
    return lengths[:, None] * np.column_stack((np.cos(phi), np.sin(phi)))


def _joint_positions(spec: ChainSpec, phi: FloatArray) -> FloatArray:
    """The pivot of every link (n rows): its parent's tip, or the base."""
    steps = _link_vectors(spec, phi)
    pivots = np.empty((spec.n, 2))
    for i in range(spec.n):
        p = spec.parent(i)
        pivots[i] = np.asarray(spec.base, float) if p < 0 else pivots[p] + steps[p]
    return pivots


def _as_vector(x: ArrayLike, n: int, name: str) -> FloatArray:
    """Convert x to a float vector of length n, failing loudly on a shape mismatch."""
    v = np.asarray(x, dtype=float).reshape(-1)
    if v.shape != (n,):
        raise ValueError(f"{name} must have {n} entries, got shape {np.shape(x)}")
    return v


def inverse_dynamics(
    spec: ChainSpec, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, *, with_gravity: bool = True
) -> FloatArray:
    """Joint torques tau = D qdd + C qd + G from the planar recursive Newton-Euler algorithm.

    Gravity enters as a fictitious base acceleration -g, so every link feels m_i g at its COM.
    """
    n = spec.n
    q, qd, qdd = (_as_vector(x, n, name) for x, name in ((q, "q"), (qd, "qd"), (qdd, "qdd")))
    phi = _link_angles(spec, q)
    omega = _rooted_sum(spec, 0.0, qd)
    alpha = _rooted_sum(spec, 0.0, qdd)
    link_vec = _link_vectors(spec, phi)
    com_vec = np.array([_rot(phi[i]) @ np.asarray(spec.com_offsets[i], float) for i in range(n)])

    gravity = np.asarray(spec.gravity, dtype=float) if with_gravity else np.zeros(2)
    tip_acc = np.empty((n, 2))  # each link's tip, where its children hang
    com_acc = np.empty((n, 2))
    for i in range(n):
        p = spec.parent(i)
        pivot_acc = -gravity if p < 0 else tip_acc[p]
        com_acc[i] = pivot_acc + alpha[i] * _perp(com_vec[i]) - omega[i] ** 2 * com_vec[i]
        tip_acc[i] = pivot_acc + alpha[i] * _perp(link_vec[i]) - omega[i] ** 2 * link_vec[i]

    # backwards: each link passes the force and moment (about its pivot) it transmits to
    # its parent's tip; a link sums its children's
    force_out = np.zeros((n, 2))
    moment_out = np.zeros(n)
    tau = np.empty(n)
    for i in reversed(range(n)):
        inertial_force = spec.masses[i] * com_acc[i]
        force_in = inertial_force + force_out[i]
        moment_in = (
            spec.inertias[i] * alpha[i]
            + _cross(com_vec[i], inertial_force)
            + _cross(link_vec[i], force_out[i])
            + moment_out[i]
        )
        tau[i] = moment_in
        p = spec.parent(i)
        if p >= 0:
            force_out[p] += force_in
            moment_out[p] += moment_in
    return tau


def mass_matrix(spec: ChainSpec, q: ArrayLike) -> FloatArray:
    """Joint-space mass matrix D(q), column j = RNEA with qdd = e_j, zero velocity and gravity."""
    n = spec.n
    zeros = np.zeros(n)
    return np.column_stack(
        [inverse_dynamics(spec, q, zeros, np.eye(n)[j], with_gravity=False) for j in range(n)]
    )


def bias_forces(spec: ChainSpec, q: ArrayLike, qd: ArrayLike) -> FloatArray:
    """Coriolis/centripetal plus gravity torques C(q, qd) qd + G(q): RNEA with qdd = 0."""
    return inverse_dynamics(spec, q, qd, np.zeros(spec.n))


def point_pose(spec: ChainSpec, q: ArrayLike, link: int, r: ArrayLike) -> FloatArray:
    """Pose (x, y, phi_link) of the point given by link-frame vector r on link `link` (0-based)."""
    q = _as_vector(q, spec.n, "q")
    _check_link(spec, link)
    phi = _link_angles(spec, q)
    pivot = _joint_positions(spec, phi)[link]
    point = pivot + _rot(phi[link]) @ _as_vector(r, 2, "r")
    return np.array([point[0], point[1], phi[link]])


def point_jacobian(spec: ChainSpec, q: ArrayLike, link: int, r: ArrayLike) -> FloatArray:
    """Analytic 3 x n Jacobian of (x, y, phi_link) of point r on link `link`.

    Joint j that moves the link rotates the point about pivot p_j: column j =
    (e_z x (P - p_j), 1).
    """
    q = _as_vector(q, spec.n, "q")
    _check_link(spec, link)
    phi = _link_angles(spec, q)
    joint_pos = _joint_positions(spec, phi)
    point = joint_pos[link] + _rot(phi[link]) @ _as_vector(r, 2, "r")
    jac = np.zeros((3, spec.n))
    for j in spec.moved_by(link):
        jac[:2, j] = _perp(point - joint_pos[j])
        jac[2, j] = 1.0
    return jac


def forward_dynamics(spec: ChainSpec, q: ArrayLike, qd: ArrayLike, tau: ArrayLike) -> FloatArray:
    """Joint accelerations qdd solving D(q) qdd = tau - bias(q, qd) (Cholesky, D is SPD)."""
    rhs = _as_vector(tau, spec.n, "tau") - bias_forces(spec, q, qd)
    chol = np.linalg.cholesky(mass_matrix(spec, q))
    return np.linalg.solve(chol.T, np.linalg.solve(chol, rhs))


def _check_link(spec: ChainSpec, link: int) -> None:
    """Reject link indices outside 0..n-1."""
    if not 0 <= link < spec.n:
        raise IndexError(f"link {link} out of range for a {spec.n}-link chain")


@dataclass(frozen=True, eq=False)
class ReferenceSolution:
    """Sampled reference trajectory; pose rows are point_pose of the hand point at each t."""

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    pose: FloatArray
    spec: ChainSpec = field(repr=False)
    link: int = field(repr=False)
    r: FloatArray = field(repr=False)
    dense: OdeSolution = field(repr=False)

    def pose_at(self, t: ArrayLike) -> FloatArray:
        """Hand-point pose at time(s) t from the solver's dense output: shape (3,) or (len(t), 3).

        Only times inside the integrated interval are accepted; extrapolation is refused.
        """
        times = np.asarray(t, dtype=float)
        t0, t1 = self.dense.t_min, self.dense.t_max
        if np.any(times < t0) or np.any(times > t1):
            raise ValueError(f"pose_at only covers [{t0}, {t1}]")
        n = self.spec.n
        states = np.atleast_2d(np.asarray(self.dense(times.reshape(-1))).T)
        poses = np.array([point_pose(self.spec, s[:n], self.link, self.r) for s in states])
        return poses[0] if times.ndim == 0 else poses.reshape(*times.shape, 3)


@dataclass(frozen=True)
class Hold:
    """Where and how the hand holds the chain: a wrench (fx, fy, tau) at `point` (in the
    frame of `link`): a constant 3-vector, or a callable f(t, q, qd) returning one."""

    wrench: ArrayLike | WrenchFunction
    link: int
    point: ArrayLike


@dataclass(frozen=True)
class Integrator:
    """solve_ivp's method and tolerances (tight: this is the reference)."""

    method: str = "DOP853"
    rtol: float = 1e-10
    atol: float = 1e-12

    def states(
        self, rhs: Callable[[float, FloatArray], FloatArray], s0: FloatArray, t_end: float,
        t_eval: ArrayLike, what: str,
    ) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        """(t, states at t) of rhs integrated from s0 to t_end; RuntimeError naming `what`."""
        times = np.asarray(t_eval, dtype=float)
        result = solve_ivp(
            rhs, (0.0, float(t_end)), s0, method=self.method, t_eval=times,
            rtol=self.rtol, atol=self.atol,
        )  # fmt: skip
        if not result.success:
            raise RuntimeError(f"{what} failed: {result.message}")
        return result.t, result.y.T


def simulate(
    spec: ChainSpec,
    q0: ArrayLike,
    qd0: ArrayLike,
    hold: Hold,
    t_end: float,
    t_eval: ArrayLike | None,
    *,
    integrator: Integrator = Integrator(),
    damping: ArrayLike | None = None,
) -> ReferenceSolution:
    """Integrate the chain from t = 0 to t_end under the hand's wrench at its hold.

    The wrench maps to joints through J_h(q)^T; optional viscous joint damping adds -b * qd.
    """
    n = spec.n
    hand_wrench, link, r = hold.wrench, hold.link, hold.point
    _check_link(spec, link)
    r_vec = _as_vector(r, 2, "r")
    state0 = np.concatenate((_as_vector(q0, n, "q0"), _as_vector(qd0, n, "qd0")))
    b = np.zeros(n) if damping is None else _as_vector(damping, n, "damping")

    if callable(hand_wrench):
        wrench_fn = hand_wrench
    else:
        constant_wrench = _as_vector(hand_wrench, 3, "hand_wrench")

        def wrench_fn(t: float, q: FloatArray, qd: FloatArray) -> ArrayLike:
            return constant_wrench

    def rhs(t: float, state: FloatArray) -> FloatArray:
        q, qd = state[:n], state[n:]
        wrench = _as_vector(wrench_fn(t, q, qd), 3, "hand_wrench(t, q, qd)")
        tau = point_jacobian(spec, q, link, r_vec).T @ wrench - b * qd
        return np.concatenate((qd, forward_dynamics(spec, q, qd, tau)))

    result = solve_ivp(
        rhs,
        (0.0, float(t_end)),
        state0,
        method=integrator.method,
        t_eval=None if t_eval is None else np.asarray(t_eval, dtype=float),
        dense_output=True,
        rtol=integrator.rtol,
        atol=integrator.atol,
    )
    if not result.success:
        raise RuntimeError(f"reference integration failed: {result.message}")

    q_samples = np.ascontiguousarray(result.y[:n].T)
    qd_samples = np.ascontiguousarray(result.y[n:].T)
    pose = np.array([point_pose(spec, qi, link, r_vec) for qi in q_samples]).reshape(-1, 3)
    return ReferenceSolution(
        t=result.t,
        q=q_samples,
        qd=qd_samples,
        pose=pose,
        spec=spec,
        link=link,
        r=r_vec,
        dense=result.sol,
    )
