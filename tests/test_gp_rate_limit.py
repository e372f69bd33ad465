"""GP-IDMPC under the drives' rate limit (issue 32): the GP's estimate answers the acceleration it
is asked at (its added mass), and the rate-limited horizon QP must hold it linear in the acceleration
the drives leave, not frozen at the planned one. Frozen, the iiwa14's flagship under the campaign's
1000 N m/s rate limit alone ran 50 rad off its reference in 10 s (docs/robustness.md, section 6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroarm import load_arm
from hydroarm.control.drive_limits import linearised_disturbance
from hydroarm.control.gp import GPConfig
from hydroarm.control.idmpc import InverseDynamicsMPC
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

ROOT = Path(__file__).resolve().parents[1]
BAND, AFTER = 0.5, 2.0  # rad, s: the campaign's band


def test_the_learned_added_mass_is_the_slope_of_a_linear_water_in_the_acceleration():
    arm = load_arm("paper")
    n = arm.n_joints
    mpc = InverseDynamicsMPC(arm, gp_config=GPConfig(window=60))
    added = np.linspace(0.5, 3.0, n)  # kg m^2: w = -M_A a, the water's added-mass force
    rng = np.random.default_rng(0)
    for _ in range(60):
        y, a = np.zeros(2 * n), rng.normal(scale=50.0, size=n)
        mpc.gp.update(mpc.gp_input(y, a), -added * a)
    for _ in range(20):
        mpc.gp.update_hyperparameters()
    mpc._gp_input = mpc.gp_input(np.zeros(2 * n), np.full(n, 5.0))
    np.testing.assert_allclose(mpc._learned_added_mass(), added, rtol=0.05)
    mpc.gp.reset()
    for _ in range(60):  # a water that pushes with the acceleration: no negative inertia, floored at 0
        y, a = np.zeros(2 * n), rng.normal(scale=50.0, size=n)
        mpc.gp.update(mpc.gp_input(y, a), added * a)
    for _ in range(20):
        mpc.gp.update_hyperparameters()
    np.testing.assert_array_equal(mpc._learned_added_mass(), np.zeros(n))


def test_the_iiwa14_flagship_under_the_rate_limit_stays_in_the_band():
    config = ExperimentConfig(arm=str(ROOT / "examples" / "urdf" / "iiwa14.urdf"), duration=3.0)
    config = with_overrides(config, {"actuator.rate_limit": 1000.0})
    traj = build_experiment(config, "GP-IDMPC").run(0)
    n = traj.q_ref.shape[1]
    late = traj.t >= AFTER
    error = np.abs(traj.q_ref - traj.x[:, :n])[late]
    assert not traj.diverged
    np.testing.assert_allclose(traj.u, traj.extra["u_command"], rtol=0, atol=1e-9)  # the drives give the command
    assert np.max(error) < BAND  # frozen estimate: 1.73 rad between 2 and 3 s (already 50 rad by 10 s)


def test_a_reset_forgets_the_linearised_estimate_of_the_last_run():
    arm = load_arm("paper")
    n = arm.n_joints
    mpc = InverseDynamicsMPC(arm, gp_config=GPConfig())
    mpc.drive_limits(np.zeros(n), np.full(n, 10.0))
    mpc.rate_qp.disturbance_model = linearised_disturbance(np.ones(n), np.ones(n))
    assert mpc.rate_qp.disturbance_model is not None
    mpc.reset()
    assert mpc.rate_qp.disturbance_model is None  # the next run starts from the plain frozen estimate
