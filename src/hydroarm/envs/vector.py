"""A vector environment sized for few cores: the copies in blocks, one block per core.

Gymnasium's ``AsyncVectorEnv`` runs one process per copy and exchanges one pipe message per copy
and step: 8 copies on 2 cores are 8 processes competing for 2 cores, and the messages cost more
than they carry. :class:`WorkerVectorEnv` splits the ``num_envs`` copies into ``workers``
contiguous blocks (default: one per core this process may run on, at most ``num_envs``): the
calling process steps the first block itself, one worker process steps each other block, each
block's copies one after the other. The observations, actions, rewards and the termination and
truncation flags live in one shared-memory block that the calling process and the workers map;
a batch step is one short message to each worker and one reply from each (carrying its copies'
``info`` dicts), the calling process stepping its own copies meanwhile. ``workers=1`` steps
every copy in the calling process (no worker process, the same code).

``gymnasium.make_vec("hydroarm/UnderwaterArm-v0", num_envs=8)`` gives it (the ids register it as
their ``vector_entry_point``, which ``make_vec`` uses when no ``vectorization_mode`` is given;
``"vector_entry_point"`` names it; ``"sync"`` and ``"async"`` still give Gymnasium's): the
keyword arguments are the environment's, plus ``workers``, ``autoreset_mode`` and ``context``
(the multiprocessing start method; default the platform's).

* **Autoreset**: ``metadata["autoreset_mode"]``, Gymnasium's :class:`~gymnasium.vector.AutoresetMode`;
  ``NEXT_STEP`` by default (the step after a copy's episode ended resets it: that step returns
  the first observation of the next episode, reward 0, not terminated nor truncated, the reset's
  ``info``, and ignores that copy's action); ``SAME_STEP`` (the ending step resets at once and
  returns the new first observation, the last one in ``info["final_obs"]`` and the last ``info``
  in ``info["final_info"]``) and ``DISABLED`` (``reset(options={"reset_mask": mask})`` resets the
  copies of a boolean mask (num_envs,)) too: the same semantics as Gymnasium's vector envs.
* **Seeds**: ``reset(seed=s)`` seeds copy i with ``s + i``, ``reset(seed=[s_0, ...])`` each copy
  with its own; copy i then gives the numbers of a single environment reset with that seed and
  stepped with row i of the actions, bit for bit (the copies are independent environments).
* **Errors**: actions of the wrong shape or not finite raise ``ValueError`` in the calling
  process, before any copy steps. An exception in a copy (here or in a worker) closes the vector env
  (every worker stopped) and is raised once in the calling process, its type and message kept,
  with a note naming the copy and the worker's traceback as its cause; a worker that dies
  (killed, crashed) raises ``RuntimeError`` naming it, and closes the rest.
* **Ctrl-C**: the workers ignore SIGINT (a terminal's Ctrl-C reaches the whole process group);
  the calling process gets the ``KeyboardInterrupt``, and if it arrives during a vector env call
  (checking the arguments, the copies stepping, their replies copied) the workers are stopped
  and the env closed before it propagates: no worker is left behind. If
  the calling process dies, its workers see their pipe close and exit.
* The copies are made, and their compiled code compiled or loaded from numba's cache, in the
  calling process and the workers while :class:`WorkerVectorEnv` is constructed: a first
  ``step`` costs what every other does.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection, wait
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.error import ClosedEnvironmentError
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from hydroarm.envs.vector_lanes import Block, RemoteTraceback, layout_of, pack_infos, serve, unstack_info, views_of

__all__ = ["WorkerVectorEnv", "default_workers", "make_arm_vector_env", "make_uvms_vector_env"]

_JOIN_TIMEOUT = 5.0
"""s: how long :meth:`WorkerVectorEnv.close` waits for a worker to exit before terminating it."""


def default_workers() -> int:
    """The number of cores this process may run on (its CPU affinity; ``os.cpu_count()`` where
    the platform has no affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - platform without sched_getaffinity
        return max(1, os.cpu_count() or 1)


def _autoreset_mode(value: AutoresetMode | str) -> AutoresetMode:
    try:
        return value if isinstance(value, AutoresetMode) else AutoresetMode(value)
    except ValueError:
        allowed = ", ".join(repr(mode.value) for mode in AutoresetMode)
        raise ValueError(f"autoreset_mode must be an AutoresetMode or one of {allowed}; got {value!r}") from None


def _closing_on_interrupt(method: Callable) -> Callable:
    """A public vector env call that, interrupted anywhere (Ctrl-C while it checks its arguments,
    waits for the workers or copies their replies), stops the workers and closes the env before
    the ``KeyboardInterrupt`` propagates."""

    @functools.wraps(method)
    def call(self: WorkerVectorEnv, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(self, *args, **kwargs)
        except KeyboardInterrupt:
            if not self.closed:
                self._shutdown(force=True)
            raise

    return call


class WorkerVectorEnv(VectorEnv):
    """``num_envs`` copies of the environment ``env_fn()`` makes, in ``workers`` lanes (see the
    module docstring): lane 0 is this process, lanes 1 .. workers - 1 are worker processes.
    ``env_fn``: a callable making one copy (picklable unless ``context`` is ``"fork"``);
    ``workers``: default :func:`default_workers`, at most ``num_envs`` (1: every copy in this
    process); ``autoreset_mode``: :class:`~gymnasium.vector.AutoresetMode` or its value;
    ``context``: the multiprocessing start method (None: the platform's default).

    Attributes beyond :class:`~gymnasium.vector.VectorEnv`'s: ``workers`` (lanes, this process
    included), ``blocks`` (each lane's ``(first copy, copies)``).
    """

    def __init__(
        self,
        env_fn: Callable[[], gymnasium.Env],
        num_envs: int,
        workers: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        context: str | None = None,
    ):
        self.closed = True  # until the lanes run
        self._memory: SharedMemory | None = None
        self._arrays: dict[str, np.ndarray] = {}
        self._pipes: list[Connection] = []  # lane w's at w - 1
        self._processes: list[multiprocessing.process.BaseProcess] = []
        self._go: list[Any] = []  # lane w's semaphore at w - 1: released once a command is in its pipe
        self._local: Block | None = None
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1; got {num_envs!r}")
        if workers is None:
            workers = min(default_workers(), int(num_envs))
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or not 1 <= workers <= num_envs:
            raise ValueError(f"workers must be an integer in [1, num_envs = {num_envs}]; got {workers!r}")
        self.num_envs = int(num_envs)
        self.workers = int(workers)
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.closed = False
        per, extra = divmod(self.num_envs, self.workers)
        counts = [per + (1 if w < extra else 0) for w in range(self.workers)]
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
        self.blocks = list(zip(starts, counts, strict=True))
        try:
            self._start(env_fn, context)  # the workers make their copies while this process makes its own
            self._local = Block(env_fn, 0, counts[0], self.autoreset_mode)
            self._set_spaces([self._local.describe(), *self._gather("make")])
            self._allocate()
        except BaseException:
            self._shutdown(force=True)
            raise

    @property
    def worker_pids(self) -> tuple[int, ...]:
        """The process ids of the worker processes (lanes 1 ..; empty with one lane or once closed)."""
        return tuple(process.pid for process in self._processes if process.pid is not None)

    # --- construction -----------------------------------------------------------------------
    def _start(self, env_fn: Callable[[], gymnasium.Env], context: str | None) -> None:
        if self.workers == 1:
            return
        ctx = multiprocessing.get_context(context)
        fork = ctx.get_start_method() == "fork"
        if fork and os.name == "posix":
            # the shared block is registered with the resource tracker once the workers run: start
            # the tracker now so that forked workers share it instead of each starting their own
            # (which would unlink the block when a worker exits)
            from multiprocessing import resource_tracker

            resource_tracker.ensure_running()
        for w, (start, count) in enumerate(self.blocks[1:], start=1):
            parent_end, child_end = ctx.Pipe()
            go = ctx.Semaphore(0)
            self._go.append(go)
            process = ctx.Process(
                target=serve,
                name=f"hydroarm-vector-env-worker-{w}",
                args=(w, env_fn, start, count, self.autoreset_mode, child_end, go, parent_end if fork else None),
                daemon=True,
            )
            self._pipes.append(parent_end)
            self._processes.append(process)
            process.start()
            child_end.close()

    def _set_spaces(self, described: list[tuple]) -> None:
        observation_space, action_space, metadata, render_mode = described[0]
        for w, (obs, action, _, _) in enumerate(described[1:], start=1):
            if obs != observation_space or action != action_space:
                raise ValueError(f"lane {w}'s copies have other spaces than lane 0's: a vector env needs equal ones")
        for name, space in (("observation", observation_space), ("action", action_space)):
            if not isinstance(space, spaces.Box):
                raise TypeError(f"WorkerVectorEnv needs Box {name} spaces; the environment's is {space!r}")
        self.single_observation_space = observation_space
        self.single_action_space = action_space
        self.observation_space = batch_space(observation_space, self.num_envs)
        self.action_space = batch_space(action_space, self.num_envs)
        self.metadata = {**metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = render_mode

    def _allocate(self) -> None:
        n = self.num_envs
        fields = [
            ("observations", (n, *self.single_observation_space.shape), self.single_observation_space.dtype),
            ("actions", (n, *self.single_action_space.shape), self.single_action_space.dtype),
            ("rewards", (n,), np.float64),
            ("terminated", (n,), np.bool_),
            ("truncated", (n,), np.bool_),
        ]
        if not self._pipes:
            self._arrays = {name: np.zeros(shape, dtype=dtype) for name, shape, dtype in fields}
        else:
            layout, size = layout_of(fields)
            self._memory = SharedMemory(create=True, size=size)
            self._arrays = views_of(self._memory.buf, layout)
            for array in self._arrays.values():
                array[...] = 0
            self._send_all("attach", (self._memory.name, layout))
            self._gather("attach")
        assert self._local is not None
        self._local.attach(self._arrays)

    # --- the pipes ----------------------------------------------------------------------------
    def _send_all(self, command: str, data: Any = None, per_lane: Sequence[Any] | None = None) -> None:
        for w, (pipe, go) in enumerate(zip(self._pipes, self._go, strict=True), start=1):
            pipe.send((command, per_lane[w] if per_lane is not None else data))
            # the worker waits on the semaphore, not on the pipe: a pipe write wakes its reader as a
            # "synchronous" wake-up, which Linux may serve on the writer's core, preempting this
            # process while it steps its own copies (measured: the lanes then take turns on one core)
            go.release()

    def _gather(self, what: str) -> list[Any]:
        """Every worker's reply to the last command, in lane order (lanes 1 ..). An error reply (or
        a worker that died) closes the vector env and raises, once every worker has been heard from."""
        replies: list[Any] = [None] * len(self._pipes)
        failures: list[tuple[int, BaseException, str | None]] = []  # (copy or -1, exception, worker traceback)
        pending = {pipe: i for i, pipe in enumerate(self._pipes)}
        sentinels = {process.sentinel: i for i, process in enumerate(self._processes)}
        while pending:
            waiting = list(pending) + [s for s, i in sentinels.items() if self._pipes[i] in pending]
            for ready in wait(waiting):
                if isinstance(ready, int):  # a worker exited: its reply may still be in the pipe
                    i = sentinels[ready]
                    pipe = self._pipes[i]
                    if pipe not in pending or pipe.poll():
                        continue
                    pending.pop(pipe)
                    failures.append((-1, self._died(i + 1, what), None))
                    continue
                i = pending.pop(ready)
                try:
                    status, payload = ready.recv()
                except (EOFError, OSError):
                    failures.append((-1, self._died(i + 1, what), None))
                    continue
                if status == "ok":
                    replies[i] = payload
                else:
                    failures.append(payload)
        if failures:
            self._shutdown(force=False)
            self._raise(failures, what)
        return replies

    def _raise(self, failures: list[tuple[int, BaseException, str | None]], what: str) -> None:
        copy, error, text = failures[0]
        if copy >= 0:
            error.add_note(
                f"raised in copy {copy} of the {self.num_envs}-copy vector env, during {what}; the vector env is closed"
            )
        if len(failures) > 1:
            error.add_note(f"{len(failures) - 1} other lane(s) failed too")
        if text is not None:
            raise error from RemoteTraceback(text)
        raise error

    def _died(self, w: int, what: str) -> RuntimeError:
        process = self._processes[w - 1]
        process.join(_JOIN_TIMEOUT)
        start, count = self.blocks[w]
        return RuntimeError(
            f"worker {w} of the vector env (copies {start}-{start + count - 1}) exited with code "
            f"{process.exitcode} during {what}; the vector env is closed"
        )

    def _run(self, command: str, what: str, data: Any = None, per_lane: Sequence[Any] | None = None) -> list:
        """Run a block command on every lane: the workers' in parallel with this process's. The
        replies per lane. An exception in a copy closes the env and is raised (the first copy's);
        an interrupt (Ctrl-C) or any other exception here stops the workers at once and closes
        the env before it propagates."""
        if self.closed:
            raise ClosedEnvironmentError(f"Trying to call {what} on WorkerVectorEnv after close()")
        local = self._local
        assert local is not None
        argument = per_lane[0] if per_lane is not None else data
        try:
            self._send_all(command, data, per_lane)
            try:
                if command == "step":
                    mine = pack_infos(local.step())
                elif command == "reset":
                    mine = pack_infos(local.reset(argument))
                elif command == "call":
                    mine = local.call(*argument)
                else:
                    mine = local.set_attr(*argument)
            except Exception as error:  # a copy of this process failed: hear the workers out, then close
                failure = (local.current, error, None)
                try:
                    self._gather(what)
                except Exception:  # noqa: BLE001 - the lower copy's error is the one to report
                    pass
                self._shutdown(force=False)
                self._raise([failure], what)
            return [mine, *self._gather(what)]
        except BaseException:
            self._shutdown(force=True)
            raise

    def _infos(self, replies: list[list[dict] | dict[str, np.ndarray]]) -> dict[str, Any]:
        """The lanes' ``info`` replies (each :func:`pack_infos`'s) as Gymnasium's vector ``info``: every
        key an array over the copies with its ``_key`` mask (``VectorEnv._add_info``)."""
        if all(isinstance(reply, dict) for reply in replies):  # every lane stacked
            first = replies[0]
            keys = first.keys()
            same = all(
                reply.keys() == keys
                and all(reply[k].dtype == first[k].dtype and reply[k].shape[1:] == first[k].shape[1:] for k in keys)
                for reply in replies[1:]
            )
            if same:
                infos: dict[str, Any] = {}
                mask = np.ones(self.num_envs, dtype=np.bool_)
                for key in keys:
                    infos[key] = np.concatenate([reply[key] for reply in replies])
                    infos[f"_{key}"] = mask.copy()
                return infos
        infos = {}
        for (start, count), reply in zip(self.blocks, replies, strict=True):
            if isinstance(reply, dict):  # stacked: back to one dict per copy
                reply = [{key: unstack_info(values, i) for key, values in reply.items()} for i in range(count)]
            for i, info in enumerate(reply):
                if info:
                    infos = self._add_info(infos, info, start + i)
        return infos

    # --- the VectorEnv API --------------------------------------------------------------------
    @_closing_on_interrupt
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        """Reset the copies: ``seed`` an int (copy i gets ``seed + i``), a list (one per copy) or
        None; ``options`` passed to every copy, but ``options["reset_mask"]`` (a bool array
        (num_envs,)) resets only the copies it marks (the others keep their observation)."""
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(
                    f"seed must be an int, None or a list of num_envs = {self.num_envs} seeds; got {seed!r}"
                )
        mask = np.ones(self.num_envs, dtype=bool)
        if options is not None and "reset_mask" in options:
            options = dict(options)
            mask = options.pop("reset_mask")
            if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},); got {mask!r}"
                )
            if not mask.any():
                raise ValueError("options['reset_mask'] must mark at least one copy")
        requests = [(s, options) if m else None for s, m in zip(seeds, mask, strict=True)]
        per_lane = [requests[start : start + count] for start, count in self.blocks]
        replies = self._run("reset", "reset", per_lane=per_lane)
        return self._arrays["observations"].copy(), self._infos(replies)

    @_closing_on_interrupt
    def step(self, actions):
        """Step every copy with its row of ``actions`` ((num_envs, *action shape), finite)."""
        if self.closed:
            raise ClosedEnvironmentError("Trying to call step on WorkerVectorEnv after close()")
        actions = np.asarray(actions)
        shape = self.action_space.shape
        if actions.shape != shape:
            raise ValueError(f"actions must have the shape {shape} (num_envs, action); got {actions.shape}")
        if not np.all(np.isfinite(actions)):
            copies = np.flatnonzero(~np.all(np.isfinite(actions.reshape(self.num_envs, -1)), axis=1))
            raise ValueError(f"actions must be finite; copies {copies.tolist()} have non-finite entries")
        a = self._arrays
        a["actions"][...] = actions
        replies = self._run("step", "step")
        return (
            a["observations"].copy(),
            a["rewards"].copy(),
            a["terminated"].copy(),
            a["truncated"].copy(),
            self._infos(replies),
        )

    @_closing_on_interrupt
    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Each copy's attribute ``name``, or its method ``name`` called with the arguments, as a tuple."""
        replies = self._run("call", f"call({name!r})", data=(name, args, kwargs))
        return tuple(value for block in replies for value in block)

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """Each copy's attribute ``name`` (a method is called without arguments)."""
        return self.call(name)

    @_closing_on_interrupt
    def set_attr(self, name: str, values: Any) -> None:
        """Set attribute ``name`` of each copy: ``values`` a list or tuple (one per copy) or one value for all."""
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ValueError(f"values must be one value or num_envs = {self.num_envs} values; got {len(values)}")
        per_lane = [(name, list(values[start : start + count])) for start, count in self.blocks]
        self._run("set_attr", f"set_attr({name!r})", per_lane=per_lane)

    def render(self) -> tuple[Any, ...] | None:
        """Each copy's ``render()``."""
        return self.call("render")

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the workers (each closes its copies), close this process's copies and free the
        shared memory (``terminate=True``: terminate the workers at once)."""
        self._shutdown(force=bool(kwargs.get("terminate", False)))

    def _shutdown(self, force: bool) -> None:
        """Stop every worker (``close``, then terminate what has not exited after
        :data:`_JOIN_TIMEOUT` s; ``force``: terminate at once), close this process's copies and
        free the shared memory. Idempotent; leaves the env closed."""
        self.closed = True
        if not force:
            for pipe, process, go in zip(self._pipes, self._processes, self._go, strict=True):
                if process.is_alive() and not pipe.closed:
                    try:
                        pipe.send(("close", None))
                    except OSError:
                        pass
                    else:
                        go.release()
        for process in self._processes:
            if force and process.is_alive():
                process.terminate()
            process.join(_JOIN_TIMEOUT)
            if process.is_alive():
                process.terminate()
                process.join(_JOIN_TIMEOUT)
            if process.is_alive():  # pragma: no cover - a worker that ignores SIGTERM
                process.kill()
                process.join()
        for pipe in self._pipes:
            pipe.close()
        self._pipes, self._processes, self._go = [], [], []
        local, self._local = self._local, None
        if local is not None:
            local.arrays = {}
            try:
                local.close()
            except Exception:  # noqa: BLE001, S110 - closing after a failure: the first error is the one to report
                pass
        self._arrays = {}
        if self._memory is not None:
            memory, self._memory = self._memory, None
            memory.close()
            memory.unlink()

    def __del__(self) -> None:
        if not getattr(self, "closed", True) and hasattr(self, "_processes"):
            self._shutdown(force=True)

    def __repr__(self) -> str:
        return (
            f"WorkerVectorEnv(num_envs={self.num_envs}, workers={self.workers}, autoreset_mode={self.autoreset_mode})"
        )


def _vector_env(
    env_class: type[gymnasium.Env],
    num_envs: int = 1,
    workers: int | None = None,
    autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
    context: str | None = None,
    **env_kwargs: Any,
) -> WorkerVectorEnv:
    env_kwargs.pop("max_episode_steps", None)  # gymnasium.make_vec passes the spec's (none is registered)
    return WorkerVectorEnv(functools.partial(env_class, **env_kwargs), num_envs, workers, autoreset_mode, context)


def make_arm_vector_env(num_envs: int = 1, **kwargs: Any) -> WorkerVectorEnv:
    """``hydroarm/UnderwaterArm-v0``'s ``vector_entry_point``: a :class:`WorkerVectorEnv` of
    :class:`~hydroarm.envs.underwater_arm.UnderwaterArmEnv` copies. ``kwargs``: ``workers``,
    ``autoreset_mode``, ``context`` (the vector env's), the rest the environment's."""
    from hydroarm.envs.underwater_arm import UnderwaterArmEnv

    return _vector_env(UnderwaterArmEnv, num_envs, **kwargs)


def make_uvms_vector_env(num_envs: int = 1, **kwargs: Any) -> WorkerVectorEnv:
    """``hydroarm/UVMS-v0``'s ``vector_entry_point``: :func:`make_arm_vector_env` for
    :class:`~hydroarm.envs.vehicle.UVMSEnv`."""
    from hydroarm.envs.vehicle import UVMSEnv

    return _vector_env(UVMSEnv, num_envs, **kwargs)
