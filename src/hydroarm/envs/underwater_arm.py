"""A Gymnasium environment: the underwater arm tracking the paper task.

``gymnasium.make("hydroarm/UnderwaterArm-v0", arm="paper", ...)`` (registered on
``import hydroarm`` when Gymnasium is installed: ``pip install hydroarm[gym]``).

* observation: the measured joint state [q, v] (2n, with the plant's seeded
  noise), then the reference [q_r, v_r] (2n) at the current time: shape (4n,);
* action: joint torques (n,) within the arm's limits (clipped if outside);
* reward: minus the tracking cost of the true state at the start of the step,
  ``-(|q_r - q|^2 + 0.01 |v_r - v|^2)`` (rad^2): its mean over an episode is
  the mean over joints of the paper's E_p, plus a small velocity term;
* truncation at the end of the task (``duration``); termination if the plant
  diverges;
* ``info``: the true state ``x``, time ``t``, the water/current disturbance
  over the step (``disturbance``, N m) and the error ``q_ref - q``;
* start: rest at q = 0, moved by the config's ``initial_state`` (none by
  default); ``reset(options={"x0": x0})`` starts at ``x0`` instead.

Seeded through ``reset(seed=...)``: the noise stream is the same as
:func:`hydroarm.studies.runner.run_closed_loop`'s with that seed, so a controller
driven through :class:`ControllerPolicy` reproduces the runner exactly.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from hydroarm.model.loading import load_arm
from hydroarm.control.interface import Controller
from hydroarm.studies.experiment import ExperimentConfig, build_controller, with_overrides
from hydroarm.model.plant import UnderwaterPlant
from hydroarm.studies.runner import DIVERGENCE_SPEED
from hydroarm.model.task import paper_reference

VELOCITY_WEIGHT = 0.01


class UnderwaterArmEnv(gymnasium.Env):
    """The underwater arm and the paper task as a Gymnasium environment (see the module docstring)."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        arm: str = "paper",
        config: ExperimentConfig | None = None,
        noise_variance: float | None = None,
        duration: float | None = None,
    ):
        config = config if config is not None else ExperimentConfig()
        overrides: dict[str, Any] = {"arm": arm}
        if noise_variance is not None:
            overrides["plant.noise_variance"] = noise_variance
        if duration is not None:
            overrides["duration"] = duration
        self.config = with_overrides(config, overrides)
        self.arm = load_arm(self.config.arm)
        self.plant = UnderwaterPlant(self.arm, self.config.water, self.config.plant)
        self.reference = paper_reference()
        self.n = self.arm.n_joints
        self.period = self.config.control_period
        self.steps = int(round(self.config.duration / self.period))
        limit = self.arm.torque_limit.astype(np.float64)
        self.action_space = spaces.Box(-limit, limit, dtype=np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(4 * self.n,), dtype=np.float64)
        self._x = np.zeros(2 * self.n)
        self._y = np.zeros(2 * self.n)
        self._k = 0

    @property
    def t(self) -> float:
        return self._k * self.period

    @property
    def measured_state(self) -> np.ndarray:
        """The last measurement [q, v] (2n,) (what a controller sees)."""
        return self._y.copy()

    def _observation(self) -> np.ndarray:
        q_r, v_r, _ = self.reference.sample(self.t)
        return np.concatenate([self._y, q_r, v_r])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._k = 0
        x0 = None if options is None else options.get("x0")
        if x0 is None:  # rest at q = 0, moved by the config's initial_state (none by default)
            self._x = self.config.initial_state.apply(np.zeros(2 * self.n))
        else:
            self._x = np.asarray(x0, dtype=float).copy()
        self._y = self.plant.measure(self._x, self.np_random)
        return self._observation(), {"x": self._x.copy(), "t": 0.0}

    def step(self, action):
        action = np.asarray(action, dtype=float)
        if action.shape != (self.n,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be {self.n} finite joint torques (N m); got {action!r}")
        tau = np.clip(action, self.action_space.low, self.action_space.high)
        t = self.t
        q_r, v_r, _ = self.reference.sample(t)
        error = q_r - self._x[: self.n]
        reward = -float(error @ error + VELOCITY_WEIGHT * np.sum((v_r - self._x[self.n :]) ** 2))
        x_next, step_info = self.plant.step(t, self._x, tau, self.period)
        diverged = not np.all(np.isfinite(x_next)) or np.max(np.abs(x_next[self.n :])) > DIVERGENCE_SPEED
        info = {"x": self._x.copy(), "t": t, "disturbance": step_info.disturbance, "error": error}
        self._k += 1
        if diverged:
            return self._observation(), reward, True, False, info
        self._x = x_next
        self._y = self.plant.measure(x_next, self.np_random)
        truncated = self._k >= self.steps
        return self._observation(), reward, False, truncated, info


class ControllerPolicy:
    """Drive the environment with a built-in controller (SMC, MPC, GP-MPC).

    ``policy = ControllerPolicy.from_name("GP-MPC", env)``; at each step
    ``action = policy(obs)``; after ``env.step`` call ``policy.observe(obs_next)``
    so a learning controller sees the transition.
    """

    def __init__(self, controller: Controller, env: UnderwaterArmEnv):
        self.controller = controller
        self.env = env
        self._last: tuple[np.ndarray, np.ndarray, float] | None = None
        controller.reset()

    @classmethod
    def from_name(cls, name: str, env: UnderwaterArmEnv) -> ControllerPolicy:
        return cls(build_controller(name, env.arm, env.config), env)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        n = self.env.n
        y = np.asarray(observation[: 2 * n], dtype=float)
        t = self.env.t
        tau = self.controller.compute(t, y, self.env.reference).tau
        self._last = (y, tau, t)
        return tau

    def observe(self, observation: np.ndarray) -> None:
        if self._last is None:
            return
        y, tau, t = self._last
        self.controller.observe(t, y, tau, np.asarray(observation[: 2 * self.env.n], dtype=float))


def register() -> None:
    """Register ``hydroarm/UnderwaterArm-v0`` with Gymnasium (idempotent)."""
    if "hydroarm/UnderwaterArm-v0" not in gymnasium.registry:
        gymnasium.register(id="hydroarm/UnderwaterArm-v0", entry_point="hydroarm.envs.underwater_arm:UnderwaterArmEnv")
