"""Small dense linear algebra for numba kernels, in place (no allocation)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def cholesky_inplace(a, n, out):
    """Lower Cholesky factor of the SPD n x n block of `a` into `out`; False if not SPD."""
    for i in range(n):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= out[i, k] * out[j, k]
            if i == j:
                if s <= 0.0:
                    return False
                out[i, i] = math.sqrt(s)
            else:
                out[i, j] = s / out[j, j]
        for j in range(i + 1, n):
            out[i, j] = 0.0
    return True


@njit(cache=True)
def cholesky_solve(chol, n, b, x):
    """Solve (L L^T) x = b for x (b and x may alias)."""
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= chol[i, k] * x[k]
        x[i] = s / chol[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= chol[k, i] * x[k]
        x[i] = s / chol[i, i]


@njit(cache=True)
def min_norm_least_squares(a, m, n, b, x):
    """x (n) minimising |A x - b| with the least |x|, for the m x n block of `a`, by the
    normal equations in a fixed order (no LAPACK: the same bits on every CPU). For the small,
    well-conditioned Jacobians it serves (re-initialisation) that is accurate to ~1e-12.

    n <= m: x = (A^T A)^-1 A^T b; n > m: x = A^T (A A^T)^-1 b. A rank-deficient A gets
    eps I added to the Gram matrix, eps a 1e-12 fraction of its mean diagonal: the minimum
    norm solution up to that fraction. False (x zero) if A is zero or not finite."""
    k = min(m, n)
    gram = np.zeros((k, k))
    chol = np.zeros((k, k))
    rhs = np.zeros(k)
    for i in range(k):
        for j in range(k):
            s = 0.0
            if n <= m:
                for r in range(m):
                    s += a[r, i] * a[r, j]
            else:
                for c in range(n):
                    s += a[i, c] * a[j, c]
            gram[i, j] = s
        if n <= m:
            s = 0.0
            for r in range(m):
                s += a[r, i] * b[r]
            rhs[i] = s
        else:
            rhs[i] = b[i]
    trace = 0.0
    for i in range(k):
        trace += gram[i, i]
    for c in range(n):
        x[c] = 0.0
    if not (trace > 0.0 and math.isfinite(trace)):
        return False
    if not cholesky_inplace(gram, k, chol):
        for i in range(k):
            gram[i, i] += 1e-12 * trace / k
        if not cholesky_inplace(gram, k, chol):
            return False
    cholesky_solve(chol, k, rhs, rhs)
    if n <= m:
        for c in range(n):
            x[c] = rhs[c]
    else:
        for c in range(n):
            s = 0.0
            for r in range(m):
                s += a[r, c] * rhs[r]
            x[c] = s
    return True
