"""Compiled (numba) kernels of the stacked GP evaluation: the same algebra as the NumPy
functions of `_batched` (`_evaluate_numpy`, `_predict_with_factor_numpy`), in plain loops,
one call per batched evaluation instead of some 40 small NumPy calls.

They differ from the NumPy versions only by rounding (summation order); tests compare the
two. Unlike NumPy's (BLAS, LAPACK, SIMD exp chosen per CPU) their order of operations is
fixed (no fastmath: no reassociation, no FMA contraction; scalar libm exp), so the same
inputs give the same bits on any x86-64 CPU (issue 29). A Cholesky that fails in
`_evaluate_kernel` (a pivot at round-off level or below, or NaN: `_PIVOT_FLOOR`) returns
``factorised = False``: the caller (`_batched._evaluate`) then runs the jitter ladder
(`_cholesky._cholesky_inverse`, compiled too) and evaluates on its factors. Compiled on first
use and cached on disk (``cache=True``), like ``hydroarm.model.water.morison``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from hydroarm.model.dynamics.fixed_order import cholesky_factor

_PIVOT_FLOOR = 8.0 * 2.220446049250313e-16
"""A Cholesky pivot must exceed this times its diagonal entry: a pivot at round-off level is
what an exactly singular K (two equal samples, no noise) leaves, and its sign is chance (LAPACK
only tests > 0, so its verdict there depends on its kernel's rounding)."""

_NO_FACTOR = np.empty((0, 0, 0))
"""Empty ``cached_linv`` argument of `_evaluate_kernel`: factorise."""


@numba.njit(cache=True)
def _evaluate_kernel(X, Y_fit, log_theta, sn2, jitter, cached_linv, with_gradient):  # pragma: no cover - compiled
    """Compiled `_evaluate_numpy` (R&W Alg. 2.1 and eq. 5.9, per row of log_theta).

    Returns (lml (o,), grad (o, d+2), half_trace_w (o,), alpha (o, n), linv (o, n, n),
    linv_finite (o,), factorised). ``factorised`` is False if any row's Cholesky
    failed (then nothing else is meaningful). ``cached_linv`` with o rows skips the
    factorisation (the incremental path's factor); pass an empty array otherwise.
    grad and half_trace_w are zero-size unless ``with_gradient``.
    """
    n_out = log_theta.shape[0]
    n, d = X.shape
    pairs = _pair_terms(X)
    exponent = np.empty(pairs.shape[1])
    use_cached = cached_linv.shape[0] == n_out
    lml = np.empty(n_out)
    alpha = np.empty((n_out, n))
    linv = np.empty((n_out, n, n)) if not use_cached else cached_linv
    linv_finite = np.ones(n_out, dtype=np.bool_)
    if with_gradient:
        grad = np.empty((n_out, d + 2))
        half_trace_w = np.empty(n_out)
    else:
        grad = np.empty((0, d + 2))
        half_trace_w = np.empty(0)
    inv_l2 = np.empty(d)
    k_signal = np.empty((n, n))
    chol = np.empty((n, n))
    k_inv = np.empty((n, n))
    whitened = np.empty(n)
    half_log_2pi_n = 0.5 * n * math.log(2.0 * math.pi)
    for r in range(n_out):
        for j in range(d):
            inv_l2[j] = math.exp(-2.0 * log_theta[r, 2 + j])
        _signal_matrix(pairs, inv_l2, log_theta[r, 0], exponent, k_signal)
        lr = linv[r]
        if not use_cached:
            status = _factor_inverse(k_signal, sn2[r] + jitter, chol, lr)
            if status == 1:
                return lml, grad, half_trace_w, alpha, linv, linv_finite, False
            if status == 2:
                linv_finite[r] = False
                lr[:, :] = np.nan
        _solve_alpha(lr, Y_fit[r], whitened, alpha[r])
        if with_gradient:  # K^-1 = L^-T L^-1, for W = alpha alpha^T - K^-1
            _inverse_from_factor(lr, k_inv)
        fit = 0.0
        log_det = 0.0
        for a in range(n):
            fit += alpha[r, a] * Y_fit[r, a]
            log_det += math.log(lr[a, a])
        lml[r] = log_det - 0.5 * fit - half_log_2pi_n
        if with_gradient:
            half_trace_w[r] = _gradient_row(alpha[r], k_inv, k_signal, pairs, inv_l2, sn2[r], grad[r])
    return lml, grad, half_trace_w, alpha, linv, linv_finite, True


@numba.njit(cache=True)
def _pair_terms(X):  # pragma: no cover - compiled
    """(d, n(n-1)/2): -1/2 (x_aj - x_bj)^2 for the pairs a > b (column p, lower triangle row-major)."""
    n, d = X.shape
    pairs = np.empty((d, n * (n - 1) // 2))
    p = 0
    for a in range(n):
        for b in range(a):
            for j in range(d):
                diff = X[a, j] - X[b, j]
                pairs[j, p] = -0.5 * diff * diff
            p += 1
    return pairs


@numba.njit(cache=True)
def _signal_matrix(pairs, inv_l2, log_sf2, exponent, k_signal):  # pragma: no cover - compiled
    """The noise-free SE kernel matrix (n, n) into ``k_signal`` (``exponent``: scratch of the pairs)."""
    d, n_pairs = pairs.shape
    n = k_signal.shape[0]
    sf2 = math.exp(log_sf2)
    exponent[:] = 0.0  # sum_j inv_l2_j D_j, summed in j order as the NumPy version's matmul
    for j in range(d):
        for p in range(n_pairs):
            exponent[p] += inv_l2[j] * pairs[j, p]
    p = 0
    for a in range(n):
        k_signal[a, a] = sf2
        for b in range(a):
            value = math.exp(exponent[p] + log_sf2)
            k_signal[a, b] = value
            k_signal[b, a] = value
            p += 1


@numba.njit(cache=True)
def _solve_alpha(lr, y, whitened, alpha_row):  # pragma: no cover - compiled
    """alpha = K^-1 y = L^-T (L^-1 y), two triangular products: more accurate than forming
    K^-1 first, as the NumPy version does, on ill-conditioned windows (docs/controllers.md)."""
    n = lr.shape[0]
    for a in range(n):
        s = 0.0
        for b in range(a + 1):
            s += lr[a, b] * y[b]
        whitened[a] = s
    for a in range(n):
        s = 0.0
        for k in range(a, n):
            s += lr[k, a] * whitened[k]
        alpha_row[a] = s


@numba.njit(cache=True)
def _inverse_from_factor(lr, k_inv):  # pragma: no cover - compiled
    """K^-1 = L^-T L^-1 (n, n, symmetric) into ``k_inv`` from the inverse factor ``lr``."""
    n = lr.shape[0]
    for a in range(n):
        for b in range(a + 1):
            s = 0.0
            for k in range(a, n):
                s += lr[k, a] * lr[k, b]
            k_inv[a, b] = s
            k_inv[b, a] = s


@numba.njit(cache=True)
def _gradient_row(alpha, k_inv, k_signal, pairs, inv_l2, sn2, grad):  # pragma: no cover - compiled
    """d lml / d log theta (d+2,) into ``grad``, from W = alpha alpha^T - K^-1 and
    A = W * K_signal (symmetric); returns half the trace of W."""
    n = alpha.shape[0]
    d = inv_l2.shape[0]
    g_sf2 = 0.0
    trace = 0.0
    for j in range(d):
        grad[2 + j] = 0.0
    p = 0
    for a in range(n):
        w_aa = alpha[a] * alpha[a] - k_inv[a, a]
        trace += w_aa
        g_sf2 += w_aa * k_signal[a, a]
        for b in range(a):
            weight = 2.0 * (alpha[a] * alpha[b] - k_inv[a, b]) * k_signal[a, b]
            g_sf2 += weight
            for j in range(d):
                grad[2 + j] += weight * pairs[j, p]
            p += 1
    half_trace = 0.5 * trace
    grad[0] = 0.5 * g_sf2
    grad[1] = sn2 * half_trace
    for j in range(d):
        grad[2 + j] *= -inv_l2[j]
    return half_trace


@numba.njit(cache=True)
def _predict_kernel(X_star, X, log_theta, linv, alpha):  # pragma: no cover - compiled
    """Compiled `_predict_with_factor_numpy`: (o, m) mean and latent variance (>= 0)."""
    n_out = log_theta.shape[0]
    m, d = X_star.shape
    n = X.shape[0]
    mean = np.empty((n_out, m))
    var = np.empty((n_out, m))
    k_star = np.empty(n)
    inv_l2 = np.empty(d)
    for r in range(n_out):
        for j in range(d):
            inv_l2[j] = math.exp(-2.0 * log_theta[r, 2 + j])
        log_sf2 = log_theta[r, 0]
        for i in range(m):
            for b in range(n):
                s = 0.0
                for j in range(d):
                    diff = X_star[i, j] - X[b, j]
                    s += inv_l2[j] * (-0.5 * diff * diff)
                k_star[b] = math.exp(s + log_sf2)
            mu = 0.0
            for b in range(n):
                mu += k_star[b] * alpha[r, b]
            explained = 0.0
            for a in range(n):
                s = 0.0
                for b in range(a + 1):
                    s += linv[r, a, b] * k_star[b]
                explained += s * s
            mean[r, i] = mu
            var[r, i] = max(math.exp(log_sf2) - explained, 0.0)
    return mean, var


@numba.njit(cache=True)
def _factor_inverse(k, noise, chol, lr):  # pragma: no cover - compiled
    """The inverse lower Cholesky factor ``lr`` (n, n) of ``k + noise I`` (k's lower triangle
    read), ``chol`` (n, n) a work array: 0 done, 1 a pivot not above `_PIVOT_FLOOR` times its
    diagonal entry or NaN (``lr`` undefined), 2 the inverse is not finite. Fixed-order loops
    (no LAPACK / BLAS; the factor is :func:`hydroarm.model.dynamics.fixed_order.cholesky_factor`)."""
    n = k.shape[0]
    if not cholesky_factor(k, chol, noise, _PIVOT_FLOOR):
        return 1
    for j in range(n):  # L^-1, lower triangular
        lr[j, j] = 1.0 / chol[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for p in range(j, i):
                s += chol[i, p] * lr[p, j]
            lr[i, j] = -s / chol[i, i]
        for i in range(j):
            lr[i, j] = 0.0
    total = 0.0
    for a in range(n):
        for b in range(a + 1):
            total += lr[a, b]
    return 0 if np.isfinite(total) else 2


@numba.njit(cache=True)
def _factor_rows(K, extra):  # pragma: no cover - compiled
    """``(linv (o, n, n), status (o,))``: `_factor_inverse` of each K[o] + extra[o] I."""
    n_out, n, _ = K.shape
    linv = np.empty((n_out, n, n))
    status = np.empty(n_out, dtype=np.int64)
    chol = np.empty((n, n))
    for o in range(n_out):
        status[o] = _factor_inverse(K[o], extra[o], chol, linv[o])
    return linv, status


@numba.njit(cache=True)
def _kernel_matrices(X1, X2, log_theta):  # pragma: no cover - compiled
    """(o, n1, n2) k(X1[a], X2[b]) per row of log_theta, in `_evaluate_kernel`'s order of
    operations (the same bits)."""
    n_out = log_theta.shape[0]
    n1, d = X1.shape
    out = np.empty((n_out, n1, X2.shape[0]))
    for a in range(n1):
        out[:, a, :] = _kernel_column(X1[a], X2, log_theta)
    return out


@numba.njit(cache=True)
def _kernel_column(x_new, X_old, log_theta):  # pragma: no cover - compiled
    """(o, n) k(x_new, X_old[b]) per row of log_theta, in `_evaluate_kernel`'s order of
    operations (the same bits as the full kernel matrix's last row)."""
    n_out = log_theta.shape[0]
    n, d = X_old.shape
    out = np.empty((n_out, n))
    inv_l2 = np.empty(d)
    for r in range(n_out):
        for j in range(d):
            inv_l2[j] = math.exp(-2.0 * log_theta[r, 2 + j])
        log_sf2 = log_theta[r, 0]
        for b in range(n):
            s = 0.0
            for j in range(d):
                diff = x_new[j] - X_old[b, j]
                s += inv_l2[j] * (-0.5 * diff * diff)
            out[r, b] = math.exp(s + log_sf2)
    return out


@numba.njit(cache=True)
def _append_kernel(linv, k_new, kappa, min_schur):  # pragma: no cover - compiled
    """``(grown (o, n+1, n+1), ok)``: the inverse factor after appending a sample with kernel
    column k_new (o, n) and prior diagonal kappa (o,); ok False if a Schur complement is not
    finite or not above min_schur (o,). c = Linv k, delta = sqrt(kappa - |c|^2), new last
    row [-(Linv^T c) / delta, 1 / delta]."""
    n_out, n, _ = linv.shape
    grown = np.zeros((n_out, n + 1, n + 1))
    c = np.empty(n)
    for o in range(n_out):
        for a in range(n):
            s = 0.0
            for b in range(a + 1):
                s += linv[o, a, b] * k_new[o, b]
            c[a] = s
        schur = kappa[o]
        for a in range(n):
            schur -= c[a] * c[a]
        if not (np.isfinite(schur) and schur > min_schur[o]):
            return grown, False
        delta = math.sqrt(schur)
        for a in range(n):
            for b in range(a + 1):
                grown[o, a, b] = linv[o, a, b]
        for a in range(n):
            s = 0.0
            for b in range(a, n):
                s += linv[o, b, a] * c[b]
            grown[o, n, a] = -s / delta
        grown[o, n, n] = 1.0 / delta
    return grown, True


@numba.njit(cache=True)
def _solve_kernel(linv, Y_fit):  # pragma: no cover - compiled
    """alpha = K^-1 y = Linv^T (Linv y) per row (o, n), in `_evaluate_kernel`'s order."""
    n_out, n, _ = linv.shape
    alpha = np.empty((n_out, n))
    whitened = np.empty(n)
    for r in range(n_out):
        for a in range(n):
            s = 0.0
            for b in range(a + 1):
                s += linv[r, a, b] * Y_fit[r, b]
            whitened[a] = s
        for a in range(n):
            s = 0.0
            for k in range(a, n):
                s += linv[r, k, a] * whitened[k]
            alpha[r, a] = s
    return alpha
