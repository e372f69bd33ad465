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
    _check_out,
    _experiment_config,
    _fail,
    app,
    console,
)
from hydroarm.config import ConfigError


@app.command()
def run(
    ctx: typer.Context,
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
    tuned: TunedOption = False,
    overrides: SetOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
    overwrite: OverwriteOption = False,
    view: Annotated[
        bool, typer.Option("--view", help="Then open the run in the browser viewer (the viewer extra).")
    ] = False,
    model: Annotated[
        Path | None,
        typer.Option("--model", help="PI-IDMPC: start from the water model saved in this file (JSON)."),
    ] = None,
    save_model: Annotated[
        Path | None,
        typer.Option("--save-model", help="PI-IDMPC: save the water model learned by the run to this file (JSON)."),
    ] = None,
    vehicle: Annotated[
        str | None,
        typer.Option(
            "--vehicle",
            help="Mount the arm on this vehicle (bluerov2-heavy or a vehicle file): the run of hydroarm run-uvms.",
        ),
    ] = None,
) -> None:
    """Run one experiment and write its trajectory, metrics and figures.

    A folder that holds the results of other settings is refused unless --overwrite.
    --view serves the saved run in the browser as soon as it is written (hydroarm view).
    Example: hydroarm run --controller gp-mpc --arm paper --noise 0.001 --seed 3 --out DIR

    With --vehicle, the vehicle-manipulator run of hydroarm run-uvms: --controller is the
    vehicle's (pid or mpc, default pid), --arm defaults to the vehicle file's, --set sets the
    run's settings (duration, current, aware, ...); writes metrics.json and trajectory.npz.
    Example: hydroarm run --vehicle bluerov2-heavy --arm alpha5 --set duration=5 --out DIR
    """
    if vehicle is not None:
        _run_on_vehicle(ctx, vehicle, controller, arm, out, overrides or [])
        return
    from hydroarm.model.loading import load_arm
    from hydroarm.studies import figures
    from hydroarm.studies.experiment import build_experiment, canonical_name, check_settings_for_arm, with_overrides
    from hydroarm.studies.outputs import claim_output, dumps
    from hydroarm.studies.runner import tracking_metrics

    try:
        name = canonical_name(controller)
    except ConfigError as error:
        _fail(f"--{error}")
    if (model is not None or save_model is not None) and name != "PI-IDMPC":
        _fail(f"--model / --save-model: only PI-IDMPC has a water model to load or save (controller {name})")
    if model is not None and not model.is_file():
        _fail(f"--model '{model}': no such file")
    _check_out(out)
    try:
        config = _experiment_config(config_file, overrides or [], tuned, arm)
        options = {"arm": arm, "plant.noise_variance": noise}
        config = with_overrides(config, {key: value for key, value in options.items() if value is not None})
        arm_model = load_arm(config.arm)
        check_settings_for_arm(config, arm_model, controllers=(name,))
        what = {"experiment": config.model_dump(mode="json"), "controller": name, "seed": seed}
        made_by = f"hydroarm run --controller {name.lower()} --seed {seed} --arm {config.arm}"
        claim_output(out, "run", what, description=made_by, overwrite=overwrite)
    except ConfigError as error:
        _fail(str(error))
    with Progress(
        TextColumn(name), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
    ) as progress:
        task = progress.add_task(name, total=int(round(config.duration / config.control_period)))
        experiment = build_experiment(config, name, arm=arm_model)
        learner = experiment.controller
        while model is not None or save_model is not None:  # PI-IDMPC, behind its Kalman filter
            if hasattr(learner, "load_model"):
                break
            learner = learner.controller
        if model is not None:
            try:
                learner.load_model(model)
            except ConfigError as error:
                progress.stop()
                _fail(str(error))
        traj = experiment.run(seed, progress=lambda k, total: progress.update(task, completed=k))
    if save_model is not None:
        learner.save_model(save_model)
        traj.meta["model_saved"] = str(save_model)
    traj.save(out / "trajectory.npz")
    metrics = tracking_metrics(traj)
    (out / "metrics.json").write_text(dumps(metrics, indent=1))
    figures.plot_tracking(traj, out / "position.png", f"{name}: position tracking", "position")
    figures.plot_tracking(traj, out / "velocity.png", f"{name}: velocity tracking", "velocity")
    figures.plot_torque(traj, out / "torque.png", f"{name}: joint torques", arm_model.torque_limit)
    if name == "GP-MPC":
        figures.plot_disturbance(traj, out / "disturbance.png", "true vs GP-estimated disturbance")
    if as_json:
        print(dumps(metrics))
    else:
        console.print(f"E_p per joint (rad^2): {[round(x, 5) for x in metrics['Ep']]}; files in {out}")
    if view:
        from hydroarm.cli.view import serve_run

        serve_run(out / "trajectory.npz")
    if traj.diverged:
        raise typer.Exit(1)


def _run_on_vehicle(
    ctx: typer.Context, vehicle: str, controller: str, arm: str | None, out: Path, overrides: list[str]
) -> None:
    """``run --vehicle``: the options of ``run`` mapped onto ``run-uvms``'s run (one code path,
    :func:`hydroarm.cli.vehicles.run_vehicle`); options that mean nothing there exit 2."""
    from hydroarm.cli._common import _parse_value
    from hydroarm.cli.vehicles import run_vehicle

    def given(param: str) -> bool:  # on the command line (Typer's own click: compare by name)
        source = ctx.get_parameter_source(param)
        return source is not None and source.name != "DEFAULT"

    for param in ("noise", "seed", "config_file", "tuned", "view", "overwrite"):
        if given(param):
            flag = "--config" if param == "config_file" else f"--{param}"
            _fail(f"{flag} does not apply with --vehicle (set the vehicle run with --set KEY=VALUE)")
    settings: dict = {}
    if given("controller"):
        if controller.lower() not in ("pid", "mpc"):
            _fail(f"--controller '{controller}': with --vehicle, the vehicle's controller: pid or mpc")
        settings["vehicle_controller"] = controller.lower()
    for item in overrides:
        if "=" not in item:
            _fail(f"--set '{item}': expected key=value, e.g. duration=5")
        key, value = item.split("=", 1)
        *parents, last = key.strip().split(".")
        target = settings
        for part in parents:
            target = target.setdefault(part, {})
            if not isinstance(target, dict):
                _fail(f"--set '{item}': '{part}' is not a section")
        target[last] = _parse_value(value.strip())
    run_vehicle(vehicle, arm or "mount", settings, out)


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
    except Exception:  # noqa: BLE001 - any unreadable file is bad input; NumPy's own words do not help here
        _fail(
            f"RUN_FILE '{run_file}': not a hydroarm trajectory (a .npz that `hydroarm run` writes as "
            "trajectory.npz, or `hydroarm reproduce` into runs/)"
        )
    try:
        arm_model = load_arm(arm) if arm else None
        render(traj, out, arm=arm_model, fps=fps, start=start, duration=duration)
    except (ConfigError, ValueError) as error:
        _fail(str(error))
    console.print(f"wrote {out}")


@app.command()
def arms(as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
    """List the built-in arms."""
    from hydroarm.model.loading import BUILTIN_ARMS, arm_description, load_arm

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
def controllers(as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
    """List the registered controllers, their settings sections and the aliases (flagship)."""
    from hydroarm.control.registry import ALIASES, REGISTRY

    rows = [
        {"name": spec.name, "sections": list(spec.sections), "estimator": spec.default_estimator,
         "observer": spec.observer, "description": spec.description}
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
        console.print(f"alias [bold]{alias}[/] = {target} (hydroarm's best controller)")


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
