"""Commands about one run and the arms: run, animate, arms, export-urdf, bench."""

from __future__ import annotations

import json
import sys
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
    TunedOption,
    _check_file_out,
    _check_out,
    _experiment_config,
    _fail,
    app,
    console,
)
from hydroarm.cli._options import (
    ControllerOption,
    ModelOption,
    NoiseOption,
    RunArmOption,
    SaveModelOption,
    VehicleOption,
    ViewOption,
)
from hydroarm.config import ConfigError, not_a_file


def _rounded(values: list[float]) -> list[float | None]:
    """E_p values to 5 decimals for a summary line; NaN (no sample after the start-up) as None."""
    return [None if x != x else round(x, 5) for x in values]


@app.command()
def run(
    controller: ControllerOption = None,
    arm: RunArmOption = None,
    noise: NoiseOption = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Noise seed.")] = 0,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("run"),
    config_file: ConfigOption = None,
    tuned: TunedOption = False,
    overrides: SetOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
    overwrite: OverwriteOption = False,
    view: ViewOption = False,
    model: ModelOption = None,
    save_model: SaveModelOption = None,
    vehicle: VehicleOption = None,
) -> None:
    """Run one experiment and write its trajectory, metrics and figures.

    A folder that holds the results of other settings is refused unless --overwrite.
    --view serves the saved run in the browser as soon as it is written (hydroarm view).
    Example: hydroarm run --controller gp-mpc --arm paper --noise 0.001 --seed 3 --out DIR

    With --vehicle (or vehicle.name in the settings), the arm works on the vehicle while the
    vehicle holds station: --controller is the arm's, the station keeper is
    vehicle.control.kind (pid or mpc), and metrics.json adds the station-keeping metrics.
    Example: hydroarm run --vehicle bluerov2-heavy --set vehicle.control.kind=mpc --set duration=5 --out VEHICLE_DIR
    """
    from hydroarm.studies.outputs import claim_output, dumps
    from hydroarm.studies.single_run import RunRequest, prepare_run, write_run

    _check_out(out)
    try:
        request = RunRequest(
            _experiment_config(config_file, overrides or [], tuned, arm, vehicle), controller, arm, noise, vehicle,
            seed, model, save_model,
        )  # fmt: skip
        prepared = prepare_run(request)
        claim_output(out, "run", prepared.what, description=prepared.made_by, overwrite=overwrite)
    except ConfigError as error:
        _fail(str(error) if not str(error).startswith("controller =") else f"--{error}")
    label = prepared.experiment.controller.name
    with Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
    ) as progress:
        task = progress.add_task(label, total=int(round(prepared.config.duration / prepared.config.control_period)))
        traj = prepared.experiment.run(seed, progress=lambda k, total: progress.update(task, completed=k))
    metrics = write_run(prepared, traj, out)
    if as_json:
        print(dumps(metrics))
    else:
        _print_summary(metrics, out)
    if view:
        from hydroarm.cli.view import serve_run

        serve_run(out / "trajectory.npz")
    if traj.diverged:
        raise typer.Exit(1)


def _print_summary(metrics: dict, out: Path) -> None:
    """``hydroarm run``'s summary lines: E_p per joint, whole run and steady, station keeping."""
    from hydroarm.studies.single_run import STEADY_AFTER

    console.print(f"E_p per joint (rad^2), whole run: {_rounded(metrics['Ep'])}")
    console.print(
        f"E_p per joint (rad^2), after the start-up (t > {STEADY_AFTER:g} s): {_rounded(metrics['Ep_steady'])}"
    )
    if "station_keeping" in metrics:
        kept = metrics["station_keeping"]
        console.print(
            f"station keeping: drift RMS {kept['drift_rms_m'] * 1e3:.2f} mm, "
            f"attitude RMS {kept['attitude_rms_deg']:.3f} deg"
        )
    console.print(f"files in {out}")


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

    Example: hydroarm animate results/runs/clean__gp-mpc__seed0.npz --out arm.gif
    """
    from hydroarm.model.arm.loading import load_arm
    from hydroarm.sim.runner import Trajectory
    from hydroarm.studies.animate import animate as render

    if not run_file.is_file():
        _fail(f"RUN_FILE '{run_file}': {not_a_file(run_file)}")
    _check_file_out(out)
    try:
        traj = Trajectory.load(run_file)
    except Exception:  # noqa: BLE001 - any unreadable file is bad input; NumPy's own words do not help here
        _fail(
            f"RUN_FILE '{run_file}': not a hydroarm trajectory (a .npz that `hydroarm run` writes as "
            "trajectory.npz, or `hydroarm reproduce` into runs/)"
        )
    try:
        arm_model = load_arm(arm) if arm else None
        out.parent.mkdir(parents=True, exist_ok=True)
        render(traj, out, arm=arm_model, fps=fps, start=start, duration=duration)
    except (ConfigError, ValueError) as error:
        _fail(str(error))
    console.print(f"wrote {out}")


@app.command()
def arms(as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
    """List the built-in arms."""
    from hydroarm.model.arm.loading import BUILTIN_ARMS, arm_description, load_arm

    rows = []
    for name in BUILTIN_ARMS:
        arm = load_arm(name)
        description = arm_description(name)
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


@app.command()
def controllers(as_json: Annotated[bool, typer.Option("--json", help="Machine-readable list.")] = False) -> None:
    """List the registered controllers (their settings sections, default estimator, whether they
    run over an observer, their GP's inputs on 6 joints) and the aliases (flagship)."""
    from hydroarm.control.registry import ALIASES, REGISTRY
    from hydroarm.sim.experiment import ExperimentConfig, gp_inputs

    rows = [
        {"name": spec.name, "sections": list(spec.sections), "estimator": spec.default_estimator,
         "observer": spec.observer, "description": spec.description,
         "gp_inputs_6_joints": (gp_inputs(spec.name, ExperimentConfig(), 6) or (None,))[0]}
        for spec in REGISTRY.values()
    ]  # fmt: skip
    if as_json:
        print(json.dumps({"controllers": rows, "aliases": ALIASES}))
        return
    table = Table(title="controllers (--controller takes the name in any case, - or _)")
    for column in ("name", "settings sections", "estimator", "observer", "description"):
        table.add_column(column)
    for row in rows:
        table.add_row(row["name"], ", ".join(row["sections"]), row["estimator"], "yes" if row["observer"] else "",
                      row["description"])  # fmt: skip
    Console().print(table)
    for alias, target in ALIASES.items():
        console.print(f"alias [bold]{alias}[/] = {target} (hydroarm's flagship: docs/controllers.md)")


@app.command("export-urdf")
def export_urdf(
    arm: Annotated[str, typer.Argument(help="Built-in arm name or arm file.")] = "paper",
    out: Annotated[Path | None, typer.Option("--out", help="File to write (default: stdout).")] = None,
) -> None:
    """Write the dry arm as URDF (links, revolute joints, inertials, cylinders).

    Example: hydroarm export-urdf paper --out paper.urdf
    """
    from hydroarm.model.arm.loading import load_arm

    try:
        from hydroarm.model.arm.urdf_export import arm_to_urdf

        text = arm_to_urdf(load_arm(arm))
    except ConfigError as error:
        _fail(str(error))
    if out is None:
        sys.stdout.write(text)
    else:
        _check_file_out(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
        console.print(f"wrote {out}")


@app.command()
def bench(
    out: Annotated[Path, typer.Option("--out", help="Output folder for bench.json and bench.md.")] = Path(
        "bench-results"
    ),
    quick: Annotated[bool, typer.Option("--quick", help="A few hundred samples (CI).")] = False,
    only: Annotated[
        str | None,
        typer.Option(
            "--only",
            help="One section alone (arm_fast, batched_env, flagship, planner, uvms): bench-<section>.json and .md.",
        ),
    ] = None,
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
    command += ["--only", only] if only else []
    try:
        code = subprocess.call(command, env=env)
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    if code != 0:
        _fail(f"the benchmark suite exited with code {code}", code=code if code > 0 else 128 - code)  # -N: signal N
    if only:
        console.print(f"wrote {out / f'bench-{only}.json'} and .md")
    else:
        console.print(f"wrote {out / 'bench.json'} and {out / 'bench.md'}")
