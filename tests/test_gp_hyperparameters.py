"""The GP's kernel describes its hyperparameters (name, bounds, number of elements, fixed) as
scikit-learn's kernels describe theirs: checked against ``ConstantKernel * RBF + WhiteKernel``,
the same model (issue 33, "control algebra once")."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

from hydroarm.control.gp import GPConfig, SEARDKernel, SlidingWindowGP, se_ard_kernel
from hydroarm.control.gp.kernels import LENGTHSCALES, SF2, SN2

CONFIG = GPConfig(log_sf2_bounds=(-3.0, 5.0), log_sn2_bounds=(-7.0, 2.0), log_lengthscale_bounds=(-4.0, 6.0))


def sklearn_kernel(config: GPConfig, d: int, fixed: bool = False):
    """scikit-learn's kernel of the same model, with the same bounds (or all fixed)."""

    def bounds(log_bounds):
        return "fixed" if fixed else tuple(math.exp(b) for b in log_bounds)

    return ConstantKernel(1.0, bounds(config.log_sf2_bounds)) * RBF(
        np.ones(d), bounds(config.log_lengthscale_bounds)
    ) + WhiteKernel(1.0, bounds(config.log_sn2_bounds))


def _by_leaf_name(kernel) -> dict:
    return {h.name.rsplit("__", 1)[-1]: h for h in kernel.hyperparameters}


@pytest.mark.parametrize("fixed", [False, True])
def test_the_hyperparameters_are_sklearns(fixed):
    """Every hyperparameter has scikit-learn's name for it, its bounds, its number of elements
    and whether it is fixed (ours: ``hyper_steps = 0``; theirs: bounds ``"fixed"``)."""
    d = 5
    config = CONFIG.model_copy(update={"hyper_steps": 0 if fixed else 1})
    ours = SEARDKernel.for_config(config, d)
    theirs = _by_leaf_name(sklearn_kernel(config, d, fixed))
    assert [h.name for h in ours.hyperparameters] == ["constant_value", "noise_level", "length_scale"]
    assert set(theirs) == {h.name for h in ours.hyperparameters}
    for hyperparameter in ours.hyperparameters:
        match = theirs[hyperparameter.name]
        assert hyperparameter.n_elements == match.n_elements
        assert hyperparameter.fixed == match.fixed
        assert hyperparameter.value_type == match.value_type
        if not fixed:
            np.testing.assert_allclose(
                np.atleast_2d(match.bounds), np.tile(hyperparameter.bounds, (hyperparameter.n_elements, 1)), rtol=1e-12
            )
    assert ours.n_dims == d + 2 == sum(h.n_elements for h in ours.hyperparameters)


def test_the_log_bounds_and_theta_are_sklearns_in_our_order():
    """scikit-learn's ``bounds`` and ``theta`` (log scale, its order: sf2, l_1..l_d, sn2) are ours
    (sf2, sn2, l_1..l_d) permuted; the same theta gives the same kernel matrix."""
    d = 4
    ours = SEARDKernel.for_config(CONFIG, d)
    theirs = sklearn_kernel(CONFIG, d)
    order = np.r_[SF2, np.arange(d + 2)[LENGTHSCALES], SN2]  # sklearn's order in our indices
    np.testing.assert_allclose(theirs.bounds, ours.log_bounds[order], rtol=0, atol=1e-12)
    theta = ours.theta(constant_value=2.5, noise_level=0.3, length_scale=np.array([0.5, 1.0, 2.0, 4.0]))
    named = ours.named(theta)
    assert named["constant_value"] == 2.5 and named["noise_level"] == 0.3
    np.testing.assert_array_equal(named["length_scale"], [0.5, 1.0, 2.0, 4.0])
    fitted = theirs.clone_with_theta(np.log(theta[order]))
    X = np.random.default_rng(2).standard_normal((7, d))
    expected = se_ard_kernel(X, X, theta[SF2], theta[LENGTHSCALES]) + theta[SN2] * np.eye(7)
    np.testing.assert_allclose(fitted(X), expected, rtol=1e-12)


def test_the_gp_takes_its_bounds_and_theta_layout_from_the_description():
    d = 3
    gp = SlidingWindowGP(d, 2, CONFIG)
    lower, upper = gp.log_bounds
    np.testing.assert_array_equal(np.c_[lower, upper], gp.kernel.log_bounds)
    assert gp.kernel["sn2"] == gp.kernel["noise_level"] and gp.kernel["l"].index == LENGTHSCALES
    theta = gp.kernel.theta(constant_value=2.0, noise_level=0.5, length_scale=3.0)
    gp.set_theta(theta)
    np.testing.assert_allclose(gp.theta, np.tile(theta, (2, 1)), rtol=1e-15)  # exp(log(theta))
    with pytest.raises(KeyError, match="constant_value, noise_level, length_scale"):
        gp.kernel["sigma"]


def test_a_theta_of_the_wrong_length_is_named_by_the_description():
    """One message from the description, wherever theta0 is checked (the GP, the settings)."""
    kernel = SEARDKernel.for_config(CONFIG, 3)
    assert kernel.check_theta(np.ones(5)) is None
    assert kernel.check_theta(np.ones(4)) == "4 values: give 5 [sf2, sn2, l_1..l_3] for 3 inputs"
    with pytest.raises(ValueError, match=r"GPConfig\.theta0.*4 values: give 5 \[sf2, sn2, l_1\.\.l_3\]"):
        SlidingWindowGP(3, 2, CONFIG.model_copy(update={"theta0": (1.0, 1.0, 1.0, 1.0)}))


def test_fixed_hyperparameters_do_not_move():
    """``fixed`` is true: with ``hyper_steps = 0`` the GP's theta stays theta0 whatever it sees."""
    config = CONFIG.model_copy(update={"hyper_steps": 0, "theta0": (2.0, 0.5, 1.0, 3.0)})
    gp = SlidingWindowGP(2, 1, config)
    assert all(h.fixed for h in gp.kernel.hyperparameters)
    rng = np.random.default_rng(0)
    for _ in range(12):
        gp.update(rng.standard_normal(2), 10.0 * rng.standard_normal(1))
        gp.update_hyperparameters()
    np.testing.assert_array_equal(gp.log_theta, np.log([[2.0, 0.5, 1.0, 3.0]]))
    moving = SlidingWindowGP(2, 1, config.model_copy(update={"hyper_steps": 1}))
    assert not any(h.fixed for h in moving.kernel.hyperparameters)
