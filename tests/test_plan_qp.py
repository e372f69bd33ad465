"""The planner's QP on its structure (hydroarm.control.plan_qp) against DAQP and an independent oracle."""

from __future__ import annotations

import daqp
import numpy as np
import pytest

from hydroarm.control.idmpc_limits import HorizonQP, condensed_problem, difference_rows
from hydroarm.control.linear import joint_lqr
from hydroarm.control.plan_qp import (
    DUAL_TOL,
    ITERATION_LIMIT,
    PRIMAL_TOL,
    SOLVED,
    joint_factors,
    solve_plan_qp,
    warm_set,
)
from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides


def random_instance(rng, n=3, horizon=12, scale=1.0):
    """A random QP of the planner's shape: per-joint condensed costs, block lower triangular torque
    rows with SPD inertias on the diagonal, and limits tight enough that many rows bind."""
    period = 0.01
    q_pos = rng.uniform(10.0, 500.0, n)
    q_vel = rng.uniform(0.0, 1.0, n)
    r_acc = 10.0 ** rng.uniform(-6.0, -4.0, n)
    p_mats = np.array([joint_lqr(period, q_pos[j], q_vel[j], r_acc[j])[0] for j in range(n)])
    hessian, grad_e0, grad_c = condensed_problem(period, horizon, q_pos, q_vel, r_acc, p_mats)
    size = n * horizon
    e0 = rng.normal(0.0, scale, (n, 2))
    c = rng.normal(0.0, 1e-3 * scale, (horizon, n, 2))
    gradient = grad_e0.reshape(size, 2 * n) @ e0.ravel() + grad_c.reshape(size, -1) @ c.ravel()
    rows = np.zeros((size, size))
    for k in range(horizon):
        root = rng.normal(0.0, 1.0, (n, n))
        rows[k * n : (k + 1) * n, k * n : (k + 1) * n] = root @ root.T + 0.1 * np.eye(n)
        for i in range(k):
            rows[k * n : (k + 1) * n, i * n : (i + 1) * n] = rng.normal(0.0, 1e-2, (n, n))
    free = np.linalg.solve(hessian, -gradient)
    reach = np.abs(rows @ free)
    limit = np.quantile(reach, rng.uniform(0.3, 0.9)) + 1e-3
    shift = rng.normal(0.0, 0.1 * limit, size)
    return hessian, gradient, rows, limit + shift, -limit + shift


def ours(hessian, gradient, rows, upper, lower, n, warm=None):
    factors = joint_factors(hessian, n)
    start = np.zeros(upper.size, dtype=np.int64) if warm is None else warm
    return solve_plan_qp(factors, gradient, rows, upper, lower, start, PRIMAL_TOL, DUAL_TOL, 10 * upper.size)


def reference(hessian, gradient, rows, upper, lower):
    x, _, flag, info = daqp.solve(hessian, gradient, rows, upper, lower, np.zeros(upper.size, dtype=np.int32))
    assert int(flag) == 1
    return np.asarray(x), np.asarray(info["lam"])


def test_joint_factors_are_the_blocks_cholesky():
    rng = np.random.default_rng(0)
    hessian = random_instance(rng)[0]
    factors = joint_factors(hessian, 3)
    for j in range(3):
        block = hessian[j::3, j::3]
        np.testing.assert_allclose(factors[j] @ factors[j].T, block, rtol=1e-12, atol=1e-12 * np.abs(block).max())
        np.testing.assert_allclose(factors[j], np.linalg.cholesky(block), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("seed", range(40))
def test_random_instances_equal_daqp(seed):
    rng = np.random.default_rng(seed)
    n, horizon = (3, 12) if seed % 2 else (6, 8)
    hessian, gradient, rows, upper, lower = random_instance(rng, n, horizon, scale=10.0 ** rng.uniform(-1, 2))
    moves, lam, flag, _ = ours(hessian, gradient, rows, upper, lower, n)
    assert flag == SOLVED
    expected, expected_lam = reference(hessian, gradient, rows, upper, lower)
    assert np.count_nonzero(expected_lam) > 0  # the limits bind: not the unconstrained solution
    scale = max(1.0, np.abs(expected).max())
    assert np.abs(moves - expected).max() <= 1e-9 * scale
    np.testing.assert_array_equal(np.sign(lam), np.sign(expected_lam))
    # warm-started from the optimal working set: one pass, the same point
    again, _, flag, iterations = ours(hessian, gradient, rows, upper, lower, n, warm_set(lam, gradient.size))
    assert flag == SOLVED and iterations == 1
    assert np.abs(again - moves).max() <= 1e-9 * scale


@pytest.mark.parametrize("seed", range(6))
def test_kkt_and_an_independent_solver(seed):
    """The KKT conditions of the solution (stationarity, feasibility, complementarity, signs) and
    Clarabel (an interior point, no shared code) on the same problem."""
    clarabel = pytest.importorskip("clarabel")
    import scipy.sparse as sp

    rng = np.random.default_rng(100 + seed)
    n = 3
    hessian, gradient, rows, upper, lower = random_instance(rng, n, 10)
    moves, lam, flag, _ = ours(hessian, gradient, rows, upper, lower, n)
    assert flag == SOLVED
    size = gradient.size
    stationarity = hessian @ moves + gradient + rows.T @ lam
    assert np.abs(stationarity).max() <= 1e-8 * (np.abs(gradient).max() + np.abs(hessian @ moves).max())
    value = rows @ moves
    assert np.all(value <= upper + PRIMAL_TOL) and np.all(value >= lower - PRIMAL_TOL)
    assert np.all(np.abs(value[lam > 0] - upper[lam > 0]) <= 1e-8 * np.abs(upper).max())
    assert np.all(np.abs(value[lam < 0] - lower[lam < 0]) <= 1e-8 * np.abs(upper).max())
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-12
    solver = clarabel.DefaultSolver(
        sp.triu(sp.csc_matrix(hessian), format="csc"), gradient, sp.csc_matrix(np.vstack([rows, -rows])),
        np.concatenate([upper, -lower]), [clarabel.NonnegativeConeT(2 * size)], settings,
    )  # fmt: skip
    solution = solver.solve()
    assert str(solution.status) in ("Solved", "AlmostSolved")
    assert np.abs(np.asarray(solution.x) - moves).max() <= 1e-6 * max(1.0, np.abs(moves).max())


def test_iteration_limit_is_reported():
    rng = np.random.default_rng(7)
    hessian, gradient, rows, upper, lower = random_instance(rng, 3, 12)
    factors = joint_factors(hessian, 3)
    size = gradient.size
    _, _, flag, iterations = solve_plan_qp(
        factors, gradient, rows, upper, lower, np.zeros(size, dtype=np.int64), PRIMAL_TOL, DUAL_TOL, 1
    )
    assert flag == ITERATION_LIMIT and iterations == 1


def test_the_planner_problems_equal_daqp():
    """The planner's own rows (the paper arm, linearised along random plans at random states),
    solved by the structured solver inside HorizonQP and by DAQP: the same plan to 1e-9."""
    arm = load_arm("paper")
    n, horizon, period = arm.n_joints, 20, 0.01
    q_pos, q_vel, r_acc = np.full(n, 300.0), np.full(n, 0.01), np.full(n, 1e-5)
    p_mats = np.array([joint_lqr(period, 300.0, 0.01, 1e-5)[0] for _ in range(n)])
    limit = np.full(n, 60.0)
    planners = {
        name: HorizonQP(arm, period, horizon, q_pos, q_vel, r_acc, p_mats, limit, 2, solver=name)
        for name in ("structured", "daqp")
    }
    rng = np.random.default_rng(3)
    bound = 0
    for _ in range(8):
        e0 = rng.normal(0.0, 0.5, (n, 2))
        c = rng.normal(0.0, 1e-4, (horizon, n, 2))
        q_r = rng.normal(0.0, 1.0, (horizon + 1, n))
        v_r = rng.normal(0.0, 1.0, (horizon + 1, n))
        a_r = rng.normal(0.0, 5.0, (horizon, n))
        q, v = q_r[0] + e0[:, 0], v_r[0] + e0[:, 1]
        mass = arm.mass_matrix(q)
        bias = arm.nonlinear_effects(q, v)
        w_hat = np.zeros(n)
        first = {name: qp.solve(e0, c, q_r, v_r, a_r, mass, bias, w_hat) for name, qp in planners.items()}
        assert first["daqp"] is not None and first["structured"] is not None
        assert planners["structured"].fallbacks == 0
        assert planners["structured"].last_iterations == planners["daqp"].last_iterations
        expected = planners["daqp"].last_moves
        scale = max(1.0, np.abs(expected).max())
        assert np.abs(planners["structured"].last_moves - expected).max() <= 1e-9 * scale
        assert planners["structured"].last_active == planners["daqp"].last_active
        bound += planners["daqp"].last_active
    assert bound >= 4  # most of these plans meet the limits


def test_unknown_solver_is_refused():
    arm = load_arm("paper")
    n = arm.n_joints
    p_mats = np.array([joint_lqr(0.01, 300.0, 0.01, 1e-5)[0] for _ in range(n)])
    with pytest.raises(ValueError, match="solver = 'osqp'"):
        HorizonQP(arm, 0.01, 5, np.ones(n), np.ones(n), np.ones(n), p_mats, np.ones(n), 1, solver="osqp")


@pytest.mark.parametrize("arm_name", ["paper", "alpha5"])
def test_water_terms_along_a_plan_are_the_per_state_terms(arm_name):
    """The planner's water at N states in one compiled pass: bit for bit the N single calls."""
    from hydroarm.control.learned_water import PhysicsInformedModel

    arm = load_arm(arm_name)
    model = PhysicsInformedModel(arm)
    rng = np.random.default_rng(5)
    model.theta = model.theta * rng.uniform(0.5, 2.0, model.theta.shape)
    q = rng.normal(0.0, 1.0, (9, arm.n_joints))
    v = rng.normal(0.0, 3.0, (9, arm.n_joints))
    added, rest = model.terms_along(q, v)
    for k in range(9):
        single_added, single_rest = model.terms(q[k], v[k])
        np.testing.assert_array_equal(added[k], single_added)
        np.testing.assert_array_equal(rest[k], single_rest)
    assert np.abs(added).max() > 0.0 and np.abs(rest).max() > 0.0


def test_a_solve_that_does_not_settle_goes_to_daqp(monkeypatch):
    """The structured solver's iteration limit hands the problem to DAQP (counted), whose answer stands."""
    import hydroarm.control.idmpc_limits as limits

    rng = np.random.default_rng(11)
    arm = load_arm("paper")
    n, horizon = arm.n_joints, 6
    p_mats = np.array([joint_lqr(0.01, 300.0, 0.01, 1e-5)[0] for _ in range(n)])
    qp = HorizonQP(arm, 0.01, horizon, np.full(n, 300.0), np.full(n, 0.01), np.full(n, 1e-5), p_mats,
                   np.full(n, 40.0), 0, solver="structured")  # fmt: skip
    hessian, gradient = qp.hessian, rng.normal(0.0, 1e4, horizon * n)
    rows = np.kron(np.eye(horizon), arm.mass_matrix(np.zeros(n)))
    upper, lower = np.full(horizon * n, 40.0), np.full(horizon * n, -40.0)
    limited = limits.solve_plan_qp

    def one_iteration(*args):
        return limited(*args[:-1], 1)

    monkeypatch.setattr(limits, "solve_plan_qp", one_iteration)
    moves, lam, ok = qp._solve_qp(gradient, rows, upper, lower)
    assert ok and qp.fallbacks == 1
    expected, expected_lam = reference(hessian, gradient, rows, upper, lower)
    np.testing.assert_array_equal(moves, expected)
    assert np.count_nonzero(expected_lam) > 0


def test_a_zero_pivot_in_the_structured_solver_goes_to_daqp(monkeypatch):
    """A ZeroDivisionError inside the compiled solver (met by a plan two periods ahead on the paper
    arm with the UR5's limits) hands the problem to DAQP (counted) instead of ending the run."""
    import hydroarm.control.idmpc_limits as limits

    rng = np.random.default_rng(12)
    arm = load_arm("paper")
    n, horizon = arm.n_joints, 6
    p_mats = np.array([joint_lqr(0.01, 300.0, 0.01, 1e-5)[0] for _ in range(n)])
    qp = HorizonQP(arm, 0.01, horizon, np.full(n, 300.0), np.full(n, 0.01), np.full(n, 1e-5), p_mats,
                   np.full(n, 40.0), 0, solver="structured")  # fmt: skip
    gradient = rng.normal(0.0, 1e4, horizon * n)
    rows = np.kron(np.eye(horizon), arm.mass_matrix(np.zeros(n)))
    upper, lower = np.full(horizon * n, 40.0), np.full(horizon * n, -40.0)

    def zero_pivot(*_args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(limits, "solve_plan_qp", zero_pivot)
    moves, _, ok = qp._solve_qp(gradient, rows, upper, lower)
    assert ok and qp.fallbacks == 1
    np.testing.assert_array_equal(moves, reference(qp.hessian, gradient, rows, upper, lower)[0])


def rate_instance(rng, n, horizon):
    """:func:`random_instance` with rate rows below its torque rows: ``(hessian, gradient, rows
    (N n, N n), upper (2 N n,), lower (2 N n,))``, the rate bounds tight enough that they bind
    on the torque rows' solution, and the first block's about a random drives' output."""
    hessian, gradient, rows, upper, lower = random_instance(rng, n, horizon, scale=10.0 ** rng.uniform(-1, 2))
    size = gradient.size
    torque_only = reference(hessian, gradient, rows, upper, lower)[0]  # the rate of the torque rows' solution
    reach = np.abs(difference_rows(rows, n) @ torque_only)
    step = np.quantile(reach, rng.uniform(0.2, 0.8)) + 1e-3
    previous = rng.uniform(-0.5, 0.5, n) * min(upper[:n].min(), -lower[:n].max())
    rate_upper, rate_lower = np.full(size, step), np.full(size, -step)
    rate_upper[:n] += previous
    rate_lower[:n] += previous
    return hessian, gradient, rows, np.concatenate([upper, rate_upper]), np.concatenate([lower, rate_lower])


def assert_kkt(hessian, gradient, stacked, upper, lower, moves, lam, tol):
    """The KKT conditions of ``min 1/2 U'HU + g'U, lower <= A U <= upper`` at (moves, lam), checked
    here from their definition: stationarity, primal feasibility, the multipliers' signs and
    complementary slackness (``tol`` relative to the problem's scale)."""
    scale = max(1.0, np.abs(gradient).max())
    assert np.abs(hessian @ moves + gradient + stacked.T @ lam).max() <= tol * scale
    value = stacked @ moves
    width = np.maximum(1.0, np.abs(upper - lower))
    assert np.all(value <= upper + tol * width) and np.all(value >= lower - tol * width)
    assert np.all(np.abs(value[lam > 0] - upper[lam > 0]) <= tol * width[lam > 0])
    assert np.all(np.abs(value[lam < 0] - lower[lam < 0]) <= tol * width[lam < 0])


@pytest.mark.parametrize("seed", range(30))
def test_random_instances_with_rate_rows_equal_daqp_and_satisfy_kkt(seed):
    """The rate rows formed inside the solver from the torque rows (row block k less block k - 1):
    the same moves and multipliers as DAQP on the stacked rows to 1e-9, and KKT checked here."""
    rng = np.random.default_rng(100 + seed)
    n, horizon = (3, 12) if seed % 2 else (6, 8)
    hessian, gradient, rows, upper, lower = rate_instance(rng, n, horizon)
    moves, lam, flag, _ = ours(hessian, gradient, rows, upper, lower, n, np.zeros(upper.size, dtype=np.int64))
    assert flag == SOLVED and lam.shape == upper.shape
    stacked = np.vstack([rows, difference_rows(rows, n)])
    expected, expected_lam = reference(hessian, gradient, stacked, upper, lower)
    assert np.count_nonzero(expected_lam[gradient.size :]) > 0  # the rate rows bind
    scale = max(1.0, np.abs(expected).max())
    np.testing.assert_allclose(moves, expected, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(lam, expected_lam, rtol=0, atol=1e-9 * max(1.0, np.abs(expected_lam).max()))
    assert_kkt(hessian, gradient, stacked, upper, lower, moves, lam, 1e-9)


def test_rate_rows_from_a_warm_working_set_reach_the_same_solution():
    """A warm start (a wrong one: the cold solution's working set with rows flipped and added)
    ends at the cold solve's solution: the start set only changes the path."""
    rng = np.random.default_rng(5)
    hessian, gradient, rows, upper, lower = rate_instance(rng, 6, 8)
    cold, cold_lam, _, _ = ours(hessian, gradient, rows, upper, lower, 6, np.zeros(upper.size, dtype=np.int64))
    warm = np.sign(cold_lam).astype(np.int64)
    warm[rng.choice(upper.size, 20, replace=False)] = rng.choice([-1, 1], 20)
    moves, lam, flag, _ = ours(hessian, gradient, rows, upper, lower, 6, warm)
    assert flag == SOLVED
    np.testing.assert_allclose(moves, cold, rtol=0, atol=1e-9 * np.abs(cold).max())
    np.testing.assert_allclose(lam, cold_lam, rtol=0, atol=1e-9 * np.abs(cold_lam).max())


def test_the_rate_limited_problems_of_a_paper_run_equal_daqp():
    """IDMPC's rate-limited QPs (the paper run, ``actuator.rate_limit = 1000``, 50 steps, 600 rows),
    recorded from the run and solved again by both: the same working set, and the same moves to
    1e-7 of their scale. Not 1e-9: these are ill-conditioned (the working set's Gram matrix
    M_A M_A' has condition numbers up to 4e8 here, so rounding alone moves the solution by about
    cond x 2.2e-16 ~ 1e-7 relative; the random instances above, cond < 1e4, agree to 1e-9), and
    each solution is checked against the KKT conditions here (stationarity to 1e-9)."""
    problems = []
    config = with_overrides(ExperimentConfig(duration=0.25), {"actuator.rate_limit": 1000.0})
    experiment = build_experiment(config, "IDMPC")
    controller = experiment.controller
    while not hasattr(controller, "rate_qp"):
        controller = controller.controller

    def recording(gradient, rows, upper, lower, lam=None, limit=None):
        qp = controller.rate_qp
        problems.append((qp.hessian, qp.n, gradient.copy(), rows.copy(), upper.copy(), lower.copy()))
        return inner(qp, gradient, rows, upper, lower, lam, limit=limit)

    inner = HorizonQP._solve_qp
    original = HorizonQP._solve_qp
    HorizonQP._solve_qp = lambda self, *args, **kwargs: recording(*args, **kwargs)
    try:
        experiment.run(0)
    finally:
        HorizonQP._solve_qp = original
    rated = [p for p in problems if p[4].size == 2 * p[2].size]
    assert len(rated) >= 20
    for hessian, n, gradient, rows, upper, lower in rated[::4]:
        moves, lam, flag, _ = ours(hessian, gradient, rows, upper, lower, n, np.zeros(upper.size, dtype=np.int64))
        assert flag == SOLVED
        stacked = np.vstack([rows, difference_rows(rows, n)])
        expected, expected_lam = reference(hessian, gradient, stacked, upper, lower)
        assert np.array_equal(np.flatnonzero(lam), np.flatnonzero(expected_lam))
        np.testing.assert_allclose(moves, expected, rtol=0, atol=1e-7 * np.abs(expected).max())
        scale = max(1.0, np.abs(gradient).max())
        assert np.abs(hessian @ moves + gradient + stacked.T @ lam).max() <= 1e-9 * scale
