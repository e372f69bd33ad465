"""Commands of the vehicle-manipulator system: ``hydroarm vehicles``, ``hydroarm study uvms``,
``hydroarm run-uvms``. Bad input (a vehicle file with a bad field, an unknown vehicle) exits
with code 2 and one line naming the field."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from hydroarm.cli._common import _check_out, _fail, app, console
from hydroarm.config import ConfigError

study_app = typer.Typer(
    help="Studies beyond the paper (the UVMS: hydroarm study uvms --out DIR).", no_args_is_help=True
)
app.add_typer(study_app, name="study")


def _vehicle_name(name: str) -> str:
    """``bluerov2-heavy`` and ``bluerov2_heavy`` both name the built-in vehicle; files pass through."""
    from hydroarm.model.vehicle import BUILTIN_VEHICLES

    key = name.replace("-", "_").lower()
    return key if key in BUILTIN_VEHICLES else name


@app.command()
def vehicles(as_json: Annotated[bool, typer.Option("--json", help="Machine-readable list.")] = False) -> None:
    """List the built-in vehicles (mass, thrusters, mounted arm)."""
    from hydroarm.model.vehicle import BUILTIN_VEHICLES, load_vehicle

    rows = []
    for name in BUILTIN_VEHICLES:
        vehicle = load_vehicle(name)
        rows.append(
            {
                "name": name.replace("_", "-"),
                "mass_kg": vehicle.mass,
                "thrusters": vehicle.n_thrusters,
                "arm": vehicle.mount_arm,
                "description": vehicle.spec.description if vehicle.spec else "",
            }
        )
    if as_json:
        typer.echo(json.dumps(rows, indent=1))
        return
    table = Table(title="built-in vehicles")
    for column in ("name", "mass (kg)", "thrusters", "arm", "description"):
        table.add_column(column)
    for row in rows:
        table.add_row(row["name"], f"{row['mass_kg']:g}", str(row["thrusters"]), row["arm"], row["description"])
    Console(soft_wrap=True).print(table)


@study_app.command("uvms")
def study_uvms(
    out: Annotated[Path, typer.Option("--out", help="Output folder (metrics.json, figures, report.md).")],
    quick: Annotated[bool, typer.Option("--quick", help="8 s runs instead of 30 s.")] = False,
    workers: Annotated[int, typer.Option("--workers", min=0, max=256, help="Parallel processes (0: this one).")] = 2,
) -> None:
    """Station keeping in a 0.2 m/s current while the Alpha 5 reaches and returns: blind vs GP
    feed-forward, PID vs MPC, and which arm effects matter."""
    from hydroarm.studies.uvms import run_uvms_study

    _check_out(out)
    try:
        metrics = run_uvms_study(out, quick=quick, workers=workers)
    except KeyboardInterrupt:
        console.print(f"[yellow]interrupted:[/] finished runs are kept in {out}/runs; run again to resume")
        raise typer.Exit(130) from None
    gains = metrics["gp_gain_percent"]
    console.print(
        f"wrote {out}/report.md: GP feed-forward cuts the drift RMS by {gains['pid']['drift_rms_m']:.0f}% (PID), "
        f"{gains['mpc']['drift_rms_m']:.0f}% (MPC); effects by drift: {', '.join(metrics['effect_ranking_by_drift'])}"
    )


@app.command("run-uvms")
def run_uvms_command(
    vehicle: Annotated[str, typer.Option("--vehicle", help="Built-in vehicle (bluerov2-heavy) or vehicle file.")] = (
        "bluerov2-heavy"
    ),
    arm: Annotated[str, typer.Option("--arm", help="Arm: 'mount' (the vehicle file's), built-in or file.")] = "mount",
    controller: Annotated[str, typer.Option("--controller", help="Vehicle controller: pid or mpc.")] = "pid",
    aware: Annotated[bool, typer.Option("--aware", help="GP feed-forward of the arm's force.")] = False,
    current: Annotated[float, typer.Option("--current", help="Current along x (m/s).")] = 0.2,
    duration: Annotated[float, typer.Option("--duration", help="Simulated time (s).")] = 10.0,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Folder for metrics.json and trajectory.npz (default: print only)."),
    ] = None,
) -> None:
    """One station-keeping run of a vehicle with its arm working; prints its metrics.

    With --out, also writes trajectory.npz: hydroarm animate DIR/trajectory.npz draws the
    vehicle with its arm. The same run as hydroarm run --vehicle.
    """
    settings = {"vehicle_controller": controller, "aware": aware, "current": current, "duration": duration}
    run_vehicle(vehicle, arm, settings, out)


def run_vehicle(vehicle: str, arm: str, settings: dict, out: Path | None) -> None:
    """The one code path of ``run-uvms`` and ``run --vehicle``: validate the vehicle, the arm and
    ``settings`` (:class:`~hydroarm.studies.uvms_run.UVMSRunConfig` fields, nested for ``plant``;
    bad input exits 2 with one line), run, print the metrics as JSON and, with ``out``, write
    ``metrics.json`` and ``trajectory.npz`` there."""
    from hydroarm.config import validate
    from hydroarm.model.uvms import build_uvms
    from hydroarm.model.vehicle import load_vehicle
    from hydroarm.studies.uvms_run import UVMSRunConfig, run_uvms, uvms_trajectory

    if out is not None:
        _check_out(out)
    name = _vehicle_name(vehicle)
    try:
        spec = load_vehicle(name)
        build_uvms(spec, arm)
        config = validate(UVMSRunConfig, {**settings, "vehicle": name, "arm": arm}, "settings")
    except ConfigError as error:
        _fail(str(error))
    except (ValueError, FileNotFoundError) as error:
        _fail(str(error).splitlines()[0])
    result = run_uvms(config)
    text = json.dumps(result.metrics, indent=1)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(text + "\n")
        uvms_trajectory(result).save(out / "trajectory.npz")
    typer.echo(text)
