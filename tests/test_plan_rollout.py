"""PI-IDMPC's compiled rollout (hydroarm.control.plan_rollout) against the NumPy / LAPACK code it
replaces: the torque allocation on random problems, the whole rollout on the paper start-up."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hydroarm.control.idmpc_limits import allocate
from hydroarm.control.interface import sample_times
from hydroarm.control.plan_rollout import allocate_fixed
from hydroarm.sim.experiment import ExperimentConfig, build_experiment


def test_allocate_fixed_equals_the_numpy_allocation():
    """Random SPD inertias, biases and accelerations with 0 to n joints over their limits: the same
    saturated set, accelerations and torques as :func:`allocate` (LAPACK's LU) to rounding, and
    the torques within the limits."""
    rng = np.random.default_rng(7)
    saturated_counts = set()
    for _ in range(400):
        n = int(rng.integers(2, 8))
        root = rng.normal(size=(n, n))
        mass = root @ root.T + 0.1 * np.eye(n)
        bias = rng.normal(size=n) * 5.0
        acceleration = rng.normal(size=n) * 10.0
        limit = np.abs(rng.normal(size=n)) * 10.0 + 1.0
        tau, a, sat = allocate(mass, bias, acceleration, limit)
        tau_f, a_f, sat_f = allocate_fixed(mass, bias, acceleration, limit)
        saturated_counts.add(int(sat.sum()))
        np.testing.assert_array_equal(sat_f, sat)
        scale = max(1.0, np.abs(a).max())
        np.testing.assert_allclose(a_f, a, rtol=0, atol=1e-11 * scale * np.linalg.cond(mass))
        np.testing.assert_allclose(tau_f, tau, rtol=0, atol=1e-10 * max(1.0, np.abs(tau).max()))
        assert np.all(np.abs(tau_f) <= limit)
    assert len(saturated_counts) >= 4  # free, partly and fully saturated problems were drawn


def _numpy_rollout(controller, t, y, reference, a_r):
    """The rollout as it was written in NumPy (one IDMPC step, the water's terms, CRBA mirrored,
    allocate, the double integrator's step), the reference of the compiled one."""
    n, period, horizon = controller.n, controller.control_period, controller.planner.horizon
    model, data = controller.arm.model, controller.planner.nominal.data
    q, v = y[:n].copy(), y[n:].copy()
    moves = np.empty((horizon, n))
    lower = np.tri(n, k=-1, dtype=bool)
    times = (t + np.arange(horizon) * period)[:, None] + controller.mpc._offsets[None, :]
    q_s, v_s, a_s = (x.reshape(times.shape + (n,)) for x in sample_times(reference, times.ravel()))
    for k in range(horizon):
        a = controller.mpc.acceleration_from_samples(np.concatenate([q, v]), q_s[k], v_s[k], a_s[k], remember=False)
        added, rest = controller.model.terms(q, v)
        mass = np.where(lower, pin.crba(model, data, q).T, pin.crba(model, data, q)) + added
        bias = pin.nonLinearEffects(model, data, q, v) - rest - controller._rest
        bound = np.maximum(np.abs(a), 100.0)
        a = np.clip(allocate(mass, bias, a, controller.torque_limit)[1], -bound, bound)
        moves[k] = a - a_r[k]
        q, v = q + period * v + 0.5 * period * period * a, v + period * a
    return moves


def test_the_compiled_rollout_is_the_numpy_rollout():
    """Every rollout of the paper start-up (0.3 s: 3 rad from the reference, the base joint
    saturated, the water model learning, a remainder estimate): the compiled rollout's moves equal
    the NumPy one's to 1e-12 of the largest move."""
    experiment = build_experiment(ExperimentConfig(duration=0.3), "PI-IDMPC")
    controller = experiment.controller.controller
    compiled = controller._rollout
    compared = []

    def both(t, y, reference, a_r):
        moves = compiled(t, y, reference, a_r)
        expected = _numpy_rollout(controller, t, y, reference, a_r)
        compared.append(float(np.abs(moves - expected).max() / np.abs(expected).max()))
        return moves

    controller._rollout = both
    experiment.run(0)
    assert len(compared) >= 10
    assert max(compared) < 1e-12


def test_the_water_along_the_plan_is_the_per_state_computation():
    """The compiled force along a plan is, bit for bit, f_k - M_A,k a_k (fixed-order product) +
    the remainder, clipped to the limits, state by state; some entries are clipped."""
    from hydroarm.control.plan_rollout import water_along_plan
    from hydroarm.model.dynamics import fixed_order

    rng = np.random.default_rng(3)
    horizon, n = 35, 6
    added = rng.normal(size=(horizon, n, n))
    rest, a = rng.normal(size=(horizon, n)) * 50.0, rng.normal(size=(horizon, n)) * 20.0
    remainder, limit = rng.normal(size=n), np.full(n, 60.0)
    expected = np.empty((horizon, n))
    for k in range(horizon):
        expected[k] = rest[k] - fixed_order.matvec(added[k], np.ascontiguousarray(a[k])) + remainder
    expected = np.clip(expected, -limit, limit)
    assert np.any(np.abs(expected) == limit)
    np.testing.assert_array_equal(water_along_plan(added, rest, a, remainder, limit), expected)
