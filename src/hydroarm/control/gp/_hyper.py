"""The hyperparameter update of `SlidingWindowGP` (paper Algorithm 1 lines 2-7, made robust) in
one compiled call, and the candidates' rule it shares with the NumPy path.

`SlidingWindowGP.update_hyperparameters` spent about two thirds of its time in Python around
its compiled evaluations (stacking candidates, the acceptance test, counting). `hyper_update`
runs the same steps in one numba call for the clean case: every factorisation of the update
succeeds without jitter and gives a finite LML. Anything else (a failed Cholesky, the jitter
ladder, a non-finite factor or LML, an output without a factor) returns None and the caller
runs its NumPy path from the same state, which handles the faults. The two paths give the same
bits in the clean case (a test): the same evaluation kernel (`_compiled._evaluate_kernel`, its
rows independent of each other, so stacking does not change them), the same elementwise
operations in the same order (no ``fastmath``: IEEE rounding per operation, as NumPy's).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from hydroarm.control.gp._compiled import _evaluate_kernel

__all__ = ["HyperUpdate", "candidates", "hyper_update"]


class HyperUpdate(NamedTuple):
    """A clean update's outcome: log theta (o, d+2), LML trace (k+1, o), gradient at the new
    theta (o, d+2), alpha (o, n), inverse factors (o, n, n), extra diagonal (o,) and the
    counters [full factorisations, accepted steps, step halvings, rejected steps]."""

    log_theta: np.ndarray
    trace: np.ndarray
    grad: np.ndarray
    alpha: np.ndarray
    linv: np.ndarray
    extra_diag: np.ndarray
    counts: np.ndarray


def candidates(log_theta, grad, n_attempts, config, bounds) -> np.ndarray:
    """(n_attempts * o, d+2) stacked candidates, attempt a = full step * 0.5**a.

    Full step: clip(log theta + clip(learning_rate * grad, +-max_log_step), bounds), ``bounds``
    the (lower, upper) log bounds (d+2,); the halved ones lie on the segment to log theta, hence
    inside the bounds too. ``config``: the GPConfig (learning_rate, max_log_step).
    """
    cap = config.max_log_step
    step = np.minimum(np.maximum(config.learning_rate * grad, -cap), cap)
    full_step = np.minimum(np.maximum(log_theta + step, bounds[0]), bounds[1])
    if n_attempts == 1:
        return full_step
    delta = full_step - log_theta
    shrink = 0.5 ** np.arange(1, n_attempts)
    halved = log_theta[None] + shrink[:, None, None] * delta[None]
    return np.concatenate([full_step, halved.reshape(-1, log_theta.shape[1])])


def hyper_update(window, log_theta, previous_gradient, cached, bounds, config) -> HyperUpdate | None:
    """`SlidingWindowGP._update_hyperparameters`'s steps in one compiled call, or None where the
    update is not clean (module docstring). ``window``: the `_batched._Window` (X (n, d), Y_fit
    (o, n)); ``cached``: (linv (o, n, n), extra_diag (o,)), the factor kept for the current
    theta, or None; ``previous_gradient`` (o, d+2) or None; ``bounds`` as `candidates`'."""
    linv, extra = (np.empty((0, 0, 0)), np.empty(0)) if cached is None else cached
    gradient = np.empty((0, 0)) if previous_gradient is None or cached is not None else previous_gradient
    out = _hyper_update_kernel(
        np.ascontiguousarray(window.X, dtype=np.float64), np.ascontiguousarray(window.Y_fit, dtype=np.float64),
        np.ascontiguousarray(log_theta, dtype=np.float64), np.ascontiguousarray(gradient, dtype=np.float64),
        np.ascontiguousarray(linv, dtype=np.float64), np.ascontiguousarray(extra, dtype=np.float64),
        bounds[0], bounds[1], float(config.jitter), int(config.hyper_steps), int(config.max_step_halvings) + 1,
        float(config.learning_rate), float(config.max_log_step), float(config.grad_tol),
    )  # fmt: skip
    return HyperUpdate(*out[1:]) if out[0] else None


@numba.njit(cache=True)
def _candidates_kernel(log_theta, grad, n_attempts, learning_rate, max_log_step, lower, upper):  # pragma: no cover
    """`candidates`, elementwise in the same operations (NaN passes through as there)."""
    n_out, n_dims = log_theta.shape
    out = np.empty((n_attempts * n_out, n_dims))
    for r in range(n_out):
        for j in range(n_dims):
            step = learning_rate * grad[r, j]
            step = -max_log_step if step < -max_log_step else step
            step = max_log_step if step > max_log_step else step
            full = log_theta[r, j] + step
            full = lower[j] if full < lower[j] else full
            full = upper[j] if full > upper[j] else full
            out[r, j] = full
            delta = full - log_theta[r, j]
            shrink = 1.0
            for a in range(1, n_attempts):
                shrink *= 0.5
                out[a * n_out + r, j] = log_theta[r, j] + shrink * delta
    return out


@numba.njit(cache=True)
def _evaluate_clean(X, Y_fit, rows, jitter, cached_linv):  # pragma: no cover - compiled
    """`_evaluate_kernel` with gradient of the stacked ``rows`` (row r: output r % o), and ok False
    where a factorisation failed or an LML or factor is not finite (the NumPy path's faults)."""
    n_out = Y_fit.shape[0]
    n_rows = rows.shape[0]
    stacked = np.empty((n_rows, Y_fit.shape[1]))
    sn2 = np.empty(n_rows)
    for r in range(n_rows):
        stacked[r] = Y_fit[r % n_out]
        sn2[r] = math.exp(rows[r, 1])  # as fixed_order.exp, the NumPy path's
    lml, grad, _, alpha, linv, finite, factorised = _evaluate_kernel(X, stacked, rows, sn2, jitter, cached_linv, True)
    ok = factorised
    for r in range(n_rows):
        ok = ok and finite[r] and np.isfinite(lml[r])
    return ok, lml, grad, alpha, linv


@numba.njit(cache=True)
def _still_active(active, grad, grad_tol):  # pragma: no cover - compiled
    """active & (max_j |grad[r, j]| > grad_tol) in place (a NaN gradient stops, as np.max's NaN)."""
    for r in range(grad.shape[0]):
        largest = abs(grad[r, 0])
        for j in range(1, grad.shape[1]):
            value = abs(grad[r, j])
            if value > largest or np.isnan(value):
                largest = value if not np.isnan(largest) else largest
        active[r] = active[r] and largest > grad_tol


@numba.njit(cache=True)
def _hyper_update_kernel(
    X, Y_fit, log_theta, previous_gradient, cached_linv, cached_extra, lower, upper,
    jitter, hyper_steps, n_attempts, learning_rate, max_log_step, grad_tol,
):  # pragma: no cover - compiled  # fmt: skip
    """`hyper_update`: (clean, log_theta, trace, grad, alpha, linv, extra_diag, counts); where not
    clean the rest is not meaningful. Nothing passed in is modified."""
    n_out = log_theta.shape[0]
    counts = np.zeros(4, dtype=np.int64)
    trace = np.empty((hyper_steps + 1, n_out))
    no_factor = np.empty((0, 0, 0))
    log_theta = log_theta.copy()
    merged = cached_linv.shape[0] != n_out and previous_gradient.shape[0] == n_out
    if cached_linv.shape[0] == n_out:  # the factor kept by the incremental path
        ok, lml, grad, alpha, linv = _evaluate_clean(X, Y_fit, log_theta, jitter, cached_linv)
        linv, extra = linv.copy(), cached_extra.copy()
    else:  # the current theta, with the first candidates from the previous gradient if it is known
        rows = log_theta
        if merged:
            first = _candidates_kernel(
                log_theta, previous_gradient, n_attempts, learning_rate, max_log_step, lower, upper
            )  # noqa: E501
            rows = np.concatenate((log_theta, first))
        ok, s_lml, s_grad, s_alpha, s_linv = _evaluate_clean(X, Y_fit, rows, jitter, no_factor)
        counts[0] += rows.shape[0] // n_out
        lml, grad, alpha = s_lml[:n_out].copy(), s_grad[:n_out].copy(), s_alpha[:n_out].copy()
        linv, extra = s_linv[:n_out].copy(), np.zeros(n_out)
    if not ok:
        return False, log_theta, trace, grad, alpha, linv, extra, counts
    trace[0] = lml
    active = np.ones(n_out, dtype=np.bool_)
    n_steps = 0
    for step in range(hyper_steps):
        if grad_tol > 0:
            _still_active(active, grad, grad_tol)
        if not active.any():
            break
        if step == 0 and merged:
            cand, t_lml, t_grad, t_alpha, t_linv = first, s_lml[n_out:], s_grad[n_out:], s_alpha[n_out:], s_linv[n_out:]
        else:
            cand = _candidates_kernel(log_theta, grad, n_attempts, learning_rate, max_log_step, lower, upper)
            ok, t_lml, t_grad, t_alpha, t_linv = _evaluate_clean(X, Y_fit, cand, jitter, no_factor)
            counts[0] += n_attempts
            if not ok:
                return False, log_theta, trace, grad, alpha, linv, extra, counts
        pending = active.copy()
        n_pending = 0
        for attempt in range(n_attempts):
            for r in range(n_out):
                t = attempt * n_out + r
                if pending[r] and t_lml[t] >= lml[r]:  # accepted: the largest step not lowering the LML
                    log_theta[r], lml[r], grad[r], alpha[r] = cand[t], t_lml[t], t_grad[t], t_alpha[t]
                    linv[r], extra[r], pending[r] = t_linv[t], 0.0, False
                    counts[1] += 1
            n_pending = int(np.count_nonzero(pending))
            if n_pending == 0:
                break
            if attempt < n_attempts - 1:
                counts[2] += n_pending
        counts[3] += n_pending
        active &= ~pending
        n_steps += 1
        trace[n_steps] = lml
    return True, log_theta, trace[: n_steps + 1].copy(), grad, alpha, linv, extra, counts
