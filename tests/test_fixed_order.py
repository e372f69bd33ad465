"""hydroarm.model.dynamics.fixed_order: the small dense algebra in a fixed order of operations.

Bitwise against plain-Python loops in the documented order (Python floats are IEEE doubles
with the same rounding: equal bits prove the order, no reassociation and no FMA), and against
SciPy / NumPy for the values. The GP's incremental factor update and solve (compiled) against
the same closed forms.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from hydroarm.control.linear import (
    covariance_prediction,
    double_integrator,
    filter_covariance,
    joint_lqr,
    kalman_correction,
)
from hydroarm.model.dynamics import fixed_order


def _python_matvec(a, x):
    out = []
    for row in a.tolist():
        s = 0.0
        for aij, xj in zip(row, x.tolist()):
            s += aij * xj
        out.append(s)
    return np.array(out)


@pytest.mark.parametrize("seed", range(3))
def test_matvec_and_matmul_sum_in_index_order(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(7, 21)) * np.exp(rng.normal(scale=5.0, size=(7, 21)))  # wide range: order shows
    x = rng.normal(size=21)
    b = rng.normal(size=(21, 4))
    np.testing.assert_array_equal(fixed_order.matvec(a, x), _python_matvec(a, x))
    expected = np.stack([_python_matvec(a, b[:, j].copy()) for j in range(4)], axis=1)
    np.testing.assert_array_equal(fixed_order.matmul(a, np.ascontiguousarray(b)), expected)
    np.testing.assert_allclose(fixed_order.matmul(a, b), a @ b, rtol=1e-12, atol=1e-12 * np.abs(a @ b).max())


def test_exp_is_libm_exp_elementwise():
    x = np.linspace(-700.0, 700.0, 10001)
    np.testing.assert_array_equal(fixed_order.exp(x), np.array([math.exp(v) for v in x.tolist()]))


@pytest.mark.parametrize("seed", range(3))
def test_cholesky_solve_against_scipy(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(6, 6))
    spd = a @ a.T + 0.1 * np.eye(6)
    b = rng.normal(size=6)
    B = rng.normal(size=(6, 3))
    factor = scipy.linalg.cho_factor(spd, lower=True)
    x, ok = fixed_order.cholesky_solve(spd, b)
    assert ok
    np.testing.assert_allclose(x, scipy.linalg.cho_solve(factor, b), rtol=1e-10)
    X, ok = fixed_order.cholesky_solve(spd, B)
    assert ok
    np.testing.assert_allclose(X, scipy.linalg.cho_solve(factor, B), rtol=1e-10)
    _, ok = fixed_order.cholesky_solve(-spd, b)  # not positive definite
    assert not ok


def test_gp_incremental_factor_is_the_full_factor():
    """The O(N^2) append (compiled) gives the factor of the grown window: against SciPy's Cholesky."""
    from hydroarm.control.gp._cholesky import _append_sample, _cholesky_inverse
    from hydroarm.control.gp._compiled import _kernel_matrices, _solve_kernel

    rng = np.random.default_rng(3)
    X = rng.normal(size=(9, 4))
    log_theta = np.log(rng.uniform(0.5, 2.0, size=(2, 6)))
    K = _kernel_matrices(X, X, log_theta)
    noise = np.exp(log_theta[:, 1])
    K[:, range(9), range(9)] += noise[:, None]
    linv, _, ok, _ = _cholesky_inverse(K[:, :8, :8].copy(), 0)
    assert ok.all()
    grown = _append_sample(linv, K[:, 8, :8].copy(), K[:, 8, 8].copy(), 0.5 * noise)
    for o in range(2):
        expected = scipy.linalg.solve_triangular(np.linalg.cholesky(K[o]), np.eye(9), lower=True)
        np.testing.assert_allclose(grown[o], expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    y = rng.normal(size=(2, 9))
    alpha = _solve_kernel(grown, y)
    for o in range(2):
        np.testing.assert_allclose(alpha[o], np.linalg.solve(K[o], y[o]), rtol=1e-8)


@pytest.mark.parametrize("seed", range(3))
def test_cholesky_in_place_is_the_allocating_solve_bit_for_bit(seed):
    """The compiled plants' in-place solve (the vehicle's and the fast arm's) and the allocating
    one are one factor and one substitution: the same bits; against SciPy; a matrix that is not
    positive definite leaves NaN (a diverging state), not a number."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(7, 7))
    spd = a @ a.T + 0.1 * np.eye(7)
    b = rng.normal(size=7)
    x, ok = fixed_order.cholesky_solve(spd, b)
    work, out = spd.copy(), np.empty(7)
    assert fixed_order.cholesky_solve_into(work, b, out) and ok
    np.testing.assert_array_equal(out, x)
    np.testing.assert_array_equal(np.triu(work, 1), np.triu(spd, 1))  # the upper triangle untouched
    np.testing.assert_allclose(np.tril(work), np.linalg.cholesky(spd), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out, scipy.linalg.cho_solve(scipy.linalg.cho_factor(spd, lower=True), b), rtol=1e-10)
    assert not fixed_order.cholesky_solve_into(-spd, b, out)
    assert np.isnan(out).all()


def test_cholesky_factor_shift_and_floor():
    """``a + shift I`` factored without forming it (the GP's ``K + sigma_n^2 I``), against NumPy; a
    pivot not above ``floor`` times its diagonal fails even when it is positive."""
    rng = np.random.default_rng(5)
    v = rng.normal(size=(5, 3))
    singular = v @ v.T  # rank 3: K alone is not positive definite
    chol = np.zeros((5, 5))
    assert not fixed_order.cholesky_factor(singular, chol, 0.0, 1e-6)
    assert fixed_order.cholesky_factor(singular, chol, 0.25, 1e-6)
    np.testing.assert_allclose(np.tril(chol), np.linalg.cholesky(singular + 0.25 * np.eye(5)), rtol=1e-12, atol=1e-14)
    near = np.array([[1.0, 1.0 - 1e-8], [1.0 - 1e-8, 1.0]])  # second pivot ~2e-8 of its diagonal 1
    assert not fixed_order.cholesky_factor(near, np.zeros((2, 2)), 0.0, 1e-6)
    assert fixed_order.cholesky_factor(near, np.zeros((2, 2)))


@pytest.mark.parametrize(
    ("period", "q_position", "q_velocity", "r_acceleration"),
    [(0.01, 300.0, 0.01, 1e-5), (0.01, 300.0, 0.01, 1e-9), (0.01, 1.0, 1.0, 10.0), (0.001, 100.0, 1.0, 1e-3)],
)
def test_the_joints_riccati_recursion_is_scipys_dare(period, q_position, q_velocity, r_acceleration):
    """The fixed-order DARE of one joint (no LAPACK) against scipy's Schur-method solution, and its
    gain against K = (R + B'PB)^-1 B'PA computed from scipy's P."""
    a_mat, b_vec = double_integrator(period)
    b_mat = b_vec[:, None]
    reference = scipy.linalg.solve_discrete_are(
        a_mat, b_mat, np.diag([q_position, q_velocity]), np.array([[r_acceleration]])
    )
    p_mat, gain, g_vec = joint_lqr(period, q_position, q_velocity, r_acceleration)
    assert np.max(np.abs(p_mat - reference)) <= 1e-12 * np.max(np.abs(reference))
    scale = 1.0 / (r_acceleration + b_vec @ reference @ b_vec)
    assert np.allclose(gain, scale * (b_vec @ reference @ a_mat), rtol=1e-11, atol=0)
    assert np.allclose(g_vec, scale * b_vec, rtol=1e-11, atol=0)


def _random_covariance(rng) -> np.ndarray:
    root = rng.normal(size=(2, 2)) * np.exp(rng.normal(scale=2.0, size=(2, 1)))
    return root @ root.T + 1e-9 * np.eye(2)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("position_only", [True, False])
def test_the_filters_correction_and_prediction_are_the_matrix_formulas(seed, position_only):
    """The Kalman filter's fixed-order algebra (no BLAS, no LAPACK inverse) against the matrix
    formulas L = S C' (C S C' + R)^-1, (I - L C) S and A P A' + q B B' in NumPy."""
    rng = np.random.default_rng(seed)
    sigma = _random_covariance(rng)
    c_mat = np.array([[1.0, 0.0]]) if position_only else np.eye(2)
    noise = np.diag(np.exp(rng.normal(scale=3.0, size=c_mat.shape[0])))
    gain, posterior = kalman_correction(sigma, c_mat, noise)
    expected = sigma @ c_mat.T @ np.linalg.inv(c_mat @ sigma @ c_mat.T + noise)
    np.testing.assert_allclose(gain, expected, rtol=1e-10, atol=1e-14 * np.abs(expected).max())
    expected_posterior = (np.eye(2) - expected @ c_mat) @ sigma
    scale = np.abs(sigma).max()
    np.testing.assert_allclose(
        posterior, 0.5 * (expected_posterior + expected_posterior.T), rtol=1e-9, atol=1e-12 * scale
    )
    assert posterior[0, 1] == posterior[1, 0]
    a_mat, b_vec = double_integrator(0.01)
    predicted = covariance_prediction(posterior, 0.01, 70.0)
    np.testing.assert_allclose(
        predicted, a_mat @ posterior @ a_mat.T + 70.0 * np.outer(b_vec, b_vec), rtol=1e-12, atol=1e-15 * scale
    )


@pytest.mark.parametrize(("variance", "acceleration"), [(7.66e-10, 68.9), (1e-6, 1.0), (1e-12, 100.0)])
def test_the_position_only_filters_covariance_is_scipys_dare(variance, acceleration):
    """The encoder's filter (C = [1, 0]): its fixed-point covariance against scipy's DARE (the
    filter's is the regulator's dual: A', C', Q_w, R)."""
    a_mat, b_vec = double_integrator(0.01)
    c_mat, noise = np.array([[1.0, 0.0]]), np.array([[variance]])
    expected = scipy.linalg.solve_discrete_are(a_mat.T, c_mat.T, acceleration * np.outer(b_vec, b_vec), noise)
    sigma = filter_covariance(0.01, c_mat, noise, acceleration)
    np.testing.assert_allclose(sigma, expected, rtol=1e-7, atol=1e-15)


def test_the_filters_algebra_refuses_a_measurement_it_was_not_written_for():
    with pytest.raises(ValueError, match="R diagonal"):
        kalman_correction(np.eye(2), np.eye(2), np.array([[1.0, 0.5], [0.5, 1.0]]))
    with pytest.raises(ValueError, match="C must be"):
        kalman_correction(np.eye(2), np.array([[0.0, 1.0]]), np.eye(1))


def test_spd_solve_is_the_cholesky_solve_and_falls_back_to_lapack():
    """On the fixtures of :func:`test_cholesky_solve_against_scipy`:
    the same bits as the Cholesky solve, scipy's values; with no factor, LAPACK's answer (here: its error)."""
    for seed in range(3):
        rng = np.random.default_rng(seed)
        a = rng.normal(size=(6, 6))
        spd, b = a @ a.T + 0.1 * np.eye(6), rng.normal(size=6)
        np.testing.assert_array_equal(fixed_order.spd_solve(spd, b), fixed_order.cholesky_solve(spd, b)[0])
        expected = scipy.linalg.solve(spd, b, assume_a="pos")
        np.testing.assert_allclose(fixed_order.spd_solve(spd, b), expected, rtol=1e-10)
    with pytest.raises(np.linalg.LinAlgError):
        fixed_order.spd_solve(np.zeros((2, 2)), np.ones(2))


CPUINFO = Path("/proc/cpuinfo")
KERNELS = ("Haswell", "Sandybridge") + (("SkylakeX",) if CPUINFO.exists() and "avx512f" in CPUINFO.read_text() else ())
"""The OpenBLAS kernels compared (SkylakeX's AVX-512 kernels run only where the CPU has them)."""

BLAS_PROBE = """
import numpy as np
from hydroarm.control.estimator import EstimatorConfig, JointKalmanFilter
from hydroarm.control.filter_design import FilterDesign
from hydroarm.control.delay_design import delay_margin_weight, told_delay_weight
from hydroarm.control.idmpc_limits import allocate
from hydroarm.model.arm.loading import load_arm
out = []
designs = FilterDesign(True, 7.66e-10, 0.0, 1, 1), FilterDesign(False, 1e-3, 1e-3), FilterDesign(False, 1e-6, 1e-4)
for design in designs:
    kalman = JointKalmanFilter(6, 0.01, EstimatorConfig(), design)
    out += [kalman.gain, kalman.covariance, kalman.posterior_covariance]
arm = load_arm("paper")
rng = np.random.default_rng(0)
for _ in range(20):
    q = rng.normal(size=6)
    mass, bias = arm.mass_matrix(q), arm.nonlinear_effects(q, rng.normal(size=6))
    out += list(allocate(mass, bias, rng.normal(scale=50.0, size=6), np.full(6, 28.0))[:2])
out += [told_delay_weight(0.01, 300.0, 0.01, w, d, g) for w in (1e-6, 1e-5) for d in (1, 2, 3) for g in (0.4, 0.61)]
out += [delay_margin_weight(0.01, 300.0, 0.01, m) for m in (1, 2)]
print(" ".join(np.asarray(a, dtype=float).tobytes().hex() for a in out))
"""


def test_the_filter_design_the_torque_allocation_and_the_delay_design_do_not_follow_the_blas_kernel():
    """The filter's gain and covariances, the torque allocation's saturated solve and the delay
    designs' weights, computed under OpenBLAS's Haswell and Sandybridge kernels (FMA and not) and,
    on a CPU with AVX-512, SkylakeX: the same bits. Before 2026-12-05 the filter's gain came from
    NumPy's products and inverse (Haswell against Sandybridge: the real loop's GP-IDMPC 7 % apart in
    E_p), and the weights from LAPACK's eigenvalues (SkylakeX against Haswell: 0.7 %)."""
    outputs = []
    for kernel in KERNELS:
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "OPENBLAS_NUM_THREADS": "1"}
        done = subprocess.run([sys.executable, "-c", BLAS_PROBE], env=env, capture_output=True, text=True, check=False)
        assert done.returncode == 0, done.stderr[-2000:]
        outputs.append(done.stdout)
    assert all(output == outputs[0] for output in outputs)
