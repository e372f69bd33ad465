"""Stacked multi-output GP evaluation: kernel matrices, log marginal likelihood and its
gradient, and prediction for several outputs (and candidate hyperparameters) at once.

Rows of ``log_theta`` are [log sf2, log sn2, log l_1..log l_d], one per output (or per
candidate: rows may repeat an output). Everything works on stacked (o, n, n) arrays, as
the cost at small windows is set by the number of NumPy calls, not by the flops.

`_evaluate` and `_predict_with_factor` run the compiled kernels of `_compiled`;
`_evaluate_numpy` and `_predict_with_factor_numpy` are their plain-NumPy twins (the
readable form of the algebra; `_evaluate` falls back to `_evaluate_numpy` when a Cholesky
fails, for its jitter ladder).

Formulas: R&W (Rasmussen & Williams 2006) Algorithm 2.1 (prediction, LML) and eq. 5.9
(gradient), in log theta.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import NamedTuple

import numpy as np

from hydroarm.control.gp._cholesky import _cholesky_inverse
from hydroarm.control.gp._compiled import (
    _NO_FACTOR,
    _evaluate_kernel,
    _kernel_matrices,
    _predict_kernel,
    _solve_kernel,
)

LOG_2PI = math.log(2.0 * math.pi)


def _neg_half_sq_diff_t(X1: np.ndarray, X2: np.ndarray) -> np.ndarray:
    """(d, n1*n2) array -1/2 (x1_aj - x2_bj)^2 at [j, a*n2 + b]: the per-dimension squared
    distances shared by all outputs, laid out so one matmul with 1/l^2 gives every exponent."""
    diff = X1.T[:, :, None] - X2.T[:, None, :]
    return (-0.5 * diff * diff).reshape(X1.shape[1], -1)


def _signal_kernels(neg_half_sq_diff_t: np.ndarray, n_rows: int, n_cols: int, log_theta: np.ndarray) -> np.ndarray:
    """(o, n_rows, n_cols) stacked sf2_o * exp(-1/2 sum_j D_j / l_oj^2)."""
    inv_l2 = np.exp(-2.0 * log_theta[:, 2:])  # (o, d)
    exponent = inv_l2 @ neg_half_sq_diff_t + log_theta[:, :1]  # (o, n_rows*n_cols); sf2 folded in
    return np.exp(exponent).reshape(log_theta.shape[0], n_rows, n_cols)


class _Window:
    """Per-window data shared by all outputs and all hyperparameter evaluations.

    X (n, d) scaled inputs, Y_fit (o, n) fitted targets (normalised if asked),
    y_mean, y_std (o,) to undo the normalisation; computed on first use (the
    O(N^2) incremental path never needs them): neg_half_sq_diff_t (d, n*n)
    (see `_neg_half_sq_diff_t`) and eye (n, n).
    """

    def __init__(self, X: np.ndarray, Y_fit: np.ndarray, y_mean: np.ndarray, y_std: np.ndarray) -> None:
        self.X = X
        self.n = X.shape[0]
        self.Y_fit = Y_fit
        self.y_mean = y_mean
        self.y_std = y_std

    @cached_property
    def neg_half_sq_diff_t(self) -> np.ndarray:
        return _neg_half_sq_diff_t(self.X, self.X)

    @cached_property
    def eye(self) -> np.ndarray:
        return np.eye(self.n)


class _Evaluation(NamedTuple):
    """LML (o,), gradient w.r.t. log theta (o, d+2) or None, 1/2 tr(W) (o,) or None,
    alpha = K^-1 y (o, n), inverse Cholesky factors (o, n, n), extra jitter used (o,)
    (> 0 where the first factorisation failed) and factorisation ok (o,)."""

    lml: np.ndarray
    grad: np.ndarray | None
    half_trace_w: np.ndarray | None
    alpha: np.ndarray
    linv: np.ndarray
    extra_diag: np.ndarray
    ok: np.ndarray


def _rows(evaluation: _Evaluation, start: int, stop: int) -> _Evaluation:
    """The rows start:stop of a stacked evaluation."""
    return _Evaluation(*(None if field is None else field[start:stop] for field in evaluation))


def _evaluate_numpy(
    window: _Window,
    Y_fit: np.ndarray,
    log_theta: np.ndarray,
    sn2: np.ndarray,
    jitter: float,
    max_jitter_retries: int,
    with_gradient: bool,
    cached: tuple[np.ndarray, np.ndarray] | None = None,
) -> _Evaluation:
    """Factorise K = K_signal + (sn2 + jitter) I for every output and return the LML
    (R&W Alg. 2.1 line 8) and, if asked, its gradient w.r.t. log theta (R&W eq. 5.9):

        dL/dlog sf2 = 1/2 sum(W * K_signal),  dL/dlog sn2 = sn2/2 tr(W),
        dL/dlog l_j = 1/2 sum(W * K_signal * D_j) / l_j^2,   W = alpha alpha^T - K^-1.

    Y_fit (o, n) holds the targets of each row of log_theta (rows may repeat an
    output, to evaluate several candidates in one batch). sn2 (o,) is passed
    separately so that sn2 = 0 is allowed by the pure functions.
    cached = (linv, extra_diag) reuses a factor of this window and theta.
    Outputs whose factorisation failed get NaN LML (never accepted).
    """
    n_out, n = log_theta.shape[0], window.n
    inv_l2 = np.exp(-2.0 * log_theta[:, 2:])
    K_signal = np.exp(inv_l2 @ window.neg_half_sq_diff_t + log_theta[:, :1]).reshape(n_out, n, n)
    if cached is None:
        K = K_signal + (sn2 + jitter)[:, None, None] * window.eye
        linv, extra_diag, ok, _ = _cholesky_inverse(K, max_jitter_retries)
    else:
        linv, extra_diag = cached
        ok = np.ones(n_out, dtype=bool)
    K_inv = linv.transpose(0, 2, 1) @ linv
    alpha = np.einsum("oab,ob->oa", K_inv, Y_fit)
    lml = (
        np.log(np.diagonal(linv, axis1=1, axis2=2)).sum(axis=1)  # = -1/2 log|K|
        - 0.5 * np.einsum("oa,oa->o", alpha, Y_fit)
        - 0.5 * n * LOG_2PI
    )
    ok = ok & np.isfinite(lml)
    if not with_gradient:
        return _Evaluation(lml, None, None, alpha, linv, extra_diag, ok)
    W = alpha[:, :, None] * alpha[:, None, :] - K_inv
    half_trace_w = 0.5 * np.einsum("oaa->o", W)
    A = (W * K_signal).reshape(n_out, -1)
    grad = np.empty(log_theta.shape)
    grad[:, 0] = 0.5 * A.sum(axis=1)
    grad[:, 1] = sn2 * half_trace_w
    grad[:, 2:] = -inv_l2 * (A @ window.neg_half_sq_diff_t.T)  # 1/2 sum(A D_j) / l_j^2
    return _Evaluation(lml, grad, half_trace_w, alpha, linv, extra_diag, ok)


def _solve_with_factor(linv: np.ndarray, Y_fit: np.ndarray) -> np.ndarray:
    """alpha = K^-1 y = Linv^T (Linv y) per output, (o, n), two O(n^2) products (compiled,
    in `_evaluate_kernel`'s order)."""
    return _solve_kernel(np.ascontiguousarray(linv, dtype=np.float64), np.ascontiguousarray(Y_fit, dtype=np.float64))


def _predict_with_factor_numpy(window: _Window, X_star, log_theta, linv, alpha):
    """(o, m) normalised mean and latent variance (clipped at 0) (R&W Alg. 2.1 lines 4-6).

    Plain-NumPy twin of :func:`~hydroarm.control.gp._compiled._predict_kernel` (tests compare the two)."""
    K_star = _signal_kernels(_neg_half_sq_diff_t(X_star, window.X), X_star.shape[0], window.n, log_theta)
    mean = np.einsum("omn,on->om", K_star, alpha)
    v = K_star @ linv.transpose(0, 2, 1)  # (o, m, n): rows of (Linv K_star^T)^T
    var = np.maximum(np.exp(log_theta[:, :1]) - np.einsum("oma,oma->om", v, v), 0.0)
    return mean, var


def _evaluate(
    window: _Window,
    Y_fit: np.ndarray,
    log_theta: np.ndarray,
    sn2: np.ndarray,
    jitter: float,
    max_jitter_retries: int,
    with_gradient: bool,
    cached: tuple[np.ndarray, np.ndarray] | None = None,
) -> _Evaluation:
    """`_evaluate_numpy` by the compiled kernels (fixed-order loops, no BLAS / LAPACK: the same
    bits on any CPU). If a Cholesky fails, the factors are recomputed with the jitter ladder
    (`_cholesky_inverse`) and the evaluation reruns on them."""
    X = np.ascontiguousarray(window.X, dtype=np.float64)
    Y_fit = np.ascontiguousarray(Y_fit, dtype=np.float64)
    log_theta = np.ascontiguousarray(log_theta, dtype=np.float64)
    sn2 = np.ascontiguousarray(sn2, dtype=np.float64)
    cached_linv = _NO_FACTOR if cached is None else np.ascontiguousarray(cached[0])
    result = _evaluate_kernel(X, Y_fit, log_theta, sn2, float(jitter), cached_linv, bool(with_gradient))
    lml, grad, half_trace_w, alpha, linv, linv_finite, factorised = result
    if not factorised:  # a Cholesky failed: the jitter ladder, then the evaluation on its factors
        K = _kernel_matrices(X, X, log_theta)
        diagonal = np.arange(window.n)
        K[:, diagonal, diagonal] += (sn2 + jitter)[:, None]
        linv, extra_diag, ok, _ = _cholesky_inverse(K, max_jitter_retries)
        result = _evaluate_kernel(X, Y_fit, log_theta, sn2, float(jitter), linv, bool(with_gradient))
        lml, grad, half_trace_w, alpha = result[:4]
        ok = ok & np.isfinite(lml)
    elif cached is None:
        extra_diag, ok = np.zeros(log_theta.shape[0]), linv_finite & np.isfinite(lml)
    else:
        extra_diag, ok = cached[1], np.isfinite(lml)
    if not with_gradient:
        grad = half_trace_w = None
    return _Evaluation(lml, grad, half_trace_w, alpha, linv, extra_diag, ok)


def _predict_with_factor(window: _Window, X_star, log_theta, linv, alpha):
    """(o, m) normalised mean and latent variance (clipped at 0) (R&W Alg. 2.1 lines 4-6)."""
    return _predict_kernel(
        np.ascontiguousarray(X_star, dtype=np.float64),
        np.ascontiguousarray(window.X, dtype=np.float64),
        np.ascontiguousarray(log_theta, dtype=np.float64),
        np.ascontiguousarray(linv, dtype=np.float64),
        np.ascontiguousarray(alpha, dtype=np.float64),
    )
