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


JACOBI_SWEEPS = 64  # cyclic sweeps at most; 3 x 3 matrices converge in 4-6


@njit(cache=True)
def symmetric_eigen(a, n, values, vectors):
    """Eigenvalues (descending) and unit eigenvectors (the columns of `vectors`) of the
    symmetric n x n block of `a`, by cyclic Jacobi rotations in a fixed order: no LAPACK, so
    the same bits on every CPU (Golub & Van Loan §8.5). `a` is left as it was."""
    w = np.empty((n, n))
    scale = 0.0
    for i in range(n):
        for j in range(n):
            w[i, j] = a[i, j]
            vectors[i, j] = 1.0 if i == j else 0.0
            scale += a[i, j] * a[i, j]
    for _ in range(JACOBI_SWEEPS):
        off = 0.0
        for p in range(n):
            for q in range(p + 1, n):
                off += w[p, q] * w[p, q]
        if off <= 1e-32 * scale:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                if w[p, q] == 0.0:
                    continue
                theta = (w[q, q] - w[p, p]) / (2.0 * w[p, q])
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):  # w <- w J, then J^T w; vectors <- vectors J
                    wkp, wkq = w[k, p], w[k, q]
                    w[k, p] = c * wkp - s * wkq
                    w[k, q] = s * wkp + c * wkq
                for k in range(n):
                    wpk, wqk = w[p, k], w[q, k]
                    w[p, k] = c * wpk - s * wqk
                    w[q, k] = s * wpk + c * wqk
                for k in range(n):
                    vkp, vkq = vectors[k, p], vectors[k, q]
                    vectors[k, p] = c * vkp - s * vkq
                    vectors[k, q] = s * vkp + c * vkq
    for i in range(n):
        values[i] = w[i, i]
    for i in range(n):  # selection sort, descending, the vectors along
        best = i
        for j in range(i + 1, n):
            if values[j] > values[best]:
                best = j
        if best != i:
            values[i], values[best] = values[best], values[i]
            for k in range(n):
                vectors[k, i], vectors[k, best] = vectors[k, best], vectors[k, i]
