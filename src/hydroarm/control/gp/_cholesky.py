"""Inverse Cholesky factors of stacked kernel matrices: full factorisation with a jitter
ladder, and the O(N^2) update of a sliding window's factor.

Every factor here is the *inverse* lower Cholesky factor ``Linv = L^-1`` of
``K = L L^T`` (what prediction and the gradient need), stacked over outputs: (o, n, n).

Everything here runs in compiled fixed-order loops or elementwise NumPy (no LAPACK / BLAS,
no CPU-dispatched reduction): the same bits on any x86-64 CPU (issue 29).

Full factorisation (`_cholesky_inverse`): a failed Cholesky is retried with extra
diagonal ``mean_diag * 1e-10 * 100**r``, r = 0 .. max_jitter_retries-1; an output that
still fails gets ``ok = False`` and a NaN factor.

Window update at fixed hyperparameters, O(N^2) instead of O(N^3):

* drop the oldest sample (`_drop_oldest`): with Linv = [[a, 0], [b, M]], the trailing
  block's Cholesky is a rank-1 update of M^-1 by p = -b / a; the factor of I + p p^T has a
  closed form (Gill, Golub, Murray & Saunders 1974, method C1: t_i = 1 + sum_{k<=i} p_k^2)
  and its inverse is I - tril_{-1}(u p^T) with u_i = p_i / t_{i-1}, so
  Linv' = diag(t_{i-1}/t_i)^{1/2} (M - u * cumsum_excl(p M)), vectorised (cumsum);
* append a sample (`_append_sample`): c = Linv' k, delta = sqrt(kappa - |c|^2), new last
  row [-(Linv'^T c)/delta, 1/delta].
"""

from __future__ import annotations

import math

import numpy as np

from hydroarm.control.gp._compiled import _append_kernel, _factor_rows

# Extra diagonal tried after a failed Cholesky, relative to the mean diagonal.
_JITTER_LADDER_START = 1e-10
_JITTER_LADDER_FACTOR = 100.0


def _cholesky_inverse(K: np.ndarray, max_jitter_retries: int):
    """Inverse lower Cholesky factors of the stacked SPD matrices K (o, n, n).

    Returns (linv (o, n, n), extra_diag (o,), ok (o,) bool, n_jittered (int)).
    Compiled fixed-order loops (`_compiled._factor_rows`: no LAPACK / BLAS, the same bits on
    any CPU). An output whose Cholesky fails is retried with extra diagonal
    mean_diag * 1e-10 * 100**r, r = 0 .. max_jitter_retries-1; outputs that still fail, or
    whose inverse is not finite (overflow), get ok = False and a NaN linv.
    """
    n_out, n, _ = K.shape
    K = np.ascontiguousarray(K, dtype=np.float64)
    extra_diag = np.zeros(n_out)
    linv, status = _factor_rows(K, extra_diag)
    n_jittered = 0
    for o in np.flatnonzero(status == 1):
        extra = _JITTER_LADDER_START * math.fsum(np.diagonal(K[o]).tolist()) / n
        for _ in range(max_jitter_retries):
            factor, row_status = _factor_rows(K[o : o + 1], np.array([extra]))
            if row_status[0] != 1:
                linv[o], status[o] = factor[0], row_status[0]
                if row_status[0] == 0:
                    extra_diag[o] = extra
                    n_jittered += 1
                break
            extra *= _JITTER_LADDER_FACTOR
    ok = status == 0
    linv[~ok] = np.nan
    return linv, extra_diag, ok, n_jittered


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
    and prior diagonal kappa (o,); None if a Schur complement falls below min_schur (o,).
    Compiled fixed-order loops (`_compiled._append_kernel`)."""
    grown, ok = _append_kernel(
        np.ascontiguousarray(linv, dtype=np.float64), np.ascontiguousarray(k_new, dtype=np.float64),
        np.ascontiguousarray(kappa, dtype=np.float64), np.ascontiguousarray(min_schur, dtype=np.float64),
    )  # fmt: skip
    return grown if ok else None
