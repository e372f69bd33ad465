"""The GP model and its pure functions: SE-ARD kernel, prediction and log marginal
likelihood (with gradient), for one output and batched over outputs.

Model (per output; Liu et al. 2023, Section 3.1): zero prior mean (the paper's eq. 5) and
the squared-exponential ARD kernel (eq. 10)::

    k(x, x') = sf2 * exp(-1/2 * sum_j (x_j - x'_j)^2 / l_j^2)
    K        = k(X, X) + sn2 * I        (noise on the training diagonal only)

Hyperparameters ``theta = [sf2, sn2, l_1 .. l_d]`` (the paper's
Theta = [sigma_f^2, sigma_n^2, lambda_1 .. lambda_n]), natural scale; ``sf2`` and ``sn2``
are variances in (target unit)^2, ``l_j`` is in the unit of input j. The noise is on the
training diagonal only, not on every kernel entry as the paper's eq. (10) reads
(Rasmussen & Williams 2006, eqs. 2.20 - 2.24; docs/controllers.md).

Prediction follows R&W Algorithm 2.1 (Cholesky); the log marginal likelihood is R&W
eq. 2.30 (the paper's eq. 11) and its gradient R&W eq. 5.9 (the paper's eq. 12)::

    L          = -1/2 y^T K^-1 y - 1/2 log|K| - n/2 log(2 pi)
    dL/dtheta  = 1/2 tr((alpha alpha^T - K^-1) dK/dtheta),   alpha = K^-1 y

Single output (SciPy, the readable form)::

    mean, var = predict(X, y, X_star, theta, *, include_noise=True, jitter=0.0)
    lml, grad = log_marginal_likelihood(X, y, theta, *, jitter=0.0)

Batched over outputs (same X, one column of Y and one row of thetas per output; the
stacked machinery of `SlidingWindowGP`)::

    mean, var = predict_multi(X, Y, X_star, thetas, *, include_noise=True, jitter=0.0)
    lml, grad = log_marginal_likelihood_multi(X, Y, thetas, *, jitter=0.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from hydroarm.control.gp._batched import LOG_2PI, _evaluate, _predict_with_factor, _solve_with_factor, _Window
from hydroarm.control.gp._checks import _check_jitter, _check_matrix, _check_theta, _check_thetas, _check_vector

__all__ = [
    "Hyperparameter",
    "SEARDKernel",
    "se_ard_kernel",
    "predict",
    "log_marginal_likelihood",
    "predict_multi",
    "log_marginal_likelihood_multi",
]

SF2, SN2, LENGTHSCALES = 0, 1, slice(2, None)
"""Where each hyperparameter sits in ``theta = [sf2, sn2, l_1 .. l_d]`` (and in a row of the
batched ``thetas``): what :class:`SEARDKernel` describes and the code indexes by."""


@dataclass(frozen=True)
class Hyperparameter:
    """One hyperparameter of a kernel, described as scikit-learn describes one
    (``sklearn.gaussian_process.kernels.Hyperparameter``: name, value type, bounds, number of
    elements, fixed), with its unit and its place in ``theta``.

    ``name``: scikit-learn's name for it (``constant_value``, ``noise_level``, ``length_scale``:
    ``ConstantKernel * RBF + WhiteKernel`` is the same model); ``symbol``: the paper's;
    ``bounds``: (low, high), natural scale; ``n_elements``: values it takes (d for the
    lengthscales); ``fixed``: the GP never changes it (its hyperparameter steps are off);
    ``index``: its place in ``theta`` (an int, or a slice for a vector).
    """

    name: str
    symbol: str
    unit: str
    bounds: tuple[float, float]
    n_elements: int
    fixed: bool
    index: int | slice
    value_type: str = "numeric"


@dataclass(frozen=True)
class SEARDKernel:
    """The GP's model of d inputs, described (the module docstring): ``k(x, x') = sf2 exp(-1/2
    sum_j (x_j - x'_j)^2 / l_j^2)`` with the noise ``sn2`` on the training diagonal.

    ``log_*_bounds``: (low, high) natural-log box of each hyperparameter; ``fixed``: none moves
    (``GPConfig.hyper_steps = 0``). :attr:`hyperparameters` describes them in ``theta``'s order;
    :meth:`named` and :meth:`theta` go between the vector and the names; :meth:`check_theta`
    says what is wrong with a vector of the wrong length.
    """

    n_inputs: int
    log_sf2_bounds: tuple[float, float]
    log_sn2_bounds: tuple[float, float]
    log_lengthscale_bounds: tuple[float, float]
    fixed: bool = False

    @classmethod
    def for_config(cls, config, n_inputs: int) -> SEARDKernel:
        """The kernel a :class:`~hydroarm.control.gp.GPConfig` sets up on ``n_inputs`` inputs."""
        return cls(
            int(n_inputs),
            tuple(config.log_sf2_bounds),
            tuple(config.log_sn2_bounds),
            tuple(config.log_lengthscale_bounds),
            fixed=config.hyper_steps == 0,
        )

    @property
    def hyperparameters(self) -> tuple[Hyperparameter, ...]:
        """sf2, sn2 and the d lengthscales, in ``theta``'s order."""

        def natural(log_bounds: tuple[float, float]) -> tuple[float, float]:
            return (math.exp(log_bounds[0]), math.exp(log_bounds[1]))

        return (
            Hyperparameter("constant_value", "sf2", "target^2", natural(self.log_sf2_bounds), 1, self.fixed, SF2),
            Hyperparameter("noise_level", "sn2", "target^2", natural(self.log_sn2_bounds), 1, self.fixed, SN2),
            Hyperparameter(
                "length_scale",
                "l",
                "input",
                natural(self.log_lengthscale_bounds),
                self.n_inputs,
                self.fixed,
                LENGTHSCALES,
            ),
        )

    @property
    def n_dims(self) -> int:
        """The length of ``theta``: d + 2."""
        return sum(h.n_elements for h in self.hyperparameters)

    def __getitem__(self, name: str) -> Hyperparameter:
        """The hyperparameter called ``name`` (scikit-learn's name or the paper's symbol)."""
        for hyperparameter in self.hyperparameters:
            if name in (hyperparameter.name, hyperparameter.symbol):
                return hyperparameter
        raise KeyError(f"{name!r}: the SE-ARD kernel has {', '.join(h.name for h in self.hyperparameters)}")

    @property
    def log_bounds(self) -> np.ndarray:
        """(d + 2, 2): the natural-log (low, high) of every entry of ``theta``, in its order
        (scikit-learn's ``kernel.bounds``, fixed ones included)."""
        rows = [self.log_sf2_bounds, self.log_sn2_bounds] + [self.log_lengthscale_bounds] * self.n_inputs
        return np.array(rows, dtype=float)

    def named(self, theta) -> dict[str, float | np.ndarray]:
        """``theta`` (d + 2,) by name: floats for sf2 and sn2, the (d,) lengthscales."""
        theta = np.asarray(theta, dtype=float)
        problem = self.check_theta(theta)
        if problem is not None:
            raise ValueError(f"theta: {problem}")
        return {
            h.name: (float(theta[h.index]) if h.n_elements == 1 and isinstance(h.index, int) else theta[h.index].copy())
            for h in self.hyperparameters
        }

    def theta(self, *, constant_value: float, noise_level: float, length_scale) -> np.ndarray:
        """The vector ``theta`` (d + 2,) from the hyperparameters by name (a scalar
        ``length_scale`` for every input, or d of them)."""
        theta = np.empty(self.n_dims)
        theta[SF2], theta[SN2] = constant_value, noise_level
        theta[LENGTHSCALES] = np.broadcast_to(np.asarray(length_scale, dtype=float), (self.n_inputs,))
        return theta

    def check_theta(self, theta) -> str | None:
        """None if ``theta`` has one value per entry of the description, else what is wrong."""
        size = len(theta)
        if size == self.n_dims:
            return None
        layout = ", ".join(
            h.symbol + (f"_1..{h.symbol}_{h.n_elements}" if h.n_elements > 1 else "") for h in self.hyperparameters
        )
        return f"{size} values: give {self.n_dims} [{layout}] for {self.n_inputs} inputs"


def se_ard_kernel(X1: np.ndarray, X2: np.ndarray, sf2: float, lengthscales: np.ndarray) -> np.ndarray:
    """SE-ARD kernel matrix (n1, n2): sf2 * exp(-1/2 sum_j (x1_j - x2_j)^2 / l_j^2).

    No noise term (noise belongs on the training diagonal only, see the module docstring).
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
        ValueError: on bad shapes / values.
        numpy.linalg.LinAlgError: if K + (sn2 + jitter) I is not positive definite.
    """
    X = _check_matrix("X", X)
    n, d = X.shape
    y = _check_vector("y", y, n)
    X_star = _check_matrix("X_star", X_star, n_cols=d)
    theta = _check_theta("theta", theta, d)
    jitter = _check_jitter(jitter)
    sf2, sn2, lengthscales = theta[SF2], theta[SN2], theta[LENGTHSCALES]

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
    sf2, sn2, lengthscales = theta[SF2], theta[SN2], theta[LENGTHSCALES]

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
    grad[SF2] = 0.5 * np.sum(W * K_signal) / sf2
    grad[SN2] = 0.5 * np.trace(W)
    grad[LENGTHSCALES] = 0.5 * np.einsum("ab,abj->j", W * K_signal, sq_diff) / lengthscales**3
    return float(lml), grad


def _evaluate_or_raise(X, Y, thetas, jitter, with_gradient):
    n_out = Y.shape[1]
    window = _Window(X, np.ascontiguousarray(Y.T), np.zeros(n_out), np.ones(n_out))
    log_theta = np.log(np.maximum(thetas, np.finfo(float).tiny))  # sn2 = 0 handled via thetas[:, SN2]
    evaluation = _evaluate(window, window.Y_fit, log_theta, thetas[:, SN2], jitter, 0, with_gradient)
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
        var = var + thetas[:, SN2, None]
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
    grad[:, SN2] = evaluation.half_trace_w  # direct form, valid at sn2 = 0 too
    return evaluation.lml, grad
