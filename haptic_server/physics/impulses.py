"""First-touch impulses (seed 001 eq 5-6, DESIGN-WAVE2 §6): a tick's colliding contacts
resolved together as a linear complementarity problem.

With R the colliding contacts' rows (n_i^T J_i over the world's q) and D its mass matrix,
A = R D^-1 R^T; the impulses lambda solve A lambda - b = w >= 0, lambda >= 0,
lambda . w = 0 with b = -(1 + e) v_n: every contact leaves at least at -e times its
approach, and one that would separate takes no impulse. A least-squares solution
(min |A lambda - b|, lambda >= 0) is not that: where one contact's impulse would lift
another off, it leaves a contact approaching (docs/grasp.md, a pad landing on two corners).
"""

from __future__ import annotations

from numba import njit

LCP_SWEEPS = 200  # projected Gauss-Seidel sweeps at most (it stops when converged)


@njit(cache=True)
def lcp(a, b, x, k):
    """x >= 0 with w = A x - b >= 0 and x . w = 0 (A = a[:k, :k], symmetric positive
    semi-definite with a positive diagonal, as R D^-1 R^T is): projected Gauss-Seidel from
    x = 0, until a sweep moves no x by more than 1e-12 of the largest (or LCP_SWEEPS)."""
    for i in range(k):
        x[i] = 0.0
    for _sweep in range(LCP_SWEEPS):
        change = 0.0
        size = 0.0
        for i in range(k):
            r = b[i]
            for j in range(k):
                r -= a[i, j] * x[j]
            new = max(0.0, x[i] + r / a[i, i])
            change = max(change, abs(new - x[i]))
            x[i] = new
            size = max(size, new)
        if change <= 1e-12 * size:
            return
