"""Running the many closed-loop runs of a study: one executor and one resume cache for
``reproduce`` and ``sweep``.

A study is a list of tasks. A task has an ``id`` (its run id: the name of its file in the
cache), a ``label`` (what progress shows) and an ``arm_key`` (the arm it runs on, sent to
each worker once, or None when the run loads its own arm).

* :meth:`RunCache.lookup` finds the finished runs in the study's cache (``runs/<id><suffix>``):
  a finished run of the same settings is reused, a missing, unreadable or stale file is
  recomputed;
* :func:`run_tasks` runs the rest on an executor (:class:`SerialExecutor`,
  :class:`LocalExecutor` or :class:`RayExecutor`, see :func:`make_executor`; an executor
  only turns tasks into outcomes), writes each result into the cache atomically
  (:func:`atomic_write`) as soon as it arrives, on the driver (workers need no shared disk,
  e.g. on a Ray cluster), and reports progress through one :data:`ProgressHook` type,
  ``(done, total, label)``.

A run that raises is a result of the study (``failed``): the others go on. Interrupts:
Ctrl-C reaches the whole process group and workers ignore it; the CLI turns SIGTERM into a
``KeyboardInterrupt`` as well. Then what has not started is cancelled, the runs that are
running finish and are written (local processes; Ray cancels its tasks), and the
``KeyboardInterrupt`` propagates. Every finished run stays on disk, and the same call
resumes from them.

Ray is optional (``pip install hydroarm[ray]``) and used through its own API only
(``ray.remote``, ``ray.wait``).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue as queues
import signal
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from hydroarm.config import ConfigError

ProgressHook = Callable[[int, int, str], None]
"""``on_progress(done, total, label)``: ``done`` of ``total`` are finished. For a study: runs
(finished or reused), ``label`` the run that just finished; for one run (``on_step``):
control steps, ``label`` that run's label."""

StepHook = Callable[[int, int], None]
"""What a run calls as it goes: ``progress(k, total)`` control steps (the runner's order)."""

STEP_EVERY = 50
"""A worker reports a run's progress every this many control steps (and at the last)."""

POLL_S = 0.2
"""How often the driver looks for finished runs and relays step progress (s)."""


class Task(Protocol):
    """What the executors need of a task (a frozen dataclass is one)."""

    @property
    def id(self) -> str: ...

    @property
    def label(self) -> str: ...

    @property
    def arm_key(self) -> str | None: ...


RunFunction = Callable[[Any, Any, StepHook | None], Any]
"""``run(task, arm, progress) -> outcome``, a module-level function (it is pickled by name):
``arm`` is ``arms[task.arm_key]`` (None without a key); ``progress(k, total)`` or None."""

Outcome = Any
"""What a run function returned, or the exception it raised."""


# --- the resume cache ----------------------------------------------------------------------


class RunCache:
    """Finished runs, one file per run: ``folder/<task id><suffix>``, written atomically.

    A study subclasses it with :meth:`read` (the finished run of a task, or None if the
    file is missing, unreadable or was made with other settings: then the run is
    recomputed) and :meth:`write` (store a run's outcome atomically; return what
    :meth:`read` would return).
    """

    suffix = ".json"

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def path(self, task: Task, suffix: str | None = None) -> Path:
        return self.folder / f"{task.id}{self.suffix if suffix is None else suffix}"

    def read(self, task: Task) -> Any | None:
        raise NotImplementedError

    def write(self, task: Task, outcome: Any) -> Any:
        raise NotImplementedError

    def lookup(self, tasks: Iterable[Task]) -> tuple[dict[str, Any], list[Task]]:
        """The finished runs among ``tasks`` (by task id) and the tasks still to run."""
        finished: dict[str, Any] = {}
        todo = []
        for task in tasks:
            found = self.read(task)
            if found is None:
                todo.append(task)
            else:
                finished[task.id] = found
        return finished, todo


@dataclass
class RunReport:
    """What :func:`run_tasks` did: ``results`` by task id (written to the cache), ``ran``
    (how many), and ``failed``: (task, the exception it raised)."""

    results: dict[str, Any] = field(default_factory=dict)
    ran: int = 0
    failed: list[tuple[Any, BaseException]] = field(default_factory=list)


def run_tasks(
    tasks: Sequence[Task],
    run: RunFunction,
    cache: RunCache,
    executor: Executor,
    arms: Mapping[str, Any] | None = None,
    reused: int = 0,
    on_progress: ProgressHook | None = None,
    on_step: ProgressHook | None = None,
    on_result: Callable[[Any, Any], None] | None = None,
    on_error: Callable[[Any, BaseException], None] | None = None,
) -> RunReport:
    """Run ``tasks`` (what :meth:`RunCache.lookup` left to run) on ``executor`` and write each
    result into ``cache`` as it arrives.

    ``run``: the worker function (:data:`RunFunction`); ``arms``: the arms the tasks name by
    ``arm_key``; ``reused``: how many runs of the study the cache already held (progress
    counts them). ``on_progress(done, total, label)``: once at the start, then per finished
    run; ``on_step(k, total, label)``: a run's control steps (serial and local processes).
    ``on_result(task, result)`` after each written result, ``on_error(task, error)`` after
    each run that raised. A KeyboardInterrupt propagates once the runs already running are
    written (see the module docstring).
    """
    report = RunReport()
    total = reused + len(tasks)
    if on_progress is not None:
        on_progress(reused, total, "reused finished runs" if reused else "starting")
    failed: set[str] = set()

    def handle(task: Task, outcome: Outcome) -> None:
        if isinstance(outcome, BaseException):
            if task.id not in failed:  # (handled again after an interrupt: counted once)
                failed.add(task.id)
                report.failed.append((task, outcome))
                if on_error is not None:
                    on_error(task, outcome)
        else:
            result = cache.write(task, outcome)
            if task.id not in report.results:
                report.ran += 1
            report.results[task.id] = result
            if on_result is not None:
                on_result(task, result)
        if on_progress is not None:
            on_progress(reused + report.ran + len(report.failed), total, task.label)

    if tasks:
        _deliver(executor.map(run, tasks, arms or {}, on_step), handle)
    return report


def _deliver(outcomes: Generator, handle: Callable[[Any, Outcome], None]) -> None:
    """``handle`` every outcome. On an interrupt while handling one, handle it again (its
    files are written atomically: whole or absent) and let the executor hand over the runs
    that are still running before the interrupt propagates."""
    current = None
    try:
        for current in outcomes:
            handle(*current)
            current = None
    except KeyboardInterrupt as interrupt:
        if current is not None:
            handle(*current)
            for item in _remaining(outcomes, interrupt):
                handle(*item)
        raise
    finally:
        outcomes.close()


def _remaining(outcomes: Generator, interrupt: KeyboardInterrupt) -> Iterator:
    """Tell the executor of the interrupt; what it still yields (runs that were running)."""
    try:
        item = outcomes.throw(interrupt)
    except (KeyboardInterrupt, StopIteration):
        return
    yield item
    with contextlib.suppress(KeyboardInterrupt):
        yield from outcomes


# --- executors -------------------------------------------------------------------------


class Executor(Protocol):
    """Turns tasks into outcomes (what ``run`` returned, or the exception it raised), yielded
    as runs finish, in any order. On a KeyboardInterrupt (raised inside, or thrown in at a
    ``yield``) it cancels what has not started, may still yield the runs already running,
    then re-raises."""

    def map(
        self,
        run: RunFunction,
        tasks: Sequence[Task],
        arms: Mapping[str, Any],
        on_step: ProgressHook | None = None,
    ) -> Generator[tuple[Task, Outcome], None, None]: ...


def _step_reporter(report: Callable[[int, int], None]) -> StepHook:
    """``progress(k, total)`` that passes on every :data:`STEP_EVERY`-th step and the last."""

    def progress(k: int, total: int) -> None:
        if k % STEP_EVERY == 0 or k == total:
            report(k, total)

    return progress


class SerialExecutor:
    """In this process, one run after the other (debugging, profiling, tiny sweeps)."""

    def map(
        self,
        run: RunFunction,
        tasks: Sequence[Task],
        arms: Mapping[str, Any],
        on_step: ProgressHook | None = None,
    ) -> Generator[tuple[Task, Outcome], None, None]:
        for task in tasks:
            progress = None
            if on_step is not None:
                progress = _step_reporter(lambda k, total, label=task.label: on_step(k, total, label))
            try:
                outcome: Outcome = run(task, _arm(arms, task), progress)
            except Exception as error:  # noqa: BLE001 - a failed run is a result of the study
                outcome = error
            yield task, outcome


def _arm(arms: Mapping[str, Any], task: Task) -> Any:
    return None if task.arm_key is None else arms[task.arm_key]


_WORKER_ARMS: dict[str, Any] = {}
_WORKER_STEPS: Any = None  # a multiprocessing queue of (task id, k, total), or None


def _init_worker(arms: dict[str, Any], steps: Any) -> None:
    """Process-pool initializer: the arms arrive once per worker, not once per task.

    Workers ignore SIGINT: Ctrl-C reaches the whole process group, and only the main
    process handles it (cancels what has not started, lets running runs finish and be
    written), so no worker dies mid-run or prints a traceback."""
    global _WORKER_STEPS
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER_ARMS.clear()
    _WORKER_ARMS.update(arms)
    _WORKER_STEPS = steps


def _call_in_worker(run: RunFunction, task: Task) -> Outcome:
    progress = None
    if _WORKER_STEPS is not None:
        steps = _WORKER_STEPS
        progress = _step_reporter(lambda k, total: steps.put((task.id, k, total)))
    return run(task, _arm(_WORKER_ARMS, task), progress)


def _result(future: Future) -> Outcome:
    try:
        return future.result()
    except Exception as error:  # noqa: BLE001 - incl. a worker that died
        return error


@dataclass
class LocalExecutor:
    """``workers`` processes of this machine (``concurrent.futures``, spawn context)."""

    workers: int = 2

    def map(
        self,
        run: RunFunction,
        tasks: Sequence[Task],
        arms: Mapping[str, Any],
        on_step: ProgressHook | None = None,
    ) -> Generator[tuple[Task, Outcome], None, None]:
        if not tasks:
            return
        context = multiprocessing.get_context("spawn")
        used = {task.arm_key: arms[task.arm_key] for task in tasks if task.arm_key is not None}
        steps = context.Queue() if on_step is not None else None
        labels = {task.id: task.label for task in tasks}

        def relay() -> None:
            while steps is not None:
                try:
                    identifier, k, total = steps.get_nowait()
                except queues.Empty:
                    return
                on_step(k, total, labels[identifier])

        pool = ProcessPoolExecutor(
            max_workers=max(1, min(self.workers, len(tasks))), mp_context=context,
            initializer=_init_worker, initargs=(used, steps),
        )  # fmt: skip
        futures = {pool.submit(_call_in_worker, run, task): task for task in tasks}
        pending: set[Future] = set(futures)
        ready: deque[Future] = deque()  # finished, not yet yielded
        drained = False  # no run left running: the pool can be shut down and joined at once
        try:
            while pending or ready:
                if not ready:
                    done, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
                    ready.extend(done)
                    relay()
                    continue
                item = futures[ready[0]], _result(ready[0])
                ready.popleft()
                yield item
            drained = True
        except KeyboardInterrupt:
            for future in pending:
                future.cancel()  # fails for a run that has started
            running = {future for future in (*ready, *pending) if not future.cancelled()}
            while running:  # they finish anyway: hand them over to be written
                done, running = wait(running, timeout=POLL_S, return_when=FIRST_COMPLETED)
                relay()
                for future in done:
                    yield futures[future], _result(future)
            drained = True
            raise
        finally:
            # Joined when nothing runs: a pool left to the interpreter's exit can meet CPython's
            # race between its exit hook waking the pool's manager thread and that thread closing
            # the wake-up pipe (concurrent.futures.process._python_exit: "OSError: [Errno 9] Bad
            # file descriptor" printed after an interrupted sweep). Otherwise (the caller stopped
            # consuming) the runs still running are not waited for here.
            pool.shutdown(wait=drained, cancel_futures=True)
            if steps is not None:
                steps.close()
                steps.cancel_join_thread()


def _ray_call(run: RunFunction, task: Task, arm: Any) -> Outcome:
    return run(task, arm, None)


@dataclass
class RayExecutor:
    """Ray tasks (``ray.remote`` + ``ray.wait``) on a cluster.

    ``address``: ``None`` or ``"local"`` starts a local Ray instance with
    ``num_cpus`` CPUs; anything else is passed to ``ray.init(address=...)``
    (``"auto"``, ``"ray://head:10001"``, ``"10.0.0.5:6379"``). If Ray is already
    initialised in this process it is used as it is. A Ray instance started here
    is shut down at the end. Every node needs hydroarm installed (same versions).
    No step progress; on an interrupt every task is cancelled.
    """

    address: str | None = None
    num_cpus: int = 2

    def map(
        self,
        run: RunFunction,
        tasks: Sequence[Task],
        arms: Mapping[str, Any],
        on_step: ProgressHook | None = None,
    ) -> Generator[tuple[Task, Outcome], None, None]:
        if not tasks:
            return
        ray = import_ray()
        started = False
        if not ray.is_initialized():
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            if self.address in (None, "local"):
                ray.init(address="local", num_cpus=self.num_cpus, include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=self.address, log_to_driver=False)
            started = True
        pending: dict = {}
        try:
            remote = ray.remote(num_cpus=1, max_retries=0)(_ray_call)
            refs = {key: ray.put(arms[key]) for key in {task.arm_key for task in tasks if task.arm_key is not None}}
            pending = {remote.remote(run, task, refs.get(task.arm_key)): task for task in tasks}
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    task = pending.pop(ref)
                    try:
                        outcome: Outcome = ray.get(ref)
                    except Exception as error:  # noqa: BLE001 - RayTaskError wraps the run's error
                        outcome = error
                    yield task, outcome
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
            if started:
                ray.shutdown()


def import_ray():
    """``import ray`` or a ConfigError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install 'hydroarm[ray]'") from None
    return ray


def make_executor(workers: int = 2, ray_address: str | None = None) -> Executor:
    """``ray_address`` None: local processes (``workers`` of them; 0 = in this process);
    ``"local"``: a new local Ray instance with ``workers`` CPUs; else a Ray cluster's address."""
    if ray_address is not None:
        import_ray()
        return RayExecutor(address=ray_address, num_cpus=max(1, workers))
    if workers <= 0:
        return SerialExecutor()
    return LocalExecutor(workers=workers)
