"""The linear time-varying MPC: condensing, Riccati, linearisation, solvers, fallbacks, closed loop."""

from __future__ import annotations

import numpy as np
import pydantic
import pytest
import scipy.linalg

import hydroarm
from hydroarm.config import ConfigError, validate
from hydroarm.control.mpc import (
    SOLVERS,
    LinearMPC,
    MPCConfig,
    QPResult,
    condense,
    lqr_gain,
    make_box_qp_solver,
    solve_riccati,
    solve_terminal_qp,
)
from hydroarm.control.qp import BoxQPSolver
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.task.references import SinusoidReference, paper_reference

T = 0.01


def linearise(arm, q, v, tau, period, discretisation="taylor2"):
    return NominalModel(arm).linearise(q, v, tau, period, discretisation)


def linearise_euler(arm, q, v, tau, period):
    return NominalModel(arm).linearise(q, v, tau, period, "euler")


def linearise_taylor2(arm, q, v, tau, period):
    return NominalModel(arm).linearise(q, v, tau, period, "taylor2")


def euler_step(arm, x, tau, period):
    return NominalModel(arm).euler_step(x, tau, period)


@pytest.fixture(scope="module")
def arm():
    return hydroarm.load_arm("paper")


def constant_reference(q0: np.ndarray) -> SinusoidReference:
    """The arm held still at q0: every linearisation is the same (an LTI problem)."""
    zeros = np.zeros((q0.shape[0], 1))
    return SinusoidReference(np.asarray(q0, dtype=float), zeros, zeros, zeros)


def paper_state(t: float) -> np.ndarray:
    q, v, _ = paper_reference().sample(t)
    return np.concatenate([q, v])


def random_problem(rng: np.random.Generator, horizon: int, nx: int = 4, nu: int = 2):
    """Random time-varying (A_k, B_k, c_k), some unstable, with weights, e0 and a box."""
    A = np.empty((horizon, nx, nx))
    for k in range(horizon):
        raw = rng.standard_normal((nx, nx))
        A[k] = raw / max(abs(np.linalg.eigvals(raw))) * rng.uniform(0.5, 1.3)
    B = rng.standard_normal((horizon, nx, nu))
    c = 0.3 * rng.standard_normal((horizon, nx))
    Q = np.diag(rng.uniform(0.5, 5.0, nx))
    R = np.diag(rng.uniform(0.05, 1.0, nu))
    P = solve_riccati(A[-1], B[-1], Q, R).P
    e0 = 5.0 * rng.standard_normal(nx)
    u_ref = rng.uniform(-0.5, 0.5, (horizon, nu))
    limit = rng.uniform(0.4, 1.2, nu)
    return A, B, c, Q, R, P, e0, u_ref, limit


def dense_first_move(A, B, c, Q, R, P, e0, u_ref, limit) -> np.ndarray:
    """The same MPC written independently: states as variables, dynamics as equalities."""
    cp = pytest.importorskip("cvxpy")
    horizon, nx, nu = B.shape
    e = cp.Variable((horizon + 1, nx))
    du = cp.Variable((horizon, nu))
    cost = cp.quad_form(e[horizon], P)
    constraints = [e[0] == e0]
    for k in range(horizon):
        cost += cp.quad_form(e[k], Q) + cp.quad_form(du[k], R)
        constraints += [
            e[k + 1] == A[k] @ e[k] + B[k] @ du[k] + c[k],
            u_ref[k] + du[k] <= limit,
            u_ref[k] + du[k] >= -limit,
        ]
    problem = cp.Problem(cp.Minimize(cost), constraints)
    problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12)
    assert problem.status == cp.OPTIMAL
    return du.value[0]


def solve_box(solver_name, A, B, c, Q, R, P, e0, u_ref, limit) -> np.ndarray:
    qp = condense(A, B, c, Q, R, P, e0)
    flat = u_ref.ravel()
    bound = np.tile(limit, B.shape[0])
    result = make_box_qp_solver(solver_name).solve(qp.H, qp.g, -bound - flat, bound - flat)
    assert result.ok, result.message
    return result.x


# --- condensing and the QP ------------------------------------------------------------
def test_condensed_matrices_equal_the_stacked_prediction():
    """H, g against Phi' Qbar Phi built block by block, full (non-diagonal) Q and R."""
    rng = np.random.default_rng(1)
    horizon, nx, nu = 5, 4, 2
    A = rng.standard_normal((horizon, nx, nx))
    B = rng.standard_normal((horizon, nx, nu))
    c = rng.standard_normal((horizon, nx))
    e0 = rng.standard_normal(nx)
    lq = rng.standard_normal((nx, nx))
    lr = rng.standard_normal((nu, nu))
    Q, R, P = lq @ lq.T, lr @ lr.T + np.eye(nu), np.eye(nx) * 7.0
    phi = np.zeros((horizon * nx, horizon * nu))
    free = np.zeros(horizon * nx)
    state = e0
    for i in range(horizon):
        state = A[i] @ state + c[i]
        free[i * nx : (i + 1) * nx] = state
        for j in range(i + 1):
            block = B[j]
            for m in range(j + 1, i + 1):
                block = A[m] @ block
            phi[i * nx : (i + 1) * nx, j * nu : (j + 1) * nu] = block
    qbar = scipy.linalg.block_diag(*([Q] * (horizon - 1) + [P]))
    rbar = np.kron(np.eye(horizon), R)
    qp = condense(A, B, c, Q, R, P, e0)
    np.testing.assert_allclose(qp.H, 2.0 * (phi.T @ qbar @ phi + rbar), rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(qp.g, 2.0 * phi.T @ qbar @ free, rtol=1e-11, atol=1e-9)
    du = rng.standard_normal(horizon * nu)
    np.testing.assert_allclose(qp.terminal_error(du), (phi @ du + free)[-nx:], rtol=1e-12)


@pytest.mark.parametrize("discretisation", ["euler", "taylor2"])
def test_unconstrained_lti_first_move_is_the_lqr_move(arm, discretisation):
    """Constant reference (LTI), huge limits: du_0 = -K e_0 (DARE gain) to 1e-6.

    The terminal weight is the DARE's P, so the cost-to-go is exact and any
    horizon gives the infinite-horizon LQR move; N = 30 anyway.
    """
    q0 = np.array([0.3, -0.8, 1.2, 0.4, -0.6, 0.2])
    reference = constant_reference(q0)
    mpc = LinearMPC(arm.with_torque_limit(1e9), MPCConfig(horizon=30, discretisation=discretisation))
    u_ref = arm.inverse_dynamics(q0, np.zeros(6), np.zeros(6))
    A, B, _ = linearise(arm, q0, np.zeros(6), u_ref, T, discretisation)
    gain = solve_riccati(A, B, mpc.Q, mpc.R).K
    rng = np.random.default_rng(2)
    for _ in range(3):
        e0 = np.concatenate([rng.uniform(-0.2, 0.2, 6), rng.uniform(-1.0, 1.0, 6)])
        out = mpc.compute(0.0, np.concatenate([q0, np.zeros(6)]) + e0, reference)
        assert out.status == "ok"
        expected = -gain @ e0
        scale = np.abs(expected).max()
        np.testing.assert_allclose(out.tau - u_ref, expected, rtol=1e-6, atol=1e-6 * scale)


@pytest.mark.parametrize("seed", [3, 4, 5, 6])
def test_first_move_equals_an_independent_dense_formulation(seed):
    """Random LTV problems with active bounds: condensed + DAQP == cvxpy's dense QP to 1e-6."""
    rng = np.random.default_rng(seed)
    problem = random_problem(rng, horizon=int(rng.integers(4, 9)))
    B, u_ref, limit = problem[1], problem[7], problem[8]
    nu = B.shape[2]
    du = solve_box("daqp", *problem)
    torque = du.reshape(-1, nu) + u_ref
    assert np.any(np.isclose(np.abs(torque), limit, rtol=0.0, atol=1e-9)), "no active bound"
    expected = dense_first_move(*problem)
    np.testing.assert_allclose(du[:nu], expected, rtol=1e-6, atol=1e-6 * np.abs(limit).max())


@pytest.mark.parametrize("other", ["osqp", "quadprog", "clarabel"])
def test_solvers_agree(other):
    rng = np.random.default_rng(11)
    for _ in range(3):
        problem = random_problem(rng, horizon=8)
        expected = solve_box("daqp", *problem)
        np.testing.assert_allclose(solve_box(other, *problem), expected, rtol=0.0, atol=1e-6)


# --- the box-QP backends behind one protocol ---------------------------------------------
def random_box_qp(rng: np.random.Generator, m: int):
    """A random strictly convex box QP ``(H, g, lb, ub)`` whose optimum has active bounds."""
    root = rng.standard_normal((m, m))
    H = root @ root.T + m * np.eye(m)
    g = 5.0 * m * rng.standard_normal(m)
    centre = rng.uniform(-1.0, 1.0, m)
    half_width = rng.uniform(0.1, 1.0, m)
    return H, g, centre - half_width, centre + half_width


@pytest.mark.parametrize("name", SOLVERS)
def test_every_backend_implements_the_box_qp_protocol(name):
    solver = make_box_qp_solver(name)
    assert isinstance(solver, BoxQPSolver)
    assert BoxQPSolver in type(solver).__mro__  # declared, not only structurally equal
    assert solver.name == name
    assert not isinstance(object(), BoxQPSolver)


@pytest.mark.parametrize("name", SOLVERS)
def test_every_backend_gives_the_solution_of_a_second_solver(name):
    """The same optimum as another backend on random strictly convex box QPs (cold and warm)."""
    second = make_box_qp_solver("quadprog" if name == "daqp" else "daqp")
    solver = make_box_qp_solver(name)
    rng = np.random.default_rng(21)
    for m in (3, 8, 8, 20):  # repeated size: backends that keep their set-up update it
        H, g, lb, ub = random_box_qp(rng, m)
        expected = second.solve(H, g, lb, ub)
        assert expected.ok, expected.message
        assert np.any(np.isclose(expected.x, lb, atol=1e-9) | np.isclose(expected.x, ub, atol=1e-9))
        for warm in (None, np.clip(expected.x + 0.05 * rng.standard_normal(m), lb, ub)):
            result = solver.solve(H, g, lb, ub, warm)
            assert isinstance(result, QPResult) and result.ok, result.message
            np.testing.assert_allclose(result.x, expected.x, rtol=0.0, atol=1e-6)


# --- Riccati and linearisation ----------------------------------------------------------
def test_riccati_doubling_equals_scipy_dare(arm):
    rng = np.random.default_rng(7)
    systems = []
    for _ in range(5):
        nx, nu = int(rng.integers(2, 7)), int(rng.integers(1, 4))
        raw = rng.standard_normal((nx, nx))
        A = raw / max(abs(np.linalg.eigvals(raw))) * rng.uniform(0.3, 1.5)
        B = rng.standard_normal((nx, nu))
        systems.append((A, B, np.diag(rng.uniform(0.1, 3, nx)), np.diag(rng.uniform(0.1, 1, nu))))
    mpc = LinearMPC(arm)
    reference = paper_reference()
    for t in (0.0, 1.3, 4.2):
        q, v, a = reference.sample(t)
        A, B, _ = linearise_euler(arm, q, v, arm.inverse_dynamics(q, v, a), T)
        systems.append((A, B, mpc.Q, mpc.R))
    for A, B, Q, R in systems:
        expected = scipy.linalg.solve_discrete_are(A, B, Q, R)
        solution = solve_riccati(A, B, Q, R)
        assert solution.method == "doubling"
        assert np.abs(solution.P - expected).max() <= 1e-8 * np.abs(expected).max()
        gain = np.linalg.solve(R + B.T @ expected @ B, B.T @ expected @ A)
        np.testing.assert_allclose(solution.K, gain, rtol=1e-7, atol=1e-9 * np.abs(gain).max())
        assert max(abs(np.linalg.eigvals(A - B @ solution.K))) < 1.0


def test_riccati_falls_back_to_scipy_when_the_doubling_is_capped(arm):
    mpc = LinearMPC(arm)
    q, v, a = paper_reference().sample(0.5)
    A, B, _ = linearise_euler(arm, q, v, arm.inverse_dynamics(q, v, a), T)
    solution = solve_riccati(A, B, mpc.Q, mpc.R, max_iterations=2)
    assert solution.method == "scipy"
    expected = scipy.linalg.solve_discrete_are(A, B, mpc.Q, mpc.R)
    assert np.abs(solution.P - expected).max() <= 1e-10 * np.abs(expected).max()


def test_linearisation_equals_finite_differences_of_the_euler_step(arm):
    rng = np.random.default_rng(8)
    n = arm.n_joints
    for _ in range(3):
        q, v = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n)
        tau = rng.uniform(-50, 50, n)
        x = np.concatenate([q, v])
        A, B, x_next = linearise_euler(arm, q, v, tau, T)
        np.testing.assert_allclose(x_next, euler_step(arm, x, tau, T), rtol=1e-10, atol=1e-10)
        h = 1e-6
        step = lambda x_, tau_: euler_step(arm, x_, tau_, T)  # noqa: E731
        fd_a = np.column_stack([(step(x + h * e, tau) - step(x - h * e, tau)) / (2 * h) for e in np.eye(2 * n)])
        fd_b = np.column_stack([(step(x, tau + h * e) - step(x, tau - h * e)) / (2 * h) for e in np.eye(n)])
        assert np.abs(A - fd_a).max() <= 1e-6 * np.abs(A).max()
        assert np.abs(B - fd_b).max() <= 1e-6 * np.abs(B).max()


def taylor2_step(arm, x: np.ndarray, tau: np.ndarray, period: float) -> np.ndarray:
    """Constant acceleration over the step: q + T v + T^2/2 a, v + T a (written out here)."""
    n = arm.n_joints
    acceleration = arm.forward_dynamics(x[:n], x[n:], tau)
    return np.concatenate([x[:n] + period * x[n:] + 0.5 * period**2 * acceleration, x[n:] + period * acceleration])


def test_taylor2_linearisation_equals_finite_differences_of_its_step(arm):
    rng = np.random.default_rng(9)
    n = arm.n_joints
    for _ in range(3):
        q, v = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n)
        tau = rng.uniform(-50, 50, n)
        x = np.concatenate([q, v])
        A, B, x_next = linearise_taylor2(arm, q, v, tau, T)
        np.testing.assert_allclose(x_next, taylor2_step(arm, x, tau, T), rtol=1e-10, atol=1e-10)
        h = 1e-6
        step = lambda x_, tau_: taylor2_step(arm, x_, tau_, T)  # noqa: E731
        fd_a = np.column_stack([(step(x + h * e, tau) - step(x - h * e, tau)) / (2 * h) for e in np.eye(2 * n)])
        fd_b = np.column_stack([(step(x, tau + h * e) - step(x, tau - h * e)) / (2 * h) for e in np.eye(n)])
        assert np.abs(A - fd_a).max() <= 1e-6 * np.abs(A).max()
        assert np.abs(B - fd_b).max() <= 1e-6 * np.abs(B).max()
        # only the position rows differ from Euler's, by T/2 times the velocity rows
        A_e, B_e, _ = linearise_euler(arm, q, v, tau, T)
        np.testing.assert_array_equal(A[n:], A_e[n:])
        np.testing.assert_allclose(B[:n], 0.5 * T * B_e[n:], rtol=1e-14)


def test_sliding_horizon_linearises_one_new_index_per_step(arm, monkeypatch):
    calls = []
    mpc = LinearMPC(arm, MPCConfig(horizon=10))
    original = mpc.nominal.forward_dynamics_derivatives
    monkeypatch.setattr(mpc.nominal, "forward_dynamics_derivatives", lambda *a: calls.append(1) or original(*a))
    reference = paper_reference()
    mpc.compute(0.0, paper_state(0.0), reference)
    assert len(calls) == 11
    for k in range(1, 6):
        mpc.compute(k * T, paper_state(k * T), reference)
        assert len(calls) == 11 + k
    mpc.compute(0.5, paper_state(0.5), reference)  # a jump: the window is rebuilt
    assert len(calls) == 11 + 5 + 11


def test_cached_linearisations_give_the_same_torque_as_a_fresh_controller(arm):
    reference = paper_reference()
    sliding = LinearMPC(arm.with_torque_limit(120.0), MPCConfig())
    rng = np.random.default_rng(12)
    for k in list(range(8)) + [3, 20, 21, 25]:
        y = paper_state(k * T) + rng.normal(0.0, 0.2, 12)
        tau = sliding.compute(k * T, y, reference).tau
        fresh = LinearMPC(arm.with_torque_limit(120.0), MPCConfig()).compute(k * T, y, reference).tau
        np.testing.assert_allclose(tau, fresh, rtol=1e-9, atol=1e-9)


# --- the controller -----------------------------------------------------------------------
def test_torque_limits_always_hold(arm):
    rng = np.random.default_rng(9)
    reference = paper_reference()
    for limit in (0.5, [0.2, 3.0, 1.0, 0.05, 0.5, 2.0]):
        mpc = LinearMPC(arm.with_torque_limit(limit), MPCConfig())
        for k in range(15):
            y = np.concatenate([rng.uniform(-10, 10, 6), rng.uniform(-20, 20, 6)])
            out = mpc.compute(k * T, y, reference)
            assert out.status == "ok"
            assert np.all(np.abs(out.tau) <= mpc.torque_limit)
        assert mpc.clip_count == 0


def test_timings_and_interface(arm):
    mpc = LinearMPC(arm)
    assert mpc.name == "MPC" and mpc.control_period == T
    assert isinstance(mpc, hydroarm.control.interface.Controller)
    out = mpc.compute(0.0, np.zeros(12), paper_reference())
    assert {"linearise", "qp_update", "qp_solve", "total"} <= set(out.timings)
    assert all(value >= 0.0 for value in out.timings.values())
    assert out.timings["total"] >= out.timings["qp_solve"]
    assert out.terminal_violation == 0.0
    with pytest.raises(ValueError, match="shape"):
        mpc.compute(0.0, np.zeros(11), paper_reference())


def test_hard_terminal_set_falls_back_to_soft_at_start_up(arm):
    """From rest at q = 0 the set x_N' P x_N <= 0.001 is out of reach (an early trial: ~1.4e4)."""
    mpc = LinearMPC(arm, MPCConfig(terminal_set="hard"))
    out = mpc.compute(0.0, np.zeros(12), paper_reference())
    assert out.status == "terminal_soft_fallback"
    assert out.terminal_violation > 1e3
    assert np.all(np.abs(out.tau) <= mpc.torque_limit)


def test_soft_terminal_set_records_the_slack(arm):
    reference = paper_reference()
    mpc = LinearMPC(arm, MPCConfig(terminal_set="soft"))
    out = mpc.compute(0.0, np.zeros(12), reference)
    assert out.status == "ok" and out.terminal_violation > 1e3
    # The recorded violation is the optimal slack of the soft problem.
    mpc.reset()
    qp, lb, ub, P = start_up_qp(mpc, reference)
    result, slack = solve_terminal_qp(qp, lb, ub, P, 1e-3, mpc.config.terminal_slack_penalty)
    assert result.ok
    assert slack == pytest.approx(out.terminal_violation, rel=1e-5)


def test_soft_terminal_set_closed_loop_from_rest_stays_bounded(arm):
    """Dry arm from rest, 1 s: the default penalty does not make the loop blow up (1e4 does)."""
    reference = paper_reference()
    plant = NominalModel(arm)
    mpc = LinearMPC(arm, MPCConfig(terminal_set="soft"))
    x = np.zeros(12)
    for k in range(100):
        out = mpc.compute(k * T, x, reference)
        assert out.status == "ok"
        x, _ = plant.step(k * T, x, out.tau, T)
    assert np.all(np.isfinite(x)) and np.abs(x[6:]).max() < 50.0
    assert np.abs(x[:6] - reference.sample(1.0)[0]).max() < 1.0


def start_up_qp(mpc: LinearMPC, reference):
    """The condensed QP of the first step from rest (rebuilt from the public pieces)."""
    arm, horizon = mpc.arm, mpc.horizon
    A, B, x_next, x_ref, u_ref = [], [], [], [], []
    for k in range(horizon + 1):
        q, v, a = reference.sample(k * T)
        tau = arm.inverse_dynamics(q, v, a)
        a_mat, b_mat, nxt = linearise(arm, q, v, tau, T, mpc.config.discretisation)
        A.append(a_mat), B.append(b_mat), x_next.append(nxt)
        x_ref.append(np.concatenate([q, v])), u_ref.append(tau)
    P = solve_riccati(A[-1], B[-1], mpc.Q, mpc.R).P
    c = np.array(x_next[:horizon]) - np.array(x_ref[1:])
    qp = condense(np.array(A[:horizon]), np.array(B[:horizon]), c, mpc.Q, mpc.R, P, -x_ref[0])
    flat = np.concatenate(u_ref[:horizon])
    limit = np.tile(mpc.torque_limit, horizon)
    return qp, -limit - flat, limit - flat, P


@pytest.mark.parametrize("mode", ["soft", "hard"])
def test_terminal_set_is_met_when_starting_on_the_reference(arm, mode):
    mpc = LinearMPC(arm, MPCConfig(terminal_set=mode))
    out = mpc.compute(0.0, paper_state(0.0), paper_reference())
    assert out.status == "ok"
    assert out.terminal_violation < 1e-6


def test_solver_failure_falls_back_to_lqr_then_to_the_shifted_plan(arm, monkeypatch):
    reference = paper_reference()
    mpc = LinearMPC(arm.with_torque_limit(50.0), MPCConfig())
    failing = lambda *args: QPResult(None, "failed", "forced failure")  # noqa: E731
    monkeypatch.setattr(mpc._solver, "solve", failing)
    y = paper_state(0.0) + 0.3
    out = mpc.compute(0.0, y, reference)
    assert out.status == "qp_failed_lqr"
    assert np.all(np.abs(out.tau) <= 50.0)
    q, v, a = reference.sample(0.0)
    u_ref = arm.inverse_dynamics(q, v, a)
    A, B, _ = linearise(arm, q, v, u_ref, T, mpc.config.discretisation)
    _, _, _, P = start_up_qp(mpc, reference)
    expected = np.clip(u_ref - lqr_gain(A, B, mpc.R, P) @ (y - np.concatenate([q, v])), -50, 50)
    np.testing.assert_allclose(out.tau, expected, rtol=1e-8, atol=1e-8)

    monkeypatch.undo()
    good = mpc.compute(T, paper_state(T), reference)
    assert good.status == "ok"
    plan = mpc._plan.copy()

    def crashing(*args):
        raise RuntimeError("solver crashed")

    monkeypatch.setattr(mpc._solver, "solve", crashing)
    for shift in (1, 2):
        out = mpc.compute((1 + shift) * T, paper_state((1 + shift) * T) + 5.0, reference)
        assert out.status == "qp_failed_shift"
        np.testing.assert_allclose(out.tau, np.clip(plan[shift], -50, 50))
    assert mpc.fallback_count == 3


def test_closed_loop_on_the_nominal_model_tracks_the_paper_reference(arm):
    """Dry arm, starting on the reference, 2 s: E_p < 1e-3 rad^2 per joint (measured <= 4e-5)."""
    reference = paper_reference()
    plant = NominalModel(arm)
    mpc = LinearMPC(arm)
    x = paper_state(0.0)
    errors = []
    for k in range(200):
        t = k * T
        out = mpc.compute(t, x, reference)
        assert out.status == "ok"
        x, _ = plant.step(t, x, out.tau, T)
        errors.append(x[:6] - reference.sample(t + T)[0])
    mean_square = np.mean(np.square(errors), axis=0)
    assert np.all(mean_square < 1e-3), mean_square


def test_feedforward_acceleration_is_compensated(arm):
    """Held still with a constant extra acceleration d: the first move is close to -M d.

    Cheap torque and a long horizon make cancelling d nearly optimal (measured
    within 2.5 %; with N = 10 and r = 1e-4 the first move overshoots by 15 %).
    """
    q0 = np.array([0.3, -0.8, 1.2, 0.4, -0.6, 0.2])
    reference = constant_reference(q0)
    mpc = LinearMPC(arm.with_torque_limit(1e9), MPCConfig(horizon=50, r=1e-4))
    x0 = np.concatenate([q0, np.zeros(6)])
    base = mpc.compute(0.0, x0, reference).tau
    d = np.array([2.0, -1.0, 0.5, 3.0, -2.0, 1.0])
    out = mpc.compute(0.0, x0, reference, feedforward_acceleration=d)
    assert out.status == "ok"
    shifted = out.tau
    expected = -arm.mass_matrix(q0) @ d
    np.testing.assert_allclose(shifted - base, expected, rtol=0.05, atol=0.05 * np.abs(expected).max())


def test_two_runs_give_identical_torques(arm):
    reference = paper_reference()

    def run():
        mpc = LinearMPC(arm.with_torque_limit(100.0), MPCConfig())
        x = np.zeros(12)
        plant = NominalModel(arm)
        torques = []
        for k in range(30):
            out = mpc.compute(k * T, x, reference)
            x, _ = plant.step(k * T, x, out.tau, T)
            torques.append(out.tau)
        return np.array(torques)

    np.testing.assert_array_equal(run(), run())


# --- configuration --------------------------------------------------------------------------
@pytest.mark.parametrize(
    "data, field",
    [
        ({"horizon": 0}, "horizon"),
        ({"control_period": 0.01}, "control_period"),  # one period per experiment, not per controller
        ({"q_position": -300.0}, "q_position"),
        ({"q_velocity": [0.01, -1.0]}, "q_velocity"),
        ({"r": 0.0}, "r"),
        ({"torque_limit": 50.0}, "torque_limit"),  # the arm's actuators' (the experiment's override), not the MPC's
        ({"terminal_set": "maybe"}, "terminal_set"),
        ({"solver": "gurobi"}, "solver"),
        ({"riccati_max_iterations": 0}, "riccati_max_iterations"),
        ({"horizon_length": 5}, "horizon_length"),
    ],
)
def test_bad_config_values_name_the_field(data, field):
    with pytest.raises(ConfigError, match=field):
        validate(MPCConfig, data, "mpc.toml")
    with pytest.raises(pydantic.ValidationError, match=field):
        MPCConfig(**data)


@pytest.mark.parametrize("field", ["q_position", "q_velocity", "r"])
def test_per_joint_lists_must_match_the_arm(arm, field):
    LinearMPC(arm, MPCConfig(**{field: [1.0] * 6}))
    with pytest.raises(ConfigError, match=rf"{field} = \[1.0, 1.0, 1.0, 1.0\]: 4 values for 6 joints"):
        LinearMPC(arm, MPCConfig(**{field: [1.0] * 4}))


def test_a_torque_limit_override_must_match_the_arm(arm):
    assert np.array_equal(arm.with_torque_limit([1.0] * 6).torque_limit, np.ones(6))
    assert arm.with_torque_limit(None) is arm
    with pytest.raises(ConfigError, match=r"torque_limit = \[1.0, 1.0, 1.0, 1.0\]: 4 values for 6 joints"):
        arm.with_torque_limit([1.0] * 4)
