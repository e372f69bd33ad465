"""The classic disturbance observers (TDE, first-order NDOB, the saturation gate) and their wiring."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.config import ConfigError
from hydroarm.control.observers import DisturbanceObserver, ObserverConfig
from hydroarm.model.arm.description import ArmSpec, build_arm
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.sim.runner import tracking_metrics


def vertical_axis_arm():
    """One joint about the vertical axis: constant inertia, no gravity torque, no Coriolis (h = 0)."""
    link = {
        "name": "rod",
        "a": 0.5,
        "alpha_deg": 0.0,
        "d": 0.0,
        "mass": 2.0,
        "com": [-0.25, 0.0, 0.0],
        "inertia_axial": 1e-3,
        "inertia_transverse": 0.04,
        "cylinder_diameter": 0.08,
    }
    return build_arm(ArmSpec(name="rod", torque_limit=100.0, links=[link]))


def exact_step(arm, y, u, w, period):
    """The exact step of the one-joint arm (M constant, h = 0) under held u + w."""
    inertia = arm.mass_matrix(np.zeros(1))[0, 0]
    acceleration = (u + w) / inertia
    return np.array([y[0] + period * y[1] + 0.5 * period**2 * acceleration[0], y[1] + period * acceleration[0]])


def take(observer, y, u, y_next, saturated=False):
    """The observer takes the one-step residual of the transition (what ObservedController feeds it)."""
    nominal = NominalModel(observer.arm, inner_step=None)
    y, u, y_next = (np.asarray(a, dtype=float) for a in (y, u, y_next))
    r = nominal.tde_residual(y, u, y_next, observer.period, "blas")
    return observer.update(y, r, saturated)


def test_tde_recovers_a_constant_disturbance_after_one_step():
    arm = vertical_axis_arm()
    period = 0.01
    observer = DisturbanceObserver(arm, period, ObserverConfig(kind="tde"))
    np.testing.assert_array_equal(observer.feedforward(), 0.0)  # nothing seen yet
    w = np.array([3.7])
    y = np.array([0.2, -0.4])
    u = np.array([1.5])
    y_next = exact_step(arm, y, u, w, period)
    take(observer, y, u, y_next)
    np.testing.assert_allclose(observer.feedforward(), w, rtol=1e-10)


def test_tde_on_a_full_arm_matches_the_dynamics_residual():
    """On the 6-joint paper arm the TDE residual is M (v+ - v)/T + h - u at the step's start."""
    from hydroarm.model.arm.loading import load_arm

    arm = load_arm("paper")
    rng = np.random.default_rng(3)
    q, v, dv, u = rng.normal(size=(4, 6))
    observer = DisturbanceObserver(arm, 0.01, ObserverConfig(kind="tde"))
    y, y_next = np.concatenate([q, v]), np.concatenate([q + 0.01 * v, v + dv])
    take(observer, y, u, y_next)
    expected = arm.mass_matrix(q) @ dv / 0.01 + arm.nonlinear_effects(q, v) - u
    np.testing.assert_allclose(observer.estimate, expected, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("gain", [0.05, 0.1, 0.5, 1.0])
def test_ndob_converges_at_rate_l(gain):
    """For a constant disturbance the NDOB's error after k steps is (1 - L)^k of the disturbance."""
    arm = vertical_axis_arm()
    period = 0.01
    observer = DisturbanceObserver(arm, period, ObserverConfig(kind="ndob", gain=gain))
    w = np.array([-2.0])
    y = np.array([0.0, 0.0])
    for k in range(1, 30):
        u = np.array([np.sin(k)])
        y_next = exact_step(arm, y, u, w, period)
        take(observer, y, u, y_next)
        y = y_next
        np.testing.assert_allclose(w - observer.estimate, w * (1.0 - gain) ** k, rtol=1e-7, atol=1e-12)


def test_gate_holds_the_feedforward_on_the_step_after_a_saturation():
    arm = vertical_axis_arm()
    observer = DisturbanceObserver(arm, 0.01, ObserverConfig(kind="tde", gate=True))
    y = np.array([0.0, 0.0])
    y_next = exact_step(arm, y, np.array([1.0]), np.array([2.0]), 0.01)
    take(observer, y, np.array([1.0]), y_next, saturated=True)
    np.testing.assert_array_equal(observer.feedforward(), 0.0)
    np.testing.assert_allclose(observer.estimate, [2.0], rtol=1e-10)  # it still learned
    take(observer, y, np.array([1.0]), y_next, saturated=False)
    np.testing.assert_allclose(observer.feedforward(), [2.0], rtol=1e-10)
    ungated = DisturbanceObserver(arm, 0.01, ObserverConfig(kind="tde"))
    take(ungated, y, np.array([1.0]), y_next, saturated=True)
    np.testing.assert_allclose(ungated.feedforward(), [2.0], rtol=1e-10)


def test_observer_settings_are_validated():
    with pytest.raises(ConfigError, match="observer.gain"):
        with_overrides(ExperimentConfig(), {"observer.gain": 1.5})
    with pytest.raises(ConfigError, match="observer.kind"):
        with_overrides(ExperimentConfig(), {"observer.kind": "eso"})


def test_an_observer_under_a_gp_controller_is_refused():
    config = with_overrides(ExperimentConfig(duration=0.1), {"observer.kind": "tde"})
    with pytest.raises(ConfigError, match="GP-IDMPC learns the disturbance itself"):
        build_experiment(config, "gp-idmpc")


@pytest.mark.parametrize(
    ("controller", "name"),
    [("IDMPC", "IDMPC+TDE+KF"), ("MPC", "MPC+TDE"), ("SMC", "SMC+TDE")],
)
def test_tde_under_every_controller_lowers_the_tracking_error(controller, name):
    """On the paper task (1.5 s, clean) the TDE's estimate, fed forward, lowers E_p after 1 s
    under each controller it runs under: the estimate is used, not only computed."""
    base = ExperimentConfig(duration=1.5)
    with_tde = build_experiment(with_overrides(base, {"observer.kind": "tde"}), controller)
    assert with_tde.controller.name == name
    traj = with_tde.run()
    plain = build_experiment(base, controller).run()
    after = traj.t > 1.0
    error = np.mean((traj.q - traj.q_ref)[after] ** 2)
    error_plain = np.mean((plain.q - plain.q_ref)[after] ** 2)
    assert error < 0.5 * error_plain
    assert np.all(np.isfinite(traj.disturbance_estimate[after]))
    assert np.isfinite(tracking_metrics(traj)["Ep"]).all()


def test_tune_takes_the_ndob_gain_into_the_grid_of_a_controller_under_an_ndob():
    from hydroarm.control.registry import controller_spec
    from hydroarm.studies.tune import NDOB_GAINS, plan_tuning, tuning_grid

    under_ndob = with_overrides(ExperimentConfig(), {"observer.kind": "ndob"})
    assert tuning_grid(under_ndob, "idmpc")["observer.gain"] == NDOB_GAINS
    assert tuning_grid(ExperimentConfig(), "idmpc") == {
        k: list(v) for k, v in controller_spec("IDMPC").tuning_grid.items()
    }
    tasks = plan_tuning(under_ndob, "IDMPC")
    assert len(tasks) == 2 * len(NDOB_GAINS) * 9  # 3 x 3 IDMPC gains x 4 L x {clean, noisy}
    assert {dict(t.point)["observer.gain"] for t in tasks} == set(NDOB_GAINS)
    assert all(t.settings["observer"]["kind"] == "ndob" for t in tasks)
