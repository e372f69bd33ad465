"""See a run in the browser: the arm in 3-D with its reference ghosted, a time slider, the time series.

Built on viser (the ``viewer`` extra; ``docs/viewer.md`` says why viser and not Rerun or
MeshCat): a local web server whose page (three.js, bundled in the wheel, nothing fetched
from the internet) shows

* every wetted cylinder of the arm at its true diameter (thin ones widened to stay
  visible), following the true joint angles ``q``, coloured by link as
  :mod:`hydroarm.studies.animate` colours them; the reference pose ``q_r`` as a grey,
  transparent ghost;
* a time slider and a play/pause button (real time; a speed setting);
* the time series a user compares: the joint errors ``q_r - q``, the torque of one joint
  against its limit, and the true disturbance against the GP's estimate with its
  +-2 sigma band (the joint is chosen in a dropdown).

:func:`write_html` writes the shareable recording: one self-contained ``.html`` (viser's
client and the recorded scene, played back with its own timeline and play button; the
time series are in the live viewer only).

    from hydroarm.studies.viewer import TrajectoryViewer, write_html
    viewer = TrajectoryViewer("run.npz", port=8080)   # http://127.0.0.1:8080
    write_html("run.npz", "run.html")
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import viser

from hydroarm.model.arm import Arm
from hydroarm.sim.runner import Trajectory
from hydroarm.studies.playback import as_arm, as_trajectory, reach

# tab10 (the colours of animate.LINK_COLOURS), RGB 0-255
LINK_RGB = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
    (148, 103, 189), (140, 86, 75), (227, 119, 194), (188, 189, 34),
)  # fmt: skip
BASE_RGB = (105, 105, 105)
GHOST_RGB = (150, 150, 150)
GHOST_OPACITY = 0.3
ELEVATION, AZIMUTH = math.radians(22.0), math.radians(-55.0)  # as animate's camera
FOV = math.radians(50.0)  # vertical field of view of the camera


@dataclass(frozen=True)
class Camera:
    """A three.js perspective camera: ``position`` and ``look_at`` (m, world), vertical ``fov`` (rad), +z up."""

    position: np.ndarray
    look_at: np.ndarray
    fov: float = FOV

    def project(self, points: np.ndarray, width: float, height: float) -> np.ndarray:
        """Pixel coordinates (x right, y down) of world ``points`` (..., 3) on a ``width`` x ``height`` canvas."""
        forward = self.look_at - self.position
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        rel = np.asarray(points, dtype=float) - self.position
        depth = rel @ forward
        scale = 1.0 / math.tan(self.fov / 2.0)
        ndc_x = scale * (rel @ right) / depth / (width / height)
        ndc_y = scale * (rel @ up) / depth
        return np.stack([(ndc_x + 1.0) / 2.0 * width, (1.0 - ndc_y) / 2.0 * height], axis=-1)


def camera_for(extent: float) -> Camera:
    """The fixed camera that frames a sphere of radius ``extent`` (m) round the base, seen as animate sees it."""
    direction = np.array(
        [math.cos(ELEVATION) * math.cos(AZIMUTH), math.cos(ELEVATION) * math.sin(AZIMUTH), math.sin(ELEVATION)]
    )
    distance = 0.9 * extent / math.sin(FOV / 2.0)
    return Camera(position=distance * direction, look_at=np.zeros(3))


def cylinder_poses(arm: Arm, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoints (C, 3), orientations ``wxyz`` (C, 4) taking +z to each axis and lengths (C,) of the cylinders."""
    ends = arm.cylinder_endpoints(q)
    axis = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(axis, axis=1)
    unit = axis / np.where(length > 0.0, length, 1.0)[:, None]
    unit[length <= 0.0] = (0.0, 0.0, 1.0)
    # the shortest rotation from +z to unit: q = (1 + z.u, z x u), normalised
    w = 1.0 + unit[:, 2]
    xyz = np.stack([-unit[:, 1], unit[:, 0], np.zeros(len(unit))], axis=1)
    wxyz = np.column_stack([w, xyz])
    flipped = w < 1e-9  # unit = -z: half a turn about x
    wxyz[flipped] = (0.0, 1.0, 0.0, 0.0)
    wxyz /= np.linalg.norm(wxyz, axis=1, keepdims=True)
    return 0.5 * (ends[:, 0] + ends[:, 1]), wxyz, length


def link_colour(arm: Arm, index: int) -> tuple[int, int, int]:
    """The RGB colour (0-255) of cylinder ``index``: its link's tab10 colour, the base grey."""
    joint = arm.cylinders[index].joint_id
    return LINK_RGB[(joint - 1) % len(LINK_RGB)] if joint > 0 else BASE_RGB


class ArmScene:
    """The arm's cylinders (solid, following ``q``) and their ghost (following ``q_r``) in a viser scene."""

    def __init__(self, server: viser.ViserServer, arm: Arm, extent: float):
        self.arm = arm
        self.camera = camera_for(extent)
        scene = server.scene
        scene.set_up_direction("+z")
        # plain lights, no shadows, no HDR environment map: a software-rendered (no GPU) browser
        # draws the first frame several times faster (bench: docs/bench.md, "Browser viewer")
        scene.configure_environment_map(hdri=None)
        scene.configure_default_lights(enabled=True, cast_shadow=False)
        server.initial_camera.position = tuple(self.camera.position)
        server.initial_camera.look_at = tuple(self.camera.look_at)
        server.initial_camera.fov = self.camera.fov
        scene.add_grid("/floor", width=2.0 * extent, height=2.0 * extent, cell_size=extent / 5.0)
        thinnest = 0.012 * extent
        radii = [max(c.diameter / 2.0, thinnest) for c in arm.cylinders]
        _, _, lengths = cylinder_poses(arm, np.zeros(arm.n_joints))
        self.solid, self.ghost = [], []
        for index, (radius, length) in enumerate(zip(radii, lengths)):
            self.ghost.append(
                scene.add_cylinder(
                    f"/reference/cylinder_{index}",
                    radius=radius * 1.02,
                    height=max(float(length), 1e-6),
                    color=GHOST_RGB,
                    opacity=GHOST_OPACITY,
                    radial_segments=24,
                )
            )
            self.solid.append(
                scene.add_cylinder(
                    f"/arm/cylinder_{index}",
                    radius=radius,
                    height=max(float(length), 1e-6),
                    color=link_colour(arm, index),
                    radial_segments=24,
                )
            )

    def show(self, q: np.ndarray, q_ref: np.ndarray) -> None:
        """Move the arm to ``q`` and the ghost to ``q_ref``."""
        for handles, angles in ((self.solid, q), (self.ghost, q_ref)):
            centres, wxyz, _ = cylinder_poses(self.arm, angles)
            for handle, centre, rotation in zip(handles, centres, wxyz):
                handle.position = tuple(centre)
                handle.wxyz = tuple(rotation)


def _series(label: str, colour: str, **extra) -> dict:
    return {"label": label, "stroke": colour, "width": 1.5, **extra}


class TrajectoryViewer:
    """Serve ``trajectory`` (a :class:`Trajectory` or its ``.npz``) at ``http://host:port``.

    ``arm``: the run's arm (default: the trajectory's ``meta["arm"]``). The server runs in
    background threads until :meth:`stop`; ``url`` is the page's address. ``server``: an
    already-started viser server to fill (``host`` and ``port`` then only name it): a browser
    may load the page while the run and the arm are still loading; the scene follows.
    """

    def __init__(
        self,
        trajectory: Trajectory | str | Path,
        arm: Arm | str | Path | None = None,
        host: str = "127.0.0.1",
        port: int = 8080,
        verbose: bool = False,
        server: viser.ViserServer | None = None,
    ):
        self.traj = as_trajectory(trajectory)
        self.arm = as_arm(arm, self.traj)
        traj = self.traj
        if server is None:
            server = viser.ViserServer(host=host, port=port, label="hydroarm", verbose=verbose)
        self.server = server
        self.url = f"http://{host}:{self.server.get_port()}"
        gui = self.server.gui
        gui.configure_theme(control_layout="fixed", control_width="large", show_share_button=False)
        self.scene = ArmScene(self.server, self.arm, reach(self.arm, np.concatenate([traj.q, traj.q_ref])))
        controller = traj.meta.get("controller", "")
        gui.add_markdown(f"**{self.arm.name}**: {controller}, {len(traj.t)} steps")
        period = float(traj.t[1] - traj.t[0]) if len(traj.t) > 1 else 0.01
        self.slider = gui.add_slider(
            "t (s)", min=float(traj.t[0]), max=float(traj.t[-1]), step=period, initial_value=0.0
        )
        self.play = gui.add_button("play / pause")
        self.speed = gui.add_slider("speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
        self.error_text = gui.add_markdown("")
        self.playing = False
        self._lock = threading.Lock()
        self.slider.on_update(lambda _: self.show_time(self.slider.value))
        self.play.on_click(lambda _: self.toggle())
        self._plots()
        self.show_time(0.0)
        self._stop = threading.Event()
        self._player = threading.Thread(target=self._run_player, daemon=True)
        self._player.start()

    def _plots(self) -> None:
        traj, gui, n = self.traj, self.server.gui, self.arm.n_joints
        t = np.ascontiguousarray(traj.t)
        error = traj.q_ref - traj.q
        colours = [f"rgb{c}" for c in LINK_RGB]
        gui.add_uplot(
            data=(t, *[np.ascontiguousarray(error[:, j]) for j in range(n)]),
            series=({"label": "t (s)"}, *[_series(f"joint {j + 1}", colours[j % 8]) for j in range(n)]),
            title="joint error q_r - q (rad)",
            scales={"x": {"time": False}},
            aspect=1.6,
        )
        self.joint = gui.add_dropdown("joint", options=[str(j + 1) for j in range(n)], initial_value="1")
        self.torque_plot = gui.add_uplot(
            data=self._torque_data(0),
            series=(
                {"label": "t (s)"},
                _series("torque", "rgb(31,119,180)"),
                _series("+limit", "rgb(214,39,40)", dash=[4, 4]),
                _series("-limit", "rgb(214,39,40)", dash=[4, 4]),
            ),
            title="torque u (N m) against its limit",
            scales={"x": {"time": False}},
            aspect=1.6,
        )
        self.disturbance_plot = gui.add_uplot(
            data=self._disturbance_data(0),
            series=(
                {"label": "t (s)"},
                _series("true", "rgb(0,0,0)"),
                _series("GP estimate", "rgb(255,127,14)"),
                _series("+2 sigma", "rgba(255,127,14,0.4)", width=0.5),
                _series("-2 sigma", "rgba(255,127,14,0.4)", width=0.5),
            ),
            bands=({"series": (3, 4), "fill": "rgba(255,127,14,0.15)"},),
            title="disturbance (N m): true vs GP",
            scales={"x": {"time": False}},
            aspect=1.6,
        )
        self.joint.on_update(lambda _: self._choose_joint(int(self.joint.value) - 1))

    def _torque_data(self, j: int) -> tuple[np.ndarray, ...]:
        u = np.ascontiguousarray(self.traj.u[:, j])
        limit = np.full_like(u, float(self.arm.torque_limit[j]))
        return (np.ascontiguousarray(self.traj.t), u, limit, -limit)

    def _disturbance_data(self, j: int) -> tuple[np.ndarray, ...]:
        traj = self.traj
        mean = np.ascontiguousarray(traj.disturbance_estimate[:, j])
        sigma = np.sqrt(np.maximum(traj.disturbance_var[:, j], 0.0))
        true = np.ascontiguousarray(traj.disturbance[:, j])
        return (np.ascontiguousarray(traj.t), true, mean, mean + 2.0 * sigma, mean - 2.0 * sigma)

    def _choose_joint(self, j: int) -> None:
        self.torque_plot.data = self._torque_data(j)
        self.disturbance_plot.data = self._disturbance_data(j)

    def index(self, time_s: float) -> int:
        """The sample nearest ``time_s`` (s)."""
        return int(np.argmin(np.abs(self.traj.t - time_s)))

    def show_time(self, time_s: float) -> None:
        """Draw the arm and its reference at the sample nearest ``time_s``."""
        k = self.index(time_s)
        with self._lock, self.server.atomic():
            self.scene.show(self.traj.q[k], self.traj.q_ref[k])
            error = float(np.linalg.norm(self.traj.q_ref[k] - self.traj.q[k]))
            self.error_text.content = f"t = {self.traj.t[k]:.2f} s, |q_r - q| = {error:.3f} rad"

    def toggle(self) -> None:
        """Play from the slider's time (from the start at the end), or pause."""
        if not self.playing and self.slider.value >= self.slider.max - 1e-9:
            self.slider.value = self.slider.min
        self.playing = not self.playing

    def _run_player(self, frame_period: float = 1.0 / 25.0) -> None:
        while not self._stop.wait(frame_period):
            if not self.playing:
                continue
            value = min(self.slider.value + self.speed.value * frame_period, self.slider.max)
            self.slider.value = value
            self.show_time(value)
            if value >= self.slider.max:
                self.playing = False

    def stop(self) -> None:
        """Stop the player and the server."""
        self._stop.set()
        self.server.stop()


def write_html(
    trajectory: Trajectory | str | Path,
    out_path: str | Path,
    arm: Arm | str | Path | None = None,
    fps: float = 25.0,
) -> Path:
    """Write a self-contained ``.html`` playing ``trajectory`` back (``fps`` frames a second, real time).

    Opens in any browser, offline, with no server: viser's client with the recorded scene
    (timeline, play/pause); send it to a colleague. Returns the path.
    """
    import contextlib
    import io

    traj = as_trajectory(trajectory)
    the_arm = as_arm(arm, traj)
    quiet = contextlib.ExitStack()  # the server only serialises the scene: no banner for the user
    quiet.enter_context(contextlib.redirect_stdout(io.StringIO()))
    quiet.enter_context(contextlib.redirect_stderr(io.StringIO()))
    with quiet:
        server = viser.ViserServer(host="127.0.0.1", port=_free_port(), verbose=False)
    try:
        scene = ArmScene(server, the_arm, reach(the_arm, np.concatenate([traj.q, traj.q_ref])))
        scene.show(traj.q[0], traj.q_ref[0])
        serializer = server.get_scene_serializer()
        period = float(traj.t[1] - traj.t[0]) if len(traj.t) > 1 else 1.0 / fps
        stride = max(1, int(round(1.0 / (fps * period))))
        for k in range(stride, len(traj.t), stride):
            serializer.insert_sleep(stride * period)
            scene.show(traj.q[k], traj.q_ref[k])
        html = serializer.as_html()
    finally:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            server.stop()
    out_path = Path(out_path)
    tmp = out_path.with_name(out_path.name + ".tmp")
    tmp.write_text(html)
    tmp.replace(out_path)
    return out_path


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def serve_until_interrupted(viewer: TrajectoryViewer) -> None:
    """Block until Ctrl-C, then stop ``viewer``."""
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
