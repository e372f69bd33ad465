"""The drives' rate limit known to the ID-MPCs (issue 32, item 2): the horizon QP's rate rows
against an independent solver (quadprog), the drives' output the controller is told, and closed loops whose
command never moves faster than the drives can follow (they diverged at 0.24 s before)."""

from __future__ import annotations

import numpy as np
import pytest
import quadprog

from hydroarm import load_arm
from hydroarm.control.drive_limits import rate_horizon
from hydroarm.control.idmpc import InverseDynamicsMPC
from hydroarm.control.idmpc_limits import HorizonQP
from hydroarm.model.real_loop.sensing import Actuator, ActuatorConfig
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

PERIOD = 0.01
RATE = 1000.0  # N m/s: the campaign's world


def test_the_drives_output_before_the_next_command_acts_is_what_they_give_then():
    config = ActuatorConfig(delay=2, rate_limit=[300.0, 50.0], bandwidth=15.0)
    drives, later = Actuator(config, 2, PERIOD), Actuator(config, 2, PERIOD)
    rng = np.random.default_rng(3)
    for _ in range(7):
        u = rng.normal(scale=20.0, size=2)
        drives.apply(u)
        later.apply(u)
    told = drives.pending_output()
    outputs = [later.apply(rng.normal(size=2)) for _ in range(3)]  # the next command acts in the third period
    np.testing.assert_array_equal(told, outputs[1])
    assert not np.array_equal(told, outputs[0])  # the commands in flight moved it
    undelayed = Actuator(ActuatorConfig(rate_limit=RATE), 2, PERIOD)
    undelayed.apply(np.array([50.0, -50.0]))
    np.testing.assert_array_equal(undelayed.pending_output(), [10.0, -10.0])


def test_the_rate_horizon_covers_the_drives_braking_ramp():
    limit = np.full(6, 500.0)
    assert rate_horizon(5, limit, np.full(6, RATE * PERIOD)) == 50  # 500 N m at 10 N m per step
    assert rate_horizon(5, limit, np.full(6, 1e6 * PERIOD)) == 5  # never shorter than the MPC's
    assert rate_horizon(5, limit, np.full(6, 1.0)) == 100  # capped


def _quadprog_plan(qp: HorizonQP, gradient, mass, bias, a_r, previous, step):
    """The same QP built here from its definition (the torque and the rate of every step) and
    solved by quadprog (Goldfarb-Idnani's dual method): an independent formulation and solver."""
    n, horizon = qp.n, qp.horizon
    rows = np.kron(np.eye(horizon), mass)
    base = (a_r @ mass.T).ravel() + np.tile(bias, horizon)  # tau = rows U + base
    shift = np.eye(horizon * n, k=-n)  # tau_{k-1} of step k's rows
    limit = np.tile(qp.limit[:n], horizon)
    before = np.concatenate([previous, np.zeros((horizon - 1) * n)])
    change = (np.eye(horizon * n) - shift) @ rows
    change_base = (np.eye(horizon * n) - shift) @ base - before
    bound = np.tile(step, horizon)
    a_ineq = np.vstack([rows, -rows, change, -change])  # a_ineq u >= b_ineq
    b_ineq = -np.concatenate([limit + base, limit - base, bound + change_base, bound - change_base])
    moves = quadprog.solve_qp(qp.hessian, -gradient, a_ineq.T, b_ineq, 0)[0]
    return moves, rows, base


@pytest.mark.parametrize("rate_solver", ["daqp", "structured"])
def test_the_rate_rows_plan_agrees_with_quadprog_and_ramps_from_the_drives_output(rate_solver):
    arm = load_arm("paper")
    controller = InverseDynamicsMPC(arm)
    n, horizon = arm.n_joints, 8
    p = controller.P
    weights = np.full(n, 300.0), np.full(n, 0.01)
    qp = HorizonQP(
        arm, PERIOD, horizon, *weights, controller.r_acceleration, p, controller.torque_limit, 0,
        rate_solver=rate_solver,
    )  # fmt: skip
    rng = np.random.default_rng(0)
    q = rng.uniform(-1, 1, n)
    mass = controller.nominal.mass_matrix(q)
    bias = controller.nominal.nonlinear_effects(q, rng.normal(size=n))
    e0 = np.stack([rng.uniform(0.5, 2.0, n) * rng.choice([-1, 1], n), np.zeros(n)], axis=1)  # a start-up's errors
    c = np.zeros((horizon, n, 2))
    a_r = np.zeros((horizon, n))
    q_r = v_r = np.zeros((horizon + 1, n))
    previous = rng.uniform(-50, 50, n)
    step = np.full(n, RATE * PERIOD)
    first = qp.solve(e0, c, q_r, v_r, a_r, mass, bias, np.zeros(n), rate=(previous, step))
    assert first is not None and qp.rate_solves == 1 and qp.fallbacks == 0
    moves = qp.last_moves.ravel()
    reference, rows, base = _quadprog_plan(qp, qp.gradient(e0, c), mass, bias, a_r, previous, step)
    np.testing.assert_allclose(moves, reference, atol=1e-5 * np.abs(reference).max())
    tau = (rows @ moves + base).reshape(horizon, n)
    ramp = np.diff(np.vstack([previous, tau]), axis=0)
    assert np.abs(ramp).max() <= step[0] * (1 + 1e-6)  # the plan ramps from the drives' output
    free = np.linalg.solve(qp.hessian, -qp.gradient(e0, c))
    free_tau = (rows @ free + base).reshape(horizon, n)
    assert np.abs(np.diff(np.vstack([previous, free_tau]), axis=0)).max() > 5 * step[0]  # the rows bind


@pytest.mark.parametrize(
    ("controller", "overrides"),
    [
        ("IDMPC", {}),
        ("PI-IDMPC", {}),
        ("IDMPC", {"estimator.kind": "none"}),  # told by a copy of the drives of its own
        (
            "IDMPC",
            {
                "sensor.velocity": "differenced",
                "sensor.resolution": 9.5874e-05,
                "sensor.delay": 1,
                "friction.scale": 1.0,
                "actuator.bandwidth": 20.0,
            },
        ),  # the target world + drives; fmt: skip
    ],
)
def test_a_rate_limited_loop_commands_what_the_drives_give_and_does_not_diverge(controller, overrides):
    config = with_overrides(ExperimentConfig(duration=0.8), {"actuator.rate_limit": RATE, **overrides})
    traj = build_experiment(config, controller).run(0)
    command, applied = traj.extra["u_command"], traj.u
    before = np.vstack([np.zeros(command.shape[1]), applied[:-1]])  # the drives' output before each command
    assert np.abs(command - before).max() <= RATE * PERIOD * (1 + 1e-9)  # never beyond what they can follow
    assert np.abs(np.diff(applied, axis=0)).max() <= RATE * PERIOD * (1 + 1e-9)
    if "actuator.bandwidth" not in overrides:  # what it commands is what the drives give
        np.testing.assert_allclose(applied, command, rtol=0, atol=1e-9)
    assert not traj.diverged and np.all(np.isfinite(traj.x))
    assert np.abs(traj.q_ref - traj.q)[-1].max() < 1.0  # it was 5 rad off and diverging at 0.24 s
