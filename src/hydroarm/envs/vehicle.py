"""A Gymnasium environment: the vehicle holds station while its arm works (``hydroarm/UVMS-v0``).

Built by the one experiment builder (:func:`hydroarm.sim.experiment.build_experiment` with the
``vehicle`` section set): the plant is the floating system's
(:class:`~hydroarm.model.vehicle.fast.FastUVMSPlant`, BlueROV2 Heavy + Alpha 5 by default, a
uniform current along world x), the arm runs its reach-and-return task under the registry's
arm controller inside the whole system's
:class:`~hydroarm.control.uvms_control.UVMSController` (``SMC`` by default, as in the vehicle
study); the agent takes the station keeper's place and drives the thrusters.

* action (n_thr,): thruster commands normalised to [-1, 1] (1: the thruster's forward limit,
  -1 its reverse limit); outside values are clipped, non-finite ones raise ``ValueError``;
* observation (12 + 2 n_arm,), float64: the vehicle's body-frame pose error to its start pose
  (position m, rotation vector rad), its body twist, the arm's angles and rates;
* observation bounds: finite (position error twice ``drift_limit``, rotation vector pi, body
  speeds :data:`MAX_SPEED` and :data:`MAX_RATE`, arm angles :data:`ARM_POSITION_BOUND` and rates
  :data:`ARM_RATE_BOUND`); the observation is clipped into them;
* reward: ``-(|position error|^2 + attitude_weight |attitude error|^2)`` (of the unclipped error);
* truncation after ``duration`` s; termination if the state blows up, drifts more than
  ``drift_limit`` m or a speed leaves its bound, with the reward ``termination_reward``
  (settings: :class:`UVMSEnvConfig`).

``reset(seed=...)`` draws the vehicle's start offset (uniform within ``start_offset`` m per
axis) from the seeded generator: the same seed gives the same episode. The compiled plant step
and the arm controller's compiled code are compiled (or loaded from numba's cache) when the
environment is made, not at the first ``step``. ``gymnasium.make_vec("hydroarm/UVMS-v0",
num_envs=...)`` gives :class:`~hydroarm.envs.vector.WorkerVectorEnv`.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import pydantic
from gymnasium import spaces

from hydroarm.config import FrozenModel
from hydroarm.control.vehicle_control import pose_error
from hydroarm.sim.experiment import ExperimentConfig, build_experiment

MAX_SPEED = 10.0
"""m/s: the bound on the vehicle's body-frame linear speeds (beyond: the episode ends)."""
MAX_RATE = 50.0
"""rad/s: the bound on the vehicle's body-frame angular rates (beyond: the episode ends)."""
ARM_POSITION_BOUND = 1e4
"""rad: the bound on the arm's joint angles."""
ARM_RATE_BOUND = 1e3
"""rad/s: the bound on the arm's joint rates (the runner's divergence speed)."""


class UVMSEnvConfig(FrozenModel):
    """The episode's settings of :class:`UVMSEnv` (the run's are its ``ExperimentConfig``)."""

    start_offset: float = pydantic.Field(
        0.05, ge=0.0, le=10.0, description="half-width of the seeded start offset per axis (m)"
    )
    drift_limit: float = pydantic.Field(5.0, gt=0.0, le=1000.0, description="drift that ends an episode (m)")
    termination_reward: float = pydantic.Field(
        -100.0, ge=-1e9, le=0.0, description="the reward of the step that ends an episode early (-)"
    )
    attitude_weight: float = pydantic.Field(
        0.1, ge=0.0, le=1e6, description="weight of the squared attitude error in the reward (1/rad^2 in m^2)"
    )


class UVMSEnv(gymnasium.Env):
    """See the module docstring. ``config``: the run's settings (default: the vehicle
    ``vehicle`` with ``arm``, the ``current``, ``duration`` s); ``episode``: :class:`UVMSEnvConfig`
    (or its fields as keywords)."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        vehicle: str = "bluerov2-heavy",
        arm: str = "mount",
        current: float = 0.2,
        duration: float = 5.0,
        start_offset: float = 0.05,
        arm_controller: str = "SMC",
        config: ExperimentConfig | None = None,
        episode: UVMSEnvConfig | None = None,
        **episode_settings: Any,
    ):
        if config is None:
            config = ExperimentConfig.model_validate(
                {"arm": arm, "duration": duration, "vehicle": {"name": vehicle, "current": current}}
            )
        if episode is None:
            episode = UVMSEnvConfig.model_validate({"start_offset": start_offset, **episode_settings})
        self.config, self.episode = config, episode
        self.experiment = build_experiment(config, arm_controller)
        self.uvms = self.experiment.uvms
        self.layout = self.uvms.layout  # the state's parts by name
        self.plant = self.experiment.plant
        self.arm_controller = self.experiment.controller.arm_controller  # the agent replaces the station keeper
        self.reference = self.experiment.reference
        self.period = config.control_period
        self.steps = int(round(config.duration / self.period))
        vehicle_ = self.uvms.vehicle
        self.n_arm, self.n_thr = self.uvms.n_arm, vehicle_.n_thrusters
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n_thr,), dtype=np.float64)
        n = self.n_arm
        high = np.concatenate([
            np.full(3, 2.0 * episode.drift_limit), np.full(3, np.pi), np.full(3, MAX_SPEED), np.full(3, MAX_RATE),
            np.full(n, ARM_POSITION_BOUND), np.full(n, ARM_RATE_BOUND),
        ])  # fmt: skip
        self.observation_space = spaces.Box(-high, high, dtype=np.float64)
        self.x = self.experiment.x0.copy()
        self.target = self.x[self.layout.base_pose].copy()
        self.k = 0
        self._y_arm = self.plant.joint_state(self.x)
        # compile (or load from numba's cache) the plant's step and the arm controller's code now,
        # not at the first step; reset() resets the controller
        y_arm = self.plant.joint_state(self.plant.measure(self.x, np.random.default_rng(0)))
        tau = self.arm_controller.compute(0.0, y_arm, self.reference).tau
        self.plant.step(0.0, self.x, np.concatenate([tau, np.zeros(self.n_thr)]), self.period)
        self.arm_controller.reset()

    def _observation(self) -> np.ndarray:
        x, parts = self.x, self.layout
        observation = np.concatenate(
            [pose_error(x[parts.base_pose], self.target), x[parts.base_velocity], x[parts.arm_q], x[parts.arm_v]]
        )
        return np.clip(observation, self.observation_space.low, self.observation_space.high)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.arm_controller.reset()
        self.x = self.experiment.x0.copy()
        self.target = self.x[self.layout.base_pose].copy()
        offset = self.episode.start_offset
        self.x[:3] += self.np_random.uniform(-offset, offset, size=3)
        self.k = 0
        self._y_arm = self._measure_arm(self.x)
        return self._observation(), {"t": 0.0}

    def _measure_arm(self, x: np.ndarray) -> np.ndarray:
        """The arm's measured joint state [q, v] (2 n_arm,) at the floating system's state ``x``."""
        return self.plant.joint_state(self.plant.measure(x, self.np_random))

    def step(self, action):
        action = np.asarray(action, dtype=float).reshape(-1)
        if action.shape != (self.n_thr,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be {self.n_thr} finite thruster commands in [-1, 1], got {action}")
        action = np.clip(action, -1.0, 1.0)
        vehicle = self.uvms.vehicle
        thrust = np.where(action >= 0.0, action * vehicle.thrust_max, -action * vehicle.thrust_min)
        t = self.k * self.period
        y_arm = self._y_arm
        tau = self.arm_controller.compute(t, y_arm, self.reference).tau
        self.x, _ = self.plant.step(t, self.x, np.concatenate([tau, thrust]), self.period)
        self._y_arm = self._measure_arm(self.x)
        if np.all(np.isfinite(y_arm)) and np.all(np.isfinite(self._y_arm)):
            # the arm controller sees the transition, as in the runner: a learning one learns over an episode
            self.arm_controller.observe(t, y_arm, tau, self._y_arm)
        self.k += 1
        observation = self._observation()
        parts = self.layout
        error = pose_error(self.x[parts.base_pose], self.target)  # unclipped: the reward and the drift
        reward = -float(error[:3] @ error[:3] + self.episode.attitude_weight * error[3:] @ error[3:])
        speeds = np.abs(np.concatenate([self.x[parts.base_velocity], self.x[parts.arm_v]]))
        limits = np.concatenate([np.full(3, MAX_SPEED), np.full(3, MAX_RATE), np.full(self.n_arm, ARM_RATE_BOUND)])
        terminated = bool(
            not np.all(np.isfinite(self.x))
            or np.linalg.norm(error[:3]) > self.episode.drift_limit
            or np.any(speeds > limits)
            or np.any(np.abs(self.x[parts.arm_q]) > ARM_POSITION_BOUND)
        )
        if terminated:
            observation = np.nan_to_num(observation, nan=0.0, posinf=0.0, neginf=0.0)
            reward = float(self.episode.termination_reward)
        info: dict[str, Any] = {"t": self.k * self.period, "thrust": thrust}
        return observation, reward, terminated, self.k >= self.steps, info
