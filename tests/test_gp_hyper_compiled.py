"""The GP's hyperparameter update in one compiled call (`hydroarm.control.gp._hyper`) gives the
same bits as its NumPy path, on every path the update takes (the kept factor, the first step
merged with the current theta, neither), and hands the faulty cases to the NumPy path."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.control.gp import GPConfig, SlidingWindowGP, _hyper


def _run(config: GPConfig, compiled: bool, n_steps: int, seed: int = 0, monkeypatch=None):
    """A GP fed a drifting nonlinear signal for n_steps, updated and queried each step: its
    log theta, LML traces, predictions and counters."""
    gp = SlidingWindowGP(4, 3, config)
    if not compiled:
        monkeypatch.setattr(gp, "_compiled_update", lambda window: None)
    rng = np.random.default_rng(seed)
    traces, predictions = [], []
    for k in range(n_steps):
        x = np.sin(0.1 * k + np.arange(4)) + 0.05 * rng.normal(size=4)
        r = np.array([np.sin(x[0] * x[1]), x[2] ** 2 - x[3], np.cos(x.sum())]) + 0.01 * rng.normal(size=3)
        gp.update(x, r)
        traces.append(gp.update_hyperparameters())
        predictions.append(np.concatenate(gp.predict(x + 0.1)))
    return gp.log_theta, traces, np.array(predictions), gp.stats.as_dict()


CONFIGS = {
    "the paper's (window 10, merged first step)": GPConfig(),
    "kept factor (window 40 >= incremental_min_window)": GPConfig(window=40, incremental_min_window=20),
    "three steps, three halvings, a gradient tolerance": GPConfig(hyper_steps=3, max_step_halvings=3, grad_tol=1e-3),
    "one attempt, normalised targets": GPConfig(max_step_halvings=0, normalize_y=True, window=15),
}


@pytest.mark.parametrize("name", CONFIGS)
def test_the_compiled_update_is_the_numpy_paths_bit_for_bit(name, monkeypatch):
    compiled = _run(CONFIGS[name], True, 80)
    reference = _run(CONFIGS[name], False, 80, monkeypatch=monkeypatch)
    assert np.array_equal(compiled[0], reference[0])
    assert all(np.array_equal(a, b) for a, b in zip(compiled[1], reference[1], strict=True))
    assert np.array_equal(compiled[2], reference[2])
    assert compiled[3] == reference[3]
    assert compiled[3]["n_accepted_steps"] > 0 and compiled[3]["n_step_halvings"] + compiled[3]["n_rejected_steps"] > 0


def test_the_compiled_update_runs_in_the_clean_case_and_declines_a_failed_factorisation():
    gp = SlidingWindowGP(2, 2, GPConfig(log_sn2_bounds=(-40.0, 10.0), theta0=(1.0, 1e-16, 1.0, 1.0), jitter=0.0))
    gp.update(np.array([0.1, 0.2]), np.array([1.0, -1.0]))
    gp.update(np.array([0.5, -0.3]), np.array([0.4, 0.2]))
    bounds = (gp._log_lower, gp._log_upper)
    clean = _hyper.hyper_update(gp._current_window(), gp.log_theta, None, None, bounds, gp.config)
    assert clean is not None and clean.trace.shape == (2, 2)
    gp.update(np.array([0.1, 0.2]), np.array([1.0, -1.0]))  # a repeated sample: K singular, sn2 = 1e-16
    window = gp._current_window()
    assert _hyper.hyper_update(window, gp.log_theta, None, None, bounds, gp.config) is None
    trace, events = gp.update_hyperparameters(return_events=True)  # the NumPy path's jitter ladder
    assert "gp_jittered" in events and np.all(np.isfinite(trace))
