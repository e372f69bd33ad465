"""A closed-loop bandwidth chosen for a stated delay margin (issue 32): ``idmpc.delay_margin``
caps each joint's LQR so that its loop stays stable with that many periods of delay it is not
told of; off by default (the ideal loop's weights, unchanged)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import polynomial as P

from hydroarm.control.delay_design import MARGIN_RADIUS, delay_margin_weight
from hydroarm.control.idmpc import IDMPCConfig, InverseDynamicsMPC
from hydroarm.control.linear import joint_lqr
from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

T = 0.01


def one_period_late_roots(gain: np.ndarray) -> np.ndarray:
    """The closed-loop poles of x_{k+1} = A x_k + B u_{k-1}, u_k = -K x_k, as the roots of
    det(z^2 I - z A + B K) = 0 written out (polynomials in z, lowest power first)."""
    b0, b1 = 0.5 * T * T, T
    k0, k1 = gain
    m00 = [b0 * k0, -1.0, 1.0]  # z^2 - z + b0 k0
    m01 = [b0 * k1, -T]  # -z T + b0 k1
    m10 = [b1 * k0]  # b1 k0 (A[1, 0] = 0)
    m11 = [b1 * k1, -1.0, 1.0]  # z^2 - z + b1 k1
    determinant = P.polysub(P.polymul(m00, m11), P.polymul(m01, m10))
    return P.polyroots(determinant)


def test_the_margin_weight_puts_the_one_period_late_loop_at_the_stated_radius():
    weight = delay_margin_weight(T, 300.0, 0.01, 1)
    radius = np.max(np.abs(one_period_late_roots(joint_lqr(T, 300.0, 0.01, weight)[1])))
    assert radius == pytest.approx(MARGIN_RADIUS, abs=1e-9)
    assert weight == pytest.approx(5.62e-5, rel=1e-3)
    lighter = joint_lqr(T, 300.0, 0.01, 0.9 * weight)[1]
    assert np.max(np.abs(one_period_late_roots(lighter))) > MARGIN_RADIUS  # the smallest such weight
    # the default wrist's weight is unstable one period late
    assert np.max(np.abs(one_period_late_roots(joint_lqr(T, 300.0, 0.01, 1e-6)[1]))) > 1.3


def test_no_margin_leaves_the_weights_alone_and_a_margin_floors_them():
    arm = load_arm("paper")
    plain = InverseDynamicsMPC(arm, IDMPCConfig(), T)
    assert IDMPCConfig().delay_margin == 0
    margin = InverseDynamicsMPC(arm, IDMPCConfig(delay_margin=1), T)
    floor = delay_margin_weight(T, 300.0, 0.01, 1)
    np.testing.assert_array_equal(margin.r_acceleration, np.maximum(plain.r_acceleration, floor))
    # off, it is left out of the settings' digest: run ids made before it still match
    assert "delay_margin" not in ExperimentConfig().canonical()["idmpc"]
    assert with_overrides(ExperimentConfig(), {"idmpc.delay_margin": 1}).digest() != ExperimentConfig().digest()


@pytest.mark.parametrize(("margin", "diverges"), [(0, True), (1, False)])
def test_told_no_delay_with_one_period_of_it_diverges_without_the_margin_and_not_with_it(margin, diverges):
    """IDMPC on the paper task, the sensor one period late, the filter told no delay, 1.5 s."""
    overrides = {"sensor.delay": 1, "estimator.delay": 0, "idmpc.delay_margin": margin}
    traj = build_experiment(with_overrides(ExperimentConfig(duration=1.5), overrides), "IDMPC").run(0)
    assert traj.diverged == diverges
