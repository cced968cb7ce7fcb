"""Chain kinematics against finite differences and the independent RNEA reference."""

from __future__ import annotations

import numpy as np

from haptic_local_model.shared.kinematics import (
    chain_record,
    free_body_chain,
    link_frames,
    mass_matrix_and_gravity,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.shared.reference import ChainSpec, bias_forces, mass_matrix

FD_STEP = 1e-7
FD_TOL = 1e-6  # central differences with h = 1e-7 on O(0.1 m) lever arms

SPEC = ChainSpec(
    base=(0.0, 0.0), lengths=(0.042, 0.042, 0.030), masses=(3.0, 3.0, 1.0),
    inertias=(0.015, 0.015, 0.005), com_offsets=((0.021, 0.0), (0.021, 0.002), (0.015, -0.001)),
    gravity=(0.0, -9.81),
)  # fmt: skip


CHAIN = chain_record(
    np.zeros(3, np.int64), np.array(SPEC.lengths), np.zeros(2), 0.0, np.array(SPEC.masses),
    np.array(SPEC.inertias), np.array(SPEC.com_offsets),
)[0]  # fmt: skip


def _pose(q: np.ndarray, link: int, r: np.ndarray) -> np.ndarray:
    pos, ang, out = np.zeros((3, 2)), np.zeros(3), np.zeros(2)
    link_frames(CHAIN, q, 3, pos, ang)
    point_on_link(pos, ang, link, r, out)
    return np.array([out[0], out[1], ang[link]])


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 3)
        r = rng.normal(scale=0.01, size=2)
        for link in range(3):
            pos, ang, jac = np.zeros((3, 2)), np.zeros(3), np.zeros((3, 3))
            link_frames(CHAIN, q, 3, pos, ang)
            p = _pose(q, link, r)
            point_jacobian(CHAIN, pos, 3, link, p[0], p[1], jac)
            for j in range(3):
                dq = np.zeros(3)
                dq[j] = FD_STEP
                fd = (_pose(q + dq, link, r) - _pose(q - dq, link, r)) / (2 * FD_STEP)
                np.testing.assert_allclose(jac[:, j], fd, atol=FD_TOL)


def test_mass_matrix_and_gravity_match_rnea_reference() -> None:
    """D(q) and G(q) by the Jacobian sum (DESIGN §2) against RNEA (shared/reference.py)."""
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 3)
        d, g = np.zeros((3, 3)), np.zeros(3)
        chain = chain_record(
            np.zeros(3, np.int64), np.array(SPEC.lengths), np.zeros(2), 0.0,
            np.array(SPEC.masses), np.array(SPEC.inertias), np.array(SPEC.com_offsets),
        )  # fmt: skip
        work = (np.zeros((3, 2)), np.zeros(3), np.zeros((3, 3)))
        mass_matrix_and_gravity(chain, np.array(SPEC.gravity), q, work, d, g)
        np.testing.assert_allclose(d, mass_matrix(SPEC, q), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(g, bias_forces(SPEC, q, np.zeros(3)), rtol=1e-12, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(d) > 0)


def test_free_body_chain_is_a_rigid_body() -> None:
    jt, lengths = free_body_chain()
    d, g = np.zeros((3, 3)), np.zeros(3)
    chain = chain_record(
        jt, lengths, np.zeros(2), 0.0, np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, 0.3]),
        np.zeros((3, 2)),
    )  # fmt: skip
    work = (np.zeros((3, 2)), np.zeros(3), np.zeros((3, 3)))
    mass_matrix_and_gravity(chain, np.array([0.0, -9.81]), np.array([0.3, -0.2, 1.0]), work, d, g)
    np.testing.assert_allclose(d, np.diag([2.0, 2.0, 0.3]))
    np.testing.assert_allclose(g, [0.0, 2.0 * 9.81, 0.0])
