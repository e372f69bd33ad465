"""The declared controller ports (hydroarm.control.interface): the feed-forward keywords of
``compute`` that observers and GP-MPC use, and the one accessor of a wrapped controller's
learner (``learner_of``, through ``WrapsController.controller``) instead of hasattr chains."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.control.gp import GPConfig
from hydroarm.control.gpmpc import GPMPC, GPMPCConfig
from hydroarm.control.interface import (
    FEEDFORWARD_PORTS,
    AccelerationFeedforward,
    ControlOutput,
    ModelLearner,
    TorqueFeedforward,
    WrapsController,
    controller_chain,
    has_port,
    learner_of,
    require_port,
)
from hydroarm.control.mpc import LinearMPC
from hydroarm.control.observers import DisturbanceObserver, ObservedController, ObserverConfig
from hydroarm.control.registry import REGISTRY, build_controller
from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, controller_settings
from hydroarm.sim.vehicle import VehicleRun


@pytest.fixture(scope="module")
def arm():
    return load_arm("paper")


def _raw(name: str, arm):
    """Registered controller ``name`` with no estimator and no observer around it."""
    config = ExperimentConfig()
    sections = {**controller_settings(config), "estimator": config.estimator.model_copy(update={"kind": "none"})}
    return build_controller(name, arm, sections, config.control_period)


def test_every_controller_that_runs_over_an_observer_declares_the_torque_port(arm):
    """Registry ``observer=True`` means the torque port: removing ``feedforward_torque`` from one
    of their ``compute`` fails here (and ObservedController refuses it when built)."""
    takes = [name for name, spec in REGISTRY.items() if spec.observer]
    assert {"SMC", "MPC", "IDMPC"} <= set(takes)
    for name in takes:
        controller = _raw(name, arm)
        assert has_port(controller, "torque"), name
        assert isinstance(controller, TorqueFeedforward), name


def test_the_linear_mpc_declares_both_ports(arm):
    mpc = LinearMPC(arm)
    assert all(has_port(mpc, port) for port in FEEDFORWARD_PORTS)
    assert isinstance(mpc, AccelerationFeedforward)
    assert not has_port(GPMPC(arm, mpc), "torque")  # GP-MPC feeds its own estimate: no port to take one


class _NoPorts:
    """A controller whose compute takes no feed-forward."""

    name = "plain"
    control_period = 0.01
    torque_limit = np.ones(6)

    def reset(self) -> None: ...

    def compute(self, t, y, reference) -> ControlOutput:
        return ControlOutput(tau=np.zeros(6))

    def observe(self, t, y, u, y_next) -> None: ...


class _TorqueOnly(_NoPorts):
    name = "torque-only"

    def __init__(self):
        self.calls = []

    def compute(self, t, y, reference, feedforward_torque=None) -> ControlOutput:
        self.calls.append(feedforward_torque)
        return ControlOutput(tau=np.zeros(6))


def test_a_wrapper_refuses_a_controller_without_its_port(arm):
    observer = DisturbanceObserver(arm, 0.01, ObserverConfig(kind="tde"))
    with pytest.raises(TypeError, match="plain.*feedforward_torque"):
        ObservedController(_NoPorts(), observer, arm)
    with pytest.raises(TypeError, match="torque-only.*feedforward_acceleration"):
        GPMPC(arm, _TorqueOnly(), GPConfig(), GPMPCConfig(feedforward="acceleration"))
    with pytest.raises(TypeError, match="feedforward_torque"):
        require_port(_NoPorts(), "torque", "test")
    GPMPC(arm, _TorqueOnly(), GPConfig(), GPMPCConfig(feedforward="torque"))  # the port it uses is there


def test_the_observer_feeds_its_estimate_through_the_port(arm):
    inner = _TorqueOnly()
    observed = ObservedController(inner, DisturbanceObserver(arm, 0.01, ObserverConfig(kind="tde")), arm)
    out = observed.compute(0.0, np.zeros(12), None)  # the inner controller reads no reference
    assert len(inner.calls) == 1 and inner.calls[0] is not None
    assert np.array_equal(out.disturbance_mean, inner.calls[0])


def test_learner_of_finds_the_model_behind_the_filter():
    """PI-IDMPC behind its Kalman filter: ``learner_of`` finds it through the declared chain
    (what ``hydroarm run --model/--save-model`` uses); a controller with no model has none."""
    experiment = build_experiment(ExperimentConfig(duration=0.05), "PI-IDMPC")
    chain = controller_chain(experiment.controller)
    assert len(chain) >= 2 and isinstance(chain[0], WrapsController)
    learner = learner_of(experiment.controller)
    assert isinstance(learner, ModelLearner) and learner is chain[-1]
    assert learner.name.startswith("PI-IDMPC")
    assert learner_of(build_experiment(ExperimentConfig(duration=0.05), "MPC").controller) is None


def test_the_vehicle_controller_wraps_the_arm_controller():
    """The station keeper's controller declares the arm's as the one it wraps."""
    config = ExperimentConfig(arm="mount", duration=0.05, vehicle=VehicleRun(name="bluerov2_heavy"))
    controller = build_experiment(config, "smc").controller
    chain = controller_chain(controller)
    assert isinstance(controller, WrapsController) and controller.controller is controller.arm_controller
    assert chain[1] is controller.arm_controller and chain[-1].name == "SMC"
