"""Commands of the real vehicle's logs: ``hydroarm replay`` (the vehicle's response to the logged
arm motion, against the IMU and the motion capture) and ``hydroarm calibrate`` (fit uncertain
parameters on chosen logs). Bad logs and bad settings exit with code 2 and one line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from hydroarm.cli._common import _check_file_out, _check_out, _fail, app, console
from hydroarm.config import ConfigError

LogsArgument = Annotated[
    list[Path],
    typer.Argument(
        help="Logs: <trial>_joint_states.csv files (their _imu/_mocap siblings beside), ROS 2 bags "
        "(.mcap or a bag folder), or folders of them."
    ),
]
VehicleOption = Annotated[str, typer.Option("--vehicle", help="Vehicle file (TOML/YAML) or built-in name.")]
ArmOption = Annotated[
    str, typer.Option("--arm", help="Arm: a built-in name or file; 'mount' (default): the vehicle file's.")
]
WorkersOption = Annotated[int, typer.Option("--workers", min=0, max=64, help="Parallel processes (0, 1: this one).")]


def _config(overrides: list[str], base: dict | None = None):
    """The replay settings: ``base`` (the vehicle file's ``[replay]`` table, what a calibration
    fitted), then each ``--set`` key=value over it."""
    import copy

    from hydroarm.config import validate
    from hydroarm.studies.replay import ReplayConfig

    data: dict = copy.deepcopy(base or {})
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set '{item}': expected key=value, e.g. inner_step=0.02 or cleaning.smoothing=1e-3")
        key, text = item.split("=", 1)
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        node = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return validate(ReplayConfig, data, "--set")


@app.command()
def replay(
    logs: LogsArgument,
    vehicle: VehicleOption,
    out: Annotated[Path, typer.Option("--out", help="Output folder (summary.json, <trial>/attitude.csv).")],
    arm: ArmOption = "mount",
    workers: WorkersOption = 2,
    figures: Annotated[bool, typer.Option("--figures/--no-figures", help="attitude.png per trial.")] = True,
    bag: Annotated[
        bool, typer.Option("--bag/--no-bag", help="Also <trial>/replay: a ROS 2 bag (MCAP) of the log and the run.")
    ] = False,
    settings: Annotated[
        list[str] | None, typer.Option("--set", help="Replay setting key=value (hydroarm settings).")
    ] = None,
) -> None:
    """Replay each log: the vehicle's roll and pitch under the logged arm motion, from the logged
    initial attitude and rates, against the IMU and the motion capture."""
    from hydroarm.sim.trials import find_trials
    from hydroarm.studies.outputs import dumps
    from hydroarm.studies.replay import load_vehicle_quietly, replay_many, summary, write_trial

    _check_out(out)
    try:
        spec = load_vehicle_quietly(vehicle)
        config = _config(settings or [], spec.replay)
        paths = find_trials(logs)

        def progress(done: int, total: int, name: str) -> None:
            console.print(f"[{done}/{total}] {name}")

        results = replay_many(paths, spec, arm, config, workers=workers, progress=progress)
    except ConfigError as error:
        _fail(str(error))
    except KeyboardInterrupt:
        console.print("[yellow]interrupted[/]")
        raise typer.Exit(130) from None
    out.mkdir(parents=True, exist_ok=True)
    for path, result in zip(paths, results, strict=True):
        write_trial(out, result, figures=figures)
        if bag:
            _write_run_bag(out / result.name / "replay", path, result)
    table = summary(results)
    table["vehicle"], table["arm"] = vehicle, arm
    table["settings"] = config.model_dump()
    (out / "summary.json").write_text(dumps(table, indent=1) + "\n")
    mean = table["mean"]
    console.print(
        f"wrote {out}/summary.json: {len(results)} trials, mean RMSE vs IMU pitch "
        f"{mean['pitch_rmse_imu_deg']:.2f} deg, roll {mean['roll_rmse_imu_deg']:.2f} deg "
        f"(hold: {mean['pitch_rmse_hold_deg']:.2f}, {mean['roll_rmse_hold_deg']:.2f})"
    )


def _write_run_bag(target: Path, log_path: Path, result) -> None:
    import shutil

    import pinocchio as pin

    from hydroarm.sim.rosbag import write_bag
    from hydroarm.sim.trials import load_trial

    if target.exists():
        shutil.rmtree(target)
    quaternions = [pin.Quaternion(pin.rpy.rpyToMatrix(*rpy)).coeffs() for rpy in result.simulated]
    write_bag(target, load_trial(log_path), (result.time, quaternions))


@app.command()
def calibrate(
    logs: LogsArgument,
    vehicle: VehicleOption,
    params: Annotated[
        str, typer.Option("--params", help="Comma-separated parameters, e.g. cb_x,cb_y,rotational_damping_scale.")
    ],
    out: Annotated[Path, typer.Option("--out", help="The calibrated vehicle file to write (.toml).")],
    arm: ArmOption = "mount",
    workers: WorkersOption = 2,
    settings: Annotated[
        list[str] | None, typer.Option("--set", help="Replay setting key=value (hydroarm settings).")
    ] = None,
) -> None:
    """Fit the chosen parameters of the vehicle file on the given (training) logs by least squares
    on the roll and pitch error against the IMU; write the calibrated vehicle file and, beside it,
    <out>.json (each parameter with its uncertainty, the residual)."""
    from hydroarm.sim.trials import find_trials, load_trial
    from hydroarm.studies.calibrate import calibrate as fit
    from hydroarm.studies.calibrate import (
        check_parameters,
        fitted_replay_settings,
        replay_settings_hint,
        write_calibrated_vehicle,
    )
    from hydroarm.studies.outputs import dumps
    from hydroarm.studies.replay import build_system, load_vehicle_quietly

    _check_file_out(out)
    if out.suffix != ".toml":
        _fail(f"--out {out}: the calibrated vehicle file must end in .toml")
    try:
        names = check_parameters(params.split(","))
        spec = load_vehicle_quietly(vehicle)
        config = _config(settings or [], spec.replay)
        paths = find_trials(logs)
        joint_names = tuple(build_system(spec, arm).arm.model.names[1:])
        for path in paths:
            load_trial(path, joint_names)
        result = fit(paths, spec, arm, names, config, workers=workers)
    except ConfigError as error:
        _fail(str(error))
    except KeyboardInterrupt:
        console.print("[yellow]interrupted[/]")
        raise typer.Exit(130) from None
    sources = [p.name for p in paths]
    write_calibrated_vehicle(out, spec, result, sources, build_system(spec, arm).arm, config)
    fitted = fitted_replay_settings(config, result.values)
    report = {
        "vehicle": vehicle,
        "arm": arm,
        "logs": sources,
        "parameters": {n: {"value": result.values[n], "sigma": result.uncertainty[n]} for n in result.names},
        "correlation": result.correlation,
        "replay_settings": fitted,
        "cost_deg2": result.cost,
        "initial_cost_deg2": result.initial_cost,
        "evaluations": result.evaluations,
        "seconds": result.seconds,
        "status": result.status,
    }
    out.with_suffix(".json").write_text(dumps(report, indent=1) + "\n")
    shown = ", ".join(f"{n} = {result.values[n]:.4g} +- {result.uncertainty[n]:.2g}" for n in result.names)
    console.print(
        f"wrote {out}: {shown}; cost {result.initial_cost:.3g} -> {result.cost:.3g} deg^2 "
        f"({result.evaluations} replays of {len(paths)} logs, {result.seconds:.0f} s)"
    )
    if fitted:
        console.print(
            f"the fitted replay settings are in {out}'s [replay] table: `hydroarm replay LOGS --vehicle {out}` "
            f"applies them (the same as {replay_settings_hint(fitted)})"
        )
