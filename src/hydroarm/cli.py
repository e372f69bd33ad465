"""The ``hydroarm`` command line: reproduce the paper, run one experiment, list arms, export URDF.

Exit codes: 0 success, 1 a run failed, 2 bad input (a clear message naming the
field, no traceback), 130 interrupted by Ctrl-C / SIGINT, 143 terminated by
SIGTERM (in both cases finished runs are kept on disk and the same command
resumes from them).
"""

from __future__ import annotations

import contextlib
import json
import signal
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from hydroarm.config import ConfigError, load_model

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Simulate and control underwater robot arms (Liu et al. 2023 reproduced and beaten).",
)
console = Console(stderr=True, soft_wrap=True)  # never break an error or summary line mid-phrase


def _fail(message: str, code: int = 2) -> None:
    console.print(f"[bold red]error:[/] {escape(message)}")
    raise typer.Exit(code)


def _check_out(out: Path) -> None:
    """``--out`` must be a folder or not exist yet (it is created only once the settings are valid)."""
    if out.exists() and not out.is_dir():
        _fail(f"--out '{out}': exists and is not a folder")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so the same cleanup runs."""


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Turn SIGTERM into :class:`Terminated` while a long command runs."""

    def handler(signum, frame):
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupted(error: KeyboardInterrupt, out: Path) -> None:
    """Say where the finished runs are and exit 130 (SIGINT) or 143 (SIGTERM)."""
    console.print(f"[yellow]interrupted:[/] finished runs are kept in {out / 'runs'}; run the same command to resume")
    raise typer.Exit(143 if isinstance(error, Terminated) else 130)


def _parse_value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _experiment_config(config_file: Path | None, overrides: list[str]):
    from hydroarm.studies.experiment import ExperimentConfig, with_overrides

    config = load_model(ExperimentConfig, config_file) if config_file else ExperimentConfig()
    pairs = {}
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set '{item}': expected key=value, e.g. mpc.r=0.001")
        key, value = item.split("=", 1)
        pairs[key.strip()] = _parse_value(value.strip())
    return with_overrides(config, pairs) if pairs else config


ConfigOption = Annotated[
    Path | None, typer.Option("--config", help="TOML/YAML experiment settings (see docs/tutorial.md).")
]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override one setting, e.g. --set mpc.r=0.001 --set gp.window=20 (repeatable)."),
]


@app.command()
def reproduce(
    out: Annotated[Path, typer.Option("--out", help="Output folder (created).")] = Path("results"),
    quick: Annotated[bool, typer.Option("--quick", help="3 s task, 2 noisy seeds, no ablation (CI).")] = False,
    seeds: Annotated[
        int | None, typer.Option("--seeds", min=1, max=100, help="Noisy seeds (default 5; quick 2).")
    ] = None,
    ablation: Annotated[
        bool | None, typer.Option("--ablation/--no-ablation", help="Run the ablation (default: on unless --quick).")
    ] = None,
    workers: Annotated[int, typer.Option("--workers", min=1, max=64, help="Parallel processes.")] = 2,
    arm: Annotated[
        str | None,
        typer.Option("--arm", help="Another arm (built-in name or file); the task is scaled to its joint limits."),
    ] = None,
    config_file: ConfigOption = None,
    overrides: SetOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print metrics.json's tables to stdout.")] = False,
) -> None:
    """Reproduce the paper's Tables 1-2 and Figures 4-15 into OUT.

    Examples: hydroarm reproduce --out results;  hydroarm reproduce --arm alpha5 --out alpha5
    """
    from hydroarm.control.registry import PAPER_CONTROLLERS
    from hydroarm.model.loading import load_arm
    from hydroarm.studies.experiment import check_settings_for_arm, with_overrides
    from hydroarm.studies.reproduce import reproduce as run

    _check_out(out)
    try:
        config = _experiment_config(config_file, overrides or [])
        if arm is not None:
            config = with_overrides(config, {"arm": arm})
        check_settings_for_arm(config, load_arm(config.arm))
    except ConfigError as error:
        _fail(str(error))
    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console,
        transient=False,
    ) as progress:  # fmt: skip
        runs = progress.add_task("runs", total=None)
        bars: dict[str, int] = {}

        def on_run(done: int, total: int, label: str) -> None:
            progress.update(runs, completed=done, total=total)

        def on_step(k: int, total: int, label: str) -> None:
            if label not in bars:
                bars[label] = progress.add_task(label, total=total)
            progress.update(bars[label], completed=k, total=total)

        try:
            with _sigterm_as_interrupt():
                metrics = run(
                    out,
                    quick=quick,
                    noisy_seeds=seeds,
                    ablation=ablation,
                    workers=workers,
                    config=config,
                    on_progress=on_run,
                    on_step=on_step,
                )
        except KeyboardInterrupt as error:
            _interrupted(error, out)
        except ConfigError as error:
            _fail(str(error))
    if as_json:
        print(json.dumps({case: metrics[case] for case in ("clean", "noisy")}, indent=1))
        return
    table = Table(title=f"E_p mean over joints (rad^2) — full tables in {out}/table1.md, table2.md")
    table.add_column("controller")
    table.add_column("clean")
    table.add_column("noisy")
    for name in PAPER_CONTROLLERS:
        table.add_row(name, f"{metrics['clean'][name]['Ep_mean']:.4g}", f"{metrics['noisy'][name]['Ep_mean']:.4g}")
    for case in ("clean", "noisy"):
        gain = metrics[case]["gain_gp_mpc_over_mpc_percent"]
        table.add_row(f"gain {case} (%)", f"{gain['mean_of_joints']:.1f} (paper {gain['paper_mean_of_joints']})", "")
    Console().print(table)
    console.print(f"report: {out / 'report.md'}  ({metrics['wall_time_s']['total']:.1f} s)")


@app.command()
def run(
    controller: Annotated[str, typer.Option("--controller", help="smc, mpc, gp-mpc, idmpc or gp-idmpc.")] = "gp-mpc",
    arm: Annotated[
        str | None, typer.Option("--arm", help="Built-in arm name or arm file (default: the settings' arm, paper).")
    ] = None,
    noise: Annotated[
        float | None,
        typer.Option(
            "--noise", min=0.0, max=10.0, help="Measurement noise variance (default: plant.noise_variance, 0)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Noise seed.")] = 0,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("run"),
    config_file: ConfigOption = None,
    overrides: SetOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
) -> None:
    """Run one experiment and write its trajectory, metrics and figures.

    Example: hydroarm run --controller gp-mpc --arm paper --noise 0.001 --seed 3 --out DIR
    """
    from hydroarm.model.loading import load_arm
    from hydroarm.studies import figures
    from hydroarm.studies.experiment import canonical_name, check_settings_for_arm, run_experiment, with_overrides
    from hydroarm.studies.runner import tracking_metrics

    try:
        name = canonical_name(controller)
    except ConfigError as error:
        _fail(f"--{error}")
    _check_out(out)
    try:
        config = _experiment_config(config_file, overrides or [])
        options = {"arm": arm, "plant.noise_variance": noise}
        config = with_overrides(config, {key: value for key, value in options.items() if value is not None})
        arm_model = load_arm(config.arm)
        check_settings_for_arm(config, arm_model)
    except ConfigError as error:
        _fail(str(error))
    out.mkdir(parents=True, exist_ok=True)
    with Progress(
        TextColumn(name), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
    ) as progress:
        task = progress.add_task(name, total=int(round(config.duration / config.control_period)))
        traj = run_experiment(config, name, seed, progress=lambda k, total: progress.update(task, completed=k))
    traj.save(out / "trajectory.npz")
    metrics = tracking_metrics(traj)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    figures.plot_tracking(traj, out / "position.png", f"{name}: position tracking", "position")
    figures.plot_tracking(traj, out / "velocity.png", f"{name}: velocity tracking", "velocity")
    figures.plot_torque(traj, out / "torque.png", f"{name}: joint torques", arm_model.torque_limit)
    if name == "GP-MPC":
        figures.plot_disturbance(traj, out / "disturbance.png", "true vs GP-estimated disturbance")
    if as_json:
        print(json.dumps(metrics))
    else:
        console.print(f"E_p per joint (rad^2): {[round(x, 5) for x in metrics['Ep']]}; files in {out}")
    if traj.diverged:
        raise typer.Exit(1)


@app.command()
def animate(
    run_file: Annotated[Path, typer.Argument(help="A trajectory .npz (from run or reproduce).")],
    out: Annotated[Path, typer.Option("--out", help="Output .gif (or .mp4 with ffmpeg).")] = Path("arm.gif"),
    arm: Annotated[str | None, typer.Option("--arm", help="Arm of the run (default: from the file).")] = None,
    fps: Annotated[int, typer.Option("--fps", min=1, max=100)] = 10,
    start: Annotated[float, typer.Option("--start", min=0.0, help="First second to show.")] = 0.0,
    duration: Annotated[
        float | None, typer.Option("--duration", min=0.0, help="Seconds to show (default: all).")
    ] = None,
) -> None:
    """Render the arm following a saved trajectory, the reference ghosted, the error in a corner.

    Example: hydroarm animate results/runs/clean__GP-MPC__seed0.npz --out arm.gif
    """
    from hydroarm.model.loading import load_arm
    from hydroarm.studies.animate import animate as render
    from hydroarm.studies.runner import Trajectory

    if not run_file.is_file():
        _fail(f"RUN_FILE '{run_file}': no such file")
    try:
        traj = Trajectory.load(run_file)
    except Exception as error:  # noqa: BLE001 - any unreadable file is bad input
        _fail(f"RUN_FILE '{run_file}': not a hydroarm trajectory ({error})")
    try:
        arm_model = load_arm(arm) if arm else None
        render(traj, out, arm=arm_model, fps=fps, start=start, duration=duration)
    except (ConfigError, ValueError) as error:
        _fail(str(error))
    console.print(f"wrote {out}")


@app.command()
def arms(as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
    """List the built-in arms."""
    from hydroarm.model.loading import BUILTIN_ARMS, load_arm

    rows = []
    for name in BUILTIN_ARMS:
        arm = load_arm(name)
        description = getattr(arm.spec, "description", "") if arm.spec is not None else "URDF arm"
        rows.append(
            {
                "name": name,
                "joints": arm.n_joints,
                "description": description,
                "torque_limit": arm.torque_limit.tolist(),
            }
        )
    if as_json:
        print(json.dumps(rows))
        return
    table = Table(title="built-in arms")
    for column in ("name", "joints", "description", "torque limit (N m)"):
        table.add_column(column)
    for row in rows:
        table.add_row(
            row["name"], str(row["joints"]), row["description"], ", ".join(f"{x:g}" for x in row["torque_limit"])
        )
    Console().print(table)


@app.command("export-urdf")
def export_urdf(
    arm: Annotated[str, typer.Argument(help="Built-in arm name or arm file.")] = "paper",
    out: Annotated[Path | None, typer.Option("--out", help="File to write (default: stdout).")] = None,
) -> None:
    """Write the dry arm as URDF (links, revolute joints, inertials, cylinders).

    Example: hydroarm export-urdf paper --out paper.urdf
    """
    from hydroarm.model.loading import load_arm

    try:
        from hydroarm.model.urdf_export import arm_to_urdf

        text = arm_to_urdf(load_arm(arm))
    except ConfigError as error:
        _fail(str(error))
    if out is None:
        sys.stdout.write(text)
    else:
        out.write_text(text)
        console.print(f"wrote {out}")


@app.command()
def sweep(
    sweep_file: Annotated[Path, typer.Argument(help="Sweep file (TOML/YAML), e.g. examples/sweep.toml.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder (created; the same command resumes).")] = Path(
        "sweep"
    ),
    workers: Annotated[
        int, typer.Option("--workers", min=1, max=256, help="Parallel processes (or the CPUs of a local Ray instance).")
    ] = 2,
    ray: Annotated[
        bool,
        typer.Option(
            "--ray", help="Run on Ray: a local Ray instance with --workers CPUs (pip install 'hydroarm[ray]')."
        ),
    ] = False,
    ray_address: Annotated[
        str | None,
        typer.Option(
            "--ray-address",
            metavar="ADDRESS",
            help="Run on this Ray cluster instead (implies --ray): auto, HOST:6379 or ray://HOST:10001.",
        ),
    ] = None,
    trajectories: Annotated[
        bool, typer.Option("--trajectories", help="Also keep every trajectory (runs/<id>.npz).")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Run a grid or random sweep over controllers, seeds, arms, water, noise, mismatch and settings.

    One row per run in OUT/results.csv (written as runs finish); OUT/summary.md and box plots at the end.
    Re-running the same command skips finished runs.

    Examples: hydroarm sweep examples/sweep.toml --out sweep1;  hydroarm sweep examples/sweep.toml --out sweep1 --ray
    """
    from hydroarm.studies.experiment import check_settings_for_arm
    from hydroarm.studies.sweep import load_sweep, plan_sweep, run_sweep

    if not sweep_file.is_file():
        _fail(f"SWEEP_FILE '{sweep_file}': no such file")
    _check_out(out)
    try:  # every setting and arm checked before the progress bar starts
        plan = plan_sweep(load_sweep(sweep_file), sweep_file.parent, str(sweep_file))
        checked = set()
        for row in plan.rows:
            arm_key = plan.tasks[row.id].arm_key
            if (id(row.config), arm_key) not in checked:
                checked.add((id(row.config), arm_key))
                where = ", ".join(f"{key} = {value!r}" for key, value in row.params.items())
                source = f"{sweep_file}: the runs with {where}" if where else f"{sweep_file}: base"
                check_settings_for_arm(row.config, plan.arms[arm_key], source)
        if ray or ray_address:
            from hydroarm.studies.executor import import_ray

            import_ray()
    except ConfigError as error:
        _fail(str(error))
    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
    ) as progress:
        task = progress.add_task("sweep", total=None)

        def hook(done: int, total: int, label: str) -> None:
            progress.update(task, completed=done, total=total, description=label[:50])

        try:
            with _sigterm_as_interrupt():
                summary = run_sweep(
                    sweep_file,
                    out,
                    workers=workers,
                    ray_address=ray_address or ("local" if ray else None),
                    on_progress=hook,
                    save_trajectories=True if trajectories else None,
                )
        except ConfigError as error:
            _fail(str(error))
        except KeyboardInterrupt as error:
            _interrupted(error, out)
    if as_json:
        print(json.dumps(summary))
    else:
        table = Table(title=f"{summary['metric_label']} — {out}/summary.md, {out}/results.csv")
        for column in ("controller", "finished", "median", "p90", "diverged"):
            table.add_column(column)
        for name, entry in summary["controllers"].items():
            cell = lambda x: "-" if x is None else f"{x:.4g}"  # noqa: E731
            table.add_row(
                name,
                f"{entry['finished']}/{entry['rows']}",
                cell(entry["median"]),
                cell(entry["p90"]),
                str(entry["diverged"]),
            )
        Console().print(table)
        console.print(
            f"{summary['ran']} runs done, {summary['reused']} reused, {len(summary['failed'])} failed "
            f"({summary['wall_s']:.1f} s)"
        )
    if summary["failed"]:
        raise typer.Exit(1)


@app.command()
def bench(
    out: Annotated[Path, typer.Option("--out", help="Output folder for bench.json and bench.md.")] = Path(
        "bench-results"
    ),
    quick: Annotated[bool, typer.Option("--quick", help="A few hundred samples (CI).")] = False,
) -> None:
    """Benchmark the control steps, the plant, peers (do-mpc, cvxpy, scikit-learn, GPyTorch) and scaling.

    The suite is development tooling in the source repository's bench/ folder (not in the
    wheel): this command runs it there (python -m hydroarm_bench) and exits with its code.

    Example: hydroarm bench --out bench-results
    """
    import os
    import subprocess

    import hydroarm

    folder = Path(hydroarm.__file__).resolve().parents[2] / "bench"
    if not (folder / "hydroarm_bench" / "__main__.py").is_file():
        _fail(
            "the benchmark suite lives in the source repository's bench/ folder; clone the repository to run it",
            code=2,
        )
    _check_out(out)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(folder), env.get("PYTHONPATH", "")) if p)
    command = [sys.executable, "-m", "hydroarm_bench", "--out", str(out)] + (["--quick"] if quick else [])
    try:
        code = subprocess.call(command, env=env)
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    if code != 0:
        _fail(f"the benchmark suite exited with code {code}", code=code if code > 0 else 128 - code)  # -N: signal N
    console.print(f"wrote {out / 'bench.json'} and {out / 'bench.md'}")


@app.command()
def tune(
    controller: Annotated[str, typer.Option("--controller", help="smc, mpc, gp-mpc, idmpc or gp-idmpc.")],
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
    the best mean E_p wins. Example: hydroarm tune --arm alpha5 --controller smc --out alpha5.toml
    """
    from hydroarm.model.loading import load_arm
    from hydroarm.studies.experiment import canonical_name, check_settings_for_arm, with_overrides
    from hydroarm.studies.tune import TUNING_GRIDS, write_settings
    from hydroarm.studies.tune import tune as run_tune

    try:
        name = canonical_name(controller)
        config = with_overrides(_experiment_config(config_file, overrides or []), {"arm": arm})
        check_settings_for_arm(config, load_arm(config.arm))
    except ConfigError as error:
        _fail(str(error))
    if out.exists() and not out.is_file():
        _fail(f"--out '{out}': exists and is not a file")
    grid = TUNING_GRIDS[name]
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
    write_settings(out, {"arm": arm, **result.best}, header)
    out.with_name(out.name + ".json").write_text(
        json.dumps({"controller": name, "arm": arm, "rows": result.rows}, indent=1)
    )
    table = Table(title=f"{name} on {arm}, dry arm: best of {len(result.rows)} points")
    for column in (*(key.split(".")[-1] for key in result.best), "clean", "noisy", "score"):
        table.add_column(column)
    for row in result.rows[:5]:
        cells = [f"{row['point'][k]:g}" for k in result.best]
        cells += [("diverged" if row[k] is None else f"{row[k]:.5g}") for k in ("clean", "noisy")]
        table.add_row(*cells, f"{row['score']:.5g}")
    Console(soft_wrap=True).print(table)
    console.print(f"wrote {out} (read it with --config {out}) and {out.name}.json")


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
