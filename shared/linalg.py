"""Small dense linear algebra for numba kernels, in place (no allocation)."""

from __future__ import annotations

import math

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
