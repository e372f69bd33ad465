"""N copies of the arm env stepped in one compiled call: :class:`BatchedArmVectorEnv`.

``gymnasium.make_vec("hydroarm/UnderwaterArmBatched-v0", num_envs=64,
vectorization_mode="vector_entry_point")`` gives it (``gymnasium.make`` of that id gives one copy,
:func:`make_compiled_arm_env`, the same numbers bit for bit). Every copy is an
:class:`~hydroarm.envs.underwater_arm.UnderwaterArmEnv` on the compiled plant
(``plant.compiled = true``, :mod:`hydroarm.model.arm.fast`): the copies' control periods are one
:class:`~hydroarm.model.arm.fast.BatchedArm` call (``numba.prange`` across the cores), the rest
(torques, rewards, measurements, the reference, autoreset) array operations over the copies. The
keyword arguments are the env's (``arm``, ``config``, ``settings``, ``noise_variance``,
``duration``, ``action_mode``, ``action_scale``, ``start_spread``).

* **Same numbers as the single env**: copy i reset with seed s and stepped with row i of the
  actions gives the observations, states, termination and truncation of one
  :func:`make_compiled_arm_env` env reset with s and stepped with those actions, bit for bit; the
  rewards to round-off (a row sum instead of a dot product; tests/test_batched_env.py).
* **The loop's settings**: the measurement noise (``plant.noise_variance``, each copy's own seeded
  stream, drawn as the single env draws it), the joint friction and the water are honoured; a
  real sensor or drive model (``sensor.*``, ``actuator.*`` away from their defaults: delays,
  dropout, quantisation, drive lag) is refused with a ``ValueError`` naming the field (step those
  with :class:`~hydroarm.envs.vector.WorkerVectorEnv`, the id ``hydroarm/UnderwaterArm-v0``).
* **Autoreset**: ``AutoresetMode.NEXT_STEP`` (Gymnasium's default): the step after a copy's
  episode ended returns that copy's first observation of the next episode (reward 0, not
  terminated nor truncated) and ignores its action. ``DISABLED``: ``reset(options={"reset_mask":
  mask})`` resets the copies of a boolean mask (num_envs,).
* **Seeds**: ``reset(seed=s)`` seeds copy i with ``s + i``; ``reset(seed=[s_0, ...])`` each copy
  its own; an unseeded copy draws its seed from the OS once, as a single env does.
* **info**: per step ``t`` (N,), ``x`` (N, 2n) (the true state at the start of the step),
  ``disturbance`` (N, n), ``error`` (N, n), ``torque`` (N, n), each with its ``_name`` mask (the
  copies that stepped, not reset), as Gymnasium's vector envs give info.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from hydroarm.envs.underwater_arm import POSITION_BOUND, VELOCITY_WEIGHT, UnderwaterArmEnv
from hydroarm.envs.vector import _autoreset_mode
from hydroarm.model.arm.fast import BatchedArm
from hydroarm.sim.runner import DIVERGENCE_SPEED

__all__ = ["BatchedArmVectorEnv", "make_batched_arm_vector_env", "make_compiled_arm_env"]

LOOP_SECTIONS = ("sensor", "actuator")
"""The real loop's sections the batched env refuses away from their defaults (their blocks keep
per-copy state in Python: step them with the worker vector env)."""


def make_compiled_arm_env(settings: dict[str, Any] | None = None, **kwargs: Any) -> UnderwaterArmEnv:
    """One :class:`UnderwaterArmEnv` on the compiled plant (``plant.compiled = true`` added to
    ``settings``): the single env whose numbers each copy of :class:`BatchedArmVectorEnv` gives."""
    return UnderwaterArmEnv(settings={**(settings or {}), "plant.compiled": True}, **kwargs)


def _check_loop(env: UnderwaterArmEnv) -> None:
    """ValueError naming the first real-loop setting the batched env cannot step."""
    for section in LOOP_SECTIONS:
        value = getattr(env.config, section)
        default = type(value)()
        for key in type(value).model_fields:
            if getattr(value, key) != getattr(default, key):
                raise ValueError(
                    f"{section}.{key} = {getattr(value, key)!r}: the batched vector env steps the ideal sensor and "
                    f"drives only; leave {section}.{key} at its default ({getattr(default, key)!r}) or use "
                    "gymnasium.make_vec('hydroarm/UnderwaterArm-v0', ...) (worker processes, every loop setting)"
                )


class BatchedArmVectorEnv(VectorEnv):
    """``num_envs`` copies of the arm env in one compiled call per step (see the module docstring).

    Attributes: ``env`` (the template :class:`UnderwaterArmEnv`: its settings, arm, plant, spaces
    and action scale), ``states`` (N, 2n) the true states, ``steps_taken`` (N,) each copy's
    control steps in its episode."""

    def __init__(self, num_envs: int = 1, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs):
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1; got {num_envs!r}")
        if kwargs.get("render_mode") is not None:
            raise ValueError("render_mode: the batched vector env does not render; leave it None")
        mode = _autoreset_mode(autoreset_mode)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED):
            raise ValueError(f"autoreset_mode must be 'NextStep' or 'Disabled' for the batched env; got {mode.value!r}")
        self.env = make_compiled_arm_env(**kwargs)
        _check_loop(self.env)
        env = self.env
        self.num_envs, self.n = int(num_envs), env.n
        self.metadata = {"autoreset_mode": mode, "render_modes": []}
        self.render_mode = None
        self.single_observation_space, self.single_action_space = env.observation_space, env.action_space
        self.observation_space = batch_space(env.observation_space, self.num_envs)
        self.action_space = batch_space(env.action_space, self.num_envs)
        self.batch = BatchedArm(env.plant.fast)
        self.period, self.inner_step = env.period, env.plant.inner_step
        self.variance = float(env.plant.config.noise_variance)
        table = [env.reference.sample(k * env.period) for k in range(env.steps + 1)]
        self._q_r = np.array([row[0] for row in table], dtype=float)
        self._v_r = np.array([row[1] for row in table], dtype=float)
        shape = (self.num_envs, 2 * self.n)
        self.states, self._y = np.zeros(shape), np.zeros(shape)
        self.steps_taken = np.zeros(self.num_envs, dtype=np.int64)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._low, self._high = env.action_space.low, env.action_space.high

    def _observations(self) -> np.ndarray:
        k = self.steps_taken
        obs = np.concatenate([self._y, self._q_r[k], self._v_r[k]], axis=1)
        return np.clip(obs, -self.env._high, self.env._high)

    def _measure(self, x: np.ndarray, c: int) -> np.ndarray:
        """Copy c's measurement of x (2n,): the plant's sensor (:meth:`UnderwaterPlant.measure`)."""
        return self.env.plant.measure(x, self._rngs[c])

    def _reset_copy(self, c: int, seed: int | None, options: dict | None) -> None:
        """Copy c's reset, as :meth:`UnderwaterArmEnv.reset` does it."""
        if seed is not None or self._rngs[c] is None:
            self._rngs[c], _ = seeding.np_random(seed)
        rng, env = self._rngs[c], self.env
        x0 = None if options is None else options.get("x0")
        if x0 is None:
            x = env.x0.copy()
            dq, dv = env.start_spread
            if dq > 0.0 or dv > 0.0:
                x += np.concatenate([rng.uniform(-dq, dq, self.n), rng.uniform(-dv, dv, self.n)])
        else:
            x = np.asarray(x0, dtype=float)
            if x.shape != (2 * self.n,) or not np.all(np.isfinite(x)):
                raise ValueError(f"options['x0'] must be {2 * self.n} finite numbers [q, v]; got {x0!r}")
        self.states[c] = x
        self.steps_taken[c] = 0
        self._y[c] = self._measure(x, c)
        self._autoreset[c] = False

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        """Reset the copies (all, or those of ``options["reset_mask"]``): ``(observations (N, 4n), info)``."""
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + c for c in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or {self.num_envs} seeds; got {len(seeds)}")
        mask = np.ones(self.num_envs, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"options['reset_mask'] must be {self.num_envs} booleans; got shape {mask.shape}")
        for c in np.flatnonzero(mask):
            self._reset_copy(int(c), seeds[c], options)
        info = {"x": self.states.copy(), "_x": mask.copy(), "t": np.zeros(self.num_envs), "_t": mask.copy()}
        return self._observations(), info

    def _torques(self, actions) -> np.ndarray:
        actions = np.asarray(actions, dtype=float)
        if actions.shape != (self.num_envs, self.n) or not np.all(np.isfinite(actions)):
            raise ValueError(f"actions must be ({self.num_envs}, {self.n}) finite numbers; got shape {actions.shape}")
        actions = np.clip(actions, self._low, self._high)
        return actions * self.env.action_scale if self.env.action_mode == "normalised" else actions

    def step(self, actions):
        """One control step of every copy: ``(observations, rewards, terminated, truncated, info)``."""
        tau = self._torques(actions)
        n, count = self.n, self.num_envs
        stepping = ~self._autoreset
        rows = np.flatnonzero(stepping)
        k = self.steps_taken[rows]
        x = self.states[rows]
        t = k * self.period
        error = self._q_r[k] - x[:, :n]
        rewards = np.zeros(count)
        speed_error = self._v_r[k] - x[:, n:]
        rewards[rows] = -(np.sum(error * error, axis=1) + VELOCITY_WEIGHT * np.sum(speed_error**2, axis=1))
        x_next, disturbance, _ = self.batch.step(t, x, tau[rows], self.period, self.inner_step)
        with np.errstate(invalid="ignore"):
            diverged = (
                ~np.all(np.isfinite(x_next), axis=1)
                | (np.max(np.abs(x_next[:, n:]), axis=1) > DIVERGENCE_SPEED)
                | (np.max(np.abs(x_next[:, :n]), axis=1) > POSITION_BOUND)
            )
        self.steps_taken[rows] += 1
        terminated, truncated = np.zeros(count, dtype=bool), np.zeros(count, dtype=bool)
        terminated[rows] = diverged
        moving = rows[~diverged]
        self.states[moving] = x_next[~diverged]
        if self.variance == 0.0:
            self._y[moving] = x_next[~diverged]
        else:
            for c in moving:
                self._y[c] = self._measure(self.states[c], int(c))
        truncated[moving] = self.steps_taken[moving] >= self.env.steps
        info = self._step_info(rows, stepping, t, x, disturbance, error, tau[rows])
        for c in np.flatnonzero(self._autoreset):
            self._reset_copy(int(c), None, None)
        if self.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP:
            self._autoreset = terminated | truncated
        return self._observations(), rewards, terminated, truncated, info

    def _step_info(self, rows, stepping, t, x, disturbance, error, tau) -> dict[str, np.ndarray]:
        """The step's info arrays (num_envs, ...) and their masks: the copies in ``rows`` stepped."""
        count, n = self.num_envs, self.n
        info: dict[str, np.ndarray] = {}
        for name, values, width in (("t", t, None), ("x", x, 2 * n), ("disturbance", disturbance, n),
                                    ("error", error, n), ("torque", tau, n)):  # fmt: skip
            full = np.zeros(count if width is None else (count, width))
            full[rows] = values
            info[name], info[f"_{name}"] = full, stepping.copy()
        return info


def make_batched_arm_vector_env(num_envs: int = 1, **kwargs: Any) -> BatchedArmVectorEnv:
    """The ``vector_entry_point`` of ``hydroarm/UnderwaterArmBatched-v0`` (``gymnasium.make_vec``)."""
    kwargs.pop("max_episode_steps", None)  # gymnasium.make_vec passes the spec's (none is registered)
    return BatchedArmVectorEnv(num_envs=num_envs, **kwargs)
