"""Compiled (numba) kernels of the stacked GP evaluation: the same algebra as the NumPy
functions of `_batched` (`_evaluate_numpy`, `_predict_with_factor_numpy`), in plain loops,
one call per batched evaluation instead of some 40 small NumPy calls.

They differ from the NumPy versions only by rounding (summation order); tests compare the
two. A Cholesky that fails in `_evaluate_kernel` (a pivot <= 0 or NaN, LAPACK dpotrf's
test) returns ``factorised = False``: the caller (`_batched._evaluate`) then reruns the
NumPy version, whose jitter ladder and fault events apply unchanged. Compiled on first
use and cached on disk (``cache=True``), like ``hydroarm.model.water``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_NO_FACTOR = np.empty((0, 0, 0))
"""Empty ``cached_linv`` argument of `_evaluate_kernel`: factorise."""

# Windows above this size factorise with LAPACK's blocked Cholesky and triangular inverse
# (no gradient needed) instead of the unblocked compiled loops: the measured crossover
# (docs/controllers.md, "The GP: measured choices"). With the gradient the compiled kernel
# is used at every size.
_COMPILED_FACTOR_MAX_WINDOW = 60


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
    # -1/2 (x_aj - x_bj)^2 for the pairs a > b (column p, lower triangle row-major)
    n_pairs = n * (n - 1) // 2
    pairs = np.empty((d, n_pairs))
    p = 0
    for a in range(n):
        for b in range(a):
            for j in range(d):
                diff = X[a, j] - X[b, j]
                pairs[j, p] = -0.5 * diff * diff
            p += 1
    exponent = np.empty(n_pairs)
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
        log_sf2 = log_theta[r, 0]
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
        lr = linv[r]
        if not use_cached:
            # Cholesky K = L L^T, K = K_signal + (sn2 + jitter) I
            noise = sn2[r] + jitter
            for j in range(n):
                s = k_signal[j, j] + noise
                for k in range(j):
                    s -= chol[j, k] * chol[j, k]
                if not s > 0.0:
                    return lml, grad, half_trace_w, alpha, linv, linv_finite, False
                pivot = math.sqrt(s)
                chol[j, j] = pivot
                for i in range(j + 1, n):
                    s = k_signal[i, j]
                    for k in range(j):
                        s -= chol[i, k] * chol[j, k]
                    chol[i, j] = s / pivot
            # L^-1, lower triangular
            for j in range(n):
                lr[j, j] = 1.0 / chol[j, j]
                for i in range(j + 1, n):
                    s = 0.0
                    for k in range(j, i):
                        s += chol[i, k] * lr[k, j]
                    lr[i, j] = -s / chol[i, i]
                for i in range(j):
                    lr[i, j] = 0.0
            total = 0.0
            for a in range(n):
                for b in range(a + 1):
                    total += lr[a, b]
            if not np.isfinite(total):
                linv_finite[r] = False
                lr[:, :] = np.nan
        # alpha = K^-1 y = L^-T (L^-1 y), two triangular products: more accurate than forming
        # K^-1 first, as the NumPy version does, on ill-conditioned windows (docs/controllers.md).
        for a in range(n):
            s = 0.0
            for b in range(a + 1):
                s += lr[a, b] * Y_fit[r, b]
            whitened[a] = s
        for a in range(n):
            s = 0.0
            for k in range(a, n):
                s += lr[k, a] * whitened[k]
            alpha[r, a] = s
        fit = 0.0
        log_det = 0.0
        if with_gradient:  # K^-1 = L^-T L^-1, for W = alpha alpha^T - K^-1
            for a in range(n):
                for b in range(a + 1):
                    s = 0.0
                    for k in range(a, n):
                        s += lr[k, a] * lr[k, b]
                    k_inv[a, b] = s
                    k_inv[b, a] = s
        for a in range(n):
            fit += alpha[r, a] * Y_fit[r, a]
            log_det += math.log(lr[a, a])
        lml[r] = log_det - 0.5 * fit - half_log_2pi_n
        if not with_gradient:
            continue
        # W = alpha alpha^T - K^-1, A = W * K_signal (symmetric)
        g_sf2 = 0.0
        trace = 0.0
        for j in range(d):
            grad[r, 2 + j] = 0.0
        p = 0
        for a in range(n):
            w_aa = alpha[r, a] * alpha[r, a] - k_inv[a, a]
            trace += w_aa
            g_sf2 += w_aa * k_signal[a, a]
            for b in range(a):
                weight = 2.0 * (alpha[r, a] * alpha[r, b] - k_inv[a, b]) * k_signal[a, b]
                g_sf2 += weight
                for j in range(d):
                    grad[r, 2 + j] += weight * pairs[j, p]
                p += 1
        half_trace_w[r] = 0.5 * trace
        grad[r, 0] = 0.5 * g_sf2
        grad[r, 1] = sn2[r] * half_trace_w[r]
        for j in range(d):
            grad[r, 2 + j] *= -inv_l2[j]
    return lml, grad, half_trace_w, alpha, linv, linv_finite, True


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
