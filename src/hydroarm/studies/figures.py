"""Figures of a run or a comparison, one panel per joint (the paper's Figures 4-15), and
the names of a reproduction's figure files (:data:`FIGURES`, :data:`ANIMATION`).

Every function takes trajectories (:class:`hydroarm.sim.runner.Trajectory`) and a
path, writes a PNG and returns the path. Headless: figures are built on
:class:`matplotlib.figure.Figure` (:func:`subplots`), never through pyplot, so importing this
module chooses no backend and leaves the caller's alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from hydroarm.sim.runner import Trajectory


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float] | None = None, **options):
    """``(figure, axes)`` as ``pyplot.subplots`` gives them, without pyplot: the figure is not
    registered with any GUI backend and draws with Agg when saved; nothing to close."""
    figure = Figure(figsize=figsize)
    return figure, figure.subplots(nrows, ncols, **options)


COLOURS = {
    "SMC": "tab:green",
    "MPC": "tab:blue",
    "GP-MPC": "tab:red",
    "IDMPC": "tab:olive",
    "GP-IDMPC": "tab:purple",
    "GP-IDMPC+KF": "tab:purple",
    "reference": "black",
}
"""One colour per controller (and the reference), in every figure and sweep plot."""

ANIMATION = "gpmpc_arm.gif"
"""The first seconds of the clean GP-MPC run: links as cylinders, the reference ghosted."""

FIGURES = {
    "fig04_disturbance.png": "Fig. 4: true vs GP-estimated disturbance (no noise)",
    "fig05_disturbance_error.png": "Fig. 5: disturbance estimate error (no noise)",
    "fig06_disturbance_noisy.png": "Fig. 6: true vs GP-estimated disturbance (noise)",
    "fig07_disturbance_error_noisy.png": "Fig. 7: disturbance estimate error (noise)",
    "fig08_position.png": "Fig. 8: position tracking, GP-MPC (no noise)",
    "fig09_error_comparison.png": "Fig. 9: tracking error of SMC, MPC, GP-MPC and hydroarm's GP-IDMPC (no noise)",
    "fig10_velocity.png": "Fig. 10: velocity tracking, GP-MPC (no noise)",
    "fig11_torque.png": "Fig. 11: joint torques, GP-MPC (no noise)",
    "fig12_position_noisy.png": "Fig. 12: position tracking, GP-MPC (noise)",
    "fig13_velocity_noisy.png": "Fig. 13: velocity tracking, GP-MPC (noise)",
    "fig14_torque_noisy.png": "Fig. 14: joint torques, GP-MPC (noise)",
    "fig15_error_comparison_noisy.png": "Fig. 15: tracking error of SMC, MPC, GP-MPC and hydroarm's GP-IDMPC (noise)",
}


def _panels(n: int, title: str, sharex: bool = True):
    rows = (n + 1) // 2
    fig, axes = subplots(rows, 2, figsize=(11, 2.4 * rows + 0.8), sharex=sharex, squeeze=False)
    fig.suptitle(title, fontsize=12)
    flat = axes.ravel()
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def _finish(fig, axes, path: Path, xlabel: str = "time (s)") -> Path:
    for ax in axes[-2:]:
        ax.set_xlabel(xlabel)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def plot_disturbance(traj: Trajectory, path: Path, title: str) -> Path:
    """True generalised disturbance vs the controller's estimate per joint (paper Figs. 4, 6)."""
    fig, axes = _panels(traj.n_joints, title)
    for j, ax in enumerate(axes):
        ax.plot(traj.t, traj.disturbance[:, j], color="black", lw=1.2, label="true")
        ax.plot(traj.t, traj.disturbance_estimate[:, j], color="tab:red", lw=1.0, ls="--", label="GP estimate")
        ax.set_ylabel(f"joint {j + 1} (N m)")
    return _finish(fig, axes, path)


def plot_disturbance_error(traj: Trajectory, path: Path, title: str) -> Path:
    """Estimate minus truth per joint (paper Figs. 5, 7), with the GP's 2-sigma band."""
    fig, axes = _panels(traj.n_joints, title)
    error = traj.disturbance_estimate - traj.disturbance
    sigma = np.sqrt(np.maximum(traj.disturbance_var, 0.0))
    for j, ax in enumerate(axes):
        ax.plot(traj.t, error[:, j], color="tab:red", lw=1.0, label="estimate - true")
        if np.isfinite(sigma[:, j]).any():
            ax.fill_between(traj.t, -2 * sigma[:, j], 2 * sigma[:, j], color="tab:gray", alpha=0.25, label="GP 2 sigma")
        late = error[traj.t > 1.0, j]
        late = late[np.isfinite(late)]  # a controller without an estimate on this joint leaves NaN
        if late.size:
            rms = float(np.sqrt(np.mean(late**2)))
            ax.set_title(f"RMS after 1 s: {rms:.3g} N m", fontsize=8)
        ax.set_ylabel(f"joint {j + 1} (N m)")
    return _finish(fig, axes, path)


def plot_tracking(traj: Trajectory, path: Path, title: str, quantity: str = "position") -> Path:
    """Reference vs true joint positions (``quantity="position"``, rad; paper Figs. 8, 12)
    or velocities (``"velocity"``, rad/s; Figs. 10, 13)."""
    fig, axes = _panels(traj.n_joints, title)
    actual, ref, unit = (traj.q, traj.q_ref, "rad") if quantity == "position" else (traj.v, traj.v_ref, "rad/s")
    name = traj.meta.get("controller", "actual")
    for j, ax in enumerate(axes):
        ax.plot(traj.t, ref[:, j], color="black", lw=1.2, ls="--", label="reference")
        ax.plot(traj.t, actual[:, j], color=COLOURS.get(name, "tab:red"), lw=1.0, label=name)
        ax.set_ylabel(f"joint {j + 1} ({unit})")
    return _finish(fig, axes, path)


def plot_torque(traj: Trajectory, path: Path, title: str, limit: np.ndarray | None = None) -> Path:
    """Applied joint torques (paper Figs. 11, 14), each joint on its own scale: the limits are
    dotted where a joint's torque comes within half of its limit, else named in the axis label
    (a wrist's few N m are not drawn flat on +-500 N m axes)."""
    fig, axes = _panels(traj.n_joints, title)
    name = traj.meta.get("controller", "")
    for j, ax in enumerate(axes):
        ax.plot(traj.t, traj.u[:, j], color=COLOURS.get(name, "tab:red"), lw=1.0, label=name)
        label = f"joint {j + 1} (N m)"
        if limit is not None:
            peak = float(np.nanmax(np.abs(traj.u[:, j]))) if traj.u.shape[0] else 0.0
            if peak >= 0.5 * limit[j]:
                ax.axhline(limit[j], color="gray", ls=":", lw=0.8, label="limit")
                ax.axhline(-limit[j], color="gray", ls=":", lw=0.8)
            else:
                label = f"joint {j + 1} (N m; limit {limit[j]:g})"
        ax.set_ylabel(label)
    return _finish(fig, axes, path)


def plot_error_comparison(trajs: dict[str, Trajectory], path: Path, title: str) -> Path:
    """Tracking error q_r - q per joint for several controllers (paper Figs. 9, 15)."""
    first = next(iter(trajs.values()))
    fig, axes = _panels(first.n_joints, title)
    for name, traj in trajs.items():
        error = traj.q_ref - traj.q
        for j, ax in enumerate(axes):
            ax.plot(traj.t, error[:, j], color=COLOURS.get(name), lw=1.0, label=name)
    for j, ax in enumerate(axes):
        ax.set_ylabel(f"joint {j + 1} error (rad)")
        ax.axhline(0.0, color="black", lw=0.5)
    return _finish(fig, axes, path)
