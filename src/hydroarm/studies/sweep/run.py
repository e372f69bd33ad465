"""Running a sweep: :func:`run_sweep` plans it, runs what is not finished yet through the
one executor (:mod:`hydroarm.studies.executor`), keeps ``results.csv`` up to date and
writes the summary at the end."""

from __future__ import annotations

import time
from pathlib import Path

from hydroarm.sim.files import atomic_write
from hydroarm.studies.executor import Executor, ProgressHook, make_executor, run_tasks
from hydroarm.studies.outputs import claim_output, dumps
from hydroarm.studies.sweep.plan import FORMAT, Plan, RunTask, plan_sweep
from hydroarm.studies.sweep.results import ResultsTable, RunFiles
from hydroarm.studies.sweep.schema import SweepConfig, load_sweep
from hydroarm.studies.sweep.summary import summarise
from hydroarm.studies.sweep.worker import execute_run

MANY_ROWS = 2000
"""A sweep with more rows rewrites results.csv at most every :data:`TABLE_EVERY_S` s."""

TABLE_EVERY_S = 2.0


def _plan_json(plan: Plan, source: str) -> dict:
    return {
        "format": FORMAT,
        "source": source,
        "sweep": plan.config.model_dump(mode="json"),
        "parameters": plan.keys,
        "rows": [
            {"id": r.id, "point": r.point, "controller": r.controller, "seed": r.seed, "params": r.params}
            for r in plan.rows
        ],
    }


def claim_sweep_folder(
    out: str | Path, plan: Plan, source: str, overwrite: bool = False, dry_run: bool = False
) -> None:
    """Check ``out`` may take this sweep's results (:func:`~hydroarm.studies.outputs.claim_output`):
    the same sweep resumes, an extended one (more seeds, more values) reuses the runs it
    shares; a folder of another sweep raises :class:`~hydroarm.studies.outputs.OutputConflict`
    unless ``overwrite``. Whether trajectories are kept does not count."""
    settings = plan.config.model_dump(mode="json", exclude={"save_trajectories"})
    runs = dict.fromkeys(plan.tasks, "")  # a run id is a hash of its settings already
    made_by = f"hydroarm sweep {source} ({len(plan.rows)} rows, sweep '{plan.config.name}')"
    claim_output(Path(out), "sweep", settings, runs, made_by, overwrite, dry_run)


def _as_plan(sweep: str | Path | SweepConfig | Plan, save_trajectories: bool | None) -> Plan:
    """:func:`run_sweep`'s ``sweep`` planned (:func:`plan_sweep`), a :class:`Plan` as it is."""
    if isinstance(sweep, Plan):
        if save_trajectories is not None and save_trajectories != sweep.config.save_trajectories:
            raise ValueError("save_trajectories: give it to plan_sweep (the plan's SweepConfig), not with a Plan")
        return sweep
    if isinstance(sweep, SweepConfig):
        config, folder, source = sweep, None, "sweep"
    else:
        config, folder, source = load_sweep(sweep), Path(sweep).parent, str(sweep)
    if save_trajectories is not None:
        config = config.model_copy(update={"save_trajectories": save_trajectories})
    return plan_sweep(config, folder, source)


def run_sweep(
    sweep: str | Path | SweepConfig | Plan,
    out_dir: str | Path,
    workers: int = 2,
    ray_address: str | None = None,
    on_progress: ProgressHook | None = None,
    executor: Executor | None = None,
    save_trajectories: bool | None = None,
    overwrite: bool = False,
) -> dict:
    """Run a sweep into ``out_dir`` (see the package docstring); return :func:`summarise`'s
    dict plus ``ran``, ``reused``, ``failed`` and ``wall_s``.

    ``sweep``: a sweep file, a :class:`SweepConfig` (relative arm paths then
    relative to the cwd) or a :class:`Plan` of :func:`plan_sweep` (planned and checked once:
    the CLI's way). ``workers``: local processes (0 = this process), or
    the CPUs of a local Ray instance. ``ray_address``: ``None`` local processes;
    ``"local"`` a new local Ray instance; else a Ray address (``"auto"``,
    ``"ray://head:10001"``). ``executor``: any
    :class:`~hydroarm.studies.executor.Executor` (overrides both).
    ``on_progress(done, total, label)``: runs finished (incl. reused) of the
    sweep's distinct runs. Every setting is validated and every arm loaded
    before the first run (:class:`~hydroarm.config.ConfigError` otherwise). A
    run that raises is listed in ``failed`` (and ``failed.json``) and retried by
    the next call; the others go on. KeyboardInterrupt stops the sweep; finished
    runs are kept (those running finish first, on local processes).
    A folder holding the results of another sweep is
    refused unless ``overwrite`` (:func:`claim_sweep_folder`).
    """
    start = time.perf_counter()
    plan = _as_plan(sweep, save_trajectories)
    source = plan.source
    out = Path(out_dir)
    claim_sweep_folder(out, plan, source, overwrite)
    cache = RunFiles(out / "runs")
    atomic_write(out / "sweep.json", dumps(_plan_json(plan, source), indent=1))
    table = ResultsTable(plan, out / "results.csv")
    finished, todo = cache.lookup(plan.tasks.values())
    for record in finished.values():
        table.add(record)
    table.write()
    runner = executor if executor is not None else make_executor(workers, ray_address)
    failed: list[dict] = []
    last_write = time.perf_counter()
    many = len(plan.rows) > MANY_ROWS

    def on_result(task: RunTask, record: dict) -> None:
        nonlocal last_write
        table.add(record)
        if not many or time.perf_counter() - last_write > TABLE_EVERY_S:
            table.write()
            last_write = time.perf_counter()

    def on_error(task: RunTask, error: BaseException) -> None:
        text = f"{type(error).__name__}: {error}"
        failed.append({"id": task.id, "controller": task.controller, "seed": task.seed, "error": text[:2000]})

    try:
        report = run_tasks(
            todo, execute_run, cache, runner, plan.arms, reused=len(finished),
            on_progress=on_progress, on_result=on_result, on_error=on_error,
        )  # fmt: skip
    finally:
        table.write()
        failed_path = out / "failed.json"
        if failed:
            atomic_write(failed_path, dumps(failed, indent=1))
        elif failed_path.exists():
            failed_path.unlink()
    summary = summarise(out)
    summary.update(ran=report.ran, reused=len(finished), failed=failed, wall_s=time.perf_counter() - start)
    return summary
