"""A Gymnasium environment: the vehicle holds station while its arm works (``hydroarm/UVMS-v0``).

The plant is :class:`~hydroarm.model.uvms_fast.FastUVMSPlant` (BlueROV2 Heavy + Alpha 5 by
default, a uniform current along world x); the arm runs its reach-and-return task under the
registry's arm controller (``SMC`` on the fixed-base arm model, as in the UVMS study); the
agent drives the thrusters.

* action (n_thr,): thruster commands normalised to [-1, 1] (1: the thruster's forward limit,
  -1 its reverse limit); outside values are clipped, non-finite ones raise ``ValueError``;
* observation (12 + 2 n_arm,), float64: the vehicle's body-frame pose error to its start pose
  (position m, rotation vector rad), its body twist, the arm's angles and rates;
* reward: ``-(|position error|^2 + 0.1 |attitude error|^2)``;
* observation bounds: finite (position error 10 m, rotation vector pi, body speeds 10 m/s and
  50 rad/s, arm angles 1e4 rad and rates 1e3 rad/s); the observation is clipped into them;
* truncation after ``duration`` s; termination if the state blows up, drifts > 5 m or a speed
  leaves its bound.

``reset(seed=...)`` draws the vehicle's start offset (uniform within ``start_offset`` m per
axis) from the seeded generator: the same seed gives the same episode.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from hydroarm.control.uvms_control import UVMSController
from hydroarm.control.vehicle_control import pose_error
from hydroarm.model.uvms import build_uvms
from hydroarm.model.uvms_fast import FastUVMSPlant
from hydroarm.model.water import CurrentConfig, Water
from hydroarm.studies.uvms_run import ReachReturn, UVMSRunConfig, arm_sections

MAX_DRIFT = 5.0
"""m: a vehicle farther than this from its start pose ends the episode."""
MAX_SPEED = 10.0
"""m/s: the bound on the vehicle's body-frame linear speeds (beyond: the episode ends)."""
MAX_RATE = 50.0
"""rad/s: the bound on the vehicle's body-frame angular rates (beyond: the episode ends)."""
ARM_POSITION_BOUND = 1e4
"""rad: the bound on the arm's joint angles."""
ARM_RATE_BOUND = 1e3
"""rad/s: the bound on the arm's joint rates (the runner's divergence speed)."""


class UVMSEnv(gymnasium.Env):
    """See the module docstring."""

    metadata = {"render_modes": []}

    def __init__(self, vehicle: str = "bluerov2_heavy", arm: str = "mount", current: float = 0.2,
                 duration: float = 5.0, start_offset: float = 0.05, arm_controller: str = "SMC"):  # fmt: skip
        defaults = UVMSRunConfig()
        self.uvms = build_uvms(vehicle, arm)
        self.plant = FastUVMSPlant(self.uvms, Water(current=CurrentConfig(model="uniform", mean=[current, 0.0, 0.0])))
        self.period = defaults.control_period
        self.steps = int(round(duration / self.period))
        self.start_offset = start_offset
        self.reference = ReachReturn(defaults.home, defaults.reach, defaults.task_period)
        self.controller = UVMSController(
            self.uvms, arm_controller=arm_controller, control_period=self.period,
            arm_sections=arm_sections(arm_controller),
        )  # fmt: skip
        self.home = np.asarray(defaults.home, dtype=float)
        vehicle_ = self.uvms.vehicle
        self.n_arm, self.n_thr = self.uvms.n_arm, vehicle_.n_thrusters
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n_thr,), dtype=np.float64)
        n = self.n_arm
        high = np.concatenate([
            np.full(3, 2.0 * MAX_DRIFT), np.full(3, np.pi), np.full(3, MAX_SPEED), np.full(3, MAX_RATE),
            np.full(n, ARM_POSITION_BOUND), np.full(n, ARM_RATE_BOUND),
        ])  # fmt: skip
        self.observation_space = spaces.Box(-high, high, dtype=np.float64)
        self.x = self.plant.initial_state(self.uvms.neutral(q_arm=self.home))
        self.target = self.x[:7].copy()
        self.k = 0

    def _observation(self) -> np.ndarray:
        nq = self.uvms.nq
        x = self.x
        observation = np.concatenate(
            [pose_error(x[:7], self.target), x[nq : nq + 6], x[7:nq], x[nq + 6 : nq + 6 + self.n_arm]]
        )
        return np.clip(observation, self.observation_space.low, self.observation_space.high)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.controller.reset()
        self.x = self.plant.initial_state(self.uvms.neutral(q_arm=self.home))
        self.target = self.x[:7].copy()
        self.x[:3] += self.np_random.uniform(-self.start_offset, self.start_offset, size=3)
        self.k = 0
        return self._observation(), {"t": 0.0}

    def step(self, action):
        action = np.asarray(action, dtype=float).reshape(-1)
        if action.shape != (self.n_thr,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be {self.n_thr} finite thruster commands in [-1, 1], got {action}")
        action = np.clip(action, -1.0, 1.0)
        vehicle = self.uvms.vehicle
        thrust = np.where(action >= 0.0, action * vehicle.thrust_max, -action * vehicle.thrust_min)
        t = self.k * self.period
        nq = self.uvms.nq
        y_arm = np.concatenate([self.x[7:nq], self.x[nq + 6 : nq + 6 + self.n_arm]])
        tau = self.controller.arm.compute(t, y_arm, self.reference).tau
        self.x, _ = self.plant.step(t, self.x, np.concatenate([tau, thrust]), self.period)
        self.k += 1
        observation = self._observation()
        error = pose_error(self.x[:7], self.target)  # unclipped: the reward and the drift
        reward = -float(error[:3] @ error[:3] + 0.1 * error[3:] @ error[3:])
        speeds = np.abs(np.concatenate([self.x[nq : nq + 6], self.x[nq + 6 : nq + 6 + self.n_arm]]))
        limits = np.concatenate([np.full(3, MAX_SPEED), np.full(3, MAX_RATE), np.full(self.n_arm, ARM_RATE_BOUND)])
        terminated = bool(
            not np.all(np.isfinite(self.x))
            or np.linalg.norm(error[:3]) > MAX_DRIFT
            or np.any(speeds > limits)
            or np.any(np.abs(self.x[7:nq]) > ARM_POSITION_BOUND)
        )
        if terminated:
            observation = np.nan_to_num(observation, nan=0.0, posinf=0.0, neginf=0.0)
            reward = -100.0
        info: dict[str, Any] = {"t": self.k * self.period, "thrust": thrust}
        return observation, reward, terminated, self.k >= self.steps, info
