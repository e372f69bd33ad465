"""Sliding-window Gaussian-process regression (Liu et al. 2023, Section 3.1).

The GP learns, online at every control step, the one-step residual
(disturbance) of the arm from the last ``window`` samples (the paper's
N_train, Algorithm 1). One independent GP per output (joint); all outputs share
the input features but each has its own hyperparameters.

Model (per output)
------------------
Zero prior mean (paper, eq. 5) and the squared-exponential ARD kernel (eq. 10)::

    k(x, x') = sf2 * exp(-1/2 * sum_j (x_j - x'_j)^2 / l_j^2)
    K        = k(X, X) + sn2 * I        (noise on the training diagonal only)

Hyperparameters ``theta = [sf2, sn2, l_1 .. l_d]`` (the paper's
Theta = [sigma_f^2, sigma_n^2, lambda_1 .. lambda_n]); ``sf2`` and ``sn2`` are
variances in (target unit)^2, ``l_j`` is in the unit of input j (after the
optional ``GPConfig.input_scale``).

The paper's eq. (10) as extracted adds ``sigma_n^2`` to *every* kernel entry.
That is a garbled (or wrong) reading: a constant on every entry would be a
constant-offset kernel, not observation noise, and it would also enter the
test covariances K(X*, X). Here the noise is on the training diagonal only, as
in Rasmussen & Williams (2006), eq. 2.20 - 2.24.

Prediction follows R&W Algorithm 2.1 (Cholesky); the log marginal likelihood
is R&W eq. 2.30 (the paper's eq. 11) and its gradient R&W eq. 5.9 (the paper's
eq. 12)::

    L          = -1/2 y^T K^-1 y - 1/2 log|K| - n/2 log(2 pi)
    dL/dtheta  = 1/2 tr((alpha alpha^T - K^-1) dK/dtheta),   alpha = K^-1 y

Public API
----------
Pure functions (single output, reference implementation with SciPy)::

    mean, var = predict(X, y, X_star, theta, *, include_noise=True, jitter=0.0)
    lml, grad = log_marginal_likelihood(X, y, theta, *, jitter=0.0)

Batched over outputs (same X, one column of Y and one row of thetas per output)::

    mean, var = predict_multi(X, Y, X_star, thetas, *, include_noise=True, jitter=0.0)
    lml, grad = log_marginal_likelihood_multi(X, Y, thetas, *, jitter=0.0)

Online estimator::

    gp = SlidingWindowGP(n_inputs, n_outputs=6, config=GPConfig())
    gp.add(x, y); gp.update_hyperparameters(); mean, var = gp.predict(x_star)

Hyperparameter steps (Algorithm 1, made robust)
-----------------------------------------------
The paper does steepest ascent on L in the natural parameters with a fixed
learning factor. We step in log space (positivity kept), cap each component of
the step at ``max_log_step``, project onto box bounds, warm-start from the
previous control step's theta, and accept a step only if L does not decrease
on the current window (otherwise halve it, up to ``max_step_halvings`` times,
then keep the previous theta). A quick trial in the SPEC found unbounded steps
unstable with 14 hyperparameters and 10 points. To keep the cost at one
batched evaluation per step, the halved candidates are factorised together
with the full step, and the first step of an update uses the gradient at the
current theta from the end of the previous update (window one sample older);
acceptance is always tested exactly on the current window.

Robustness: a failed Cholesky factorisation is retried with a growing diagonal
jitter (relative to the mean diagonal: 1e-10, 1e-8, 1e-6, 1e-4, bounded by
``max_jitter_retries``); if it still fails, the candidate hyperparameters are
rejected (previous theta kept) or, if the current theta itself cannot be
factorised on the new window, that output predicts its prior. Every such
event is counted in ``SlidingWindowGP.stats``; no LinAlgError leaves the class.

Scaling (measured on the paper's reference trajectory, water torques from
``hydroarm.model.water`` as targets, inputs [q, q'], one-step-ahead RMSE): raw N*m
targets with the paper's theta0 = 1 and the default bounds work best;
``normalize_y`` (window mean/std) is worse (joint 1: 20 vs 8.5 N*m with
measurement noise, 1.5e-2 vs 3e-3 N*m without) because the 10-sample window
statistics are noisy and the mean lags; ``output_scale`` is neutral;
``input_scale`` is neutral for [q, q'] (same order of magnitude) but should be
set when inputs mix units (e.g. torques ~ 500 N*m with angles ~ 1 rad), since
every lengthscale starts at 1 and moves at most ``max_log_step`` per step.

Window update: incremental vs full refactorisation
--------------------------------------------------
When the hyperparameters are unchanged, the factor of the slid window is
obtained in O(N^2) from the previous one instead of O(N^3). We keep the
*inverse* Cholesky factor Linv = L^-1 (what prediction and the gradient need):

* drop the oldest sample: with Linv = [[a, 0], [b, M]], the trailing block's
  Cholesky is a rank-1 update of M^-1 by p = -b / a; the factor of
  I + p p^T has a closed form (Gill, Golub, Murray & Saunders 1974, method C1:
  t_i = 1 + sum_{k<=i} p_k^2), and its inverse is I - tril_{-1}(u p^T) with
  u_i = p_i / t_{i-1}, so Linv' = diag(t_{i-1}/t_i)^{1/2} (M - u * cumsum_excl(p M)),
  all vectorised (cumsum), no Python loop over rows;
* append the new sample: c = Linv' k, delta = sqrt(kappa - |c|^2), new last row
  [-(Linv'^T c)/delta, 1/delta].

Measured with ``bench/gp_window_update.py`` (``add`` + ``predict`` with fixed
theta, 6 outputs, d = 12, 1 BLAS thread, median of 2000 reps, 2-core x86_64
VM, microseconds; "full" includes rebuilding the O(N^2 d) squared distances)::

    N                      10     20     50     100     200
    full (NumPy)          169    214    524    3677   15647
    incremental (NumPy)   170    196    327    1396    5314
    full (compiled <= 60)  59     87    371    3605   18531   (see "Compiled kernels")
    incremental            152    181    317    1625    6555   (same code, re-measured)

So the incremental path gains nothing at small N (call overhead dominates; with
the compiled full factorisation it loses below ~40), and wins clearly above;
``GPConfig.incremental_min_window`` (default
30) selects it only for windows at least that large, and a full
refactorisation is forced every ``refactor_every`` incremental updates to bound
round-off drift (after 2000 incremental updates the factor still agreed with a
fresh one to 1e-13). With the paper's N_train = 10 the full refactorisation is
used. Hyperparameter steps do not prevent it: ``add`` slides the window at the
theta left by the last update, and ``update_hyperparameters`` starts from that
factor instead of refactorising (the candidates still need full ones).

Compiled kernels
----------------
At N = 10 the NumPy formulation of one batched evaluation (kernel matrices,
batched Cholesky, one LAPACK triangular inverse per row, K^-1, alpha, LML,
gradient: ~40 NumPy calls) costs ~170 us for the 18 stacked rows of one
hyperparameter step, nearly all of it call overhead. ``_evaluate_kernel`` and
``_predict_kernel`` (numba, cached on disk like hydroarm.model.water) do the same
algebra in plain loops, ~37 us; the NumPy versions stay as the readable
references (``_evaluate_reference``, ``_predict_with_factor_reference``) and
tests compare the two (they differ by rounding only). A Cholesky that fails in
the kernel (a pivot <= 0 or NaN, LAPACK's test) makes the wrapper rerun the
reference, so the jitter ladder and the event counts are those of the
reference. Without the gradient (``predict`` after ``add``), LAPACK's blocked
factorisation wins above ~60 samples and is used there. One GP control step
(add + one hyperparameter step + predict, 6 outputs, d = 12, N = 10) went from
~390 us to ~170 us; see ``bench/README.md``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Annotated, NamedTuple

import numba
import numpy as np
import pydantic
from pydantic import StrictBool, StrictFloat, StrictInt
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.linalg.lapack import dpotrf, dtrtri

__all__ = [
    "GPConfig",
    "GPStats",
    "SlidingWindowGP",
    "se_ard_kernel",
    "predict",
    "log_marginal_likelihood",
    "predict_multi",
    "log_marginal_likelihood_multi",
]

LOG_2PI = math.log(2.0 * math.pi)

# Extra diagonal tried after a failed Cholesky, relative to the mean diagonal.
_JITTER_LADDER_START = 1e-10
_JITTER_LADDER_FACTOR = 100.0


# --------------------------------------------------------------------------
# Input validation
# --------------------------------------------------------------------------


def _as_finite_array(name: str, value, ndim: int) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array; got {type(value).__name__}") from exc
    if array.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D; got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must contain only finite values (no NaN/inf)")
    return array


def _check_matrix(name: str, value, n_rows: int | None = None, n_cols: int | None = None) -> np.ndarray:
    array = _as_finite_array(name, value, 2)
    expected = f"({n_rows if n_rows is not None else 'n'}, {n_cols if n_cols is not None else 'd'})"
    if (n_rows is not None and array.shape[0] != n_rows) or (n_cols is not None and array.shape[1] != n_cols):
        raise ValueError(f"{name} must have shape {expected}; got {array.shape}")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"{name} must be non-empty with shape {expected}; got {array.shape}")
    return array


def _check_vector(name: str, value, length: int) -> np.ndarray:
    array = _as_finite_array(name, value, 1)
    if array.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},); got {array.shape}")
    return array


def _check_theta(name: str, value, n_inputs: int) -> np.ndarray:
    """theta = [sf2, sn2, l_1..l_d], finite and > 0 (sn2 may be 0)."""
    try:
        theta = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array [sf2, sn2, l_1..l_d]") from exc
    if theta.shape != (n_inputs + 2,):
        raise ValueError(
            f"{name} must have shape (d+2,) = ({n_inputs + 2},) as [sf2, sn2, l_1..l_{n_inputs}]; "
            f"got shape {theta.shape}"
        )
    _check_theta_values(name, theta)
    return theta


def _check_theta_values(name: str, theta: np.ndarray) -> None:
    if not np.all(np.isfinite(theta)):
        raise ValueError(f"{name} must be finite")
    if theta[..., 0].min() <= 0.0:
        raise ValueError(f"{name}: sf2 (index 0) must be > 0")
    if theta[..., 1].min() < 0.0:
        raise ValueError(f"{name}: sn2 (index 1) must be >= 0")
    if theta[..., 2:].min() <= 0.0:
        raise ValueError(f"{name}: lengthscales (index 2..) must be > 0")


def _check_jitter(jitter) -> float:
    if not (isinstance(jitter, (int, float)) and math.isfinite(jitter) and jitter >= 0.0):
        raise ValueError(f"jitter must be a finite float >= 0; got {jitter!r}")
    return float(jitter)


# --------------------------------------------------------------------------
# Single-output reference implementation (SciPy, R&W Alg. 2.1 / eq. 5.9)
# --------------------------------------------------------------------------


def se_ard_kernel(X1: np.ndarray, X2: np.ndarray, sf2: float, lengthscales: np.ndarray) -> np.ndarray:
    """SE-ARD kernel matrix (n1, n2): sf2 * exp(-1/2 sum_j (x1_j - x2_j)^2 / l_j^2).

    No noise term (noise belongs on the training diagonal only, see module doc).
    """
    scaled_diff = (X1[:, None, :] - X2[None, :, :]) / lengthscales
    return sf2 * np.exp(-0.5 * np.einsum("abj,abj->ab", scaled_diff, scaled_diff))


def _cholesky_or_raise(K: np.ndarray):
    try:
        return cho_factor(K, lower=True, check_finite=False)
    except np.linalg.LinAlgError as exc:
        raise np.linalg.LinAlgError(
            "K(X, X) + (sn2 + jitter) I is not positive definite (near-duplicate inputs with "
            "tiny sn2?); increase sn2 or jitter"
        ) from exc


def predict(X, y, X_star, theta, *, include_noise: bool = True, jitter: float = 0.0):
    """GP posterior at X_star given (X, y) and fixed hyperparameters (R&W Alg. 2.1).

    Args:
        X: (n, d) training inputs.
        y: (n,) training targets (zero prior mean: no centring is done here).
        X_star: (m, d) test inputs.
        theta: (d+2,) [sf2, sn2, l_1..l_d], natural scale (not log).
        include_noise: if True (default) the variance is that of a noisy
            observation y* = f(x*) + eps, i.e. latent variance + sn2; this is
            what scikit-learn's GaussianProcessRegressor with a WhiteKernel(sn2)
            term returns from ``predict(X_star, return_std=True)`` (squared).
            If False, the variance of the latent f(x*).
        jitter: extra value added to the training diagonal only (numerical;
            sklearn's ``alpha``), not to the predictive variance.

    Returns:
        mean (m,), var (m,) in target units and target units^2. The latent
        variance is clipped at 0 (round-off), as sklearn does.

    Raises:
        ValueError on bad shapes / values; numpy.linalg.LinAlgError if
        K + (sn2 + jitter) I is not positive definite.
    """
    X = _check_matrix("X", X)
    n, d = X.shape
    y = _check_vector("y", y, n)
    X_star = _check_matrix("X_star", X_star, n_cols=d)
    theta = _check_theta("theta", theta, d)
    jitter = _check_jitter(jitter)
    sf2, sn2, lengthscales = theta[0], theta[1], theta[2:]

    K = se_ard_kernel(X, X, sf2, lengthscales)
    K[np.diag_indices_from(K)] += sn2 + jitter
    chol = _cholesky_or_raise(K)  # Alg. 2.1 line 2: L = chol(K + sn2 I)
    alpha = cho_solve(chol, y, check_finite=False)  # line 3
    K_star = se_ard_kernel(X_star, X, sf2, lengthscales)  # (m, n)
    mean = K_star @ alpha  # line 4
    v = solve_triangular(chol[0], K_star.T, lower=True, check_finite=False)  # line 5
    var = np.maximum(sf2 - np.einsum("nm,nm->m", v, v), 0.0)  # line 6 (diagonal only)
    if include_noise:
        var = var + sn2
    return mean, var


def log_marginal_likelihood(X, y, theta, *, jitter: float = 0.0):
    """Log marginal likelihood and its gradient w.r.t. theta (natural scale).

    L = -1/2 y^T K^-1 y - sum(log diag L) - n/2 log(2 pi)   (R&W Alg. 2.1 line 8, paper eq. 11)
    dL/dtheta_i = 1/2 tr((alpha alpha^T - K^-1) dK/dtheta_i)  (R&W eq. 5.9, paper eq. 12)
    with dK/dsf2 = K_f / sf2, dK/dsn2 = I, dK/dl_j = K_f * (x_j - x'_j)^2 / l_j^3.

    Args:
        X: (n, d), y: (n,), theta: (d+2,) [sf2, sn2, l_1..l_d] natural scale.
        jitter: constant extra diagonal (not a hyperparameter, no gradient).

    Returns:
        lml (float), grad (d+2,) = dL/d[sf2, sn2, l_1..l_d] at theta as given.
    """
    X = _check_matrix("X", X)
    n, d = X.shape
    y = _check_vector("y", y, n)
    theta = _check_theta("theta", theta, d)
    jitter = _check_jitter(jitter)
    sf2, sn2, lengthscales = theta[0], theta[1], theta[2:]

    K_signal = se_ard_kernel(X, X, sf2, lengthscales)
    K = K_signal.copy()
    K[np.diag_indices_from(K)] += sn2 + jitter
    chol = _cholesky_or_raise(K)
    alpha = cho_solve(chol, y, check_finite=False)
    lml = -0.5 * y @ alpha - np.sum(np.log(np.diag(chol[0]))) - 0.5 * n * LOG_2PI

    K_inv = cho_solve(chol, np.eye(n), check_finite=False)
    W = np.outer(alpha, alpha) - K_inv
    sq_diff = (X[:, None, :] - X[None, :, :]) ** 2  # (n, n, d)
    grad = np.empty(d + 2)
    grad[0] = 0.5 * np.sum(W * K_signal) / sf2
    grad[1] = 0.5 * np.trace(W)
    grad[2:] = 0.5 * np.einsum("ab,abj->j", W * K_signal, sq_diff) / lengthscales**3
    return float(lml), grad


# --------------------------------------------------------------------------
# Batched multi-output machinery (NumPy, stacked (o, n, n) arrays)
# --------------------------------------------------------------------------
# log_theta rows are [log sf2, log sn2, log l_1..log l_d] per output. The cost
# at N = 10 is dominated by the number of NumPy calls, not by flops, so every
# step below works on all outputs at once.


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


def _cholesky_inverse(K: np.ndarray, max_jitter_retries: int):
    """Inverse lower Cholesky factors of the stacked SPD matrices K (o, n, n).

    Returns (linv (o, n, n), extra_diag (o,), ok (o,) bool, n_jittered (int)).
    Fast path: one batched np.linalg.cholesky plus a LAPACK dtrtri per output.
    If any output fails, each is factorised alone; a failed one is retried
    with extra diagonal mean_diag * 1e-10 * 100**r, r = 0 .. max_jitter_retries-1;
    outputs that still fail get ok = False and a NaN linv.
    """
    n_out, n, _ = K.shape
    extra_diag = np.zeros(n_out)
    ok = np.ones(n_out, dtype=bool)
    try:
        chol = np.linalg.cholesky(K)
    except np.linalg.LinAlgError:
        chol = None
    if chol is not None:
        # dtrtri on the F-contiguous transpose (upper) avoids a copy; result transposed back.
        linv = np.array([dtrtri(chol[o].T, lower=0)[0].T for o in range(n_out)])
        finite = np.isfinite(linv.sum(axis=(1, 2)))  # a sum propagates any inf / NaN
        if not finite.all():  # overflow in the inverse of a nearly singular factor
            ok = finite
            linv[~ok] = np.nan
        return linv, extra_diag, ok, 0

    linv = np.empty_like(K)
    n_jittered = 0
    for o in range(n_out):
        factor, info = dpotrf(K[o], lower=1, clean=1)
        if info != 0:
            extra = _JITTER_LADDER_START * float(np.trace(K[o])) / n
            for _ in range(max_jitter_retries):
                factor, info = dpotrf(K[o] + extra * np.eye(n), lower=1, clean=1)
                if info == 0:
                    extra_diag[o] = extra
                    n_jittered += 1
                    break
                extra *= _JITTER_LADDER_FACTOR
        if info == 0:
            inverse, info = dtrtri(factor, lower=1)
        if info != 0 or not np.all(np.isfinite(inverse)):
            ok[o] = False
            linv[o] = np.nan
            continue
        linv[o] = inverse
    return linv, extra_diag, ok, n_jittered


def _evaluate_reference(
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
    """alpha = K^-1 y = Linv^T (Linv y) per output, (o, n), two O(n^2) products."""
    return np.einsum("oba,ob->oa", linv, np.einsum("oab,ob->oa", linv, Y_fit))


def _predict_with_factor_reference(window: _Window, X_star, log_theta, linv, alpha):
    """(o, m) normalised mean and latent variance (clipped at 0) (R&W Alg. 2.1 lines 4-6).

    NumPy reference of :func:`_predict_kernel` (tests compare the two)."""
    K_star = _signal_kernels(_neg_half_sq_diff_t(X_star, window.X), X_star.shape[0], window.n, log_theta)
    mean = np.einsum("omn,on->om", K_star, alpha)
    v = K_star @ linv.transpose(0, 2, 1)  # (o, m, n): rows of (Linv K_star^T)^T
    var = np.maximum(np.exp(log_theta[:, :1]) - np.einsum("oma,oma->om", v, v), 0.0)
    return mean, var


# --------------------------------------------------------------------------
# Compiled kernels (numba): the same algebra as the NumPy references above,
# one call per batched evaluation instead of ~40 small NumPy calls
# --------------------------------------------------------------------------
# At the paper's N = 10 the NumPy formulation costs ~200 us per evaluation, almost
# all of it call overhead (a batched Cholesky plus one LAPACK dtrtri per row, ~20
# einsum/matmul calls); these loops do the same flops in ~15 us. They differ from
# the references only by rounding (summation order); tests compare them. A
# Cholesky that fails (a pivot <= 0 or NaN, as LAPACK's dpotrf) makes the wrapper
# rerun the NumPy reference, whose jitter ladder and event counting then apply
# unchanged.

_NO_FACTOR = np.empty((0, 0, 0))

# Above this window a bare factorisation (no gradient) is faster in LAPACK's blocked
# Cholesky and triangular inverse than in the unblocked compiled loops (measured
# crossover ~60 samples, 6 outputs, d = 12). With the gradient the compiled kernel is
# faster at every size measured (10 - 200): the reference then also pays K^-1 and
# the O(n^2 d) gradient in several NumPy passes.
_COMPILED_FACTOR_MAX_WINDOW = 60


@numba.njit(cache=True)
def _evaluate_kernel(X, Y_fit, log_theta, sn2, jitter, cached_linv, with_gradient):  # pragma: no cover - compiled
    """Compiled `_evaluate_reference` (R&W Alg. 2.1 and eq. 5.9, per row of log_theta).

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
        exponent[:] = 0.0  # sum_j inv_l2_j D_j, summed in j order as the reference's matmul
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
        # alpha = K^-1 y = L^-T (L^-1 y), two triangular products. (The reference forms
        # K^-1 first; with K's condition number ~1e9 on clean closed-loop windows,
        # sn2 ~ 1e-5 against sf2 ~ 300, that loses ~100x more digits: predictive means
        # ~3e-5 N m from an extended-precision solve, against ~2e-7 this way.)
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
    """Compiled `_predict_with_factor_reference`: (o, m) mean and latent variance (>= 0)."""
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
    """`_evaluate_reference` by the compiled kernel; the reference reruns if a Cholesky fails."""
    result = _evaluate_kernel(
        np.ascontiguousarray(window.X, dtype=np.float64),
        np.ascontiguousarray(Y_fit, dtype=np.float64),
        np.ascontiguousarray(log_theta, dtype=np.float64),
        np.ascontiguousarray(sn2, dtype=np.float64),
        float(jitter),
        _NO_FACTOR if cached is None else np.ascontiguousarray(cached[0]),
        bool(with_gradient),
    )
    lml, grad, half_trace_w, alpha, linv, linv_finite, factorised = result
    if not factorised:
        return _evaluate_reference(
            window, Y_fit, log_theta, sn2, jitter, max_jitter_retries, with_gradient, cached
        )
    if cached is None:
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


def _check_thetas(thetas, n_outputs: int, n_inputs: int) -> np.ndarray:
    thetas = _as_finite_array("thetas", thetas, 2)
    if thetas.shape != (n_outputs, n_inputs + 2):
        raise ValueError(
            f"thetas must have shape (n_outputs, d+2) = ({n_outputs}, {n_inputs + 2}), one row "
            f"[sf2, sn2, l_1..l_d] per output; got {thetas.shape}"
        )
    _check_theta_values("thetas", thetas)
    return thetas


def _evaluate_or_raise(X, Y, thetas, jitter, with_gradient):
    n_out = Y.shape[1]
    window = _Window(X, np.ascontiguousarray(Y.T), np.zeros(n_out), np.ones(n_out))
    log_theta = np.log(np.maximum(thetas, np.finfo(float).tiny))  # sn2 = 0 handled via thetas[:, 1]
    evaluation = _evaluate(window, window.Y_fit, log_theta, thetas[:, 1], jitter, 0, with_gradient)
    if not evaluation.ok.all():
        raise np.linalg.LinAlgError(
            f"K + (sn2 + jitter) I is not positive definite for outputs {np.flatnonzero(~evaluation.ok).tolist()}; "
            "increase sn2 or jitter"
        )
    return window, log_theta, evaluation


def predict_multi(X, Y, X_star, thetas, *, include_noise: bool = True, jitter: float = 0.0):
    """Batched `predict` for o independent outputs sharing the inputs.

    Args:
        X: (n, d); Y: (n, o); X_star: (m, d); thetas: (o, d+2), row o is
        [sf2, sn2, l_1..l_d] of output o (natural scale).

    Returns:
        mean (m, o), var (m, o); equal to calling `predict` per column.
    """
    X = _check_matrix("X", X)
    n, d = X.shape
    Y = _check_matrix("Y", Y, n_rows=n)
    X_star = _check_matrix("X_star", X_star, n_cols=d)
    thetas = _check_thetas(thetas, Y.shape[1], d)
    jitter = _check_jitter(jitter)
    window, log_theta, evaluation = _evaluate_or_raise(X, Y, thetas, jitter, with_gradient=False)
    linv = evaluation.linv
    alpha = _solve_with_factor(linv, window.Y_fit)
    mean, var = _predict_with_factor(window, X_star, log_theta, linv, alpha)
    if include_noise:
        var = var + thetas[:, 1:2]
    return mean.T, var.T


def log_marginal_likelihood_multi(X, Y, thetas, *, jitter: float = 0.0):
    """Batched `log_marginal_likelihood`: lml (o,), grad (o, d+2) w.r.t. natural theta."""
    X = _check_matrix("X", X)
    n, d = X.shape
    Y = _check_matrix("Y", Y, n_rows=n)
    thetas = _check_thetas(thetas, Y.shape[1], d)
    jitter = _check_jitter(jitter)
    _, _, evaluation = _evaluate_or_raise(X, Y, thetas, jitter, with_gradient=True)
    grad = evaluation.grad / thetas  # dL/dtheta = (dL/dlog theta) / theta
    grad[:, 1] = evaluation.half_trace_w  # direct form, valid at sn2 = 0 too
    return evaluation.lml, grad


# --------------------------------------------------------------------------
# Incremental factor update (fixed hyperparameters)
# --------------------------------------------------------------------------


def _drop_oldest(linv: np.ndarray) -> np.ndarray:
    """Inverse Cholesky factor (o, n-1, n-1) of K[1:, 1:] from that (o, n, n) of K.

    Linv = [[a, 0], [b, M]], M = L_rr^-1, p = L_rr^-1 l_r0 = -b/a, and
    K_rr = L_rr (I + p p^T) L_rr^T. With t_i = 1 + sum_{k<=i} p_k^2 (t_{-1} = 1),
    chol(I + p p^T) = Lt D^1/2 with Lt^-1 = I - tril_{-1}(u p^T), u_i = p_i / t_{i-1},
    D_ii = t_i / t_{i-1} (Gill et al. 1974, method C1). Hence
    Linv' = D^-1/2 (M - u * cumsum_exclusive(p M)).
    """
    a = linv[:, 0, 0]
    p = -linv[:, 1:, 0] / a[:, None]  # (o, n-1)
    M = linv[:, 1:, 1:]
    t = 1.0 + np.cumsum(p * p, axis=1)
    t_prev = np.concatenate([np.ones((p.shape[0], 1)), t[:, :-1]], axis=1)
    u = p / t_prev
    weighted_rows = np.cumsum(p[:, :, None] * M, axis=1)  # inclusive prefix sums of p_j M[j, :]
    exclusive = np.zeros_like(M)
    exclusive[:, 1:] = weighted_rows[:, :-1]
    return (M - u[:, :, None] * exclusive) * np.sqrt(t_prev / t)[:, :, None]


def _append_sample(linv: np.ndarray, k_new: np.ndarray, kappa: np.ndarray, min_schur: np.ndarray):
    """Inverse factor (o, n+1, n+1) after appending a sample with kernel column k_new (o, n)
    and prior diagonal kappa (o,); None if a Schur complement falls below min_schur (o,)."""
    c = np.einsum("oab,ob->oa", linv, k_new)
    schur = kappa - np.einsum("oa,oa->o", c, c)
    if not (np.all(np.isfinite(schur)) and np.all(schur > min_schur)):
        return None
    delta = np.sqrt(schur)
    n_out, n, _ = linv.shape
    grown = np.zeros((n_out, n + 1, n + 1))
    grown[:, :n, :n] = linv
    grown[:, n, :n] = -np.einsum("oba,ob->oa", linv, c) / delta[:, None]
    grown[:, n, n] = 1.0 / delta
    return grown


# --------------------------------------------------------------------------
# Config, statistics, online estimator
# --------------------------------------------------------------------------


def _require(condition: bool, field_name: str, message: str, value) -> None:
    if not condition:
        raise ValueError(f"GPConfig.{field_name} {message}; got {value!r}")


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _check_log_bounds(field_name: str, bounds) -> None:
    ok = (
        isinstance(bounds, tuple)
        and len(bounds) == 2
        and all(_is_number(b) and math.isfinite(b) for b in bounds)
        and bounds[0] < bounds[1]
    )
    _require(ok, field_name, "must be a tuple (low, high) of finite natural-log values with low < high", bounds)


LogBounds = Annotated[tuple[StrictFloat, StrictFloat], pydantic.Strict(False)]
"""A (low, high) pair of `GPConfig`: a list is accepted (TOML, YAML and ``--set`` have no
tuples), its items are strict (``[true, 1.0]`` is refused)."""

Floats = Annotated[tuple[StrictFloat, ...], pydantic.Strict(False)]
"""A vector of `GPConfig`: a list is accepted, its items are strict (see `LogBounds`)."""


@dataclass(frozen=True)
class GPConfig:
    """Validated, immutable settings of `SlidingWindowGP` (paper Algorithm 1 + our safeguards).

    Defaults are the paper's where it gives a value (window 10, theta0 = 1, no
    target scaling) and measured choices otherwise (module docstring).

    Fields:
        window: N_train, samples kept (int in [2, 1000]; paper 10).
        hyper_steps: gradient-ascent steps on the LML per update (int in [0, 100];
            0 = fixed hyperparameters). Default 1 per 10 ms control step:
            3 steps cost ~2.2x as much for a small gain (module docstring).
        learning_rate: step = learning_rate * dL/dlog(theta) (float > 0), log space.
        max_log_step: cap on |change| of any log-hyperparameter per step (float > 0).
        max_step_halvings: halvings of a step that would decrease the LML before
            the step is rejected (int in [0, 20]); each level adds one stacked
            candidate per output to the batch (0 is ~15 % cheaper, same accuracy
            in our trials).
        grad_tol: the paper's training accuracy epsilon: an output stops
            stepping when max |dL/dlog theta| <= grad_tol (float >= 0; 0 = always step).
        log_sf2_bounds, log_sn2_bounds, log_lengthscale_bounds: box bounds
            (natural log, within [-100, 100]) for sf2, sn2 and every lengthscale. sf2, sn2 are in
            fitted target units^2 (N*m^2 for raw torques; unit-free with
            normalize_y or output_scale), lengthscales in scaled input units.
            Defaults for raw torques: sf2 in [1e-4, 1e8], sn2 in [1e-6, 1e6]
            (a lower sn2 floor, 1e-8, made noise-free fits over-confident and
            ~40x less accurate), lengthscales in [1e-2, 1e3].
        theta0: initial [sf2, sn2, l_1..l_d] for every output (natural scale),
            or None for all ones (paper). Must lie within the bounds.
        normalize_y: standardise each output's window targets by the window
            mean and (population) std before fitting, as sklearn's normalize_y
            (the paper does not). Measured worse on the arm; off by default.
        input_scale: per-feature divisors (tuple of d floats in [1e-6, 1e6]) applied to
            inputs before the kernel, or None. Set it when inputs mix units
            (e.g. torques ~ 500 N*m next to angles ~ 1 rad).
        output_scale: per-output (or one common) divisor of the targets (floats
            in [1e-6, 1e6]), or None; excludes normalize_y.
        jitter: absolute value added to the training diagonal (float >= 0;
            like sklearn's alpha).
        max_jitter_retries: retries with growing extra diagonal after a failed
            Cholesky (int in [0, 20]).
        incremental_min_window: use the O(N^2) rank update of the factor when
            the window holds at least this many samples and theta is unchanged
            since the last factorisation (int >= 2); measured break-even ~20.
        refactor_every: force a full refactorisation after this many
            consecutive incremental updates (int >= 1).

    As the ``gp`` section of the experiment settings (a mapping validated by pydantic, see
    `hydroarm.config.FrozenModel`), unknown keys, NaN and infinities are refused and every
    field is strict (``StrictInt``, ``StrictFloat``, ``StrictBool``: no boolean or string
    for a number, no number or string for a boolean, no float for an int); the tuples also
    take lists (`LogBounds`, `Floats`). The pydantic config below is not strict itself:
    in strict mode pydantic accepts only a ``GPConfig`` instance for a dataclass, not a
    mapping. Constructing a ``GPConfig`` directly does not go through pydantic:
    ``__post_init__`` checks every field.
    """

    __pydantic_config__ = pydantic.ConfigDict(extra="forbid", allow_inf_nan=False)  # not a field: no annotation

    window: StrictInt = 10
    hyper_steps: StrictInt = 1
    learning_rate: StrictFloat = 0.1
    max_log_step: StrictFloat = 1.0
    max_step_halvings: StrictInt = 1
    grad_tol: StrictFloat = 0.0
    log_sf2_bounds: LogBounds = (math.log(1e-4), math.log(1e8))
    log_sn2_bounds: LogBounds = (math.log(1e-6), math.log(1e6))
    log_lengthscale_bounds: LogBounds = (math.log(1e-2), math.log(1e3))
    theta0: Floats | None = None
    normalize_y: StrictBool = False
    input_scale: Floats | None = None
    output_scale: Floats | None = None
    jitter: StrictFloat = 1e-10
    max_jitter_retries: StrictInt = 4
    incremental_min_window: StrictInt = 30
    refactor_every: StrictInt = 100

    def __post_init__(self) -> None:
        """Check every field; a bad one raises ``hydroarm.config.ConfigError`` (a ValueError)
        ``GPConfig.<field> = <value>: <what is allowed>`` that names the field, so that an
        enclosing settings file reports it as ``gp.<field>``."""
        from hydroarm.config import ConfigError, field_error

        try:
            self._check_fields()
        except ConfigError:
            raise
        except ValueError as error:  # from _require: "GPConfig.<field> <rule>; got <value>"
            name, _, rest = str(error).removeprefix("GPConfig.").partition(" ")
            rule = rest.rsplit("; got ", 1)[0]
            value = getattr(self, name, None)
            if isinstance(value, tuple):  # name the first entry out of range
                for k, item in enumerate(value):
                    if not (_is_number(item) and math.isfinite(item)):
                        bad = True
                    elif name.startswith("log_"):
                        bad = False
                    else:  # theta0 entries > 0, scales in [1e-6, 1e6]
                        bad = not (1e-6 <= item <= 1e6) if name.endswith("_scale") else item <= 0
                    if bad:
                        raise field_error(f"{name}.{k}", item, rule, prefix="GPConfig.") from None
            raise field_error(name, value, rule, prefix="GPConfig.") from None

    def _check_fields(self) -> None:
        _require(
            _is_int(self.window) and 2 <= self.window <= 1000, "window", "must be an int >= 2 and <= 1000", self.window
        )
        _require(
            _is_int(self.hyper_steps) and 0 <= self.hyper_steps <= 100,
            "hyper_steps",
            "must be an int >= 0 and <= 100",
            self.hyper_steps,
        )
        for name in ("learning_rate", "max_log_step"):
            value = getattr(self, name)
            ok = _is_number(value) and math.isfinite(value) and value > 0
            _require(ok, name, "must be a finite float > 0", value)
        for name in ("grad_tol", "jitter"):
            value = getattr(self, name)
            ok = _is_number(value) and math.isfinite(value) and value >= 0
            _require(ok, name, "must be a finite float >= 0", value)
        for name in ("max_step_halvings", "max_jitter_retries"):
            value = getattr(self, name)
            _require(_is_int(value) and 0 <= value <= 20, name, "must be an int >= 0 and <= 20", value)
        _require(
            _is_int(self.incremental_min_window) and self.incremental_min_window >= 2,
            "incremental_min_window",
            "must be an int >= 2",
            self.incremental_min_window,
        )
        _require(
            _is_int(self.refactor_every) and self.refactor_every >= 1,
            "refactor_every",
            "must be an int >= 1",
            self.refactor_every,
        )
        _require(isinstance(self.normalize_y, bool), "normalize_y", "must be a bool", self.normalize_y)
        for name in ("log_sf2_bounds", "log_sn2_bounds", "log_lengthscale_bounds"):
            _check_log_bounds(name, getattr(self, name))
            low, high = getattr(self, name)
            _require(
                -100.0 <= low and high <= 100.0,
                name,
                "must lie within [-100, 100] (exp(100) ~ 2.7e43: wider bounds overflow the kernel)",
                (low, high),
            )
        if self.theta0 is not None:
            theta0 = self.theta0
            ok = (
                isinstance(theta0, tuple)
                and len(theta0) >= 3
                and all(_is_number(v) and math.isfinite(v) and v > 0 for v in theta0)
            )
            _require(ok, "theta0", "must be None or a tuple (sf2, sn2, l_1..l_d) of finite floats > 0", theta0)
            log_theta0 = [math.log(v) for v in theta0]
            names = ["sf2", "sn2"] + [f"l_{j + 1}" for j in range(len(theta0) - 2)]
            fields = ["log_sf2_bounds", "log_sn2_bounds"] + ["log_lengthscale_bounds"] * (len(theta0) - 2)
            for name, entry, value, field_name in zip(names, theta0, log_theta0, fields):
                low, high = getattr(self, field_name)
                _require(
                    low <= value <= high,
                    "theta0",
                    f"entry {name} = {entry!r} must lie within exp({field_name} = {(low, high)!r}) "
                    f"= [{math.exp(low):.3g}, {math.exp(high):.3g}]",
                    theta0,
                )
        else:
            for name in ("log_sf2_bounds", "log_sn2_bounds", "log_lengthscale_bounds"):
                low, high = getattr(self, name)
                _require(low <= 0.0 <= high, name, "must contain 0 (theta0=None initialises theta to 1)", (low, high))
        for name in ("input_scale", "output_scale"):
            value = getattr(self, name)
            ok = value is None or (
                isinstance(value, tuple)
                and len(value) >= 1
                and all(_is_number(v) and math.isfinite(v) and 1e-6 <= v <= 1e6 for v in value)
            )
            _require(ok, name, "must be None or a tuple of floats >= 1e-6 and <= 1e6", value)
        _require(
            not (self.normalize_y and self.output_scale is not None),
            "output_scale",
            "must be None when normalize_y is True (choose one target scaling)",
            self.output_scale,
        )


@dataclass
class GPStats:
    """Counters of `SlidingWindowGP` events (summed over outputs)."""

    n_updates: int = 0  # update_hyperparameters calls that ran steps
    n_accepted_steps: int = 0  # per output and step, LML did not decrease
    n_rejected_steps: int = 0  # per output and step, every halving decreased the LML (theta kept)
    n_step_halvings: int = 0
    n_jittered_factorizations: int = 0  # Cholesky succeeded only with extra diagonal
    n_cholesky_fallbacks: int = 0  # Cholesky failed even with max jitter: previous theta / prior kept
    n_prior_predictions: int = 0  # outputs predicted from the prior because no factor existed
    n_full_factorizations: int = 0  # stacked (all outputs) full factorisations of a window
    n_incremental_updates: int = 0  # O(N^2) window updates of the factor

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class SlidingWindowGP:
    """n_outputs independent sliding-window GPs sharing their inputs (paper Algorithm 1).

    Usage at control step k::

        gp.add(x_prev, residual_prev)      # newest sample; the oldest drops out when full
        gp.update_hyperparameters()        # <= hyper_steps safeguarded gradient steps
        mean, var = gp.predict(x_now)      # (n_outputs,), (n_outputs,)

    Args:
        n_inputs: d, the input dimension (e.g. 12 for the state).
        n_outputs: number of outputs / independent GPs (default 6 joints).
        config: GPConfig (defaults if None).

    State (read-only from outside): ``config``, ``stats`` (GPStats),
    ``n_samples``, ``theta`` (n_outputs, d+2) natural scale, ``log_theta``,
    ``window_inputs`` (n, d) in original units and ``window_targets``
    (n, n_outputs), oldest first.
    """

    def __init__(self, n_inputs: int, n_outputs: int = 6, config: GPConfig | None = None) -> None:
        if not (_is_int(n_inputs) and n_inputs >= 1):
            raise ValueError(f"n_inputs must be an int >= 1; got {n_inputs!r}")
        if not (_is_int(n_outputs) and n_outputs >= 1):
            raise ValueError(f"n_outputs must be an int >= 1; got {n_outputs!r}")
        config = GPConfig() if config is None else config
        if not isinstance(config, GPConfig):
            raise ValueError(f"config must be a GPConfig; got {type(config).__name__}")
        from hydroarm.config import field_error

        if config.theta0 is not None and len(config.theta0) != n_inputs + 2:
            raise field_error(
                "theta0", config.theta0, f"{len(config.theta0)} values: give d+2 = {n_inputs + 2} for {n_inputs} inputs",
                prefix="GPConfig.",
            )
        if config.input_scale is not None and len(config.input_scale) != n_inputs:
            raise field_error(
                "input_scale", config.input_scale, f"{len(config.input_scale)} values: give one per input ({n_inputs})",
                prefix="GPConfig.",
            )
        if config.output_scale is not None and len(config.output_scale) not in (1, n_outputs):
            raise field_error(
                "output_scale", config.output_scale,
                f"{len(config.output_scale)} values: give 1 or one per output ({n_outputs})", prefix="GPConfig.",
            )
        self.n_inputs = int(n_inputs)
        self.n_outputs = int(n_outputs)
        self.config = config
        if config.input_scale is None:
            self._inv_input_scale = np.ones(n_inputs)
        else:
            self._inv_input_scale = 1.0 / np.asarray(config.input_scale, dtype=float)
        self._targets_scaled = config.normalize_y or config.output_scale is not None
        self._output_scale = np.ones(n_outputs)
        if config.output_scale is not None:
            self._output_scale = self._output_scale * np.asarray(config.output_scale, dtype=float)
        lower = [config.log_sf2_bounds[0], config.log_sn2_bounds[0]] + [config.log_lengthscale_bounds[0]] * n_inputs
        upper = [config.log_sf2_bounds[1], config.log_sn2_bounds[1]] + [config.log_lengthscale_bounds[1]] * n_inputs
        self._log_lower = np.array(lower)
        self._log_upper = np.array(upper)
        theta0 = np.ones(n_inputs + 2) if config.theta0 is None else np.asarray(config.theta0, dtype=float)
        self._log_theta0 = np.log(theta0)
        self.reset()

    # ----- state ------------------------------------------------------------

    def reset(self) -> None:
        """Empty the window, restore theta0 and zero the statistics."""
        self._X_raw = np.empty((0, self.n_inputs))  # inputs as given, oldest first
        self._X = np.empty((0, self.n_inputs))  # scaled inputs
        self._Y = np.empty((0, self.n_outputs))
        self._log_theta = np.tile(self._log_theta0, (self.n_outputs, 1))
        self.stats = GPStats()
        self._window = None  # _Window cache for the current samples
        self._previous_gradient = None  # dL/dlog theta at the current theta, previous window
        self._invalidate_factor()

    def _invalidate_factor(self) -> None:
        self._linv = None  # (o, n, n) inverse Cholesky factors for the current theta and window
        self._extra_diag = np.zeros(self.n_outputs)  # jitter beyond config.jitter used per output
        self._factor_ok = np.ones(self.n_outputs, dtype=bool)
        self._n_incremental_since_full = 0
        self._alpha = None  # (o, n) K^-1 y_fit

    @property
    def n_samples(self) -> int:
        return self._X.shape[0]

    @property
    def theta(self) -> np.ndarray:
        """(n_outputs, d+2) [sf2, sn2, l_1..l_d] per output, natural scale (copy)."""
        return np.exp(self._log_theta)

    @property
    def log_theta(self) -> np.ndarray:
        return self._log_theta.copy()

    @property
    def log_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower (d+2,), upper (d+2,)) natural-log bounds of [sf2, sn2, l_1..l_d]."""
        return self._log_lower.copy(), self._log_upper.copy()

    @property
    def window_inputs(self) -> np.ndarray:
        return self._X_raw.copy()

    @property
    def window_targets(self) -> np.ndarray:
        return self._Y.copy()

    def set_theta(self, theta) -> None:
        """Set hyperparameters: (d+2,) for every output or (n_outputs, d+2); within the bounds."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape == (self.n_inputs + 2,):
            theta = np.tile(theta, (self.n_outputs, 1))
        theta = _check_thetas(theta, self.n_outputs, self.n_inputs)
        if theta[:, 1].min() <= 0:
            raise ValueError("theta: sn2 (index 1) must be > 0 for SlidingWindowGP")
        log_theta = np.log(theta)
        tolerance = 1e-12
        if np.any(log_theta < self._log_lower - tolerance) or np.any(log_theta > self._log_upper + tolerance):
            raise ValueError(
                "theta must lie within exp(GPConfig.log_sf2_bounds / log_sn2_bounds / log_lengthscale_bounds)"
            )
        self._log_theta = np.clip(log_theta, self._log_lower, self._log_upper)
        self._previous_gradient = None
        self._invalidate_factor()

    # ----- data ---------------------------------------------------------------

    def add(self, x, y) -> None:
        """Append one sample x (d,), y (n_outputs,); drop the oldest when the window is full.

        If the hyperparameters are unchanged since the last factorisation and
        the window is large enough (GPConfig.incremental_min_window), the
        factor is rank-updated in O(N^2); otherwise it is recomputed lazily.
        """
        x = _check_vector("x", x, self.n_inputs)
        y = _check_vector("y", y, self.n_outputs)
        x_scaled = x * self._inv_input_scale
        full = self.n_samples >= self.config.window
        n_new = self.n_samples if full else self.n_samples + 1
        use_incremental = (
            self._linv is not None
            and bool(self._factor_ok.all())
            and n_new >= self.config.incremental_min_window
            and self._n_incremental_since_full < self.config.refactor_every
        )
        keep = slice(1, None) if full else slice(None)
        self._X_raw = np.concatenate([self._X_raw[keep], x[None]])
        self._X = np.concatenate([self._X[keep], x_scaled[None]])
        self._Y = np.concatenate([self._Y[keep], y[None]])
        self._window = None
        self._alpha = None
        if not use_incremental:
            self._linv = None
            return
        linv = _drop_oldest(self._linv) if full else self._linv
        grown = self._append_to_factor(linv, x_scaled)
        if grown is None:
            self._invalidate_factor()
            return
        self._linv = grown
        self._n_incremental_since_full += 1
        self.stats.n_incremental_updates += 1

    def _append_to_factor(self, linv: np.ndarray, x_scaled: np.ndarray):
        X_old = self._X[:-1]
        k_new = _signal_kernels(_neg_half_sq_diff_t(x_scaled[None], X_old), 1, X_old.shape[0], self._log_theta)
        noise = np.exp(self._log_theta[:, 1]) + self.config.jitter + self._extra_diag
        kappa = np.exp(self._log_theta[:, 0]) + noise
        # The exact Schur complement is >= the diagonal noise; much less means round-off drift.
        return _append_sample(linv, k_new[:, 0, :], kappa, 0.5 * noise)

    def _current_window(self) -> _Window:
        """Cached window data; targets standardised per output if normalize_y
        (population std as sklearn; a (near-)zero std is replaced by 1)."""
        if self._window is None:
            Y = self._Y
            if self.config.normalize_y:
                y_mean = Y.mean(axis=0)
                y_std = Y.std(axis=0)
                y_std = np.where(y_std > 1e-12 * np.maximum(np.abs(y_mean), 1.0), y_std, 1.0)
            else:
                y_mean, y_std = np.zeros(self.n_outputs), self._output_scale
            Y_fit = ((Y - y_mean) / y_std).T
            self._window = _Window(self._X, np.ascontiguousarray(Y_fit), y_mean, y_std)
        return self._window

    # ----- factorisation ------------------------------------------------------

    def _evaluate(self, window: _Window, log_theta: np.ndarray, cached=None) -> _Evaluation:
        """`_evaluate` (with gradient) with this GP's settings.

        log_theta may stack several candidates per output: row r belongs to
        output r % n_outputs. Factorisation events are counted by the caller.
        """
        n_repeats = log_theta.shape[0] // self.n_outputs
        Y_fit = window.Y_fit if n_repeats == 1 else np.concatenate([window.Y_fit] * n_repeats)
        cfg = self.config
        if cached is None:
            self.stats.n_full_factorizations += n_repeats
        return _evaluate(
            window, Y_fit, log_theta, np.exp(log_theta[:, 1]), cfg.jitter, cfg.max_jitter_retries, True, cached
        )

    def _count_factorization_events(self, evaluation: _Evaluation, relevant: np.ndarray | None = None) -> None:
        """Count jittered and failed factorisations among the relevant rows (all if None)."""
        ok, jittered = evaluation.ok, evaluation.extra_diag > 0
        if relevant is not None:
            ok, jittered = ok | ~relevant, jittered & relevant
        self.stats.n_cholesky_fallbacks += int(ok.size - np.count_nonzero(ok))
        self.stats.n_jittered_factorizations += int(np.count_nonzero(jittered))

    def _ensure_factor(self, window: _Window) -> None:
        if self._linv is not None:
            return
        n = window.n
        sn2 = np.exp(self._log_theta[:, 1])
        compiled = (None,) * 7
        if n <= _COMPILED_FACTOR_MAX_WINDOW:
            compiled = _evaluate_kernel(
                np.ascontiguousarray(window.X), window.Y_fit, self._log_theta, sn2, float(self.config.jitter),
                _NO_FACTOR, False,
            )  # fmt: skip
        if compiled[6]:  # every Cholesky succeeded: the factor (and alpha) as the reference below
            linv, extra_diag, ok, n_jittered = compiled[4], np.zeros(self.n_outputs), compiled[5], 0
            alpha = compiled[3]
        else:
            K_signal = _signal_kernels(window.neg_half_sq_diff_t, n, n, self._log_theta)
            K = K_signal + (sn2 + self.config.jitter)[:, None, None] * window.eye
            linv, extra_diag, ok, n_jittered = _cholesky_inverse(K, self.config.max_jitter_retries)
            alpha = None
        self.stats.n_full_factorizations += 1
        self.stats.n_jittered_factorizations += n_jittered
        self.stats.n_cholesky_fallbacks += int(self.n_outputs - np.count_nonzero(ok))
        self._linv, self._extra_diag, self._factor_ok = linv, extra_diag, ok
        self._n_incremental_since_full = 0
        self._alpha = alpha if ok.all() else None

    # ----- hyperparameters ----------------------------------------------------

    def update_hyperparameters(self) -> np.ndarray:
        """Up to hyper_steps safeguarded gradient-ascent steps on each output's LML.

        Paper Algorithm 1 lines 2-7, made robust: in log space,
        delta = clip(learning_rate * dL/dlog theta, +-max_log_step) and
        candidate_a = clip(log theta + delta, log bounds) shrunk by 0.5**a,
        a = 0 .. max_step_halvings. The largest candidate whose LML on the
        current window is >= that of the current theta is accepted (the same
        outcome as halving and retrying); if none is, the step is rejected
        (theta kept; that output stops stepping for this update). A candidate
        whose Cholesky fails even with jitter counts as not acceptable.
        Warm-started from the current theta; all outputs together.

        Cost (NumPy call overhead dominates at N = 10): the halved candidates
        are factorised in the same stacked batch as the full step, and the
        first step's direction is the gradient at the current theta computed
        at the end of the previous update (on the window one sample older), so
        the current theta and the first candidates also share one batch: one
        hyperparameter step costs one batched evaluation. The acceptance test is
        always exact on the current window, so the LML never decreases.

        Returns:
            lml_trace (k+1, n_outputs): LML on the current window at the
            current theta and after each of the k steps taken (NaN for outputs
            whose factorisation failed); shape (0, n_outputs) if hyper_steps = 0
            or the window is empty (then nothing is done).
        """
        cfg = self.config
        n_out = self.n_outputs
        if cfg.hyper_steps == 0 or self.n_samples == 0:
            return np.empty((0, n_out))
        self.stats.n_updates += 1
        window = self._current_window()
        log_theta = self._log_theta
        n_attempts = cfg.max_step_halvings + 1
        merged_candidates = None
        if self._linv is not None and self._factor_ok.all():  # factor kept by the incremental path
            current = self._evaluate(window, log_theta, cached=(self._linv, self._extra_diag))
        elif self._previous_gradient is not None:
            merged_candidates = self._candidates(log_theta, self._previous_gradient, n_attempts)
            stacked = self._evaluate(window, np.concatenate([log_theta, merged_candidates]))
            current = _rows(stacked, 0, n_out)
            merged_trials = _rows(stacked, n_out, stacked.lml.shape[0])
            self._count_factorization_events(current)
        else:
            current = self._evaluate(window, log_theta)
            self._count_factorization_events(current)
        lml, grad, alpha = current.lml, current.grad, current.alpha
        linv, extra_diag, factor_ok = current.linv, current.extra_diag, current.ok
        if not factor_ok.all():  # no steps (and no NaN candidates) for outputs without a factor
            grad = np.where(factor_ok[:, None], grad, 0.0)
        active = factor_ok
        trace = [lml]
        for step in range(cfg.hyper_steps):
            if cfg.grad_tol > 0:
                active = active & (np.abs(grad).max(axis=1) > cfg.grad_tol)
            if not active.any():
                break
            if step == 0 and merged_candidates is not None:
                candidates, trials = merged_candidates, merged_trials
            else:
                candidates = self._candidates(log_theta, grad, n_attempts)
                trials = self._evaluate(window, candidates)
            pending = active
            for attempt in range(n_attempts):
                rows = slice(attempt * n_out, (attempt + 1) * n_out)
                trial = _rows(trials, rows.start, rows.stop)
                candidate = candidates[rows]
                self._count_factorization_events(trial, pending)
                accept = pending & trial.ok & (trial.lml >= lml)
                n_accepted = int(np.count_nonzero(accept))
                if n_accepted == n_out:
                    log_theta, lml, grad, alpha = candidate, trial.lml, trial.grad, trial.alpha
                    linv, extra_diag = trial.linv, trial.extra_diag
                elif n_accepted > 0:
                    log_theta = np.where(accept[:, None], candidate, log_theta)
                    lml = np.where(accept, trial.lml, lml)
                    grad = np.where(accept[:, None], trial.grad, grad)
                    alpha = np.where(accept[:, None], trial.alpha, alpha)
                    linv = np.where(accept[:, None, None], trial.linv, linv)
                    extra_diag = np.where(accept, trial.extra_diag, extra_diag)
                self.stats.n_accepted_steps += n_accepted
                pending = pending & ~accept
                n_pending = int(np.count_nonzero(pending))
                if n_pending == 0:
                    break
                if attempt < n_attempts - 1:
                    self.stats.n_step_halvings += n_pending
            self.stats.n_rejected_steps += n_pending
            if n_pending:
                active = active & ~pending
            trace.append(lml)

        self._log_theta = log_theta
        self._previous_gradient = grad
        self._linv, self._extra_diag, self._factor_ok = linv, extra_diag, factor_ok
        self._n_incremental_since_full = 0
        self._alpha = alpha
        return np.array(trace)

    def _candidates(self, log_theta: np.ndarray, grad: np.ndarray, n_attempts: int) -> np.ndarray:
        """(n_attempts * n_outputs, d+2) stacked candidates, attempt a = full step * 0.5**a.

        Full step: clip(log theta + clip(learning_rate * grad, +-max_log_step), log bounds);
        the halved ones lie on the segment to log theta, hence inside the bounds too.
        """
        cfg = self.config
        step = np.minimum(np.maximum(cfg.learning_rate * grad, -cfg.max_log_step), cfg.max_log_step)
        full_step = np.minimum(np.maximum(log_theta + step, self._log_lower), self._log_upper)
        if n_attempts == 1:
            return full_step
        delta = full_step - log_theta
        shrink = 0.5 ** np.arange(1, n_attempts)
        halved = log_theta[None] + shrink[:, None, None] * delta[None]
        return np.concatenate([full_step, halved.reshape(-1, log_theta.shape[1])])

    # ----- prediction ---------------------------------------------------------

    def predict(self, x_star, *, include_noise: bool = True):
        """Predictive mean and variance at x_star (d,) or (m, d) (R&W Alg. 2.1).

        Returns:
            mean, var of shape (n_outputs,) for x_star (d,), else (m, n_outputs),
            in target units / units^2. var includes sn2 unless include_noise is
            False (latent variance). Outputs without a valid factor (Cholesky
            failed, counted in stats) and an empty window give the prior:
            mean 0 (window mean if normalize_y), var sf2 (+ sn2), scaled.
        """
        single = np.ndim(x_star) == 1
        if single:
            X_star = _check_vector("x_star", x_star, self.n_inputs)[None]
        else:
            X_star = _check_matrix("x_star", x_star, n_cols=self.n_inputs)
        X_star = X_star * self._inv_input_scale
        log_theta = self._log_theta
        sn2 = np.exp(log_theta[:, 1:2]) if include_noise else 0.0
        if self.n_samples == 0:
            mean = np.zeros((self.n_outputs, X_star.shape[0]))
            var = np.broadcast_to(np.exp(log_theta[:, :1]) + sn2, mean.shape).copy()
        else:
            window = self._current_window()
            self._ensure_factor(window)
            ok = self._factor_ok
            if self._alpha is None:
                self._alpha = _solve_with_factor(self._linv, window.Y_fit)
            if ok.all():
                mean, var = _predict_with_factor(window, X_star, log_theta, self._linv, self._alpha)
            else:  # prior for outputs without a factor
                self.stats.n_prior_predictions += int(self.n_outputs - ok.sum())
                mean = np.zeros((self.n_outputs, X_star.shape[0]))
                var = np.tile(np.exp(log_theta[:, :1]), (1, X_star.shape[0]))
                if ok.any():
                    mean[ok], var[ok] = _predict_with_factor(
                        window, X_star, log_theta[ok], self._linv[ok], self._alpha[ok]
                    )
            var = var + sn2
            if self._targets_scaled:
                mean = mean * window.y_std[:, None] + window.y_mean[:, None]
                var = var * (window.y_std**2)[:, None]
        if single:
            return mean[:, 0], var[:, 0]
        return mean.T, var.T
