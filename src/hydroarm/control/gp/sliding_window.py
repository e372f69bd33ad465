"""The online estimator: n_outputs sliding-window GPs sharing their inputs (Liu et al. 2023,
Section 3.1 and Algorithm 1), learning the one-step residual (disturbance) of the arm from
the last ``window`` samples (the paper's N_train); each output (joint) has its own
hyperparameters.

Algorithm 1, made robust: hyperparameter steps in log space, capped, projected onto box
bounds, warm-started and accepted only if the LML does not decrease
(`SlidingWindowGP.update_hyperparameters`); the window's factor updated in O(N^2) when
theta is unchanged (`SlidingWindowGP.update`, `_cholesky`).

Faults: a failed Cholesky is retried with a growing diagonal jitter (at most
``max_jitter_retries``); if it still fails, the candidate hyperparameters are rejected
(previous theta kept) or, if the current theta itself cannot be factorised on the window,
that output predicts its prior. No LinAlgError leaves the class. Each event is counted in
``SlidingWindowGP.stats`` and returned by the call that met it (``return_events=True``;
names in :data:`FAULTS`).
"""

from __future__ import annotations

import numpy as np

from hydroarm.config import field_error
from hydroarm.control.gp._batched import (
    _evaluate,
    _Evaluation,
    _predict_with_factor,
    _rows,
    _solve_with_factor,
    _Window,
)
from hydroarm.control.gp._checks import _check_matrix, _check_thetas, _check_vector, _is_int
from hydroarm.control.gp._cholesky import _append_sample, _cholesky_inverse, _drop_oldest
from hydroarm.control.gp._compiled import _NO_FACTOR, _evaluate_kernel, _kernel_column, _kernel_matrices
from hydroarm.control.gp._hyper import candidates, hyper_update
from hydroarm.control.gp.config import GPConfig
from hydroarm.control.gp.events import FAULTS, GPStats
from hydroarm.control.gp.kernels import SF2, SN2, SEARDKernel
from hydroarm.model.dynamics.fixed_order import exp

__all__ = ["SlidingWindowGP"]


class SlidingWindowGP:
    """n_outputs independent sliding-window GPs sharing their inputs (paper Algorithm 1).

    Usage at control step k::

        gp.update(x_prev, residual_prev)   # newest sample; the oldest drops out when full
        gp.update_hyperparameters()        # <= hyper_steps safeguarded gradient steps
        mean, var = gp.predict(x_now)      # (n_outputs,), (n_outputs,)

    ``update_hyperparameters`` and ``predict`` meet the faults (jitter, failed Cholesky,
    prior prediction); with ``return_events=True`` they also return the fault events of
    that call, a tuple of names from :data:`FAULTS`. ``update`` meets none: a failed O(N^2)
    update only leaves the factor to be recomputed by the next call that needs it.

    It is a :class:`~hydroarm.control.interface.DisturbanceEstimator`: ``update(x, r)``, then
    ``mean(x)`` and ``variance(x)`` (``predict``'s two halves, from one prediction per input and
    state).

    Args:
        n_inputs: d, the input dimension (e.g. 12 for the state).
        n_outputs: number of outputs / independent GPs (default 6 joints).
        config: GPConfig (defaults if None).

    State (read-only from outside): ``config``, ``kernel`` (its :class:`SEARDKernel`: the
    hyperparameters described, names and bounds), ``stats`` (GPStats),
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
        for name, problem in config.size_problems(n_inputs, n_outputs).items():
            raise field_error(name, getattr(config, name), problem, prefix="GPConfig.")
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
        self.kernel = SEARDKernel.for_config(config, n_inputs)
        log_bounds = self.kernel.log_bounds
        self._log_lower = log_bounds[:, 0].copy()
        self._log_upper = log_bounds[:, 1].copy()
        theta0 = np.ones(self.kernel.n_dims) if config.theta0 is None else np.asarray(config.theta0, dtype=float)
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
        self._call_faults = [0] * len(FAULTS)  # fault counts of the current call, in FAULTS order
        self._window = None  # _Window cache for the current samples
        self._previous_gradient = None  # dL/dlog theta at the current theta, previous window
        self._invalidate_factor()
        self._prediction = None  # (x, mean, var) of the last mean/variance call, this state

    def _invalidate_factor(self) -> None:
        self._linv = None  # (o, n, n) inverse Cholesky factors for the current theta and window
        self._extra_diag = np.zeros(self.n_outputs)  # jitter beyond config.jitter used per output
        self._factor_ok = np.ones(self.n_outputs, dtype=bool)
        self._n_incremental_since_full = 0
        self._alpha = None  # (o, n) K^-1 y_fit

    def _record_faults(self, jittered: int = 0, fallbacks: int = 0, priors: int = 0) -> None:
        """Count fault events in ``stats`` and in the events of the current call."""
        self.stats.n_jittered_factorizations += jittered
        self.stats.n_cholesky_fallbacks += fallbacks
        self.stats.n_prior_predictions += priors
        for k, count in enumerate((jittered, fallbacks, priors)):
            self._call_faults[k] += count

    def _call_events(self) -> tuple[str, ...]:
        """The fault events of the current call, grouped in :data:`FAULTS` order."""
        return tuple(name for name, count in zip(FAULTS, self._call_faults) for _ in range(count))

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
        if theta.shape == (self.kernel.n_dims,):
            theta = np.tile(theta, (self.n_outputs, 1))
        theta = _check_thetas(theta, self.n_outputs, self.n_inputs)
        if theta[:, SN2].min() <= 0:
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
        self._prediction = None

    # ----- data ---------------------------------------------------------------

    def update(self, x, r) -> bool:
        """Append one sample x (d,), r (n_outputs,); drop the oldest when the window is full.
        Always True (a sample of the wrong size or non-finite raises ValueError).

        If the hyperparameters are unchanged since the last factorisation and
        the window is large enough (GPConfig.incremental_min_window), the
        factor is rank-updated in O(N^2); otherwise it is recomputed lazily.
        """
        x = _check_vector("x", x, self.n_inputs)
        y = _check_vector("y", r, self.n_outputs)
        self._prediction = None
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
            return True
        linv = _drop_oldest(self._linv) if full else self._linv
        grown = self._append_to_factor(linv, x_scaled)
        if grown is None:
            self._invalidate_factor()
            return True
        self._linv = grown
        self._n_incremental_since_full += 1
        self.stats.n_incremental_updates += 1
        return True

    def _append_to_factor(self, linv: np.ndarray, x_scaled: np.ndarray):
        X_old = np.ascontiguousarray(self._X[:-1])
        k_new = _kernel_column(np.ascontiguousarray(x_scaled, dtype=np.float64), X_old, self._log_theta)
        noise = exp(self._log_theta[:, SN2]) + self.config.jitter + self._extra_diag
        kappa = exp(self._log_theta[:, SF2]) + noise
        # The exact Schur complement is >= the diagonal noise; much less means round-off drift.
        return _append_sample(linv, k_new, kappa, 0.5 * noise)

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
            window, Y_fit, log_theta, exp(log_theta[:, SN2]), cfg.jitter, cfg.max_jitter_retries, True, cached
        )

    def _count_factorization_events(self, evaluation: _Evaluation, relevant: np.ndarray | None = None) -> None:
        """Count jittered and failed factorisations among the relevant rows (all if None)."""
        ok, jittered = evaluation.ok, evaluation.extra_diag > 0
        if relevant is not None:
            ok, jittered = ok | ~relevant, jittered & relevant
        self._record_faults(jittered=int(np.count_nonzero(jittered)), fallbacks=int(ok.size - np.count_nonzero(ok)))

    def _ensure_factor(self, window: _Window) -> None:
        if self._linv is not None:
            return
        n = window.n
        sn2 = exp(self._log_theta[:, SN2])
        compiled = _evaluate_kernel(
            np.ascontiguousarray(window.X), window.Y_fit, self._log_theta, sn2, float(self.config.jitter),
            _NO_FACTOR, False,
        )  # fmt: skip
        if compiled[6]:  # every Cholesky succeeded: the factor (and alpha) as the NumPy path below
            linv, extra_diag, ok, n_jittered = compiled[4], np.zeros(self.n_outputs), compiled[5], 0
            alpha = compiled[3]
        else:
            X = np.ascontiguousarray(window.X)
            K = _kernel_matrices(X, X, self._log_theta)
            diagonal = np.arange(n)
            K[:, diagonal, diagonal] += (sn2 + self.config.jitter)[:, None]
            linv, extra_diag, ok, n_jittered = _cholesky_inverse(K, self.config.max_jitter_retries)
            alpha = None
        self.stats.n_full_factorizations += 1
        self._record_faults(jittered=n_jittered, fallbacks=int(self.n_outputs - np.count_nonzero(ok)))
        self._linv, self._extra_diag, self._factor_ok = linv, extra_diag, ok
        self._n_incremental_since_full = 0
        self._alpha = alpha if ok.all() else None

    # ----- hyperparameters ----------------------------------------------------

    def update_hyperparameters(self, *, return_events: bool = False):
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

        The halved candidates are factorised in the same stacked batch as the
        full step, and the first step's direction is the gradient at the
        current theta computed at the end of the previous update (on the window
        one sample older), so the current theta and the first candidates also
        share one batch: one hyperparameter step is one batched evaluation. The
        acceptance test is always exact on the current window, so the LML never
        decreases.

        Returns:
            lml_trace (k+1, n_outputs): LML on the current window at the
            current theta and after each of the k steps taken (NaN for outputs
            whose factorisation failed); shape (0, n_outputs) if hyper_steps = 0
            or the window is empty (then nothing is done).
            With ``return_events``, ``(lml_trace, events)``: ``events`` are the
            fault events of this call (``"gp_jittered"``, ``"gp_cholesky_fallback"``;
            see :data:`FAULTS`).
        """
        self._call_faults = [0] * len(FAULTS)
        self._prediction = None
        trace = self._update_hyperparameters()
        return (trace, self._call_events()) if return_events else trace

    def _update_hyperparameters(self) -> np.ndarray:
        """`update_hyperparameters` without the events: the LML trace."""
        cfg = self.config
        n_out = self.n_outputs
        if cfg.hyper_steps == 0 or self.n_samples == 0:
            return np.empty((0, n_out))
        self.stats.n_updates += 1
        window = self._current_window()
        if (compiled := self._compiled_update(window)) is not None:
            return compiled
        log_theta, bounds = self._log_theta, (self._log_lower, self._log_upper)
        n_attempts = cfg.max_step_halvings + 1
        merged_candidates = None
        if self._linv is not None and self._factor_ok.all():  # factor kept by the incremental path
            current = self._evaluate(window, log_theta, cached=(self._linv, self._extra_diag))
        elif self._previous_gradient is not None:
            merged_candidates = candidates(log_theta, self._previous_gradient, n_attempts, cfg, bounds)
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
                thetas, trials = merged_candidates, merged_trials
            else:
                thetas = candidates(log_theta, grad, n_attempts, cfg, bounds)
                trials = self._evaluate(window, thetas)
            pending = active
            for attempt in range(n_attempts):
                rows = slice(attempt * n_out, (attempt + 1) * n_out)
                trial = _rows(trials, rows.start, rows.stop)
                candidate = thetas[rows]
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

    def _compiled_update(self, window: _Window) -> np.ndarray | None:
        """The update by `_hyper.hyper_update` where it is clean (the same bits as the NumPy path):
        state and counters set, the LML trace returned; None (nothing changed) otherwise."""
        cached = (self._linv, self._extra_diag) if self._linv is not None and self._factor_ok.all() else None
        bounds = (self._log_lower, self._log_upper)
        result = hyper_update(window, self._log_theta, self._previous_gradient, cached, bounds, self.config)
        if result is None:
            return None
        self.stats.count_steps(*(int(count) for count in result.counts))
        self._log_theta, self._previous_gradient, self._alpha = result.log_theta, result.grad, result.alpha
        self._linv, self._extra_diag, self._factor_ok = result.linv, result.extra_diag, np.ones(self.n_outputs, bool)
        self._n_incremental_since_full = 0
        return result.trace

    # ----- prediction ---------------------------------------------------------

    def predict(self, x_star, *, include_noise: bool = True, return_events: bool = False):
        """Predictive mean and variance at x_star (d,) or (m, d) (R&W Alg. 2.1).

        Returns:
            mean, var of shape (n_outputs,) for x_star (d,), else (m, n_outputs),
            in target units / units^2. var includes sn2 unless include_noise is
            False (latent variance). Outputs without a valid factor (Cholesky
            failed) and an empty window give the prior: mean 0 (window mean if
            normalize_y), var sf2 (+ sn2), scaled.
            With ``return_events``, ``(mean, var, events)``: ``events`` are the
            fault events of this call (the factorisation's ``"gp_jittered"`` and
            ``"gp_cholesky_fallback"`` if the factor had to be computed, then one
            ``"gp_prior_prediction"`` per output predicted from its prior; see
            :data:`FAULTS`).
        """
        self._call_faults = [0] * len(FAULTS)
        mean, var = self._predict(x_star, include_noise)
        return (mean, var, self._call_events()) if return_events else (mean, var)

    def mean(self, x) -> np.ndarray:
        """The predictive mean (n_outputs,) at x (d,) (:meth:`predict`'s first half; the fault
        events are counted in ``stats``)."""
        return self._predicted(x)[0].copy()

    def variance(self, x) -> np.ndarray:
        """The predictive variance (n_outputs,) at x (d,), the noise included (:meth:`predict`'s
        second half)."""
        return self._predicted(x)[1].copy()

    def _predicted(self, x) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` at x (d,), computed once per input and state: ``mean(x)`` then
        ``variance(x)`` is one prediction, the same numbers as ``predict(x)``."""
        x = _check_vector("x_star", x, self.n_inputs)
        cached = self._prediction
        if cached is None or not np.array_equal(cached[0], x):
            mean, var = self.predict(x)
            cached = self._prediction = (x.copy(), mean, var)
        return cached[1], cached[2]

    def _predict(self, x_star, include_noise: bool):
        """`predict` without the events: (mean, var)."""
        single = np.ndim(x_star) == 1
        if single:
            X_star = _check_vector("x_star", x_star, self.n_inputs)[None]
        else:
            X_star = _check_matrix("x_star", x_star, n_cols=self.n_inputs)
        X_star = X_star * self._inv_input_scale
        log_theta = self._log_theta
        sn2 = exp(log_theta[:, SN2])[:, None] if include_noise else 0.0
        sf2 = exp(log_theta[:, SF2])[:, None]
        if self.n_samples == 0:
            mean = np.zeros((self.n_outputs, X_star.shape[0]))
            var = np.broadcast_to(sf2 + sn2, mean.shape).copy()
        else:
            window = self._current_window()
            self._ensure_factor(window)
            ok = self._factor_ok
            if self._alpha is None:
                self._alpha = _solve_with_factor(self._linv, window.Y_fit)
            if ok.all():
                mean, var = _predict_with_factor(window, X_star, log_theta, self._linv, self._alpha)
            else:  # prior for outputs without a factor
                self._record_faults(priors=int(self.n_outputs - ok.sum()))
                mean = np.zeros((self.n_outputs, X_star.shape[0]))
                var = np.tile(sf2, (1, X_star.shape[0]))
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
