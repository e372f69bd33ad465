"""The lanes of :class:`~hydroarm.envs.vector.WorkerVectorEnv`: a block of copies stepped one
after the other (:class:`Block`), the worker process that serves one (:func:`serve`), and the
shared-memory layout and ``info`` packing they share with the vector env. Internal to
:mod:`hydroarm.envs.vector`, which documents the behaviour."""

from __future__ import annotations

import signal
import traceback
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

__all__ = ["Block", "RemoteTraceback", "layout_of", "pack_infos", "serve", "unstack_info", "views_of"]

ALIGN = 64
"""Bytes: the alignment of each array in the shared block."""

PARENT_CHECK = 1.0
"""s: how often an idle worker checks that the main process's end of its pipe is still open."""


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker (the cause of the re-raised exception)."""

    def __init__(self, text: str):
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return "\n" + self.text


SCALARS = (bool, int, float)


def pack_infos(infos: list[dict]) -> list[dict] | dict[str, np.ndarray]:
    """A block's ``info`` dicts as one dict of stacked arrays ``{key: (count, ...)}`` when every
    copy has the same keys and each key's values are arrays of one shape and dtype, or scalars of
    one type (what Gymnasium's ``VectorEnv._add_info`` would make of them, with fewer objects to
    pickle and merge); else the list as it is."""
    if not infos or not infos[0]:
        return infos
    keys = infos[0].keys()
    if any(info.keys() != keys for info in infos[1:]):
        return infos
    stacked: dict[str, np.ndarray] = {}
    for key in keys:
        values = [info[key] for info in infos]
        first = values[0]
        kind = type(first)
        if key == "final_obs" or any(type(value) is not kind for value in values):
            return infos
        if kind is np.ndarray:
            if any(value.shape != first.shape or value.dtype != first.dtype for value in values):
                return infos
            stacked[key] = np.array(values)  # (count, ...): the shapes and dtypes are equal
        elif kind in SCALARS or issubclass(kind, np.number):
            stacked[key] = np.array(values, dtype=kind)
        else:
            return infos
    return stacked


def unstack_info(values: np.ndarray, i: int) -> Any:
    """Copy i's value of a :func:`pack_infos` array, typed so that ``VectorEnv._add_info`` batches it as
    the original (a NumPy scalar for numbers, a Python bool for booleans)."""
    value = values[i]
    return value.item() if values.dtype == np.bool_ and values.ndim == 1 else value


class Block:
    """A worker's contiguous copies ``start .. start + count - 1``, stepped one after the other,
    reading their actions from and writing their results into the (shared) arrays it is given."""

    def __init__(self, env_fn: Callable[[], gymnasium.Env], start: int, count: int, autoreset_mode: AutoresetMode):
        self.start = start
        self.current = start  # the copy being run: an error names it
        self.envs: list[gymnasium.Env] = []
        for i in range(count):
            self.current = start + i
            self.envs.append(env_fn())
        self.autoreset_mode = autoreset_mode
        self.autoreset = np.zeros(count, dtype=bool)
        self.arrays: dict[str, np.ndarray] = {}

    def describe(self) -> tuple[spaces.Space, spaces.Space, dict[str, Any], str | None]:
        """The copies' (observation space, action space, metadata, render mode); all copies must agree."""
        first = self.envs[0]
        for i, env in enumerate(self.envs[1:], start=1):
            self.current = self.start + i
            if env.observation_space != first.observation_space or env.action_space != first.action_space:
                raise ValueError(
                    f"copy {self.start + i} has other spaces than copy {self.start}: a vector env needs equal ones"
                )
        return first.observation_space, first.action_space, dict(first.metadata), first.render_mode

    def attach(self, arrays: dict[str, np.ndarray]) -> None:
        """Use ``arrays`` (each of the whole vector env, (num_envs, ...)): this block's rows."""
        stop = self.start + len(self.envs)
        self.arrays = {name: array[self.start : stop] for name, array in arrays.items()}

    def reset(self, requests: Sequence[tuple[int | None, dict | None] | None]) -> list[dict]:
        """Reset each copy whose request ``(seed, options)`` is not None."""
        observations = self.arrays["observations"]
        infos: list[dict] = []
        for i, (env, request) in enumerate(zip(self.envs, requests, strict=True)):
            self.current = self.start + i
            if request is None:
                infos.append({})
                continue
            seed, options = request
            observation, info = env.reset(seed=seed, options=options)
            observations[i] = observation
            self.autoreset[i] = False
            infos.append(info)
        return infos

    def step(self) -> list[dict]:
        """Step every copy with its row of the actions (autoreset as the mode says)."""
        a = self.arrays
        observations, actions, rewards = a["observations"], a["actions"], a["rewards"]
        terminations, truncations = a["terminated"], a["truncated"]
        mode = self.autoreset_mode
        infos: list[dict] = []
        for i, env in enumerate(self.envs):
            self.current = self.start + i
            if mode == AutoresetMode.NEXT_STEP and self.autoreset[i]:
                observation, info = env.reset()
                reward, terminated, truncated = 0.0, False, False
            else:
                observation, reward, terminated, truncated, info = env.step(actions[i].copy())
                if mode == AutoresetMode.SAME_STEP and (terminated or truncated):
                    final_observation, final_info = observation, info
                    observation, reset_info = env.reset()
                    info = {"final_info": final_info, "final_obs": final_observation, **reset_info}
            if mode == AutoresetMode.NEXT_STEP:
                self.autoreset[i] = terminated or truncated
            observations[i] = observation
            rewards[i] = reward
            terminations[i] = terminated
            truncations[i] = truncated
            infos.append(info)
        return infos

    def call(self, name: str, args: tuple, kwargs: dict) -> list[Any]:
        """Each copy's ``name`` (an attribute, or a method called with ``args``, ``kwargs``)."""
        results = []
        for i, env in enumerate(self.envs):
            self.current = self.start + i
            value = env.get_wrapper_attr(name)
            results.append(value(*args, **kwargs) if callable(value) else value)
        return results

    def set_attr(self, name: str, values: Sequence[Any]) -> None:
        for i, (env, value) in enumerate(zip(self.envs, values, strict=True)):
            self.current = self.start + i
            env.set_wrapper_attr(name, value)

    def close(self) -> None:
        for env in self.envs:
            env.close()


def layout_of(fields: Sequence[tuple[str, tuple[int, ...], np.dtype]]) -> tuple[dict[str, tuple], int]:
    """Byte offsets of the arrays in one block (each aligned to :data:`ALIGN`), and its size."""
    layout, offset = {}, 0
    for name, shape, dtype in fields:
        layout[name] = (shape, np.dtype(dtype).str, offset)
        size = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        offset += -(-size // ALIGN) * ALIGN
    return layout, max(offset, ALIGN)


def views_of(buffer, layout: dict[str, tuple]) -> dict[str, np.ndarray]:
    return {
        name: np.ndarray(shape, dtype=np.dtype(dtype), buffer=buffer, offset=offset)
        for name, (shape, dtype, offset) in layout.items()
    }


def serve(
    index: int,
    env_fn: Callable[[], gymnasium.Env],
    start: int,
    count: int,
    autoreset_mode: AutoresetMode,
    pipe: Connection,
    go: Any,
    parent_end: Connection | None,
) -> None:  # pragma: no cover - runs in the worker processes (the tests drive it through them)
    """A worker process: make its block of copies, then serve commands until ``close`` or until
    the main process's end of the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle
    if parent_end is not None:
        parent_end.close()  # the main process's end: closed here so its death shows as EOF
    block: Block | None = None
    memory: SharedMemory | None = None
    current = start
    try:
        block = Block(env_fn, start, count, autoreset_mode)
        pipe.send(("ok", block.describe()))
        while True:
            while not go.acquire(timeout=PARENT_CHECK):  # the command is in the pipe when go is released
                if pipe.poll():  # the main process's end closed (EOF: recv raises) or a command came
                    break
            command, data = pipe.recv()
            current = block.current = start
            if command == "step":
                pipe.send(("ok", pack_infos(block.step())))
            elif command == "reset":
                pipe.send(("ok", pack_infos(block.reset(data))))
            elif command == "call":
                pipe.send(("ok", block.call(*data)))
            elif command == "set_attr":
                block.set_attr(*data)
                pipe.send(("ok", None))
            elif command == "attach":
                name, layout = data
                memory = SharedMemory(name=name)
                block.attach(views_of(memory.buf, layout))
                pipe.send(("ok", None))
            elif command == "close":
                pipe.send(("ok", None))
                break
            else:
                raise RuntimeError(f"unknown command {command!r}")
    except (EOFError, BrokenPipeError):  # the main process is gone: nothing to report to
        pass
    except BaseException as error:  # noqa: BLE001 - every failure goes back to the main process
        if block is not None:
            current = block.current
        text = "".join(traceback.format_exception(error))
        try:
            pipe.send(("error", (current, error, text)))
        except Exception:  # the exception itself does not pickle: send its text
            pipe.send(("error", (current, RuntimeError(f"{type(error).__name__}: {error}"), text)))
    finally:
        if block is not None:
            block.arrays = {}
            try:
                block.close()
            except Exception:  # noqa: BLE001, S110 - closing after a failure: the first error is the one to report
                pass
        if memory is not None:
            memory.close()
