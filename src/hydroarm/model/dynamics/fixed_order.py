"""Small dense algebra in a fixed order of operations: the same inputs give the same bits on
any x86-64 machine.

NumPy's ``@``, ``np.dot``, ``np.linalg`` and numba's ``np.dot`` go through BLAS / LAPACK, whose
kernels (OpenBLAS picks one per CPU: Haswell, SkylakeX, Sandybridge, ...) sum in different
orders; NumPy's ``np.exp`` and ``einsum`` pick SIMD variants per CPU. In a closed loop that
amplifies last-bit differences (a learner's accept / reject test, a chaotic plant) the results
then depend on the machine (issue 29, docs/data/reproducibility.md). The functions here are
plain loops compiled by numba without ``fastmath`` (no reassociation, no contraction into FMA:
LLVM keeps the source order), summing in index order; ``math.exp`` is one libm call per
element. Sizes are those of an arm (n <= ~20): BLAS gains nothing there. The Cholesky
functions are inlined into their callers (``inline="always"``): called from the vehicle's
compiled step they cost about 1 us of its 43 us otherwise (bench_side_by_side.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "exp",
    "matvec",
    "matmul",
    "cholesky_factor",
    "forward_substitute",
    "cholesky_substitute",
    "cholesky_solve",
    "cholesky_solve_into",
    "spd_solve",
    "symmetrize",
]


@numba.njit(cache=True)
def symmetrize(upper):  # pragma: no cover - compiled
    """The symmetric matrix (n, n) whose upper triangle is ``upper``'s (its strict lower triangle
    is not read): what Pinocchio's CRBA and ABA derivatives leave in the workspace (M, M^-1).
    Exact: each entry plus an exact zero, as ``np.triu(upper) + np.triu(upper, 1).T`` gives it
    (a -0.0 becomes +0.0), bit for bit (a test), at about a fifteenth of that expression's cost
    (two ``np.triu`` calls: about 10 us for 6 x 6 on a quiet machine)."""
    n = upper.shape[0]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            value = upper[i, j] + 0.0
            out[i, j] = value
            out[j, i] = value
    return out


@numba.njit(cache=True)
def exp(x):  # pragma: no cover - compiled
    """Elementwise exp of a 1-D array by scalar libm calls (NumPy's SIMD exp differs per CPU)."""
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        out[i] = math.exp(x[i])
    return out


@numba.njit(cache=True)
def matvec(a, x):  # pragma: no cover - compiled
    """``a @ x`` for a (m, n), x (n,): each entry summed in column order."""
    m, n = a.shape
    out = np.empty(m)
    for i in range(m):
        s = 0.0
        for j in range(n):
            s += a[i, j] * x[j]
        out[i] = s
    return out


@numba.njit(cache=True)
def matmul(a, b):  # pragma: no cover - compiled
    """``a @ b`` for a (m, k), b (k, n): each entry summed in k order."""
    m, k = a.shape
    n = b.shape[1]
    out = np.empty((m, n))
    for i in range(m):
        for j in range(n):
            s = 0.0
            for p in range(k):
                s += a[i, p] * b[p, j]
            out[i, j] = s
    return out


@numba.njit(cache=True, inline="always")
def cholesky_factor(a, chol, shift=0.0, floor=0.0):  # pragma: no cover - compiled
    """The lower Cholesky factor L of ``a + shift I`` (a (n, n) symmetric, its lower triangle
    read) into the lower triangle of ``chol`` (n, n; ``a`` itself for a factor in place: each
    entry is read before it is written; the strict upper triangle is left as it was). Column by
    column, each entry's sum in index order. Returns False (``chol`` partly written) at the first
    pivot not above ``floor`` times its diagonal entry ``a[j, j] + shift`` (0 by default: not
    positive), or NaN."""
    n = a.shape[0]
    for j in range(n):
        diagonal = a[j, j] + shift
        s = diagonal
        for p in range(j):
            s -= chol[j, p] * chol[j, p]
        limit = floor * diagonal if floor != 0.0 else 0.0
        if not s > limit:
            return False
        pivot = math.sqrt(s)
        chol[j, j] = pivot
        for i in range(j + 1, n):
            s = a[i, j]
            for p in range(j):
                s -= chol[i, p] * chol[j, p]
            chol[i, j] = s / pivot
    return True


@numba.njit(cache=True, inline="always")
def forward_substitute(chol, b, x):  # pragma: no cover - compiled
    """x (n,) = L^-1 b for b (n,), L the lower triangle of ``chol`` (n, n), row by row, each sum in
    index order (b and x may be strided views; x may be b)."""
    n = chol.shape[0]
    for i in range(n):
        s = b[i]
        for p in range(i):
            s -= chol[i, p] * x[p]
        x[i] = s / chol[i, i]


@numba.njit(cache=True, inline="always")
def cholesky_substitute(chol, b, x):  # pragma: no cover - compiled
    """x (n,) = (L L^T)^-1 b for b (n,), L the lower triangle of ``chol`` (:func:`cholesky_factor`):
    L z = b forward (:func:`forward_substitute`), then L^T x = z backward, into ``x`` (b and x may
    be strided views; x may be b)."""
    n = chol.shape[0]
    forward_substitute(chol, b, x)
    for i in range(n - 1, -1, -1):
        s = x[i]
        for p in range(i + 1, n):
            s -= chol[p, i] * x[p]
        x[i] = s / chol[i, i]


@numba.njit(cache=True)
def cholesky_solve(a, b):  # pragma: no cover - compiled
    """``(x, ok)``: x = a^-1 b for a symmetric positive definite (n, n) and b (n,) or (n, k),
    by the Cholesky factor a = L L^T (lower triangle of a read) and two triangular solves.
    ``ok`` False (x undefined) if a pivot is not > 0."""
    n = a.shape[0]
    rhs = b.reshape(n, -1)
    k = rhs.shape[1]
    chol = np.zeros((n, n))
    if not cholesky_factor(a, chol):
        return np.full(b.shape, np.nan), False
    x = np.empty((n, k))
    for c in range(k):
        cholesky_substitute(chol, rhs[:, c], x[:, c])
    return x.reshape(b.shape), True


@numba.njit(cache=True, inline="always")
def cholesky_solve_into(a, b, out):  # pragma: no cover - compiled
    """out (n,) = a^-1 b for a symmetric positive definite (n, n) overwritten by its factor (lower
    triangle) and b (n,): :func:`cholesky_solve` without allocating (the compiled plants' inner
    loop). Returns ok; when a pivot is not > 0, ``out`` is all NaN (a diverging state)."""
    if not cholesky_factor(a, a):
        out[:] = np.nan
        return False
    cholesky_substitute(a, b, out)
    return True


def spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` (n,) or (n, k) for a symmetric positive definite ``a`` (n, n) (a mass matrix, or a
    principal block of one): :func:`cholesky_solve` on contiguous copies, the same bits on any
    machine; LAPACK's ``np.linalg.solve`` only where the factor fails (a state no longer finite,
    where the bits no longer matter)."""
    x, ok = cholesky_solve(np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float))
    return x if ok else np.linalg.solve(a, b)
