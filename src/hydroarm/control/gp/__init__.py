"""Sliding-window Gaussian-process regression (Liu et al. 2023, Section 3.1, Algorithm 1).

One module per concept, in the style of scikit-learn's ``gaussian_process``:

* `kernels`: the model (SE-ARD kernel, zero mean, noise on the training diagonal), its
  hyperparameters described (`SEARDKernel`, `Hyperparameter`: name, bounds, fixed, as
  scikit-learn's kernels describe theirs) and its pure functions: `predict`,
  `log_marginal_likelihood` and their batched forms `predict_multi`,
  `log_marginal_likelihood_multi`;
* `config`: `GPConfig`, the validated settings;
* `sliding_window`: `SlidingWindowGP`, the online estimator (window, hyperparameter steps,
  faults);
* `events`: what the estimator reports: the fault events of a call (`FAULTS`) and its
  counters (`GPStats`);
* private: `_batched` (stacked multi-output evaluation in NumPy), `_compiled` (the same
  algebra compiled with numba), `_cholesky` (factorisation with a jitter ladder, O(N^2)
  window updates), `_checks` (argument checks).

Usage at control step k::

    gp = SlidingWindowGP(n_inputs, n_outputs=6, config=GPConfig())
    gp.update(x, y); gp.update_hyperparameters(); mean, var = gp.predict(x_star)

Measured choices (defaults, scaling, compiled kernels, incremental window update) are in
docs/controllers.md, "The GP: measured choices".
"""

from hydroarm.control.gp.config import GPConfig
from hydroarm.control.gp.events import FAULTS, GPStats
from hydroarm.control.gp.kernels import (
    Hyperparameter,
    SEARDKernel,
    log_marginal_likelihood,
    log_marginal_likelihood_multi,
    predict,
    predict_multi,
    se_ard_kernel,
)
from hydroarm.control.gp.sliding_window import SlidingWindowGP

__all__ = [
    "FAULTS",
    "GPConfig",
    "GPStats",
    "SlidingWindowGP",
    "SEARDKernel",
    "Hyperparameter",
    "se_ard_kernel",
    "predict",
    "log_marginal_likelihood",
    "predict_multi",
    "log_marginal_likelihood_multi",
]
