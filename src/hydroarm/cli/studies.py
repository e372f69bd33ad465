"""Commands that run studies: reproduce, sweep, tune."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from hydroarm.cli._common import (
    ConfigOption,
    OverwriteOption,
    SetOption,
    Terminated,
    TunedOption,
    _check_file_out,
    _check_out,
    _experiment_config,
    _fail,
    _interrupted,
    _sigterm_as_interrupt,
    app,
    console,
)
from hydroarm.cli._options import (
    AblationOption,
    QuickOption,
    RayAddressOption,
    RayOption,
    ReplicasOption,
    ReproduceArmOption,
    ReproduceOutOption,
    ReproduceWorkersOption,
    SeedsOption,
    SweepOutOption,
    SweepWorkersOption,
    TrajectoriesOption,
)
from hydroarm.config import ConfigError


@contextlib.contextmanager
def _study_progress(step_bars: bool = True):
    """A progress display of a study: yields ``(on_run, on_step)`` hooks, one bar for the runs
    (``on_run(done, total, label)``; its description the label unless ``step_bars``) and, if
    ``step_bars``, one per running run (``on_step(k, total, label)``)."""
    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console,
        transient=False,
    ) as progress:  # fmt: skip
        runs = progress.add_task("runs" if step_bars else "sweep", total=None)
        bars: dict[str, int] = {}

        def on_run(done: int, total: int, label: str) -> None:
            if step_bars:
                progress.update(runs, completed=done, total=total)
            else:
                progress.update(runs, completed=done, total=total, description=label[:50])

        def on_step(k: int, total: int, label: str) -> None:
            if label not in bars:
                bars[label] = progress.add_task(label, total=total)
            progress.update(bars[label], completed=k, total=total)

        yield on_run, on_step


@app.command()
def reproduce(
    out: ReproduceOutOption = Path("results"),
    quick: QuickOption = False,
    seeds: SeedsOption = None,
    ablation: AblationOption = None,
    workers: ReproduceWorkersOption = 2,
    arm: ReproduceArmOption = None,
    config_file: ConfigOption = None,
    tuned: TunedOption = False,
    overrides: SetOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print metrics.json's tables to stdout.")] = False,
    overwrite: OverwriteOption = False,
    replicas: ReplicasOption = None,
) -> None:
    """Reproduce the paper's Tables 1-2 and Figures 4-15 into OUT.

    The same command resumes from the finished runs in OUT; a folder holding results of other
    settings is refused unless --overwrite. OUT/summary.json holds every number (metrics.json only
    the tables').
    Examples: hydroarm reproduce --out results;  hydroarm reproduce --arm alpha5 --out alpha5
    """
    from hydroarm.sim.experiment import with_overrides
    from hydroarm.studies.outputs import dumps
    from hydroarm.studies.reproduce import check_study
    from hydroarm.studies.reproduce import reproduce as run

    _check_out(out)
    try:
        config = _experiment_config(config_file, overrides or [], tuned, arm)
        if arm is not None:
            config = with_overrides(config, {"arm": arm})
        check_study(out, config, quick, seeds, ablation, replicas, overwrite)
    except ConfigError as error:
        _fail(str(error))
    with _study_progress() as (on_run, on_step):
        try:
            with _sigterm_as_interrupt():
                metrics = run(
                    out, quick=quick, noisy_seeds=seeds, ablation=ablation, workers=workers, config=config,
                    on_progress=on_run, on_step=on_step, overwrite=overwrite, replicas=replicas,
                )  # fmt: skip
        except KeyboardInterrupt as error:
            _interrupted(error, out)
        except ConfigError as error:
            _fail(str(error))
    if as_json:
        print(dumps({case: metrics[case] for case in ("clean", "noisy")}, indent=1))
        return
    _print_reproduction(metrics, out)


def _print_reproduction(metrics: dict, out: Path) -> None:
    """``hydroarm reproduce``'s summary: E_p mean over joints per paper row, the gains, the files."""
    from hydroarm.control.registry import PAPER_CONTROLLERS

    table = Table(title=f"E_p mean over joints (rad^2) — full tables in {out}/table1.md, table2.md")
    table.add_column("controller")
    table.add_column("clean")
    table.add_column("noisy")
    cell = lambda x, spec: "-" if x is None else format(x, spec)  # noqa: E731 - null: not defined
    for name in PAPER_CONTROLLERS:
        table.add_row(
            name, cell(metrics["clean"][name]["Ep_mean"], ".4g"), cell(metrics["noisy"][name]["Ep_mean"], ".4g")
        )
    for case in ("clean", "noisy"):
        gain = metrics[case]["gain_gp_mpc_over_mpc_percent"]
        paper = f" (paper {gain['paper_mean_of_joints']})" if "paper_mean_of_joints" in gain else ""
        table.add_row(f"gain {case} (%)", cell(gain["mean_of_joints"], ".1f") + paper, "")
    Console().print(table)
    console.print(
        f"report: {out / 'report.md'}, every number: {out / 'summary.json'}  ({metrics['wall_time_s']['total']:.1f} s)"
    )


@app.command()
def sweep(
    sweep_file: Annotated[Path, typer.Argument(help="Sweep file (TOML/YAML), e.g. examples/sweep.toml.")],
    out: SweepOutOption = Path("sweep"),
    workers: SweepWorkersOption = 2,
    ray: RayOption = False,
    ray_address: RayAddressOption = None,
    trajectories: TrajectoriesOption = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
    overwrite: OverwriteOption = False,
) -> None:
    """Run a grid or random sweep over controllers, seeds, arms, water, noise, mismatch and settings.

    One row per run in OUT/results.csv (written as runs finish); OUT/summary.md and box plots at the end.
    Re-running the same command skips finished runs (so does an extended sweep: more seeds or values);
    a folder holding results of another sweep is refused unless --overwrite.

    Examples: hydroarm sweep examples/sweep.toml --out sweep1;  hydroarm sweep examples/sweep.toml --out sweep1 --ray
    """
    from hydroarm.studies.outputs import dumps
    from hydroarm.studies.sweep import claim_sweep_folder, load_sweep, plan_sweep, run_sweep

    if not sweep_file.is_file():
        _fail(f"SWEEP_FILE '{sweep_file}': no such file")
    _check_out(out)
    try:  # every setting and arm checked before the progress bar starts (plan_sweep does it all)
        sweep = load_sweep(sweep_file)
        if trajectories:
            sweep = sweep.model_copy(update={"save_trajectories": True})
        plan = plan_sweep(sweep, sweep_file.parent, str(sweep_file))
        if ray or ray_address:
            from hydroarm.studies.executor import import_ray

            import_ray()
        claim_sweep_folder(out, plan, str(sweep_file), overwrite, dry_run=True)
    except ConfigError as error:
        _fail(str(error))
    with _study_progress(step_bars=False) as (hook, _):
        try:
            with _sigterm_as_interrupt():
                address = ray_address or ("local" if ray else None)
                summary = run_sweep(
                    plan, out, workers=workers, ray_address=address, on_progress=hook, overwrite=overwrite
                )
        except ConfigError as error:
            _fail(str(error))
        except KeyboardInterrupt as error:
            _interrupted(error, out)
    if as_json:
        print(dumps(summary))
    else:
        _print_sweep(summary, out)
    if summary["failed"]:
        raise typer.Exit(1)


def _print_sweep(summary: dict, out: Path) -> None:
    """``hydroarm sweep``'s summary: per controller the finished runs, median, p90, divergences."""
    table = Table(title=f"{summary['metric_label']} — {out}/summary.md, {out}/results.csv")
    for column in ("controller", "finished", "median", "p90", "diverged"):
        table.add_column(column)
    for name, entry in summary["controllers"].items():
        cell = lambda x: "-" if x is None else f"{x:.4g}"  # noqa: E731
        table.add_row(
            name, f"{entry['finished']}/{entry['rows']}", cell(entry["median"]), cell(entry["p90"]),
            str(entry["diverged"]),
        )  # fmt: skip
    Console().print(table)
    console.print(
        f"{summary['ran']} runs done, {summary['reused']} reused, {len(summary['failed'])} failed "
        f"({summary['wall_s']:.1f} s)"
    )


@app.command()
def tune(
    controller: Annotated[str, typer.Option("--controller", help="A registered controller (hydroarm controllers).")],
    arm: Annotated[str, typer.Option("--arm", help="Built-in arm name or arm file.")] = "paper",
    out: Annotated[
        Path, typer.Option("--out", help="Settings file (TOML) to write or update; --config reads it.")
    ] = Path("tuned.toml"),
    workers: Annotated[int, typer.Option("--workers", min=0, max=256, help="Parallel processes (0: this one).")] = 2,
    config_file: ConfigOption = None,
    overrides: SetOption = None,
) -> None:
    """Tune a controller's gains on the arm without water ("tuned once on land") and write them.

    Every point of the controller's grid runs the arm's task clean and noisy on the dry arm;
    the best mean E_p wins.
    Example: hydroarm tune --arm alpha5 --controller smc --out alpha5.toml
    """
    from hydroarm.model.arm.loading import load_arm
    from hydroarm.sim.experiment import (
        arm_for_settings_file,
        canonical_name,
        check_settings_for_arm,
        with_overrides,
    )
    from hydroarm.studies.tune import tune as run_tune
    from hydroarm.studies.tune import tuning_grid, write_settings

    try:
        name = canonical_name(controller)
        config = with_overrides(_experiment_config(config_file, overrides or []), {"arm": arm})
        check_settings_for_arm(config, load_arm(config.arm), controllers=(name,))
    except ConfigError as error:
        _fail(str(error))
    if out.exists() and not out.is_file():
        _fail(f"--out '{out}': exists and is not a file")
    _check_file_out(out)
    grid = tuning_grid(config, name)
    with (
        _sigterm_as_interrupt(),
        Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                 console=console) as progress,
    ):  # fmt: skip
        bar = progress.add_task(f"tune {name}", total=None)
        try:
            result = run_tune(
                config, name, out.with_name(out.name + ".runs"), workers,
                on_progress=lambda done, total, label: progress.update(bar, completed=done, total=total),
            )  # fmt: skip
        except KeyboardInterrupt as error:
            progress.stop()
            console.print(f"[yellow]interrupted:[/] finished runs are kept in {out.name}.runs; run again to resume")
            raise typer.Exit(143 if isinstance(error, Terminated) else 130) from None
        except ConfigError as error:
            progress.stop()
            _fail(str(error))
    header = (
        f"hydroarm tune --controller {name.lower()} --arm {arm}: tuned on the dry arm (clean + noisy, mean E_p)\n"
        f"grid: {json.dumps(grid)}\nbest score {result.rows[0]['score']:.6g} rad^2"
    )
    written_arm = arm_for_settings_file(arm, out)
    try:
        write_settings(out, {"arm": written_arm, **result.best}, header)
    except ConfigError as error:  # the file at --out is of a newer settings schema
        _fail(str(error))
    out.with_name(out.name + ".json").write_text(
        json.dumps({"controller": name, "arm": written_arm, "rows": result.rows}, indent=1)
    )
    table = Table(title=f"{name} on {arm}, dry arm: best of {len(result.rows)} points")
    for column in (*(key.split(".")[-1] for key in result.best), "clean", "noisy", "score"):
        table.add_column(column, no_wrap=True, min_width=len(column))  # a header is never cut
    for row in result.rows[:5]:
        cells = [f"{row['point'][k]:g}" for k in result.best]
        cells += [("diverged" if row[k] is None else f"{row[k]:.5g}") for k in ("clean", "noisy")]
        table.add_row(*cells, f"{row['score']:.5g}")
    Console(soft_wrap=True).print(table)
    console.print(f"wrote {out} (read it with --config {out}) and {out.name}.json")
