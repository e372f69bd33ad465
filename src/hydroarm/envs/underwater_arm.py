"""A Gymnasium environment: an underwater arm tracking its task.

``UnderwaterArmEnv`` is the closed loop of :func:`hydroarm.sim.runner.run_closed_loop`
with the controller taken out: the agent gives the joint torques. Everything else comes
from the one experiment builder, :func:`hydroarm.sim.experiment.build_experiment`
(with no controller): the true plant (:class:`~hydroarm.model.arm.plant.UnderwaterPlant`,
with the water, current and measurement noise of the settings), the arm's own task
(:func:`~hydroarm.model.task.references.task_for_arm`: the paper's sinusoids, scaled into the joint
ranges of arms with limits) and the start state (the task's, moved by the settings'
``initial_state``: :func:`~hydroarm.sim.experiment.start_for_arm`).

``arm``: a built-in arm (``"paper"``, ``"ur5"``, ``"alpha5"``), a DH arm file or a URDF
(``.urdf`` with its ``<stem>.hydro.toml`` beside it, or the ``.hydro.toml`` itself);
default: the settings' ``arm`` (``"paper"``). ``config``: an
:class:`~hydroarm.sim.experiment.ExperimentConfig` (default: the paper reading's settings with
:data:`ENV_DEFAULT_SETTINGS`: the energy-consistent added mass, ``water.added_mass_model =
"kirchhoff"``, since the paper's Morison added mass feeds energy into rotating links and random
torques then spin a light wrist to divergence; ``settings={"water.added_mass_model": "morison"}``
gives the paper's water; a ``config`` given is used as it is);
``settings``: dotted overrides of it, as ``hydroarm run --set`` takes them (``{"water.added_mass":
False}``: every water, plant, current and task setting is reachable so); ``noise_variance`` and
``duration`` override ``plant.noise_variance`` and ``duration`` (after ``settings``).
With n the arm's joint count:

* observation (4n,), float64: the measured joint state [q, v] (2n, rad and rad/s, with
  the plant's seeded noise: what a controller sees), then the reference [q_r, v_r] (2n)
  at the current time;
* observation bounds: finite, ``|q| <= POSITION_BOUND`` rad and ``|v| <= DIVERGENCE_SPEED``
  rad/s for the measured state and the reference (the measurement is clipped into them; a true
  state outside them ends the episode, ``terminated``);
* action (n,), ``action_mode="normalised"`` (default): numbers in [-1, 1], joint i's torque
  ``action_i * action_scale_i`` (N m); ``action_scale`` defaults to :data:`ACTION_MARGIN` times
  the largest torque joint i needs along the task (the dry inverse dynamics of the reference
  minus the water's torques on it, sampled at :data:`TASK_SAMPLES` instants), capped at the
  torque limit, so that a policy can track the task and a random one does not spin a light
  wrist to divergence. ``action_mode="torque"``: raw torques (N m) in
  ``Box(-limit, limit)``. Actions outside the box are clipped, non-finite ones or a wrong shape
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
* the start: the task's start, or, with ``start_spread = (dq, dv)`` (rad, rad/s), a uniform
  draw within ``+-dq`` and ``+-dv`` around it from the env's seeded ``np_random`` at every
  ``reset``; ``reset(options={"x0": x0})`` starts at ``x0`` (2n,) instead;
* the plant's compiled step is compiled (or loaded from numba's cache) when the env is made,
  not at the first ``step``.

Vector envs: ``gymnasium.make_vec("hydroarm.envs:hydroarm/UnderwaterArm-v0", num_envs=8)`` gives
:class:`~hydroarm.envs.vector.WorkerVectorEnv` (the id's ``vector_entry_point``): the copies in
blocks on one worker process per core, through shared memory. Its autoreset mode
(``metadata["autoreset_mode"]``) is ``AutoresetMode.NEXT_STEP`` by default: the step after an
episode ended returns the first observation of the next one (its reward 0, not terminated) and
ignores that step's action. ``vectorization_mode="async"`` / ``"sync"`` give Gymnasium's (one
process per copy / all in this process), with the same autoreset mode.

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

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from hydroarm.control.interface import Controller
from hydroarm.sim.experiment import ExperimentConfig, build_controller, build_experiment, with_overrides
from hydroarm.sim.loop import Loop
from hydroarm.sim.runner import DIVERGENCE_SPEED

__all__ = [
    "ACTION_MARGIN",
    "ENV_DEFAULT_SETTINGS",
    "POSITION_BOUND",
    "VELOCITY_WEIGHT",
    "ControllerPolicy",
    "UnderwaterArmEnv",
    "task_torque",
]

VELOCITY_WEIGHT = 0.01
"""Weight of the velocity error in the reward (s^2)."""

POSITION_BOUND = 1e4
"""rad: the observation's bound on every joint position (and the reference's); a true position
beyond it ends the episode (a joint at the divergence speed for 10 s: no task comes near it)."""

ACTION_MARGIN = 2.0
"""The normalised action's full scale over the largest torque the task needs, per joint (-)."""

TASK_SAMPLES = 200
"""Instants of the task at which :func:`task_torque` samples the torque the task needs."""

ACTION_MODES = ("normalised", "torque")

ENV_DEFAULT_SETTINGS: dict[str, Any] = {"water.added_mass_model": "kirchhoff"}
"""What the env changes from the paper reading's settings when no ``config`` is given: the
energy-consistent added mass (docs/model.md). With the paper's Morison added mass, random torques
end 99 of 100 ten-second episodes early on the paper arm and 100 of 100 on the UR5
(docs/data/env_random_episodes.json): that model feeds energy into rotating links."""


def task_torque(experiment) -> np.ndarray:
    """The largest |torque| (n,) N m each joint needs to follow the experiment's task on its
    true plant: the dry inverse dynamics of the reference minus the water's torques (drag,
    added mass, buoyancy; the current left out) on it, at :data:`TASK_SAMPLES` instants over the
    episode (at least 1e-6 N m)."""
    from hydroarm.model.water.morison import hydrodynamic_torques

    config, arm = experiment.config, experiment.arm
    largest = np.zeros(arm.n_joints)
    for t in np.linspace(0.0, config.duration, TASK_SAMPLES):
        q, v, a = (np.asarray(x, dtype=float) for x in experiment.reference.sample(float(t)))
        water = hydrodynamic_torques(arm, config.water, q, v, a)
        tau = arm.inverse_dynamics(q, v, a) - water.drag - water.added_mass - water.buoyancy
        largest = np.maximum(largest, np.abs(tau))
    return np.maximum(largest, 1e-6)


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
        action_mode: str = "normalised",
        action_scale: np.ndarray | list[float] | None = None,
        start_spread: tuple[float, float] = (0.0, 0.0),
        settings: Mapping[str, Any] | None = None,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}; got {render_mode!r}")
        self.render_mode = render_mode
        self._scene = None
        overrides: dict[str, Any] = {}
        if config is None:
            config = ExperimentConfig()
            overrides.update(ENV_DEFAULT_SETTINGS)
        overrides.update(dict(settings) if settings is not None else {})
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
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}; got {action_mode!r}")
        self.action_mode = action_mode
        limit = np.asarray(self.arm.torque_limit, dtype=np.float64)
        if action_scale is None:
            scale = np.minimum(limit, ACTION_MARGIN * task_torque(self.experiment))
        else:
            scale = np.broadcast_to(np.asarray(action_scale, dtype=np.float64), (self.n,)).copy()
            if not np.all(np.isfinite(scale)) or np.any(scale <= 0) or np.any(scale > limit):
                raise ValueError(
                    f"action_scale must be {self.n} torques 0 < x <= the torque limit (N m); got {scale!r}"
                )
        self.action_scale = scale
        """N m per unit of a normalised action, per joint (``action_mode="normalised"``)."""
        if action_mode == "normalised":
            self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n,), dtype=np.float64)
        else:
            self.action_space = spaces.Box(-limit, limit, dtype=np.float64)
        spread = np.asarray(start_spread, dtype=float)
        if spread.shape != (2,) or not np.all(np.isfinite(spread)) or np.any(spread < 0):
            raise ValueError(f"start_spread must be (position rad, velocity rad/s) >= 0; got {start_spread!r}")
        self.start_spread = (float(spread[0]), float(spread[1]))
        high = np.concatenate([np.full(self.n, POSITION_BOUND), np.full(self.n, DIVERGENCE_SPEED)] * 2)
        self.observation_space = spaces.Box(-high, high, dtype=np.float64)
        self._high = high
        self.loop = Loop(self.plant, self.period)
        """The closed loop's plant, sensor and drives (:class:`~hydroarm.sim.loop.Loop`); the agent is
        the controller."""
        self._x = self.x0.copy()
        self._y = self.x0.copy()
        self._k = 0
        self._reference_step = -1
        self._reference_sample = (np.zeros(self.n), np.zeros(self.n))
        # the compiled step is compiled (or loaded from numba's cache) now, not at the first step
        self.plant.step(0.0, self.x0, np.zeros(self.n), self.period)

    def torque(self, action) -> np.ndarray:
        """The joint torques (n,) N m of ``action`` (in ``action_space``'s units), clipped to the box."""
        action = np.asarray(action, dtype=float)
        if action.shape != (self.n,) or not np.all(np.isfinite(action)):
            unit = "normalised actions in [-1, 1]" if self.action_mode == "normalised" else "finite joint torques (N m)"
            raise ValueError(f"action must be {self.n} finite numbers ({unit}); got {action!r}")
        action = np.clip(action, self.action_space.low, self.action_space.high)
        return action * self.action_scale if self.action_mode == "normalised" else action

    def action(self, torque) -> np.ndarray:
        """The action (in ``action_space``'s units) for joint torques ``torque`` (n,) N m, clipped."""
        torque = np.asarray(torque, dtype=float)
        action = torque / self.action_scale if self.action_mode == "normalised" else torque
        return np.clip(action, self.action_space.low, self.action_space.high)

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

    def _reference_now(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q_r, v_r)`` (n,) at the current step, read-only: sampled once a step (the
        observation after a step and the next step's reward see the same time, so the second
        reads the first's sample, the same numbers)."""
        if self._reference_step != self._k:
            q_r, v_r, _ = self.reference.sample(self.t)
            self._reference_sample = (q_r, v_r)
            self._reference_step = self._k
        return self._reference_sample

    def _observation(self) -> np.ndarray:
        q_r, v_r = self._reference_now()
        return np.clip(np.concatenate([self._y, q_r, v_r]), -self._high, self._high)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._k = 0
        x0 = None if options is None else options.get("x0")
        if x0 is None:
            self._x = self.x0.copy()
            dq, dv = self.start_spread
            if dq > 0.0 or dv > 0.0:
                n = self.n
                self._x += np.concatenate([self.np_random.uniform(-dq, dq, n), self.np_random.uniform(-dv, dv, n)])
        else:
            x0 = np.asarray(x0, dtype=float)
            if x0.shape != (2 * self.n,) or not np.all(np.isfinite(x0)):
                raise ValueError(f"options['x0'] must be {2 * self.n} finite numbers [q, v]; got {x0!r}")
            self._x = x0.copy()
        # the sensor's dropout stream: the episode's seed, as the runner's; drawn only for a real sensor
        # (the ideal sensor draws nothing beyond the noise, so its numbers stay the runner's)
        if seed is None and not self.plant.sensor.ideal:
            seed = int(self.np_random.integers(2**63))
        self._y = self.loop.reset(self._x, self.np_random, 0 if seed is None else seed)
        return self._observation(), {"x": self._x.copy(), "t": 0.0}

    def step(self, action):
        tau = self.torque(action)
        t = self.t
        q_r, v_r = self._reference_now()
        error = q_r - self._x[: self.n]
        reward = -float(error @ error + VELOCITY_WEIGHT * np.sum((v_r - self._x[self.n :]) ** 2))
        step = self.loop.step(t, tau)
        x_next, step_info = step.x_next, step.info
        diverged = (
            not np.all(np.isfinite(x_next))
            or np.max(np.abs(x_next[self.n :])) > DIVERGENCE_SPEED
            or np.max(np.abs(x_next[: self.n])) > POSITION_BOUND
        )
        info = {
            "x": self._x.copy(),
            "t": t,
            "disturbance": step_info.disturbance,
            "error": error,
            "torque": tau,
            "applied_torque": step.applied,
        }
        self._k += 1
        if diverged:
            return self._observation(), reward, True, False, info
        self._y, _ = self.loop.measure_next()
        self._x = self.loop.x
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
    ``action = policy(obs)`` (the controller's torque in the env's action units: divided by
    ``action_scale`` in the default normalised mode, so the torques agree with the runner's to
    rounding; with ``action_mode="torque"`` bit for bit); after ``env.step`` call ``policy.observe(obs_next)`` so a
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
        return self.env.action(tau)

    def observe(self, observation: np.ndarray) -> None:
        """Pass the last transition (y_k, u_k, y_{k+1}) to the controller."""
        if self._last is None:
            return
        y, tau, t = self._last
        self.controller.observe(t, y, tau, np.asarray(observation[: 2 * self.env.n], dtype=float))
