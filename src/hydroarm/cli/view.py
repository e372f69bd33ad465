"""The ``view`` command: a saved run in the browser (needs the ``viewer`` extra)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Annotated

import typer

from hydroarm.cli._common import _check_file_out, _fail, app, console
from hydroarm.config import ConfigError, not_a_file

INSTALL_HINT = "the viewer needs the viewer extra: pip install 'hydroarm[viewer]'"


def _looks_like_a_trajectory(run_file: Path) -> bool:
    """A cheap check before the server starts: an .npz with a trajectory's arrays."""
    import numpy as np

    try:
        with np.load(run_file, allow_pickle=False) as archive:
            return {"t", "x", "u", "q_ref", "meta_json"} <= set(archive.files)
    except Exception:  # noqa: BLE001 - any unreadable file is bad input
        return False


def serve_run(
    run_file: Path,
    arm: str | None = None,
    port: int = 8080,
    host: str = "127.0.0.1",
    browser: bool = True,
    out: Path | None = None,
) -> None:
    """Write ``run_file`` as a shareable .html (``out``), or serve it at http://host:port until Ctrl-C.

    Serving starts the web server first and points the browser at it, then loads the run, the
    arm and the scene: the page loads while they do (what a user waits for is the arm drawn)."""
    try:
        import viser
    except ImportError:
        _fail(INSTALL_HINT)
    if not run_file.is_file():
        _fail(f"RUN_FILE '{run_file}': {not_a_file(run_file)}")
    if out is not None:
        _check_file_out(out)
        out.parent.mkdir(parents=True, exist_ok=True)
    not_a_run = f"RUN_FILE '{run_file}': not a hydroarm trajectory (a .npz from run, reproduce or sweep --trajectories)"
    if not _looks_like_a_trajectory(run_file):
        _fail(not_a_run)
    server = None
    if out is None:
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # viser's own banner: the line below says it
                server = viser.ViserServer(host=host, port=port, label="hydroarm", verbose=False)
        except OSError as error:
            _fail(f"cannot serve on {host}:{port}: {error}")
        url = f"http://{host}:{server.get_port()}"
        console.print(f"viewer at {url} (Ctrl-C to stop)")
        if browser:
            import webbrowser

            webbrowser.open(url)
    try:
        from hydroarm.model.arm.loading import load_arm
        from hydroarm.sim.runner import Trajectory
        from hydroarm.studies import viewer as browser_viewer

        try:
            traj = Trajectory.load(run_file)
        except Exception:  # noqa: BLE001 - any unreadable file is bad input
            raise ConfigError(not_a_run) from None
        arm_model = load_arm(arm) if arm else None
        if server is None:
            browser_viewer.write_html(traj, out, arm=arm_model)
            console.print(f"wrote {out} (open it in a browser; no server needed)")
            return
        viewer = browser_viewer.TrajectoryViewer(traj, arm=arm_model, host=host, port=port, server=server)
    except (ConfigError, ValueError) as error:
        if server is not None:
            server.stop()
        _fail(str(error))
    browser_viewer.serve_until_interrupted(viewer)


@app.command("view")
def view_command(
    run_file: Annotated[Path, typer.Argument(help="A trajectory .npz (from run, reproduce or sweep --trajectories).")],
    port: Annotated[int, typer.Option("--port", min=1, max=65535, help="Port of the local web server.")] = 8080,
    host: Annotated[str, typer.Option("--host", help="Address to serve on (default: this machine only).")] = (
        "127.0.0.1"
    ),
    no_browser: Annotated[bool, typer.Option("--no-browser", help="Serve only; do not open a browser.")] = False,
    out: Annotated[
        Path | None, typer.Option("--out", help="Write a self-contained .html recording instead of serving.")
    ] = None,
    arm: Annotated[str | None, typer.Option("--arm", help="Arm of the run (default: from the file).")] = None,
) -> None:
    """Show a saved run in the browser: the arm in 3-D, its reference ghosted, a time slider, the time series.

    Example: hydroarm view run/trajectory.npz --port 8080
    """
    serve_run(run_file, arm=arm, port=port, host=host, browser=not no_browser, out=out)
