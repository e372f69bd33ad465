"""Show the arm moving: a saved trajectory rendered as a GIF (or MP4), headless.

Each wetted cylinder of the arm is drawn as a solid tube at its true diameter
(thin ones widened to stay visible) following the true joint angles ``q``;
the reference pose ``q_r`` is drawn the same way, ghosted (grey,
transparent). A corner shows the time and the tracking error ``|q_r - q|``
(Euclidean norm over the joints, rad). The axes are fixed from the arm's
reach, so the camera never moves. Matplotlib 3-D on the Agg backend, frames
written with Pillow (GIF) or ffmpeg (MP4, when installed): no display needed.

A vehicle-manipulator run (``hydroarm run --vehicle``:
``meta["vehicle"]`` and ``extra["base_pose"]``) is drawn with the vehicle: its
hull box (the vehicle file's ``[hull]``) at the base pose of each sample, the
arm mounted under it; the axes are centred on the station-keeping target
(marked by the cross), so the camera still never moves and the drift shows.

    from hydroarm.studies.animate import animate
    animate("run.npz", "arm.gif")                    # arm from the run's meta["arm"]
    animate(traj, "arm.gif", arm="paper", fps=10, duration=4.0)
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib import animation
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from hydroarm.config import ConfigError
from hydroarm.model.arm.description import Arm
from hydroarm.sim.runner import Trajectory
from hydroarm.studies.playback import VehicleMotion, as_arm, as_trajectory, reach, vehicle_motion

SIDES = 10  # facets per tube
HULL_COLOUR = (1.0, 0.78, 0.05, 0.5)  # translucent amber: no link's colour
HULL_FACES = ((0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5))
LINK_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive")


def _hull_faces(vehicle: VehicleMotion, pose: np.ndarray) -> list[np.ndarray]:
    """The six faces of the hull box at ``pose``."""
    corners = vehicle.corners(pose)
    return [corners[list(face)] for face in HULL_FACES]


def _tube(start: np.ndarray, end: np.ndarray, radius: float, ring: np.ndarray) -> list[np.ndarray]:
    """Side facets (quads) of a tube from ``start`` to ``end``."""
    axis = end - start
    length = np.linalg.norm(axis)
    if length <= 0.0:
        return []
    axis = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    circle = radius * (np.outer(ring[:, 0], u) + np.outer(ring[:, 1], w))  # (SIDES + 1, 3)
    bottom, top = start + circle, end + circle
    return [np.array([bottom[k], bottom[k + 1], top[k + 1], top[k]]) for k in range(SIDES)]


class _Scene:
    """The figure and the artists of one animation."""

    def __init__(
        self,
        arm: Arm,
        traj: Trajectory,
        extent: float,
        size: tuple[float, float],
        title: str,
        vehicle: VehicleMotion | None = None,
    ):
        self.arm = arm
        self.vehicle = vehicle
        cx, cy, cz = (0.0, 0.0, 0.0) if vehicle is None else vehicle.target
        self.fig = Figure(figsize=size)
        FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0.0, 0.0, 1.0, 0.93), projection="3d")
        ax = self.ax
        ax.set_xlim(cx - extent, cx + extent)
        ax.set_ylim(cy - extent, cy + extent)
        ax.set_zlim(cz - extent, cz + extent)
        ax.set_box_aspect((1.0, 1.0, 1.0), zoom=1.1)
        ax.view_init(elev=22.0, azim=-55.0)
        ax.set_xlabel("x (m)", fontsize=7, labelpad=-6)
        ax.set_ylabel("y (m)", fontsize=7, labelpad=-6)
        ax.set_zlabel("z (m)", fontsize=7, labelpad=-6)
        ax.tick_params(labelsize=6, pad=-2)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(4))
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_pane_color((0.95, 0.97, 1.0, 1.0))
        # base marker (a vehicle's station-keeping target): a small cross on the base plane
        ax.plot([cx - 0.08 * extent, cx + 0.08 * extent], [cy, cy], [cz, cz], color="black", lw=1.0)
        ax.plot([cx, cx], [cy - 0.08 * extent, cy + 0.08 * extent], [cz, cz], color="black", lw=1.0)
        self.ring = np.column_stack(
            [np.cos(np.linspace(0.0, 2.0 * math.pi, SIDES + 1)), np.sin(np.linspace(0.0, 2.0 * math.pi, SIDES + 1))]
        )
        thinnest = 0.012 * extent
        self.radii = [max(c.diameter / 2.0, thinnest) for c in arm.cylinders]
        colours = [
            LINK_COLOURS[(c.joint_id - 1) % len(LINK_COLOURS)] if c.joint_id > 0 else "dimgray" for c in arm.cylinders
        ]
        self.ghost = Poly3DCollection(
            [], facecolors=(0.5, 0.5, 0.5, 0.28), edgecolors=(0.35, 0.35, 0.35, 0.25), linewidths=0.3
        )
        self.solid = Poly3DCollection([], linewidths=0.2, edgecolors=(0.1, 0.1, 0.1, 0.35))
        self.colours = colours
        ax.add_collection3d(self.ghost)
        ax.add_collection3d(self.solid)
        (self.ghost_joints,) = ax.plot([], [], [], "o", color="gray", ms=2.5, alpha=0.4)
        (self.joints,) = ax.plot([], [], [], "o", color="black", ms=3.0)
        self.fig.text(0.5, 0.97, title, ha="center", va="center", fontsize=9)
        self.clock = self.fig.text(0.02, 0.93, "", fontsize=8, family="monospace", va="top")
        handles = [
            Line2D([], [], color="tab:blue", lw=5, label="arm, true q (colour: link)"),
            Line2D([], [], color=(0.55, 0.55, 0.55, 0.5), lw=5, label="reference q_r"),
        ]
        if vehicle is not None:
            handles.append(Line2D([], [], color=HULL_COLOUR, lw=5, label=f"{vehicle.name} hull"))
        self.fig.legend(
            handles=handles,
            loc="upper right",
            bbox_to_anchor=(0.99, 0.95),
            fontsize=7,
            frameon=False,
        )

    def _polygons(self, q: np.ndarray, pose: np.ndarray | None = None) -> tuple[list[np.ndarray], list, np.ndarray]:
        """The arm's tube facets, their colours and the joint origins; on a vehicle, placed by the
        base ``pose`` and the mount, with the hull's faces (one collection: depth-sorted together)."""
        ends = self.arm.cylinder_endpoints(q)
        joints = np.array([p.translation for p in self.arm.joint_placements(q)])
        polygons, colours = [], []
        if pose is not None:
            rotation, origin = self.vehicle.arm_frame(pose)
            ends, joints = ends @ rotation.T + origin, joints @ rotation.T + origin
        for (start, end), radius, colour in zip(ends, self.radii, self.colours, strict=True):
            facets = _tube(start, end, radius, self.ring)
            polygons += facets
            colours += [colour] * len(facets)
        return polygons, colours, joints

    def update(self, t: float, q: np.ndarray, q_ref: np.ndarray, pose: np.ndarray | None = None) -> None:
        polygons, _, ghost_joints = self._polygons(q_ref, pose)
        self.ghost.set_verts(polygons)
        polygons, colours, joints = self._polygons(q, pose)
        text = f"t = {t:5.2f} s\n|q_r - q| = {float(np.linalg.norm(q_ref - q)):6.3f} rad"
        if pose is not None:
            hull = _hull_faces(self.vehicle, pose)
            polygons, colours = polygons + hull, colours + [HULL_COLOUR] * len(hull)
            text += f"\ndrift = {float(np.linalg.norm(pose[:3] - self.vehicle.target)):6.3f} m"
        self.solid.set_verts(polygons)
        self.solid.set_facecolor(colours)
        self.joints.set_data_3d(joints[:, 0], joints[:, 1], joints[:, 2])
        self.ghost_joints.set_data_3d(ghost_joints[:, 0], ghost_joints[:, 1], ghost_joints[:, 2])
        self.clock.set_text(text)


def _frames(traj: Trajectory, fps: float, stride: int | None, start: float, duration: float | None) -> np.ndarray:
    steps = len(traj.t)
    if steps == 0:
        raise ConfigError("the trajectory is empty")
    period = float(traj.t[1] - traj.t[0]) if steps > 1 else 1.0 / fps
    if stride is None:
        stride = max(1, int(round(1.0 / (fps * period))))
    if stride < 1:
        raise ConfigError(f"stride must be >= 1, got {stride}")
    end = traj.t[-1] + 0.5 * period if duration is None else start + duration
    chosen = np.flatnonzero((traj.t >= start - 1e-12) & (traj.t < end - 1e-12))
    return chosen[::stride]


def _title(arm: Arm, traj: Trajectory, title: str | None, vehicle: VehicleMotion | None = None) -> str:
    if title is not None:
        return title
    controller = traj.meta.get("controller", "")
    name = arm.name if vehicle is None else f"{vehicle.name} + {arm.name}"
    return f"{name}: {controller}".rstrip(": ")


def _scene(
    traj: Trajectory, arm: Arm, frames: np.ndarray, size, title: str | None
) -> tuple[_Scene, VehicleMotion | None]:
    """The scene of ``frames`` (sample indices): axes fixed from the arm's reach (and the vehicle's drift)."""
    vehicle = vehicle_motion(traj)
    configurations = np.concatenate([traj.q[frames], traj.q_ref[frames]])
    extent = reach(arm, configurations) if vehicle is None else vehicle.extent(arm, frames, configurations)
    return _Scene(arm, traj, extent, size, _title(arm, traj, title, vehicle), vehicle), vehicle


def _draw(scene: _Scene, vehicle: VehicleMotion | None, traj: Trajectory, k: int) -> None:
    scene.update(float(traj.t[k]), traj.q[k], traj.q_ref[k], None if vehicle is None else vehicle.poses[k])


def animate(
    trajectory: Trajectory | str | Path,
    out_path: str | Path,
    arm: Arm | str | Path | None = None,
    fps: float = 10.0,
    stride: int | None = None,
    start: float = 0.0,
    duration: float | None = None,
    dpi: int = 80,
    size: tuple[float, float] = (5.0, 4.4),
    title: str | None = None,
) -> Path:
    """Render ``trajectory`` (a :class:`Trajectory` or its ``.npz``) to ``out_path`` (.gif or .mp4).

    ``arm``: the run's arm (an :class:`Arm`, a name or file; default the
    trajectory's ``meta["arm"]``, else ``"paper"``). ``fps``: frames per second
    of the movie; ``stride``: control steps per frame (default: real time at
    ``fps``); ``start``/``duration`` (s) choose the window. Returns the path.
    """
    traj = as_trajectory(trajectory)
    the_arm = as_arm(arm, traj)
    out_path = Path(out_path)
    suffix = out_path.suffix.lower()
    if suffix == ".gif":
        writer = animation.PillowWriter(fps=fps)
    elif suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ConfigError(f"{out_path}: .mp4 needs ffmpeg on the PATH; write a .gif instead")
        writer = animation.FFMpegWriter(fps=fps, codec="libx264", extra_args=["-pix_fmt", "yuv420p"])
    else:
        raise ConfigError(f"{out_path}: unknown movie format '{suffix}' (use .gif or .mp4)")
    frames = _frames(traj, fps, stride, start, duration)
    if frames.size == 0:
        raise ConfigError(f"no trajectory samples in [{start}, {start + (duration or 0.0)}) s")
    scene, vehicle = _scene(traj, the_arm, frames, size, title)
    tmp = out_path.with_name(out_path.stem + ".tmp" + out_path.suffix)
    with writer.saving(scene.fig, str(tmp), dpi):
        for k in frames:
            _draw(scene, vehicle, traj, int(k))
            writer.grab_frame()
    tmp.replace(out_path)
    return out_path


def render_frame(
    trajectory: Trajectory | str | Path,
    out_png: str | Path,
    time: float = 0.0,
    arm: Arm | str | Path | None = None,
    dpi: int = 100,
    size: tuple[float, float] = (5.0, 4.4),
    title: str | None = None,
) -> Path:
    """One frame (the sample nearest ``time`` s) as a PNG, drawn exactly as :func:`animate` draws it."""
    traj = as_trajectory(trajectory)
    the_arm = as_arm(arm, traj)
    k = int(np.argmin(np.abs(traj.t - time)))
    scene, vehicle = _scene(traj, the_arm, np.array([k]), size, title)
    _draw(scene, vehicle, traj, k)
    out_png = Path(out_png)
    scene.fig.savefig(out_png, dpi=dpi)
    return out_png
