"""The inverse-dynamics MPC and the Kalman filter: closed forms, an independent QP, invariants."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

import hydroarm
from hydroarm.control.estimator import EstimatorConfig, JointKalmanFilter, steady_state_covariance
from hydroarm.control.idmpc import IDMPCConfig, InverseDynamicsMPC, allocate, unconstrained_move
from hydroarm.model.task import SinusoidReference, paper_reference

T = 0.01


def _lqr_by_iteration(q_pos, q_vel, r, period=T, steps=20_000):
    """The LQR gain of one joint by iterating the Riccati difference equation (no scipy)."""
    a = np.array([[1.0, period], [0.0, 1.0]])
    b = np.array([[0.5 * period**2], [period]])
    q = np.diag([q_pos, q_vel])
    p = q.copy()
    for _ in range(steps):
        k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
        p = q + a.T @ p @ (a - b @ k)
    return k[0]


@pytest.mark.parametrize("q_vel, r", [(0.01, 1e-5), (1.0, 1e-3), (0.0, 1e-2)])
def test_unconstrained_move_is_the_joint_lqr_for_a_constant_acceleration_reference(paper_arm, q_vel, r):
    """A reference of constant acceleration has no one-step defect: the move is -K e0."""
    controller = InverseDynamicsMPC(paper_arm, IDMPCConfig(q_velocity=q_vel, r_acceleration=r))
    q0, v0, a0 = np.linspace(-1, 1, 6), np.linspace(0.5, -0.5, 6), np.linspace(2.0, -3.0, 6)

    class Parabola:
        def sample(self, t):
            t = np.asarray(t, dtype=float)[..., None]
            return q0 + v0 * t + 0.5 * a0 * t**2, v0 + a0 * t, np.broadcast_to(a0, t.shape[:-1] + (6,))

    rng = np.random.default_rng(0)
    y = np.concatenate([q0, v0]) + rng.normal(0.0, 0.1, 12)
    t = 0.7
    q_r, v_r, a_r = Parabola().sample(t)
    move = controller.planned_acceleration(t, y, Parabola()) - a_r
    gain = _lqr_by_iteration(300.0, q_vel, r)
    expected = -(gain[0] * (y[:6] - q_r) + gain[1] * (y[6:] - v_r))
    np.testing.assert_allclose(move, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())


def _brute_force_first_move(e0, c, q_pos, q_vel, r, p_terminal, period=T):
    """The finite-horizon problem of one joint as one least-squares problem in the N moves."""
    horizon = c.shape[0]
    a = np.array([[1.0, period], [0.0, 1.0]])
    b = np.array([0.5 * period**2, period])
    # e_k = A^k e0 + sum_{j<k} A^{k-1-j} (B u_j + c_j): affine in u
    rows, rhs = [], []
    sqrt_q = np.sqrt(np.array([q_pos, q_vel]))
    root_p = np.linalg.cholesky(p_terminal).T
    free = e0.copy()
    effect = np.zeros((2, horizon))
    for k in range(horizon + 1):
        weight = root_p if k == horizon else np.diag(sqrt_q)
        rows.append(weight @ effect)
        rhs.append(-weight @ free)
        if k < horizon:
            u_row = np.zeros((1, horizon))
            u_row[0, k] = np.sqrt(r)
            rows.append(u_row)
            rhs.append(np.zeros(1))
            effect = a @ effect
            effect[:, k] += b
            free = a @ free + c[k]
    moves, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return moves[0]


def test_preview_of_the_reference_defects_equals_the_brute_force_qp():
    rng = np.random.default_rng(4)
    n, horizon = 3, 12
    q_pos, q_vel, r = 300.0, 0.01, 1e-4
    a = np.array([[1.0, T], [0.0, 1.0]])
    b = np.array([[0.5 * T**2], [T]])
    p = scipy.linalg.solve_discrete_are(a, b, np.diag([q_pos, q_vel]), np.array([[r]]))
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)[0]
    g = b[:, 0] / (r + float((b.T @ p @ b)[0, 0]))
    e0 = rng.normal(size=(n, 2))
    c = rng.normal(scale=1e-3, size=(horizon, n, 2))
    moves = unconstrained_move(e0, c, np.repeat(p[None], n, 0), np.repeat(k[None], n, 0), np.repeat(g[None], n, 0), T)
    for j in range(n):
        expected = _brute_force_first_move(e0[j], c[:, j], q_pos, q_vel, r, p)
        np.testing.assert_allclose(moves[j], expected, rtol=1e-7)


def test_torque_map_is_the_dry_inverse_dynamics(paper_arm):
    controller = InverseDynamicsMPC(paper_arm, IDMPCConfig(torque_limit=1e6))
    plant = hydroarm.UnderwaterPlant(paper_arm, hydroarm.Water().off())
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, v, a = rng.normal(size=6), rng.normal(size=6), rng.normal(scale=5.0, size=6)
        tau, realised, saturated = controller.torque_map(q, v, a, np.zeros(6))
        assert not saturated.any()
        np.testing.assert_allclose(tau, paper_arm.inverse_dynamics(q, v, a), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(plant.acceleration(0.0, q, v, tau), a, rtol=1e-9, atol=1e-9)
        w_hat = rng.normal(scale=10.0, size=6)  # M q'' + h = tau + w: the estimate is subtracted
        tau_w, _, _ = controller.torque_map(q, v, a, w_hat)
        np.testing.assert_allclose(tau_w, tau - w_hat, rtol=1e-12, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    scale=st.floats(0.1, 1e4),
    limit=st.floats(0.5, 500.0),
)
def test_allocation_holds_the_limits_and_keeps_the_free_joints_plan(seed, scale, limit):
    arm = hydroarm.load_arm("paper")
    rng = np.random.default_rng(seed)
    q, v = rng.normal(size=6) * 2.0, rng.normal(size=6) * 3.0
    mass = arm.mass_matrix(q)
    bias = arm.nonlinear_effects(q, v) - rng.normal(scale=scale * 0.1, size=6)
    planned = rng.normal(scale=scale, size=6)
    limits = np.full(6, limit) * rng.uniform(0.2, 1.0, 6)
    tau, a, saturated = allocate(mass, bias, planned, limits)
    assert np.all(np.abs(tau) <= limits * (1 + 1e-12))
    np.testing.assert_allclose(mass @ a + bias, tau, rtol=1e-8, atol=1e-8 * (1 + np.abs(tau).max()))
    np.testing.assert_array_equal(a[~saturated], planned[~saturated])
    assert np.all(np.isclose(np.abs(tau[saturated]), limits[saturated]))


@pytest.mark.parametrize("measurement, acceleration", [(1e-3, 1e2), (1e-6, 1.0), (1e-2, 1e5)])
def test_kalman_steady_state_is_scipys_dare(measurement, acceleration):
    a = np.array([[1.0, T], [0.0, 1.0]])
    b = np.array([0.5 * T**2, T])
    expected = scipy.linalg.solve_discrete_are(a.T, np.eye(2), acceleration * np.outer(b, b), measurement * np.eye(2))
    sigma = steady_state_covariance(T, measurement, acceleration)
    np.testing.assert_allclose(sigma, expected, rtol=1e-8, atol=1e-14)
    kalman = JointKalmanFilter(
        6, T, EstimatorConfig(measurement_variance=measurement, acceleration_variance=acceleration)
    )
    np.testing.assert_allclose(kalman.gain, expected @ np.linalg.inv(expected + measurement * np.eye(2)), rtol=1e-8)


def test_kalman_filter_tracks_a_double_integrator_better_than_the_measurement():
    rng = np.random.default_rng(2)
    kalman = JointKalmanFilter(1, T, EstimatorConfig(measurement_variance=1e-3, acceleration_variance=1.0))
    x = np.array([0.0, 1.0])
    raw, filtered = [], []
    for k in range(2000):
        acc = np.array([np.sin(0.01 * k)])
        y = x + rng.normal(0.0, np.sqrt(1e-3), 2)
        estimate = kalman.update(y)
        if k > 100:
            raw.append(y - x)
            filtered.append(estimate - x)
        kalman.predict(acc)
        x = np.array([x[0] + T * x[1] + 0.5 * T**2 * acc[0], x[1] + T * acc[0]])
    assert np.sqrt(np.mean(np.square(filtered))) < 0.5 * np.sqrt(np.mean(np.square(raw)))


@pytest.mark.slow
def test_gp_idmpc_beats_the_smc_on_the_paper_task():
    config = hydroarm.ExperimentConfig()
    ours = np.mean(hydroarm.tracking_metrics(hydroarm.run_experiment(config, "gp-idmpc", 0))["Ep"])
    smc = np.mean(hydroarm.tracking_metrics(hydroarm.run_experiment(config, "smc", 0))["Ep"])
    assert ours < smc, (ours, smc)


def test_paper_reference_defects_are_third_order():
    """Sanity of the defect model: the sampled sinusoid deviates from the double integrator by O(T^3)."""
    reference: SinusoidReference = paper_reference()
    q, v, a = reference.sample(np.arange(3) * T)
    defect = q[1] - q[0] - T * v[0] - 0.5 * T**2 * a[0]
    assert np.max(np.abs(defect)) < 1e-4 and np.max(np.abs(defect)) > 0
