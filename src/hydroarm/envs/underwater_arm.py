"""A Gymnasium environment: an underwater arm tracking its task.

``UnderwaterArmEnv`` is the closed loop of :func:`hydroarm.sim.runner.run_closed_loop`
with the controller taken out: the agent gives the joint torques. Everything else comes
from the one experiment builder, :func:`hydroarm.sim.experiment.build_experiment`
(with no controller): the true plant (:class:`~hydroarm.model.plant.UnderwaterPlant`,
with the water, current and measurement noise of the settings), the arm's own task
(:func:`~hydroarm.model.task.task_for_arm`: the paper's sinusoids, scaled into the joint
ranges of arms with limits) and the start state (the task's, moved by the settings'
``initial_state``: :func:`~hydroarm.sim.experiment.start_for_arm`).

``arm``: a built-in arm (``"paper"``, ``"ur5"``, ``"alpha5"``), a DH arm file or a URDF
(``.urdf`` with its ``<stem>.hydro.toml`` beside it, or the ``.hydro.toml`` itself);
default: the settings' ``arm`` (``"paper"``). ``config``: an
:class:`~hydroarm.sim.experiment.ExperimentConfig` (default: the paper reading's settings);
``noise_variance`` and ``duration`` override ``plant.noise_variance`` and ``duration``.
With n the arm's joint count:

* observation (4n,), float64: the measured joint state [q, v] (2n, rad and rad/s, with
  the plant's seeded noise: what a controller sees), then the reference [q_r, v_r] (2n)
  at the current time;
* action (n,): joint torques (N m) within the arm's torque limits (``action_space``:
  ``Box(-limit, limit)``); torques outside are clipped, non-finite ones or a wrong shape
  raise ``ValueError``;
* reward: minus the tracking cost of the true state at the start of the step,
  ``-(|q_r - q|^2 + 0.01 |v_r - v|^2)`` (rad^2): its mean over an episode is the sum
  over joints of the paper's E_p, plus a small velocity term;
* truncation at the end of the task (``duration`` / ``control_period`` steps);
  termination if the plant diverges (a non-finite state or a joint faster than
  :data:`~hydroarm.sim.runner.DIVERGENCE_SPEED`);
* ``info`` of ``step``: the true state ``x`` and time ``t`` at the start of the step, the
  water/current disturbance averaged over the step (``disturbance``, N m) and the
  tracking error ``q_r - q`` (``error``, rad); of ``reset``: ``x`` and ``t``;
* ``reset(options={"x0": x0})`` starts at ``x0`` (2n,) instead of the task's start.

Seeded through ``reset(seed=...)``: the measurement-noise stream is the one
:func:`~hydroarm.sim.runner.run_closed_loop` draws with that seed, so a controller
driven through :class:`ControllerPolicy` reproduces the runner bit for bit.

Example (``gymnasium.make`` imports :mod:`hydroarm.envs`, which registers the id)::

    import gymnasium
    from hydroarm.envs.underwater_arm import ControllerPolicy

    env = gymnasium.make("hydroarm.envs:hydroarm/UnderwaterArm-v0", arm="alpha5", duration=2.0)
    policy = ControllerPolicy.from_name("gp-mpc", env)
    obs, info = env.reset(seed=0)
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        policy.observe(obs)  # a learning controller sees the transition
        done = terminated or truncated
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from hydroarm.control.interface import Controller
from hydroarm.sim.experiment import ExperimentConfig, build_controller, build_experiment, with_overrides
from hydroarm.sim.runner import DIVERGENCE_SPEED

__all__ = ["VELOCITY_WEIGHT", "ControllerPolicy", "UnderwaterArmEnv"]

VELOCITY_WEIGHT = 0.01
"""Weight of the velocity error in the reward (s^2)."""


class UnderwaterArmEnv(gymnasium.Env):
    """An underwater arm tracking its task, as a Gymnasium environment (see the module docstring).

    Attributes: ``config`` (the settings), ``experiment`` (what
    :func:`~hydroarm.sim.experiment.build_experiment` built), ``arm``, ``plant``,
    ``reference``, ``x0`` (the default start), ``n`` (joints), ``period`` (s), ``steps``
    (per episode).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        arm: str | Path | None = None,
        config: ExperimentConfig | None = None,
        noise_variance: float | None = None,
        duration: float | None = None,
        render_mode: str | None = None,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}; got {render_mode!r}")
        self.render_mode = render_mode
        self._scene = None
        config = config if config is not None else ExperimentConfig()
        overrides: dict[str, Any] = {}
        if arm is not None:
            overrides["arm"] = str(arm)
        if noise_variance is not None:
            overrides["plant.noise_variance"] = noise_variance
        if duration is not None:
            overrides["duration"] = duration
        self.config = with_overrides(config, overrides) if overrides else config
        self.experiment = build_experiment(self.config, None)
        self.arm = self.experiment.arm
        self.plant = self.experiment.plant
        self.reference = self.experiment.reference
        self.x0 = self.experiment.x0.copy()
        self.n = self.arm.n_joints
        self.period = self.experiment.control_period
        self.steps = int(round(self.config.duration / self.period))
        limit = np.asarray(self.arm.torque_limit, dtype=np.float64)
        self.action_space = spaces.Box(-limit, limit, dtype=np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(4 * self.n,), dtype=np.float64)
        self._x = self.x0.copy()
        self._y = self.x0.copy()
        self._k = 0

    @property
    def t(self) -> float:
        """The current time (s): control step k times the period, as the runner counts it."""
        return self._k * self.period

    @property
    def measured_state(self) -> np.ndarray:
        """The last measurement [q, v] (2n,) (what a controller sees)."""
        return self._y.copy()

    @property
    def state(self) -> np.ndarray:
        """The true state [q, v] (2n,)."""
        return self._x.copy()

    def _observation(self) -> np.ndarray:
        q_r, v_r, _ = self.reference.sample(self.t)
        return np.concatenate([self._y, q_r, v_r])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._k = 0
        x0 = None if options is None else options.get("x0")
        if x0 is None:
            self._x = self.x0.copy()
        else:
            x0 = np.asarray(x0, dtype=float)
            if x0.shape != (2 * self.n,) or not np.all(np.isfinite(x0)):
                raise ValueError(f"options['x0'] must be {2 * self.n} finite numbers [q, v]; got {x0!r}")
            self._x = x0.copy()
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

    def render(self) -> np.ndarray | None:
        """``render_mode="rgb_array"``: the arm (true state) and its reference ghosted, as
        :mod:`hydroarm.studies.animate` draws them, an (H, W, 3) uint8 image (matplotlib Agg)."""
        if self.render_mode != "rgb_array":
            return None
        from hydroarm.studies.animate import _Scene, reach

        if self._scene is None:
            self._scene = _Scene(self.arm, None, reach(self.arm), (5.0, 4.4), self.arm.name)  # type: ignore[arg-type]
        q_r, _, _ = self.reference.sample(self.t)
        self._scene.update(self.t, self._x[: self.n], q_r)
        canvas = self._scene.fig.canvas
        canvas.draw()
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class ControllerPolicy:
    """Drive the environment with a built-in controller (SMC, MPC, GP-MPC).

    ``policy = ControllerPolicy.from_name("gp-mpc", env)`` (any spelling of the registry's
    names; ``env`` may be wrapped, e.g. by ``gymnasium.make``); at each step
    ``action = policy(obs)``; after ``env.step`` call ``policy.observe(obs_next)`` so a
    learning controller sees the transition. Call ``policy.reset()`` with each new episode
    after the first (the constructor resets the controller).
    """

    def __init__(self, controller: Controller, env: gymnasium.Env):
        self.controller = controller
        self.env: UnderwaterArmEnv = env.unwrapped  # type: ignore[assignment]
        self._last: tuple[np.ndarray, np.ndarray, float] | None = None
        controller.reset()

    @classmethod
    def from_name(cls, name: str, env: gymnasium.Env) -> ControllerPolicy:
        """The registry's controller ``name`` on the env's arm, with the env's settings
        (:func:`~hydroarm.sim.experiment.build_controller`)."""
        inner: UnderwaterArmEnv = env.unwrapped  # type: ignore[assignment]
        return cls(build_controller(name, inner.arm, inner.config), env)

    def reset(self) -> None:
        """Forget the episode (the controller's state and the last step)."""
        self.controller.reset()
        self._last = None

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        n = self.env.n
        y = np.asarray(observation[: 2 * n], dtype=float)
        t = self.env.t
        tau = np.asarray(self.controller.compute(t, y, self.env.reference).tau, dtype=float)
        self._last = (y, tau, t)
        return tau

    def observe(self, observation: np.ndarray) -> None:
        """Pass the last transition (y_k, u_k, y_{k+1}) to the controller."""
        if self._last is None:
            return
        y, tau, t = self._last
        self.controller.observe(t, y, tau, np.asarray(observation[: 2 * self.env.n], dtype=float))
