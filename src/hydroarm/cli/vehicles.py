"""Commands of the vehicle-manipulator system: ``hydroarm vehicles``, ``hydroarm study uvms``
(one run on a vehicle is ``hydroarm run --vehicle``). Bad input (a vehicle file with a bad
field, an unknown vehicle) exits with code 2 and one line naming the field."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from hydroarm.cli._common import _check_out, app, console

study_app = typer.Typer(
    help="Studies beyond the paper (the UVMS: hydroarm study uvms --out DIR).", no_args_is_help=True
)
app.add_typer(study_app, name="study")


@app.command()
def vehicles(as_json: Annotated[bool, typer.Option("--json", help="Machine-readable list.")] = False) -> None:
    """List the built-in vehicles (mass, thrusters, mounted arm)."""
    from hydroarm.model.vehicle.description import BUILTIN_VEHICLES, load_vehicle

    rows = []
    for name in BUILTIN_VEHICLES:
        vehicle = load_vehicle(name)
        rows.append(
            {
                "name": name,
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
    from hydroarm.studies.vehicle_study import run_vehicle_study

    _check_out(out)
    try:
        metrics = run_vehicle_study(out, quick=quick, workers=workers)
    except KeyboardInterrupt:
        console.print(f"[yellow]interrupted:[/] finished runs are kept in {out}/runs; run again to resume")
        raise typer.Exit(130) from None
    gains = metrics["gp_gain_percent"]
    console.print(
        f"wrote {out}/report.md: GP feed-forward cuts the drift RMS by {gains['pid']['drift_rms_m']:.0f}% (PID), "
        f"{gains['mpc']['drift_rms_m']:.0f}% (MPC); effects by drift: {', '.join(metrics['effect_ranking_by_drift'])}"
    )
