"""Inverse Cholesky factors of stacked kernel matrices: full factorisation with a jitter
ladder, and the O(N^2) update of a sliding window's factor.

Every factor here is the *inverse* lower Cholesky factor ``Linv = L^-1`` of
``K = L L^T`` (what prediction and the gradient need), stacked over outputs: (o, n, n).

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

import numpy as np
from scipy.linalg.lapack import dpotrf, dtrtri

# Extra diagonal tried after a failed Cholesky, relative to the mean diagonal.
_JITTER_LADDER_START = 1e-10
_JITTER_LADDER_FACTOR = 100.0


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
